"""Lifting the payload off only when the wind cannot blow it into a trunk (issue 28).

A payload lying on the ground feels no swing; the moment the cable lifts it, the wind's drag acts on it at once.
Its drag equilibrium is the angle θ_eq with tan θ_eq = k_p·|w|²/(m·g) (k_p the payload's drag coefficient,
N per (m/s)², w the wind), and a step into an equilibrium overshoots: an undamped pendulum released at the
vertical swings out to twice it. On a 3 m cable in a 13.6 m/s gust a 0.1 kg payload's equilibrium alone lies
1.76 m downwind, and the drag accelerates it there at ~5 m/s²: no move of the airframe after the lift-off can stop
it (docs/measurements.md, 2026-12-05). The companion measures the wind from the hanging payload's swing only
(:mod:`companion.control.drag_id`), too late for this.

Before the lift-off the airframe alone feels the wind: the force observer's push d (m/s² of the whole system,
:class:`~companion.control.disturbance.ForceObserver`) is its drag k_a·|w|²/(M + m) while it holds its place, the
payload's cable slack. With the airframe's drag coefficient k_a declared (``[payload] airframe_drag_n_per_mps2``)
that gives the wind speed, and so the payload's reach at the lift-off,

    reach = l·sin(min(OVERSHOOT·θ_eq(|w| + GUST_MPS), π/2))     downwind of the airframe,

which :class:`LiftOffGate` checks against every trunk's safety ring. While it is blocked the climb holds
:data:`WAIT_BELOW_M` under the lift-off height (the payload still on the ground); it lifts off once the reach is
clear, and after :data:`MAX_WAIT_S` blocked the flight says there is no route. The push is measured only where
the force observer runs (controller ``smc_ff`` with a swing input); elsewhere the gate sees no wind and never holds.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

from companion.control.drag_id import declared_drag_c
from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams

WAIT_BELOW_M = 0.4  # (m) the climb waits this far below the height at which the cable lifts the payload
GUST_MPS = 2.0  # (m/s) the reach is judged in a wind this much stronger than measured
OVERSHOOT = 2.0  # the payload released into its drag equilibrium swings to this many times its angle
MAX_WAIT_S = 30.0  # (s) blocked this long: no route
PAYLOAD_R_M = 0.05  # (m) the payload's own radius beyond the point mass

log = logging.getLogger(__name__)


def payload_reach_m(push_mps2: float, m_total_kg: float, k_airframe: float, c_payload: float, cable_m: float
                    ) -> float:
    """How far (m) downwind of the airframe the payload swings once lifted: ``push_mps2`` the measured push on the
    system (m/s²) of total mass ``m_total_kg``, ``k_airframe`` the airframe's drag coefficient (N per (m/s)²),
    ``c_payload`` the payload's drag angle per (m/s)² (k_p/(m·g), rad), ``cable_m`` (m)."""
    wind = math.sqrt(max(push_mps2, 0.0) * m_total_kg / k_airframe) + GUST_MPS
    theta = math.atan(c_payload * wind * wind)
    return cable_m * math.sin(min(OVERSHOOT * theta, 0.5 * math.pi))


def blocking_trunk(xy: tuple[float, float], unit: tuple[float, float], reach_m: float,
                   obstacles: Sequence[Obstacle]) -> Obstacle | None:
    """The first obstacle whose safety ring (plus the payload's radius) the segment from ``xy`` ``reach_m`` along
    ``unit`` (m, NED x y) touches, None when none does."""
    x0, y0 = xy
    ux, uy = unit
    for o in obstacles:
        s = min(max((o.x_m - x0) * ux + (o.y_m - y0) * uy, 0.0), reach_m)
        if math.hypot(x0 + s * ux - o.x_m, y0 + s * uy - o.y_m) < o.radius_m + o.safe_distance_m + PAYLOAD_R_M:
            return o
    return None


class LiftOffGate:
    """Whether the climb may lift the payload now (see module docstring). ``k_airframe`` (N per (m/s)²) and
    ``c_payload`` (rad per (m/s)²) > 0 arm it; ``lift_z_ned_m`` where the cable lifts the payload (NED z, m)."""

    def __init__(self, k_airframe: float, c_payload: float, m_total_kg: float, cable_m: float,
                 lift_z_ned_m: float) -> None:
        self.k_airframe, self.c_payload = k_airframe, c_payload
        self.m_total_kg, self.cable_m = m_total_kg, cable_m
        self.wait_z_ned_m = lift_z_ned_m + WAIT_BELOW_M
        self.armed = k_airframe > 0.0 and c_payload > 0.0
        self.open = not self.armed
        self.t_blocked_s: float | None = None  # when the current block began (s)
        self.waited_s = 0.0  # (s) blocked in all
        self.worst: dict[str, float] | None = None  # the largest reach judged blocked, for the report
        self._t_prev: float | None = None

    def target_z(self, t_s: float, xy: tuple[float, float], ref_z_ned_m: float, push_mps2: tuple[float, float],
                 obstacles: Sequence[Obstacle], climb_z_ned_m: float) -> float:
        """Where the climb heads this tick (NED z, m): ``climb_z_ned_m`` once open, else the wait height while the
        payload's reach downwind of ``xy`` touches a trunk. Opens for good once the reference (``ref_z_ned_m``)
        passes the wait height unblocked."""
        if self.open:
            return climb_z_ned_m
        dt = 0.0 if self._t_prev is None else t_s - self._t_prev
        self._t_prev = t_s
        h = math.hypot(*push_mps2)
        reach = payload_reach_m(h, self.m_total_kg, self.k_airframe, self.c_payload, self.cable_m)
        hit = blocking_trunk(xy, (push_mps2[0] / h, push_mps2[1] / h), reach, obstacles) if h > 1e-6 else None
        if hit is None:
            self.t_blocked_s = None
            if ref_z_ned_m <= self.wait_z_ned_m + 1e-3:
                self.open = True
                if self.waited_s > 0.0:
                    log.info("lifting the payload off after %.1f s of waiting for the wind", self.waited_s)
            return climb_z_ned_m
        if self.t_blocked_s is None:
            self.t_blocked_s = t_s
            if self.worst is None:
                log.info("lift-off held: the wind would swing the payload %.2f m downwind, into the trunk at "
                         "(%.1f, %.1f)", reach, hit.x_m, hit.y_m)
        self.waited_s += dt
        if self.worst is None or reach > self.worst["reach_m"]:
            self.worst = {"reach_m": round(reach, 3), "t_s": round(t_s, 3), "trunk_x_m": hit.x_m, "trunk_y_m": hit.y_m}
        return max(self.wait_z_ned_m, climb_z_ned_m)

    def facts(self) -> dict[str, Any]:
        """The report's ``lift_off``: armed (both drags declared), seconds blocked (from the first blocked tick,
        climbing below the wait height included), the largest reach that blocked it."""
        return {"armed": self.armed, "waited_s": round(self.waited_s, 3), "held_by": self.worst}

    def timed_out(self, t_s: float) -> bool:
        """Blocked for :data:`MAX_WAIT_S` without a break (warned of once: the flight ends ``no_route``)."""
        out = self.t_blocked_s is not None and t_s - self.t_blocked_s >= MAX_WAIT_S
        if out:
            log.warning("the wind held the payload on the ground for %.0f s: no lift-off, no route", MAX_WAIT_S)
        return out


def lift_gate(mission: Mission, params: VehicleParams, z0_ned_m: float, climb_z_ned_m: float) -> LiftOffGate:
    """The gate of a flight that starts at ``z0_ned_m`` and climbs to ``climb_z_ned_m`` (NED z, m) with ``params``:
    armed when the climb lifts the payload off the ground and ``mission``'s ``[payload]`` declares both drag
    coefficients, open otherwise."""
    pay = mission.payload
    lifts = z0_ned_m > -params.l and climb_z_ned_m < -params.l
    k_a = pay.airframe_drag_n_per_mps2 if lifts else 0.0
    return LiftOffGate(k_a, declared_drag_c(pay.drag_n_per_mps2, params.m, params.g), params.M + params.m, params.l,
                       -params.l)
