"""The bundled vehicle's settings (:class:`SitlConfig`): the model it flies, its wind, rotors, IMU, links, ids,
lockstep and failsafe parameters; checked before it starts."""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig
from sim_bridge.imu import ImuNoise
from sim_bridge.inner_loop import eq49_torque_problem
from sim_bridge.physics import RotorConfig

M = mavlink2


@dataclass(frozen=True)
class SitlConfig:
    """Everything the vehicle needs to start (the CLI fills it from flags)."""

    params: VehicleParams = field(default_factory=VehicleParams)
    wind: WindConfig = field(default_factory=WindConfig)
    rotor: RotorConfig = field(default_factory=RotorConfig)
    lockstep: bool = False
    control_period_us: int = 4000
    physics_dt_us: int = 1000
    thr_hover: float | None = None  # default 1 / thrust_to_weight
    offboard_timeout_s: float = 1.0  # COM_OF_LOSS_T (PX4 v1.15 default)
    obl_action: int = 0  # COM_OBL_RC_ACT
    fail_act_t_s: float = 5.0  # COM_FAIL_ACT_T: hold after offboard loss, then land
    air_mode: int = 2  # MC_AIRMODE (sim_bridge.inner_loop): PX4's default is 0; eq. 49's yaw torque needs 2
    takeoff_alt_m: float = 2.5
    home: tuple[float, float, float] = (47.397742, 8.545594, 488.0)
    onboard_bind: tuple[str, int] = ("127.0.0.1", 14580)
    onboard_remote: tuple[str, int] = ("127.0.0.1", 14540)
    gcs_bind: tuple[str, int] = ("127.0.0.1", 18570)
    gcs_remote: tuple[str, int] = ("127.0.0.1", 14550)
    sysid: int = 1
    compid: int = M.MAV_COMP_ID_AUTOPILOT1
    payload_sysid: int = 2
    payload_compid: int = M.MAV_COMP_ID_USER11  # 35, as ArduPilot's SIM_SlungPayload
    payload_interval_us: int = 100_000
    duration_s: float | None = None
    onboard_peer: tuple[str, int] | None = None  # lock the link to this peer from the start
    gcs_peer: tuple[str, int] | None = None
    onboard_serial: tuple[str, int] | None = None  # (device, baud bit/s): the onboard link on a serial device
    signing_key: bytes | None = None
    prearm_checks: bool = True  # False: SYS_STATUS as ArduCopter's ARMING_CHECK 0 (pre-arm bit present, not enabled)
    imu: ImuNoise = field(default_factory=ImuNoise)
    #: the hover thrust (N) MPC_THR_HOVER was calibrated for: the declared vehicle's when the true payload differs
    #: (``--payload-mass-kg``: the autopilot was tuned with what it was told); None: the simulated vehicle's own
    thrust_ref_n: float | None = None

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for inconsistent settings."""
        if self.control_period_us <= 0 or self.control_period_us % self.physics_dt_us:
            raise ValueError("control_period_ms: must be a positive multiple of the 1 ms physics step")
        for k in ("sysid", "payload_sysid"):
            if not 1 <= getattr(self, k) <= 255:
                raise ValueError(f"{k}: must be in 1..255")
        if self.sysid == self.payload_sysid:
            raise ValueError("payload_sysid: must differ from the vehicle's sysid")
        if not 0.05 <= (self.thr_hover or 0.4) <= 0.95:
            raise ValueError("thr_hover: must be in [0.05, 0.95]")
        if not 0 <= self.obl_action <= 4:
            raise ValueError("obl_action: COM_OBL_RC_ACT must be 0..4 (5 hold, 6 terminate, 7 disarm: refused)")
        if self.air_mode not in (0, 1, 2):
            raise ValueError(f"air_mode: MC_AIRMODE must be 0, 1 or 2, got {self.air_mode}")
        if not 0.0 <= self.fail_act_t_s <= 25.0:
            raise ValueError("fail_act_t: must be in [0, 25] s")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise ValueError("signing_key: must be 32 bytes")
        self.imu.validate()
        if self.wind.model == "paper":
            problem = eq49_torque_problem(self.wind.scale, self.rotor, self.params, air_mode=self.air_mode)
            if problem is not None:
                raise ValueError(problem)


#: the parameters whose live change :func:`live_wind_problem` checks
LIVE_WIND_PARAMS = ("MC_AIRMODE", "SIM_WIND_SCALE", "SIM_WIND_MODEL")


def live_wind_problem(cfg: SitlConfig, values: dict[str, float]) -> str | None:
    """Why the parameter ``values`` (:data:`LIVE_WIND_PARAMS`, as they would be after a PARAM_SET) cannot be flown,
    or None: eq. 49 beyond the torque the mixer holds at that ``MC_AIRMODE``, as :meth:`SitlConfig.validate` refuses
    it at the start. Physical wind (``cfg.wind.model`` not ``paper``/``none``) or SIM_WIND_MODEL 0: nothing to check."""
    if values["SIM_WIND_MODEL"] < 0.5 or cfg.wind.model not in ("paper", "none"):
        return None
    return eq49_torque_problem(values["SIM_WIND_SCALE"], cfg.rotor, cfg.params,
                               air_mode=round(values["MC_AIRMODE"]))
