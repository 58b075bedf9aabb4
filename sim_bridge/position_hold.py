"""The bundled vehicle's internal position controller (POSCTL hold, AUTO.LOITER/TAKEOFF/LAND, and OFFBOARD
position/velocity setpoints from SET_POSITION_TARGET_LOCAL_NED).

A plain cascaded P-position / P-velocity loop, like PX4's multicopter position controller without the
integrators: position error → velocity setpoint (+ velocity feed-forward, clipped) → acceleration setpoint
(+ acceleration feed-forward, clipped) → thrust vector → attitude quaternion + collective thrust for
:class:`sim_bridge.physics.VehicleSim`. Per axis, as PX4's trajectory_setpoint: a NaN position means "do not
control the position on this axis" and the velocity (then the acceleration) is used alone; an axis with none
of the three holds zero velocity. Pure: numpy only.
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
    return position_control_target(pos_ned_m, vel_ned_mps, target_pos_ned_m, _NAN3, _NAN3, yaw_rad,
                                   total_mass_kg, g_mps2, gains, max_descent_mps)


_NAN3 = np.full(3, np.nan)


def position_control_target(
    pos_ned_m: np.ndarray,
    vel_ned_mps: np.ndarray,
    pos_sp_ned_m: np.ndarray,
    vel_sp_ned_mps: np.ndarray,
    acc_sp_ned_mps2: np.ndarray,
    yaw_rad: float,
    total_mass_kg: float,
    g_mps2: float,
    gains: PositionHoldGains,
    max_descent_mps: float | None = None,
) -> tuple[np.ndarray, float]:
    """Attitude quaternion [w,x,y,z] and thrust (N) for a position / velocity / acceleration setpoint (NED).

    Per axis: position given → v_sp = kp·error + velocity (feed-forward, if given); else velocity given →
    v_sp = velocity; else v_sp = 0 unless only an acceleration is given (then it is flown open loop).
    Velocities are clipped to the gains' limits, accelerations to ±0.8 g vertically; the horizontal force
    to the tilt limit. The acceleration setpoint (if given) is added as feed-forward.
    """
    pos = np.asarray(pos_ned_m, dtype=float)
    vel = np.asarray(vel_ned_mps, dtype=float)
    p_sp = np.asarray(pos_sp_ned_m, dtype=float)
    v_ff = np.asarray(vel_sp_ned_mps, dtype=float)
    a_ff = np.asarray(acc_sp_ned_mps2, dtype=float)
    kp = (gains.kp_xy, gains.kp_xy, gains.kp_z)
    kv = (gains.kv_xy, gains.kv_xy, gains.kv_z)
    v_sp = np.zeros(3)
    open_loop = [False, False, False]
    for i in range(3):
        if math.isfinite(p_sp[i]):
            v_sp[i] = kp[i] * (p_sp[i] - pos[i]) + (v_ff[i] if math.isfinite(v_ff[i]) else 0.0)
        elif math.isfinite(v_ff[i]):
            v_sp[i] = v_ff[i]
        elif math.isfinite(a_ff[i]):
            open_loop[i] = True
    vxy = math.hypot(v_sp[0], v_sp[1])
    if vxy > gains.vmax_xy_mps:
        v_sp[:2] *= gains.vmax_xy_mps / vxy
    vdown = gains.vmax_down_mps if max_descent_mps is None else max_descent_mps
    v_sp[2] = min(max(v_sp[2], -gains.vmax_up_mps), vdown)
    a_sp = np.zeros(3)
    for i in range(3):
        if not open_loop[i]:
            a_sp[i] = kv[i] * (v_sp[i] - vel[i])
        if math.isfinite(a_ff[i]):
            a_sp[i] += a_ff[i]
    a_sp[2] = min(max(a_sp[2], -0.8 * g_mps2), 0.8 * g_mps2)
    # thrust vector (N, NED) f = m (a − g e_z); its horizontal part is limited by the tilt limit
    f = total_mass_kg * np.array([a_sp[0], a_sp[1], a_sp[2] - g_mps2])
    fz_up = -f[2]
    fxy = math.hypot(f[0], f[1])
    fxy_max = fz_up * math.tan(gains.tilt_max_rad)
    if fxy > fxy_max:
        f[:2] *= fxy_max / fxy
    return attitude_for_thrust(f, yaw_rad)


def attitude_for_thrust(f: np.ndarray, yaw_rad: float) -> tuple[np.ndarray, float]:
    """Attitude quaternion [w,x,y,z] and thrust (N) that point the rotors' thrust along ``f`` (NED, N) at heading
    ``yaw_rad`` (rad): the body z axis (down) opposite to ``f``, the body x axis in the heading's vertical plane."""
    thrust_n = float(np.linalg.norm(f))
    b3x, b3y, b3z = -f[0] / thrust_n, -f[1] / thrust_n, -f[2] / thrust_n
    cx, cy = math.cos(yaw_rad), math.sin(yaw_rad)
    b2x, b2y, b2z = -b3z * cy, b3z * cx, b3x * cy - b3y * cx  # b3 × c with c = [cos ψ, sin ψ, 0]
    n2 = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
    b2x, b2y, b2z = b2x / n2, b2y / n2, b2z / n2
    b1x, b1y, b1z = b2y * b3z - b2z * b3y, b2z * b3x - b2x * b3z, b2x * b3y - b2y * b3x  # b2 × b3
    phi = math.atan2(b2z, b3z)
    theta = -math.asin(max(-1.0, min(1.0, b1z)))
    psi = math.atan2(b1y, b1x)
    return quat_from_euler(phi, theta, psi), thrust_n
