"""The bundled vehicle's LiDAR on its links: a scan at the sensor's rate on the vehicle's clock, sent as MAVLink
``OBSTACLE_DISTANCE`` and, when asked, published raw on Zenoh (``slungpilot.scan``). docs/sitl.md, *LiDAR*.

``OBSTACLE_DISTANCE`` (id 330) as the MAVLink spec defines it: ``frame`` MAV_FRAME_BODY_FRD, ``increment_f`` the
element width (deg; ``increment`` its rounded value), ``angle_offset`` (deg, clockwise from forward) of element 0,
``min_distance``/``max_distance`` and ``distances`` in cm; a measured ray with nothing within range is
``max_distance + 1``, a ray not measured (dropout, or closer than the minimum range) ``UINT16_MAX``, and unused
elements are ``UINT16_MAX`` too. Two layouts (``--lidar-mavlink``):

* ``split`` (default): every ray at the sensor's own resolution, 72 per message: a 360-ray 1° scan is 5 messages
  with ``angle_offset`` 0, 72, 144, 216, 288 and the same ``time_usec``. For the companion, which groups them by
  ``time_usec``. PX4 (CollisionPrevention::_addObstacleSensorData) and ArduPilot (AP_Proximity_MAV) read each
  message as a whole 360° scan, so they would misread this layout;
* ``sectors``: one message, 72 sectors of 5° (the nearest return of the rays within ±2.5° of each sector's
  centre), the layout PX4 streams (its fused obstacle map) and both autopilots read.

Sent from the vehicle's system id with component :data:`LIDAR_COMPID` (MAV_COMP_ID_OBSTACLE_AVOIDANCE, 196;
``--lidar-compid``), with its own sequence numbers, so the autopilot's stream is numbered as without a LiDAR.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink_io.codec import send_payload
from companion.zenoh_io import schema
from sim_bridge.lidar import Lidar
from sim_bridge.world import World, WorldArrays

log = logging.getLogger(__name__)

LIDAR_COMPID = mavlink2.MAV_COMP_ID_OBSTACLE_AVOIDANCE  # 196
UINT16_MAX = 65535
PER_MESSAGE = 72  # OBSTACLE_DISTANCE's distances[72]
SECTOR_DEG = 5.0  # the ``sectors`` layout: 72 × 5° = 360°
LAYOUTS = ("split", "sectors")
_ID = mavlink2.MAVLINK_MSG_ID_OBSTACLE_DISTANCE  # 330
_CRC_EXTRA = mavlink2.MAVLink_obstacle_distance_message.crc_extra
#: the wire order (pymavlink's native format): time_usec, distances[72], min, max, sensor_type, increment,
#: increment_f, angle_offset, frame
_PAYLOAD = struct.Struct("<Q72HHHBBffB")


def to_cm(ranges_m: np.ndarray, range_min_m: float, range_max_m: float) -> tuple[list[int], int, int]:
    """Ranges (m; +inf no return, NaN not measured) as OBSTACLE_DISTANCE cm: (distances, min_distance,
    max_distance), a return clipped into [min_distance, max_distance]."""
    lo, hi = round(range_min_m * 100.0), round(range_max_m * 100.0)
    r = np.asarray(ranges_m, dtype=np.float64)
    cm = np.full(r.shape, UINT16_MAX, dtype=np.int64)
    ret = np.isfinite(r)
    cm[ret] = np.clip(np.rint(r[ret] * 100.0), lo, hi)
    cm[np.isposinf(r)] = hi + 1
    return cm.tolist(), lo, hi


def split_messages(ranges_m: np.ndarray, step_deg: float, range_min_m: float,
                   range_max_m: float) -> list[tuple[list[int], float, float, int, int]]:
    """The ``split`` layout: per message (distances[72], increment_f deg, angle_offset deg, min cm, max cm)."""
    cm, lo, hi = to_cm(ranges_m, range_min_m, range_max_m)
    out = []
    for k in range(0, len(cm), PER_MESSAGE):
        part = cm[k : k + PER_MESSAGE]
        part += [UINT16_MAX] * (PER_MESSAGE - len(part))
        out.append((part, float(step_deg), float(k * step_deg), lo, hi))
    return out


def sector_message(ranges_m: np.ndarray, step_deg: float, range_min_m: float,
                   range_max_m: float) -> tuple[list[int], float, float, int, int]:
    """The ``sectors`` layout: one message of 72 sectors of 5°; a sector is its nearest return, else
    ``max + 1`` if one of its rays measured nothing within range, else ``UINT16_MAX``."""
    r = np.asarray(ranges_m, dtype=np.float64)
    sector = np.rint(np.arange(r.size) * step_deg / SECTOR_DEG).astype(np.int64) % PER_MESSAGE
    best = np.full(PER_MESSAGE, math.nan)
    free = np.zeros(PER_MESSAGE, dtype=bool)
    ret = np.isfinite(r)
    np.fmin.at(best, sector[ret], r[ret])
    free[sector[np.isposinf(r)]] = True
    merged = np.where(np.isfinite(best), best, np.where(free, math.inf, math.nan))
    cm, lo, hi = to_cm(merged, range_min_m, range_max_m)
    return cm, SECTOR_DEG, 0.0, lo, hi


class ScanSender:
    """Scans the world at the LiDAR's rate on the vehicle clock and sends each scan; the vehicle calls
    :meth:`on_step` after every control period (its telemetry of that instant already queued).

    ``layout``: ``split`` or ``sectors`` (module docstring); ``gcs``: also on the GCS link (default onboard
    only: bandwidth); ``publisher``: a :class:`ZenohScanPublisher` or None."""

    def __init__(self, lidar: Lidar, world: World, *, compid: int = LIDAR_COMPID, layout: str = "split",
                 gcs: bool = False, publisher: Any = None) -> None:
        if layout not in LAYOUTS:
            raise ValueError(f"layout: must be one of {LAYOUTS}, got {layout!r}")
        if not 1 <= compid <= 255:
            raise ValueError(f"compid: must be in 1..255, got {compid}")
        self.lidar = lidar
        self.world = world
        self._trunks = WorldArrays(world)
        self.compid = compid
        self.layout = layout
        self.gcs = gcs
        self.publisher = publisher
        self.next_us = lidar.cfg.period_us  # the first scan one period after boot, then every period
        self.scans = 0
        self.last_ranges: np.ndarray | None = None
        self._mavs: list | None = None

    def _senders(self, vehicle: Any) -> list:
        if self._mavs is None:
            links = [vehicle.onboard] + ([vehicle.gcs] if self.gcs else [])
            self._mavs = [lk.sender(vehicle.sysid, self.compid) for lk in links if lk is not None]
        return self._mavs

    def on_step(self, vehicle: Any) -> None:
        """Scan and send when one is due at the vehicle's time ``vehicle.t_us`` (µs), from its true pose."""
        t_us = vehicle.t_us
        if t_us < self.next_us:
            return
        period = self.lidar.cfg.period_us
        self.next_us = (t_us // period + 1) * period
        sim = vehicle.sim
        ranges = self.lidar.scan(sim.pos_ned_m, sim.euler_rad, *self._trunks.at(t_us * 1e-6))
        self.last_ranges = ranges
        self.scans += 1
        self.send(ranges, t_us, self._senders(vehicle))
        if self.publisher is not None:
            self.publisher.publish(t_us, ranges, self.lidar.cfg)

    def send(self, ranges: np.ndarray, t_us: int, mavs: list) -> None:
        """OBSTACLE_DISTANCE message(s) of one scan, stamped ``t_us`` (the vehicle's boot time, µs)."""
        c = self.lidar.cfg
        if self.layout == "split":
            msgs = split_messages(ranges, c.step_deg, c.range_min_m, c.range_max_m)
        else:
            msgs = [sector_message(ranges, c.step_deg, c.range_min_m, c.range_max_m)]
        payloads = [_PAYLOAD.pack(t_us, *dist, lo, hi, mavlink2.MAV_DISTANCE_SENSOR_LASER, round(inc), inc, off,
                                  mavlink2.MAV_FRAME_BODY_FRD) for dist, inc, off, lo, hi in msgs]
        for mav in mavs:  # packed once, framed per link (its sequence numbers; signed by the link when on)
            for p in payloads:
                send_payload(mav, _ID, _CRC_EXTRA, p)


class ZenohScanPublisher:
    """Publishes each raw scan at ``<prefix>/<vehicle_id>/scan`` (:func:`companion.zenoh_io.schema.encode_scan`)
    on an open ``zenoh.Session``; congestion control DROP, so a slow subscriber never stalls the vehicle."""

    def __init__(self, session: Any, prefix: str, vehicle_id: str) -> None:
        import zenoh

        self.key = schema.scan_key(prefix, vehicle_id)
        self.vehicle_id = vehicle_id
        self.seq = 0
        self.errors = 0
        enc = zenoh.Encoding.APPLICATION_JSON.with_schema(schema.encoding_schema(schema.SCAN))
        self._pub = session.declare_publisher(self.key, encoding=enc,
                                              congestion_control=zenoh.CongestionControl.DROP)

    def publish(self, t_us: int, ranges: np.ndarray, cfg: Any) -> None:
        """Encode and put one scan taken at vehicle time ``t_us`` (µs); a failing put is counted, never raised."""
        payload = schema.encode_scan(self.seq, self.vehicle_id, t_us * 1e-6, time.time(), t_us, 0.0,
                                     math.radians(cfg.step_deg), cfg.range_min_m, cfg.range_max_m, ranges)
        self.seq += 1
        try:
            self._pub.put(payload)
        except Exception as exc:  # a Zenoh problem must not stop the vehicle
            self.errors += 1
            if self.errors == 1:
                log.warning("scan not published on %s: %s", self.key, exc)

    def undeclare(self) -> None:
        """Undeclare the publisher (before its session closes)."""
        self._pub.undeclare()
