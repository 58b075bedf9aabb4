"""Reference generator: desired velocity in, flyable reference (position, velocity, acceleration) out.

A third-order integrator chain per tick of ``dt``: the commanded acceleration is ``k_vel·(v_des − v)``
clipped to the acceleration limit (by norm, separately horizontal and vertical); the acceleration follows it
as a first-order lag of time constant 1/(4·k_vel) (critically damped chain, no overshoot) with the jerk
clipped to ``j_max``; then a, v and p are integrated (semi-implicit Euler). The
reference is therefore continuous in position, velocity and acceleration, and its jerk is bounded — the
payload sees no step in the vehicle's acceleration, which is what excites the swing.

The state is kept as plain floats (the generator runs every control tick; numpy on 3-vectors costs more
than the arithmetic); ``pos_ned_m``, ``vel_ned_mps`` and ``acc_ned_mps2`` return fresh (3,) arrays.
"""

from __future__ import annotations

import math

import numpy as np

from companion.planning.params import PlannerParams


class ReferenceGenerator:
    """Integrates a desired velocity (3,) NED m/s into a reference with bounded acceleration and jerk."""

    def __init__(self, params: PlannerParams, pos_ned_m: np.ndarray) -> None:
        self.params = params
        self.reset(pos_ned_m)

    def reset(self, pos_ned_m: np.ndarray, vel_ned_mps: np.ndarray | None = None) -> None:
        """Restart at ``pos_ned_m`` (m) with velocity ``vel_ned_mps`` (default 0) and zero acceleration."""
        self.p = [float(v) for v in pos_ned_m]
        self.v = [0.0, 0.0, 0.0] if vel_ned_mps is None else [float(v) for v in vel_ned_mps]
        self.a = [0.0, 0.0, 0.0]

    @property
    def pos_ned_m(self) -> np.ndarray:
        """Reference position (m, NED), a copy."""
        return np.array(self.p)

    @property
    def vel_ned_mps(self) -> np.ndarray:
        """Reference velocity (m/s, NED), a copy."""
        return np.array(self.v)

    @property
    def acc_ned_mps2(self) -> np.ndarray:
        """Reference acceleration (m/s², NED), a copy."""
        return np.array(self.a)

    def step(self, v_des_ned_mps, dt_s: float) -> None:
        """Advance by ``dt_s`` seconds towards ``v_des_ned_mps`` (3,), respecting all limits."""
        p = self.params
        vx, vy, vz = map(float, v_des_ned_mps)
        n = math.hypot(vx, vy)
        if n > p.v_max_mps:
            s = p.v_max_mps / n
            vx, vy = vx * s, vy * s
        vz = min(max(vz, -p.vz_max_mps), p.vz_max_mps)
        v, a, pos = self.v, self.a, self.p
        ax = p.k_vel * (vx - v[0])
        ay = p.k_vel * (vy - v[1])
        az = p.k_vel * (vz - v[2])
        n = math.hypot(ax, ay)
        if n > p.a_max_mps2:
            s = p.a_max_mps2 / n
            ax, ay = ax * s, ay * s
        az = min(max(az, -p.az_max_mps2), p.az_max_mps2)
        tau_s = max(dt_s, 0.25 / p.k_vel)
        jx = (ax - a[0]) / tau_s
        jy = (ay - a[1]) / tau_s
        jz = (az - a[2]) / tau_s
        n = math.sqrt(jx * jx + jy * jy + jz * jz)
        j_lim = p.j_max_mps3
        if p.start_jerk_frac < 1.0:
            vh = math.hypot(v[0], v[1])
            if vh < p.start_ramp_mps and ax * v[0] + ay * v[1] >= 0.0 and math.hypot(ax, ay) > math.hypot(a[0], a[1]):
                # speeding up from (near) rest: a gentler onset of the acceleration excites the payload less (a
                # step of acceleration swings a pendulum to twice its steady angle; a ramp over ~half its period
                # barely more)
                j_lim *= p.start_jerk_frac + (1.0 - p.start_jerk_frac) * vh / p.start_ramp_mps
        if n > j_lim:
            s = j_lim / n
            jx, jy, jz = jx * s, jy * s, jz * s
        a[0] += jx * dt_s
        a[1] += jy * dt_s
        a[2] += jz * dt_s
        for i in range(3):
            v[i] += a[i] * dt_s
            pos[i] += v[i] * dt_s

    def step_vertical(self, vz_des_ned_mps: float, dt_s: float) -> None:
        """Advance only the vertical channel by ``dt_s`` towards ``vz_des_ned_mps`` (m/s), with the same limits
        as :meth:`step` (the horizontal channels belong to a time-parameterised planner then)."""
        p = self.params
        vz = min(max(float(vz_des_ned_mps), -p.vz_max_mps), p.vz_max_mps)
        az = min(max(p.k_vel * (vz - self.v[2]), -p.az_max_mps2), p.az_max_mps2)
        tau_s = max(dt_s, 0.25 / p.k_vel)
        jz = min(max((az - self.a[2]) / tau_s, -p.j_max_mps3), p.j_max_mps3)
        self.a[2] += jz * dt_s
        self.v[2] += self.a[2] * dt_s
        self.p[2] += self.v[2] * dt_s

    def set_horizontal(self, pos_m, vel_mps, acc_mps2) -> None:
        """Overwrite the horizontal reference (2 floats each: m, m/s, m/s²) with a planner's."""
        self.p[0], self.p[1] = float(pos_m[0]), float(pos_m[1])
        self.v[0], self.v[1] = float(vel_mps[0]), float(vel_mps[1])
        self.a[0], self.a[1] = float(acc_mps2[0]), float(acc_mps2[1])
