"""The bundled vehicle's internal position controller (POSCTL hold, AUTO.LOITER/TAKEOFF/LAND).

A plain cascaded P-position / P-velocity loop, like PX4's multicopter position controller without the
integrators: position error → velocity setpoint (clipped) → acceleration setpoint (clipped) → thrust vector
→ attitude quaternion + collective thrust for :class:`sim_bridge.physics.VehicleSim`. Pure: numpy only.
It is "enough to take off, hold and land", not a payload-aware controller (that is the companion's job).
Frames: NED (z down), quaternions [w, x, y, z] rotating body FRD into NED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.core.rotations import quat_from_euler


@dataclass(frozen=True)
class PositionHoldGains:
    """Gains and limits of the internal position loop (SI units)."""

    kp_xy: float = 0.95  # position → velocity, 1/s
    kp_z: float = 1.0
    kv_xy: float = 1.8  # velocity → acceleration, 1/s
    kv_z: float = 4.0
    vmax_xy_mps: float = 3.0
    vmax_up_mps: float = 1.5
    vmax_down_mps: float = 1.0
    tilt_max_rad: float = 0.5

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-positive or non-finite values."""
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{k}: must be finite and > 0, got {v}")
        if self.tilt_max_rad >= 1.2:
            raise ValueError(f"tilt_max_rad: must be < 1.2 rad, got {self.tilt_max_rad}")


def position_hold_target(
    pos_ned_m: np.ndarray,
    vel_ned_mps: np.ndarray,
    target_pos_ned_m: np.ndarray,
    yaw_rad: float,
    total_mass_kg: float,
    g_mps2: float,
    gains: PositionHoldGains,
    max_descent_mps: float | None = None,
) -> tuple[np.ndarray, float]:
    """Attitude quaternion [w,x,y,z] and thrust (N) that fly towards ``target_pos_ned_m`` and hold there.

    ``max_descent_mps`` (if given) replaces ``gains.vmax_down_mps``: AUTO.LAND puts the target far below
    and lets this limit set the descent speed.
    """
    err = np.asarray(target_pos_ned_m, dtype=float) - np.asarray(pos_ned_m, dtype=float)
    v_sp = np.array([gains.kp_xy * err[0], gains.kp_xy * err[1], gains.kp_z * err[2]])
    vxy = math.hypot(v_sp[0], v_sp[1])
    if vxy > gains.vmax_xy_mps:
        v_sp[:2] *= gains.vmax_xy_mps / vxy
    vdown = gains.vmax_down_mps if max_descent_mps is None else max_descent_mps
    v_sp[2] = min(max(v_sp[2], -gains.vmax_up_mps), vdown)
    dv = v_sp - np.asarray(vel_ned_mps, dtype=float)
    a_sp = np.array([gains.kv_xy * dv[0], gains.kv_xy * dv[1], gains.kv_z * dv[2]])
    a_sp[2] = min(max(a_sp[2], -0.8 * g_mps2), 0.8 * g_mps2)
    # thrust vector (N, NED) f = m (a − g e_z); its horizontal part is limited by the tilt limit
    f = total_mass_kg * np.array([a_sp[0], a_sp[1], a_sp[2] - g_mps2])
    fz_up = -f[2]
    fxy = math.hypot(f[0], f[1])
    fxy_max = fz_up * math.tan(gains.tilt_max_rad)
    if fxy > fxy_max:
        f[:2] *= fxy_max / fxy
    thrust_n = float(np.linalg.norm(f))
    # body z axis (down) opposite to the thrust vector; attitude from it and the yaw
    b3 = -f / thrust_n
    c = np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
    b2 = np.cross(b3, c)
    b2 /= np.linalg.norm(b2)
    b1 = np.cross(b2, b3)
    phi = math.atan2(b2[2], b3[2])
    theta = -math.asin(max(-1.0, min(1.0, b1[2])))
    psi = math.atan2(b1[1], b1[0])
    return quat_from_euler(phi, theta, psi), thrust_n
