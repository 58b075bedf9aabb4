"""Attitude and thrust from a desired force (replaces eq. 38, whose printed form has typos).

Model (eqs. 11–12): the rotor thrust in NED is −R_F·[0, 0, T], gravity is +z. A desired thrust force F
(NED, N) is realised by turning the body's −z axis along F and setting T = |F|:

    z_b = −F/|F|,  y_c = [−sin ψ_d, cos ψ_d, 0],  x_b = (y_c × z_b)/|y_c × z_b|,  y_b = z_b × x_b,
    R_F = [x_b y_b z_b],  φ = atan2(R₃₂, R₃₃),  θ = −asin(R₃₁),  ψ = atan2(R₂₁, R₁₁).

Limits, in this order: F_z <= −T_min (always some lift), |F_horizontal| <= |F_z|·tan(tilt_max), and
|F| <= T_max by shrinking the horizontal part first (altitude has priority over horizontal motion).
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.rotations import quat_from_euler


def limit_force_xyz(
    fx: float, fy: float, fz: float, tilt_max_rad: float, thrust_min_n: float, thrust_max_n: float
) -> tuple[float, float, float]:
    """:func:`limit_force` on three floats (N, NED)."""
    fz = max(min(fz, -thrust_min_n), -thrust_max_n)
    h = math.hypot(fx, fy)
    h_max = min(-fz * math.tan(tilt_max_rad), math.sqrt(max(thrust_max_n * thrust_max_n - fz * fz, 0.0)))
    if h > h_max and h > 0.0:
        k = h_max / h
        fx, fy = fx * k, fy * k
    return fx, fy, fz


def limit_force(force_ned_n: np.ndarray, tilt_max_rad: float, thrust_min_n: float, thrust_max_n: float) -> np.ndarray:
    """The desired thrust force (N, NED) clipped to the tilt and thrust limits (see module docstring)."""
    fx, fy, fz = (float(v) for v in force_ned_n)
    return np.array(limit_force_xyz(fx, fy, fz, tilt_max_rad, thrust_min_n, thrust_max_n))


def attitude_from_force(force_ned_n, yaw_rad: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(quaternion [w, x, y, z] body FRD→NED, thrust N, Euler [φ, θ, ψ] rad) that produce ``force_ned_n``.

    Scalar arithmetic (cross products written out): this runs every control tick.
    """
    fx, fy, fz = map(float, force_ned_n)
    thrust = math.sqrt(fx * fx + fy * fy + fz * fz)
    if thrust < 1e-09:
        zx, zy, zz = 0.0, 0.0, 1.0
    else:
        zx, zy, zz = -fx / thrust, -fy / thrust, -fz / thrust
    # ZYX Euler: the body x axis lies in the vertical plane of the heading, so x_b ⟂ y_c and ψ is exact
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    # x_b = y_c × z_b with y_c = [−sin ψ, cos ψ, 0]
    xx, xy, xz = cy * zz, sy * zz, -sy * zy - cy * zx
    nx = math.sqrt(xx * xx + xy * xy + xz * xz)
    # (nx ~ 0: thrust horizontal across the heading, never reached within the tilt limits)
    if nx >= 1e-6:
        xx, xy, xz = xx / nx, xy / nx, xz / nx
    else:
        xx, xy, xz = cy, sy, 0.0
    # y_b = z_b × x_b; only its z component is needed
    yb_z = zx * xy - zy * xx
    phi = math.atan2(yb_z, zz)
    theta = -math.asin(max(-1.0, min(1.0, xz)))
    psi = math.atan2(xy, xx)
    return quat_from_euler(phi, theta, psi), thrust, np.array((phi, theta, psi))
