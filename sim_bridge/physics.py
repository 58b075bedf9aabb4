"""The bundled vehicle's physics: the Lagrangian model plus what a real airframe adds around it.

One physics step (default 1 ms): wind (eq. 49, or drag of the physical wind of
:mod:`companion.core.turbulence` on airframe and payload, held over the step) → inner attitude loop (SMC) →
rotor mixer with rotor-speed limits (eq. 13) → RK4 of the 8-DOF model → ground contact, compiled in
:mod:`sim_bridge.physics_kernel`; :class:`VehicleSim` here holds the state, the targets and the wind field and
reads the state out. Pure and deterministic; the MAVLink shell in ``sim_bridge.vehicle`` drives it.

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

import numpy as np

from companion.core.model import (
    IDX_Z,
    _check_domain,
    euler_rate_matrix,
    payload_offset_ned_m,
    rotation_body_to_ned,
)
from companion.core.rotations import euler_tuple_from_quat, quat_from_euler
from companion.core.turbulence import TABLE_DT_S, WindField
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig, wind_scale_factor
from companion.errors import ModelError
from sim_bridge.contact import _payload_angles
from sim_bridge.inner_loop import (
    AIR_MODE_ALL,
    InnerLoopGains,
    RotorConfig,
    gains_packed,
    mixer_inverse,
    mixer_matrix,
)
from sim_bridge.physics_kernel import _physics_steps

__all__ = ["InnerLoopGains", "RotorConfig", "VehicleSim"]


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
        self.air_mode = AIR_MODE_ALL  # PX4's MC_AIRMODE (sim_bridge.inner_loop); 2: eq. 49's yaw torque needs it
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
            gp, a_mat, a_inv, f_max, self.air_mode, self.armed, self.landed, self._pl,
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
