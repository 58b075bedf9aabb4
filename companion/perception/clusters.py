"""Returns into trunks: segmentation of consecutive returns, and a circle fitted to each (pure: numpy only).

Segmentation walks the kept returns in ray order: a new segment starts where the range jumps by more than
``JUMP_M + JUMP_FRAC · range`` or rays are missing between two returns (wrapping around 360°). A trunk seen from
one side shows an arc of less than 180° (at range d, a trunk of radius r shows 180° − 2·asin(r/d) of its
circumference, and only a few rays of it when far), and an algebraic fit (Kåsa) on a short, noisy arc is biased
towards small circles and can be far off. So the centre and radius are found by a few Gauss-Newton steps on the
geometric residuals (distance to the circle minus the radius) with a prior on the radius (``radius_prior_m``,
``radius_prior_sigma_m``), started from the Kåsa fit when it is sane, else from the arc's centroid pushed away from
the sensor by the prior radius. The covariance of (centre, radius) is the residuals' variance (at least the
sensor's noise) times the inverse normal matrix: a short arc has a large one, along the line of sight mostly.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from companion.perception.circle_batch import fit_circles
from companion.perception.points import ScanPoints

JUMP_M = 0.25  # range jump (m) that starts a new segment ...
JUMP_FRAC = 0.03  # ... plus this fraction of the range
MIN_POINTS = 3  # returns a circle needs
MAX_RADIUS_M = 1.5  # a segment wider than a trunk of this radius is not a trunk (a wall, a bush)
NOISE_FLOOR_M = 0.01  # the range noise assumed at least (m, 1σ)


@dataclass(frozen=True, slots=True)
class Detection:
    """One trunk seen in one scan: centre (north, east; m, mission frame), radius (m), the 2×2 covariance of the
    centre (m²), the radius' 1σ (m), the number of returns, the visible arc (rad) and the mean NED height of the
    returns (m)."""

    x_m: float
    y_m: float
    radius_m: float
    cov_xy: np.ndarray
    radius_sigma_m: float
    n_points: int
    arc_rad: float
    z_m: float

    @property
    def sigma_m(self) -> float:
        """The centre's 1σ along its worst axis (m)."""
        return math.sqrt(max(float(np.linalg.eigvalsh(self.cov_xy)[-1]), 0.0))


def segments(pts: ScanPoints, jump_m: float = JUMP_M, jump_frac: float = JUMP_FRAC) -> list[np.ndarray]:
    """Index arrays (into ``pts``' returns) of consecutive returns, wrapping around the scan's end."""
    n = len(pts.ray)
    if n == 0:
        return []
    r, ray = pts.range_m, pts.ray
    n_rays = len(pts.bearing_rad)
    gap_rays = np.diff(ray, append=ray[0] + n_rays)
    jump = np.abs(np.diff(r, append=r[0]))
    brk = (gap_rays > 2) | (jump > jump_m + jump_frac * np.minimum(r, np.roll(r, -1)))
    cuts = np.flatnonzero(brk)  # a segment ends at each cut
    if len(cuts) == 0:
        return [np.arange(n)]
    starts = (cuts + 1) % n
    out = []
    for s, e in zip(starts, np.roll(cuts, -1), strict=True):
        out.append(np.arange(s, e + 1) if e >= s else np.concatenate([np.arange(s, n), np.arange(0, e + 1)]))
    return out


def kasa(xy: np.ndarray) -> tuple[float, float, float] | None:
    """The algebraic (Kåsa) circle through ``xy`` (N, 2): (cx, cy, r) in m, or None when degenerate."""
    mx, my = float(xy[:, 0].mean()), float(xy[:, 1].mean())
    x, y = xy[:, 0] - mx, xy[:, 1] - my  # centred: better conditioned
    z = x * x + y * y
    sxx, syy, sxy = float(x @ x), float(y @ y), float(x @ y)
    det = sxx * syy - sxy * sxy
    if abs(det) < 1e-300:
        return None
    d = (-float(x @ z) * syy + float(y @ z) * sxy) / det
    e = (-float(y @ z) * sxx + float(x @ z) * sxy) / det
    cx, cy = -d / 2.0, -e / 2.0
    r2 = cx * cx + cy * cy + float(z.mean())
    if not (math.isfinite(r2) and r2 > 0.0):
        return None
    return cx + mx, cy + my, math.sqrt(r2)


def fit_circle(xy: np.ndarray, sensor_xy: tuple[float, float], r0: float, r0_sigma: float,
               noise_m: float = NOISE_FLOOR_M) -> tuple[np.ndarray, np.ndarray] | None:
    """Centre and radius (cx, cy, r; m) of the trunk whose near side ``xy`` (N ≥ 3, 2; m) is, seen from
    ``sensor_xy``, with a radius prior ``r0`` ± ``r0_sigma`` (m); and their 3×3 covariance (m²). None when the fit
    fails (a line, a degenerate arc). One segment of :func:`~companion.perception.circle_batch.fit_circles`."""
    p, cov, ok = fit_circles(np.asarray(xy, dtype=float), np.array([0]), sensor_xy, r0, r0_sigma, noise_m)
    return (p[0], cov[0]) if ok[0] else None


class Clusterer:
    """:class:`ScanPoints` → :class:`Detection` list; segments that are no trunk are counted in ``skipped`` by
    reason (``few_points``, ``too_wide``, ``no_fit``)."""

    def __init__(self, radius_prior_m: float = 0.25, radius_prior_sigma_m: float = 0.15,
                 noise_m: float = NOISE_FLOOR_M) -> None:
        self.r0 = radius_prior_m
        self.r0_sigma = radius_prior_sigma_m
        self.noise_m = noise_m
        self.skipped: Counter[str] = Counter()

    def detect(self, pts: ScanPoints) -> list[Detection]:
        """The trunks one placed scan shows: every segment fitted at once."""
        segs = []
        for seg in segments(pts):
            if len(seg) < MIN_POINTS:
                self.skipped["few_points"] += 1
            elif float(np.hypot(*(pts.xy_m[seg[-1]] - pts.xy_m[seg[0]]))) > 2.0 * MAX_RADIUS_M:
                self.skipped["too_wide"] += 1
            else:
                segs.append(seg)
        if not segs:
            return []
        idx = np.concatenate(segs)
        starts = np.cumsum([0] + [len(g) for g in segs[:-1]])
        p, cov, ok = fit_circles(pts.xy_m[idx], starts, pts.origin_m, self.r0, self.r0_sigma, self.noise_m)
        out: list[Detection] = []
        for k, seg in enumerate(segs):
            if not ok[k] or not 0.0 < p[k, 2] <= MAX_RADIUS_M:
                self.skipped["no_fit"] += 1
                continue
            xy = pts.xy_m[seg]
            ang = np.arctan2(xy[[0, -1], 1] - p[k, 1], xy[[0, -1], 0] - p[k, 0])
            arc = float(abs((ang[1] - ang[0] + math.pi) % (2.0 * math.pi) - math.pi))
            out.append(Detection(float(p[k, 0]), float(p[k, 1]), float(p[k, 2]), cov[k, :2, :2].copy(),
                                 math.sqrt(max(float(cov[k, 2, 2]), 0.0)), len(seg), arc,
                                 float(pts.z_m[seg].mean())))
        return out
