"""Euler–Lagrange model of a quadrotor carrying a point payload on a rigid massless cable.

Generalized coordinates (paper eq. 3–10), NED inertial frame, z down, gravity along +z::

    q = [x, y, z, φ, θ, ψ, α, β]      metres (NED), radians (ZYX Euler angles), radians (swing)

The payload hangs at ξ_p = ξ + l·[sα·cβ, −sβ, cα·cβ] (eqs. 3–4). Inputs are ``u = [T, τφ, τθ, τψ]``
(N, N·m; T is the rotor thrust, along −z_body) and the disturbance ``d = [dx, dy, dz, dφ, dθ, dψ]``
(N in the inertial frame, N·m in the body frame) — eq. 14's D without its two zeros. ``d`` may carry two
more entries [Q_α, Q_β] (N·m): generalised forces on the swing angles, which a force on the payload has
(:func:`companion.core.wind.generalized_drag`; eq. 14's D has zeros there, eq. 49 leaves them zero).

Derivation (the Lagrangian of eq. 10 is the source of truth; the printed eqs. 16–18 are not, see
``docs/model-derivation.md``). The kinetic energy splits into two uncoupled blocks:

* translation + swing, with J = ∂r/∂(α, β) for the payload offset r = ξ_p − ξ::

      (M+m)·ξ̈ + m·J·s̈           = F + d_ξ + (M+m)·g·e_z − m·J̇ṡ
      m·Jᵀ·ξ̈  + (m·JᵀJ + Ip)·s̈  = −m·Jᵀ·(J̇ṡ − g·e_z)

  JᵀJ = l²·diag(cβ², 1) is diagonal, so eliminating ξ̈ (Schur complement) gives the swing accelerations
  in closed form, with effective inertias m·l²·cβ²·M/(M+m) + Ip and m·l²·M/(M+m) + Ip;

* rotation: L_rot = ½·ΩᵀIΩ with Ω = R_η·η̇ (eq. 7). The torques of eq. 13 are body-frame torques, so the
  generalized force on (φ, θ, ψ) is R_ηᵀ·τ (eq. 15 puts τ straight on the Euler-angle equations, which only
  holds at level attitude). With that force the Euler–Lagrange equations are exactly Euler's rigid-body
  equations I·Ω̇ + Ω×IΩ = τ, mapped back with η̈ = R_η⁻¹·(Ω̇ − Ṙ_η·η̇). We use that (physical) form.

The numeric kernels are compiled with numba (``cache=True``: the first import on a machine compiles and
caches, later imports load the cache). The pure-Python entry points check their inputs for NaN/inf and
raise :class:`ModelError` rather than letting a NaN run silently through a simulation. The parameters
(:class:`~companion.core.vehicle_params.VehicleParams`, also importable from here) live in
:mod:`companion.core.vehicle_params`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.vehicle_params import VehicleParams
from companion.errors import ModelError

N_Q = 8
N_X = 16
IDX_X, IDX_Y, IDX_Z, IDX_PHI, IDX_THETA, IDX_PSI, IDX_ALPHA, IDX_BETA = range(8)


# --------------------------------------------------------------------------------------------------------
# Compiled kernels. x = [q(8), q̇(8)], u = [T, τφ, τθ, τψ], d = [dx, dy, dz, dφ, dθ, dψ] or
# [dx, dy, dz, dφ, dθ, dψ, Qα, Qβ], p = VehicleParams.packed().


# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache()


@njit(cache=True)
def _deriv(x, u, d, p, out):  # pragma: no cover - compiled
    """Write ẋ = [q̇, q̈] of the Lagrangian model into ``out`` (length 16)."""
    M = p[0]
    m = p[1]
    g = p[2]
    Ip = p[6]
    l = p[7]
    phi = x[3]
    th = x[4]
    psi = x[5]
    al = x[6]
    be = x[7]
    dal = x[14]
    dbe = x[15]
    sphi = math.sin(phi)
    cphi = math.cos(phi)
    sth = math.sin(th)
    cth = math.cos(th)
    spsi = math.sin(psi)
    cpsi = math.cos(psi)
    sa = math.sin(al)
    ca = math.cos(al)
    sb = math.sin(be)
    cb = math.cos(be)
    T = u[0]
    mt = M + m

    # Thrust in NED, eq. 11–12: F = −R_F·[0, 0, T].
    fx = -(cphi * sth * cpsi + sphi * spsi) * T + d[0]
    fy = -(cphi * sth * spsi - sphi * cpsi) * T + d[1]
    fz = -(cphi * cth) * T + d[2] + mt * g

    # Payload offset Jacobian J (3x2) and the velocity-product acceleration a_c = J̇·ṡ.
    j0a = l * ca * cb
    j0b = -l * sa * sb
    j1a = 0.0
    j1b = -l * cb
    j2a = -l * sa * cb
    j2b = -l * ca * sb
    ac0 = l * (-sa * cb * dal * dal - 2.0 * ca * sb * dal * dbe - sa * cb * dbe * dbe)
    ac1 = l * (sb * dbe * dbe)
    ac2 = l * (-ca * cb * (dal * dal + dbe * dbe) + 2.0 * sa * sb * dal * dbe)

    # Right-hand sides: rξ = F + d + (M+m)g·e_z − m·a_c ;  rs = −m·Jᵀ(a_c − g·e_z)
    r0 = fx - m * ac0
    r1 = fy - m * ac1
    r2 = fz - m * ac2
    rsa = -m * (j0a * ac0 + j1a * ac1 + j2a * (ac2 - g))
    rsb = -m * (j0b * ac0 + j1b * ac1 + j2b * (ac2 - g))
    if d.shape[0] > 6:  # generalised forces on α, β (a force on the payload: Jᵀ·F_p)
        rsa += d[6]
        rsb += d[7]

    # Schur complement: (D − m²JᵀJ/(M+m))·s̈ = rs − m·Jᵀ·rξ/(M+m), JᵀJ = l²·diag(cβ², 1).
    ka = m * l * l * cb * cb * M / mt + Ip
    kb = m * l * l * M / mt + Ip
    dda = (rsa - m * (j0a * r0 + j1a * r1 + j2a * r2) / mt) / ka
    ddb = (rsb - m * (j0b * r0 + j1b * r1 + j2b * r2) / mt) / kb
    ddx = (r0 - m * (j0a * dda + j0b * ddb)) / mt
    ddy = (r1 - m * (j1a * dda + j1b * ddb)) / mt
    ddz = (r2 - m * (j2a * dda + j2b * ddb)) / mt

    _rotation_acc(x, u, d, p, sphi, cphi, sth, cth, out)
    for i in range(8):
        out[i] = x[8 + i]
    out[8] = ddx
    out[9] = ddy
    out[10] = ddz
    out[14] = dda
    out[15] = ddb


@njit(cache=True)
def _rotation_acc(x, u, d, p, sphi, cphi, sth, cth, out):  # pragma: no cover - compiled
    """The rotation block of the Lagrangian (uncoupled from translation and swing): η̈ = [φ̈, θ̈, ψ̈] (rad/s²) into
    ``out[11:14]``, from Euler's rigid-body equations. Ω = R_η·η̇ (eq. 7); I·Ω̇ = τ − Ω×IΩ;
    η̈ = R_η⁻¹(Ω̇ − Ṙ_η·η̇). ``sphi`` … ``cth``: sin/cos of φ and θ, already computed by the caller."""
    Ixx = p[3]
    Iyy = p[4]
    Izz = p[5]
    dphi = x[11]
    dth = x[12]
    dpsi = x[13]
    wx = dphi - sth * dpsi
    wy = cphi * dth + sphi * cth * dpsi
    wz = -sphi * dth + cphi * cth * dpsi
    tx = u[1] + d[3]
    ty = u[2] + d[4]
    tz = u[3] + d[5]
    dwx = (tx - (Izz - Iyy) * wy * wz) / Ixx
    dwy = (ty - (Ixx - Izz) * wz * wx) / Iyy
    dwz = (tz - (Iyy - Ixx) * wx * wy) / Izz
    # Ṙ_η·η̇
    b0 = -cth * dth * dpsi
    b1 = -sphi * dphi * dth + (cphi * cth * dphi - sphi * sth * dth) * dpsi
    b2 = -cphi * dphi * dth + (-sphi * cth * dphi - cphi * sth * dth) * dpsi
    v0 = dwx - b0
    v1 = dwy - b1
    v2 = dwz - b2
    tth = sth / cth
    out[11] = v0 + sphi * tth * v1 + cphi * tth * v2
    out[12] = cphi * v1 - sphi * v2
    out[13] = (sphi * v1 + cphi * v2) / cth


@njit(cache=True)
def _rk4(x, u, d, p, dt, n_steps):  # pragma: no cover - compiled
    """``n_steps`` classical RK4 steps of length ``dt`` with u, d held; returns the new state."""
    k1 = np.empty(16)
    k2 = np.empty(16)
    k3 = np.empty(16)
    k4 = np.empty(16)
    xt = np.empty(16)
    y = x.copy()
    for _ in range(n_steps):
        _deriv(y, u, d, p, k1)
        for i in range(16):
            xt[i] = y[i] + 0.5 * dt * k1[i]
        _deriv(xt, u, d, p, k2)
        for i in range(16):
            xt[i] = y[i] + 0.5 * dt * k2[i]
        _deriv(xt, u, d, p, k3)
        for i in range(16):
            xt[i] = y[i] + dt * k3[i]
        _deriv(xt, u, d, p, k4)
        for i in range(16):
            y[i] = y[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    return y


@njit(cache=True)
def _rk4_batch(X, U, D, p, dt, n_steps):  # pragma: no cover - compiled
    """RK4 for N vehicles sharing parameters: X (N,16), U (N,4), D (N,6); returns new X."""
    out = np.empty_like(X)
    for k in range(X.shape[0]):
        out[k] = _rk4(X[k], U[k], D[k], p, dt, n_steps)
    return out


# --------------------------------------------------------------------------------------------------------
# Checked Python entry points.


def _as_vec(name: str, v, n: int) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if name == "d" and a.shape == (8,):  # with the swing channels [Qα, Qβ]
        n = 8
    if a.shape != (n,):
        raise ModelError(f"{name}: expected shape ({n},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelError(f"{name}: non-finite value in {a.tolist()}")
    return a


def accelerations(q, q_dot, u, d, params: VehicleParams) -> np.ndarray:
    """Generalized accelerations q̈ (8,) of the model for q, q̇ (8,), u (4,), d (6,) or (8,) (with Qα, Qβ).

    Units: m/s² for x, y, z; rad/s² for φ, θ, ψ, α, β. Raises :class:`ModelError` on non-finite input or at
    the Euler-angle singularity θ = ±90°.
    """
    x = np.concatenate([_as_vec("q", q, 8), _as_vec("q_dot", q_dot, 8)])
    _check_domain(x)
    out = np.empty(16)
    _deriv(x, _as_vec("u", u, 4), _as_vec("d", d, 6), params.packed(), out)
    return out[8:]


def dynamics(t: float, x, u, params: VehicleParams) -> np.ndarray:
    """ẋ = f(t, x, u, params) in python-control's convention, for scipy's integrators too.

    x = [q, q̇] (16,); u = [T, τφ, τθ, τψ, dx, dy, dz, dφ, dθ, dψ] (10,): control then disturbance.
    """
    uu = np.asarray(u, dtype=np.float64)
    xx = np.asarray(x, dtype=np.float64)
    out = np.empty(16)
    _deriv(xx, uu[:4].copy(), uu[4:10].copy(), params.packed(), out)
    return out


def _check_domain(x: np.ndarray) -> None:
    if abs(math.cos(x[IDX_THETA])) < 1e-6:
        raise ModelError(f"θ = {x[IDX_THETA]:.6f} rad: Euler-angle singularity (pitch at ±90°)")


def rk4_step(x, u, d, params: VehicleParams | np.ndarray, dt: float = 1e-3, n_steps: int = 1) -> np.ndarray:
    """Advance state x = [q, q̇] (16,) by ``n_steps`` RK4 steps of ``dt`` seconds with u, d held.

    ``params`` may be a :class:`VehicleParams` or its :meth:`~VehicleParams.packed` array (faster in loops).
    Raises :class:`ModelError` if an input or the result is non-finite.
    """
    p = params.packed() if isinstance(params, VehicleParams) else params
    xx = _as_vec("x", x, 16)
    _check_domain(xx)
    y = _rk4(xx, _as_vec("u", u, 4), _as_vec("d", d, 6), p, float(dt), int(n_steps))
    if not np.all(np.isfinite(y)):
        raise ModelError(f"state diverged to non-finite values after RK4 from x={xx.tolist()}")
    return y


def rk4_batch(X, U, D, params: VehicleParams, dt: float = 1e-3, n_steps: int = 1) -> np.ndarray:
    """Batched :func:`rk4_step` over N vehicles with shared parameters: X (N,16), U (N,4), D (N,6)."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    U = np.ascontiguousarray(U, dtype=np.float64)
    D = np.ascontiguousarray(D, dtype=np.float64)
    for name, a, n in (("X", X, 16), ("U", U, 4), ("D", D, 6)):
        if a.ndim != 2 or a.shape[1] != n or a.shape[0] != X.shape[0]:
            raise ModelError(f"{name}: expected shape (N, {n}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ModelError(f"{name}: non-finite values")
    Y = _rk4_batch(X, U, D, params.packed(), float(dt), int(n_steps))
    if not np.all(np.isfinite(Y)):
        raise ModelError("batch state diverged to non-finite values")
    return Y


# --------------------------------------------------------------------------------------------------------
# Kinematics and energy.


def rotation_body_to_ned(phi: float, theta: float, psi: float) -> np.ndarray:
    """R_F of eq. 12: ZYX rotation from body FRD to NED (3x3)."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    return np.array(
        [
            [ct * cp, cp * st * sf - cf * sp, cf * cp * st + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - cp * sf],
            [-st, sf * ct, cf * ct],
        ]
    )


def euler_rate_matrix(phi: float, theta: float) -> np.ndarray:
    """R_η of eq. 7: body rates Ω = R_η·η̇ (3x3)."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    return np.array([[1.0, 0.0, -st], [0.0, cf, sf * ct], [0.0, -sf, cf * ct]])


def payload_offset_ned_m(alpha: float, beta: float, l: float) -> np.ndarray:
    """T_p·[0, 0, l] of eqs. 3–4: payload position relative to the quadrotor, NED metres."""
    return l * np.array([math.sin(alpha) * math.cos(beta), -math.sin(beta), math.cos(alpha) * math.cos(beta)])


def energy_j(x, params: VehicleParams) -> float:
    """Total mechanical energy K + V (J), potential referenced to z = 0 (z down: V = −M·g·z − m·g·z_p)."""
    x = np.asarray(x, dtype=np.float64)
    q, qd = x[:8], x[8:]
    p = params
    al, be = q[6], q[7]
    ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
    J = p.l * np.array([[ca * cb, -sa * sb], [0.0, -cb], [-sa * cb, -ca * sb]])
    v_load = qd[:3] + J @ qd[6:8]
    omega = euler_rate_matrix(q[3], q[4]) @ qd[3:6]
    k = 0.5 * p.M * float(qd[:3] @ qd[:3]) + 0.5 * float(omega @ (np.array([p.Ixx, p.Iyy, p.Izz]) * omega))
    k += 0.5 * p.m * float(v_load @ v_load) + 0.5 * p.Ip * float(qd[6] ** 2 + qd[7] ** 2)
    z_load = q[2] + p.l * ca * cb
    v = -p.M * p.g * q[2] - p.m * p.g * z_load
    return k + v


def warm_up() -> None:
    """Compile (or load from cache) the numba kernels; call once before timing anything."""
    p = VehicleParams().packed()
    x = np.zeros(16)
    _rk4(x, np.zeros(4), np.zeros(6), p, 1e-3, 1)
    _rk4_batch(x[None, :].copy(), np.zeros((1, 4)), np.zeros((1, 6)), p, 1e-3, 1)
