"""Typed telemetry: the MAVLink messages the companion reads, decoded into SI units (pure: stdlib only).

:func:`decode` turns one received message into one frozen event (or None for a message nobody here reads);
:func:`decode_frame` does the same straight from an unsigned MAVLink 2 frame's bytes. Estimation
(:class:`~companion.estimation.vehicle_state.VehicleState`, :class:`~companion.estimation.swing_feed.SwingFeed`)
and the request answers (:meth:`~companion.mavlink_io.commands.RequestLink.answer_of`) consume these events; a
new message the companion should read gets its event class and decoder here.

Every event carries its source: ``src_system``, ``src_component`` and ``seq`` (the frame's sequence number).
Units are SI and named in the fields (``t_boot_s``: vehicle time since boot, s; ``pos_ned_m``: local NED, m; ...).

Validity checks that belong to decoding: a non-finite value in a field the companion would use (position,
velocity, attitude, rates, home, swing angles, IMU acceleration, estimator accuracy, parameter value) turns the
message into :class:`Rejected` (``kind="nonfinite"``), which the vehicle state counts in its ``rejected`` tally.
Range, ordering and clock checks need the state and stay there.

Hot path: a message decoded by the codec's ``decode_lite`` (``LiteMessage``) is decoded again from its frame
with one precompiled ``struct`` call over just the fields used (a prefix of the payload; MAVLink 2's trimmed
trailing zeros are restored), and the event is built without the frozen dataclass ``__init__`` (which goes
through ``object.__setattr__`` per field). pymavlink's own message objects take a slower path by field name.
The layouts are checked against pymavlink's in ``tests/test_telemetry.py``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields
from math import isfinite
from typing import Any, ClassVar

MG_TO_MPS2 = 9.80665e-3  # SCALED_IMU's milli-g in m/s²
SWING_ARRAY_NAME = "SWING"  # DEBUG_FLOAT_ARRAY name of the cable-angle sensor
_SWING_RAW = SWING_ARRAY_NAME.encode().ljust(10, b"\x00")  # ... as char[10] on the wire


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


# ------------------------------------------------------------------------------------------------ decoders
# Each takes the unpacked fields (wire order, a prefix of the payload), the source system, component and sequence
# number. ``x * 0.0`` is 0.0 for every finite x and NaN for ±inf and NaN: a sum of such terms is 0.0 exactly when
# every term is finite (no overflow, unlike a sum of the values themselves).
def _text(raw: bytes | str) -> str:
    """A char[] field as pymavlink shows it: up to the first NUL, ASCII (undecodable bytes replaced)."""
    if raw.__class__ is bytes:
        return raw.split(b"\x00", 1)[0].decode("ascii", errors="replace")
    return str(raw).split("\x00", 1)[0]


def _d_heartbeat(t: tuple, s: int, c: int, q: int) -> Heartbeat:
    custom_mode, mav_type, autopilot, base_mode, system_status = t
    return Heartbeat._make(s, c, q, mav_type, autopilot, base_mode, custom_mode, system_status)


def _d_sys_status(t: tuple, s: int, c: int, q: int) -> SysStatus:
    return SysStatus._make(s, c, q, t[0], t[2], t[1])


def _d_command_long(t: tuple, s: int, c: int, q: int) -> CommandLong:
    return CommandLong._make(s, c, q, t[7], t[8], t[9], t[:7])


def _d_command_int(t: tuple, s: int, c: int, q: int) -> CommandInt:
    return CommandInt._make(s, c, q, t[7], t[8], t[9], (*t[:4], float(t[4]), float(t[5]), t[6]), t[10])


def _d_attitude(t: tuple, s: int, c: int, q: int) -> Attitude | Rejected:
    ms, r, p, y, rr, pr, yr = t
    if r * 0.0 + p * 0.0 + y * 0.0 + rr * 0.0 + pr * 0.0 + yr * 0.0 != 0.0:
        return Rejected._make(s, c, q, "ATTITUDE", "nonfinite")
    return Attitude._make(s, c, q, ms * 1e-3, (r, p, y), (rr, pr, yr))


def _d_local_position(t: tuple, s: int, c: int, q: int) -> LocalPositionNed | Rejected:
    ms, x, y, z, vx, vy, vz = t
    if x * 0.0 + y * 0.0 + z * 0.0 + vx * 0.0 + vy * 0.0 + vz * 0.0 != 0.0:
        return Rejected._make(s, c, q, "LOCAL_POSITION_NED", "nonfinite")
    return LocalPositionNed._make(s, c, q, ms * 1e-3, (x, y, z), (vx, vy, vz))


def _d_global_position(t: tuple, s: int, c: int, q: int) -> GlobalPositionInt:
    ms, lat, lon, alt, _rel, vx, vy, vz = t
    return GlobalPositionInt._make(s, c, q, ms * 1e-3, lat * 1e-7, lon * 1e-7, alt * 1e-3,
                            (vx * 1e-2, vy * 1e-2, vz * 1e-2))


def _d_home(t: tuple, s: int, c: int, q: int) -> HomePosition | Rejected:
    lat, lon, alt, x, y, z = t
    if x * 0.0 + y * 0.0 + z * 0.0 != 0.0:
        return Rejected._make(s, c, q, "HOME_POSITION", "nonfinite")
    return HomePosition._make(s, c, q, (x, y, z), lat * 1e-7, lon * 1e-7, alt * 1e-3)


def _d_origin(t: tuple, s: int, c: int, q: int) -> GpsGlobalOrigin:
    return GpsGlobalOrigin._make(s, c, q, t[0] * 1e-7, t[1] * 1e-7, t[2] * 1e-3)


def _d_mission_count(t: tuple, s: int, c: int, q: int) -> MissionCount:
    return MissionCount._make(s, c, q, t[0], t[3])


def _d_mission_item(t: tuple, s: int, c: int, q: int) -> MissionItemInt:
    p1, p2, p3, p4, x, y, z, seq, command, _ts, _tc, frame, current, autocontinue, mission_type = t
    return MissionItemInt._make(s, c, q, seq, frame, command, current, autocontinue, (p1, p2, p3, p4), x, y, z,
                                mission_type)


def _d_mission_ack(t: tuple, s: int, c: int, q: int) -> MissionAck:
    return MissionAck._make(s, c, q, t[2], t[3])


def _d_ext_state(t: tuple, s: int, c: int, q: int) -> ExtendedSysState:
    return ExtendedSysState._make(s, c, q, t[1])


def _d_system_time(t: tuple, s: int, c: int, q: int) -> SystemTime:
    return SystemTime._make(s, c, q, t[1])


def _d_highres(t: tuple, s: int, c: int, q: int) -> HighresImu | Rejected:
    us, ax, ay, az = t
    if ax * 0.0 + ay * 0.0 + az * 0.0 != 0.0:
        return Rejected._make(s, c, q, "HIGHRES_IMU", "nonfinite")
    return HighresImu._make(s, c, q, us * 1e-6, (ax, ay, az))


def _d_scaled(t: tuple, s: int, c: int, q: int) -> ScaledImu:
    ms, ax, ay, az = t
    return ScaledImu._make(s, c, q, ms * 1e-3, (ax * MG_TO_MPS2, ay * MG_TO_MPS2, az * MG_TO_MPS2))


def _d_est_status(t: tuple, s: int, c: int, q: int) -> EstimatorStatus | Rejected:
    acc = t[7]
    if not isfinite(acc):
        return Rejected._make(s, c, q, "ESTIMATOR_STATUS", "nonfinite")
    return EstimatorStatus._make(s, c, q, acc)


def _d_statustext(t: tuple, s: int, c: int, q: int) -> StatusText:
    return StatusText._make(s, c, q, t[0], _text(t[1]), t[2], t[3])


def _d_ack(t: tuple, s: int, c: int, q: int) -> CommandAck:
    return CommandAck._make(s, c, q, t[0], t[1])


def _d_param(t: tuple, s: int, c: int, q: int) -> ParamValue | Rejected:
    if not isfinite(t[0]):
        return Rejected._make(s, c, q, "PARAM_VALUE", "nonfinite")
    return ParamValue._make(s, c, q, _text(t[3]), t[0])


def _d_debug_array(t: tuple, s: int, c: int, q: int) -> SwingSensor | Rejected | None:
    us, _array_id, name, a, b, da, db, reach = t
    if name != _SWING_RAW and _text(name) != SWING_ARRAY_NAME:  # the wire's bytes, else as text
        return None
    if a * 0.0 + b * 0.0 + da * 0.0 + db * 0.0 != 0.0:
        return Rejected._make(s, c, q, "DEBUG_FLOAT_ARRAY", "nonfinite")
    return SwingSensor._make(s, c, q, us * 1e-6, (a, b, da, db), reach)


def _d_version(t: tuple, s: int, c: int, q: int) -> AutopilotVersion:
    return AutopilotVersion._make(s, c, q, t[0], t[2], t[6], t[7], bytes(t[8:16]))


def _d_obstacle_distance(t: tuple, s: int, c: int, q: int) -> ObstacleDistance | Rejected:
    inc_f, offset = t[77], t[78]
    if inc_f * 0.0 + offset * 0.0 != 0.0:
        return Rejected._make(s, c, q, "OBSTACLE_DISTANCE", "nonfinite")
    return ObstacleDistance._make(s, c, q, t[0], t[1:73], t[73], t[74], t[75], inc_f if inc_f != 0.0 else t[76],
                                  offset, t[79])


class _Layout:
    """One message's decoding: its id, the struct of the payload prefix it reads, those fields' names and array
    lengths (for pymavlink's message objects), and the decoder."""

    __slots__ = ("build", "fields", "msgid", "size", "unpack_from")

    def __init__(self, msgid: int, fmt: str, field_spec: str, build: Any) -> None:
        st = struct.Struct(fmt)
        self.msgid, self.size, self.unpack_from, self.build = msgid, st.size, st.unpack_from, build
        self.fields = tuple((f.partition("*")[0], int(f.partition("*")[2] or 1)) for f in field_spec.split())


_LAYOUTS = {lay.msgid: lay for lay in (
    _Layout(0, "<IBBBB", "custom_mode type autopilot base_mode system_status", _d_heartbeat),
    _Layout(1, "<III", "onboard_control_sensors_present onboard_control_sensors_enabled "
                       "onboard_control_sensors_health", _d_sys_status),
    _Layout(2, "<QI", "time_unix_usec time_boot_ms", _d_system_time),
    _Layout(22, "<fHH16s", "param_value param_count param_index param_id", _d_param),
    _Layout(26, "<Ihhh", "time_boot_ms xacc yacc zacc", _d_scaled),
    _Layout(30, "<Iffffff", "time_boot_ms roll pitch yaw rollspeed pitchspeed yawspeed", _d_attitude),
    _Layout(32, "<Iffffff", "time_boot_ms x y z vx vy vz", _d_local_position),
    _Layout(33, "<Iiiiihhh", "time_boot_ms lat lon alt relative_alt vx vy vz", _d_global_position),
    _Layout(44, "<HBBB", "count target_system target_component mission_type", _d_mission_count),
    _Layout(47, "<BBBB", "target_system target_component type mission_type", _d_mission_ack),
    _Layout(49, "<iii", "latitude longitude altitude", _d_origin),
    _Layout(73, "<ffffiifHHBBBBBB", "param1 param2 param3 param4 x y z seq command target_system target_component "
                                    "frame current autocontinue mission_type", _d_mission_item),
    _Layout(75, "<4fiifHBBB", "param1 param2 param3 param4 x y z command target_system target_component frame",
            _d_command_int),
    _Layout(76, "<7fHBB", "param1 param2 param3 param4 param5 param6 param7 command target_system "
                          "target_component", _d_command_long),
    _Layout(77, "<HB", "command result", _d_ack),
    _Layout(105, "<Qfff", "time_usec xacc yacc zacc", _d_highres),
    _Layout(148, "<QQIIIIHH8B", "capabilities uid flight_sw_version middleware_sw_version os_sw_version "
                                "board_version vendor_id product_id flight_custom_version*8", _d_version),
    _Layout(230, "<Qfffffff", "time_usec vel_ratio pos_horiz_ratio pos_vert_ratio mag_ratio hagl_ratio tas_ratio "
                              "pos_horiz_accuracy", _d_est_status),
    _Layout(242, "<iiifff", "latitude longitude altitude x y z", _d_home),
    _Layout(245, "<BB", "vtol_state landed_state", _d_ext_state),
    _Layout(253, "<B50sHB", "severity text id chunk_seq", _d_statustext),
    _Layout(350, "<QH10s5f", "time_usec array_id name data*5", _d_debug_array),
    _Layout(330, "<Q72HHHBBffB", "time_usec distances*72 min_distance max_distance sensor_type increment "
                                 "increment_f angle_offset frame", _d_obstacle_distance),
)}
#: the message ids :func:`decode` reads (others decode to None)
DECODED_IDS = frozenset(_LAYOUTS)
_ZEROS = bytes(256)


def decode_frame(frame: bytes) -> TelemetryEvent | None:
    """The event of one unsigned MAVLink 2 frame (``frame`` exactly its bytes, CRC already checked: e.g. by
    ``codec.decode_lite`` or ``codec.check_crc``), or None for a message not read here."""
    lay = _LAYOUTS.get(frame[7] | (frame[8] << 8) | (frame[9] << 16))
    if lay is None:
        return None
    n = frame[1]
    size = lay.size  # MAVLink 2 trims the payload's trailing zeros: put them back when the prefix read lost some
    t = lay.unpack_from(frame, 10) if n >= size else lay.unpack_from(frame[10:10 + n] + _ZEROS[: size - n])
    return lay.build(t, frame[5], frame[6], frame[4])


def decode(msg: Any) -> TelemetryEvent | None:
    """The event of one received message: a codec ``LiteMessage`` (decoded from its frame) or a pymavlink
    message object (read by field name); None for a message not read here (see :data:`DECODED_IDS`)."""
    try:
        frame = msg._frame
    except AttributeError:
        return _decode_object(msg)
    lay = _LAYOUTS.get(frame[7] | (frame[8] << 8) | (frame[9] << 16))  # as decode_frame, inlined: the hot path
    if lay is None:
        return None
    n = frame[1]
    size = lay.size
    t = lay.unpack_from(frame, 10) if n >= size else lay.unpack_from(frame[10:10 + n] + _ZEROS[: size - n])
    return lay.build(t, frame[5], frame[6], frame[4])


def _decode_object(msg: Any) -> TelemetryEvent | None:
    """The slow path: a pymavlink message object (any text field as str or bytes, arrays as sequences)."""
    lay = _LAYOUTS.get(msg.get_msgId())
    if lay is None:
        return None
    vals: list[Any] = []
    for name, n in lay.fields:
        v = getattr(msg, name)
        if n == 1:
            vals.append(v)
        else:
            v = list(v)[:n]
            vals.extend(v + [0] * (n - len(v)))
    return lay.build(tuple(vals), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
