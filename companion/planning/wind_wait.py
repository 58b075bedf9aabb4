"""How long the shaped planner waited for the wind, and a goal the wind puts within the payload's reach of a trunk.

The shaped planner waits (holds where it braked, :mod:`companion.planning.shaped`) when no plan the payload's swing
fits clears the trunks while a route at the bare safety ring exists: a gust widened the payload's drift and closed
the gaps, or a moving trunk is in the way. It flies on when the gust passes. But where the goal itself lies inside a
trunk's route disc moved upwind by the payload's drift (:func:`~companion.planning.shaped_obstacles.route_shift_m`),
the wind holds the payload within reach of that trunk wherever the vehicle would hold at the goal: every lull lets it
creep closer, every gust stops it again, and the flight ends in a timeout with nobody told why (forest 73, 0.1 kg on
3 m in moderate turbulence, docs/measurements.md, twenty-fourth sitting). After ``goal_wind_wait_s`` of waiting in
all with the goal so placed, the planner says there is no route, as the lift-off does after 30 s of a gust that would
swing the payload into a trunk (:mod:`companion.flight.liftoff`).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from companion.planning.shaped_obstacles import Rings

log = logging.getLogger(__name__)

MAX_STEP_S = 0.2  # (s) at most this much of a gap between two replans counts as waiting (a paused planner)


def trunk_reaching(rings: Rings, goal_m: np.ndarray) -> int | None:
    """The index (into ``rings.c``) of the trunk whose route disc at the bare ring, moved upwind by the payload's
    drift, holds ``goal_m`` (m, NED x y), the nearest if several; None if none does."""
    if not len(rings.route_c):
        return None
    d = np.hypot(rings.route_c[:, 0] - goal_m[0], rings.route_c[:, 1] - goal_m[1]) - rings.route_bare
    j = int(np.argmin(d))
    return j if d[j] < 0.0 else None


class WindWait:
    """The waits of one flight (s): ``waited_s`` in all, ``goal_in_reach_s`` of it with the goal within the wind's
    reach of a trunk (:func:`trunk_reaching`), and whether that has lasted ``limit_s``."""

    def __init__(self, limit_s: float) -> None:
        self.limit_s = limit_s
        self.waited_s = 0.0
        self.goal_in_reach_s = 0.0
        self.trunk_m: tuple[float, float] | None = None  # the trunk the goal lay within reach of, last time it did
        self.shift_m = 0.0  # how far (m) the wind was expected to hold the payload off its path then
        self.verdict = False  # the goal held within reach for limit_s: no route
        self._last_t: float | None = None
        self._waiting = False
        self._in_reach = False

    def waiting(self, rings: Rings, goal_m: np.ndarray) -> None:
        """This replan waits; ``rings`` its obstacles, ``goal_m`` (m, NED x y) the point it heads for."""
        self._waiting = True
        j = trunk_reaching(rings, goal_m)
        self._in_reach = j is not None
        if j is not None:
            self.trunk_m = (float(rings.c[j, 0]), float(rings.c[j, 1]))
            self.shift_m = math.hypot(*rings.pred.payload_shift)

    def replanned(self, t_s: float) -> bool:
        """Count the time since the last replan (s) as this one decided; True once the goal has lain within the
        wind's reach of a trunk for ``limit_s`` of waiting in all (once: the planner then has no route)."""
        dt = 0.0 if self._last_t is None else min(max(t_s - self._last_t, 0.0), MAX_STEP_S)
        self._last_t = t_s
        if self._waiting:
            self.waited_s += dt
            self.goal_in_reach_s += dt if self._in_reach else 0.0
        self._waiting = self._in_reach = False
        if self.verdict or self.goal_in_reach_s < self.limit_s - 1e-9:
            return False
        self.verdict = True
        assert self.trunk_m is not None
        log.warning("the goal lies within the payload's reach of the trunk at (%.1f, %.1f) in this wind (held %.2f m "
                    "downwind): %.0f s of waiting for it to ease, no route", *self.trunk_m, self.shift_m,
                    self.goal_in_reach_s)
        return True

    def facts(self) -> dict[str, Any]:
        """The report's part: the waits (s) and, where the goal lay within the wind's reach, the trunk (m)."""
        out: dict[str, Any] = {"waited_s": round(self.waited_s, 2),
                               "goal_in_wind_reach_s": round(self.goal_in_reach_s, 2),
                               "no_route_goal_in_wind_reach": self.verdict}
        if self.trunk_m is not None:
            out |= {"trunk_x_m": round(self.trunk_m[0], 2), "trunk_y_m": round(self.trunk_m[1], 2),
                    "downwind_m": round(self.shift_m, 2)}
        return out
