"""Perception end to end: poses and scans in, the local map's trunks out (pure: numpy only).

:class:`Perception` is what the pilot owns. It is fed on arrival, outside the control tick: the vehicle's poses
(:meth:`~Perception.on_position`, :meth:`~Perception.on_attitude`), ``OBSTACLE_DISTANCE`` parts
(:meth:`~Perception.on_part`) and whole scans from other inputs (:meth:`~Perception.on_scan`: Zenoh, ROS 2). Each
scan that passes the gate goes through the stages — pose at its time, points, clusters, map — and the tick reads
only :attr:`~Perception.obstacles`, a tuple rebuilt when a scan changed the map. Refusals and drops are counted by
stage and reason (:meth:`~Perception.facts`, for the report); the time each stage took, per scan, is kept for
the bench (:attr:`~Perception.stage_s`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

from companion.core.obstacles import Obstacle
from companion.perception.clusters import Clusterer, Detection
from companion.perception.local_map import LocalMap
from companion.perception.points import PointFilter, ScanPoints
from companion.perception.pose_history import Pose, PoseHistory
from companion.perception.scan import ObstacleDistanceAssembler, Scan, ScanGate, ScanPart


class Perception:
    """Scans into the local map of trunks (mission frame). ``vehicle_sysid``: whose scans are taken (None: any,
    until :attr:`vehicle_sysid` is set). ``timer``: a clock for the stage timings (s; None: not timed).
    ``defer``: a scan that passes the gate and has its pose is mapped later, a slice at a time, by :meth:`work`
    (the real-time runner's between-ticks slot, within a budget) instead of on arrival (lockstep: arrival, so
    every run maps the same scans at the same step)."""

    def __init__(self, vehicle_sysid: int | None = None, *, local_map: LocalMap | None = None,
                 clusterer: Clusterer | None = None, points: PointFilter | None = None,
                 gate: ScanGate | None = None, timer: Any = None, defer: bool = False) -> None:
        self.vehicle_sysid = vehicle_sysid
        self.poses = PoseHistory()
        self.assembler = ObstacleDistanceAssembler()
        self.gate = gate or ScanGate()
        self.points = points or PointFilter()
        self.clusterer = clusterer or Clusterer()
        self.map = local_map or LocalMap()
        self.refused: Counter[str] = Counter()  # whole scans or parts refused before the map, by reason
        self.scans_mapped = 0
        self.restamped = 0  # scans placed at the newest pose: their stamp was not on the vehicle's clock
        self.last_points: ScanPoints | None = None
        self.last_detections: list[Detection] = []
        self.timer = timer
        self.stage_s: dict[str, float] = {}
        self.defer = defer
        self.superseded = 0  # deferred scans replaced by a newer one before they were mapped
        self._work: Iterator[None] | None = None
        #: called after each scan is mapped (on arrival, or at the end of deferred work): e.g. the seen-free update
        self.on_mapped: Callable[[], None] | None = None

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        """The confirmed trunks now (``source="perception"``): what the tick reads."""
        return self.map.obstacles

    def obstacles_at(self, t_s: float) -> tuple[Obstacle, ...]:
        """The confirmed trunks at vehicle time ``t_s`` (s): moving ones advanced from their scan's time."""
        return self.map.obstacles_at(t_s)

    # ------------------------------------------------------------------ input
    def on_position(self, t_s: float, pos_m: tuple[float, float, float]) -> None:
        """The vehicle's position at vehicle time ``t_s`` (s), mission-frame NED (m)."""
        self.poses.add_position(t_s, pos_m)

    def on_attitude(self, t_s: float, euler_rad: tuple[float, float, float]) -> None:
        """The vehicle's attitude at vehicle time ``t_s`` (s): roll, pitch, yaw (rad)."""
        self.poses.add_attitude(t_s, euler_rad)

    def on_part(self, part: ScanPart) -> int:
        """One ``OBSTACLE_DISTANCE`` message; returns the number of scans it completed and mapped."""
        if self.vehicle_sysid is not None and part.system_id != self.vehicle_sysid:
            self.refused["wrong_vehicle"] += 1  # before assembly: another system's parts never break ours
            return 0
        t0 = self._now()
        scans = self.assembler.add(part)
        self._took("assembly", t0)
        return sum(self.on_scan(s) for s in scans)

    def on_scan(self, scan: Scan) -> bool:
        """One whole scan; True if it was taken (mapped now, or with ``defer`` by the next :meth:`work` calls)."""
        if not self.gate.check(scan, self.vehicle_sysid if scan.system_id is not None else None):
            return False
        pose = self.poses.at(scan.t_s)
        if isinstance(pose, str):
            self.refused[pose] += 1
            return False
        work = self._process(scan, pose)
        if not self.defer:
            for _ in work:
                pass
            return True
        if self._work is not None:
            self.superseded += 1  # a newer scan came before the last one was done: the newer one wins
        self._work = work
        return True

    @property
    def pending(self) -> bool:
        """A deferred scan is still being processed."""
        return self._work is not None

    def work(self, deadline_s: float, clock: Callable[[], float]) -> bool:
        """Go on with a deferred scan until it is mapped (True) or ``clock()`` passes ``deadline_s`` (False: call
        again). A slice is one stage: points, clusters (every circle fit at once), map."""
        while self._work is not None:
            try:
                next(self._work)
            except StopIteration:
                self._work = None
                return True
            if clock() > deadline_s:
                return False
        return True

    def drop_pending(self) -> None:
        """Give up the deferred scan (its processing failed)."""
        self._work = None

    def _process(self, scan: Scan, pose: Pose) -> Iterator[None]:
        """Generator: points, clusters, map; yields between them (each stage timed on its own)."""
        t0 = self._now()
        pts = self.points.place(scan, pose)
        self._took("points", t0)
        yield
        t1 = self._now()
        dets = self.clusterer.detect(pts)
        self._took("clusters", t1)
        yield
        t2 = self._now()
        self.map.update(dets, pts)
        self._took("map", t2)
        self.last_points, self.last_detections = pts, dets
        self.scans_mapped += 1
        if self.on_mapped is not None:
            self.on_mapped()

    def on_foreign_scan(self, scan: Scan) -> bool:
        """A whole scan whose stamp may be on another clock than the vehicle's (ROS time): placed at its stamp when
        the pose history covers it, else at the newest pose (counted ``restamped``); True if it was mapped."""
        if isinstance(self.poses.at(scan.t_s), str):
            newest = self.poses.newest_s
            if newest is None:
                self.refused["no_pose"] += 1
                return False
            self.restamped += 1
            scan = replace(scan, t_s=newest)
        return self.on_scan(scan)

    def _now(self) -> float:
        return self.timer() if self.timer is not None else 0.0

    def _took(self, stage: str, t0: float) -> float:
        if self.timer is None:
            return 0.0
        t1 = self.timer()
        self.stage_s[stage] = t1 - t0
        return t1

    # ------------------------------------------------------------------ views
    def free_distance_m(self, from_xy: tuple[float, float], heading_rad: float) -> float:
        """How far (m) the last scan saw free from ``from_xy`` (mission frame, m) along ``heading_rad`` (rad from
        north, clockwise); see :meth:`LocalMap.free_distance_m`."""
        return self.map.free_distance_m(from_xy, heading_rad)

    def facts(self) -> dict[str, Any]:
        """For the report: scans mapped, refused (by stage and reason), returns dropped, the map's counts."""
        refused = Counter(self.refused)
        refused.update({f"part_{k}": v for k, v in self.assembler.refused.items()})
        refused.update(self.gate.refused)
        return {
            "scans_mapped": self.scans_mapped, "parts": self.assembler.parts,
            "partial_scans": self.assembler.partial_scans, "refused": dict(sorted(refused.items())),
            "refused_total": sum(refused.values()), "returns_dropped": dict(self.points.dropped),
            "segments_skipped": dict(self.clusterer.skipped),
            "segments_cut": self.clusterer.cuts, "map": dict(self.map.counts),
            "tracks": len(self.map.tracks), "trunks": len(self.map.obstacles),
            "pose_samples_ignored": self.poses.ignored, "restamped": self.restamped, "superseded": self.superseded,
            # the map as it ended (mission frame; at most 64): what an evaluation scores against the truth
            "trunks_final": [{"x_m": round(o.x_m, 4), "y_m": round(o.y_m, 4), "radius_m": round(o.radius_m, 4),
                              "vx_mps": round(o.vx_mps, 3), "vy_mps": round(o.vy_mps, 3)}
                             for o in self.map.obstacles[:64]],
            # the confirmed tracks as estimated (radius as fitted, not inflated; 1σ of centre and radius in m,
            # velocity m/s, hits, last seen s vehicle time) at the last scan's time map_t_s (s): for centre and
            # radius errors against the truth
            "map_t_s": None if self.map.last is None else round(self.map.last.t_s, 3),
            "tracks_final": [_track_fact(tr) for tr in self.map.tracks.values() if tr.confirmed][:64],
        }


def _track_fact(tr: Any) -> dict[str, Any]:
    """One confirmed :class:`~companion.perception.local_map.Track` for the report (m, m/s, s): its centre and 1σ
    from the model the map publishes it by (still or moving), the velocity of its moving model."""
    import math

    pos, cov = tr.pos, tr.pos_cov
    sig = math.sqrt(max(float(cov[0, 0] + cov[1, 1]) / 2.0, 0.0))
    return {"id": tr.id, "x_m": round(float(pos[0]), 4), "y_m": round(float(pos[1]), 4),
            "radius_m": round(tr.radius_m, 4), "sigma_xy_m": round(sig, 4),
            "sigma_r_m": round(math.sqrt(max(tr.radius_var, 0.0)), 4), "vx_mps": round(float(tr.x[2]), 3),
            "vy_mps": round(float(tr.x[3]), 3), "moving": bool(tr.moving), "hits": tr.hits,
            "last_seen_s": round(tr.last_seen_s, 3), "source": "perception"}
