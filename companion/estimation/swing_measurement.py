"""The swing measured (not estimated): from the cable-angle sensor or from the payload's position, whichever is
fresh and allowed. Pure: the vehicle state's latest samples in, angles (rad, rad/s) out.

Swing input, in order of preference:

1. the cable-angle sensor: ``DEBUG_FLOAT_ARRAY`` named ``"SWING"`` (data = [α, β, α̇, β̇, l]) from the
   vehicle — used while it is fresher than ``swing_max_age_s`` (default 0.05 s of vehicle time); a data[4]
   shorter than the cable says the payload rests on the ground with the cable slack: no swing (zeros);
2. the payload's own position stream (``LOCAL_POSITION_NED`` from the payload system, as ArduPilot's
   slung-payload simulation sends it), inverted through eqs. 3–4 — used while fresher than 0.3 s;
3. none: the estimate carries ``swing=None``; the flight core then flies without feed-forward and with
   the full-cable-length envelope, and says so in its commands.

``swing_input`` restricts the choice: ``"auto"`` (the order above), ``"cable_sensor"``, ``"payload_position"``
or ``"none"`` (ignore both, e.g. to fly as a vehicle without any swing measurement would).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from companion.core.floats import floats
from companion.estimation.estimate import swing_from_payload

SLACK_FRACTION = 0.95  # a payload nearer than this fraction of the cable's length lies on the ground (no swing)
ZERO_SWING = np.zeros(4)  # [α, β, α̇, β̇] of a payload resting on the ground (read-only, shared)
ZERO_SWING.flags.writeable = False


class SwingSources(Protocol):
    """What the choice reads of :class:`~companion.estimation.vehicle_state.VehicleState` (vehicle time, s)."""

    cable_length_m: float
    swing_input: str
    swing_max_age_s: float
    payload_max_age_s: float
    t_s: float
    pos_ned_m: np.ndarray | None
    vel_ned_mps: np.ndarray | None
    swing_sensor: np.ndarray | None
    swing_sensor_t_s: float
    payload_pos_ned_m: np.ndarray | None
    payload_vel_ned_mps: np.ndarray | None
    payload_t_s: float


def measured_swing(st: SwingSources) -> np.ndarray | None:
    """The best swing measurement available, whatever ``swing_input`` says (for logs and metrics)."""
    if st.swing_sensor is not None and st.t_s - st.swing_sensor_t_s <= st.swing_max_age_s:
        return st.swing_sensor
    if st.pos_ned_m is None or st.payload_pos_ned_m is None or st.payload_vel_ned_mps is None:
        return None
    if st.vel_ned_mps is None or st.t_s - st.payload_t_s > st.payload_max_age_s:
        return None
    return payload_swing(st)


def payload_swing(st: SwingSources) -> np.ndarray | None:
    """Swing angles from the payload's position; zero while it rests on the ground (nearer than the cable)."""
    assert st.pos_ned_m is not None and st.payload_pos_ned_m is not None
    if math.dist(st.pos_ned_m, st.payload_pos_ned_m) < SLACK_FRACTION * st.cable_length_m:
        return ZERO_SWING
    try:
        return swing_from_payload(st.pos_ned_m, st.payload_pos_ned_m, st.vel_ned_mps, st.payload_vel_ned_mps,
                                  st.cable_length_m)
    except ValueError:
        return None


def chosen_swing(st: SwingSources) -> tuple[np.ndarray | None, str]:
    """(swing [α, β, α̇, β̇], its source) for the estimate, as ``swing_input`` allows: ``cable_sensor``,
    ``payload_position`` or (None, ``none``), also when the chosen one is not finite."""
    swing = None
    source = "none"
    use_cable = st.swing_input in ("auto", "cable_sensor")
    use_payload = st.swing_input in ("auto", "payload_position")
    if (
        use_cable
        and st.swing_sensor is not None
        and st.t_s - st.swing_sensor_t_s <= st.swing_max_age_s
    ):
        swing, source = st.swing_sensor, "cable_sensor"
    elif (
        use_payload
        and st.payload_pos_ned_m is not None
        and st.payload_vel_ned_mps is not None
        and st.t_s - st.payload_t_s <= st.payload_max_age_s
    ):
        swing = payload_swing(st)
        source = "payload_position" if swing is not None else "none"
    if swing is not None and not all(map(math.isfinite, floats(swing))):
        swing, source = None, "none"
    return swing, source
