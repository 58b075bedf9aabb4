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
from math import isfinite
from typing import Any

from companion.mavlink_io.events import (  # the events, re-exported: decoding and its types are one interface
    Attitude,
    AutopilotVersion,
    CommandAck,
    CommandInt,
    CommandLong,
    EstimatorStatus,
    ExtendedSysState,
    GlobalPositionInt,
    GpsGlobalOrigin,
    Heartbeat,
    HighresImu,
    HomePosition,
    LocalPositionNed,
    MissionAck,
    MissionCount,
    MissionItemInt,
    ObstacleDistance,
    ParamValue,
    Rejected,
    ScaledImu,
    StatusText,
    SwingSensor,
    SysStatus,
    SystemTime,
    TelemetryEvent,
)

MG_TO_MPS2 = 9.80665e-3  # SCALED_IMU's milli-g in m/s²
SWING_ARRAY_NAME = "SWING"  # DEBUG_FLOAT_ARRAY name of the cable-angle sensor
_SWING_RAW = SWING_ARRAY_NAME.encode().ljust(10, b"\x00")  # ... as char[10] on the wire


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

__all__ = [
    "DECODED_IDS",
    "MG_TO_MPS2",
    "SWING_ARRAY_NAME",
    "Attitude",
    "AutopilotVersion",
    "CommandAck",
    "CommandInt",
    "CommandLong",
    "EstimatorStatus",
    "ExtendedSysState",
    "GlobalPositionInt",
    "GpsGlobalOrigin",
    "Heartbeat",
    "HighresImu",
    "HomePosition",
    "LocalPositionNed",
    "MissionAck",
    "MissionCount",
    "MissionItemInt",
    "ObstacleDistance",
    "ParamValue",
    "Rejected",
    "ScaledImu",
    "StatusText",
    "SwingSensor",
    "SysStatus",
    "SystemTime",
    "TelemetryEvent",
    "decode",
    "decode_frame",
]
