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

which :class:`LiftOffGate` checks against every trunk's safety ring. A mission that does not declare k_a (a user's
first, most likely) gets a typical quadrotor's (:func:`typical_airframe_drag`: C_d·A 0.04 m² at 1.25 kg), and the
gate then reads a push under :data:`ASSUMED_PUSH_FLOOR_MPS2` as no wind (eq. 49 pushes up to 0.37 m/s² in a climb,
and it drags nothing) and only holds: a lean for a wind inferred from an assumed drag lifted heavy payloads far
beyond their drag angle where the airframe's drag was twice the assumed one (docs/measurements.md). A payload whose
drag the mission leaves to be identified (``[payload] drag_n_per_mps2`` 0) is judged at the provisional drag's cap
(:data:`~companion.planning.drag_timing.PROVISIONAL_C_MAX`, rad per (m/s)², the most the flight budgets before it knows
c), and the climb leans for it as for half the cap (below). While it is blocked the climb holds :data:`WAIT_BELOW_M`
under the lift-off height (the payload still on the ground); it lifts off once the reach is clear, and after
:data:`MAX_WAIT_S` blocked the flight says there is no route. The push is measured only where the force observer
runs (controller ``smc_ff`` with a swing input); elsewhere the gate sees no wind and never holds.

The same wind says where to lift from: during the climb the reference moves upwind of the payload lying on the
ground by l·sin θ_eq (:func:`equilibrium_offset_m`, the measured wind, no gust; only as far as the way stays
:data:`LIFT_MARGIN_M` clear of every trunk's ring, :func:`clear_offset_m`), so the cable lifts the payload near its
drag equilibrium instead of releasing it at the vertical, whence it swung to twice θ_eq (0.1 kg on 2 m in a steady
6 m/s wind: 1.93·θ_eq before, 1.48·θ_eq so; docs/measurements.md). The point is frozen once the payload is lifted.
Lifted from a lean θ_L, a payload whose drag angle is θ_eq swings to max(θ_L, 2·θ_eq − θ_L): for a payload whose
drag is unknown the lean is taken at half the cap (:data:`LEAN_CAP_SHARE`). That keeps the swing within θ_L for
every payload up to it (more than lifting from above only where θ_eq < θ_L/2, a small swing either way) and lowers
it for every payload beyond (the twenty-first sitting's grid: docs/measurements.md).
The climb does not wait for the airframe to get there: waiting, it met other gusts, and the swing was no smaller.
It heads there at the planner's gain ka, or faster where the climb reaches the lift-off height in under three
time constants (:func:`lean_gain_per_s`: 3/s on 0.5 m, lifted 1 s into the climb; 0.1 kg in a steady 7 m/s wind
swings to 1.29·θ_eq, not 1.59·θ_eq). A faster gain on every cable chased the push's gusts on long ones
(docs/measurements.md).
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
from companion.planning.drag_timing import PROVISIONAL_C_MAX
from companion.planning.params import PlannerParams

WAIT_BELOW_M = 0.4  # (m) the climb waits this far below the height at which the cable lifts the payload
GUST_MPS = 2.0  # (m/s) the reach is judged in a wind this much stronger than measured
OVERSHOOT = 2.0  # the payload released into its drag equilibrium swings to this many times its angle
MAX_WAIT_S = 30.0  # (s) blocked this long: no route
PAYLOAD_R_M = 0.05  # (m) the payload's own radius beyond the point mass
LIFT_MARGIN_M = 0.1  # (m) the way to the lift point keeps this much beyond a trunk's safety ring (tracking)
LEAN_CAP_SHARE = 0.5  # a payload of unknown drag is leaned for as for this share of PROVISIONAL_C_MAX
#: an airframe whose drag the mission does not declare is taken to have a typical quadrotor's frontal C_d·A: this
#: at TYPICAL_MASS_KG (the bundled model's), the area scaled with the mass to the 2/3, in AIR_DENSITY_KGPM3
TYPICAL_DRAG_AREA_M2 = 0.04
TYPICAL_MASS_KG = 1.25
AIR_DENSITY_KGPM3 = 1.225
#: (m/s²) with the airframe's drag assumed, a push below this is read as no wind: 1.5× the most eq. 49 (which drags
#: nothing) pushes in a climb flown (0.37 m/s², the lockstep Table 2 missions); 5.5 m/s on the assumed airframe with
#: 0.1 kg. Flown at 0.35-0.7 (docs/measurements.md, 2026-12-05, twenty-third sitting)
ASSUMED_PUSH_FLOOR_MPS2 = 0.55

log = logging.getLogger(__name__)


def lean_gain_per_s(cable_m: float, p: PlannerParams) -> float:
    """(1/s) the climb's reference gain toward the lift point: the planner's ``ka``, or faster where the climb
    reaches the lift-off height (``cable_m`` up, accelerating at half ``az_max_mps2`` to ``vz_max_mps``) in less
    than three of its time constants."""
    a, v = 0.5 * p.az_max_mps2, p.vz_max_mps
    t = math.sqrt(2.0 * cable_m / a) if cable_m <= v * v / (2.0 * a) else v / a + (cable_m - v * v / (2.0 * a)) / v
    return max(p.ka, 3.0 / t)


def typical_airframe_drag(airframe_kg: float) -> float:
    """(N per (m/s)²) ½·ρ·C_d·A assumed for a quadrotor of ``airframe_kg`` (kg) whose drag is not declared:
    :data:`TYPICAL_DRAG_AREA_M2` at :data:`TYPICAL_MASS_KG`, the area scaled with the mass to the 2/3."""
    return 0.5 * AIR_DENSITY_KGPM3 * TYPICAL_DRAG_AREA_M2 * (airframe_kg / TYPICAL_MASS_KG) ** (2.0 / 3.0)


def wind_sq_from_push(push_mps2: float, m_total_kg: float, k_airframe: float) -> float:
    """|w|² ((m/s)²) of the wind whose drag k_a·|w|² on the airframe alone (``k_airframe``, N per (m/s)²) pushes the
    system of ``m_total_kg`` (kg) at ``push_mps2`` (m/s²)."""
    return max(push_mps2, 0.0) * m_total_kg / k_airframe


def payload_reach_m(push_mps2: float, m_total_kg: float, k_airframe: float, c_payload: float, cable_m: float
                    ) -> float:
    """How far (m) downwind of the airframe the payload swings once lifted: ``push_mps2`` the measured push on the
    system (m/s²) of total mass ``m_total_kg``, ``k_airframe`` the airframe's drag coefficient (N per (m/s)²),
    ``c_payload`` the payload's drag angle per (m/s)² (k_p/(m·g), rad), ``cable_m`` (m)."""
    wind = math.sqrt(wind_sq_from_push(push_mps2, m_total_kg, k_airframe)) + GUST_MPS
    theta = math.atan(c_payload * wind * wind)
    return cable_m * math.sin(min(OVERSHOOT * theta, 0.5 * math.pi))


def equilibrium_offset_m(push_mps2: tuple[float, float], m_total_kg: float, k_airframe: float, c_payload: float,
                         cable_m: float) -> tuple[float, float]:
    """(m, NED x y) where the airframe lifts the payload from, relative to where it lies: upwind by l·sin θ_eq in the
    wind the push ``push_mps2`` (m/s², NED x y) measures; arguments as :func:`payload_reach_m`."""
    h = math.hypot(*push_mps2)
    if h < 1e-6:
        return 0.0, 0.0
    theta = math.atan(c_payload * wind_sq_from_push(h, m_total_kg, k_airframe))
    d = cable_m * math.sin(theta)
    return -d * push_mps2[0] / h, -d * push_mps2[1] / h


def ring_entry_m(xy: tuple[float, float], unit: tuple[float, float], length_m: float, o: Obstacle,
                 radius_m: float) -> float | None:
    """How far (m) along the segment from ``xy`` ``length_m`` along ``unit`` (m, NED x y) it enters ``o``'s safety
    ring grown by ``radius_m`` (m): 0 when it starts inside, None when it stays outside."""
    dx, dy = o.x_m - xy[0], o.y_m - xy[1]
    r = o.radius_m + o.safe_distance_m + radius_m
    c = dx * dx + dy * dy - r * r
    if c < 0.0:
        return 0.0
    b = dx * unit[0] + dy * unit[1]  # along the segment to the ring's centre
    disc = b * b - c
    if b <= 0.0 or disc <= 0.0:
        return None
    s = b - math.sqrt(disc)
    return s if s < length_m else None


def clear_offset_m(origin_xy: tuple[float, float], offset_xy: tuple[float, float], obstacles: Sequence[Obstacle],
                   radius_m: float) -> tuple[float, float]:
    """``offset_xy`` (m, NED x y) shortened to where the segment from ``origin_xy`` along it first enters an
    obstacle's safety ring plus ``radius_m`` (m: the airframe's), whole when it enters none."""
    d = math.hypot(*offset_xy)
    if d < 1e-9:
        return offset_xy
    unit = (offset_xy[0] / d, offset_xy[1] / d)
    s = min((e for o in obstacles if (e := ring_entry_m(origin_xy, unit, d, o, radius_m)) is not None), default=d)
    return s * unit[0], s * unit[1]


def blocking_trunk(xy: tuple[float, float], unit: tuple[float, float], reach_m: float,
                   obstacles: Sequence[Obstacle]) -> Obstacle | None:
    """The first obstacle whose safety ring (plus the payload's radius) the segment from ``xy`` ``reach_m`` along
    ``unit`` (m, NED x y) touches, None when none does."""
    return next((o for o in obstacles if ring_entry_m(xy, unit, reach_m, o, PAYLOAD_R_M) is not None), None)


class LiftOffGate:
    """Whether the climb may lift the payload now (see module docstring). ``k_airframe`` (N per (m/s)²) > 0 arms
    it; ``c_payload`` (rad per (m/s)²) the payload's drag angle, 0 when unknown (the reach is then judged at
    :data:`PROVISIONAL_C_MAX`, the lean at :data:`LEAN_CAP_SHARE` of it); ``lift_z_ned_m`` where the cable lifts
    the payload (NED z, m); ``airframe_drag_declared`` False: ``k_airframe`` is assumed, a push below
    :data:`ASSUMED_PUSH_FLOOR_MPS2` is read as no wind, and the climb does not lean (:meth:`lift_point`)."""

    def __init__(self, k_airframe: float, c_payload: float, m_total_kg: float, cable_m: float,
                 lift_z_ned_m: float, origin_xy: tuple[float, float] = (0.0, 0.0),
                 lean_gain_per_s: float = PlannerParams.ka, airframe_drag_declared: bool = True) -> None:
        self.k_airframe, self.c_payload = k_airframe, c_payload
        self.airframe_drag_declared = airframe_drag_declared
        self.lean_gain_per_s = lean_gain_per_s  # (1/s) the climb's reference gain toward the lift point
        self.c_reach = c_payload if c_payload > 0.0 else PROVISIONAL_C_MAX  # (rad per (m/s)²) the reach's drag
        self.c_lean = c_payload if c_payload > 0.0 else LEAN_CAP_SHARE * PROVISIONAL_C_MAX  # (rad per (m/s)²)
        self.m_total_kg, self.cable_m = m_total_kg, cable_m
        self.wait_z_ned_m = lift_z_ned_m + WAIT_BELOW_M
        self.armed = k_airframe > 0.0
        self.open = not self.armed
        self.t_blocked_s: float | None = None  # when the current block began (s)
        self.waited_s = 0.0  # (s) blocked in all
        self.worst: dict[str, float] | None = None  # the largest reach judged blocked, for the report
        self._t_prev: float | None = None
        #: (m, NED x y) where the payload lies (the airframe's start) and the point upwind of it to lift it from
        self.origin_xy = origin_xy
        self.lift_xy = origin_xy

    def lift_point(self, push_mps2: tuple[float, float], obstacles: Sequence[Obstacle] = (),
                   airframe_r_m: float = 0.0) -> tuple[float, float]:
        """(m, NED x y) where the airframe heads during the climb: upwind of the payload by
        :func:`equilibrium_offset_m` while the payload lies on the ground (the gate not yet open), as far as the
        way there stays clear of ``obstacles`` for an airframe of ``airframe_r_m`` (m); then frozen. With the
        airframe's drag assumed, not declared, the payload's start (no lean)."""
        if self.armed and not self.open and self.airframe_drag_declared:
            off = equilibrium_offset_m(push_mps2, self.m_total_kg, self.k_airframe, self.c_lean, self.cable_m)
            dx, dy = clear_offset_m(self.origin_xy, off, obstacles, airframe_r_m + LIFT_MARGIN_M)
            self.lift_xy = (self.origin_xy[0] + dx, self.origin_xy[1] + dy)
        return self.lift_xy

    def lean_velocity(self, ref_xy: tuple[float, float], push_mps2: tuple[float, float],
                      obstacles: Sequence[Obstacle], airframe_r_m: float) -> tuple[float, float]:
        """(m/s, NED x y) the climb's horizontal reference velocity from ``ref_xy`` (m) toward :meth:`lift_point`
        (arguments as there): its gain times the way left."""
        lx, ly = self.lift_point(push_mps2, obstacles, airframe_r_m)
        k = self.lean_gain_per_s
        return k * (lx - ref_xy[0]), k * (ly - ref_xy[1])

    def target_z(self, t_s: float, xy: tuple[float, float], ref_z_ned_m: float, push_mps2: tuple[float, float],
                 obstacles: Sequence[Obstacle], climb_z_ned_m: float) -> float:
        """Where the climb heads this tick (NED z, m): ``climb_z_ned_m`` once open, else the wait height while the
        payload's reach downwind of the airframe at ``xy`` (m) touches a trunk. Opens for good once the reference
        (``ref_z_ned_m``) passes the wait height unblocked."""
        if self.open:
            return climb_z_ned_m
        dt = 0.0 if self._t_prev is None else t_s - self._t_prev
        self._t_prev = t_s
        h = math.hypot(*push_mps2)
        if not self.airframe_drag_declared and h < ASSUMED_PUSH_FLOOR_MPS2:  # no wind an assumed drag can judge
            h, push_mps2 = 0.0, (0.0, 0.0)
        reach = payload_reach_m(h, self.m_total_kg, self.k_airframe, self.c_reach, self.cable_m)
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
        """The report's ``lift_off``: armed (the climb lifts the payload off the ground), whether the airframe's drag
        was declared (else a typical one was assumed and a push under the floor ignored), the one used (N per
        (m/s)²; 0 unarmed), whether the payload's was declared (else the
        reach was judged at the provisional cap), seconds blocked (from the first blocked tick,
        climbing below the wait height included), the largest reach that blocked it, and how far upwind of the
        payload the climb leaned to lift it (m, :meth:`lift_point`)."""
        lean = math.hypot(self.lift_xy[0] - self.origin_xy[0], self.lift_xy[1] - self.origin_xy[1])
        return {"armed": self.armed, "airframe_drag_declared": self.airframe_drag_declared,
                "airframe_drag_n_per_mps2": round(self.k_airframe, 5), "payload_drag_declared": self.c_payload > 0.0,
                "waited_s": round(self.waited_s, 3), "held_by": self.worst, "lean_m": round(lean, 3)}

    def timed_out(self, t_s: float) -> bool:
        """Blocked for :data:`MAX_WAIT_S` without a break (warned of once: the flight ends ``no_route``)."""
        out = self.t_blocked_s is not None and t_s - self.t_blocked_s >= MAX_WAIT_S
        if out:
            log.warning("the wind held the payload on the ground for %.0f s: no lift-off, no route", MAX_WAIT_S)
        return out


def lift_gate(mission: Mission, params: VehicleParams, planner: PlannerParams, z0_ned_m: float,
              climb_z_ned_m: float, origin_xy: tuple[float, float] = (0.0, 0.0)) -> LiftOffGate:
    """The gate of a flight that starts at ``z0_ned_m`` and ``origin_xy`` (NED, m) and climbs to ``climb_z_ned_m``
    (NED z, m) with ``params``, leaning at :func:`lean_gain_per_s` for its cable and ``planner``:
    armed when the climb lifts the payload off the ground, open otherwise. The airframe's drag coefficient is
    ``mission``'s ``[payload]`` one, or where it declares none :func:`typical_airframe_drag` (assumed: see
    :class:`LiftOffGate`); the payload's drag from the mission too, or unknown."""
    pay = mission.payload
    lifts = z0_ned_m > -params.l and climb_z_ned_m < -params.l
    declared = pay.airframe_drag_n_per_mps2 > 0.0
    k_a = pay.airframe_drag_n_per_mps2 if declared else typical_airframe_drag(params.M)
    return LiftOffGate(k_a if lifts else 0.0, declared_drag_c(pay.drag_n_per_mps2, params.m, params.g),
                       params.M + params.m, params.l, -params.l, origin_xy, lean_gain_per_s(params.l, planner),
                       declared)
