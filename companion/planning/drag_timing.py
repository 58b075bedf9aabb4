"""What drag a plan is timed for (issue 28): the payload's drag angle declared or identified, a provisional one
while only its drift shows a wind, or none; and when a plan timed for one must be re-timed for the newest.

The timing itself (:mod:`companion.planning.timing`) budgets the drag it is given (:class:`~.timing.DragBudget`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from companion.planning.timing import DRAG_GUST_MPS

DRAG_RETIME_FRAC = 0.2  # a plan timed with a drag angle this much off the newest estimate is re-timed

#: a payload the wind holds out by more than this drag angle (its drift over the cable, rad) shows a wind; while its
#: drag is not yet known (identified after a speed-up, :mod:`companion.control.drag_id`), the timing budgets a
#: provisional one (:func:`provisional_drag`)
UNKNOWN_DRAG_RAD = 0.03
#: (m/s) the airspeed a payload of unknown drag is taken to hang at in the wind that holds it out...
PROVISIONAL_AIRSPEED_MPS = 3.0
#: (rad per (m/s)²) ...unless that makes its drag angle per (m/s)² more than this (2.4x the bundled world's 0.1 kg
#: payload, 0.0034): then the airspeed that gives this one. Of 0.0035, 0.005 and 0.008 the most careful: forest 84's
#: gusts hit no payload (measured: docs/measurements.md, 2026-12-05, twentieth sitting)
PROVISIONAL_C_MAX = 0.008
MAX_DRIFT_SIN = 0.99  # a drift of the whole cable (sin 1) is read as this: tan θ stays finite (7.0)


def provisional_drag(drift_ned_m: tuple[float, float], cable_l_m: float,
                     vel_mps: tuple[float, float]) -> tuple[float, tuple[float, float]]:
    """(c, wind) for the timing to budget while the payload's drag is not yet known: the drag angle θ of its
    drift ``drift_ned_m`` (m, NED x y, downwind) on ``cable_l_m`` (m), taken at an airspeed A along the drift,
    A = max(PROVISIONAL_AIRSPEED_MPS, √(tan θ / PROVISIONAL_C_MAX)): c = tan θ / A² (rad per (m/s)²) and the wind
    (m/s, NED x y) blows A past the vehicle's velocity ``vel_mps``. The trailing then grows by 2·tan θ / A per m/s
    of speed into the wind: the smaller the airspeed assumed, the faster (c is the payload's, A the weather's)."""
    d = math.hypot(*drift_ned_m)
    tan_th = math.tan(math.asin(min(d / cable_l_m, MAX_DRIFT_SIN)))
    a = max(PROVISIONAL_AIRSPEED_MPS, math.sqrt(tan_th / PROVISIONAL_C_MAX))
    return tan_th / (a * a), (float(vel_mps[0]) + a * drift_ned_m[0] / d, float(vel_mps[1]) + a * drift_ned_m[1] / d)


def budgeted_drag(drag_c: float, wind_mps: tuple[float, float], drift_ned_m: tuple[float, float], cable_l_m: float,
                  vel_mps: tuple[float, float]) -> tuple[float, tuple[float, float]]:
    """(c, wind) the timing budgets: the payload's drag angle per (m/s)² ``drag_c`` (rad, declared or identified; 0:
    not known) with the wind ``wind_mps`` (m/s) measured with it; while it is not known and the drift shows a wind
    (UNKNOWN_DRAG_RAD), :func:`provisional_drag`; else none (0, (0, 0))."""
    if drag_c > 0.0:
        return drag_c, (float(wind_mps[0]), float(wind_mps[1]))
    if math.hypot(*drift_ned_m) > UNKNOWN_DRAG_RAD * cable_l_m:
        return provisional_drag(drift_ned_m, cable_l_m, vel_mps)
    return 0.0, (0.0, 0.0)


def drag_changed(c_now: float, c_plan: float) -> bool:
    """Whether a plan timed with drag angle ``c_plan`` must be re-timed for the newest ``c_now`` (rad per (m/s)²).
    Only a new drag estimate re-times a plan: re-timing for each change of the measured wind (or for the drag
    measured now) slowed the moderate-turbulence flights by 20-30 % and cost collisions (issue 28)."""
    return abs(c_now - c_plan) > DRAG_RETIME_FRAC * max(c_now, c_plan)


#: (m/s) a plan timed in a wind this far from the newest estimate is re-timed: beyond what the gust margin covers
WIND_RETIME_MPS = DRAG_GUST_MPS


def wind_changed(w_now: tuple[float, float], w_plan: tuple[float, float]) -> bool:
    """Whether a plan timed in wind ``w_plan`` must be re-timed for the newest estimate ``w_now`` (m/s, NED x y)."""
    return math.hypot(w_now[0] - w_plan[0], w_now[1] - w_plan[1]) > WIND_RETIME_MPS


class TimedFor(NamedTuple):
    """What a plan is timed for: the payload's drag angle ``drag_c`` (rad per (m/s)², 0: none) and the wind
    ``wind_mps`` (m/s, NED x y) with it, as :func:`budgeted_drag` gives them."""

    drag_c: float = 0.0
    wind_mps: tuple[float, float] = (0.0, 0.0)

    def outdated(self, now: TimedFor) -> bool:
        """Whether a plan timed for this must be re-timed for ``now``: another drag (:func:`drag_changed`; a drift
        that shows a wind only after the plan was made is one), or a drag and the wind moved (:func:`wind_changed`)."""
        return (drag_changed(now.drag_c, self.drag_c)
                or (now.drag_c > 0.0 and wind_changed(now.wind_mps, self.wind_mps)))
