"""One range scan, typed, and how it is put together and checked (pure: numpy only).

A :class:`Scan` is one sweep of a 2-D range sensor in the airframe's x-y plane: vehicle time (s since boot, the
time the telemetry carries), the rays' angles in body FRD (rad, 0 = forward, positive clockwise seen from above,
as MAVLink's ``OBSTACLE_DISTANCE`` counts them), and per ray a range (m) with two markers told apart:
``+inf`` = no return within ``range_max_m`` (the ray saw free space to its limit) and ``NaN`` = unknown (no data,
a dropout, a reading below ``range_min_m``).

:class:`ObstacleDistanceAssembler` turns ``OBSTACLE_DISTANCE`` messages (:class:`ScanPart`) into scans: parts of
the same ``time_usec`` are one scan (the bundled vehicle sends 360 rays of 1° as five messages of 72, PX4 expects
one message of 72 sectors of 5°); a scan is complete when its parts cover 360°, or is flushed as a partial one
when a part of a newer time arrives. :class:`ScanGate` then refuses, and counts by reason, what must not reach the
map: wrong vehicle, floods faster than :data:`MAX_RATE_HZ`, stale or repeated times, bad ranges.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

UINT16_MAX = 65535
MAV_FRAME_GLOBAL = 0  # OBSTACLE_DISTANCE's default: angles from north
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
FRAMES = {MAV_FRAME_BODY_FRD: "body_frd", MAV_FRAME_GLOBAL: "north", MAV_FRAME_LOCAL_NED: "north"}
MAX_RATE_HZ = 50.0  # scans kept per second of vehicle time at most (a flood's extra scans are counted, not mapped)
MAX_RAYS = 4096  # one scan's rays at most
MAX_RANGE_M = 1000.0  # a sensor range limit above this is refused as absurd
PART_SECTORS = 72  # OBSTACLE_DISTANCE's distances[] length


@dataclass(frozen=True, slots=True)
class Scan:
    """One sweep: ``t_s`` vehicle time (s since boot); ``angles_rad`` ray angles (rad, in ``frame``: ``"body_frd"``
    from the airframe's nose, positive clockwise, or ``"north"`` from north, positive clockwise, level); ``ranges_m``
    per ray (m; +inf no return within range, NaN unknown); ``range_min_m``/``range_max_m`` the sensor's limits (m);
    ``increment_rad`` the rays' nominal spacing (rad); ``source`` where it came from (``mavlink``, ``zenoh``,
    ``ros2``); ``system_id`` the MAVLink system that sent it (None off MAVLink)."""

    t_s: float
    angles_rad: np.ndarray
    ranges_m: np.ndarray
    range_min_m: float
    range_max_m: float
    increment_rad: float
    frame: str = "body_frd"
    source: str = "mavlink"
    system_id: int | None = None


@dataclass(frozen=True, slots=True)
class ScanPart:
    """One ``OBSTACLE_DISTANCE`` message as sent: ``time_usec`` (µs since boot), ``distances_cm`` (72 values, cm;
    ``max_distance_cm + 1`` = nothing in range, ``UINT16_MAX`` = unknown), ``min_distance_cm``/``max_distance_cm``,
    ``increment_deg`` (``increment_f`` when non-zero, else the integer ``increment``), ``angle_offset_deg`` (the
    first sector's angle), ``frame`` (MAV_FRAME), ``system_id`` of the sender."""

    time_usec: int
    distances_cm: tuple[int, ...]
    min_distance_cm: int
    max_distance_cm: int
    increment_deg: float
    angle_offset_deg: float
    frame: int
    system_id: int


def part_problem(p: ScanPart) -> str | None:
    """Why a part cannot be used (a refusal reason), or None."""
    if not (math.isfinite(p.increment_deg) and math.isfinite(p.angle_offset_deg)):
        return "nonfinite"
    if p.frame not in FRAMES:
        return "frame"
    if p.increment_deg <= 0.0:
        return "increment"
    used = _used_sectors(p)
    if used == 0:
        return "empty"
    if used * p.increment_deg > 360.0 + 1e-6:
        return "coverage"
    if p.max_distance_cm <= p.min_distance_cm or p.max_distance_cm * 0.01 > MAX_RANGE_M:
        return "range_limits"
    return None


def _used_sectors(p: ScanPart) -> int:
    """Sectors up to the last one that is not ``UINT16_MAX`` (PX4 fills unused trailing sectors with it)."""
    d = p.distances_cm
    n = len(d)
    while n > 0 and d[n - 1] == UINT16_MAX:
        n -= 1
    return n


def part_rays(p: ScanPart) -> tuple[np.ndarray, np.ndarray]:
    """A valid part's rays: angles (rad, wrapped to [0, 2π)) and ranges (m; +inf no return, NaN unknown)."""
    n = _used_sectors(p)
    d = np.asarray(p.distances_cm[:n], dtype=float)
    ang = np.radians(p.angle_offset_deg + p.increment_deg * np.arange(n)) % (2.0 * math.pi)
    r = d * 0.01
    unknown = (d == UINT16_MAX) | (d < p.min_distance_cm) | (d > p.max_distance_cm + 1)
    r[d == p.max_distance_cm + 1] = math.inf
    r[unknown] = math.nan
    return ang, r


class ObstacleDistanceAssembler:
    """``OBSTACLE_DISTANCE`` parts → scans: :meth:`add` returns the scans it completed (usually zero or one).

    Parts of one ``time_usec`` and sender accumulate; a scan is out when its parts cover 360° (a repeated angle is
    kept once), or as a partial scan when a newer time arrives first. A part older than the one being assembled is
    refused (``out_of_order``). Refused parts are counted in ``refused`` by reason."""

    def __init__(self) -> None:
        self.refused: Counter[str] = Counter()
        self.parts = 0
        self.partial_scans = 0
        self._key: tuple[int, int] | None = None  # (system id, time_usec) being assembled
        self._keys: set[int] = set()  # the rays held, by angle in millidegrees
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # per part: keys, angles rad, ranges m
        self._limits = (0.0, 0.0, 0.0, 0)  # min m, max m, increment rad, frame

    def add(self, p: ScanPart) -> list[Scan]:
        """Take one part; the scans completed by it (a partial one flushed first when ``p`` starts a newer one)."""
        why = part_problem(p)
        if why is not None:
            self.refused[why] += 1
            return []
        self.parts += 1
        out: list[Scan] = []
        key = (p.system_id, p.time_usec)
        if self._key is not None and key != self._key:
            if key[0] == self._key[0] and key[1] < self._key[1]:
                self.refused["out_of_order"] += 1
                return []
            out.append(self._flush(partial=True))
        if self._key is None:
            self._key = key
            self._limits = (p.min_distance_cm * 0.01, p.max_distance_cm * 0.01, math.radians(p.increment_deg),
                            p.frame)
        elif self._limits[3] != p.frame:
            self.refused["frame_mixed"] += 1
            return out
        inc = min(self._limits[2], math.radians(p.increment_deg))
        self._limits = (self._limits[0], self._limits[1], inc, self._limits[3])
        ang, rng = part_rays(p)
        keys = np.round(np.degrees(ang) * 1000.0).astype(np.int64) % 360000
        self._parts.append((keys, ang, rng))
        self._keys.update(keys.tolist())
        if len(self._keys) * math.degrees(inc) >= 360.0 - 1e-6 or len(self._keys) >= MAX_RAYS:
            out.append(self._flush(partial=False))
        return out

    def _flush(self, partial: bool) -> Scan:
        assert self._key is not None
        sysid, t_us = self._key
        keys = np.concatenate([k for k, _, _ in self._parts])
        ang = np.concatenate([a for _, a, _ in self._parts])
        rng = np.concatenate([r for _, _, r in self._parts])
        _, first = np.unique(keys, return_index=True)  # sorted by angle; a repeated angle's first reading kept
        lo, hi, inc, frame = self._limits
        self._key, self._keys, self._parts = None, set(), []
        self.partial_scans += partial
        return Scan(t_us * 1e-6, ang[first], rng[first], lo, hi, inc, FRAMES[frame], "mavlink", sysid)


def scan_problem(s: Scan) -> str | None:
    """Why a scan (from any input) is not a valid one: a refusal reason, or None. NaN ranges (unknown) and +inf
    (no return) are valid markers; −inf, negative ranges and non-finite angles or limits are not."""
    if not (math.isfinite(s.t_s) and math.isfinite(s.range_min_m) and math.isfinite(s.range_max_m)
            and math.isfinite(s.increment_rad)):
        return "nonfinite"
    n = len(s.ranges_m)
    if n == 0 or n > MAX_RAYS or len(s.angles_rad) != n:
        return "ray_count"
    if not 0.0 <= s.range_min_m < s.range_max_m <= MAX_RANGE_M:
        return "range_limits"
    if s.increment_rad <= 0.0 or n * s.increment_rad > 2.0 * math.pi + 1e-6:
        return "increment"
    if not np.isfinite(s.angles_rad).all():
        return "nonfinite"
    with np.errstate(invalid="ignore"):
        if (s.ranges_m < 0.0).any():  # −inf included; NaN compares False
            return "negative_range"
    return None


class ScanGate:
    """What may reach the map, counted by reason in ``refused``: a bad scan (:func:`scan_problem`), one from
    another system than the vehicle (``wrong_vehicle``), one of the same time as the last kept (``duplicate``: the
    same scan from a second input), one older (``stale``), one less than ``1 / max_rate_hz`` s of vehicle time
    after the last kept (``rate_limit``)."""

    def __init__(self, max_rate_hz: float = MAX_RATE_HZ) -> None:
        self.min_gap_s = 1.0 / max_rate_hz
        self.refused: Counter[str] = Counter()
        self.passed = 0
        self._last_t_s = -math.inf

    def check(self, s: Scan, vehicle_sysid: int | None) -> bool:
        """True if ``s`` may go on (counted as passed); else counted by reason in ``refused``."""
        why = scan_problem(s)
        if why is None and s.system_id is not None and s.system_id != vehicle_sysid:
            why = "wrong_vehicle"
        if why is None and s.t_s == self._last_t_s:
            why = "duplicate"  # the same scan again (a resend, or the same sensor on MAVLink and Zenoh)
        if why is None and s.t_s < self._last_t_s:
            why = "stale"
        if why is None and s.t_s - self._last_t_s < self.min_gap_s - 1e-9:
            why = "rate_limit"
        if why is not None:
            self.refused[why] += 1
            return False
        self._last_t_s = s.t_s
        self.passed += 1
        return True
