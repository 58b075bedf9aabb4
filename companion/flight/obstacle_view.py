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
    """Obstacles from ``source(t_s)`` (live input) or the mission's own list, plus those of ``perceived(t_s)``
    (the vehicle's own sensors' map, when it has one), culled around the vehicle. Each keeps its ``source``."""

    def __init__(self, mission_obstacles: Sequence[Obstacle]) -> None:
        self.mission_obstacles = mission_obstacles
        self.source: Callable[[float], Sequence[Obstacle]] | None = None
        self.perceived: Callable[[float], Sequence[Obstacle]] | None = None
        self._merged_of: tuple[Sequence[Obstacle] | None, Sequence[Obstacle] | None] = (None, None)
        self._merged: tuple[Obstacle, ...] = ()
        self._last: Sequence[Obstacle] | None = None
        self._seen: dict[tuple, Obstacle] = {}
        self._culled: Sequence[Obstacle] = ()
        self._cull_xy = (float("inf"), float("inf"))

    def use_source(self, source: Callable[[float], Sequence[Obstacle]]) -> None:
        """From now on take obstacles from ``source(t_s)`` (it merges the mission's own with live ones)."""
        self.source = source

    @property
    def seen(self) -> tuple[Obstacle, ...]:
        """Every obstacle the planner has been given during the flight (mission and live ones; not the perceived
        ones, whose estimates change with every scan: see the perception facts)."""
        return tuple(self._seen.values())

    @property
    def in_use(self) -> Sequence[Obstacle]:
        """The whole set given last (before culling): mission, live and perceived obstacles."""
        return self._last if self._last is not None else ()

    def around(self, t_s: float, x_m: float, y_m: float) -> Sequence[Obstacle]:
        """The obstacles for the planner at time ``t_s`` (s) with the vehicle at (``x_m``, ``y_m``) (mission frame)."""
        obstacles = self.source(t_s) if self.source else self.mission_obstacles
        if self.perceived is not None:
            obstacles = self._merge(obstacles, self.perceived(t_s))
        if obstacles is not self._last:
            self._last = obstacles
            if len(self._seen) < MAX_OBSTACLES_SEEN:
                for o in obstacles:
                    if o.source != "perception":  # a perceived trunk moves with each scan: not a record of one
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

    def _merge(self, given: Sequence[Obstacle], perceived: Sequence[Obstacle]) -> Sequence[Obstacle]:
        """``given`` followed by ``perceived``; the same tuple while neither changed."""
        if not perceived:
            return given
        if self._merged_of[0] is not given or self._merged_of[1] is not perceived:
            self._merged_of = (given, perceived)
            self._merged = (*given, *perceived)
        return self._merged
