"""Reference generator: desired velocity in, flyable reference (position, velocity, acceleration) out.

A third-order integrator chain per tick of ``dt``: the commanded acceleration is ``k_vel·(v_des − v)``
clipped to the acceleration limit (by norm, separately horizontal and vertical); the acceleration follows it
as a first-order lag of time constant 1/(4·k_vel) (critically damped chain, no overshoot) with the jerk
clipped to ``j_max``; then a, v and p are integrated (semi-implicit Euler). The
reference is therefore continuous in position, velocity and acceleration, and its jerk is bounded — the
payload sees no step in the vehicle's acceleration, which is what excites the swing.
"""

from __future__ import annotations

import numpy as np

from companion.planning.base import saturate
from companion.planning.params import PlannerParams


class ReferenceGenerator:
    """Integrates a desired velocity (3,) NED m/s into a reference with bounded acceleration and jerk."""

    def __init__(self, params: PlannerParams, pos_ned_m: np.ndarray) -> None:
        self.params = params
        self.pos_ned_m = np.array(pos_ned_m, dtype=np.float64)
        self.vel_ned_mps = np.zeros(3)
        self.acc_ned_mps2 = np.zeros(3)

    def reset(self, pos_ned_m: np.ndarray, vel_ned_mps: np.ndarray | None = None) -> None:
        """Restart at ``pos_ned_m`` (m) with velocity ``vel_ned_mps`` (default 0) and zero acceleration."""
        self.pos_ned_m = np.array(pos_ned_m, dtype=np.float64)
        self.vel_ned_mps = np.zeros(3) if vel_ned_mps is None else np.array(vel_ned_mps, dtype=np.float64)
        self.acc_ned_mps2 = np.zeros(3)

    def step(self, v_des_ned_mps: np.ndarray, dt_s: float) -> None:
        """Advance by ``dt_s`` seconds towards ``v_des_ned_mps`` (3,), respecting all limits."""
        p = self.params
        v_des = np.array(v_des_ned_mps, dtype=np.float64)
        v_des[:2] = saturate(v_des[:2], p.v_max_mps)
        v_des[2] = float(np.clip(v_des[2], -p.vz_max_mps, p.vz_max_mps))
        a_cmd = p.k_vel * (v_des - self.vel_ned_mps)
        a_cmd[:2] = saturate(a_cmd[:2], p.a_max_mps2)
        a_cmd[2] = float(np.clip(a_cmd[2], -p.az_max_mps2, p.az_max_mps2))
        tau_s = max(dt_s, 0.25 / p.k_vel)
        jerk = (a_cmd - self.acc_ned_mps2) / tau_s
        jerk = saturate(jerk, p.j_max_mps3)
        self.acc_ned_mps2 = self.acc_ned_mps2 + jerk * dt_s
        self.vel_ned_mps = self.vel_ned_mps + self.acc_ned_mps2 * dt_s
        self.pos_ned_m = self.pos_ned_m + self.vel_ned_mps * dt_s
