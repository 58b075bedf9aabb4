"""Ground and cable contact of the bundled vehicle's physics (compiled kernels of its step).

The payload rests on the ground with the cable slack until the airframe is one cable length away; then the
cable snaps taut (a plastic impulse along it) and the coupled 8-DOF model takes over; a payload that reaches
the ground in flight stops there and the cable goes slack again (see :mod:`sim_bridge.physics`). ``pl`` is
[slack (1.0/0.0), payload x, y, z] (NED, m), updated in place.
"""

from __future__ import annotations

import math
from pathlib import Path

from numba import njit

from companion.core.kernel_cache import use_kernel_cache

# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__))


@njit(cache=True)
def _hold_on_ground(x, p, pl):  # pragma: no cover - compiled
    """Airframe held on the ground (level, at rest). A payload still on a taut cable below the ground plane
    (only a hand-made initial state can do that) is put down where it is."""
    for i in (3, 4, 8, 9, 10, 11, 12, 13):
        x[i] = 0.0
    if pl[0] < 0.5:
        _cable_contact(x, p, pl)


@njit(cache=True)
def _payload_angles(x, pl, l):  # pragma: no cover - compiled
    """While slack: α, β of the direction airframe → payload (0, 0 when it lies right below), rates 0."""
    rx = pl[1] - x[0]
    ry = pl[2] - x[1]
    rz = pl[3] - x[2]
    dist = math.sqrt(rx * rx + ry * ry + rz * rz)
    if dist > 1e-9:
        x[7] = math.asin(min(1.0, max(-1.0, -ry / dist)))
        x[6] = math.atan2(rx, rz) if abs(rx) + abs(rz) > 1e-12 else 0.0
    else:
        x[6] = 0.0
        x[7] = 0.0
    x[14] = 0.0
    x[15] = 0.0
    return dist


@njit(cache=True)
def _cable_contact(x, p, pl):  # pragma: no cover - compiled
    """Switch between the slack cable (payload on the ground) and the taut cable (coupled model).

    Slack → taut when the airframe is one cable length from the payload: a plastic impulse J along the cable
    unit vector e (airframe → payload) cancels the separating speed s = −v_q·e (payload at rest):
    J = s·M·m/(M+m), v_q += J/M·e, v_p = −J/m·e; α̇, β̇ from v_p − v_q (perpendicular to e) through the
    payload Jacobian, whose columns are orthogonal (JᵀJ = l²·diag(cβ², 1)).
    Taut → slack when the payload point reaches the ground plane z ≥ 0: it stops there.
    """
    big_m = p[0]
    m = p[1]
    l = p[7]
    if pl[0] > 0.5:
        dist = _payload_angles(x, pl, l)
        if dist < l:
            return
        al = x[6]
        be = x[7]
        ca = math.cos(al)
        sa = math.sin(al)
        cb = math.cos(be)
        sb = math.sin(be)
        e0 = sa * cb
        e1 = -sb
        e2 = ca * cb
        s = -(x[8] * e0 + x[9] * e1 + x[10] * e2)
        vp0 = 0.0
        vp1 = 0.0
        vp2 = 0.0
        if s > 0.0:
            jm = s * big_m * m / (big_m + m)
            x[8] += jm / big_m * e0
            x[9] += jm / big_m * e1
            x[10] += jm / big_m * e2
            vp0 = -jm / m * e0
            vp1 = -jm / m * e1
            vp2 = -jm / m * e2
        w0 = vp0 - x[8]
        w1 = vp1 - x[9]
        w2 = vp2 - x[10]
        # columns of J: ∂r/∂α = l[cα cβ, 0, −sα cβ], ∂r/∂β = l[−sα sβ, −cβ, −cα sβ]
        x[14] = (ca * cb * w0 - sa * cb * w2) / (l * max(cb * cb, 1e-9))
        x[15] = (-sa * sb * w0 - cb * w1 - ca * sb * w2) / l
        pl[0] = 0.0
        return
    zp = x[2] + l * math.cos(x[6]) * math.cos(x[7])
    if zp > 0.0:
        pl[0] = 1.0
        pl[1] = x[0] + l * math.sin(x[6]) * math.cos(x[7])
        pl[2] = x[1] - l * math.sin(x[7])
        pl[3] = 0.0
        _payload_angles(x, pl, l)
