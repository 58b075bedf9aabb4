"""The legs of a multi-leg mission: which point the flight heads for now, when a waypoint counts as passed or
reached, and the hold at a waypoint. Pure; times are the estimates' (s), positions NED metres.

The targets are the mission's waypoints in order, then the goal. A waypoint without a hold is *passed* without
stopping: within :data:`PASS_RADIUS_M` horizontally (the reference turns the corner there), or within twice that
once the vehicle is beyond the corner's bisector (a path that cut the corner a little wider); horizontally only:
its altitude is where the vertical channel heads on the leg that ends there, and the flight does not wait for it
(waiting let a planner that had passed the point fly on while the core still waited). A waypoint with
``hold_s`` > 0 is *reached* by the goal's rule (:class:`~companion.flight.arrival.ArrivalRule`: the arrival
tolerance for a dwell) and hovered ``hold_s`` before the flight leaves it. The goal itself stays the flight
core's own business (its arrival rule and hold).

What a planner is given (see :meth:`Legs.plan_goal`): a velocity planner (safe, APF) the current target, with
the speed it may pass it at (:meth:`Legs.pass_speed_mps`, 0 at a hold or the goal); a time-parameterised
planner (shaped) the end of the current *stretch* (the next hold waypoint, or the goal) and the pass-through
waypoints before it, to plan as one path, with each leg's speed limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.control import feedforward_xyz
from companion.control.params import FeedForwardGains
from companion.core.mission import Mission
from companion.estimation.estimate import Estimate
from companion.flight.arrival import ArrivalRule
from companion.planning import PlanOutput
from companion.planning.legs_route import PLAN_PASS_M

PASS_RADIUS_M = 0.6  # a pass-through waypoint counts as passed this close (m, horizontally)


@dataclass(frozen=True, slots=True)
class Target:
    """One point of the mission: NED position (m), hover ``hold_s`` (s), the speed limit of the leg ending here
    (m/s, None: the planner's own), name, and whether it is the goal."""

    pos_ned_m: np.ndarray
    hold_s: float
    speed_max_mps: float | None
    name: str
    is_goal: bool = False


class Legs:
    """Where a multi-leg mission is (see module docstring); :meth:`update` once a cruise tick."""

    def __init__(self, mission: Mission, v_max_mps: float) -> None:
        self.targets = [Target(np.asarray(w.pos_ned_m, dtype=np.float64), float(w.hold_s), w.speed_max_mps,
                               w.name or f"wp{i + 1}") for i, w in enumerate(mission.waypoints)]
        self.targets.append(Target(np.asarray(mission.goal_ned_m, dtype=np.float64), float(mission.hold_s), None,
                                   "goal", True))
        self.v_max_mps = v_max_mps
        self.index = 0
        n = len(mission.waypoints)
        self.reached_t_s: list[float | None] = [None] * n
        self.closest_m: list[float] = [math.inf] * n
        self.hold_until_s: float | None = None
        self._prev_xy = np.asarray(mission.start_ned_m[:2], dtype=np.float64)
        self._arrival: ArrivalRule | None = None

    # ------------------------------------------------------------------------------------------------
    @property
    def at_goal(self) -> bool:
        """True once every waypoint is behind: the goal is the target."""
        return self.index >= len(self.targets) - 1

    @property
    def current(self) -> Target:
        """The point the flight heads for now."""
        return self.targets[self.index]

    @property
    def holding(self) -> bool:
        """True while hovering at a hold waypoint."""
        return self.hold_until_s is not None

    def stretch_end(self) -> int:
        """Index of the next point the flight stops at: the next hold waypoint or the goal."""
        k = self.index
        while not (self.targets[k].is_goal or self.targets[k].hold_s > 0.0):
            k += 1
        return k

    def plan_goal(self, timed: bool) -> tuple[np.ndarray, tuple[np.ndarray, ...], tuple[float, ...]]:
        """(goal (2,) m, pass-through points before it ((2,) m each), speed limit of each leg (m/s, inf: none))
        for the planner: the current target alone for a velocity planner, the stretch for a timed one."""
        end = self.stretch_end() if timed else self.index
        legs = self.targets[self.index:end + 1]
        caps = tuple(math.inf if t.speed_max_mps is None else float(t.speed_max_mps) for t in legs)
        return legs[-1].pos_ned_m[:2].copy(), tuple(t.pos_ned_m[:2].copy() for t in legs[:-1]), caps

    def speed_max_mps(self) -> float | None:
        """The current leg's speed limit (m/s), None when it has none."""
        return self.current.speed_max_mps

    def _turn(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions (2,) into and out of the current target (out = in at the last point)."""
        w = self.current.pos_ned_m[:2]
        u_in = w - self._prev_xy
        n_in = float(np.hypot(*u_in))
        u_in = u_in / n_in if n_in > 1e-9 else np.array((1.0, 0.0))
        if self.index + 1 >= len(self.targets):
            return u_in, u_in
        u_out = self.targets[self.index + 1].pos_ned_m[:2] - w
        n_out = float(np.hypot(*u_out))
        return u_in, (u_out / n_out if n_out > 1e-9 else u_in)

    def pass_speed_mps(self) -> float:
        """The speed (m/s) a velocity planner may pass the current target at: the slower leg's limit times
        cos(turn/2) (a straight pass at full speed, a right angle at 71 %, a reversal at 0); 0 at a hold or the goal."""
        t = self.current
        if t.is_goal or t.hold_s > 0.0:
            return 0.0
        u_in, u_out = self._turn()
        cos_half = math.sqrt(max(0.0, 0.5 * (1.0 + float(u_in @ u_out))))
        nxt = self.targets[self.index + 1].speed_max_mps
        v = min([self.v_max_mps] + [c for c in (t.speed_max_mps, nxt) if c is not None])
        return v * cos_half

    # ------------------------------------------------------------------------------------------------
    def update(self, est: Estimate, plan_xy: tuple[float, float] | None = None) -> bool:
        """Advance past, or hold at, the current waypoint; True when a waypoint was passed or left this tick.
        ``plan_xy``: a time-parameterised plan's reference (m): the point also counts as passed once the plan
        has dropped it (:func:`companion.planning.legs_route.remaining_vias`: the reference within
        PLAN_PASS_M and beyond it along the next leg), so that the core never waits for a point its planner
        has flown past."""
        if self.at_goal:
            return False
        i, t = self.index, self.current
        pos = est.pos_ned_m
        d = math.hypot(float(pos[0]) - t.pos_ned_m[0], float(pos[1]) - t.pos_ned_m[1])
        self.closest_m[i] = min(self.closest_m[i], d)
        if self.hold_until_s is not None:
            if est.t_s >= self.hold_until_s:
                self._next()
                return True
            return False
        if t.hold_s > 0.0:
            if self._arrival is None:
                self._arrival = ArrivalRule(t.pos_ned_m)
            arrived = self._arrival.arrived(est)
            if arrived is not None:
                self.reached_t_s[i] = arrived
                self.hold_until_s = arrived + t.hold_s
            return False
        u_in, u_out = self._turn()
        bis = u_in + u_out
        beyond = (float(pos[0]) - t.pos_ned_m[0]) * bis[0] + (float(pos[1]) - t.pos_ned_m[1]) * bis[1] >= 0.0
        if d < PASS_RADIUS_M or (beyond and d < 2.0 * PASS_RADIUS_M) or self._plan_passed(plan_xy, u_out):
            self.reached_t_s[i] = est.t_s
            self._next()
            return True
        return False

    def _plan_passed(self, plan_xy: tuple[float, float] | None, u_out: np.ndarray) -> bool:
        """Whether the plan's reference is past the current waypoint by the planner's own rule."""
        if plan_xy is None:
            return False
        rx, ry = plan_xy[0] - self.current.pos_ned_m[0], plan_xy[1] - self.current.pos_ned_m[1]
        return math.hypot(rx, ry) < PLAN_PASS_M and rx * u_out[0] + ry * u_out[1] > 0.0

    def _next(self) -> None:
        self._prev_xy = self.current.pos_ned_m[:2].copy()
        self.index += 1
        self.hold_until_s = None
        self._arrival = None

    def facts(self) -> list[dict[str, object]]:
        """Per waypoint, for the report: name, position (m), hold (s), speed limit (m/s), when it was reached or
        passed (vehicle time, s; None: never) and the closest the vehicle came (m, horizontally)."""
        return [{"name": t.name, "ned_m": [float(c) for c in t.pos_ned_m], "hold_s": t.hold_s,
                 "speed_max_mps": t.speed_max_mps, "reached_t_s": self.reached_t_s[i],
                 "closest_m": None if math.isinf(self.closest_m[i]) else round(self.closest_m[i], 3)}
                for i, t in enumerate(self.targets[:-1])]


_NO_LEGS: dict[str, object] = {}


def legs_done(legs: Legs | None, est: Estimate, plan_xy: tuple[float, float] | None = None) -> bool:
    """Advance a multi-leg mission's waypoints (:meth:`Legs.update`, ``plan_xy`` a timed plan's reference (m));
    True once the goal is the target (always for a mission without waypoints)."""
    if legs is None:
        return True
    legs.update(est, plan_xy)
    return legs.at_goal


def leg_plan(legs: Legs | None, mission: Mission, goal_xy: np.ndarray, timed: bool
             ) -> tuple[np.ndarray, float, dict[str, object], float | None]:
    """What the planner is given this tick: (goal (2,) m, the altitude to fly at (NED z, m), the PlanInput's
    multi-leg fields, the current leg's speed limit (m/s) or None). Without waypoints: the mission's goal,
    nothing else."""
    if legs is None:
        return goal_xy, float(mission.goal_ned_m[2]), _NO_LEGS, None
    goal, vias, caps = legs.plan_goal(timed)
    fields = {"via_m": vias, "leg_caps_mps": caps, "goal_pass_mps": 0.0 if timed else legs.pass_speed_mps()}
    return goal, float(legs.current.pos_ned_m[2]), fields, legs.speed_max_mps()


def capped(vx: float, vy: float, cap: float | None) -> tuple[float, float]:
    """The horizontal velocity (m/s) scaled down to ``cap`` (m/s) if faster (None: unchanged)."""
    n = math.hypot(vx, vy)
    if cap is None or n <= cap:
        return vx, vy
    return vx * cap / n, vy * cap / n


def planned_swing_acc(out: PlanOutput, ref_acc: list[float], trust: float, ff_cfg: FeedForwardGains,
                      cable_l_m: float) -> list[float] | None:
    """Reference acceleration (m/s², NED) for a feed-forward controller (the smc_ff) flying a time-parameterised
    plan: a_ref − trust·ff(nominal swing): the feed-forward then acts on the deviation from the planned swing
    only; ``trust`` (0..1) is the one the controller's swing is scaled by. None without a planned reference."""
    r = out.reference
    if r is None:
        return None
    fx, fy, fz = feedforward_xyz(*(float(v) for v in r.swing_nom), ff_cfg, cable_l_m)
    return [ref_acc[0] - trust * fx, ref_acc[1] - trust * fy, ref_acc[2] - trust * fz]
