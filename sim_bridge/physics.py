"""The bundled vehicle's physics: the Lagrangian model plus what a real airframe adds around it.

One physics step (default 1 ms): wind of eq. 49 → inner attitude loop (SMC) → rotor mixer with rotor-speed
limits (eq. 13) → RK4 of the 8-DOF model → ground contact. Pure and deterministic; the MAVLink shell in
``sim_bridge.vehicle`` drives it.

Ground: the airframe rests on the plane z = 0 (home) while landed; the payload hangs freely below it, as
if launched from a stand or a roof edge (there is no payload–ground contact). Rotors are ideal (no motor
lag); rotor thrust is limited to [0, f_max] per rotor.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.model import (
    IDX_Z,
    VehicleParams,
    _check_domain,
    _rk4,
    euler_rate_matrix,
    payload_offset_ned_m,
    rotation_body_to_ned,
)
from companion.core.rotations import euler_from_quat, quat_from_euler
from companion.core.wind import WindConfig, eq49_signal, wind_scale_factor
from companion.errors import ModelError
from sim_bridge.inner_loop import (
    InnerLoopGains,
    RotorConfig,
    _mix,
    _rate_torque,
    _smc_torque,
    gains_packed,
    max_rotor_thrust_n,
    mixer_inverse,
    mixer_matrix,
)

__all__ = ["InnerLoopGains", "RotorConfig", "VehicleSim"]


# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__), Path(__file__).with_name("inner_loop.py"))


@njit(cache=True)
def _physics_steps(
    x, t, n, dt, p, wind_k, tgt_euler, tgt_euler_rate, rates_only, tgt_rates, thrust, gp, a_mat, a_inv,
    f_max, armed, landed, f_out, tau_out, d_out,
):  # pragma: no cover - compiled
    """``n`` physics steps in place on ``x``: wind → attitude SMC → mixer → RK4 → ground.

    Returns (t, landed, ok). ``f_out``, ``tau_out``, ``d_out`` receive the last step's rotor thrusts,
    body torques and disturbance.
    """
    inertia = p[3:6]
    tau = np.empty(3)
    u = np.empty(4)
    d = np.empty(6)
    w = np.empty(3)
    tilt = np.empty(3)
    hover = (p[0] + p[1]) * p[2]
    for _ in range(n):
        wv = 0.0 if (landed or wind_k == 0.0) else wind_k * eq49_signal(t)
        for i in range(6):
            d[i] = wv
        if armed:
            if rates_only:
                phi = x[3]
                th = x[4]
                w[0] = x[11] - math.sin(th) * x[13]
                w[1] = math.cos(phi) * x[12] + math.sin(phi) * math.cos(th) * x[13]
                w[2] = -math.sin(phi) * x[12] + math.cos(phi) * math.cos(th) * x[13]
                _rate_torque(w, tgt_rates, inertia, gp[12], tau)
            else:
                # Tilt priority (as PX4's attitude control): keep the commanded thrust direction
                # b3 = R_d·e3 at the *current* heading, so a yaw error (e.g. yaw torque saturated in strong
                # wind) never tilts the thrust the wrong way; the yaw channel still tracks ψ_d.
                sf = math.sin(tgt_euler[0])
                cf = math.cos(tgt_euler[0])
                st = math.sin(tgt_euler[1])
                ct = math.cos(tgt_euler[1])
                sp = math.sin(tgt_euler[2])
                cp = math.cos(tgt_euler[2])
                b0 = cf * st * cp + sf * sp
                b1 = cf * st * sp - sf * cp
                b2 = cf * ct
                sy = math.sin(x[5])
                cy = math.cos(x[5])
                v0 = cy * b0 + sy * b1  # b3 in the current heading frame: [cφ·sθ, −sφ, cφ·cθ]
                v1 = -sy * b0 + cy * b1
                tilt[0] = math.asin(min(1.0, max(-1.0, -v1)))
                tilt[1] = math.atan2(v0, b2)
                tilt[2] = tgt_euler[2]
                _smc_torque(x[3:6], x[11:14], tilt, tgt_euler_rate, inertia, gp, tau)
            _mix(thrust, tau, a_inv, f_max, not landed, f_out)
        else:
            for i in range(4):
                f_out[i] = 0.0
        for r in range(4):
            u[r] = 0.0
            for c in range(4):
                u[r] += a_mat[r, c] * f_out[c]
        tau_out[0] = u[1]
        tau_out[1] = u[2]
        tau_out[2] = u[3]
        if landed and u[0] <= hover + 1e-9:
            _hold_on_ground(x, p, dt)
            t += dt
            continue
        landed = False
        y = _rk4(x, u, d, p, dt, 1)
        for i in range(16):
            if not math.isfinite(y[i]):
                return t, landed, False
        for i in range(16):
            x[i] = y[i]
        if x[2] >= 0.0 and x[10] >= 0.0:
            # touch-down: no bounce, no sliding, airframe level
            x[2] = 0.0
            for i in (3, 4, 8, 9, 10, 11, 12, 13):
                x[i] = 0.0
            landed = True
        t += dt
    for i in range(6):
        d_out[i] = d[i]
    return t, landed, True


@njit(cache=True)
def _hold_on_ground(x, p, h):  # pragma: no cover - compiled
    """Airframe held on the ground: the payload swings as a pendulum on a fixed pivot (ξ̈ = 0).

    Semi-implicit Euler on the swing equations with the quadrotor's acceleration set to zero.
    """
    m = p[1]
    g = p[2]
    ip = p[6]
    l = p[7]
    al = x[6]
    be = x[7]
    dal = x[14]
    dbe = x[15]
    ka = m * l * l * math.cos(be) ** 2 + ip
    kb = m * l * l + ip
    dda = (2.0 * m * l * l * math.cos(be) * math.sin(be) * dal * dbe - m * g * l * math.sin(al) * math.cos(be)) / ka
    ddb = (-m * l * l * math.sin(be) * math.cos(be) * dal * dal - m * g * l * math.cos(al) * math.sin(be)) / kb
    x[14] = dal + h * dda
    x[15] = dbe + h * ddb
    x[6] = al + h * x[14]
    x[7] = be + h * x[15]
    for i in (3, 4, 8, 9, 10, 11, 12, 13):
        x[i] = 0.0


class VehicleSim:
    """Quadrotor + payload with its own attitude loop, flying the analytic model in simulated time."""

    def __init__(
        self,
        params: VehicleParams,
        wind: WindConfig | None = None,
        rotor: RotorConfig | None = None,
        gains: InnerLoopGains | None = None,
        dt_s: float = 1e-3,
        x0: np.ndarray | None = None,
        t0_s: float = 0.0,
    ) -> None:
        self.params = params
        self.wind = wind or WindConfig()
        self.rotor = rotor or RotorConfig()
        self.gains = gains or InnerLoopGains()
        self.dt_s = float(dt_s)
        self.t_s = float(t0_s)
        self.x = np.zeros(16) if x0 is None else np.array(x0, dtype=np.float64)
        if self.x.shape != (16,):
            raise ModelError(f"x0: expected shape (16,), got {self.x.shape}")
        self._p = params.packed()
        self.armed = False
        self.landed = self.x[IDX_Z] >= 0.0 and abs(self.x[8 + IDX_Z]) < 1e-9
        self.target_euler_rad = np.array([0.0, 0.0, self.x[5]])
        self.target_rates_frd_rad_s: np.ndarray | None = None
        self.rates_only = False
        self.target_thrust_n = 0.0
        self.rotor_thrust_n = np.zeros(4)
        self.torque_nm = np.zeros(3)
        self.disturbance = np.zeros(6)
        self._zeros3 = np.zeros(3)
        self._consts_key: tuple | None = None
        self._consts: tuple = ()

    # ---------------------------------------------------------------- targets
    def set_attitude_target(
        self,
        q_wxyz: np.ndarray | None,
        thrust_n: float | None,
        body_rates_frd_rad_s: np.ndarray | None = None,
    ) -> None:
        """Set the inner loop's target: attitude quaternion (NED→FRD body, [w, x, y, z]) and/or body rates
        (rad/s), and collective thrust (N). ``None`` keeps the previous value; attitude None with body
        rates given means a rate-only target. Tilt is limited to ``gains.max_tilt_rad``."""
        if q_wxyz is not None:
            eul = euler_from_quat(q_wxyz)
            tilt_max = self.gains.max_tilt_rad
            eul[0] = min(max(eul[0], -tilt_max), tilt_max)
            eul[1] = min(max(eul[1], -tilt_max), tilt_max)
            self.target_euler_rad = eul
            self.rates_only = False
        elif body_rates_frd_rad_s is not None:
            self.rates_only = True
        self.target_rates_frd_rad_s = None if body_rates_frd_rad_s is None else np.asarray(
            body_rates_frd_rad_s, dtype=np.float64
        )
        if thrust_n is not None:
            self.target_thrust_n = float(min(max(thrust_n, 0.0), self.max_thrust_n))

    def set_euler_target(self, euler_rad: np.ndarray, thrust_n: float) -> None:
        """Convenience for internal controllers: Euler target [φ, θ, ψ] (rad) and thrust (N)."""
        self.set_attitude_target(quat_from_euler(*euler_rad), thrust_n)

    # ---------------------------------------------------------------- stepping
    def _kernel_constants(self) -> tuple:
        """Packed gains, mixer matrices and rotor limit, rebuilt only when ``gains``/``rotor`` are replaced
        (the parameter protocol swaps the frozen dataclasses at run time)."""
        key = (self.gains, self.rotor)
        if self._consts_key != key:
            self._consts_key = key
            self._consts = (gains_packed(self.gains), mixer_matrix(self.rotor), mixer_inverse(self.rotor),
                            max_rotor_thrust_n(self.rotor, self.params))
        return self._consts

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` physics steps of ``dt_s`` (one compiled call)."""
        _check_domain(self.x)
        if self.target_rates_frd_rad_s is not None:
            rates = self.target_rates_frd_rad_s
            tgt_euler_rate = np.linalg.solve(euler_rate_matrix(self.x[3], self.x[4]), rates)
        else:
            rates = tgt_euler_rate = self._zeros3
        gp, a_mat, a_inv, f_max = self._kernel_constants()
        t, landed, ok = _physics_steps(
            self.x, self.t_s, int(n_steps), self.dt_s, self._p, wind_scale_factor(self.wind),
            self.target_euler_rad, tgt_euler_rate, self.rates_only, rates, self.target_thrust_n,
            gp, a_mat, a_inv, f_max, self.armed, self.landed,
            self.rotor_thrust_n, self.torque_nm, self.disturbance,
        )
        self.t_s = t
        self.landed = landed
        if not ok:
            raise ModelError(f"simulation diverged at t = {self.t_s:.3f} s")

    # ---------------------------------------------------------------- views
    @property
    def max_thrust_n(self) -> float:
        """Total thrust at ω_max on all rotors, N."""
        return 4.0 * max_rotor_thrust_n(self.rotor, self.params)

    @property
    def thrust_n(self) -> float:
        """Collective thrust actually produced (after rotor limits), N."""
        return float(np.sum(self.rotor_thrust_n))

    @property
    def target_thrust(self) -> float:
        """Alias of ``target_thrust_n``."""
        return self.target_thrust_n

    @property
    def rotor_omega_rad_s(self) -> np.ndarray:
        """Rotor speeds ω_i = sqrt(f_i / c_T), rad/s."""
        return np.sqrt(self.rotor_thrust_n / self.rotor.c_t)

    @property
    def pos_ned_m(self) -> np.ndarray:
        return self.x[0:3].copy()

    @property
    def vel_ned_mps(self) -> np.ndarray:
        return self.x[8:11].copy()

    @property
    def euler_rad(self) -> np.ndarray:
        return self.x[3:6].copy()

    @property
    def quat_wxyz(self) -> np.ndarray:
        return quat_from_euler(*self.x[3:6])

    @property
    def body_rates_frd_rad_s(self) -> np.ndarray:
        """Body angular velocity Ω = R_η·η̇ (eq. 7), rad/s."""
        phi, th = self.x[3], self.x[4]
        dphi, dth, dpsi = self.x[11:14]
        return np.array(
            [
                dphi - math.sin(th) * dpsi,
                math.cos(phi) * dth + math.sin(phi) * math.cos(th) * dpsi,
                -math.sin(phi) * dth + math.cos(phi) * math.cos(th) * dpsi,
            ]
        )

    @property
    def swing(self) -> np.ndarray:
        """[α, β, α̇, β̇] in rad and rad/s."""
        return np.array([self.x[6], self.x[7], self.x[14], self.x[15]])

    @property
    def payload_pos_ned_m(self) -> np.ndarray:
        return self.x[0:3] + payload_offset_ned_m(self.x[6], self.x[7], self.params.l)

    @property
    def payload_vel_ned_mps(self) -> np.ndarray:
        al, be, dal, dbe = self.x[6], self.x[7], self.x[14], self.x[15]
        ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
        l = self.params.l
        return self.x[8:11] + l * np.array(
            [ca * cb * dal - sa * sb * dbe, -cb * dbe, -sa * cb * dal - ca * sb * dbe]
        )

    @property
    def thrust_vector_ned_n(self) -> np.ndarray:
        """Rotor thrust in NED, −R_F·[0, 0, T] (eq. 11), N."""
        return -rotation_body_to_ned(*self.x[3:6]) @ np.array([0.0, 0.0, self.thrust_n])
