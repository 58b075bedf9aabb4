"""The physical wind's drag on the bundled vehicle, as a compiled kernel of its physics step.

Quadratic drag F = k·|v_rel|·v_rel (k = ½·ρ·C_d·A, N per (m/s)²; v_rel = wind − the point's velocity) on the
airframe's centre of mass and on the payload point; the generalised forces follow from the two positions'
Jacobians w.r.t. q (see :mod:`companion.core.wind` and docs/model-derivation.md): Q_ξ = F_a + F_p,
Q_η = 0, Q_(α,β) = Jᵀ·F_p. The wind is read from a table (NED m/s, a sample every ``tab_dt`` s from t = 0,
:class:`companion.core.turbulence.WindField`), interpolated linearly, and held over one physics step.
"""

from __future__ import annotations

import math
from pathlib import Path

from numba import njit

from companion.core.kernel_cache import use_kernel_cache

# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__))


@njit(cache=True)
def _drag_disturbance(x, t, wtab, tab_dt, k, l, slack, landed, d):  # pragma: no cover - compiled
    """Write the generalised disturbance (8,) of quadratic drag into ``d``: k[0]·|v|·v on the airframe and
    (taut cable only) k[1]·|v|·v on the payload, v = wind − the point's velocity; the payload's force enters
    the swing channels through Jᵀ (see :func:`companion.core.wind.generalized_drag`). Zero on the ground."""
    for i in range(8):
        d[i] = 0.0
    if landed:
        return
    s = max(t, 0.0) / tab_dt
    i0 = min(int(s), wtab.shape[0] - 2)
    f = s - i0
    w0 = (1.0 - f) * wtab[i0, 0] + f * wtab[i0 + 1, 0]
    w1 = (1.0 - f) * wtab[i0, 1] + f * wtab[i0 + 1, 1]
    w2 = (1.0 - f) * wtab[i0, 2] + f * wtab[i0 + 1, 2]
    r0 = w0 - x[8]
    r1 = w1 - x[9]
    r2 = w2 - x[10]
    ka = k[0] * math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    d[0] = ka * r0
    d[1] = ka * r1
    d[2] = ka * r2
    if slack or k[1] == 0.0:
        return
    ca = math.cos(x[6])
    sa = math.sin(x[6])
    cb = math.cos(x[7])
    sb = math.sin(x[7])
    dal = x[14]
    dbe = x[15]
    # J = ∂r/∂(α, β) = l·[[cα cβ, −sα sβ], [0, −cβ], [−sα cβ, −cα sβ]]; payload velocity ξ̇ + J·ṡ
    r0 = w0 - (x[8] + l * (ca * cb * dal - sa * sb * dbe))
    r1 = w1 - (x[9] - l * cb * dbe)
    r2 = w2 - (x[10] + l * (-sa * cb * dal - ca * sb * dbe))
    kp = k[1] * math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    f0 = kp * r0
    f1 = kp * r1
    f2 = kp * r2
    d[0] += f0
    d[1] += f1
    d[2] += f2
    d[6] = l * (ca * cb * f0 - sa * cb * f2)
    d[7] = l * (-sa * sb * f0 - cb * f1 - ca * sb * f2)
