"""ROS 2 ``sensor_msgs/msg/LaserScan`` from its CDR bytes, and as a :class:`~companion.perception.scan.Scan` (pure).

The bytes are what rmw_zenoh puts in a Zenoh sample's payload: the 4-byte encapsulation header (``00 01 00 00``
little-endian CDR, ``00 00 00 00`` big-endian), then the message in plain CDR (XCDR1), every primitive aligned to
its size counted from the end of the header::

    header.stamp.sec int32, header.stamp.nanosec uint32, header.frame_id string (uint32 length with the NUL, bytes,
    NUL), angle_min, angle_max, angle_increment, time_increment, scan_time, range_min, range_max (float32, rad, s,
    m), ranges float32[] and intensities float32[] (uint32 count, then the values)

Conversion (:func:`scan_of`): the scan's frame is taken to be the airframe's (a LiDAR mounted level at the
vehicle's centre; the ``frame_id`` and any tf are not read). ROS frames are FLU (x forward, y left, z up) with
angles counter-clockwise seen from above; the companion's body frame is FRD with angles clockwise, so a ray at
ROS angle θ is at FRD angle −θ. Ranges follow REP 117: NaN = no valid measurement (unknown), +inf = no return
within range (free), −inf = an object too close to measure (unknown here); finite values above ``range_max`` are
no return, below ``range_min`` unknown. A negative finite range, a non-finite or zero increment, more rays than
:data:`~companion.perception.scan.MAX_RAYS` or a truncated message is refused (``ValueError`` naming the field).
The stamp (s) becomes the scan's time; whether it is on the vehicle's clock is the caller's question.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from companion.perception.scan import MAX_RAYS, Scan

TYPE_NAME = "sensor_msgs::msg::dds_::LaserScan_"  # the DDS type name rmw_zenoh puts in its key expressions
MAX_FRAME_ID = 256


@dataclass(frozen=True, slots=True)
class LaserScan:
    """The message's fields: ``stamp_s`` (s), ``frame_id``, angles (rad), times (s), ranges (m, float32 values as
    floats), intensities (device units)."""

    stamp_s: float
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: np.ndarray
    intensities: np.ndarray


class _Reader:
    """Aligned CDR reads from ``buf`` after the 4-byte encapsulation header."""

    def __init__(self, buf: bytes) -> None:
        if len(buf) < 4 or buf[0] != 0 or buf[1] not in (0, 1):
            raise ValueError("encapsulation: not plain CDR (expected 00 00 or 00 01)")
        self.buf = buf
        self.end = "<" if buf[1] == 1 else ">"
        self.pos = 4

    def take(self, fmt: str, size: int, count: int = 1) -> tuple:
        self.pos += (-(self.pos - 4)) % size
        n = size * count
        if self.pos + n > len(self.buf):
            raise ValueError(f"message: truncated at byte {self.pos}")
        out = struct.unpack_from(f"{self.end}{count}{fmt}", self.buf, self.pos)
        self.pos += n
        return out

    def string(self) -> str:
        (n,) = self.take("I", 4)
        if n == 0 or n > MAX_FRAME_ID or self.pos + n > len(self.buf):
            raise ValueError(f"header.frame_id: bad length {n}")
        raw = self.buf[self.pos:self.pos + n - 1]
        self.pos += n
        return raw.decode("utf-8", errors="replace")

    def floats(self, what: str) -> np.ndarray:
        (n,) = self.take("I", 4)
        if n > MAX_RAYS:
            raise ValueError(f"{what}: {n} values, more than {MAX_RAYS}")
        self.pos += (-(self.pos - 4)) % 4
        if self.pos + 4 * n > len(self.buf):
            raise ValueError(f"{what}: truncated")
        out = np.frombuffer(self.buf, dtype=np.dtype(f"{self.end}f4"), count=n, offset=self.pos).astype(float)
        self.pos += 4 * n
        return out


def decode_cdr(buf: bytes) -> LaserScan:
    """A LaserScan from its CDR bytes (encapsulation header included); ``ValueError`` naming what is wrong."""
    r = _Reader(bytes(buf))
    sec, nsec = r.take("i", 4)[0], r.take("I", 4)[0]
    frame_id = r.string()
    a_min, a_max, a_inc, t_inc, t_scan, r_min, r_max = r.take("f", 4, 7)
    ranges = r.floats("ranges")
    intens = r.floats("intensities")
    return LaserScan(sec + nsec * 1e-9, frame_id, a_min, a_max, a_inc, t_inc, t_scan, r_min, r_max, ranges, intens)


def scan_of(msg: LaserScan, source: str = "ros2") -> Scan:
    """The message as a :class:`Scan` in body FRD (see the module's docstring for the conventions)."""
    for name in ("angle_min", "angle_increment", "range_min", "range_max"):
        if not math.isfinite(getattr(msg, name)):
            raise ValueError(f"{name}: not finite")
    if msg.angle_increment == 0.0:
        raise ValueError("angle_increment: zero")
    if not 0.0 <= msg.range_min < msg.range_max:
        raise ValueError(f"range_min/range_max: {msg.range_min}..{msg.range_max} m is not a range")
    r = msg.ranges.copy()
    with np.errstate(invalid="ignore"):
        if (np.isfinite(r) & (r < 0.0)).any():
            raise ValueError("ranges: a negative range")
        r[r > msg.range_max] = math.inf  # +inf included
        r[r < msg.range_min] = math.nan  # -inf included
    angles_flu = msg.angle_min + msg.angle_increment * np.arange(len(r))
    angles_frd = (-angles_flu) % (2.0 * math.pi)
    return Scan(msg.stamp_s, angles_frd, r, float(msg.range_min), float(msg.range_max), abs(msg.angle_increment),
                "body_frd", source, None)
