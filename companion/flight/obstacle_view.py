"""The obstacles the planner is given each tick, and the record of every obstacle met during a flight.

Culling keeps the tick's cost bounded when a perception node publishes hundreds of far-away trunks (the planner's
cost grows with every obstacle it is given): only those within :data:`RELEVANT_RADIUS_M` of the vehicle are passed
on, recomputed when the set changes or the vehicle has moved 2 m.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from companion.core.obstacles import Obstacle

RELEVANT_RADIUS_M = 20.0  # obstacles farther than this from the vehicle are not given to the planner
MAX_OBSTACLES_SEEN = 4096  # the report's record of obstacles met is bounded too
RECULL_M = 2.0  # the vehicle moved this far since the last cull: cull again


class ObstacleView:
    """Obstacles from ``source(t_s)`` (live input) or the mission's own list, culled around the vehicle."""

    def __init__(self, mission_obstacles: Sequence[Obstacle]) -> None:
        self.mission_obstacles = mission_obstacles
        self.source: Callable[[float], Sequence[Obstacle]] | None = None
        self._last: Sequence[Obstacle] | None = None
        self._seen: dict[tuple, Obstacle] = {}
        self._culled: Sequence[Obstacle] = ()
        self._cull_xy = (float("inf"), float("inf"))

    def use_source(self, source: Callable[[float], Sequence[Obstacle]]) -> None:
        """From now on take obstacles from ``source(t_s)`` (it merges the mission's own with live ones)."""
        self.source = source

    @property
    def seen(self) -> tuple[Obstacle, ...]:
        """Every obstacle the planner has been given during the flight (mission and live ones)."""
        return tuple(self._seen.values())

    def around(self, t_s: float, x_m: float, y_m: float) -> Sequence[Obstacle]:
        """The obstacles for the planner at time ``t_s`` (s) with the vehicle at (``x_m``, ``y_m``) (mission frame)."""
        obstacles = self.source(t_s) if self.source else self.mission_obstacles
        if obstacles is not self._last:
            self._last = obstacles
            if len(self._seen) < MAX_OBSTACLES_SEEN:
                for o in obstacles:
                    self._seen.setdefault((o.x_m, o.y_m, o.radius_m, o.height_m), o)
        elif (x_m - self._cull_xy[0]) ** 2 + (y_m - self._cull_xy[1]) ** 2 < RECULL_M ** 2:
            return self._culled
        self._cull_xy = (x_m, y_m)
        if len(obstacles) <= 16:
            self._culled = obstacles
        else:
            r = RELEVANT_RADIUS_M
            self._culled = tuple(o for o in obstacles
                                 if (o.x_m - x_m) ** 2 + (o.y_m - y_m) ** 2 < (r + o.radius_m) ** 2)
        return self._culled
