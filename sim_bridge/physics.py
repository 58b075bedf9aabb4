"""The bundled vehicle's physics: the Lagrangian model plus what a real airframe adds around it.

One physics step (default 1 ms): wind (eq. 49, or drag of the physical wind of
:mod:`companion.core.turbulence` on airframe and payload, held over the step) → inner attitude loop (SMC) →
rotor mixer with rotor-speed limits (eq. 13) → RK4 of the 8-DOF model → ground contact. Pure and
deterministic; the MAVLink shell in ``sim_bridge.vehicle`` drives it.

Ground: the airframe rests on the plane z = 0 (home) while landed. The payload has ground contact too: it
starts resting on the ground under the airframe with the cable slack, and while it lies there the airframe
flies alone (mass M; the payload carries its own weight). When the airframe gets one cable length away the
cable snaps taut: a plastic (perfectly inelastic) impulse along the cable removes the separating velocity,
conserving momentum along it, and the coupled 8-DOF model takes over with the swing angles and rates of that
geometry. A payload that reaches the ground (z ≥ 0) in flight stops there (no bounce, no sliding), and the
cable goes slack again. Dragging the payload along the ground is therefore a series of such stick/jerk
events. Rotors are ideal (no motor lag); rotor thrust is limited to [0, f_max] per rotor.

While the cable is slack, the state's α, β hold the direction from the airframe to the payload (0 when the
payload lies directly below it) and α̇ = β̇ = 0, so the simulated cable-angle sensor stays defined. The
contact kernels live in :mod:`sim_bridge.contact`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.model import (
    IDX_Z,
    _check_domain,
    _deriv,
    _rk4,
    euler_rate_matrix,
    payload_offset_ned_m,
    rotation_body_to_ned,
)
from companion.core.rotations import euler_tuple_from_quat, quat_from_euler
from companion.core.turbulence import TABLE_DT_S, WindField
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig, eq49_signal, wind_scale_factor
from companion.errors import ModelError
from sim_bridge.contact import _cable_contact, _hold_on_ground, _payload_angles
from sim_bridge.inner_loop import (
    InnerLoopGains,
    RotorConfig,
    _mix,
    _rate_torque,
    _smc_torque,
    gains_packed,
    mixer_inverse,
    mixer_matrix,
)
from sim_bridge.wind_drag import _drag_disturbance

__all__ = ["InnerLoopGains", "RotorConfig", "VehicleSim"]


# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__), *(Path(__file__).with_name(f) for f in ("inner_loop.py", "wind_drag.py",
                                                                      "contact.py")))


@njit(cache=True)
def _physics_steps(
    x, t, n, dt, p, p_free, wind_k, wtab, tab_dt, drag_k, tgt_euler, tgt_euler_rate, rates_only, tgt_rates,
    thrust, gp, a_mat, a_inv, f_max, armed, landed, pl, f_out, tau_out, d_out, a_out,
):  # pragma: no cover - compiled
    """``n`` physics steps in place on ``x``: wind → attitude SMC → mixer → RK4 → ground and cable contact.

    Wind: eq. 49 times ``wind_k`` on all six channels, or (``wtab`` non-empty: the wind velocity table, NED m/s,
    a sample every ``tab_dt`` s from t = 0) drag ``drag_k`` = [k_airframe, k_payload] (N per (m/s)²) on the
    airframe and on the payload, held over each step. ``pl`` = [slack (1.0/0.0), payload x, y, z]: the
    payload's ground contact, updated in place; while slack the airframe flies with ``p_free`` (the parameters
    with m = 0). Returns (t, landed, ok). ``f_out``, ``tau_out``, ``d_out`` receive the last step's rotor
    thrusts, body torques and disturbance (first six channels), ``a_out`` the airframe's acceleration ξ̈ at
    the final state under them (0 on the ground), for the IMU.
    """
    inertia = p[3:6]
    tau = np.empty(3)
    u = np.empty(4)
    d6 = np.empty(6)
    d8 = np.zeros(8)
    physical = wtab.shape[0] > 1
    d = d8 if physical else d6
    w = np.empty(3)
    tilt = np.empty(3)
    for _ in range(n):
        slack = pl[0] > 0.5
        hover = (p[0] + (0.0 if slack else p[1])) * p[2]
        if physical:
            _drag_disturbance(x, t, wtab, tab_dt, drag_k, p[7], slack, landed, d8)
        else:
            wv = 0.0 if (landed or wind_k == 0.0) else wind_k * eq49_signal(t)
            for i in range(6):
                d6[i] = wv
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
            _hold_on_ground(x, p, pl)
            t += dt
            continue
        landed = False
        y = _rk4(x, u, d, p_free if slack else p, dt, 1)
        for i in range(16):
            if not math.isfinite(y[i]):
                return t, landed, False
        for i in range(16):
            x[i] = y[i]
        _cable_contact(x, p, pl)
        if x[2] >= 0.0 and x[10] >= 0.0:
            # touch-down: no bounce, no sliding, airframe level
            x[2] = 0.0
            for i in (3, 4, 8, 9, 10, 11, 12, 13):
                x[i] = 0.0
            landed = True
        t += dt
    for i in range(6):
        d_out[i] = d[i]
    if landed:
        for i in range(3):
            a_out[i] = 0.0
    else:
        k = np.empty(16)
        _deriv(x, u, d, p_free if pl[0] > 0.5 else p, k)
        for i in range(3):
            a_out[i] = k[8 + i]
    return t, landed, True


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
        self._p_free = self._p.copy()  # the airframe alone, while the payload lies on the ground
        self._p_free[1] = 0.0
        self._p_free[6] = max(self._p_free[6], 1e-9)
        self.armed = False
        self.landed = self.x[IDX_Z] >= 0.0 and abs(self.x[8 + IDX_Z]) < 1e-9
        # payload contact [slack, x, y, z]: a payload below the ground plane in x0 rests on the ground instead
        self._pl = np.zeros(4)
        if self.x[IDX_Z] + params.l * math.cos(self.x[6]) * math.cos(self.x[7]) > 0.0:
            offset = payload_offset_ned_m(self.x[6], self.x[7], params.l)
            self._pl[:] = (1.0, self.x[0] + offset[0], self.x[1] + offset[1], 0.0)
            self.x[6] = self.x[7] = self.x[14] = self.x[15] = 0.0
            _payload_angles(self.x, self._pl, params.l)
        self.target_euler_rad = np.array([0.0, 0.0, self.x[5]])
        self.target_rates_frd_rad_s: np.ndarray | None = None
        self.rates_only = False
        self.target_thrust_n = 0.0
        self.rotor_thrust_n = np.zeros(4)
        self.torque_nm = np.zeros(3)
        self.disturbance = np.zeros(6)
        self._field_cfg: WindConfig | None = None
        self._field: WindField | None = None
        self._no_table = np.zeros((0, 3))
        self._drag_k = np.zeros(2)
        self._accel = np.zeros(3)  # ξ̈ after the last step (the kernel writes it)
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
            phi, theta, psi = euler_tuple_from_quat(q_wxyz)
            tilt_max = self.gains.max_tilt_rad
            self.target_euler_rad = np.array([min(max(phi, -tilt_max), tilt_max),
                                              min(max(theta, -tilt_max), tilt_max), psi])
            self.rates_only = False
        elif body_rates_frd_rad_s is not None:
            self.rates_only = True
        self.target_rates_frd_rad_s = None if body_rates_frd_rad_s is None else np.asarray(
            body_rates_frd_rad_s, dtype=np.float64
        )
        if thrust_n is not None:  # max_thrust_n from the cached rotor limit (same value)
            self.target_thrust_n = float(min(max(thrust_n, 0.0), 4.0 * self._kernel_constants()[3]))

    def set_euler_target(self, euler_rad: np.ndarray, thrust_n: float) -> None:
        """Convenience for internal controllers: Euler target [φ, θ, ψ] (rad) and thrust (N)."""
        self.set_attitude_target(quat_from_euler(*euler_rad), thrust_n)

    # ---------------------------------------------------------------- stepping
    def _kernel_constants(self) -> tuple:
        """Packed gains, mixer matrices and rotor limit, rebuilt only when ``gains``/``rotor`` are replaced
        (the parameter protocol swaps the frozen dataclasses at run time)."""
        key = self._consts_key
        if key is None or key[0] is not self.gains or key[1] is not self.rotor:  # identity: cheap every step
            self._consts_key = (self.gains, self.rotor)
            self._consts = (gains_packed(self.gains), mixer_matrix(self.rotor), mixer_inverse(self.rotor),
                            self.params.max_thrust_n / 4.0)
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
        wtab = self._wind_table(self.t_s + (int(n_steps) + 1) * self.dt_s)
        t, landed, ok = _physics_steps(
            self.x, self.t_s, int(n_steps), self.dt_s, self._p, self._p_free, wind_scale_factor(self.wind),
            wtab, TABLE_DT_S, self._drag_k, self.target_euler_rad, tgt_euler_rate, self.rates_only, rates,
            self.target_thrust_n,
            gp, a_mat, a_inv, f_max, self.armed, self.landed, self._pl,
            self.rotor_thrust_n, self.torque_nm, self.disturbance, self._accel,
        )
        self.t_s = t
        self.landed = landed
        if not ok:
            raise ModelError(f"simulation diverged at t = {self.t_s:.3f} s")

    def _wind_field(self) -> WindField | None:
        """The physical wind field for ``self.wind`` (rebuilt only when the configuration changes value)."""
        if self._field_cfg != self.wind:
            self._field_cfg = self.wind
            self._field = WindField(self.wind) if self.wind.is_physical else None
            self._drag_k = self.wind.drag_coefficients() if self.wind.is_physical else np.zeros(2)
        return self._field

    def _wind_table(self, t_until_s: float) -> np.ndarray:
        """The wind velocity table covering [0, ``t_until_s``] s (empty unless the wind is physical)."""
        field = self._wind_field()
        return self._no_table if field is None else field.cover(t_until_s)

    # ---------------------------------------------------------------- views
    @property
    def wind_ned_mps(self) -> np.ndarray:
        """The air's velocity (NED, m/s) at the airframe now: zero unless the wind is physical."""
        field = self._wind_field()
        return np.zeros(3) if field is None else field.velocity(self.t_s)

    @property
    def max_thrust_n(self) -> float:
        """Total thrust at ω_max on all rotors, N: the airframe's ``params.max_thrust_n`` (the rotors do not
        grow with the payload; ``rotor.thrust_to_weight`` only sets the default MPC_THR_HOVER)."""
        return 4.0 * (self.params.max_thrust_n / 4.0)

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
    def payload_on_ground(self) -> bool:
        """True while the payload rests on the ground and the cable is slack."""
        return bool(self._pl[0] > 0.5)

    @property
    def payload_pos_ned_m(self) -> np.ndarray:
        if self._pl[0] > 0.5:
            return self._pl[1:4].copy()
        return self.x[0:3] + payload_offset_ned_m(self.x[6], self.x[7], self.params.l)

    @property
    def payload_vel_ned_mps(self) -> np.ndarray:
        if self._pl[0] > 0.5:
            return np.zeros(3)
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

    @property
    def accel_ned_mps2(self) -> np.ndarray:
        """The airframe's acceleration ξ̈ (NED, m/s²) at the current state under the last step's rotor
        thrusts, torques and disturbance (zero while it rests on the ground)."""
        if self.landed:
            return np.zeros(3)
        return self._accel.copy()

    @property
    def specific_force_frd_mps2(self) -> np.ndarray:
        """What an ideal accelerometer on the airframe reads: Rᵀ·(ξ̈ − g·e_z), body FRD, m/s².

        It is the sum of the non-gravitational forces on the airframe (rotor thrust, the cable's pull,
        the disturbance) divided by M: hovering with the payload hanging still it reads [0, 0, −g], not
        −(M+m)·g/M, because the cable pulls the airframe down with m·g.
        """
        a = self.accel_ned_mps2
        a[2] -= self.params.g
        return rotation_body_to_ned(*self.x[3:6]).T @ a
