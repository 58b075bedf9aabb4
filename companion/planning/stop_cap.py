"""The speed the flight may keep inside the space its range sensor has seen free (pure: floats only).

"Never faster than it can stop, swing envelope included, inside the space it has seen free": on each mapped scan
the pilot measures how far the scan saw free from the sensor along the direction of travel
(:meth:`companion.perception.local_map.LocalMap.free_distance_m`: the range limit, a trunk's surface, or the
shadow behind one) and hands the flight core a :class:`SeenFree`. Each tick the core turns it into the planners'
speed cap (``PlanInput.v_cap_mps``) with :func:`stop_cap_mps`, a handful of float operations:

    d = d_free − |p − p_scan| − margin − v · latency,    v_cap = sqrt(2 · a_stop · max(0, d))

with ``margin`` = the envelope radius (swing included) + the airframe's radius + the trunks' safe distance,
``a_stop`` the planner's swing-bounded deceleration, and ``latency`` what passes before the next scan and plan
take effect. The distance flown since the scan is subtracted whatever its direction (a conservative bound).
Without perception there is no :class:`SeenFree` and the cap is ``inf``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
