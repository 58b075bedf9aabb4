"""Independent numeric Euler–Lagrange check of ``companion.core.model`` and the pendulum periods of issue 2.

The Lagrangian is written here straight from the paper's eqs. 3–9 (nothing taken from ``model.py``), the
Euler–Lagrange equations (eq. 14) are formed by central finite differences, and the resulting q̈ is
compared with :func:`companion.core.model.accelerations` at many random states and inputs. The generalized
force is Q = [F + d_ξ, R_ηᵀ·(τ + d_τ), 0, 0] with F = −R_F·[0, 0, T] (eqs. 11–12): the torques are
body-frame torques (see docs/model-derivation.md).

The finite-difference helpers are also used by tests/test_printed_equations.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.model import accelerations, rk4_step

# --------------------------------------------------------------------------------------------------------
from companion.core.vehicle_params import VehicleParams

# The Lagrangian of eq. 10, built from eqs. 3–9 (NED, z down, V = −M·g·z − m·g·z_p).


def lagrangian(q: np.ndarray, qd: np.ndarray, p: VehicleParams) -> float:
    """L = K − V (J) of eqs. 5–9 for q = [x y z φ θ ψ α β], q̇ in SI units."""
    phi, th, al, be = q[3], q[4], q[6], q[7]
    # eq. 4: T_p = Rot_y(α)·Rot_x(β); payload offset = T_p·[0, 0, l] (eqs. 2–3)
    rot_y = np.array([[math.cos(al), 0.0, math.sin(al)], [0.0, 1.0, 0.0], [-math.sin(al), 0.0, math.cos(al)]])
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(be), -math.sin(be)], [0.0, math.sin(be), math.cos(be)]])
    offset = rot_y @ rot_x @ np.array([0.0, 0.0, p.l])
    # payload velocity: d/dt of the offset, by the chain rule on (α, β) (exact derivative of eq. 3)
    d_rot_y = np.array([[-math.sin(al), 0.0, math.cos(al)], [0.0, 0.0, 0.0], [-math.cos(al), 0.0, -math.sin(al)]])
    d_rot_x = np.array([[0.0, 0.0, 0.0], [0.0, -math.sin(be), -math.cos(be)], [0.0, math.cos(be), -math.sin(be)]])
    e_l = np.array([0.0, 0.0, p.l])
    v_load = qd[:3] + (d_rot_y @ rot_x @ e_l) * qd[6] + (rot_y @ d_rot_x @ e_l) * qd[7]
    # eq. 7: Ω = R_η·η̇
    r_eta = np.array(
        [
            [1.0, 0.0, -math.sin(th)],
            [0.0, math.cos(phi), math.sin(phi) * math.cos(th)],
            [0.0, -math.sin(phi), math.cos(phi) * math.cos(th)],
        ]
    )
    omega = r_eta @ qd[3:6]
    inertia = np.array([p.Ixx, p.Iyy, p.Izz])  # eq. 8 with zero products of inertia
    kin = (
        0.5 * p.M * qd[:3] @ qd[:3]
        + 0.5 * omega @ (inertia * omega)
        + 0.5 * p.m * v_load @ v_load
        + 0.5 * p.Ip * (qd[6] ** 2 + qd[7] ** 2)
    )
    z_load = q[2] + offset[2]
    pot = p.M * p.g * (-q[2]) + p.m * p.g * (-z_load)  # eq. 9
    return float(kin - pot)


def generalized_force(q: np.ndarray, u: np.ndarray, d: np.ndarray, physical: bool = True) -> np.ndarray:
    """Q of eq. 14: thrust F = −R_F·[0,0,T] + d_ξ on (x, y, z); R_ηᵀ·(τ + d_τ) (or eq. 15's τ + d_τ when
    ``physical`` is False) on (φ, θ, ψ); nothing on (α, β)."""
    phi, th, psi = q[3], q[4], q[5]
    sf, cf, st, ct, sp, cp = (math.sin(phi), math.cos(phi), math.sin(th), math.cos(th), math.sin(psi),
                              math.cos(psi))
    thrust_dir = np.array([cf * cp * st + sf * sp, cf * st * sp - cp * sf, cf * ct])  # R_F third column
    r_eta = np.array([[1.0, 0.0, -st], [0.0, cf, sf * ct], [0.0, -sf, cf * ct]])
    tau = np.asarray(u[1:4]) + np.asarray(d[3:6])
    out = np.zeros(8)
    out[:3] = -thrust_dir * u[0] + np.asarray(d[:3])
    out[3:6] = r_eta.T @ tau if physical else tau
    return out


_H_VEL = 1.0  # L is quadratic in q̇: central differences in q̇ are exact for any step
_H_POS = 1e-5


def momentum(q: np.ndarray, qd: np.ndarray, p: VehicleParams) -> np.ndarray:
    """∂L/∂q̇ (8,) by central differences (exact up to rounding: L is quadratic in q̇)."""
    out = np.empty(8)
    for i in range(8):
        e = np.zeros(8)
        e[i] = _H_VEL
        out[i] = (lagrangian(q, qd + e, p) - lagrangian(q, qd - e, p)) / (2 * _H_VEL)
    return out


def mass_matrix(q: np.ndarray, p: VehicleParams) -> np.ndarray:
    """∂²L/∂q̇² (8x8), the generalized inertia matrix, by central differences of the momentum."""
    z = np.zeros(8)
    mm = np.empty((8, 8))
    for j in range(8):
        e = np.zeros(8)
        e[j] = _H_VEL
        mm[:, j] = (momentum(q, z + e, p) - momentum(q, z - e, p)) / (2 * _H_VEL)
    return 0.5 * (mm + mm.T)


def bias(q: np.ndarray, qd: np.ndarray, p: VehicleParams) -> np.ndarray:
    """h(q, q̇) = (∂²L/∂q̇∂q)·q̇ − ∂L/∂q, so that eq. 14 reads M(q)·q̈ + h = Q."""
    speed = max(1.0, float(np.max(np.abs(qd))))
    h = 1e-4 / speed
    dp_dt = (momentum(q + h * qd, qd, p) - momentum(q - h * qd, qd, p)) / (2 * h)
    dl_dq = np.empty(8)
    for i in range(8):
        e = np.zeros(8)
        e[i] = _H_POS
        dl_dq[i] = (lagrangian(q + e, qd, p) - lagrangian(q - e, qd, p)) / (2 * _H_POS)
    return dp_dt - dl_dq


def fd_accelerations(q, qd, u, d, p: VehicleParams, physical: bool = True) -> np.ndarray:
    """q̈ solved from M(q)·q̈ = Q − h with everything from finite differences of the Lagrangian."""
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    return np.linalg.solve(mass_matrix(q, p), generalized_force(q, u, d, physical) - bias(q, qd, p))


def random_case(rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """A random state and input away from the Euler singularity (|θ| < 1.2) and the swing bounds (eq. 1)."""
    q = np.concatenate(
        [rng.uniform(-5, 5, 3), rng.uniform(-1.2, 1.2, 2), rng.uniform(-math.pi, math.pi, 1), rng.uniform(-1.3, 1.3, 2)]
    )
    qd = rng.uniform(-3.0, 3.0, 8)
    u = np.concatenate([rng.uniform(0.0, 40.0, 1), rng.uniform(-1.0, 1.0, 3)])
    d = np.concatenate([rng.uniform(-5.0, 5.0, 3), rng.uniform(-0.5, 0.5, 3)])
    return q, qd, u, d


PARAMS = [
    VehicleParams(),
    # asymmetric body, heavy payload inertia, short cable: exercises every gyroscopic and coupling term
    VehicleParams(M=2.0, m=0.7, Ixx=0.011, Iyy=0.019, Izz=0.026, Ip=0.01, l=0.6, g=9.7),
]


# --------------------------------------------------------------------------------------------------------
# Numeric Euler–Lagrange vs the model.


def test_fd_lagrangian_reproduces_printed_mass_matrix_entries() -> None:
    """Sanity of the FD machinery itself: a few mass-matrix entries read off the printed eq. 10."""
    p = VehicleParams()
    q = np.array([0.3, -0.2, 1.0, 0.2, -0.4, 0.7, 0.5, -0.3])
    mm = mass_matrix(q, p)
    al, be, th, phi = q[6], q[7], q[4], q[3]
    assert mm[0, 0] == pytest.approx(p.M + p.m, rel=1e-12)
    assert mm[1, 7] == pytest.approx(-p.m * p.l * math.cos(be), rel=1e-10)
    assert mm[6, 6] == pytest.approx(p.m * p.l**2 * math.cos(be) ** 2 + p.Ip, rel=1e-10)
    assert mm[3, 5] == pytest.approx(-p.Ixx * math.sin(th), rel=1e-10)
    assert mm[4, 4] == pytest.approx(p.Iyy * math.cos(phi) ** 2 + p.Izz * math.sin(phi) ** 2, rel=1e-10)
    assert mm[0, 6] == pytest.approx(p.m * p.l * math.cos(al) * math.cos(be), rel=1e-10)


@pytest.mark.parametrize("params", PARAMS, ids=["table1", "asymmetric"])
def test_model_matches_numeric_euler_lagrange(params: VehicleParams) -> None:
    """``accelerations`` equals the FD Euler–Lagrange solution at 150 random states/inputs (fixed seed).

    FD error budget: momentum exact (quadratic in q̇), directional derivative O(h²)≈1e-8, rounding
    ≈ 1e-16·|L|/1e-5 ≈ 1e-9; so 1e-5 relative to the largest acceleration is a wide but still sharp bound
    (a wrong Coriolis coefficient or a missing factor shows up at 1e-2 or more).
    """
    rng = np.random.default_rng(20240602)
    worst = 0.0
    for _ in range(150):
        q, qd, u, d = random_case(rng)
        ref = fd_accelerations(q, qd, u, d, params)
        got = accelerations(q, qd, u, d, params)
        scale = max(1.0, float(np.max(np.abs(ref))))
        err = float(np.max(np.abs(got - ref))) / scale
        worst = max(worst, err)
        assert err < 1e-5, f"q={q}, qd={qd}, u={u}, d={d}: model {got} vs Euler–Lagrange {ref}"
    assert worst < 1e-5


def test_eq15_identity_torque_mapping_differs_from_model_when_tilted() -> None:
    """Eq. 15 puts τ straight on (φ, θ, ψ): equal to the physical R_ηᵀ·τ only at φ = θ = 0."""
    p = VehicleParams()
    qd = np.array([0.0, 0.0, 0.0, 0.3, -0.2, 0.5, 0.1, -0.1])
    u = np.array([p.hover_thrust_n, 0.05, -0.08, 0.02])
    d = np.zeros(6)
    level = np.array([0.0, 0.0, -2.0, 0.0, 0.0, 1.0, 0.2, 0.1])
    tilted = level.copy()
    tilted[3:5] = [0.4, -0.3]
    for q, same in ((level, True), (tilted, False)):
        model = accelerations(q, qd, u, d, p)
        ident = fd_accelerations(q, qd, u, d, p, physical=False)
        assert np.allclose(model[:3], ident[:3], atol=1e-6) and np.allclose(model[6:], ident[6:], atol=1e-6)
        assert np.allclose(model[3:6], ident[3:6], atol=1e-5) == same


# --------------------------------------------------------------------------------------------------------
# Swing with the quadrotor held (ξ̈ = 0): the swing rows of eq. 14, closed form (eq. 18 counterpart).


def held_swing_accelerations(s: np.ndarray, sd: np.ndarray, p: VehicleParams) -> np.ndarray:
    """[α̈, β̈] of the derived swing equations with ξ̈ = 0 (support holds the quadrotor still)."""
    al, be = s
    ald, bed = sd
    ml = p.m * p.l
    ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
    a_dd = ml * (2 * p.l * ald * bed * cb * sb - p.g * cb * sa) / (p.Ip + ml * p.l * cb**2)
    b_dd = ml * (-p.l * ald**2 * cb * sb - p.g * sb * ca) / (p.Ip + ml * p.l)
    return np.array([a_dd, b_dd])


def rk4_swing(f, s0: np.ndarray, sd0: np.ndarray, p: VehicleParams, duration_s: float, dt: float = 1e-3):
    """Fixed-step RK4 of s̈ = f(s, ṡ, p); returns times (n,) and the swing angles (n, 2)."""
    y = np.concatenate([s0, sd0]).astype(float)
    n = round(duration_s / dt)
    out = np.empty((n + 1, 2))
    out[0] = y[:2]

    def rhs(v: np.ndarray) -> np.ndarray:
        return np.concatenate([v[2:], f(v[:2], v[2:], p)])

    for k in range(n):
        k1 = rhs(y)
        k2 = rhs(y + 0.5 * dt * k1)
        k3 = rhs(y + 0.5 * dt * k2)
        k4 = rhs(y + dt * k3)
        y = y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = y[:2]
    return np.arange(n + 1) * dt, out


def test_held_swing_equations_match_numeric_euler_lagrange() -> None:
    """The closed-form held swing equations are the swing rows of M·q̈ + h = 0 with ξ̈ = 0."""
    rng = np.random.default_rng(7)
    for p in PARAMS:
        for _ in range(20):
            q, qd, _, _ = random_case(rng)
            mm, h = mass_matrix(q, p), bias(q, qd, p)
            ref = np.linalg.solve(mm[6:, 6:], -h[6:])  # ξ̈ = 0; rotation does not couple to the swing
            got = held_swing_accelerations(q[6:], qd[6:], p)
            assert np.allclose(got, ref, rtol=1e-6, atol=1e-6 * max(1.0, np.max(np.abs(ref))))


def period_from_zero_crossings(t: np.ndarray, sig: np.ndarray) -> float:
    """Mean period (s) from linearly interpolated zero crossings (two crossings per period)."""
    idx = np.nonzero(np.signbit(sig[:-1]) != np.signbit(sig[1:]))[0]
    assert len(idx) >= 5, f"only {len(idx)} zero crossings"
    tc = t[idx] - sig[idx] * (t[idx + 1] - t[idx]) / (sig[idx + 1] - sig[idx])
    return 2.0 * float(tc[-1] - tc[0]) / (len(tc) - 1)


def simulate_model(x0: np.ndarray, u: np.ndarray, p: VehicleParams, duration_s: float) -> tuple[np.ndarray, ...]:
    """Model RK4 at 1 kHz from x0 with u held, zero disturbance; returns t (n,) and states (n, 16)."""
    dt = 1e-3
    n = round(duration_s / dt)
    xs = np.empty((n + 1, 16))
    xs[0] = x0
    pk = p.packed()
    d = np.zeros(6)
    for k in range(n):
        xs[k + 1] = rk4_step(xs[k], u, d, pk, dt, 1)
    return np.arange(n + 1) * dt, xs


SMALL_SWING_RAD = 0.02  # amplitude error of the period ≈ θ0²/16 = 2.5e-5


@pytest.mark.parametrize("axis", [6, 7], ids=["alpha", "beta"])
def test_free_quadrotor_two_body_pendulum_period(axis: int) -> None:
    """Free quadrotor at hover thrust, level: period 2π·sqrt(M·l/((M+m)·g)) within 0.1 %."""
    p = VehicleParams()
    x0 = np.zeros(16)
    x0[2] = -10.0
    x0[axis] = SMALL_SWING_RAD
    t, xs = simulate_model(x0, np.array([p.hover_thrust_n, 0.0, 0.0, 0.0]), p, 9.5)
    other = 13 - axis
    expected = 2 * math.pi * math.sqrt(p.M * p.l / ((p.M + p.m) * p.g))
    period = period_from_zero_crossings(t, xs[:, axis])
    assert period == pytest.approx(expected, rel=1e-3)
    assert np.max(np.abs(xs[:, other])) < 1e-9  # a planar swing stays planar
    # the quadrotor swings against the payload: the system's centre of mass stays put horizontally
    offset_x = p.l * np.sin(xs[:, 6]) * np.cos(xs[:, 7])
    offset_y = -p.l * np.sin(xs[:, 7])
    com_h = (p.M * xs[:, :2] + p.m * (xs[:, :2] + np.stack([offset_x, offset_y], axis=1))) / p.total_mass
    assert np.max(np.abs(com_h - com_h[0])) < 1e-9


@pytest.mark.parametrize("axis", [0, 1], ids=["alpha", "beta"])
def test_held_quadrotor_pendulum_period(axis: int) -> None:
    """Quadrotor held (ξ̈ = 0): period 2π·sqrt((m·l²+Ip)/(m·g·l)) within 0.1 %, Ip included."""
    p = VehicleParams()
    s0 = np.zeros(2)
    s0[axis] = SMALL_SWING_RAD
    t, s = rk4_swing(held_swing_accelerations, s0, np.zeros(2), p, 9.0)
    expected = 2 * math.pi * math.sqrt((p.m * p.l**2 + p.Ip) / (p.m * p.g * p.l))
    assert expected == pytest.approx(2 * math.pi * math.sqrt(p.l / p.g), rel=1e-5)
    assert period_from_zero_crossings(t, s[:, axis]) == pytest.approx(expected, rel=1e-3)


def test_model_with_immovable_quadrotor_gives_held_period() -> None:
    """The full model with M → ∞ (1e6·m, hover thrust) is a held support: same period as ξ̈ = 0."""
    p = VehicleParams(M=0.25e6, m=0.25, Ip=1e-6)
    x0 = np.zeros(16)
    x0[6] = SMALL_SWING_RAD
    t, xs = simulate_model(x0, np.array([p.hover_thrust_n, 0.0, 0.0, 0.0]), p, 9.0)
    expected = 2 * math.pi * math.sqrt((p.m * p.l**2 + p.Ip) / (p.m * p.g * p.l))
    assert period_from_zero_crossings(t, xs[:, 6]) == pytest.approx(expected, rel=1e-3)
