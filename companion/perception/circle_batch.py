"""Circle fits of many segments at once (pure: numpy only): the same fit as
:func:`companion.perception.clusters.fit_circle`, each numpy call covering every segment of a scan, so a scan's
fits cost about as much for 50 trunks as for 5 (one Python-level fit costs ~20 numpy calls per Gauss-Newton
step). Segments are given as one array of points and their start offsets (``np.add.reduceat`` sums per segment).
"""

from __future__ import annotations

import numpy as np

GN_STEPS = 6
MAX_RADIUS_M = 1.5


def _sums(vals: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Per segment sums of the (M,) or (K, M) values: (S,) or (K, S)."""
    return np.add.reduceat(vals, starts, axis=-1)


def _starts(xy: np.ndarray, starts: np.ndarray, n: np.ndarray, seg: np.ndarray, sensor_xy: tuple[float, float],
            r0: float) -> np.ndarray:
    """(S, 3) starting (cx, cy, r): per segment Kåsa's circle (closed form on centred points) when it has 5 points
    or more, lies behind the arc and has a plausible radius; else the centroid pushed away from the sensor by
    ``r0``."""
    mean = _sums(xy.T, starts) / n  # (2, S)
    x, y = xy[:, 0] - mean[0, seg], xy[:, 1] - mean[1, seg]
    z = x * x + y * y
    sxx, syy, sxy, sxz, syz, sz = _sums(np.stack([x * x, y * y, x * y, x * z, y * z, z]), starts)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = sxx * syy - sxy * sxy
        d = (-sxz * syy + syz * sxy) / det
        e = (-syz * sxx + sxz * sxy) / det
        kx, ky = -d / 2.0, -e / 2.0
        kr = np.sqrt(kx * kx + ky * ky + sz / n)
    away = mean - np.asarray(sensor_xy, dtype=float)[:, None]
    away /= np.maximum(np.hypot(away[0], away[1]), 1e-9)
    good = (n >= 5) & np.isfinite(kr) & (kr > 0.02) & (kr < MAX_RADIUS_M) & (kx * away[0] + ky * away[1] > 0.0)
    cx = np.where(good, kx + mean[0], mean[0] + away[0] * r0)
    cy = np.where(good, ky + mean[1], mean[1] + away[1] * r0)
    return np.stack([cx, cy, np.where(good, kr, r0)], axis=1)


def _normal(xy: np.ndarray, starts: np.ndarray, n: np.ndarray, seg: np.ndarray, p: np.ndarray, noise_m: float,
            r0: float, w0: float) -> tuple[np.ndarray, np.ndarray]:
    """(S, 3, 3) information matrices (JᵀJ / σ² plus the radius prior) and (S, 3) gradients at ``p``."""
    dx, dy = xy[:, 0] - p[seg, 0], xy[:, 1] - p[seg, 1]
    rho = np.maximum(np.sqrt(dx * dx + dy * dy), 1e-9)
    ux, uy = dx / rho, dy / rho
    res = rho - p[seg, 2]
    sxx, sxy, syy, sx, sy, sxr, syr, sr, srr = _sums(
        np.stack([ux * ux, ux * uy, uy * uy, ux, uy, ux * res, uy * res, res, res * res]), starts)
    s2 = np.maximum(srr / np.maximum(n - 2, 1), noise_m * noise_m)
    h = np.empty((len(n), 3, 3))
    h[:, 0, 0], h[:, 0, 1], h[:, 0, 2] = sxx, sxy, sx
    h[:, 1, 0], h[:, 1, 1], h[:, 1, 2] = sxy, syy, sy
    h[:, 2, 0], h[:, 2, 1], h[:, 2, 2] = sx, sy, n
    h /= s2[:, None, None]
    h[:, 2, 2] += w0
    g = np.stack([-sxr, -syr, -sr], axis=1) / s2[:, None]
    g[:, 2] += w0 * (p[:, 2] - r0)
    return h, g


def fit_circles(xy: np.ndarray, starts: np.ndarray, sensor_xy: tuple[float, float], r0: float, r0_sigma: float,
                noise_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per segment (points ``xy[starts[i]:starts[i+1]]``, m; at least 3 each): (S, 3) centre and radius (m),
    (S, 3, 3) their covariance (m²) and (S,) whether the fit succeeded."""
    m = len(xy)
    n = np.diff(np.append(starts, m)).astype(float)
    seg = np.repeat(np.arange(len(starts)), n.astype(int))
    p = _starts(xy, starts, n, seg, sensor_xy, r0)
    w0 = 1.0 / (r0_sigma * r0_sigma)
    ok = np.ones(len(starts), dtype=bool)
    for _ in range(GN_STEPS):
        h, g = _normal(xy, starts, n, seg, p, noise_m, r0, w0)
        with np.errstate(invalid="ignore", over="ignore"):
            ok &= np.isfinite(h).all(axis=(1, 2)) & (np.abs(np.linalg.det(h)) > 1e-300)
            h[~ok] = np.eye(3)
            g[~ok] = 0.0
            step = np.linalg.solve(h, g[:, :, None])[:, :, 0]
        p = p - step
        ok &= np.isfinite(p).all(axis=1) & (p[:, 2] > 0.0)
        p[~ok] = np.array([0.0, 0.0, 1.0])
        if float(np.max(np.sum(step * step, axis=1), initial=0.0)) < 1e-10:
            break
    h, _ = _normal(xy, starts, n, seg, p, noise_m, r0, w0)
    h[~ok] = np.eye(3)
    return p, np.linalg.inv(h), ok


def residual_ss(xy: np.ndarray, starts: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(S,) per segment sum of squared geometric residuals (m²): distance of each point to its segment's circle
    ``p`` (S, 3: cx, cy, r; m) minus the radius."""
    n = np.diff(np.append(starts, len(xy))).astype(int)
    seg = np.repeat(np.arange(len(starts)), n)
    res = np.hypot(xy[:, 0] - p[seg, 0], xy[:, 1] - p[seg, 1]) - p[seg, 2]
    return _sums(res * res, starts)
