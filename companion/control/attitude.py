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

from companion.rotations import quat_from_euler


def limit_force(force_ned_n: np.ndarray, tilt_max_rad: float, thrust_min_n: float, thrust_max_n: float) -> np.ndarray:
    """The desired thrust force (N, NED) clipped to the tilt and thrust limits (see module docstring)."""
    f = np.array(force_ned_n, dtype=np.float64)
    f[2] = min(f[2], -thrust_min_n)
    f[2] = max(f[2], -thrust_max_n)
    h = math.hypot(f[0], f[1])
    h_max = min(-f[2] * math.tan(tilt_max_rad), math.sqrt(max(thrust_max_n**2 - f[2] ** 2, 0.0)))
    if h > h_max and h > 0.0:
        f[:2] *= h_max / h
    return f


def attitude_from_force(force_ned_n: np.ndarray, yaw_rad: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(quaternion [w, x, y, z] body FRD→NED, thrust N, Euler [φ, θ, ψ] rad) that produce ``force_ned_n``."""
    f = np.asarray(force_ned_n, dtype=np.float64)
    thrust = float(np.linalg.norm(f))
    z_b = np.array([0.0, 0.0, 1.0]) if thrust < 1e-09 else -f / thrust
    # ZYX Euler: the body x axis lies in the vertical plane of the heading, so x_b ⟂ y_c and ψ is exact
    y_c = np.array([-math.sin(yaw_rad), math.cos(yaw_rad), 0.0])
    x_b = np.cross(y_c, z_b)
    nx = float(np.linalg.norm(x_b))
    # (nx ~ 0: thrust horizontal across the heading, never reached within the tilt limits)
    x_b = x_b / nx if nx >= 1e-6 else np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
    y_b = np.cross(z_b, x_b)
    phi = math.atan2(y_b[2], z_b[2])
    theta = -math.asin(max(-1.0, min(1.0, x_b[2])))
    psi = math.atan2(x_b[1], x_b[0])
    euler = np.array([phi, theta, psi])
    return quat_from_euler(phi, theta, psi), thrust, euler
