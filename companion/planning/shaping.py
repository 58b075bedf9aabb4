"""Swing-free shaping of a planned motion: the pendulum frequency, a smoothing cascade and the notch map.

Linearised about the hanging position, the payload's swing obeys (see :mod:`companion.control.position`)

    α̈ = −ω²·(α + a_x/g),    β̈ = −ω²·(β − a_y/g),

where a is the airframe's horizontal acceleration and ω depends on what is prescribed (both from the
Lagrangian of :mod:`companion.core.model`; :func:`pendulum_omega_rad_s`, tested against the model):

* the airframe's *acceleration* (a held or acceleration-controlled support): ω² = m·g·l / (m·l² + Ip) ≈ g/l
  (period 2.006 s for Table 1);
* the airframe's *force* (a free airframe at fixed thrust): the coupled two-body mode,
  ω² = m·g·l / (m·l²·M/(M+m) + Ip) ≈ g·(M+m)/(M·l) (period 1.831 s).

The position controller cancels the payload's reaction on the airframe (f of eq. 29, from the Lagrangian)
and commands an acceleration, so in closed loop the support is acceleration-controlled and the planner uses
the first (``support = "held"``); the coupled frequency is the one a force-level (open-loop) profile would
have to cancel. ``slungpilot``'s closed-loop check: ``tools``-free, see ``tests/test_planning_shaped.py``.

**Notch map.** Take a smooth *payload* trajectory p_L(t) (four times differentiable) and fly the airframe
along

    p_q = p_L + a_L/ω²,   i.e.   a_q = (1 + D²/ω²)·a_L.

Substituting a_q into the swing equation gives the particular solution α = −a_L,x/g, β = a_L,y/g exactly: a
payload starting at rest follows p_L with swing |θ| = |a_L|/g and *no free oscillation*; when a_L returns to
zero so does the swing (no residual). The operator 1 + s²/ω² has its zeros at s = ±jω: an input shaper with
an exact notch at the pendulum frequency — the continuous counterpart of the ZV shaper (whose
1 + e^(−sT/2) also vanishes at ±jω) without the ZV shaper's half-period (1.0 s) delay; instead the airframe
leads the payload by a_L/ω² (<= l·tan θ_max). The swing bound becomes an acceleration bound on the payload
path, |a_L| <= g·tan θ_max: the physical bound itself.

**Smoothing cascade.** The planned (unshaped) motion u(t) has a piecewise-constant acceleration (bang-bang
along the route). Three causal moving averages of widths τ1, τ2, τ3 (a quadratic B-spline kernel) make
p_L = F∗u four times differentiable: |a_L'| <= Δa/τ_min, |a_L''| <= Δa/(τ_i·τ_j), so the airframe's
acceleration a_L + a_L''/ω² and jerk stay bounded; averages never raise |a| above the unshaped bound
(convex combinations); the cascade delays the motion by (τ1 + τ2 + τ3)/2.

**Longer cables.** The lead's share, |a_L''|/ω² <= 4·max|a_u|/(τ2·τ3·ω²) (the L1 norm of the cascade's second
derivative), grows with the cable as 1/ω² ≈ l/g: with the widths of a 1 m cable, a 3 m cable's airframe reference
asks up to ~9 times the planned acceleration where re-plans change it at the cascade's rhythm (moderate
turbulence: 10-16 m/s² for 1.1 m/s² plans, issue 28). :func:`shaper_taus_s` scales the widths with the
pendulum's period beyond ``shaper_period_s`` (1 m), so the lead keeps the 1 m cable's share on every cable, at the
cost of a delay that grows with the period.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.model import VehicleParams

SUPPORTS = ("held", "free")
#: reference row layout: airframe p, v, a, jerk (2 each) and the nominal swing [α, β, α̇, β̇, α̈, β̈]
REF_COLS = 14


def pendulum_omega_rad_s(params: VehicleParams, support: str = "held") -> float:
    """Small-swing pendulum frequency ω (rad/s) from the model's Lagrangian (see module docstring).

    ``held``: airframe acceleration prescribed, ω² = m·g·l/(m·l² + Ip). ``free``: airframe force
    prescribed (two-body mode), ω² = m·g·l/(m·l²·M/(M+m) + Ip) ≈ g·(M+m)/(M·l).
    """
    p = params
    if support == "held":
        inertia = p.m * p.l * p.l + p.Ip
    elif support == "free":
        inertia = p.m * p.l * p.l * p.M / (p.M + p.m) + p.Ip
    else:
        raise ValueError(f"support: must be one of {', '.join(SUPPORTS)}, got {support!r}")
    return math.sqrt(p.m * p.g * p.l / inertia)


def shaper_taus_s(taus_s: tuple[float, ...], omega_rad_s: float, period_s: float) -> tuple[float, ...]:
    """The cascade's widths (s) for a pendulum of frequency ``omega_rad_s``: ``taus_s`` up to the period
    ``period_s``, scaled by the pendulum's period over it beyond (see module docstring, *Longer cables*)."""
    k = max(1.0, 2.0 * math.pi / omega_rad_s / period_s)
    return taus_s if k == 1.0 else tuple(k * t for t in taus_s)


def box_widths(taus_s: tuple[float, ...], h_s: float) -> tuple[int, int, int]:
    """Moving-average widths in samples (>= 1) of the three-stage cascade at step ``h_s`` (s)."""
    w = tuple(max(1, round(t / h_s)) for t in taus_s)
    if len(w) != 3:
        raise ValueError(f"shaper_tau_s: need three widths, got {taus_s!r}")
    return w  # type: ignore[return-value]


def cascade_lag(widths: tuple[int, int, int]) -> int:
    """Input rows the cascade needs before its first full output: Σ(w − 1)."""
    return sum(widths) - 3


use_kernel_cache(Path(__file__))


@njit(cache=True)
def _box(x, w, out):  # pragma: no cover - compiled
    """Causal moving average of width w along rows; rows < w−1 average what there is."""
    n, m = x.shape
    acc = np.zeros(m)
    for i in range(n):
        for c in range(m):
            acc[c] += x[i, c]
            if i >= w:
                acc[c] -= x[i - w, c]
            out[i, c] = acc[c] / min(i + 1, w)


@njit(cache=True)
def _shape(u, w1, w2, w3, k_notch, g, out):  # pragma: no cover - compiled
    """Reference rows from unshaped rows u (n, 6) = [p, v, a]: out (n, REF_COLS); see module docstring.

    Rows 0 .. Σ(w−1)+1 and the last two are not fully determined (window or central differences short)."""
    n = u.shape[0]
    t1 = np.empty((n, 6))
    t2 = np.empty((n, 6))
    t3 = np.empty((n, 6))
    _box(u, w1, t1)
    _box(t1, w2, t2)
    _box(t2, w3, t3)
    for i in range(n):
        lo = max(i - 2, 0)
        hi = min(i + 2, n - 1)
        im, ip = max(i - 1, 0), min(i + 1, n - 1)
        for c in range(2):
            a0 = t3[i, 4 + c]
            am1, ap1 = t3[im, 4 + c], t3[ip, 4 + c]
            am2, ap2 = t3[lo, 4 + c], t3[hi, 4 + c]
            jl = (ap1 - am1) * 0.5  # per step; scaled by the caller's step through k_notch and g
            sl = ap1 - 2.0 * a0 + am1
            cl = (ap2 - 2.0 * ap1 + 2.0 * am1 - am2) * 0.5
            out[i, c] = t3[i, c] + k_notch[0] * a0
            out[i, 2 + c] = t3[i, 2 + c] + k_notch[1] * jl
            out[i, 4 + c] = a0 + k_notch[2] * sl
            out[i, 6 + c] = jl * k_notch[3] + k_notch[4] * cl
            sign = -1.0 if c == 0 else 1.0
            out[i, 8 + c] = sign * a0 / g
            out[i, 10 + c] = sign * jl * k_notch[3] / g
            out[i, 12 + c] = sign * sl * k_notch[5] / g


def shape_reference(u: np.ndarray, widths: tuple[int, int, int], h_s: float, omega_rad_s: float,
                    g_mps2: float) -> np.ndarray:
    """Airframe reference and nominal swing (n, REF_COLS) from unshaped rows ``u`` (n, 6) = [p, v, a]
    sampled every ``h_s`` (see module docstring): [p_q, v_q, a_q, jerk_q, α, β, α̇, β̇, α̈, β̈] with
    p_q = F∗p + a_L/ω², v_q = F∗v + a_L'/ω², a_q = a_L + a_L''/ω², α = −a_L,x/g, β = a_L,y/g."""
    k = 1.0 / (omega_rad_s * omega_rad_s)
    coeffs = np.array([k, k / h_s, k / (h_s * h_s), 1.0 / h_s, k / h_s**3, 1.0 / (h_s * h_s)])
    out = np.empty((u.shape[0], REF_COLS))
    _shape(np.ascontiguousarray(u, dtype=np.float64), int(widths[0]), int(widths[1]), int(widths[2]), coeffs,
           float(g_mps2), out)
    return out
