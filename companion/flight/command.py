"""What the flight core hands out each tick (:class:`Command`), what the pilot streams of it (:class:`Setpoint`) and
where its climb ends. Pure data."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from companion.flight.phase import CorePhase


class Setpoint(NamedTuple):
    """An attitude setpoint to stream: vehicle time (s), attitude quaternion [w, x, y, z] body FRD → NED, thrust
    (0..1)."""

    t_s: float
    q_ned_frd_wxyz: np.ndarray
    thrust_norm: float


class Command(NamedTuple):
    """One attitude setpoint plus what led to it (for SET_ATTITUDE_TARGET, the report and telemetry).

    q_ned_frd_wxyz: attitude quaternion [w, x, y, z] body FRD → NED; thrust_n (N) and thrust_norm (0..1,
    via the vehicle profile); euler_cmd_rad [φ, θ, ψ]; reference position/velocity/acceleration (NED, SI);
    force_att_n / force_rep_n: the planner's attractive and repulsive parts (2,) (velocity units for the
    APF-as-gradient-flow, see :mod:`companion.planning.apf`); r_max_m: envelope radius used;
    envelope_mode: ``"swing"`` or ``"full_cable"``; phase; ff_accel (3,) m/s² anti-swing feed-forward;
    plan_mode: ``"track"`` or ``"escape"`` (safe planner's trap escape), ``"brake"`` / ``"wait"`` / ``"no_route"``
    (shaped planner stopping; waiting for the wind); no_route: the planner found no route to the goal (the mission
    ends ``no_route``).
    A named tuple: immutable, and cheap to build every tick.
    """

    t_s: float
    q_ned_frd_wxyz: np.ndarray
    thrust_n: float
    thrust_norm: float
    euler_cmd_rad: np.ndarray
    ref_pos_ned_m: np.ndarray
    ref_vel_ned_mps: np.ndarray
    ref_acc_ned_mps2: np.ndarray
    force_att_n: np.ndarray
    force_rep_n: np.ndarray
    r_max_m: float
    envelope_mode: str
    phase: CorePhase
    ff_accel: np.ndarray
    plan_mode: str = "track"
    no_route: bool = False


LIFT_MARGIN_M = 0.3  # a payload lifted off the ground hangs this far clear of it before the vehicle moves sideways


def climb_altitude_ned_m(z0_ned_m: float, start_z_ned_m: float, cable_m: float) -> float:
    """Where the vertical climb ends (NED z, m): the mission's start altitude, but a vehicle taking off with its
    payload on the ground (less than a cable's length up) first lifts it straight up, to a cable's length plus
    LIFT_MARGIN_M, before it moves sideways.

    Moving off diagonally drags the payload: the cable snaps taut at an angle and the payload swings from there
    (Group 1, origin to 5 m above (3, 4), took off at 45°: 0.55 rad at lift-off, against 0.2 rad in flight)."""
    lift_z = -(cable_m + LIFT_MARGIN_M)
    if z0_ned_m > -cable_m and start_z_ned_m > lift_z:
        return lift_z
    return start_z_ned_m
