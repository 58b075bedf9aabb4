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

Two trunks side by side with a gap narrower than a ray's spacing (two crossing trunks passing each other, a moving
one passing a still one) give one segment: no ray passes between them and the range at the seam changes less
than the jump. One circle does not fit such a segment: its residuals exceed what the range noise explains (a χ²
test at 99.9 %). Such a segment is cut in two where the two circles fitted to the pieces leave the least residual,
when that cuts the residuals by :data:`SPLIT_GAIN` at least (:meth:`Clusterer.split`; counted in ``cuts``).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from companion.perception.circle_batch import fit_circles, residual_ss
from companion.perception.points import ScanPoints

JUMP_M = 0.25  # range jump (m) that starts a new segment ...
JUMP_FRAC = 0.03  # ... plus this fraction of the range
MIN_POINTS = 3  # returns a circle needs
MAX_RADIUS_M = 1.5  # a segment wider than a trunk of this radius is not a trunk (a wall, a bush)
NOISE_FLOOR_M = 0.01  # the range noise assumed at least (m, 1σ)
SPLIT_Z = 3.09  # a segment's residuals beyond this quantile (normal z: 99.9 %) of the noise's χ² are two trunks
SPLIT_GAIN = 4.0  # a cut must divide the residuals' sum of squares by this much at least
MIN_PIECE = 2  # a cut may leave this few returns on one side (a neighbour's edge)
SPLIT_ROUNDS = 2  # cuts per segment at most 2**rounds - 1 (three trunks in a row)


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
    reason (``few_points``, ``too_wide``, ``no_fit``), segments cut in two (two trunks) in ``cuts``."""

    def __init__(self, radius_prior_m: float = 0.25, radius_prior_sigma_m: float = 0.15,
                 noise_m: float = NOISE_FLOOR_M) -> None:
        self.r0 = radius_prior_m
        self.r0_sigma = radius_prior_sigma_m
        self.noise_m = noise_m
        self.skipped: Counter[str] = Counter()
        self.cuts = 0

    def detect(self, pts: ScanPoints) -> list[Detection]:
        """The trunks one placed scan shows: every segment fitted at once, a segment that is two trunks cut."""
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
        p, cov, ok = self._fit(pts, segs)
        for _ in range(SPLIT_ROUNDS):
            cut = self.split(pts, segs, p, ok)
            if len(cut) == len(segs):
                break
            segs = [g for g in cut if len(g) >= MIN_POINTS]
            self.skipped["few_points"] += len(cut) - len(segs)
            if not segs:
                return []
            p, cov, ok = self._fit(pts, segs)
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

    def _fit(self, pts: ScanPoints, segs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`fit_circles` of ``segs`` (index arrays into ``pts``): (S, 3) circles, (S, 3, 3) covariances, (S,)
        success."""
        idx = np.concatenate(segs)
        starts = np.cumsum([0] + [len(g) for g in segs[:-1]])
        return fit_circles(pts.xy_m[idx], starts, pts.origin_m, self.r0, self.r0_sigma, self.noise_m)

    def split(self, pts: ScanPoints, segs: list[np.ndarray], p: np.ndarray, ok: np.ndarray) -> list[np.ndarray]:
        """``segs`` with every segment that one circle (``p``, fitted; ``ok``) does not fit cut in two: where
        the two pieces' circles (a plausible radius; a piece of :data:`MIN_PIECE` returns, a trunk's edge, fits
        any) leave the least residual, if that is :data:`SPLIT_GAIN` times less than one circle's (or one circle
        failed). A piece under :data:`MIN_POINTS` returns is later skipped (``few_points``)."""
        n = np.array([len(g) for g in segs])
        starts = np.cumsum(np.append(0, n[:-1]))
        ssr = residual_ss(pts.xy_m[np.concatenate(segs)], starts, np.where(ok[:, None], p, 0.0))
        dof = np.maximum(n - 3, 1)
        bad = np.flatnonzero((n >= 2 * MIN_PIECE)
                             & (~ok | (ssr > self.noise_m ** 2 * chi2_quantile(dof, SPLIT_Z))))
        if len(bad) == 0:
            return segs
        pieces, owner = [], []
        for k in bad.tolist():
            for c in range(MIN_PIECE, n[k] - MIN_PIECE + 1):
                pieces += [segs[k][:c], segs[k][c:]]
                owner.append(k)
        pssr = self._pieces_ssr(pts, pieces)
        both = pssr[0::2] + pssr[1::2]
        owner_a = np.array(owner)
        out: list[np.ndarray] = []
        for k, seg in enumerate(segs):
            js = np.flatnonzero(owner_a == k)
            if not len(js) or not np.isfinite(both[js].min()):
                out.append(seg)
                continue
            floor = self.noise_m ** 2 * float(chi2_quantile(max(n[k] - 6, 1), SPLIT_Z))  # what noise leaves
            j = self._pick_cut(pts, pieces, js, both[js], floor)
            if not ok[k] or SPLIT_GAIN * both[j] < ssr[k]:
                out += [pieces[2 * j], pieces[2 * j + 1]]
                self.cuts += 1
            else:
                out.append(seg)
        return out

    @staticmethod
    def _pick_cut(pts: ScanPoints, pieces: list[np.ndarray], js: np.ndarray, ssr: np.ndarray, floor: float) -> int:
        """Of one segment's cuts ``js`` (pairs in ``pieces``) with residuals ``ssr`` (m²): the least residual, or
        where the residuals cannot tell (within :data:`SPLIT_GAIN` of the least, or below ``floor``, m², what the
        noise leaves: pieces of 3 returns fit any three points), the one across the largest range step (m) between
        two consecutive returns (the seam)."""
        close = js[ssr <= max(SPLIT_GAIN * float(ssr.min()), floor)]
        if len(close) == 1:
            return int(close[0])
        step = [abs(float(pts.range_m[pieces[2 * j + 1][0]] - pts.range_m[pieces[2 * j][-1]])) for j in close]
        return int(close[int(np.argmax(step))])

    def _pieces_ssr(self, pts: ScanPoints, pieces: list[np.ndarray]) -> np.ndarray:
        """Per piece the residuals' sum of squares (m²) of its circle: 0 for a piece too short to fit, inf when
        the fit fails or its radius is implausible."""
        out = np.zeros(len(pieces))
        fit = [i for i, g in enumerate(pieces) if len(g) >= MIN_POINTS]
        if fit:
            idx = np.concatenate([pieces[i] for i in fit])
            starts = np.cumsum([0] + [len(pieces[i]) for i in fit[:-1]])
            pp, _, ok = fit_circles(pts.xy_m[idx], starts, pts.origin_m, self.r0, self.r0_sigma, self.noise_m)
            ok &= (pp[:, 2] > 0.0) & (pp[:, 2] <= MAX_RADIUS_M)
            out[fit] = np.where(ok, residual_ss(pts.xy_m[idx], starts, np.where(ok[:, None], pp, 0.0)), np.inf)
        return out


def chi2_quantile(dof: np.ndarray, z: float) -> np.ndarray:
    """The χ² quantile of ``dof`` degrees of freedom at the normal quantile ``z`` (Wilson-Hilferty)."""
    k = np.asarray(dof, dtype=float)
    return k * (1.0 - 2.0 / (9.0 * k) + z * np.sqrt(2.0 / (9.0 * k))) ** 3
