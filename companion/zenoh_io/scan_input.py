"""Range scans from Zenoh: the project's raw scan stream and ROS 2 ``LaserScan`` as rmw_zenoh carries it.

Two subscriptions on the companion's session:

- ``<prefix>/<vehicle_id>/scan``: schema ``slungpilot.scan`` (:func:`companion.zenoh_io.schema.encode_scan`), JSON,
  ``time_usec`` on the vehicle's clock, rays in body FRD;
- ``<domain_id>/<topic>/sensor_msgs::msg::dds_::LaserScan_/*``: a ROS 2 ``sensor_msgs/msg/LaserScan`` published
  through rmw_zenoh, whose data key expression is ``<domain_id>/<fully qualified topic without its leading
  slash>/<DDS type name>/<type hash>`` (the hash, ``RIHS01_<sha256>``, is matched by ``*``) and whose payload is
  the message in CDR with its 4-byte encapsulation header (decoded by :mod:`companion.perception.laserscan`: FLU
  angles turned to FRD; the scan is taken to be the airframe's). The sample's attachment (rmw_zenoh's sequence
  number, source timestamp and publisher gid) is not needed and not read. The stamp is ROS time, usually not the
  vehicle's: such a scan is placed with the newest pose unless the pose history covers its stamp (a simulation
  with ``use_sim_time`` on the vehicle's clock).

Threading: as the obstacle input (:mod:`companion.zenoh_io.telemetry`), no Python runs on Zenoh's threads. Each
subscription has a Zenoh ring channel of :data:`RING` samples (a flood loses its oldest inside Zenoh); :meth:`drain`
runs on the flight's thread between ticks (the runner's obstacle ingest), keeps the newest sample of each
subscription (older ones counted ``superseded``), decodes it and hands it to the pilot (``sink(scan,
vehicle_clock)``), which maps it outside the tick. A sample that cannot be decoded is counted by reason.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from companion.perception.laserscan import TYPE_NAME, decode_cdr, scan_of
from companion.perception.scan import Scan
from companion.zenoh_io import schema as ts

log = logging.getLogger(__name__)

RING = 8  # samples each subscription holds between two drains
MAX_SAMPLE_BYTES = 256 * 1024


def ros_key(domain_id: int, topic: str, type_hash: str = "*") -> str:
    """rmw_zenoh's data key expression of a LaserScan topic: ``"0/scan/sensor_msgs::msg::dds_::LaserScan_/*"``."""
    t = topic.strip("/")
    if not t:
        raise ValueError("topic: empty")
    return f"{int(domain_id)}/{t}/{TYPE_NAME}/{type_hash}"


def scan_from_json(raw: bytes | str) -> Scan:
    """A ``slungpilot.scan`` sample as a :class:`Scan` (vehicle clock, body FRD); ``ValueError`` naming the field."""
    if len(raw) > MAX_SAMPLE_BYTES:
        raise ValueError(f"sample: {len(raw)} bytes is above {MAX_SAMPLE_BYTES}")
    d = ts.decode(raw)
    if d.get("schema") != ts.SCAN:
        raise ValueError(f"schema: expected {ts.SCAN!r}, got {d.get('schema')!r}")
    if d.get("frame") != "body_frd":
        raise ValueError(f"frame: expected 'body_frd', got {d.get('frame')!r}")
    t_us = d.get("time_usec")
    if not isinstance(t_us, int) or isinstance(t_us, bool) or t_us < 0:
        raise ValueError(f"time_usec: expected a non-negative integer, got {t_us!r}")
    nums = {}
    for k in ("angle_min_rad", "angle_increment_rad", "range_min_m", "range_max_m"):
        v = d.get(k)
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"{k}: expected a finite number, got {v!r}")
        nums[k] = float(v)
    try:
        r = ts.scan_ranges(d)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"ranges_m: {exc}") from None
    inc = nums["angle_increment_rad"]
    ang = (nums["angle_min_rad"] + inc * np.arange(len(r))) % (2.0 * math.pi)
    return Scan(t_us * 1e-6, ang, r, nums["range_min_m"], nums["range_max_m"], abs(inc), "body_frd", "zenoh", None)


class ScanInput:
    """The scan subscriptions of one vehicle on an open Zenoh ``session``; :meth:`drain` between ticks.

    ``sink(scan, vehicle_clock)`` takes each decoded scan (the pilot's ``on_scan``); ``ros_topic`` None: no ROS 2
    subscription."""

    def __init__(self, session: zenoh.Session, sink: Callable[[Scan, bool], Any], *, prefix: str = "slungpilot",
                 vehicle_id: str = "1", ros_topic: str | None = "scan", ros_domain_id: int = 0) -> None:
        self.sink = sink
        self.keys = {"slungpilot": ts.scan_key(prefix, vehicle_id)}
        if ros_topic is not None:
            self.keys["ros2"] = ros_key(ros_domain_id, ros_topic)
        self._subs = {name: session.declare_subscriber(key, zenoh.handlers.RingChannel(RING))
                      for name, key in self.keys.items()}
        self.received: Counter[str] = Counter()
        self.refused: Counter[str] = Counter()
        self.superseded = 0
        self.last_error: str | None = None

    def drain(self) -> int:
        """Take what waits: the newest sample of each subscription decoded and handed on; returns how many."""
        handed = 0
        for name, sub in self._subs.items():
            newest = None
            while (sample := sub.try_recv()) is not None:
                if newest is not None:
                    self.superseded += 1
                newest = sample
            if newest is None:
                continue
            self.received[name] += 1
            try:
                raw = newest.payload.to_bytes()
                scan = scan_from_json(raw) if name == "slungpilot" else scan_of(decode_cdr(raw))
            except ValueError as exc:
                self._refuse(name, str(exc))
                continue
            self.sink(scan, name == "slungpilot")
            handed += 1
        return handed

    def _refuse(self, name: str, why: str) -> None:
        self.refused[f"{name}: {why.split(':', 1)[0]}"] += 1
        if self.last_error is None or sum(self.refused.values()) % 100 == 1:
            log.warning("scan from %s refused: %s (%d refused)", self.keys[name], why[:200],
                        sum(self.refused.values()))
        self.last_error = why

    def facts(self) -> dict[str, Any]:
        """For the report: the keys, samples taken, superseded and refused (by input and field)."""
        return {"keys": dict(self.keys), "received": dict(self.received), "superseded": self.superseded,
                "refused": dict(self.refused)}

    def close(self) -> None:
        """Undeclare the subscriptions (the session's owner closes the session)."""
        for sub in self._subs.values():
            try:
                sub.undeclare()
            except Exception:  # already gone with its session
                log.debug("scan subscription already undeclared")
        self._subs = {}
