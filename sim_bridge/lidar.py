"""A 2-D scanning LiDAR on the airframe (pure numpy, no I/O): rays in the airframe's x-y plane at its real attitude,
cast against vertical cylinders of finite height and the ground plane.

Ray ``i`` leaves the airframe's centre at the angle ``θ_i = i · step`` (rad) from the body forward axis,
clockwise seen from above (towards body +y, MAVLink's BODY_FRD): direction ``R(φ, θ, ψ) · [cos θ_i, sin θ_i, 0]``
in NED (R body → NED, eq. 12). Each ray is cast against every trunk (a vertical cylinder from the ground z = 0 up
to z = −height: its side and its top disc; a ray passing above the top misses it) and the ground (z = 0, NED z
down); the nearest hit wins, so trunks occlude what stands behind them and a tilted scan strikes the ground.

A range is the 3-D distance (m) from the sensor to the hit. Result per ray: a finite range in
``[range_min_m, range_max_m]``; ``+inf`` = measured, nothing within ``range_max_m``; NaN = not measured (a
dropout, or a hit closer than ``range_min_m``, which the sensor cannot measure). Noise: Gaussian (σ
``noise_m``) on every return, clipped to the range limits; dropouts: each ray independently with probability
``dropout``. The random stream is seeded and draws the same numbers for every scan whatever the geometry, so a
run repeats bit for bit.

Left out (docs/sitl.md): the whole scan is taken at one instant (a spinning sensor's 100 ms sweep is not
smeared over the motion), no beam width (a ray is a line: thin trunks between rays are missed), no reflectivity,
no mixed pixels at edges, no rain/dust returns; the payload and the cable are invisible to it; the sensor sits at
the airframe's centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core.model import rotation_body_to_ned


@dataclass(frozen=True)
class LidarConfig:
    """The LiDAR's settings: ranges (m), scan rate (Hz), angular step (deg), 1σ range noise (m), dropout
    probability per ray (0..1) and the noise generator's seed. Defaults like a common 2-D LiDAR."""

    range_max_m: float = 12.0
    range_min_m: float = 0.1
    rate_hz: float = 10.0
    step_deg: float = 1.0
    noise_m: float = 0.01
    dropout: float = 0.0
    seed: int = 0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for values no sensor has, or that MAVLink cannot carry."""
        for key in ("range_max_m", "range_min_m", "rate_hz", "step_deg", "noise_m", "dropout"):
            v = getattr(self, key)
            if not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"{key}: must be a finite number, got {v!r}")
        if not 0.0 <= self.range_min_m < self.range_max_m <= 600.0:
            raise ValueError(f"range_max_m: need 0 <= range_min_m < range_max_m <= 600 m (OBSTACLE_DISTANCE's cm "
                             f"in a uint16), got {self.range_min_m}, {self.range_max_m}")
        if not 0.0 < self.rate_hz <= 100.0:
            raise ValueError(f"rate_hz: must be in (0, 100] Hz, got {self.rate_hz}")
        n = 360.0 / self.step_deg if self.step_deg > 0 else 0.0
        if not 0.25 <= self.step_deg <= 45.0 or abs(n - round(n)) > 1e-6:
            raise ValueError(f"step_deg: must divide 360 and be in [0.25, 45] deg, got {self.step_deg}")
        if not 0.0 <= self.noise_m <= 1.0:
            raise ValueError(f"noise_m: must be in [0, 1] m, got {self.noise_m}")
        if not 0.0 <= self.dropout <= 1.0:
            raise ValueError(f"dropout: must be a probability in [0, 1], got {self.dropout}")

    @property
    def n_rays(self) -> int:
        """Rays per scan (360° / step)."""
        return round(360.0 / self.step_deg)

    @property
    def period_us(self) -> int:
        """Time between scans (µs)."""
        return round(1e6 / self.rate_hz)


class Lidar:
    """The sensor: :meth:`scan` one scan at a pose; :meth:`true_ranges` the same without noise or dropouts."""

    def __init__(self, cfg: LidarConfig) -> None:
        cfg.validate()
        self.cfg = cfg
        self.angles_rad = np.arange(cfg.n_rays, dtype=np.float64) * math.radians(cfg.step_deg)
        self._body = np.vstack([np.cos(self.angles_rad), np.sin(self.angles_rad)])  # (2, n) body x, y
        self._rng = np.random.default_rng(cfg.seed)

    def directions_ned(self, euler_rad) -> np.ndarray:
        """The rays' unit directions in NED (3, n) at attitude ``euler_rad`` (roll, pitch, yaw; rad)."""
        r = rotation_body_to_ned(float(euler_rad[0]), float(euler_rad[1]), float(euler_rad[2]))
        return r[:, :2] @ self._body

    def true_ranges(self, pos_ned_m, euler_rad, cx, cy, radius, height) -> np.ndarray:
        """Noise-free distance (m) along each ray to its nearest hit, ``+inf`` if none within ``range_max_m``.

        ``pos_ned_m`` the sensor (NED, m), ``euler_rad`` the airframe's attitude; trunks as arrays (m,) of centre
        x, y (NED, m), radius (m) and height (m) above the ground."""
        o = np.asarray(pos_ned_m, dtype=np.float64)
        d = self.directions_ned(euler_rad)
        best = _ground_hits(o, d)
        cx, cy, radius, height = (np.asarray(a, dtype=np.float64) for a in (cx, cy, radius, height))
        if cx.size:
            near = np.hypot(cx - o[0], cy - o[1]) <= self.cfg.range_max_m + radius
            if np.any(near):
                best = np.minimum(best, _trunk_hits(o, d, cx[near], cy[near], radius[near], height[near]))
        best[best > self.cfg.range_max_m] = math.inf
        return best

    def scan(self, pos_ned_m, euler_rad, cx, cy, radius, height) -> np.ndarray:
        """One measured scan (m, per ray): see the module docstring for +inf and NaN. Draws from the seeded
        generator: ``n`` normals and ``n`` uniforms per scan, always."""
        c = self.cfg
        true = self.true_ranges(pos_ned_m, euler_rad, cx, cy, radius, height)
        noise = self._rng.standard_normal(true.size)
        lost = self._rng.random(true.size) < c.dropout
        out = true.copy()
        hit = np.isfinite(true)
        out[hit] = np.clip(true[hit] + c.noise_m * noise[hit], c.range_min_m, c.range_max_m)
        out[(hit & (true < c.range_min_m)) | lost] = math.nan
        return out


def _ground_hits(o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Distance along each ray (3, n) from ``o`` to the ground z = 0 (+inf for rays not going down)."""
    dz = d[2]
    out = np.full(dz.shape, math.inf)
    down = dz > 1e-12
    if o[2] < 0.0:
        out[down] = -o[2] / dz[down]
    return out


def _trunk_hits(o: np.ndarray, d: np.ndarray, cx, cy, radius, height) -> np.ndarray:
    """Per ray, the distance to the nearest hit on the trunks' sides or top discs (+inf if none): (n,) from
    rays (3, n) and trunks (m,). Arrays are (m, n): a trunk per row, so the minimum runs over contiguous rows."""
    dx, dy, dz = d
    ox, oy = (o[0] - cx)[:, None], (o[1] - cy)[:, None]  # (m, 1)
    r2 = (radius * radius)[:, None]
    a = dx * dx + dy * dy  # (n,), > 0 unless the ray is vertical
    half_b = ox * dx + oy * dy  # (m, n)
    c = ox * ox + oy * oy - r2  # (m, 1)
    disc = half_b * half_b - a * c
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s = (-half_b - np.sqrt(disc)) / a  # entering the side; NaN where the ray misses the circle
        s = np.where(c < 0.0, 0.0, s)  # the sensor inside a trunk: touching it
        z = o[2] + s * dz
        s = np.where((s >= 0.0) & (z <= 0.0) & (z >= -height[:, None]), s, math.inf)  # NaN compares False
        above = height < -o[2]  # the sensor above these trunks' tops: a ray going down may land on the top disc
        if np.any(above):
            s_top = (-height[above, None] - o[2]) / dz  # (k, n)
            px, py = ox[above] + s_top * dx, oy[above] + s_top * dy
            top_ok = (s_top >= 0.0) & (px * px + py * py <= r2[above])
            s[above] = np.where(top_ok & (s_top < s[above]), s_top, s[above])
    return np.min(s, axis=0)
