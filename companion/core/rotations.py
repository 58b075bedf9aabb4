"""Attitude conversions between ZYX Euler angles (φ, θ, ψ) and quaternions, MAVLink conventions.

Quaternions are [w, x, y, z] and rotate body FRD into NED, as in MAVLink's ATTITUDE_QUATERNION and
SET_ATTITUDE_TARGET; they match :func:`companion.core.model.rotation_body_to_ned` (eq. 12).
"""

from __future__ import annotations

import math

import numpy as np


def quat_from_euler(phi: float, theta: float, psi: float) -> np.ndarray:
    """Unit quaternion [w, x, y, z] (body FRD → NED) of ZYX Euler angles in radians."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def euler_from_quat(q) -> np.ndarray:
    """ZYX Euler angles [φ, θ, ψ] (rad) of a quaternion [w, x, y, z]; the quaternion is normalized first."""
    return np.array(euler_tuple_from_quat(q))


def euler_tuple_from_quat(q) -> tuple[float, float, float]:
    """:func:`euler_from_quat` as a tuple of floats (φ, θ, ψ) in rad, for hot paths that need no array."""
    w, x, y, z = q
    w, x, y, z = float(w), float(x), float(y), float(z)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"quaternion {list(q)} has no direction")
    w, x, y, z = w / n, x / n, y / n, z / n
    phi = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    theta = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    psi = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return phi, theta, psi


def wrap_pi(a: float) -> float:
    """Angle wrapped into [−π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
