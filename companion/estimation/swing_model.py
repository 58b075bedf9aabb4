"""Process and measurement models of the swing estimator, reduced from the project's Lagrangian model.

The estimator does not integrate the whole 8-DOF model: the autopilot measures and controls the attitude, so
the attitude R (body FRD → NED, eq. 12) and the collective thrust T are *inputs*. The translation + swing
block of ``companion.core.model`` (derived from eq. 10, see ``docs/model-derivation.md``) then gives the
airframe acceleration ξ̈ and the swing accelerations s̈ = [α̈, β̈] in closed form, with J = ∂r/∂s for the
payload offset r = l·[sα·cβ, −sβ, cα·cβ] and a_c = J̇·ṡ::

    r_ξ = F + d + (M+m)·g·e_z − m·a_c,          F = −R·[0, 0, T]ᵀ   (eq. 11)
    r_s = −m·Jᵀ·(a_c − g·e_z)
    s̈   = diag(1/k_α, 1/k_β)·(r_s − m·Jᵀ·r_ξ/(M+m)),   k_α = m·l²·cβ²·M/(M+m) + Ip,  k_β = m·l²·M/(M+m) + Ip
    ξ̈   = (r_ξ − m·J·s̈)/(M+m)

``d`` (N, NED) is every force on the airframe the model does not know: wind, drag, thrust-model error. Eq. 14
applies it to ξ only (its two swing rows are zero), i.e. it acts on the airframe, not on the payload.

The airframe's own drag changes as fast as its velocity, too fast for a random walk to follow, so its part that is
linear in the velocity is modelled: f = F − c·(v_N, v_E, 0) + d, with c (N per m/s) a state. Rotors drag linearly
in the airspeed across them (blade flapping and induced drag; ArduPilot's EKF has EK3_DRAG_MCOEF for it, and its
SITL quad drags ~1 N per m/s); with it d is left the wind and the slow rest. The bundled vehicle has no drag
(c = 0): the estimator learns that too. Only the horizontal part: along z, drag and thrust error are one (δT).

The payload drags too: p = −k·|v_p|·v_p on the payload (v_p = v + J·ṡ its velocity, still air), k a state. In
cruise it makes the payload trail behind the vertical by k·v²/(m·g) (0.06 rad at 1.8 m/s for ArduPilot's SITL
payload, 0.25 kg of 30 cm sphere); without it that pull on the airframe would be read as the airframe's own drag
and the trailing angle missed. It enters the Lagrangian's generalized forces as p on ξ and Jᵀ·p on s.

State x (16,)::

    [α, β, α̇, β̇,  v_N, v_E, v_D,  d_N, d_E, d_D,  b_x, b_y, b_z,  δT,  c,  k]
     rad, rad/s    airframe m/s     force on the airframe, N  accelerometer bias, m/s², body FRD  thrust error, N
                                      airframe drag, N per m/s; payload drag, N per (m/s)²

The thrust in the model is the commanded one plus δT (F = −R·[0, 0, T + δT]): the thrust a vehicle produces
is not the thrust the companion asked for (thrust curve, hover-thrust normalization, motor lag, and a rotor
that saturates while the attitude loop fights a torque). δT is fast (the accelerometer's z axis pins it), d
is slow (wind, drag).

Process model (python-control's f(t, x, u, params)): α̇, β̇ as states, [α̈, β̈] and v̇ = ξ̈ from the closed form
above; d, b, δT, c and k are random walks (zero drift plus process noise). u = [T, φ, θ, ψ] (N, rad).

Measurement models:

* accelerometer (HIGHRES_IMU / SCALED_IMU, specific force in body FRD, m/s²)::

      f_b = Rᵀ·(ξ̈ − g·e_z) + b      ⇔      M·(R·(f_b − b)) = F + d + T_cable,   T_cable = t·r/l

  (the airframe's Newton equation: thrust, cable tension and the unknown force d are the only non-gravity
  forces on it; the tension follows from the payload's dynamics, which is what the closed form encodes);
* payload position fix relative to the airframe (NED, m): h = r(α, β) = l·[sα·cβ, −sβ, cα·cβ];
* airframe velocity (LOCAL_POSITION_NED, m/s): h = v.

Pure: numpy and math only. The scalar kernel :func:`translation_swing_accel` is the same algebra as
``companion.core.model._deriv`` (tests compare the two on random states).
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.vehicle_params import VehicleParams

N_STATE = 16
I_AL, I_BE, I_DAL, I_DBE = 0, 1, 2, 3
I_THRUST = 13
I_DRAG = 14
I_PDRAG = 15
SL_SWING = slice(0, 4)
SL_VEL = slice(4, 7)
SL_FORCE = slice(7, 10)
SL_BIAS = slice(10, 13)
STATE_NAMES = ("alpha", "beta", "alpha_dot", "beta_dot", "v_n", "v_e", "v_d", "d_n", "d_e", "d_d",
               "b_x", "b_y", "b_z", "thrust_err", "drag_coef", "payload_drag")


def rotation_from_euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """R_F of eq. 12 (body FRD → NED), 3×3."""
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    sp, cp = math.sin(psi), math.cos(psi)
    return np.array([[ct * cp, cp * st * sf - cf * sp, cf * cp * st + sf * sp],
                     [ct * sp, sf * st * sp + cf * cp, cf * st * sp - cp * sf],
                     [-st, sf * ct, cf * ct]])


def rotation_from_quat(q_wxyz) -> np.ndarray:
    """Rotation matrix (body FRD → NED) of a unit quaternion [w, x, y, z] (normalized here)."""
    w, x, y, z = (float(v) for v in q_wxyz)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"quaternion {[w, x, y, z]} has no direction")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rotate_by_rates(R: np.ndarray, rates_frd_rad_s, dt_s: float) -> np.ndarray:
    """R·Exp([ω·dt]×): the attitude ``dt_s`` later at constant body rates (Rodrigues)."""
    wx, wy, wz = (float(v) * dt_s for v in rates_frd_rad_s)
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-18:
        return R
    th = math.sqrt(th2)
    s = math.sin(th) / th
    c = (1.0 - math.cos(th)) / th2
    E = np.array([[1.0 - c * (wy * wy + wz * wz), -s * wz + c * wx * wy, s * wy + c * wx * wz],
                  [s * wz + c * wx * wy, 1.0 - c * (wx * wx + wz * wz), -s * wx + c * wy * wz],
                  [-s * wy + c * wx * wz, s * wx + c * wy * wz, 1.0 - c * (wx * wx + wy * wy)]])
    return R @ E


def thrust_axis_by_rates(R, rates_frd_rad_s, dt_s: float) -> tuple[float, float, float]:
    """Third column of :func:`rotate_by_rates` (the body z axis in NED), as three floats, without matrices."""
    wx = rates_frd_rad_s[0] * dt_s
    wy = rates_frd_rad_s[1] * dt_s
    wz = rates_frd_rad_s[2] * dt_s
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-18:
        return R[0][2], R[1][2], R[2][2]
    th = math.sqrt(th2)
    s = math.sin(th) / th
    c = (1.0 - math.cos(th)) / th2
    v0 = s * wy + c * wx * wz
    v1 = -s * wx + c * wy * wz
    v2 = 1.0 - c * (wx * wx + wy * wy)
    r0, r1, r2 = R[0], R[1], R[2]
    return (r0[0] * v0 + r0[1] * v1 + r0[2] * v2, r1[0] * v0 + r1[1] * v1 + r1[2] * v2,
            r2[0] * v0 + r2[1] * v1 + r2[2] * v2)


def thrust_force_ned_n(R: np.ndarray, thrust_n: float) -> tuple[float, float, float]:
    """F = −R·[0, 0, T] (eq. 11), N, NED."""
    return -R[0, 2] * thrust_n, -R[1, 2] * thrust_n, -R[2, 2] * thrust_n


def translation_swing_accel(
    al: float, be: float, dal: float, dbe: float, fx: float, fy: float, fz: float,
    M: float, m: float, g: float, Ip: float, l: float, px: float = 0.0, py: float = 0.0, pz: float = 0.0,
) -> tuple[float, float, float, float, float]:
    """(α̈, β̈, ẍ, ÿ, z̈) of the model for swing state (α, β, α̇, β̇), the non-gravity, non-cable force on
    the airframe f (thrust, drag and d; N, NED) and a force p on the payload (its drag; N, NED). rad/s², m/s².
    With p = 0 the same algebra as ``companion.core.model._deriv``; p enters as its generalized forces (the
    payload sits at ξ + r(s)): p on ξ and Jᵀ·p on s."""
    sa, ca, sb, cb = math.sin(al), math.cos(al), math.sin(be), math.cos(be)
    mt = M + m
    j0a = l * ca * cb
    j0b = -l * sa * sb
    j1b = -l * cb
    j2a = -l * sa * cb
    j2b = -l * ca * sb
    dal2 = dal * dal
    dbe2 = dbe * dbe
    ac0 = l * (-sa * cb * (dal2 + dbe2) - 2.0 * ca * sb * dal * dbe)
    ac1 = l * (sb * dbe2)
    ac2 = l * (-ca * cb * (dal2 + dbe2) + 2.0 * sa * sb * dal * dbe)
    r0 = fx + px - m * ac0
    r1 = fy + py - m * ac1
    r2 = fz + pz + mt * g - m * ac2
    rsa = -m * (j0a * ac0 + j2a * (ac2 - g)) + j0a * px + j2a * pz
    rsb = -m * (j0b * ac0 + j1b * ac1 + j2b * (ac2 - g)) + j0b * px + j1b * py + j2b * pz
    ka = m * l * l * cb * cb * M / mt + Ip
    kb = m * l * l * M / mt + Ip
    dda = (rsa - m * (j0a * r0 + j2a * r2) / mt) / ka
    ddb = (rsb - m * (j0b * r0 + j1b * r1 + j2b * r2) / mt) / kb
    ax = (r0 - m * (j0a * dda + j0b * ddb)) / mt
    ay = (r1 - m * j1b * ddb) / mt
    az = (r2 - m * (j2a * dda + j2b * ddb)) / mt
    return dda, ddb, ax, ay, az


def payload_drag_unit(al: float, be: float, dal: float, dbe: float, vn: float, ve: float, vd: float,
                      l: float) -> tuple[float, float, float]:
    """−|v_p|·v_p for the payload's velocity v_p = v + J·ṡ (m/s, NED): its quadratic drag per unit coefficient
    (multiply by k, N per (m/s)², for the force in N). Still air: the wind on the payload is not modelled."""
    sa, ca, sb, cb = math.sin(al), math.cos(al), math.sin(be), math.cos(be)
    un = vn + l * (ca * cb * dal - sa * sb * dbe)
    ue = ve - l * cb * dbe
    ud = vd + l * (-sa * cb * dal - ca * sb * dbe)
    s = math.sqrt(un * un + ue * ue + ud * ud)
    return -s * un, -s * ue, -s * ud


def accel_force_jacobian_rows(al: float, be: float, M: float, m: float, Ip: float, l: float) -> tuple:
    """∂(α̈, β̈, ẍ, ÿ, z̈)/∂f as five row tuples of three floats, for the force f on the airframe (N, NED); the
    accelerations are affine in f: ∂s̈/∂f = −m·K⁻¹·Jᵀ/(M+m), ∂ξ̈/∂f = (I − m·J·∂s̈/∂f)/(M+m)."""
    sa, ca, sb, cb = math.sin(al), math.cos(al), math.sin(be), math.cos(be)
    mt = M + m
    ja0, ja2 = l * ca * cb, -l * sa * cb
    jb0, jb1, jb2 = -l * sa * sb, -l * cb, -l * ca * sb
    ka = m * l * l * cb * cb * M / mt + Ip
    kb = m * l * l * M / mt + Ip
    qa = -m / (mt * ka)
    qb = -m / (mt * kb)
    ua0, ua2 = qa * ja0, qa * ja2
    ub0, ub1, ub2 = qb * jb0, qb * jb1, qb * jb2
    k = m / mt
    it = 1.0 / mt
    return (
        (ua0, 0.0, ua2),
        (ub0, ub1, ub2),
        (it - k * (ja0 * ua0 + jb0 * ub0), -k * jb0 * ub1, -k * (ja0 * ua2 + jb0 * ub2)),
        (-k * jb1 * ub0, it - k * jb1 * ub1, -k * jb1 * ub2),
        (-k * (ja2 * ua0 + jb2 * ub0), -k * jb2 * ub1, it - k * (ja2 * ua2 + jb2 * ub2)),
    )


def accel_force_jacobian(al: float, be: float, M: float, m: float, Ip: float, l: float) -> np.ndarray:
    """:func:`accel_force_jacobian_rows` as a 5×3 array."""
    return np.array(accel_force_jacobian_rows(al, be, M, m, Ip, l))


def payload_offset_m(al: float, be: float, l: float) -> tuple[float, float, float]:
    """r = ξ_p − ξ = l·[sα·cβ, −sβ, cα·cβ] (eqs. 3–4), NED metres."""
    cb = math.cos(be)
    return l * math.sin(al) * cb, -l * math.sin(be), l * math.cos(al) * cb


def payload_offset_jacobian(al: float, be: float, l: float) -> np.ndarray:
    """J = ∂r/∂(α, β), 3×2."""
    sa, ca, sb, cb = math.sin(al), math.cos(al), math.sin(be), math.cos(be)
    return l * np.array([[ca * cb, -sa * sb], [0.0, -cb], [-sa * cb, -ca * sb]])


def swing_from_offset(offset_ned_m) -> tuple[float, float]:
    """(α, β) of a payload offset r (NED, any length > 0): β = asin(−r_y/|r|), α = atan2(r_x, r_z)."""
    rx, ry, rz = (float(v) for v in offset_ned_m)
    n = math.sqrt(rx * rx + ry * ry + rz * rz)
    if not (n > 1e-9 and math.isfinite(n)):
        raise ValueError(f"payload offset {[rx, ry, rz]} has no direction")
    return math.atan2(rx, rz), math.asin(max(-1.0, min(1.0, -ry / n)))


def airframe_force_ned_n(x, R: np.ndarray, thrust_n: float) -> tuple[float, float, float]:
    """f = F − c·(v_N, v_E, 0) + d: every non-gravity, non-cable force on the airframe in state x (N, NED), thrust
    ``thrust_n`` + δT along −z body."""
    fx, fy, fz = thrust_force_ned_n(R, thrust_n + float(x[I_THRUST]))
    c = float(x[I_DRAG])
    return fx - c * float(x[4]) + float(x[7]), fy - c * float(x[5]) + float(x[8]), fz + float(x[9])


def payload_force_ned_n(x, l: float) -> tuple[float, float, float]:
    """p = −k·|v_p|·v_p, the payload's drag in state x (N, NED)."""
    k = float(x[I_PDRAG])
    u = payload_drag_unit(float(x[0]), float(x[1]), float(x[2]), float(x[3]), float(x[4]), float(x[5]),
                          float(x[6]), l)
    return k * u[0], k * u[1], k * u[2]


def dynamics(t: float, x, u, params: VehicleParams) -> np.ndarray:
    """ẋ = f(t, x, u, params) of the estimator's state (16,), u = [T (N), φ, θ, ψ (rad)] (python-control's
    convention). The random-walk states (d, b, δT, c, k) have zero drift."""
    x = np.asarray(x, dtype=np.float64)
    R = rotation_from_euler(float(u[1]), float(u[2]), float(u[3]))
    fx, fy, fz = airframe_force_ned_n(x, R, float(u[0]))
    p = params
    dda, ddb, ax, ay, az = translation_swing_accel(
        x[0], x[1], x[2], x[3], fx, fy, fz, p.M, p.m, p.g, p.Ip, p.l, *payload_force_ned_n(x, p.l))
    out = np.zeros(N_STATE)
    out[0], out[1], out[2], out[3] = x[2], x[3], dda, ddb
    out[4], out[5], out[6] = ax, ay, az
    return out


def imu_specific_force(x, R: np.ndarray, thrust_n: float, params: VehicleParams) -> np.ndarray:
    """Predicted accelerometer reading f_b = Rᵀ·(ξ̈ − g·e_z) + b (m/s², body FRD)."""
    x = np.asarray(x, dtype=np.float64)
    fx, fy, fz = airframe_force_ned_n(x, R, thrust_n)
    p = params
    _, _, ax, ay, az = translation_swing_accel(x[0], x[1], x[2], x[3], fx, fy, fz, p.M, p.m, p.g, p.Ip, p.l,
                                               *payload_force_ned_n(x, p.l))
    return R.T @ np.array([ax, ay, az - p.g]) + x[SL_BIAS]


def payload_offset_from_global(
    payload_lat_deg: float, payload_lon_deg: float, payload_alt_m: float,
    vehicle_lat_deg: float, vehicle_lon_deg: float, vehicle_alt_m: float,
) -> np.ndarray:
    """Payload position relative to the vehicle (NED, m) from two GLOBAL_POSITION_INT fixes (degrees, metres
    above MSL), the way ArduPilot's slung-payload convention gives it. Local flat-earth (WGS-84 radii of
    curvature at the vehicle's latitude): exact to < 1 mm over a cable's length."""
    a = 6378137.0
    e2 = 6.69437999014e-3
    lat = math.radians(vehicle_lat_deg)
    s = math.sin(lat)
    w = math.sqrt(1.0 - e2 * s * s)
    r_n = a * (1.0 - e2) / (w * w * w)  # meridian radius
    r_e = a / w  # prime vertical radius
    dn = math.radians(payload_lat_deg - vehicle_lat_deg) * (r_n + vehicle_alt_m)
    de = math.radians(payload_lon_deg - vehicle_lon_deg) * (r_e + vehicle_alt_m) * math.cos(lat)
    return np.array([dn, de, -(payload_alt_m - vehicle_alt_m)])
