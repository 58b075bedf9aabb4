"""Clearance and collisions of a flight against its obstacles: the one scoring used by the flight report (``fly``,
``slungpilot report RUN_DIR``), by ``evaluate`` (:mod:`lab.evaljob`) and by ``experiments`` (which read the report).

Clearance (m) of the airframe against a vertical cylinder = horizontal distance − r_obs − ``airframe_r_m``
(r_uav + L_uav); of the payload point = horizontal distance − r_obs; each counted only on the rows where that point
is below the obstacle's top (NED z > −height_m). Per obstacle the minimum over the rows (+inf if never below); a
collision is an obstacle whose clearance is < 0.

Where a moving obstacle is at each logged time ``t_s`` (vehicle time, s):

* a mission obstacle (``source == "mission"``) with a velocity is at its file position at the mission clock's zero
  ``clock_t0_s`` — the first setpoint of the mission (``FlightCore.t0_s``, kept in
  ``FlightLog.obstacle_clock_t0_s``) — and moves at constant velocity from there (:meth:`Obstacle.at_time`); before
  the zero it stands at its file position, as the flight core sees it;
* a world trunk (``source == "world"``: the truth of a flight in a simulated world, ``fly --sitl --world``) is at
  its file position at the vehicle's boot, vehicle time 0, and moves at constant velocity from there
  (:mod:`companion.core.world`), whatever ``clock_t0_s``;
* a live obstacle (any other source) is logged where it was seen, already advanced by the obstacle store, and is
  scored there, standing;
* without a clock zero (``clock_t0_s`` None: run folders written before the log carried it) every obstacle is
  scored at its logged position, moving ones included — the report's behaviour before the clock zero was logged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.core.obstacles import Obstacle
from companion.core.world import WORLD_SOURCE


def is_moving(o: Obstacle) -> bool:
    """Whether ``o`` has a velocity."""
    return o.vx_mps != 0.0 or o.vy_mps != 0.0


def _track(o: Obstacle, t: np.ndarray, clock_t0_s: float | None) -> tuple[float | np.ndarray, float | np.ndarray]:
    """Where ``o`` is at each time of ``t`` (NED x, y in m): scalars for an obstacle that stands (see module
    docstring), arrays (n,) for a mission obstacle moving from the clock zero or a world trunk moving from time 0."""
    if o.source == WORLD_SOURCE and is_moving(o):
        return o.x_m + o.vx_mps * t, o.y_m + o.vy_mps * t
    if clock_t0_s is None or o.source != "mission" or not is_moving(o):
        return o.x_m, o.y_m
    dt = np.maximum(t - float(clock_t0_s), 0.0)
    return o.x_m + o.vx_mps * dt, o.y_m + o.vy_mps * dt


def _at(v: float | np.ndarray, rows: np.ndarray) -> float | np.ndarray:
    return v[rows] if isinstance(v, np.ndarray) else v


def obstacle_clearances(t_s, pos_ned_m, payload_ned_m, obstacles: Sequence[Obstacle], airframe_r_m: float,
                        clock_t0_s: float | None = None) -> np.ndarray:
    """Per obstacle, the minimum clearance (m) over the rows: ``t_s`` (n,) vehicle time (s), ``pos_ned_m`` (n, 3)
    airframe and ``payload_ned_m`` (n, 3) payload positions (NED, m; NaN rows where the payload is unknown),
    ``airframe_r_m`` the airframe circle's radius (m), ``clock_t0_s`` the mission clock's zero (s; see module
    docstring). +inf for an obstacle the vehicle and payload were never below the top of."""
    t = np.asarray(t_s, dtype=np.float64)
    pos = np.asarray(pos_ned_m, dtype=np.float64)
    pay = np.asarray(payload_ned_m, dtype=np.float64)
    out = np.full(len(obstacles), math.inf)
    for i, o in enumerate(obstacles):
        ox, oy = _track(o, t, clock_t0_s)
        below = pos[:, 2] > -o.height_m
        if np.any(below):
            d = np.hypot(pos[below, 0] - _at(ox, below), pos[below, 1] - _at(oy, below)) - o.radius_m - airframe_r_m
            out[i] = min(out[i], float(np.min(d)))
        pb = np.isfinite(pay[:, 2]) & (pay[:, 2] > -o.height_m)
        if np.any(pb):
            d = np.hypot(pay[pb, 0] - _at(ox, pb), pay[pb, 1] - _at(oy, pb)) - o.radius_m
            out[i] = min(out[i], float(np.min(d)))
    return out


@dataclass(frozen=True)
class Score:
    """What the report says about obstacles: the smallest clearance (m; None if the flight was never below any
    obstacle's top), the obstacles touched (clearance < 0), and how many of those have a velocity."""

    min_clearance_m: float | None
    collisions: int
    collisions_moving: int


def score(clearances: np.ndarray, obstacles: Sequence[Obstacle]) -> Score:
    """The :class:`Score` of per-obstacle ``clearances`` (m, from :func:`obstacle_clearances`) of ``obstacles``."""
    clear = np.asarray(clearances, dtype=np.float64)
    finite = clear[np.isfinite(clear)]
    hit = clear < 0.0
    return Score(
        min_clearance_m=float(np.min(finite)) if finite.size else None,
        collisions=int(np.sum(hit)),
        collisions_moving=sum(1 for o, h in zip(obstacles, hit, strict=True) if h and is_moving(o)),
    )
