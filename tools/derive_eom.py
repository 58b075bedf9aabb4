"""Derive the quadrotor–payload equations of motion symbolically and set them against the paper's print.

Development-time generator (needs sympy, which is *not* a runtime dependency of slungpilot):

    .venv/bin/python tools/derive_eom.py            # derivation + comparison report
    .venv/bin/python tools/derive_eom.py --quiet    # comparison report only

Route (paper eqs. 3–15, NED, z down, gravity along +z):

1. payload position ξ_p = ξ + T_p·[0, 0, l] with T_p = Rot_y(α)·Rot_x(β) (eqs. 2–4);
2. K = ½M·ξ̇ᵀξ̇ + ½ΩᵀIΩ + ½m·ξ̇_pᵀξ̇_p + ½Ip(α̇² + β̇²), Ω = R_η·η̇ (eqs. 6–8);
   V = −M·g·z − m·g·z_p (eq. 9); L = K − V (eq. 10, checked against the printed eq. 10);
3. Euler–Lagrange d/dt(∂L/∂q̇) − ∂L/∂q = Q (eq. 14) with
   Q = [F + d_ξ, R_ηᵀ·(τ + d_τ), 0, 0] (physical: τ is a body-frame torque) and, for a like-for-like
   comparison with the print, Q = [F + d_ξ, τ + d_τ, 0, 0] (eq. 15's identity mapping);
4. every printed equation (eqs. 16, 17, 18, 29, 38) is transcribed below as printed and the difference
   derived − printed is simplified and reported. A zero difference means the printed equation is right.

The numeric twin of this script (no sympy) is tests/test_model_lagrangian.py and
tests/test_printed_equations.py; the write-up is docs/model-derivation.md.
"""

from __future__ import annotations

import argparse
import sys

import sympy as sp

t = sp.Symbol("t")
M, m, g, l, Ip = sp.symbols("M m g l I_p", positive=True)
Ixx, Iyy, Izz = sp.symbols("I_xx I_yy I_zz", positive=True)
T = sp.Symbol("T")
tau_phi, tau_th, tau_psi = sp.symbols("tau_phi tau_theta tau_psi")
dx, dy, dz, dphi, dth, dpsi = sp.symbols("d_x d_y d_z d_phi d_theta d_psi")

NAMES = ["x", "y", "z", "phi", "theta", "psi", "alpha", "beta"]
q = [sp.Function(n)(t) for n in NAMES]
x, y, z, phi, th, psi, al, be = q
qd = [sp.diff(v, t) for v in q]
qdd = [sp.diff(v, t, 2) for v in q]

# Plain symbols for printing / substitution: phi, phi_d, phi_dd ...
S = {n: sp.Symbol(n) for n in NAMES}
SD = {n: sp.Symbol(n + "_d") for n in NAMES}
SDD = {n: sp.Symbol(n + "_dd") for n in NAMES}


def plain(expr: sp.Expr) -> sp.Expr:
    """Replace the functions of t by plain symbols (second derivatives first)."""
    rep = {}
    for n, vd, vdd in zip(NAMES, qd, qdd, strict=True):
        rep[vdd] = SDD[n]
        rep[vd] = SD[n]
    expr = expr.subs(rep)
    return expr.subs({v: S[n] for n, v in zip(NAMES, q, strict=True)})


def s(a: sp.Expr) -> sp.Expr:
    return sp.sin(a)


def c(a: sp.Expr) -> sp.Expr:
    return sp.cos(a)


# ---------------------------------------------------------------------------------------------------------
# Eqs. 3–9: kinematics and energies.

rot_y_alpha = sp.Matrix([[c(al), 0, s(al)], [0, 1, 0], [-s(al), 0, c(al)]])
rot_x_beta = sp.Matrix([[1, 0, 0], [0, c(be), -s(be)], [0, s(be), c(be)]])
T_p = rot_y_alpha * rot_x_beta
T_p_printed = sp.Matrix(
    [
        [c(al), s(al) * s(be), s(al) * c(be)],
        [0, c(be), -s(be)],
        [-s(al), s(be) * c(al), c(al) * c(be)],
    ]
)
xi = sp.Matrix([x, y, z])
xi_p = xi + T_p * sp.Matrix([0, 0, l])

R_eta = sp.Matrix([[1, 0, -s(th)], [0, c(phi), s(phi) * c(th)], [0, -s(phi), c(phi) * c(th)]])
eta_d = sp.Matrix(qd[3:6])
Omega = R_eta * eta_d
I_body = sp.diag(Ixx, Iyy, Izz)

xi_d = xi.diff(t)
xi_p_d = xi_p.diff(t)
K = (
    sp.Rational(1, 2) * M * (xi_d.T * xi_d)[0]
    + sp.Rational(1, 2) * (Omega.T * I_body * Omega)[0]
    + sp.Rational(1, 2) * m * (xi_p_d.T * xi_p_d)[0]
    + sp.Rational(1, 2) * Ip * (qd[6] ** 2 + qd[7] ** 2)
)
V = M * g * (-z) + m * g * (-xi_p[2])
L = K - V

# Eq. 10 as printed.
xd_, yd_, zd_, phid_, thd_, psid_, ald_, bed_ = qd
L_printed = (
    sp.Rational(1, 2) * (M + m) * (xd_**2 + yd_**2 + zd_**2)
    + sp.Rational(1, 2) * (Ixx * s(th) ** 2 + Iyy * c(th) ** 2 * s(phi) ** 2 + Izz * c(th) ** 2 * c(phi) ** 2)
    * psid_**2
    + sp.Rational(1, 2) * (Iyy * c(phi) ** 2 + Izz * s(phi) ** 2) * thd_**2
    + sp.Rational(1, 2) * Ixx * phid_**2
    + sp.Rational(1, 2) * m * l**2 * bed_**2
    - m * l * c(be) * yd_ * bed_
    + sp.Rational(1, 2) * m * l**2 * ald_**2 * c(be) ** 2
    + sp.Rational(1, 2) * Ip * (ald_**2 + bed_**2)
    - Ixx * s(th) * psid_ * phid_
    + (Iyy - Izz) * c(th) * c(phi) * s(phi) * psid_ * thd_
    - m * l * bed_ * s(be) * (s(al) * xd_ + c(al) * zd_)
    + m * l * ald_ * c(be) * (c(al) * xd_ - s(al) * zd_)
    + M * g * z
    + m * g * (z + l * c(al) * c(be))
)

# ---------------------------------------------------------------------------------------------------------
# Eqs. 11–15: generalized forces.

R_F = sp.Matrix(
    [
        [c(th) * c(psi), c(psi) * s(th) * s(phi) - c(phi) * s(psi), c(phi) * c(psi) * s(th) + s(phi) * s(psi)],
        [c(th) * s(psi), s(phi) * s(th) * s(psi) + c(phi) * c(psi), c(phi) * s(th) * s(psi) - c(psi) * s(phi)],
        [-s(th), s(phi) * c(th), c(phi) * c(th)],
    ]
)
F = -R_F * sp.Matrix([0, 0, T])
tau = sp.Matrix([tau_phi, tau_th, tau_psi])
d_tau = sp.Matrix([dphi, dth, dpsi])
d_xi = sp.Matrix([dx, dy, dz])
Q_phys = list(F + d_xi) + list(R_eta.T * (tau + d_tau)) + [0, 0]
Q_ident = list(F + d_xi) + list(tau + d_tau) + [0, 0]


def euler_lagrange_lhs(lagr: sp.Expr) -> list[sp.Expr]:
    """d/dt(∂L/∂q̇_i) − ∂L/∂q_i for the eight coordinates."""
    return [sp.expand(sp.diff(sp.diff(lagr, vd), t) - sp.diff(lagr, v)) for v, vd in zip(q, qd, strict=True)]


def zero(expr: sp.Expr) -> bool:
    """True if a trigonometric polynomial expression is identically zero."""
    e = sp.expand(sp.expand_trig(plain(expr)))
    if e == 0:
        return True
    return sp.simplify(e) == 0


def simp(expr: sp.Expr) -> str:
    """Readable form of an expression polynomial in the rates/accelerations: one factored coefficient per
    monomial in (q̇, q̈, g), e.g. ``(I_yy - I_zz)*sin(phi)*cos(phi)*cos(theta) * (psi_dd)``."""
    e = sp.expand(sp.expand_trig(plain(expr)))
    if e == 0:
        return "0"
    num, den = sp.fraction(sp.together(e))
    gens = [SDD[n] for n in NAMES] + [SD[n] for n in NAMES] + [g]
    gens = [v for v in gens if num.has(v)]
    if not gens:
        return str(sp.factor(e))
    parts = []
    for monom, coef in sp.Poly(sp.expand(num), *gens).terms():
        mono = sp.Mul(*[v**k for v, k in zip(gens, monom, strict=True)])
        parts.append(f"[{sp.factor(sp.trigsimp(coef))}]*{mono}")
    body = " + ".join(parts)
    return body if den == 1 else f"({body}) / ({sp.factor(den)})"


# ---------------------------------------------------------------------------------------------------------
# The printed equations, transcribed symbol by symbol (right-hand sides; left side is F + d or τ + d).

a_dd, b_dd = qdd[6], qdd[7]
ad, bd = qd[6], qd[7]
xdd, ydd, zdd, phidd, thdd, psidd = qdd[:6]
phid, thd, psid = qd[3:6]
sa, ca, sb, cb = s(al), c(al), s(be), c(be)
sf, cf, st, ct = s(phi), c(phi), s(th), c(th)

EQ16_PRINTED_RHS = [
    (M + m) * xdd + m * l * ca * cb * a_dd - m * l * sa * sb * b_dd
    - 2 * m * l * sb * ca * ad * bd - m * l * cb * sa * ad**2 - m * l * cb * sa * bd**2,
    (M + m) * ydd - m * l * cb * b_dd + m * l * sb * bd**2,
    (M + m) * zdd - m * l * sa * cb * a_dd - m * l * ca * sb * b_dd + 2 * m * l * sb * sa * ad * bd
    - m * l * cb * ca * ad**2 - m * l * cb * ca * bd**2 - (M + m) * g,
]

D_ = Iyy - Izz
EQ17_PRINTED_RHS = [
    # φ row
    Ixx * phidd - Ixx * st * psidd - D_ * sf * cf * ct**2 * psid**2
    + (-Ixx * psid * ct + D_ * (thd * sf * cf + psid * ct * sf**2 - psid * ct * cf**2)) * thd,
    # θ row (note the printed "{(Iyy − Izz)cθcφsφ} ψ̇" — a velocity where an acceleration belongs)
    (Iyy * cf**2 + Izz * sf**2) * thdd + (D_ * ct * cf * sf) * psid
    + (Ixx * psid * ct + D_ * (-2 * thd * sf * cf + psid * ct * cf**2 - psid * ct * sf**2)) * phid
    + st * ct * (-Ixx + Iyy * sf**2 + Izz * cf**2) * psid**2,
    # ψ row (printed "{Ixx s²θ + c²θ(...)} ψ̇" — again a velocity where ψ̈ belongs)
    -Ixx * st * phidd + D_ * ct * cf * sf * thdd
    + (Ixx * st**2 + ct**2 * (Izz * cf**2 + Iyy * sf**2)) * psid
    - Izz * phid * ct**2 * sf * cf * psid
    - (Ixx * thd * ct - D_ * psid * ct**2 * sf * cf) * phid
    + Iyy * phid * ct**2 * sf * cf * psid
    + (Ixx * psid * st * ct - D_ * (thd * st * cf * sf + phid * ct * sf**2 - phid * ct * cf**2)) * thd
    + (Ixx * thd * st * ct - 2 * (Iyy * sf**2 + Izz * cf**2) * thd * st * ct) * psid,
]

EQ18_PRINTED = [
    (-ca * cb * xdd + sa * cb * zdd + 2 * l * ad * bd * cb * sb - g * cb * sa) * m * l / (Ip + m * l**2 * cb**2),
    (sa * sb * xdd + cb * ydd + ca * sb * zdd + l * ad**2 * cb * sb + g * sb * ca) * m * l / (Ip + m * l**2),
]

# Eq. 29: (M+m)ξ̈ = F + f + (0, 0, (M+m)g) + d, with f1..f3 as printed.
EQ29_F_PRINTED = [
    -m * l * ca * cb * a_dd + m * sa * sb * l * b_dd + m * l * (bd * sb * ca + cb * sa * ad) * ad
    + m * l * (bd * cb * sa + ad * sb * ca) * bd,
    m * l * cb * b_dd - m * l * sb * bd**2,
    m * l * sa * cb * a_dd + m * l * ca * sb * b_dd - m * l * (bd * sb * sa - ad * cb * ca) * ad
    - m * l * (ad * sb * sa - bd * cb * ca) * bd,
]


def report(verbose: bool) -> int:
    """Derive, compare, print. Returns the number of printed equations found wrong."""
    out = sys.stdout.write
    wrong = 0

    out("== Eq. 4: T_p = Rot_y(α)·Rot_x(β) vs printed: ")
    out("equal\n" if all(zero(e) for e in (T_p - T_p_printed)) else "DIFFERENT\n")
    out("   payload offset T_p·[0,0,l] = " + str(plain(sp.simplify(T_p * sp.Matrix([0, 0, l])).T)) + "\n")

    out("== Eq. 10: Lagrangian from eqs. 3–9 vs printed: ")
    dl = sp.expand(sp.expand_trig(L - L_printed))
    dl = sp.simplify(dl)
    out("equal\n" if dl == 0 else f"DIFFERENT by {simp(dl)}\n")
    wrong += dl != 0

    lhs = euler_lagrange_lhs(L)

    # Eq. 16: translation rows, EL_lhs = F + d  (gravity is inside the EL lhs through ∂V/∂z).
    out("== Eq. 16 (translation): derived  F + d = ...\n")
    for i, name in enumerate(("x", "y", "z")):
        if verbose:
            out(f"   {name}: {simp(lhs[i])}\n")
        diff = lhs[i] - EQ16_PRINTED_RHS[i]
        ok = zero(diff)
        wrong += not ok
        out(f"   {name} row vs printed: " + ("equal\n" if ok else f"derived − printed = {simp(diff)}\n"))

    # Eq. 29 f1..f3: (M+m)ξ̈ = F + d + (M+m)g·e_z + f with F + d = lhs  ⇒  f = (M+m)ξ̈ − lhs − (M+m)g·e_z.
    out("== Eq. 29 (f1–f3, payload reaction on the quadrotor)\n")
    for i in range(3):
        f_derived = (M + m) * qdd[i] - lhs[i] - ((M + m) * g if i == 2 else 0)
        diff = f_derived - EQ29_F_PRINTED[i]
        ok = zero(diff)
        wrong += not ok
        out(f"   f{i + 1}: " + ("equal\n" if ok else f"derived − printed = {simp(diff)}\n"))

    # Eq. 18: swing rows are lhs = 0; solve each for its own second derivative.
    out("== Eq. 18 (swing), solved for α̈ and β̈ with ξ̈ as a given\n")
    for k, (idx, nm) in enumerate(((6, "alpha"), (7, "beta"))):
        sol = sp.solve(sp.Eq(lhs[idx], 0), qdd[idx])[0]
        # eq. 18 has no cross term in the other swing acceleration (JᵀJ is diagonal): check
        assert sp.simplify(sp.diff(sol, qdd[13 - idx])) == 0
        if verbose:
            out(f"   {nm}_dd = {simp(sol)}\n")
        diff = sp.simplify(sp.expand_trig(sol - EQ18_PRINTED[k]))
        ok = diff == 0
        wrong += not ok
        out(f"   {nm} vs printed: " + ("equal\n" if ok else f"derived − printed = {simp(diff)}\n"))

    # Eq. 17: rotation rows with the identity torque mapping of eq. 15 (like-for-like with the print).
    out("== Eq. 17 (rotation, identity torque mapping τ of eq. 15): derived τ + d = ...\n")
    for i, name in ((3, "phi"), (4, "theta"), (5, "psi")):
        if verbose:
            out(f"   {name}: {simp(lhs[i])}\n")
        diff = lhs[i] - EQ17_PRINTED_RHS[i - 3]
        ok = zero(diff)
        wrong += not ok
        out(f"   {name} row vs printed: " + ("equal\n" if ok else f"derived − printed = {simp(diff)}\n"))

    # Physical mapping: EL rotation rows = R_ηᵀ·(I·Ω̇ + Ω×IΩ), i.e. Euler's equations with τ in body axes.
    out("== Rotation with Q = R_ηᵀ·(τ + d): EL rows ≡ R_ηᵀ·(I·Ω̇ + Ω × I·Ω)? ")
    Om_d = Omega.diff(t)
    euler = I_body * Om_d + Omega.cross(I_body * Omega)
    ok = all(zero(e) for e in (sp.Matrix(lhs[3:6]) - R_eta.T * euler))
    out("yes (Euler's equations, body-frame torque)\n" if ok else "NO\n")
    wrong += not ok
    out("   generalized torque R_ηᵀ·τ (physical) vs τ (eq. 15), per row:\n")
    for name, qp, qi in zip(("phi", "theta", "psi"), Q_phys[3:6], Q_ident[3:6], strict=True):
        out(f"     {name}: {plain(sp.expand(qp))}    (eq. 15: {plain(qi)})\n")
    if verbose:
        out("   closed form used in companion.core.model._deriv: I·Ω̇ = τ + d − Ω×IΩ;  η̈ = R_η⁻¹(Ω̇ − Ṙ_η·η̇)\n")

    # Eq. 38: thrust-direction inversion.
    out("== Eq. 38 (attitude + thrust from F = −R_F·[0,0,T])\n")
    Fx, Fy, Fz = F
    tan_th = sp.simplify((Fx * c(psi) + Fy * s(psi)) / Fz)
    tan_phi_over = sp.simplify((Fx * s(psi) - Fy * c(psi)) * c(th) / Fz)
    out(f"   (Fx cψ + Fy sψ)/Fz = {plain(tan_th)}   (printed: tan θ_d)\n")
    out(f"   (Fx sψ − Fy cψ)cθ/Fz = {plain(tan_phi_over)}   (printed: tan φ_d)\n")
    t_print = sp.simplify(Fz / (c(phi) * s(th)))
    t_true = sp.simplify(-Fz / (c(phi) * c(th)))
    out(f"   printed T = Fz/(cφ sθ) evaluates to {plain(t_print)};  −Fz/(cφ cθ) = {plain(t_true)}\n")
    wrong += sp.simplify(t_print - T) != 0
    out(f"== {wrong} printed equation rows differ from the derivation\n")
    return wrong


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quiet", action="store_true", help="print the comparison only, not the derived equations")
    args = ap.parse_args(argv)
    report(verbose=not args.quiet)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
