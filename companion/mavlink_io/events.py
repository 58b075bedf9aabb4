"""The typed telemetry events: frozen, slotted, SI units, each with its source (pure: stdlib only).

Decoded from MAVLink by :mod:`companion.mavlink_io.telemetry` (which re-exports them); every event carries
``src_system``, ``src_component`` and ``seq`` (the frame's sequence number). Units are named in the fields
(``t_boot_s``: vehicle time since boot, s; ``pos_ned_m``: local NED, m; ...).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar


# ------------------------------------------------------------------------------------------------ events
@dataclass(frozen=True, slots=True)
class Sourced:
    """Who sent a message: MAVLink system and component id, and the frame's sequence number (0..255)."""

    src_system: int
    src_component: int
    seq: int


@dataclass(frozen=True, slots=True)
class Heartbeat(Sourced):
    """HEARTBEAT: MAV_TYPE, MAV_AUTOPILOT, base mode flags, autopilot-specific custom mode, MAV_STATE."""

    message: ClassVar[str] = "HEARTBEAT"
    mav_type: int
    autopilot: int
    base_mode: int
    custom_mode: int
    system_status: int


@dataclass(frozen=True, slots=True)
class SysStatus(Sourced):
    """SYS_STATUS: the onboard sensors present and healthy (MAV_SYS_STATUS_SENSOR bit masks)."""

    message: ClassVar[str] = "SYS_STATUS"
    sensors_present: int
    sensors_health: int
    sensors_enabled: int  # ArduCopter with ARMING_CHECK 0: the pre-arm bit present, not enabled (never healthy)


@dataclass(frozen=True, slots=True)
class Attitude(Sourced):
    """ATTITUDE: Euler angles (roll, pitch, yaw; rad, NED→FRD) and body rates (FRD, rad/s) at ``t_boot_s``."""

    message: ClassVar[str] = "ATTITUDE"
    t_boot_s: float
    euler_rad: tuple[float, float, float]
    rates_frd_rad_s: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class LocalPositionNed(Sourced):
    """LOCAL_POSITION_NED: position (m) and velocity (m/s) in the autopilot's local NED frame at ``t_boot_s``."""

    message: ClassVar[str] = "LOCAL_POSITION_NED"
    t_boot_s: float
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class GlobalPositionInt(Sourced):
    """GLOBAL_POSITION_INT: WGS-84 latitude and longitude (deg), altitude above mean sea level (m) and NED
    velocity (m/s) at ``t_boot_s``."""

    message: ClassVar[str] = "GLOBAL_POSITION_INT"
    t_boot_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_ned_mps: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class HomePosition(Sourced):
    """HOME_POSITION: home in the autopilot's local NED frame (m), and as WGS-84 latitude and longitude (deg) and
    altitude above mean sea level (m)."""

    message: ClassVar[str] = "HOME_POSITION"
    pos_ned_m: tuple[float, float, float]
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    alt_amsl_m: float = 0.0


@dataclass(frozen=True, slots=True)
class GpsGlobalOrigin(Sourced):
    """GPS_GLOBAL_ORIGIN: the WGS-84 latitude and longitude (deg) and altitude above mean sea level (m) of the
    autopilot's local NED origin."""

    message: ClassVar[str] = "GPS_GLOBAL_ORIGIN"
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


@dataclass(frozen=True, slots=True)
class MissionCount(Sourced):
    """MISSION_COUNT: how many items the sender holds of ``mission_type`` (MAV_MISSION_TYPE: 0 mission,
    1 fence, 2 rally)."""

    message: ClassVar[str] = "MISSION_COUNT"
    count: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionItemInt(Sourced):
    """MISSION_ITEM_INT, as sent: item ``item_seq`` (the message's ``seq``; ``seq`` is the frame's) of
    ``mission_type``, its MAV_FRAME and MAV_CMD, the four parameters (command-specific units), ``x``/``y`` (global
    frames: degrees × 1e7; local frames: metres × 1e4) and ``z`` (m, the frame's altitude or NED z). Nothing is
    checked here (NaN parameters are normal, e.g. yaw): the mission's conversion checks the fields it uses."""

    message: ClassVar[str] = "MISSION_ITEM_INT"
    item_seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float
    mission_type: int


@dataclass(frozen=True, slots=True)
class MissionAck(Sourced):
    """MISSION_ACK: the MAV_MISSION_RESULT (0 accepted) of a transfer of ``mission_type``."""

    message: ClassVar[str] = "MISSION_ACK"
    result: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class ExtendedSysState(Sourced):
    """EXTENDED_SYS_STATE: MAV_LANDED_STATE."""

    message: ClassVar[str] = "EXTENDED_SYS_STATE"
    landed_state: int


@dataclass(frozen=True, slots=True)
class SystemTime(Sourced):
    """SYSTEM_TIME: the vehicle's time since boot (ms, exact: the lockstep step marker is this number)."""

    message: ClassVar[str] = "SYSTEM_TIME"
    t_boot_ms: int

    @property
    def t_boot_s(self) -> float:
        """Time since boot, s."""
        return self.t_boot_ms * 1e-3


@dataclass(frozen=True, slots=True)
class HighresImu(Sourced):
    """HIGHRES_IMU: specific force (FRD, m/s²) at ``t_s`` (its ``time_usec``, s)."""

    message: ClassVar[str] = "HIGHRES_IMU"
    t_s: float
    accel_frd_mps2: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class ScaledImu(Sourced):
    """SCALED_IMU: specific force (FRD, m/s², from the message's milli-g) at ``t_boot_s``."""

    message: ClassVar[str] = "SCALED_IMU"
    t_boot_s: float
    accel_frd_mps2: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class EstimatorStatus(Sourced):
    """ESTIMATOR_STATUS (PX4): the estimator's horizontal position accuracy (1σ, m)."""

    message: ClassVar[str] = "ESTIMATOR_STATUS"
    pos_horiz_accuracy_m: float


@dataclass(frozen=True, slots=True)
class StatusText(Sourced):
    """STATUSTEXT: MAV_SEVERITY and the text (up to 50 characters); a longer text comes in chunks sharing an ``id``
    (0: not chunked), numbered by ``chunk_seq``."""

    message: ClassVar[str] = "STATUSTEXT"
    severity: int
    text: str
    id: int = 0
    chunk_seq: int = 0


@dataclass(frozen=True, slots=True)
class CommandAck(Sourced):
    """COMMAND_ACK: the MAV_CMD answered and its MAV_RESULT."""

    message: ClassVar[str] = "COMMAND_ACK"
    command: int
    result: int


@dataclass(frozen=True, slots=True)
class ParamValue(Sourced):
    """PARAM_VALUE: a parameter's name and (finite) value."""

    message: ClassVar[str] = "PARAM_VALUE"
    param_id: str
    value: float


@dataclass(frozen=True, slots=True)
class SwingSensor(Sourced):
    """DEBUG_FLOAT_ARRAY named ``SWING``, the cable-angle sensor: ``swing`` = (α rad, β rad, α̇ rad/s, β̇ rad/s)
    at ``t_s`` (its ``time_usec``, s); ``reach_m``: the distance to the payload (m; may be NaN: unknown)."""

    message: ClassVar[str] = "DEBUG_FLOAT_ARRAY"
    t_s: float
    swing: tuple[float, float, float, float]
    reach_m: float


@dataclass(frozen=True, slots=True)
class AutopilotVersion(Sourced):
    """AUTOPILOT_VERSION: capability bits, the flight software version word, vendor and product ids, and the
    flight software's custom version (8 bytes, e.g. a git hash prefix)."""

    message: ClassVar[str] = "AUTOPILOT_VERSION"
    capabilities: int
    flight_sw_version: int
    vendor_id: int
    product_id: int
    flight_custom_version: bytes


@dataclass(frozen=True, slots=True)
class ObstacleDistance(Sourced):
    """OBSTACLE_DISTANCE: one range sensor's sectors at ``time_usec`` (µs, vehicle time since boot, exact);
    ``distances_cm`` 72 sectors (cm; ``max_distance_cm + 1`` = nothing in range, 65535 = unknown/unused),
    ``increment_deg`` the sectors' width (deg: ``increment_f`` when non-zero, else ``increment``),
    ``angle_offset_deg`` the first sector's angle (deg, clockwise), ``frame`` its MAV_FRAME (12: body FRD, 0 or 1:
    north-aligned). Assembled into scans by :mod:`companion.perception.scan`."""

    message: ClassVar[str] = "OBSTACLE_DISTANCE"
    time_usec: int
    distances_cm: tuple[int, ...]
    min_distance_cm: int
    max_distance_cm: int
    sensor_type: int
    increment_deg: float
    angle_offset_deg: float
    frame: int


@dataclass(frozen=True, slots=True)
class CommandLong(Sourced):
    """COMMAND_LONG (e.g. a ground station's pause or land for the companion): MAV_CMD, its target, params 1-7
    (units per command; NaN is a value some commands use)."""

    message: ClassVar[str] = "COMMAND_LONG"
    command: int
    target_system: int
    target_component: int
    params: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class CommandInt(CommandLong):
    """COMMAND_INT: as :class:`CommandLong`, params 1-4 then x, y (integers, e.g. degE7) and z, and its frame."""

    message: ClassVar[str] = "COMMAND_INT"
    frame: int


@dataclass(frozen=True, slots=True)
class Rejected(Sourced):
    """A message refused while decoding: ``message`` its type name, ``kind`` why (``nonfinite``)."""

    message: str
    kind: str


TelemetryEvent = (Heartbeat | SysStatus | Attitude | LocalPositionNed | GlobalPositionInt | HomePosition
                  | ExtendedSysState | SystemTime | HighresImu | ScaledImu | EstimatorStatus | StatusText
                  | CommandAck | ParamValue | SwingSensor | AutopilotVersion | GpsGlobalOrigin | MissionCount
                  | MissionItemInt | MissionAck | ObstacleDistance | CommandLong | CommandInt | Rejected)


def _constructor(cls: type) -> Any:
    """A positional constructor of the frozen, slotted ``cls`` that fills its slots directly (a frozen
    dataclass's ``__init__`` costs about 3× more per field); same instance as ``cls(*args)``."""
    names = [f.name for f in fields(cls)]
    env: dict[str, Any] = {"_new": object.__new__, "_cls": cls}
    body = [f"def make({', '.join(names)}):", "    o = _new(_cls)"]
    for k, n in enumerate(names):
        env[f"_s{k}"] = getattr(cls, n).__set__  # the slot's member descriptor
        body.append(f"    _s{k}(o, {n})")
    body.append("    return o")
    exec("\n".join(body), env)  # code generated from our own field names, as dataclasses does
    return env["make"]


for _cls in (Heartbeat, SysStatus, Attitude, LocalPositionNed, GlobalPositionInt, HomePosition, ExtendedSysState,
             SystemTime, HighresImu, ScaledImu, EstimatorStatus, StatusText, CommandAck, ParamValue, SwingSensor,
             AutopilotVersion, GpsGlobalOrigin, MissionCount, MissionItemInt, MissionAck, ObstacleDistance,
             CommandLong, CommandInt, Rejected):
    _cls._make = _constructor(_cls)  # type: ignore[attr-defined]  # the decoders' constructor
