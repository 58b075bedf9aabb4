"""The pilot's range-sensor input: scans and poses into the perception map, and the seen-free distance for the
flight core's speed cap. Fed on arrival (MAVLink) or between ticks (Zenoh, and in real time the deferred mapping),
never inside the tick, which only reads the map's current trunks and the core's cap.

A failure here is counted and logged, never raised into the input path: a bad scan or a bug in perception costs
the map one scan, not the flight.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from companion.flight.core import FlightCore
from companion.flight.mission_frame import MissionFrame
from companion.flight.obstacle_view import ObstacleView
from companion.mavlink_io.telemetry import Attitude, LocalPositionNed, ObstacleDistance, Rejected, TelemetryEvent
from companion.perception.pipeline import Perception
from companion.perception.scan import Scan, ScanPart
from companion.planning.stop_cap import SeenFree, free_along

log = logging.getLogger(__name__)


class Sensing:
    """The perception map of one flight (None until on) and what feeds it. ``mode``: True (always on), False
    (never), None (on at the vehicle's first scan); ``lockstep``: each scan mapped on arrival (the same steps
    every run), else deferred and mapped between ticks, a slice at a time (:meth:`work`)."""

    def __init__(self, mode: bool | None, lockstep: bool, frame: MissionFrame, obstacles: ObstacleView,
                 core: FlightCore, vehicle_sysid: Callable[[], int | None], log_due: Callable[[float], bool]) -> None:
        self.mode = mode
        self.lockstep = lockstep
        self.frame = frame
        self.obstacles = obstacles
        self.core = core
        self.vehicle_sysid = vehicle_sysid
        self.log_due = log_due  # whether a failure at that monotonic time (s) is logged (shared rate limit)
        self.perception: Perception | None = None
        self.errors = 0
        self._seen_pts: object = None  # the scan the core's seen-free cap was last measured on
        if mode:
            self._start()

    def _start(self) -> None:
        self.perception = Perception(self.vehicle_sysid(), defer=not self.lockstep)
        p = self.perception
        self.obstacles.perceived = p.obstacles_at
        p.on_mapped = lambda: self._seen_free(p)  # also when a deferred (real-time) scan is mapped between ticks
        log.info("perception on: trunks mapped from the vehicle's range scans")

    def _failed(self, what: str, exc: BaseException, wall_s: float | None) -> None:
        """Count a failure; log it (None: always, else when the shared once-a-second log is due at ``wall_s``)."""
        self.errors += 1
        if wall_s is None or self.log_due(wall_s):
            log.error("perception failed on %s (%d times): %r", what, self.errors, exc, exc_info=self.errors == 1)

    def on_event(self, ev: TelemetryEvent, wall_s: float) -> None:
        """A telemetry event on arrival at monotonic ``wall_s`` (s): the vehicle's poses (mission frame) and its
        range scans."""
        if self.perception is None and ev.__class__ is not ObstacleDistance:
            return
        try:
            self._feed(ev)
        except Exception as exc:  # a bug in perception must not take the telemetry input down with it
            self._failed("a message", exc, wall_s)

    def _feed(self, ev: TelemetryEvent) -> None:
        p = self.perception
        src, own = ev.src_system, self.vehicle_sysid()
        cls = ev.__class__
        if p is None:
            if self.mode is False or src != own:
                return
            self._start()
            p = self.perception
            assert p is not None
        p.vehicle_sysid = own
        if cls is ObstacleDistance:
            p.on_part(ScanPart(ev.time_usec, ev.distances_cm, ev.min_distance_cm, ev.max_distance_cm,
                               ev.increment_deg, ev.angle_offset_deg, ev.frame, src))
            self._seen_free(p)
        elif src != own:
            return
        elif cls is LocalPositionNed:
            o = self.frame.origin_ned_m
            x, y, z = ev.pos_ned_m
            p.on_position(ev.t_boot_s, (x - float(o[0]), y - float(o[1]), z - float(o[2])))
        elif cls is Attitude:
            p.on_attitude(ev.t_boot_s, ev.euler_rad)
        elif cls is Rejected and ev.message == "OBSTACLE_DISTANCE":
            p.refused["part_nonfinite"] += 1

    def on_scan(self, scan: Scan, vehicle_clock: bool = True) -> None:
        """A whole range scan from another input than MAVLink (Zenoh: the project's stream, ROS 2), handed over
        between ticks; ``vehicle_clock`` False: its stamp may be on another clock (ROS time)."""
        if self.perception is None:
            if self.mode is False:
                return
            self._start()
        p = self.perception
        assert p is not None
        p.vehicle_sysid = self.vehicle_sysid()
        try:
            p.on_scan(scan) if vehicle_clock else p.on_foreign_scan(scan)
            self._seen_free(p)
        except Exception as exc:  # counted, never raised into the input
            self._failed(f"a {scan.source} scan", exc, None)

    def work(self, deadline_s: float, clock: Callable[[], float], wall_s: float) -> None:
        """Real time, between ticks (at monotonic ``wall_s``): map a deferred scan, a slice at a time, until
        ``clock()`` passes ``deadline_s``; a failure drops that scan and is counted."""
        p = self.perception
        if p is None or not p.pending:
            return
        try:
            p.work(deadline_s, clock)
        except Exception as exc:
            p.drop_pending()
            self._failed("a deferred scan", exc, wall_s)

    def _seen_free(self, p: Perception) -> None:
        """On a newly mapped scan: how far it saw free from the sensor along the direction of travel, for the core's
        speed cap (:mod:`companion.planning.stop_cap`); computed here, on arrival, never in the tick."""
        pts = p.map.last
        if pts is None or pts is self._seen_pts:
            return
        self._seen_pts = pts
        origin = (float(pts.origin_m[0]), float(pts.origin_m[1]))
        # the confirmed trunks (published radii): a return on one is the planner's to fly around, not unseen space
        known = np.array([(o.x_m, o.y_m, o.radius_m) for o in p.obstacles], dtype=np.float64).reshape(-1, 3)
        d, heading = max((free_along(pts.bearing_rad, pts.free_m, h, ray_of_return=pts.ray, return_xy_m=pts.xy_m,
                                     known_xy_m=known[:, :2], known_r_m=known[:, 2], range_max_m=pts.range_max_m), h)
                         for h in self.core.travel_headings_rad())
        self.core.cap.seen = SeenFree(origin[0], origin[1], heading, d, pts.t_s)

    def facts(self) -> dict[str, Any] | None:
        """The report's ``perception`` (None when the map never started)."""
        return None if self.perception is None else self.perception.facts() | {"errors": self.errors}
