"""Payload identification: cable length and payload mass from a few seconds of IMU and attitude data.

The airframe's Newton equation in the body frame, with the cable force from the payload's own equation
(t·r̂ = m·(g·e_z − a − r̈), a = ξ̈ the airframe's acceleration, r the payload offset) and the accelerometer's
specific force f_b = Rᵀ·(a − g·e_z)::

    M·f_b = −T·e_z + m·Rᵀ·(g·e_z − a − r̈) + Rᵀ·d = −T·e_z − m·f_b − m·Rᵀ·r̈ + Rᵀ·d

Its two lateral rows contain no thrust at all (the rotors push along z_body only)::

    f_b,xy = −μ·(Rᵀ·r̈)_xy + (Rᵀ·d)_xy/(M+m),        μ = m/(M+m)

and r̈ follows from the pendulum driven by the pivot acceleration the same accelerometer measures,
a = R·f_b + g·e_z. So for a candidate cable length l we integrate the pendulum (the model's swing equation with
ξ̈ = a given: (m·JᵀJ + Ip)·s̈ = m·Jᵀ·(g·e_z − a − J̇ṡ), Ip → 0) from rest, and fit the lateral specific force
by linear least squares in μ, a slow disturbance (constant + linear trend per axis) and a free oscillation at
ω = √(g/l) (the swing that was already there when the window starts; its amplitude is free). The residual is
a function of l alone; a grid search and a golden-section refinement find its minimum. The mass follows as
m = μ·M/(1 − μ) with the vehicle's own mass M known. Both sides are low-passed (zero phase, 3 Hz): the payload
does not follow vibration. r̈ contains −a, so accelerometer noise below that cut-off is on both sides of the
fit and biases μ up (errors in variables): with PX4 SIH's 1.7 m/s² per-sample noise the mass comes out ~3×
too large and the fit is flagged not ok (an alternative regressor, the payload's own specific force, removes
that bias but correlates with the wind-induced tilt and biases the mass low by ~20 % under eq. 49's wind; we
keep the one that is better for a clean IMU).

Needs: an excitation (a lateral move: a step or doublet of a metre at hover, or the first seconds of a
mission's cruise) that swings the payload by ~0.1 rad or more, IMU specific force and attitude (no thrust, no
position). Accuracy (``tests/test_payload_id.py`` on the bundled physics, eq. 49 wind, PX4-SITL-like IMU noise,
`python -m lab.swing_bench`): see ``docs/swing-estimation.md``.

The alternative the issue mentions, mass from the hover thrust (``mass_from_hover_thrust``), is given too; it
depends on the thrust being calibrated in newtons and is biased by any vertical force (eq. 49's wind pushes
down by 0.23 N on average: +0.023 kg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.estimation.swing_model import rotation_from_euler

use_kernel_cache(Path(__file__))

_GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)


@dataclass(frozen=True, slots=True)
class PayloadId:
    """Identified payload.

    cable_length_m, payload_mass_kg: the estimates; mass_ratio: μ = m/(M+m); cable_length_sigma_m and
    payload_mass_sigma_kg: 1σ from the least-squares statistics (residual-based, optimistic when the residual is
    not white); swing_signal_mps2: RMS of the fitted swing term μ·(Rᵀr̈)_xy; residual_mps2: RMS of what the
    fit leaves; ok: enough excitation (swing signal > 3× residual) and l not at the search limits; reason:
    why not when not ok; residual_tau: the residual's integrated autocorrelation time (samples, >= 1): the σ
    above treat the residual as white, a coloured one (wind, not sensor noise) makes them √residual_tau too small.
    """

    cable_length_m: float
    payload_mass_kg: float
    mass_ratio: float
    cable_length_sigma_m: float
    payload_mass_sigma_kg: float
    swing_signal_mps2: float
    residual_mps2: float
    n_samples: int
    window_s: float
    ok: bool
    reason: str = ""
    residual_tau: float = 1.0


def butter2(wn: float) -> tuple[np.ndarray, np.ndarray]:
    """A 2nd-order Butterworth low-pass (b, a) for the cut-off ``wn`` as a fraction of Nyquist (0 < wn < 1): the
    bilinear transform with pre-warping, as ``scipy.signal.butter(2, wn)`` gives it (importing scipy.signal costs a
    flight ~1 s; ``tests/test_payload_id.py`` holds the two equal)."""
    k = math.tan(0.5 * math.pi * wn)
    n = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * n
    return (np.array([b0, 2.0 * b0, b0]),
            np.array([1.0, 2.0 * (k * k - 1.0) * n, (1.0 - math.sqrt(2.0) * k + k * k) * n]))


@njit(cache=True, nogil=True)
def _lfilter2(b, a, x, z0, z1):  # pragma: no cover - compiled
    """A 2nd-order IIR over ``x`` (transposed direct form II) from the state (z0, z1); a new array."""
    y = np.empty_like(x)
    for n in range(len(x)):
        yn = b[0] * x[n] + z0
        z0 = b[1] * x[n] - a[1] * yn + z1
        z1 = b[2] * x[n] - a[2] * yn
        y[n] = yn
    return y


@njit(cache=True, nogil=True)
def _filtfilt2(b, a, x):  # pragma: no cover - compiled
    """Zero-phase 2nd-order IIR along axis 0 of ``x`` (N, k), as ``scipy.signal.filtfilt(b, a, x, axis=0)``:
    odd extension by 9 samples at each end, each pass started in its steady state for the first sample."""
    edge = 9
    s = a[0] + a[1] + a[2]
    zi0 = ((b[1] - a[1] * b[0]) + (b[2] - a[2] * b[0])) / s
    zi1 = (b[2] - a[2] * b[0]) - a[2] * zi0
    n = x.shape[0]
    out = np.empty_like(x)
    for c in range(x.shape[1]):
        ext = np.empty(n + 2 * edge)
        for i in range(edge):
            ext[i] = 2.0 * x[0, c] - x[edge - i, c]
            ext[n + edge + i] = 2.0 * x[n - 1, c] - x[n - 2 - i, c]
        ext[edge:edge + n] = x[:, c]
        y = _lfilter2(b, a, ext, zi0 * ext[0], zi1 * ext[0])
        y = _lfilter2(b, a, y[::-1].copy(), zi0 * y[-1], zi1 * y[-1])[::-1]
        out[:, c] = y[edge:edge + n]
    return out


@njit(cache=True, nogil=True)
def _pendulum_acc(al, be, dal, dbe, ax, ay, az, l, g):  # pragma: no cover - compiled
    """(α̈, β̈, r̈ north, east, down) of the point payload for swing (α, β, α̇, β̇) and pivot acceleration a."""
    sa, ca, sb, cb = math.sin(al), math.cos(al), math.sin(be), math.cos(be)
    # (JᵀJ)·s̈ = Jᵀ·(g·e_z − a − a_c) with JᵀJ = l²·diag(cβ², 1)
    ac0 = l * (-sa * cb * (dal * dal + dbe * dbe) - 2.0 * ca * sb * dal * dbe)
    ac1 = l * sb * dbe * dbe
    ac2 = l * (-ca * cb * (dal * dal + dbe * dbe) + 2.0 * sa * sb * dal * dbe)
    w0, w1, w2 = -ax - ac0, -ay - ac1, g - az - ac2
    dda = (ca * cb * w0 - sa * cb * w2) / (l * max(cb * cb, 1e-6))
    ddb = (-sa * sb * w0 - cb * w1 - ca * sb * w2) / l
    # relative acceleration r̈ = J·s̈ + a_c
    p0 = l * (ca * cb * dda - sa * sb * ddb) + ac0
    p1 = -l * cb * ddb + ac1
    p2 = l * (-sa * cb * dda - ca * sb * ddb) + ac2
    return dda, ddb, p0, p1, p2


@njit(cache=True, nogil=True)
def _relative_accel(a_ned, R, t, l, g):  # pragma: no cover - compiled
    """(Rᵀ·r̈)_xy (N, 2): the payload's acceleration relative to the pivot, seen in the body frame, for a point
    payload on a rigid cable of length l hanging from rest from a pivot with acceleration a_ned (N, 3), integrated
    with RK4 over the samples (a linear in between). All NaN when the swing leaves ±1.5 rad. Compiled without the
    GIL: a flight identifies beside its control loop."""
    n = len(t)
    out = np.zeros((n, 2))
    al = be = dal = dbe = 0.0
    for k in range(n):
        ax, ay, az = a_ned[k, 0], a_ned[k, 1], a_ned[k, 2]
        _, _, p0, p1, p2 = _pendulum_acc(al, be, dal, dbe, ax, ay, az, l, g)
        out[k, 0] = R[k, 0, 0] * p0 + R[k, 1, 0] * p1 + R[k, 2, 0] * p2
        out[k, 1] = R[k, 0, 1] * p0 + R[k, 1, 1] * p1 + R[k, 2, 1] * p2
        if k + 1 < n:  # classical RK4 on (α, β, α̇, β̇), the pivot acceleration linear between samples
            h = t[k + 1] - t[k]
            bx, by, bz = a_ned[k + 1, 0], a_ned[k + 1, 1], a_ned[k + 1, 2]
            mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
            k1a, k1b, _, _, _ = _pendulum_acc(al, be, dal, dbe, ax, ay, az, l, g)
            a2, b2, da2, db2 = al + 0.5 * h * dal, be + 0.5 * h * dbe, dal + 0.5 * h * k1a, dbe + 0.5 * h * k1b
            k2a, k2b, _, _, _ = _pendulum_acc(a2, b2, da2, db2, mx, my, mz, l, g)
            a3, b3, da3, db3 = al + 0.5 * h * da2, be + 0.5 * h * db2, dal + 0.5 * h * k2a, dbe + 0.5 * h * k2b
            k3a, k3b, _, _, _ = _pendulum_acc(a3, b3, da3, db3, mx, my, mz, l, g)
            a4, b4, da4, db4 = al + h * da3, be + h * db3, dal + h * k3a, dbe + h * k3b
            k4a, k4b, _, _, _ = _pendulum_acc(a4, b4, da4, db4, bx, by, bz, l, g)
            al += h / 6.0 * (dal + 2.0 * da2 + 2.0 * da3 + da4)
            be += h / 6.0 * (dbe + 2.0 * db2 + 2.0 * db3 + db4)
            dal += h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a)
            dbe += h / 6.0 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
            if not (abs(be) < 1.5 and abs(al) < 1.5):
                return out * np.nan
    return out


def _design(t: np.ndarray, p: np.ndarray, R: np.ndarray, l: float, g: float) -> np.ndarray:
    """Columns: −(Rᵀr̈)_xy (coefficient μ), a free swing along north and east (cos, sin each: 4), per body axis a
    constant and a trend (4); rows: x samples then y samples."""
    n = len(t)
    w = math.sqrt(g / l)
    tt = t - t[0]
    c, s = np.cos(w * tt), np.sin(w * tt)
    X = np.zeros((2 * n, 9))
    X[:n, 0] = -p[:, 0]
    X[n:, 0] = -p[:, 1]
    # a swing already there at the window's start, r = A·cos + B·sin along north (0) and east (1), adds
    # r̈ = −ω²·r, seen in body axes via Rᵀ
    col = 1
    for axis in (0, 1):
        for basis in (c, s):
            rdd = -w * w * basis
            X[:n, col] = -R[:, axis, 0] * rdd
            X[n:, col] = -R[:, axis, 1] * rdd
            col += 1
    span = max(tt[-1], 1e-9)
    X[:n, 5] = 1.0
    X[:n, 6] = tt / span
    X[n:, 7] = 1.0
    X[n:, 8] = tt / span
    return X


def _fit(t, f_xy, a_ned, R, l, g):
    p = _relative_accel(a_ned, R, t, float(l), float(g))
    if not np.all(np.isfinite(p)):
        return math.inf, None, None, None
    X = _design(t, p, R, l, g)
    y = np.concatenate([f_xy[:, 0], f_xy[:, 1]])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ coef
    return float(res @ res), coef, X, res


def _checked(t_s, accel_frd_mps2, euler_rad, vehicle_mass_kg: float, g_mps2: float,
             l_range_m: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`identify_payload`'s samples as float arrays (t, accel, euler); ValueError when they or the settings
    cannot be used."""
    t = np.asarray(t_s, dtype=np.float64)
    f = np.asarray(accel_frd_mps2, dtype=np.float64)
    e = np.asarray(euler_rad, dtype=np.float64)
    n = len(t)
    if n < 50 or f.shape != (n, 3) or e.shape != (n, 3):
        raise ValueError(f"need >= 50 samples of t (N,), accel (N, 3), euler (N, 3); got {t.shape}, {f.shape}, "
                         f"{e.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(f)) and np.all(np.isfinite(e))):
        raise ValueError("non-finite samples")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("t_s must increase")
    if not (vehicle_mass_kg > 0.0 and g_mps2 > 0.0 and 0.0 < l_range_m[0] < l_range_m[1]):
        raise ValueError("vehicle_mass_kg, g_mps2 must be > 0 and l_range_m increasing")
    return t, f, e


def _best_length(sse_of, l_range_m: tuple[float, float]) -> float:
    """The cable length (m) in ``l_range_m`` that minimises ``sse_of(l)`` (the fit's residual sum): a grid of 40
    in log(l), then golden section between the best point's neighbours (to 1e-4 relative, 30 steps at most)."""
    grid = np.exp(np.linspace(math.log(l_range_m[0]), math.log(l_range_m[1]), 40))
    sse = [(sse_of(float(lv)), float(lv)) for lv in grid]
    k = int(np.argmin([s for s, _ in sse]))
    lo = grid[max(k - 1, 0)]
    hi = grid[min(k + 1, len(grid) - 1)]
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1 = sse_of(x1)
    f2 = sse_of(x2)
    for _ in range(30):
        if f1 < f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - _GOLDEN * (hi - lo)
            f1 = sse_of(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + _GOLDEN * (hi - lo)
            f2 = sse_of(x2)
        if hi - lo < 1e-4 * hi:
            break
    return 0.5 * (lo + hi)


def _verdict(mu: float, m_hat: float, sigma_m: float, signal: float, resid: float, l_hat: float,
             l_range_m: tuple[float, float], M: float) -> str:
    """Why the identification is not to be used ("" when it is): no payload seen, mass not determined, too
    little excitation (swing signal under 3 × the residual, m/s²), or the cable length at the search limit."""
    if not (0.0 < mu < 1.0):
        return f"no payload seen (mass ratio {mu:.3f} outside (0, 1))"
    if m_hat > 10.0 * M or sigma_m > 0.3 * m_hat:
        return f"mass not determined: {m_hat:.3f} ± {sigma_m:.3f} kg"
    if signal < 3.0 * resid:
        return f"too little excitation: swing signal {signal:.3f} m/s² < 3 × residual {resid:.3f} m/s²"
    if l_hat < 1.05 * l_range_m[0] or l_hat > 0.95 * l_range_m[1]:
        return f"cable length {l_hat:.2f} m at the search limit {l_range_m}"
    return ""


def identify_payload(
    t_s,
    accel_frd_mps2,
    euler_rad,
    vehicle_mass_kg: float,
    g_mps2: float = 9.81,
    l_range_m: tuple[float, float] = (0.2, 5.0),
    pivot_cutoff_hz: float = 3.0,
) -> PayloadId:
    """Cable length and payload mass from samples of the accelerometer's specific force (N, 3; body FRD, m/s²)
    and the attitude (N, 3; ZYX Euler, rad) at times ``t_s`` (N,; s, increasing, near-uniform) over a window with
    a lateral excitation; ``vehicle_mass_kg`` is the airframe's mass M without payload. The pivot acceleration
    that drives the simulated pendulum is low-passed (zero phase, ``pivot_cutoff_hz``; 0 = off): the payload does
    not follow vibration (the specific force is filtered alike). Raises ValueError on bad input."""
    t, f, e = _checked(t_s, accel_frd_mps2, euler_rad, vehicle_mass_kg, g_mps2, l_range_m)
    n = len(t)
    R = np.array([rotation_from_euler(*row) for row in e])
    a = np.einsum("nij,nj->ni", R, f) + np.array([0.0, 0.0, g_mps2])
    if pivot_cutoff_hz > 0.0:
        fs = (n - 1) / (t[-1] - t[0])
        if pivot_cutoff_hz < 0.45 * fs:
            b, a_f = butter2(pivot_cutoff_hz / (0.5 * fs))
            a = _filtfilt2(b, a_f, np.ascontiguousarray(a))
            f = _filtfilt2(b, a_f, np.ascontiguousarray(f))
    f_xy = f[:, 0:2]
    l_hat = _best_length(lambda lv: _fit(t, f_xy, a, R, lv, g_mps2)[0], l_range_m)
    s0, coef, X, res = _fit(t, f_xy, a, R, l_hat, g_mps2)
    if coef is None:
        return PayloadId(math.nan, math.nan, math.nan, math.nan, math.nan, 0.0, math.nan, n, float(t[-1] - t[0]),
                         False, "the pendulum diverged for every cable length")
    mu = float(coef[0])
    dof = max(len(res) - X.shape[1] - 1, 1)
    s2 = s0 / dof
    try:
        cov = s2 * np.linalg.inv(X.T @ X)
        sigma_mu = math.sqrt(max(cov[0, 0], 0.0))
    except np.linalg.LinAlgError:
        sigma_mu = math.inf
    # σ_l from the curvature of the residual sum: SSE(l) ≈ SSE0 + ½·SSE''·δl², σ_l² = 2·s²/SSE''
    dl = 0.02 * l_hat
    sp = _fit(t, f_xy, a, R, l_hat + dl, g_mps2)[0]
    sm = _fit(t, f_xy, a, R, l_hat - dl, g_mps2)[0]
    curv = (sp - 2.0 * s0 + sm) / (dl * dl)
    sigma_l = math.sqrt(2.0 * s2 / curv) if curv > 0.0 else math.inf
    M = vehicle_mass_kg
    m_hat = mu * M / (1.0 - mu) if mu < 1.0 else math.inf
    sigma_m = sigma_mu * M / (1.0 - mu) ** 2 if mu < 1.0 else math.inf
    signal = float(np.sqrt(np.mean((coef[0] * X[:, 0]) ** 2)))
    resid = float(np.sqrt(np.mean(res * res)))
    reason = _verdict(mu, m_hat, sigma_m, signal, resid, l_hat, l_range_m, M)
    return PayloadId(
        cable_length_m=l_hat, payload_mass_kg=m_hat, mass_ratio=mu, cable_length_sigma_m=sigma_l,
        payload_mass_sigma_kg=sigma_m, swing_signal_mps2=signal, residual_mps2=resid, n_samples=n,
        window_s=float(t[-1] - t[0]), ok=not reason, reason=reason, residual_tau=autocorrelation_time(res, n),
    )


def autocorrelation_time(res: np.ndarray, n: int) -> float:
    """The integrated autocorrelation time (samples) of a residual stacked as two series of ``n`` (x, then y):
    1 + 2·Σρ_k up to the first lag whose correlation is not positive, the larger of the two."""
    out = 1.0
    for r in (res[:n], res[n:]):
        r = r - r.mean()
        spec = np.fft.rfft(r, 2 * len(r))
        acf = np.fft.irfft(spec * np.conj(spec))[: len(r)]
        if acf[0] <= 0.0:
            continue
        rho = acf[1:] / acf[0]
        stop = int(np.argmax(rho <= 0.0)) if np.any(rho <= 0.0) else len(rho)
        out = max(out, 1.0 + 2.0 * float(np.sum(rho[:stop])))
    return out


def mass_from_hover_thrust(thrust_n, vehicle_mass_kg: float, g_mps2: float = 9.81, accel_down_mps2=None) -> float:
    """Payload mass (kg) from the thrust that holds the vehicle: m = mean(T / (g − a_z)) − M (a_z: the airframe's
    downward acceleration, 0 in a steady hover). Only as good as the thrust's calibration in newtons, and biased
    by any vertical force: a downward push d_z adds d_z/g."""
    T = np.asarray(thrust_n, dtype=np.float64)
    az = np.zeros_like(T) if accel_down_mps2 is None else np.asarray(accel_down_mps2, dtype=np.float64)
    if T.size == 0 or T.shape != az.shape or not (np.all(np.isfinite(T)) and np.all(np.isfinite(az))):
        raise ValueError("thrust_n (and accel_down_mps2) must be non-empty, finite and of one shape")
    return float(np.mean(T / (g_mps2 - az))) - vehicle_mass_kg
