"""The paper's printed equations of motion (eqs. 16, 17, 18, 29, 38), transcribed as printed, against the
derivation. One test per row found correct and one per typo named in docs/model-derivation.md, each
checking the *stated* difference (so the document cannot drift from the truth).

The reference ("derived") side is the finite-difference Euler–Lagrange machinery of
tests/test_model_lagrangian.py (the Lagrangian written from eqs. 3–9) and ``companion.core.model`` itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_model_lagrangian import (  # tests/ is a plain directory on sys.path (pytest's prepend mode)
    PARAMS,
    bias,
    generalized_force,
    held_swing_accelerations,
    mass_matrix,
    random_case,
    rk4_swing,
    simulate_model,
)

from companion.core.model import accelerations
from companion.core.vehicle_params import VehicleParams

N_CASES = 60


def _trig(q: np.ndarray) -> tuple[float, ...]:
    phi, th, al, be = q[3], q[4], q[6], q[7]
    return (math.sin(phi), math.cos(phi), math.sin(th), math.cos(th),
            math.sin(al), math.cos(al), math.sin(be), math.cos(be))


# --------------------------------------------------------------------------------------------------------
# Printed equations, symbol by symbol.


def eq16_printed_rhs(q, qd, qdd, p: VehicleParams) -> np.ndarray:
    """Right-hand sides of eq. 16 as printed (they equal F + d)."""
    _, _, _, _, sa, ca, sb, cb = _trig(q)
    ad, bd = qd[6], qd[7]
    add, bdd = qdd[6], qdd[7]
    mt, ml = p.M + p.m, p.m * p.l
    return np.array([
        mt * qdd[0] + ml * ca * cb * add - ml * sa * sb * bdd
        - 2 * ml * sb * ca * ad * bd - ml * cb * sa * ad**2 - ml * cb * sa * bd**2,
        mt * qdd[1] - ml * cb * bdd + ml * sb * bd**2,
        mt * qdd[2] - ml * sa * cb * add - ml * ca * sb * bdd + 2 * ml * sb * sa * ad * bd
        - ml * cb * ca * ad**2 - ml * cb * ca * bd**2 - mt * p.g,
    ])


def eq29_f_printed(q, qd, qdd, p: VehicleParams) -> np.ndarray:
    """f1, f2, f3 of eq. 29 as printed."""
    _, _, _, _, sa, ca, sb, cb = _trig(q)
    ad, bd = qd[6], qd[7]
    add, bdd = qdd[6], qdd[7]
    m, l = p.m, p.l
    return np.array([
        -m * l * ca * cb * add + m * sa * sb * l * bdd + m * l * (bd * sb * ca + cb * sa * ad) * ad
        + m * l * (bd * cb * sa + ad * sb * ca) * bd,
        m * l * cb * bdd - m * l * sb * bd**2,
        m * l * sa * cb * add + m * l * ca * sb * bdd - m * l * (bd * sb * sa - ad * cb * ca) * ad
        - m * l * (ad * sb * sa - bd * cb * ca) * bd,
    ])


def eq18_printed(q, qd, xi_dd, p: VehicleParams, fix_gravity: bool = False,
                 fix_centrifugal: bool = False) -> np.ndarray:
    """[α̈, β̈] of eq. 18 as printed, given the quadrotor acceleration ξ̈; the ``fix_*`` flags flip the sign
    of the named β term (the typos), for checking each one alone."""
    _, _, _, _, sa, ca, sb, cb = _trig(q)
    ad, bd = qd[6], qd[7]
    xdd, ydd, zdd = xi_dd
    m, l, g, ip = p.m, p.l, p.g, p.Ip
    a_dd = (-ca * cb * xdd + sa * cb * zdd + 2 * l * ad * bd * cb * sb - g * cb * sa) * m * l / (ip + m * l**2 * cb**2)
    centrifugal = (-1.0 if fix_centrifugal else 1.0) * l * ad**2 * cb * sb
    gravity = (-1.0 if fix_gravity else 1.0) * g * sb * ca
    b_dd = (sa * sb * xdd + cb * ydd + ca * sb * zdd + centrifugal + gravity) * m * l / (ip + m * l**2)
    return np.array([a_dd, b_dd])


def eq17_printed_rhs(q, qd, qdd, p: VehicleParams, fix_theta: bool = False, fix_psi: bool = False) -> np.ndarray:
    """Right-hand sides of eq. 17 as printed (they equal τ + d). ``fix_theta`` / ``fix_psi`` put ψ̈ where the
    print has ψ̇ in the θ row's (Iyy−Izz)cθcφsφ term / the ψ row's {Ixx s²θ + c²θ(...)} term."""
    sf, cf, st, ct, *_ = _trig(q)
    phid, thd, psid = qd[3], qd[4], qd[5]
    phidd, thdd, psidd = qdd[3], qdd[4], qdd[5]
    ixx, iyy, izz = p.Ixx, p.Iyy, p.Izz
    dd = iyy - izz
    row_phi = (
        ixx * phidd - ixx * st * psidd - dd * sf * cf * ct**2 * psid**2
        + (-ixx * psid * ct + dd * (thd * sf * cf + psid * ct * sf**2 - psid * ct * cf**2)) * thd
    )
    row_theta = (
        (iyy * cf**2 + izz * sf**2) * thdd + (dd * ct * cf * sf) * (psidd if fix_theta else psid)
        + (ixx * psid * ct + dd * (-2 * thd * sf * cf + psid * ct * cf**2 - psid * ct * sf**2)) * phid
        + st * ct * (-ixx + iyy * sf**2 + izz * cf**2) * psid**2
    )
    row_psi = (
        -ixx * st * phidd + dd * ct * cf * sf * thdd
        + (ixx * st**2 + ct**2 * (izz * cf**2 + iyy * sf**2)) * (psidd if fix_psi else psid)
        - izz * phid * ct**2 * sf * cf * psid
        - (ixx * thd * ct - dd * psid * ct**2 * sf * cf) * phid
        + iyy * phid * ct**2 * sf * cf * psid
        + (ixx * psid * st * ct - dd * (thd * st * cf * sf + phid * ct * sf**2 - phid * ct * cf**2)) * thd
        + (ixx * thd * st * ct - 2 * (iyy * sf**2 + izz * cf**2) * thd * st * ct) * psid
    )
    return np.array([row_phi, row_theta, row_psi])


def eq38_printed(f_ned: np.ndarray, psi_d: float) -> tuple[float, float, float]:
    """(φ_d, θ_d, T) of eq. 38 as printed: T = F_z / (c_φd · s_θd)."""
    fx, fy, fz = (float(v) for v in f_ned)
    th_d = math.atan((fx * math.cos(psi_d) + fy * math.sin(psi_d)) / fz)
    ph_d = math.atan((fx * math.sin(psi_d) - fy * math.cos(psi_d)) * math.cos(th_d) / fz)
    return ph_d, th_d, fz / (math.cos(ph_d) * math.sin(th_d))


# --------------------------------------------------------------------------------------------------------
# Derived counterparts (finite-difference Euler–Lagrange, no sympy).


def derived_swing(q, qd, xi_dd, p: VehicleParams) -> np.ndarray:
    """[α̈, β̈] from the swing rows of M·q̈ + h = 0 with ξ̈ given (rotation does not couple to the swing)."""
    mm, h = mass_matrix(q, p), bias(q, qd, p)
    return np.linalg.solve(mm[6:, 6:], -(mm[6:, :3] @ xi_dd + h[6:]))


def derived_rotation_lhs(q, qd, qdd, p: VehicleParams) -> np.ndarray:
    """d/dt(∂L/∂η̇) − ∂L/∂η for (φ, θ, ψ): what eq. 15's identity mapping sets equal to τ + d."""
    return (mass_matrix(q, p) @ qdd + bias(q, qd, p))[3:6]


def _cases(seed: int):
    rng = np.random.default_rng(seed)
    for k in range(N_CASES):
        q, qd, u, d = random_case(rng)
        yield PARAMS[k % len(PARAMS)], q, qd, u, d, rng.uniform(-8.0, 8.0, 8)


# --------------------------------------------------------------------------------------------------------
# Eq. 16 and eq. 29: correct as printed.


def test_eq16_printed_translation_rows_hold_for_the_model() -> None:
    """F + d = printed right-hand side of eq. 16, with q̈ from the model (all three rows correct)."""
    for p, q, qd, u, d, _ in _cases(1):
        qdd = accelerations(q, qd, u, d, p)
        lhs = generalized_force(q, u, d)[:3]
        assert np.allclose(eq16_printed_rhs(q, qd, qdd, p), lhs, rtol=0, atol=1e-9 * (1 + np.max(np.abs(lhs))))


def test_eq29_printed_f1_f3_hold_for_the_model() -> None:
    """(M+m)ξ̈ = F + f + (M+m)g·e_z + d with the printed f1–f3 (correct as printed)."""
    for p, q, qd, u, d, _ in _cases(2):
        qdd = accelerations(q, qd, u, d, p)
        rhs = generalized_force(q, u, d)[:3] + eq29_f_printed(q, qd, qdd, p) + np.array([0, 0, p.total_mass * p.g])
        assert np.allclose(p.total_mass * qdd[:3], rhs, rtol=0, atol=1e-9 * (1 + np.max(np.abs(rhs))))


# --------------------------------------------------------------------------------------------------------
# Eq. 18: α row correct; β row has two sign typos (gravity, centrifugal).


def test_eq18_alpha_printed_is_correct() -> None:
    for p, q, qd, _, _, xi_dd in _cases(3):
        ref = derived_swing(q, qd, xi_dd[:3], p)
        assert eq18_printed(q, qd, xi_dd[:3], p)[0] == pytest.approx(ref[0], rel=1e-6, abs=1e-6)


def test_eq18_beta_with_both_signs_fixed_is_the_derived_equation() -> None:
    for p, q, qd, _, _, xi_dd in _cases(4):
        ref = derived_swing(q, qd, xi_dd[:3], p)
        got = eq18_printed(q, qd, xi_dd[:3], p, fix_gravity=True, fix_centrifugal=True)[1]
        assert got == pytest.approx(ref[1], rel=1e-6, abs=1e-6)


def test_eq18_beta_gravity_term_sign_typo() -> None:
    """Printed +g·sβ·cα should be −g·sβ·cα: printed − derived = 2·m·l·g·sβ·cα / (Ip + m·l²)."""
    for p, q, qd, _, _, xi_dd in _cases(5):
        ref = derived_swing(q, qd, xi_dd[:3], p)[1]
        got = eq18_printed(q, qd, xi_dd[:3], p, fix_centrifugal=True)[1]
        stated = 2 * p.m * p.l * p.g * math.sin(q[7]) * math.cos(q[6]) / (p.Ip + p.m * p.l**2)
        assert abs(stated) > 1e-3
        assert got - ref == pytest.approx(stated, rel=1e-6, abs=1e-6)


def test_eq18_beta_centrifugal_term_sign_typo() -> None:
    """Printed +l·α̇²·cβ·sβ should be −l·α̇²·cβ·sβ: printed − derived = 2·m·l²·α̇²·cβ·sβ / (Ip + m·l²)."""
    for p, q, qd, _, _, xi_dd in _cases(6):
        ref = derived_swing(q, qd, xi_dd[:3], p)[1]
        got = eq18_printed(q, qd, xi_dd[:3], p, fix_gravity=True)[1]
        stated = 2 * p.m * p.l**2 * qd[6] ** 2 * math.cos(q[7]) * math.sin(q[7]) / (p.Ip + p.m * p.l**2)
        assert got - ref == pytest.approx(stated, rel=1e-6, abs=1e-6)


def _held_printed(fix_gravity: bool):
    def f(s: np.ndarray, sd: np.ndarray, p: VehicleParams) -> np.ndarray:
        q = np.zeros(8)
        qd = np.zeros(8)
        q[6:], qd[6:] = s, sd
        return eq18_printed(q, qd, np.zeros(3), p, fix_gravity=fix_gravity)

    return f


BETA0_RAD = 0.01


def test_printed_beta_equation_is_an_inverted_pendulum_when_held() -> None:
    """Quadrotor held at hover (ξ̈ = 0): printed eq. 18 makes β grow ≥ 10× within 1.5 s, at the inverted
    pendulum rate sqrt(m·g·l/(m·l²+Ip)) ≈ 3.13 1/s (β = β0·cosh(λt) while small)."""
    p = VehicleParams()
    t, s = rk4_swing(_held_printed(fix_gravity=False), np.array([0.0, BETA0_RAD]), np.zeros(2), p, 1.5)
    assert np.max(np.abs(s[:, 1])) > 10 * BETA0_RAD
    lam = math.sqrt(p.m * p.g * p.l / (p.m * p.l**2 + p.Ip))
    k = int(np.searchsorted(t, 1.0))
    assert math.acosh(s[k, 1] / BETA0_RAD) / t[k] == pytest.approx(lam, rel=0.02)
    # the gravity sign alone is the culprit: flip it and the held swing is a bounded oscillation
    _, s_fixed = rk4_swing(_held_printed(fix_gravity=True), np.array([0.0, BETA0_RAD]), np.zeros(2), p, 3.0)
    assert np.max(np.abs(s_fixed[:, 1])) <= BETA0_RAD * (1 + 1e-6)


def test_derived_model_swing_is_bounded_held_and_free() -> None:
    """Same start, the derived equations and the model: β oscillates with amplitude β0 (held and free)."""
    p = VehicleParams()
    _, s = rk4_swing(held_swing_accelerations, np.array([0.0, BETA0_RAD]), np.zeros(2), p, 3.0)
    assert np.max(np.abs(s[:, 1])) <= BETA0_RAD * (1 + 1e-6)
    assert np.min(s[:, 1]) < -0.99 * BETA0_RAD  # it does swing through
    for params in (p, VehicleParams(M=0.25e6)):  # free at hover thrust; immovable quadrotor (held)
        x0 = np.zeros(16)
        x0[7] = BETA0_RAD
        _, xs = simulate_model(x0, np.array([params.hover_thrust_n, 0.0, 0.0, 0.0]), params, 3.0)
        assert np.max(np.abs(xs[:, 7])) <= BETA0_RAD * (1 + 1e-6)
        assert np.min(xs[:, 7]) < -0.99 * BETA0_RAD


# --------------------------------------------------------------------------------------------------------
# Eq. 17 (with eq. 15's identity torque mapping, like for like): φ row correct; θ and ψ rows each print
# a velocity ψ̇ where the acceleration ψ̈ belongs.


def test_eq17_phi_row_printed_is_correct() -> None:
    for p, q, qd, _, _, qdd in _cases(7):
        ref = derived_rotation_lhs(q, qd, qdd, p)
        assert eq17_printed_rhs(q, qd, qdd, p)[0] == pytest.approx(ref[0], rel=1e-6, abs=1e-7)


def test_eq17_with_both_fixes_is_the_derived_rotation() -> None:
    for p, q, qd, _, _, qdd in _cases(8):
        ref = derived_rotation_lhs(q, qd, qdd, p)
        got = eq17_printed_rhs(q, qd, qdd, p, fix_theta=True, fix_psi=True)
        assert np.allclose(got, ref, rtol=1e-6, atol=1e-7)


def test_eq17_theta_row_psi_rate_for_psi_acceleration_typo() -> None:
    """θ row: printed (Iyy−Izz)cθcφsφ·ψ̇ should be ·ψ̈: printed − derived = (Iyy−Izz)cθcφsφ·(ψ̇ − ψ̈)."""
    for p, q, qd, _, _, qdd in _cases(9):
        sf, cf, _, ct, *_ = _trig(q)
        ref = derived_rotation_lhs(q, qd, qdd, p)[1]
        stated = (p.Iyy - p.Izz) * ct * cf * sf * (qd[5] - qdd[5])
        assert eq17_printed_rhs(q, qd, qdd, p)[1] - ref == pytest.approx(stated, rel=1e-6, abs=1e-7)


def test_eq17_psi_row_psi_rate_for_psi_acceleration_typo() -> None:
    """ψ row: printed {Ixx s²θ + c²θ(Izz c²φ + Iyy s²φ)}·ψ̇ should be ·ψ̈ (the ψ̈ inertia; eq. 39's g3 is its
    inverse): printed − derived = {…}·(ψ̇ − ψ̈)."""
    for p, q, qd, _, _, qdd in _cases(10):
        sf, cf, st, ct, *_ = _trig(q)
        ref = derived_rotation_lhs(q, qd, qdd, p)[2]
        inertia = p.Ixx * st**2 + ct**2 * (p.Izz * cf**2 + p.Iyy * sf**2)
        stated = inertia * (qd[5] - qdd[5])
        assert eq17_printed_rhs(q, qd, qdd, p)[2] - ref == pytest.approx(stated, rel=1e-6, abs=1e-7)


def test_eq17_as_printed_has_no_yaw_inertia_at_level_attitude() -> None:
    """Consequence of the ψ-row typo: the printed rows' η̈-coefficient matrix is singular at θ = 0 (ψ̈ does
    not appear), so the printed eq. 17 cannot be integrated for yaw; the derived matrix is positive definite."""
    p = VehicleParams()
    q = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.2, 0.0, 0.0])
    qd = np.zeros(8)
    base = eq17_printed_rhs(q, qd, np.zeros(8), p)
    cols = []
    for j in (3, 4, 5):
        e = np.zeros(8)
        e[j] = 1.0
        cols.append(eq17_printed_rhs(q, qd, e, p) - base)
    printed_inertia = np.array(cols).T
    assert abs(np.linalg.det(printed_inertia)) < 1e-18
    assert np.all(np.linalg.eigvalsh(mass_matrix(q, p)[3:6, 3:6]) > 1e-4)


# --------------------------------------------------------------------------------------------------------
# Eq. 38: the attitude angles are right, the thrust is not.


@pytest.mark.parametrize(("phi", "theta", "psi"), [(0.2, -0.3, 0.4), (-0.1, 0.25, -2.0), (0.3, 0.05, 1.0)])
def test_eq38_printed_thrust_typo(phi: float, theta: float, psi: float) -> None:
    """With F = −R_F·[0, 0, T] (eq. 11): printed φ_d, θ_d recover the attitude; printed T = Fz/(cφ·sθ)
    evaluates to −T·cθ/sθ (infinite at level attitude); the right inversion is T = −Fz/(cφ·cθ)."""
    thrust = 17.0
    sf, cf, st, ct, sp, cp = (math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta), math.sin(psi),
                              math.cos(psi))
    f_ned = -thrust * np.array([cf * cp * st + sf * sp, cf * st * sp - cp * sf, cf * ct])
    ph_d, th_d, t_printed = eq38_printed(f_ned, psi)
    assert ph_d == pytest.approx(phi, abs=1e-12)
    assert th_d == pytest.approx(theta, abs=1e-12)
    assert t_printed == pytest.approx(-thrust * ct / st, rel=1e-12)
    assert -f_ned[2] / (math.cos(ph_d) * math.cos(th_d)) == pytest.approx(thrust, rel=1e-12)


def test_eq38_printed_thrust_divides_by_zero_at_level_attitude() -> None:
    p = VehicleParams()
    with pytest.raises(ZeroDivisionError):
        eq38_printed(np.array([0.0, 0.0, -p.hover_thrust_n]), 0.0)
