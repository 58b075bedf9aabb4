"""The speed the flight may keep inside the space its range sensor has seen free (pure: numpy, floats).

"Never faster than it can stop, swing envelope included, inside the space it has seen free": on each mapped scan
the pilot measures how far the scan saw free from the sensor along the direction of travel (:func:`free_along`:
from the sensor itself that is the free distance of the ray nearest to the heading — its return, the range
limit, or where a tilted ray met the ground; a dropout saw nothing free) and hands the flight core a
:class:`SeenFree`. Each tick the core turns it into the planners' speed cap (``PlanInput.v_cap_mps``) with
:func:`stop_cap_mps`, a handful of float operations:

    d = d_free − |p − p_scan| − margin − v · latency,    v_cap = sqrt(2 · a_stop · max(0, d))

with ``margin`` = the envelope radius (swing included) + the airframe's radius + the trunks' safe distance,
``a_stop`` the planner's swing-bounded deceleration, and ``latency`` what passes before the next scan and plan
take effect. The distance flown since the scan is subtracted whatever its direction (a conservative bound).
Without perception there is no :class:`SeenFree` and the cap is ``inf``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LATENCY_S = 0.2  # a scan period (10 Hz) plus the re-plan and the reference's reaction (s)


@dataclass(frozen=True, slots=True)
class SeenFree:
    """What the last mapped scan saw free: from the sensor at (``x_m``, ``y_m``) (mission frame, m) along the
    heading ``heading_rad`` (rad from north, clockwise), ``d_free_m`` (m), at vehicle time ``t_s`` (s)."""

    x_m: float
    y_m: float
    heading_rad: float
    d_free_m: float
    t_s: float


def stop_cap_mps(seen: SeenFree | None, x_m: float, y_m: float, speed_mps: float, margin_m: float,
                 a_stop_mps2: float, latency_s: float = LATENCY_S) -> float:
    """The speed cap (m/s) at (``x_m``, ``y_m``) (m) flying at ``speed_mps`` (m/s): see the module docstring;
    ``inf`` when nothing was seen (no perception)."""
    if seen is None:
        return math.inf
    d = (seen.d_free_m - math.hypot(x_m - seen.x_m, y_m - seen.y_m) - margin_m
         - max(0.0, speed_mps) * latency_s)
    return math.sqrt(2.0 * a_stop_mps2 * max(0.0, d))


def free_along(bearing_rad: np.ndarray, free_m: np.ndarray, heading_rad: float, *,
               ray_of_return: np.ndarray | None = None, return_xy_m: np.ndarray | None = None,
               known_xy_m: np.ndarray | None = None, known_r_m: np.ndarray | None = None,
               range_max_m: float = math.inf) -> float:
    """How far (m) a scan saw free from its sensor along ``heading_rad`` (rad from north): the horizontal free
    distance ``free_m`` (m) of the ray whose bearing (``bearing_rad``, rad from north) is nearest to the heading
    (what :meth:`~companion.perception.local_map.LocalMap.free_distance_m` finds from the sensor's position, without
    its march: ~10 µs instead of ~3 ms).

    A return on a trunk the map already knows (``ray_of_return``/``return_xy_m``: the scan's kept returns, their ray
    index and mission-frame position, m; ``known_xy_m``/``known_r_m``: the map's trunks, centres and radii, m; the
    return within the radius + 0.15 m) is the planner's to fly around, not a wall of unseen space: that ray counts
    as free to ``range_max_m``. What stays is the range limit, dropouts, ground strikes and returns not yet mapped:
    a trunk appearing is what the cap slows the flight for."""
    diff = np.abs((bearing_rad - heading_rad + math.pi) % (2.0 * math.pi) - math.pi)
    k = int(np.argmin(diff))
    d = float(free_m[k])
    if ray_of_return is None or return_xy_m is None or known_xy_m is None or known_r_m is None or not len(known_r_m):
        return d
    j = int(np.searchsorted(ray_of_return, k))
    if j >= len(ray_of_return) or int(ray_of_return[j]) != k:
        return d
    x, y = float(return_xy_m[j, 0]), float(return_xy_m[j, 1])
    on_known = np.hypot(known_xy_m[:, 0] - x, known_xy_m[:, 1] - y) <= known_r_m + 0.15
    return range_max_m if bool(on_known.any()) else d


SEEN_SAFE_M = 0.1  # the trunks' safe distance in the cap's margin (the perception map's, m)


class SeenCap:
    """A flight's cap: the last :class:`SeenFree` (``seen``, None without perception: no cap), the planner's
    swing-bounded deceleration ``a_stop_mps2`` (m/s²), the ``latency_s`` (s) before a lower cap takes effect, and
    the airframe's radius (m) in the margin."""

    def __init__(self, a_stop_mps2: float, latency_s: float, airframe_r_m: float) -> None:
        self.seen: SeenFree | None = None
        self.a_stop_mps2 = a_stop_mps2
        self.latency_s = latency_s
        self.airframe_r_m = airframe_r_m

    def cap_mps(self, pos_ned_m: np.ndarray, vel_ned_mps: np.ndarray, r_max_m: float) -> float:
        """The cap (m/s) at this position and velocity with the envelope radius ``r_max_m`` (m)."""
        if self.seen is None:
            return math.inf
        return stop_cap_mps(self.seen, float(pos_ned_m[0]), float(pos_ned_m[1]),
                            math.hypot(float(vel_ned_mps[0]), float(vel_ned_mps[1])),
                            r_max_m + self.airframe_r_m + SEEN_SAFE_M, self.a_stop_mps2, self.latency_s)


def travel_headings_rad(ref_p: np.ndarray, ref_v: np.ndarray | None, goal_xy: np.ndarray) -> tuple[float, ...]:
    """The direction of travel (rad from north) to measure the seen-free distance along: the reference's velocity
    ``ref_v``; while slower than 0.3 m/s (no direction yet, or stopped by the cap) the directions from ``ref_p``
    towards ``goal_xy`` and 30° and 60° either side, of which the pilot takes the freest."""
    if ref_v is not None and math.hypot(ref_v[0], ref_v[1]) > 0.3:
        return (math.atan2(ref_v[1], ref_v[0]),)
    h = math.atan2(float(goal_xy[1]) - float(ref_p[1]), float(goal_xy[0]) - float(ref_p[0]))
    return tuple(h + math.radians(d) for d in (0.0, -30.0, 30.0, -60.0, 60.0))
