"""From a route to a path the vehicle can fly fast: the minimum-curvature path inside the route's corridor.

The shortest route hugs the inflated discs with curvature 1/radius on every arc: flown at the lateral-
acceleration bound that means crawling. The route is resampled every ``ds`` metres and each point may move
along the route's normal, within the free interval between the discs; the offsets minimise
Σ|x[i−1] − 2x[i] + x[i+1]|² (squared curvature): a pentadiagonal quadratic programme with bounds, solved by an
active set with banded solves. Points only move along normals inside the free intervals, so the path keeps the
route's homotopy class, and it turns on the widest radii the corridor allows (the racing line's classic
minimum-curvature approximation of the fastest line). Timing along it: :mod:`companion.planning.timing`.

Compiled kernels (numba, cached); the Python wrappers only shape arrays.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache

use_kernel_cache(Path(__file__))


@njit(cache=True)
def _resample(p, ds):  # pragma: no cover - compiled
    n = p.shape[0]
    s = np.zeros(n)
    for i in range(1, n):
        s[i] = s[i - 1] + math.hypot(p[i, 0] - p[i - 1, 0], p[i, 1] - p[i - 1, 1])
    total = s[-1]
    m = max(2, math.ceil(total / ds) + 1) if total > 1e-9 else 1
    out = np.empty((m, 2))
    if m == 1:
        out[0] = p[0]
        return out
    j = 0
    for k in range(m):
        sk = total * k / (m - 1)
        while j < n - 2 and s[j + 1] < sk:
            j += 1
        seg = s[j + 1] - s[j]
        t = 0.0 if seg <= 1e-12 else min(1.0, max(0.0, (sk - s[j]) / seg))
        out[k, 0] = p[j, 0] + t * (p[j + 1, 0] - p[j, 0])
        out[k, 1] = p[j, 1] + t * (p[j + 1, 1] - p[j, 1])
    return out


@njit(cache=True)
def _solve_penta(a0, a1, a2, b):  # pragma: no cover - compiled
    """Solve the symmetric positive-definite pentadiagonal system (diagonals a0, a1, a2; rhs b (n, 2))."""
    n = len(a0)
    # LDLᵀ without pivoting (SPD), banded
    d = np.zeros(n)
    l1 = np.zeros(n)
    l2 = np.zeros(n)
    for i in range(n):
        v = a0[i]
        if i >= 1:
            v -= l1[i - 1] * l1[i - 1] * d[i - 1]
        if i >= 2:
            v -= l2[i - 2] * l2[i - 2] * d[i - 2]
        d[i] = v
        if i + 1 < n:
            w = a1[i]
            if i >= 1:
                w -= l2[i - 1] * l1[i - 1] * d[i - 1]
            l1[i] = w / v
        if i + 2 < n:
            l2[i] = a2[i] / v
    y = b.copy()
    for i in range(n):
        if i >= 1:
            y[i] -= l1[i - 1] * y[i - 1]
        if i >= 2:
            y[i] -= l2[i - 2] * y[i - 2]
    for i in range(n):
        y[i] /= d[i]
    for i in range(n - 1, -1, -1):
        if i + 1 < n:
            y[i] -= l1[i] * y[i + 1]
        if i + 2 < n:
            y[i] -= l2[i] * y[i + 2]
    return y


@njit(cache=True)
def _corridor(ref, nrm, cx, cy, r, d_max, skip):  # pragma: no cover - compiled
    """Free offsets [lo, hi] along each normal line through ref[k] (the interval that contains 0)."""
    n = ref.shape[0]
    lo = np.full(n, -d_max)
    hi = np.full(n, d_max)
    for k in range(n):
        for j in range(len(r)):
            if skip[j]:
                continue
            ox, oy = ref[k, 0] - cx[j], ref[k, 1] - cy[j]
            b = ox * nrm[k, 0] + oy * nrm[k, 1]
            c = ox * ox + oy * oy - r[j] * r[j]
            disc = b * b - c
            if disc <= 0.0:
                continue
            sq = math.sqrt(disc)
            d1, d2 = -b - sq, -b + sq
            if d2 <= 1e-9:
                lo[k] = max(lo[k], d2)
            elif d1 >= -1e-9:
                hi[k] = min(hi[k], d1)
            else:  # the reference point is inside this disc: stay put
                lo[k] = max(lo[k], 0.0)
                hi[k] = min(hi[k], 0.0)
        if lo[k] > hi[k]:
            lo[k] = hi[k] = 0.0
    return lo, hi


@njit(cache=True)
def _min_curvature(ref, nrm, lo, hi, n_fixed_start, tgt1x, tgt1y, w_head, rounds, wres):  # pragma: no cover
    """Offsets d minimising Σ wres[i]·|x[i−1] − 2x[i] + x[i+1]|² (x = ref + d·n) within [lo, hi] (active set)."""
    n = ref.shape[0]
    h0 = np.zeros(n)
    h1 = np.zeros(n)
    h2 = np.zeros(n)
    g = np.zeros(n)
    cf = np.array([1.0, -2.0, 1.0])
    for i in range(1, n - 1):  # residual i couples i−1, i, i+1 with coefficients 1, −2, 1
        rx = ref[i - 1, 0] - 2.0 * ref[i, 0] + ref[i + 1, 0]
        ry = ref[i - 1, 1] - 2.0 * ref[i, 1] + ref[i + 1, 1]
        wi = wres[i]
        for a in range(3):
            ka = i - 1 + a
            g[ka] += wi * cf[a] * (rx * nrm[ka, 0] + ry * nrm[ka, 1])
            h0[ka] += wi * cf[a] * cf[a]
            for b in range(a + 1, 3):
                kb = i - 1 + b
                v = wi * cf[a] * cf[b] * (nrm[ka, 0] * nrm[kb, 0] + nrm[ka, 1] * nrm[kb, 1])
                if kb - ka == 1:
                    h1[ka] += v
                else:
                    h2[ka] += v
    if n_fixed_start >= 2 and w_head > 0.0:
        h0[1] += w_head
        g[1] += w_head * ((ref[1, 0] - tgt1x) * nrm[1, 0] + (ref[1, 1] - tgt1y) * nrm[1, 1])
    state = np.zeros(n, np.int64)  # 0 free, 1 at lo, 2 at hi, 3 pinned at 0
    state[0] = 3
    state[n - 1] = 3
    d = np.zeros(n)
    for _ in range(rounds):
        a0 = h0 + 1e-9
        a1 = h1.copy()
        a2 = h2.copy()
        rhs = np.zeros((n, 2))
        for k in range(n):
            rhs[k, 0] = -g[k]
        for k in range(n):
            if state[k] == 0:
                continue
            val = 0.0 if state[k] == 3 else (lo[k] if state[k] == 1 else hi[k])
            for j in range(max(0, k - 2), min(n, k + 3)):
                if j == k or state[j] != 0:
                    continue
                m = min(j, k)
                coef = h1[m] if abs(j - k) == 1 else h2[m]
                rhs[j, 0] -= coef * val
            a0[k] = 1.0
            rhs[k, 0] = val
            if k >= 1:
                a1[k - 1] = 0.0
            if k + 1 < n:
                a1[k] = 0.0
            if k >= 2:
                a2[k - 2] = 0.0
            if k + 2 < n:
                a2[k] = 0.0
        y = _solve_penta(a0, a1, a2, rhs)
        changed = False
        for k in range(n):
            if state[k] == 0:
                if y[k, 0] < lo[k] - 1e-9:
                    state[k] = 1
                    changed = True
                elif y[k, 0] > hi[k] + 1e-9:
                    state[k] = 2
                    changed = True
            d[k] = y[k, 0] if state[k] == 0 else (0.0 if state[k] == 3 else (lo[k] if state[k] == 1 else hi[k]))
        if not changed:
            # release bounds whose gradient points back into the interval
            for k in range(1, n - 1):
                if state[k] == 1 or state[k] == 2:
                    gk = g[k] + h0[k] * d[k]
                    if k >= 1:
                        gk += h1[k - 1] * d[k - 1]
                    if k + 1 < n:
                        gk += h1[k] * d[k + 1]
                    if k >= 2:
                        gk += h2[k - 2] * d[k - 2]
                    if k + 2 < n:
                        gk += h2[k] * d[k + 2]
                    if (state[k] == 1 and gk < -1e-9) or (state[k] == 2 and gk > 1e-9):
                        state[k] = 0
                        changed = True
            if not changed:
                break
    return d


def resample(points: np.ndarray, ds_m: float) -> np.ndarray:
    """The polyline ``points`` (n, 2) resampled at uniform arc length (about ``ds_m``), ends kept."""
    return _resample(np.ascontiguousarray(points, dtype=np.float64), float(ds_m))


def smooth_path(points: np.ndarray, centers: np.ndarray, radii: np.ndarray, *, ds_m: float = 0.4,
                heading: np.ndarray | None = None, d_max_m: float = 4.0, w_heading: float = 50.0,
                rounds: int = 30) -> np.ndarray:
    """Minimum-curvature path in the route's corridor (see module docstring); points (n, 2) about ``ds_m``
    apart, from the route's start to its goal.

    Each point of the resampled route may move along the route's normal within the free interval between
    the discs (at most ``d_max_m``); the offsets minimise Σ|x[i−1] − 2x[i] + x[i+1]|², a pentadiagonal
    quadratic programme with bounds solved by an active set. ``heading`` (unit (2,)) pulls the first step
    along the current velocity (weight ``w_heading``). Discs that contain the start or the goal do not bound
    (the route search shrank them there).
    """
    return smooth_path_pinned(points, centers, radii, ds_m=ds_m, heading=heading, d_max_m=d_max_m,
                              w_heading=w_heading, rounds=rounds)[0]


def smooth_path_pinned(points: np.ndarray, centers: np.ndarray, radii: np.ndarray, *, ds_m: float = 0.4,
                       heading: np.ndarray | None = None, d_max_m: float = 4.0, w_heading: float = 50.0,
                       rounds: int = 30, pins_s_m: tuple[float, ...] = (), pin_m: float = 0.3
                       ) -> tuple[np.ndarray, list[int]]:
    """:func:`smooth_path`, with the points at arc lengths ``pins_s_m`` (m along ``points``: waypoints flown
    through) kept within ``pin_m`` of the route; also returns the index of each pinned point in the path."""
    ref = resample(points, ds_m)
    n = len(ref)
    seg = np.hypot(*np.diff(np.asarray(points, dtype=np.float64), axis=0).T)
    total = float(np.sum(seg))
    pins = [min(n - 1, max(0, round(sp / total * (n - 1)))) if total > 1e-9 else 0 for sp in pins_s_m]
    if n < 4:
        return ref, pins
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    r = np.ascontiguousarray(np.asarray(radii, dtype=np.float64).reshape(-1))
    tan = np.empty_like(ref)
    tan[1:-1] = ref[2:] - ref[:-2]
    tan[0] = ref[1] - ref[0]
    tan[-1] = ref[-1] - ref[-2]
    tan /= np.maximum(np.hypot(tan[:, 0], tan[:, 1]), 1e-12)[:, None]
    nrm = np.ascontiguousarray(np.stack([-tan[:, 1], tan[:, 0]], axis=1))
    skip = np.zeros(len(r), np.bool_)
    for e in (0, n - 1):
        skip |= np.hypot(c[:, 0] - ref[e, 0], c[:, 1] - ref[e, 1]) < r - 1e-6
    lo, hi = _corridor(ref, nrm, np.ascontiguousarray(c[:, 0]), np.ascontiguousarray(c[:, 1]), r, float(d_max_m),
                       skip)
    for k in pins:
        lo[k], hi[k] = max(lo[k], -pin_m), min(hi[k], pin_m)
    if heading is not None:
        tgt = ref[0] + float(np.hypot(*(ref[1] - ref[0]))) * np.asarray(heading, dtype=np.float64)
        nfix, tx, ty = 2, float(tgt[0]), float(tgt[1])
    else:
        nfix, tx, ty = 1, 0.0, 0.0
    wres = np.ones(n)
    d = _min_curvature(ref, nrm, lo, hi, nfix, tx, ty, float(w_heading), int(rounds), np.ascontiguousarray(wres))
    return ref + d[:, None] * nrm, pins


def path_clear(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> float:
    """Smallest clearance (m) of the polyline's vertices and segment midpoints to the discs (negative: inside)."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    if len(c) == 0:
        return math.inf
    p = np.asarray(points)
    pts = np.concatenate([p, 0.5 * (p[1:] + p[:-1])])
    d = np.hypot(pts[:, None, 0] - c[None, :, 0], pts[:, None, 1] - c[None, :, 1]) - np.asarray(radii)[None, :]
    return float(d.min())
