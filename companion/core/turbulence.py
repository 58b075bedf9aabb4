"""Physical wind for the simulators: a mean wind, Dryden turbulence and a 1-cosine discrete gust (pure).

Only the simulated world reads this (the bundled vehicle and the in-process runner); the companion never
does. Velocities are NED (z down), m/s, the velocity *of the air* (where it blows TO).

**Mean wind**: ``mean_speed_mps`` from ``direction_deg`` — the direction it blows FROM, clockwise from north,
as meteorologists say (``direction_deg = 270`` is a westerly: the air moves east, +y).

**Dryden turbulence** (MIL-F-8785C §3.7.2.1, low altitude, h in ft, 10 ft <= h <= 1000 ft)::

    L_w = h            L_u = L_v = h / (0.177 + 0.000823·h)^1.2
    σ_w = 0.1·W20      σ_u = σ_v = σ_w / (0.177 + 0.000823·h)^0.4

W20 is the wind speed at 20 ft: light 15 kt, moderate 30 kt, severe 45 kt (MIL-F-8785C Fig. 11,
MIL-HDBK-1797 §4.9.2), unless the mission gives ``w20_mps``. One-sided spectra in ω (rad/s), frozen
turbulence carried past the vehicle at V (the mean wind speed, floored at 1 m/s: a hovering multirotor has no
airspeed of its own to carry it, and V → 0 would make the correlation times infinite)::

    Φ_u(ω) = σ_u²·(2L_u/πV) / (1 + (L_u·ω/V)²)
    Φ_v(ω) = σ_v²·(L_v/πV)·(1 + 3(L_v·ω/V)²) / (1 + (L_v·ω/V)²)²      (w likewise with L_w, σ_w)

i.e. the autocorrelations R_u(τ) = σ_u²·e^(−τ/T_u) and R_v(τ) = σ_v²·(1 − τ/(2T_v))·e^(−τ/T_v), T = L/V.
u lies along the mean wind (along ``direction_deg`` when calm), v across it (horizontal), w vertical.
The shaping filters H_u = σ_u·√(2T_u)/(1 + T_u·s) and H_v = σ_v·√T_v·(1 + √3·T_v·s)/(1 + T_v·s)² are driven by
unit white noise and discretised exactly (zero-order-hold-free: the state transition e^(A·dt) and the noise
covariance ∫e^(Aτ)BBᵀe^(Aᵀτ)dτ in closed form), started in their stationary distribution, sampled every
:data:`TABLE_DT_S` and seeded (``seed``): the same seed gives the same bits. The altitude is fixed
(``altitude_m``): the flights stay within a few metres of it.

**Discrete gust** (MIL-F-8785C §3.7.2.2, 1-cosine): along the mean wind, starting at ``gust_start_s``::

    v(x) = 0 (x < 0),  A/2·(1 − cos(π·x/d)) (0 <= x <= d),  A (x > d),   x = V·(t − t_start)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KNOT_MPS = 0.514444
FT_M = 0.3048
#: W20 (m/s) of each turbulence intensity, MIL-F-8785C low altitude: 15, 30, 45 kt.
W20_BY_INTENSITY = {"none": 0.0, "light": 15.0 * KNOT_MPS, "moderate": 30.0 * KNOT_MPS, "severe": 45.0 * KNOT_MPS}
#: Sample period of the wind table (s); the simulators interpolate linearly between samples.
TABLE_DT_S = 0.01
MIN_ADVECTION_MPS = 1.0
_CHUNK = 1000  # samples generated at a time (10 s): fixed, so the bits never depend on how far anyone looked


@dataclass(frozen=True)
class DrydenParams:
    """σ (m/s) and length scales L (m) of the three components u, v, w."""

    sigma_u: float
    sigma_v: float
    sigma_w: float
    L_u: float
    L_v: float
    L_w: float


def dryden_low_altitude(w20_mps: float, altitude_m: float) -> DrydenParams:
    """MIL-F-8785C low-altitude Dryden σ and L for the 20 ft wind ``w20_mps`` at ``altitude_m`` (clamped to
    the model's 10–1000 ft)."""
    h = min(max(altitude_m / FT_M, 10.0), 1000.0)
    k = 0.177 + 0.000823 * h
    sigma_w = 0.1 * w20_mps
    sigma_uv = sigma_w / k**0.4
    l_uv = h / k**1.2 * FT_M
    return DrydenParams(sigma_uv, sigma_uv, sigma_w, l_uv, l_uv, h * FT_M)


def first_order_step(tau_s: float, dt_s: float) -> tuple[float, float]:
    """Exact discretisation of H_u (unit variance): x ← a·x + b·n with a = e^(−dt/T), b = √(1 − a²)."""
    a = math.exp(-dt_s / tau_s)
    return a, math.sqrt(1.0 - a * a)


def second_order_step(tau_s: float, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of (1 + √3·T·s)/(1 + T·s)² driven by unit white noise, with output scaled to unit
    variance: returns (Φ (2,2), chol(Q_d) (2,2), C (2,), chol(P∞) (2,2)) for x ← Φ·x + chol(Q_d)·n, y = C·x.

    State: x1'' + 2a·x1' + a²·x1 = n (a = 1/T), y = √T·(a²·x1 + √3·a·x1'). P∞ = diag(1/(4a³), 1/(4a)).
    """
    a = 1.0 / tau_s
    h = dt_s
    e = math.exp(-a * h)
    phi = e * np.array([[1.0 + a * h, h], [-a * a * h, 1.0 - a * h]])
    p_inf = np.diag([1.0 / (4.0 * a**3), 1.0 / (4.0 * a)])
    q_d = p_inf - phi @ p_inf @ phi.T  # exact for a stationary process: P∞ = Φ·P∞·Φᵀ + Q_d
    q_d = 0.5 * (q_d + q_d.T)
    c = math.sqrt(tau_s) * np.array([a * a, math.sqrt(3.0) * a])
    return phi, np.linalg.cholesky(q_d), c, np.linalg.cholesky(p_inf)


def wind_axes(direction_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (NED) along which the air moves for a wind FROM ``direction_deg`` and across it."""
    d = math.radians(direction_deg)
    along = np.array([-math.cos(d), -math.sin(d), 0.0])
    return along, np.array([-along[1], along[0], 0.0])


def gust_speed(t_s: float, amplitude_mps: float, length_m: float, start_s: float, v_mps: float) -> float:
    """MIL-F-8785C 1-cosine gust speed (m/s) at time ``t_s``, advected at ``v_mps``."""
    x = v_mps * (t_s - start_s)
    if amplitude_mps == 0.0 or x < 0.0:
        return 0.0
    if x > length_m:
        return amplitude_mps
    return 0.5 * amplitude_mps * (1.0 - math.cos(math.pi * x / length_m))


class DrydenSampler:
    """Seeded Dryden u, v, w samples every ``dt_s`` (m/s), generated in fixed chunks (deterministic)."""

    def __init__(self, p: DrydenParams, v_mps: float, seed: int, dt_s: float = TABLE_DT_S) -> None:
        self.p, self.dt_s = p, dt_s
        self._rng = np.random.default_rng(seed)
        self._u = first_order_step(p.L_u / v_mps, dt_s)
        self._v = second_order_step(p.L_v / v_mps, dt_s)
        self._w = second_order_step(p.L_w / v_mps, dt_s)
        n0 = self._rng.standard_normal(5)  # the stationary start
        self._xu = float(n0[0])
        self._xv = self._v[3] @ n0[1:3]
        self._xw = self._w[3] @ n0[3:5]

    def chunk(self) -> np.ndarray:
        """The next :data:`_CHUNK` samples (n, 3): u, v, w in m/s (σ-scaled)."""
        noise = self._rng.standard_normal((_CHUNK, 5))
        out = np.empty((_CHUNK, 3))
        au, bu = self._u
        xu = self._xu
        for k in range(_CHUNK):
            out[k, 0] = xu
            xu = au * xu + bu * noise[k, 0]
        self._xu = xu
        self._xv = _second_order_run(self._v, self._xv, noise[:, 1:3], out[:, 1])
        self._xw = _second_order_run(self._w, self._xw, noise[:, 3:5], out[:, 2])
        out *= np.array([self.p.sigma_u, self.p.sigma_v, self.p.sigma_w])
        return out


def _second_order_run(step: tuple, x: np.ndarray, noise: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Run one second-order filter over ``noise`` (n, 2), writing unit-variance outputs to ``out``."""
    phi, lq, c, _ = step
    xs = np.empty((len(noise), 2))
    for k in range(len(noise)):
        xs[k] = x
        x = phi @ x + lq @ noise[k]
    out[:] = xs @ c
    return x


class WindField:
    """The wind velocity (NED, m/s) over time for a physical wind configuration, as a growing table.

    ``cfg`` is a :class:`companion.core.wind.WindConfig` with ``model == "turbulence"``.
    """

    def __init__(self, cfg) -> None:
        self.cfg = cfg
        self.along, self.across = wind_axes(cfg.direction_deg)
        self.v_adv = max(cfg.mean_speed_mps, MIN_ADVECTION_MPS)
        w20 = cfg.w20_mps if cfg.w20_mps > 0.0 else W20_BY_INTENSITY[cfg.intensity]
        self.dryden = dryden_low_altitude(w20, cfg.altitude_m)
        self._sampler = DrydenSampler(self.dryden, self.v_adv, cfg.seed) if w20 > 0.0 else None
        self.table = np.empty((0, 3))

    def _extend(self) -> None:
        n = len(self.table)
        t = (n + np.arange(_CHUNK)) * TABLE_DT_S
        c = self.cfg
        g = np.array([gust_speed(tk, c.gust_amplitude_mps, c.gust_length_m, c.gust_start_s, self.v_adv) for tk in t])
        turb = self._sampler.chunk() if self._sampler is not None else np.zeros((_CHUNK, 3))
        along = c.mean_speed_mps + g + turb[:, 0]
        new = along[:, None] * self.along + turb[:, 1:2] * self.across
        new[:, 2] += turb[:, 2]
        self.table = np.concatenate([self.table, new])

    def cover(self, t_s: float) -> np.ndarray:
        """The table (n, 3), sample k at k·:data:`TABLE_DT_S` seconds, long enough to interpolate at ``t_s``."""
        while (len(self.table) - 2) * TABLE_DT_S <= t_s:
            self._extend()
        return self.table

    def velocity(self, t_s: float) -> np.ndarray:
        """Wind velocity (NED, m/s) at ``t_s`` >= 0, linearly interpolated between samples."""
        tab = self.cover(t_s)
        x = max(t_s, 0.0) / TABLE_DT_S
        i = int(x)
        f = x - i
        return (1.0 - f) * tab[i] + f * tab[i + 1]
