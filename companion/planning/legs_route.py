"""The shaped planner's route through waypoints: one path through every pass-through waypoint to the stop at the
end of the stretch, timed as one (no stop in between), each leg under its own speed limit. Pure.

The route is the shortest route around the discs leg by leg (:func:`companion.planning.route.find_route` from
the replan state to the first waypoint, from there to the next, ... to the goal), concatenated; the
minimum-curvature relaxation (:func:`companion.planning.path.smooth_path_pinned`) keeps the path within
:data:`PIN_M` of each waypoint (it turns the corner there instead of stopping), and the timing
(:func:`companion.planning.timing.speed_profile` with ``caps``) keeps each leg under its limit. Only the plain
inflations of the route search are timed (not the other side of an apex): each leg is short.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.planning.params import PlannerParams
from companion.planning.path import smooth_path_pinned
from companion.planning.route import find_route
from companion.planning.timing import DragBudget, Profile, speed_profile

PIN_M = 0.3  # the path passes within this much (m) of a waypoint's route point
PLAN_PASS_M = 1.2  # a waypoint this close (m) with the state beyond it is behind the plan


def route_through(p0: np.ndarray, vias: Sequence[np.ndarray], goal: np.ndarray, c: np.ndarray, r: np.ndarray,
                  hard: np.ndarray) -> tuple[np.ndarray, tuple[float, ...]] | None:
    """The route from ``p0`` through ``vias`` to ``goal`` around the discs (points (n, 2) m), and the arc length
    (m, along those points) of each via; None when a leg has no route."""
    parts: list[np.ndarray] = []
    at: list[float] = []
    length = 0.0
    a = np.asarray(p0, dtype=np.float64)
    for b in (*vias, goal):
        rt = find_route(a, b, c, r, hard)
        if rt is None:
            return None
        pts = rt.points if not parts else rt.points[1:]
        if len(pts):
            prev = parts[-1][-1] if parts else pts[0]
            length += float(np.sum(np.hypot(*np.diff(np.vstack([prev[None, :], pts]), axis=0).T)))
        parts.append(pts)
        at.append(length)
        a = np.asarray(b, dtype=np.float64)
    return np.concatenate(parts), tuple(at[:-1])


def remaining_vias(p0: np.ndarray, vias: Sequence[np.ndarray], goal: np.ndarray, caps: Sequence[float]
                   ) -> tuple[tuple[np.ndarray, ...], tuple[float, ...]]:
    """The vias (and leg caps) still ahead of the plan state ``p0``: leading ones within :data:`PLAN_PASS_M`
    that ``p0`` is already beyond (along the direction to the next point) are dropped (the flight core counts
    them passed a moment later, when the vehicle, behind its reference, gets there)."""
    vs, cs = list(vias), list(caps) if caps else [math.inf] * (len(vias) + 1)
    while vs:
        nxt = vs[1] if len(vs) > 1 else goal
        d = np.asarray(nxt, dtype=np.float64) - vs[0]
        rel = np.asarray(p0, dtype=np.float64) - vs[0]
        if not (float(np.hypot(*rel)) < PLAN_PASS_M and float(rel @ d) > 0.0):
            break
        vs.pop(0)
        cs.pop(0)
    return tuple(vs), tuple(cs)


def timed_through(p0: np.ndarray, v0: np.ndarray, vias: Sequence[np.ndarray], caps: Sequence[float],
                  goal: np.ndarray, c: np.ndarray, ring: np.ndarray, hard: np.ndarray, a_max: float,
                  p: PlannerParams, extras: Sequence[float], drag: DragBudget | None = None
                  ) -> list[tuple[Profile, float]]:
    """Timed routes through ``vias`` to ``goal``: (profile, the inflation (m) it was found with), one per
    inflation in ``extras`` that has a route of a length not seen yet, fastest first; ``drag`` as in
    :func:`~companion.planning.timing.speed_profile`."""
    speed = math.hypot(float(v0[0]), float(v0[1]))
    heading = v0 / speed if speed > 0.05 else None
    out: list[tuple[Profile, float]] = []
    lengths: list[float] = []
    lim = np.asarray(caps if caps else [math.inf] * (len(vias) + 1), dtype=np.float64)
    for e in extras:
        rt = route_through(p0, vias, goal, c, ring + e, hard)
        if rt is None:
            continue
        pts, at = rt
        total = float(np.sum(np.hypot(*np.diff(pts, axis=0).T))) if len(pts) > 1 else 0.0
        if any(abs(total - L) < 1e-3 for L in lengths):
            continue
        lengths.append(total)
        path, pins = smooth_path_pinned(pts, c, ring, ds_m=p.route_ds_m, heading=heading, pins_s_m=at, pin_m=PIN_M)
        s_path = np.r_[0.0, np.cumsum(np.hypot(*np.diff(path, axis=0).T))]
        ends = np.array([s_path[k] for k in pins], dtype=np.float64)
        prof = speed_profile(path, speed, a_max_mps2=a_max, v_max_mps=p.shaped_v_max_mps, heading=heading,
                             a_brake_mps2=p.shaped_brake_mps2, caps=(ends, lim) if np.any(np.isfinite(lim)) else None,
                             drag=drag)
        out.append((prof, e))
    out.sort(key=lambda pe: pe[0].duration_s)
    return out
