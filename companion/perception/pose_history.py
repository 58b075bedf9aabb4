"""The vehicle's recent poses, to place a scan where the vehicle was when it was taken (pure: numpy only).

Positions (mission-frame NED, m) and attitudes (roll, pitch, yaw, rad, NED → body FRD) arrive as separate
messages at their own rates; each goes into its own bounded ring with its vehicle time (s since boot). The pose at
a scan's time interpolates both: positions linearly, angles linearly on the shortest arc. A time older than either
ring's oldest sample is *late* (refused: the vehicle was somewhere the history no longer holds); a time newer than
the newest sample is held at the newest for up to :data:`MAX_HOLD_S` (the scan's pose messages may still be on
their way), beyond that it is *ahead* (refused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CAPACITY = 512  # samples per ring (2 s of 250 Hz telemetry, 10 s of 50 Hz)
MAX_HOLD_S = 0.1  # a scan up to this much newer than the newest pose uses the newest pose


@dataclass(frozen=True, slots=True)
class Pose:
    """Where the vehicle was at ``t_s`` (s): ``pos_m`` mission-frame NED (m), ``euler_rad`` roll, pitch, yaw (rad),
    ``r_body_to_ned`` the rotation matrix of that attitude (body FRD vectors → NED)."""

    t_s: float
    pos_m: np.ndarray
    euler_rad: tuple[float, float, float]
    r_body_to_ned: np.ndarray


def rotation_body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The 3×3 rotation of a body FRD vector into NED for ZYX Euler angles (rad)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    return np.array([
        [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
        [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
        [-sp, sr * cp, cr * cp],
    ])


class _Ring:
    """A bounded ring of (time, 3 values) samples, times non-decreasing."""

    def __init__(self, capacity: int) -> None:
        self.t = np.full(capacity, math.nan)
        self.v = np.zeros((capacity, 3))
        self.n = 0  # samples written in all
        self.cap = capacity

    def add(self, t_s: float, v: tuple[float, float, float]) -> bool:
        """Append a sample; False (ignored) when it is older than the newest one or not finite."""
        if not (math.isfinite(t_s) and all(map(math.isfinite, v))):
            return False
        if self.n and t_s < self.t[(self.n - 1) % self.cap]:
            return False
        k = self.n % self.cap
        self.t[k] = t_s
        self.v[k] = v
        self.n += 1
        return True

    def span(self) -> tuple[float, float] | None:
        """(oldest, newest) time held, or None when empty."""
        if self.n == 0:
            return None
        return float(self.t[self.n % self.cap if self.n >= self.cap else 0]), float(self.t[(self.n - 1) % self.cap])

    def at(self, t_s: float, angles: bool) -> np.ndarray:
        """The values interpolated at ``t_s`` (inside :meth:`span`, or held at an end)."""
        m = min(self.n, self.cap)
        start = self.n % self.cap if self.n >= self.cap else 0
        idx = (start + np.arange(m)) % self.cap
        ts = self.t[idx]
        j = int(np.searchsorted(ts, t_s, side="right"))
        if j <= 0:
            return self.v[idx[0]].copy()
        if j >= m:
            return self.v[idx[m - 1]].copy()
        t0, t1 = ts[j - 1], ts[j]
        a, b = self.v[idx[j - 1]], self.v[idx[j]]
        w = 0.0 if t1 <= t0 else (t_s - t0) / (t1 - t0)
        d = b - a
        if angles:
            d = (d + math.pi) % (2.0 * math.pi) - math.pi
        return a + w * d


class PoseHistory:
    """Recent positions and attitudes; :meth:`at` the pose at a time, or a refusal reason (``late``, ``ahead``,
    ``no_pose``)."""

    def __init__(self, capacity: int = CAPACITY) -> None:
        self._pos = _Ring(capacity)
        self._att = _Ring(capacity)
        self.ignored = 0  # samples out of order or not finite

    def add_position(self, t_s: float, pos_m: tuple[float, float, float]) -> None:
        """A position sample: vehicle time (s), mission-frame NED (m)."""
        self.ignored += not self._pos.add(t_s, pos_m)

    def add_attitude(self, t_s: float, euler_rad: tuple[float, float, float]) -> None:
        """An attitude sample: vehicle time (s), roll, pitch, yaw (rad)."""
        self.ignored += not self._att.add(t_s, euler_rad)

    @property
    def newest_s(self) -> float | None:
        """The newest time both rings hold (s), or None."""
        a, b = self._pos.span(), self._att.span()
        return None if a is None or b is None else min(a[1], b[1])

    def at(self, t_s: float) -> Pose | str:
        """The pose at vehicle time ``t_s`` (s), or why there is none."""
        spans = (self._pos.span(), self._att.span())
        if spans[0] is None or spans[1] is None:
            return "no_pose"
        if t_s < max(spans[0][0], spans[1][0]):
            return "late"
        if t_s > min(spans[0][1], spans[1][1]) + MAX_HOLD_S:
            return "ahead"
        pos = self._pos.at(t_s, angles=False)
        e = self._att.at(t_s, angles=True)
        euler = (float(e[0]), float(e[1]), float(e[2]))
        return Pose(t_s, pos, euler, rotation_body_to_ned(*euler))
