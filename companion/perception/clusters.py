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

from companion.perception.points import ScanPoints

JUMP_M = 0.25  # range jump (m) that starts a new segment ...
JUMP_FRAC = 0.03  # ... plus this fraction of the range
MIN_POINTS = 3  # returns a circle needs
MAX_RADIUS_M = 1.5  # a segment wider than a trunk of this radius is not a trunk (a wall, a bush)
NOISE_FLOOR_M = 0.01  # the range noise assumed at least (m, 1σ)
GN_STEPS = 6


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


def _inv3(m: list[list[float]]) -> list[list[float]] | None:
    """The inverse of a 3×3 matrix (nested lists), or None when singular (plain floats: a scan fits dozens of
    circles, and numpy's per-call overhead on 3×3 is most of their cost)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    co = [[e * i - f * h, c * h - b * i, b * f - c * e],
          [f * g - d * i, a * i - c * g, c * d - a * f],
          [d * h - e * g, b * g - a * h, a * e - b * d]]
    det = a * co[0][0] + b * co[1][0] + c * co[2][0]
    if not math.isfinite(det) or abs(det) < 1e-300:
        return None
    return [[v / det for v in row] for row in co]


def _mul3(m: list[list[float]], v: tuple[float, float, float]) -> tuple[float, float, float]:
    return (m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2], m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2])


def kasa(xy: np.ndarray) -> tuple[float, float, float] | None:
    """The algebraic (Kåsa) circle through ``xy`` (N, 2): (cx, cy, r) in m, or None when degenerate."""
    mx, my = float(xy[:, 0].mean()), float(xy[:, 1].mean())
    x, y = xy[:, 0] - mx, xy[:, 1] - my  # centred: better conditioned
    z = x * x + y * y
    sxx, syy, sxy = float(x @ x), float(y @ y), float(x @ y)
    inv = _inv3([[sxx, sxy, 0.0], [sxy, syy, 0.0], [0.0, 0.0, float(len(x))]])
    if inv is None:
        return None
    d, e, f = _mul3(inv, (-float(x @ z), -float(y @ z), -float(z.sum())))
    cx, cy = -d / 2.0, -e / 2.0
    r2 = cx * cx + cy * cy - f
    if not (math.isfinite(r2) and r2 > 0.0):
        return None
    return cx + mx, cy + my, math.sqrt(r2)


def _normal(x: np.ndarray, y: np.ndarray, p: tuple[float, float, float], noise_m: float):
    """Gauss-Newton's pieces at ``p`` = (cx, cy, r): JᵀJ (3×3 lists, J = ∂res/∂p, res = |xy − c| − r), Jᵀres and
    the residuals' variance (m², at least ``noise_m``²); None when a point sits on the centre."""
    dx, dy = x - p[0], y - p[1]
    rho = np.sqrt(dx * dx + dy * dy)
    if float(rho.min()) < 1e-9:
        return None
    ux, uy = dx / rho, dy / rho
    res = rho - p[2]
    n = len(x)
    sux, suy = float(ux.sum()), float(uy.sum())
    jtj = [[float(ux @ ux), float(ux @ uy), sux], [float(ux @ uy), float(uy @ uy), suy], [sux, suy, float(n)]]
    jtr = (-float(ux @ res), -float(uy @ res), -float(res.sum()))
    sigma2 = max(float(res @ res) / max(n - 2, 1), noise_m * noise_m)
    return jtj, jtr, sigma2


def fit_circle(xy: np.ndarray, sensor_xy: tuple[float, float], r0: float, r0_sigma: float,
               noise_m: float = NOISE_FLOOR_M) -> tuple[np.ndarray, np.ndarray] | None:
    """Centre and radius (cx, cy, r; m) of the trunk whose near side ``xy`` (N, 2; m) is, seen from
    ``sensor_xy``, with a radius prior ``r0`` ± ``r0_sigma`` (m); and their 3×3 covariance (m²). None when the fit
    fails (a line, a degenerate arc)."""
    start = _start(xy, sensor_xy, r0)
    if start is None:
        return None
    p = (float(start[0]), float(start[1]), float(start[2]))
    x, y = xy[:, 0], xy[:, 1]
    w0 = 1.0 / (r0_sigma * r0_sigma)
    for _ in range(GN_STEPS):
        nrm = _normal(x, y, p, noise_m)
        if nrm is None:
            return None
        jtj, jtr, s2 = nrm
        h = [[v / s2 for v in row] for row in jtj]
        h[2][2] += w0
        inv = _inv3(h)
        if inv is None:
            return None
        g = (jtr[0] / s2, jtr[1] / s2, jtr[2] / s2 + w0 * (p[2] - r0))
        step = _mul3(inv, g)
        p = (p[0] - step[0], p[1] - step[1], p[2] - step[2])
        if not all(map(math.isfinite, p)) or p[2] <= 0.0:
            return None
        if step[0] ** 2 + step[1] ** 2 + step[2] ** 2 < 1e-10:
            break
    nrm = _normal(x, y, p, noise_m)
    if nrm is None:
        return None
    jtj, _, s2 = nrm
    h = [[v / s2 for v in row] for row in jtj]
    h[2][2] += w0
    cov = _inv3(h)
    if cov is None:
        return None
    return np.array(p), np.array(cov)


def _start(xy: np.ndarray, sensor_xy: tuple[float, float], r0: float) -> np.ndarray | None:
    """The starting (cx, cy, r): Kåsa's when its circle lies behind the arc and its radius is plausible, else the
    arc's centroid pushed away from the sensor by ``r0``."""
    cx, cy = float(xy[:, 0].mean()), float(xy[:, 1].mean())
    ax, ay = cx - sensor_xy[0], cy - sensor_xy[1]
    dist = math.hypot(ax, ay)
    if dist < 1e-6:
        return None
    ax, ay = ax / dist, ay / dist
    k = kasa(xy) if len(xy) >= 5 else None
    if k is not None and 0.02 < k[2] < MAX_RADIUS_M and (k[0] - cx) * ax + (k[1] - cy) * ay > 0.0:
        return np.array(k)
    return np.array([cx + ax * r0, cy + ay * r0, r0])


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
        """The trunks one placed scan shows."""
        out: list[Detection] = []
        for seg in segments(pts):
            det = self.fit_segment(pts, seg)
            if det is not None:
                out.append(det)
        return out

    def fit_segment(self, pts: ScanPoints, seg: np.ndarray) -> Detection | None:
        """The trunk one segment (indices into ``pts``' returns) shows, or None (counted in ``skipped``)."""
        if len(seg) < MIN_POINTS:
            self.skipped["few_points"] += 1
            return None
        xy = pts.xy_m[seg]
        chord = float(np.hypot(*(xy[-1] - xy[0])))
        if chord > 2.0 * MAX_RADIUS_M:
            self.skipped["too_wide"] += 1
            return None
        fit = fit_circle(xy, pts.origin_m, self.r0, self.r0_sigma, self.noise_m)
        if fit is None or not 0.0 < fit[0][2] <= MAX_RADIUS_M:
            self.skipped["no_fit"] += 1
            return None
        p, cov = fit
        ang = np.arctan2(xy[:, 1] - p[1], xy[:, 0] - p[0])
        arc = float(abs((ang[-1] - ang[0] + math.pi) % (2.0 * math.pi) - math.pi))
        return Detection(float(p[0]), float(p[1]), float(p[2]), cov[:2, :2].copy(),
                         math.sqrt(max(float(cov[2, 2]), 0.0)), len(seg), arc, float(pts.z_m[seg].mean()))
