"""Candidate routes for the shaped planner, timed, and the capsules that stand for moving obstacles.

Which routes to time (see :mod:`companion.planning.shaped`, step 2): the shortest route around the discs and
the routes around the discs inflated by k·``route_extra_m`` (k < ``route_candidates``), which pass through ever
wider gaps; then the apex of the fastest one (its point farthest from the straight line to the goal) is walled
off by a large disc beyond it and the first half of those inflations searched again: the best routes on the
other side of that apex. Each route becomes a minimum-curvature path in the real free space
(:mod:`companion.planning.path`) timed at the acceleration bound (:mod:`companion.planning.timing`);
candidates are compared by time, not length.

Moving obstacles enter the route search as capsules: discs along the obstacle's predicted track around the
time the plan would meet it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from companion.planning.clearance import Predicted, clearance
from companion.planning.legs_route import timed_through
from companion.planning.params import PlannerParams
from companion.planning.path import smooth_path
from companion.planning.route import find_route
from companion.planning.timeline import Timeline
from companion.planning.timing import DragBudget, Profile, sample_motion, speed_profile

CAPSULE_STEP_M = 0.45  # spacing of a capsule's discs: the union's edge sags < 3 cm for a 0.95 m ring
APEX_WALL_M = 50.0  # (m) the radius of the disc that walls off a route's apex (the search on its other side)


@dataclass(frozen=True, slots=True)
class Candidate:
    """A timed route: ``profile`` from the replan state to the goal (or a stop), its ``duration_s``, the extra
    inflation it was found with (m), and whether it ends at the goal."""

    profile: Profile
    duration_s: float
    extra_m: float
    reaches_goal: bool
    walled: bool = False


def timed_routes(p0: np.ndarray, v0: np.ndarray, goal: np.ndarray, c: np.ndarray, ring: np.ndarray, hard: np.ndarray,
                 a_max: float, p: PlannerParams, options: Sequence[tuple[bool, float]] | None = None,
                 vias: Sequence[np.ndarray] = (), caps: Sequence[float] = (), drag: DragBudget | None = None
                 ) -> list[Candidate]:
    """Timed routes from (p0, v0) to the goal around discs (centres ``c``, radii ``ring``, start/goal shrink
    limits ``hard``) at the acceleration bound ``a_max``, fastest first (see module docstring).

    Routes around the discs inflated by k·``route_extra_m`` go through ever wider gaps; then the apex of
    the fastest one (its point farthest from the straight line to the goal) is walled off by a large disc
    beyond it and the search repeated, which finds the best route on the other side of that apex.
    ``options`` (walled, extra) restricts the search to those (a refresh); default: all of them. With ``vias``
    (pass-through waypoints) the route runs through them as one path, each leg under its speed limit in ``caps``
    (:func:`companion.planning.legs_route.timed_through`, plain inflations only). ``drag``: the payload's drag
    budget of the timing (:class:`~companion.planning.timing.DragBudget`), None: none.
    """
    if vias:
        plain_opts = [e for b, e in (list(options) if options is not None else search_options(p)) if not b]
        return [Candidate(pr, pr.duration_s, e, True)
                for pr, e in timed_through(p0, v0, vias, caps, goal, c, ring, hard, a_max, p, plain_opts or [0.0],
                                           drag)]
    speed = math.hypot(float(v0[0]), float(v0[1]))
    heading = v0 / speed if speed > 0.05 else None
    out: list[Candidate] = []
    lengths: list[float] = []

    def search(cc: np.ndarray, rr: np.ndarray, hh: np.ndarray, extras: Sequence[float]) -> bool:
        found = False
        for e in extras:
            rt = find_route(p0, goal, cc, rr + e, hh)
            if rt is None:
                continue
            found = True
            if any(abs(rt.length_m - L) < 1e-3 for L in lengths):
                continue
            lengths.append(rt.length_m)
            path = smooth_path(rt.points, cc, rr, ds_m=p.route_ds_m, heading=heading)
            prof = speed_profile(path, speed, a_max_mps2=a_max, v_max_mps=p.shaped_v_max_mps, heading=heading,
                                 a_brake_mps2=p.shaped_brake_mps2, drag=drag)
            out.append(Candidate(prof, prof.duration_s, e, True))
            paths.append(path)
        return found

    paths: list[np.ndarray] = []
    opts = list(options) if options is not None else search_options(p)
    plain = [e for b, e in opts if not b]
    walled = [e for b, e in opts if b]
    if not search(c, ring, hard, plain or [0.0]) or not walled:
        out.sort(key=lambda cd: cd.duration_s)
        return out
    # the other side of the fastest route's apex
    centre = _apex_wall(paths[int(np.argmin([cd.duration_s for cd in out]))], p0, goal)
    if centre is not None:
        n0 = len(out)
        search(np.vstack([c, centre[None, :]]), np.r_[ring, APEX_WALL_M], np.r_[hard, APEX_WALL_M - 0.3], walled)
        out[n0:] = [replace(cd, walled=True) for cd in out[n0:]]
    out.sort(key=lambda cd: cd.duration_s)
    return out


def _apex_wall(path: np.ndarray, p0: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
    """The centre (m) of a disc of radius :data:`APEX_WALL_M` walling off the apex of ``path`` (its point farthest
    from the straight line ``p0`` → ``goal``, if more than 0.5 m off it; the disc's edge 0.05 m beyond), or None."""
    line = goal - p0
    dist = float(np.hypot(line[0], line[1]))
    if dist <= 1e-6:
        return None
    nrm = np.array((-line[1], line[0])) / dist
    dev = (path - p0[None, :]) @ nrm
    i = int(np.argmax(np.abs(dev)))
    if abs(dev[i]) <= 0.5:
        return None
    return path[i] + math.copysign(1.0, float(dev[i])) * nrm * (APEX_WALL_M - 0.05)


def search_options(p: PlannerParams) -> list[tuple[bool, float]]:
    """Every (walled, extra) search option: the k·extra inflations, then the other side of the apex with the
    first half of them."""
    extras = [k * p.route_extra_m for k in range(p.route_candidates)]
    return [(False, e) for e in extras] + [(True, e) for e in extras[: max(1, (len(extras) + 1) // 2)]]


def capsules(c: np.ndarray, r: np.ndarray, hard: np.ndarray, conflicts: list[tuple[int, float]], pred: Predicted,
             t_now: float, env_m: float, margin_m: float, airframe_r_m: float, growth_mps: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The discs (c, r, hard) plus, for each (moving obstacle j, conflict time), discs along j's predicted track
    ±(ring/speed + 0.3 s) around that time: radius r_o + Δd + ``env_m`` + ``margin_m`` + growth·look-ahead."""
    env, margin = env_m, margin_m
    add_c, add_r, add_h = [c], [r], [hard]
    for j, t_c in conflicts:
        vx, vy = float(pred.vx[j]), float(pred.vy[j])
        speed = math.hypot(vx, vy)
        dt_c = max(t_c - t_now, 0.0)
        ring = float(pred.ring_payload[j]) - margin + env + margin + growth_mps * dt_c
        half = min(3.0, ring / max(speed, 1e-3) + 0.3)
        t0, t1 = max(dt_c - half, 0.0), dt_c + half
        n = max(2, math.ceil(speed * (t1 - t0) / CAPSULE_STEP_M) + 1)
        ts = np.linspace(t0, t1, n)
        pts = np.stack([pred.cx[j] + vx * ts, pred.cy[j] + vy * ts], axis=1)
        add_c.append(pts)
        add_r.append(np.full(n, ring))
        add_h.append(np.full(n, float(pred.ring_payload[j]) - margin + airframe_r_m))
    return np.concatenate(add_c), np.concatenate(add_r), np.concatenate(add_h)


def warm_up() -> None:
    """Run every compiled kernel of the shaped planner once on a tiny problem (loads them from numba's cache, or
    compiles them), so that the first replan of a flight is not the one that pays for it."""
    c = np.array([[2.0, 0.1], [4.0, -0.3]])
    r = np.array([0.6, 0.5])
    rt = find_route(np.zeros(2), np.array([6.0, 0.0]), c, r, r)
    assert rt is not None
    path = smooth_path(rt.points, c, r, ds_m=0.4, heading=np.array([1.0, 0.0]))
    prof = speed_profile(path, 0.5, a_max_mps2=1.0, v_max_mps=2.0, heading=np.array([1.0, 0.0]))
    pos, vel, acc = sample_motion(prof, np.arange(0.0, prof.duration_s, 0.05))
    tl = Timeline(0.0, np.zeros(2), 0.01, (3, 4, 5), 3.0, 9.81)
    tl.splice(2, np.concatenate([pos, vel, acc], axis=1), 0)
    z = np.zeros(1)
    clearance(tl.ref, 0.0, 0.01, 0.0, 1.0, Predicted(z, z, z, z, z + 0.5, z + 0.3, z, np.zeros(1, np.bool_)))
