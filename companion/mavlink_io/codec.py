"""Fast MAVLink 2 framing for the lockstep hot path: precompiled packing and decoding, standard frames.

pymavlink's generated codec is correct but slow in pure Python (a frame costs ~10–20 µs to pack or decode).
This module produces and reads *byte-identical* MAVLink 2 frames (unsigned, trailing payload zeros trimmed,
CRC-16/MCRF4XX with the message's CRC extra) with a few precompiled ``struct.Struct`` calls:

* ``send_*`` functions pack the hot messages and write the frame through a pymavlink ``MAVLink`` object,
  using and advancing *its* sequence number and counters, so fast and pymavlink-packed frames can be mixed
  on one link;
* :func:`decode_frame` decodes one unsigned MAVLink 2 frame of any message pymavlink's common dialect knows
  into pymavlink's own message class (same fields and types as ``MAVLink.decode``), skipping pymavlink's
  per-byte work. It raises :class:`FrameError` on a bad CRC (the caller counts it).

The CRC uses the C-accelerated ``fastcrc`` package when installed (pymavlink itself prefers it), else
pymavlink's CRC.
"""

from __future__ import annotations

import struct
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

try:  # pymavlink uses fastcrc too when it is installed; same polynomial and start value
    from fastcrc.crc16 import mcrf4xx as crc_mcrf4xx  # CRC-16/MCRF4XX (MAVLink's X.25 CRC) of bytes
except ImportError:  # pragma: no cover - depends on the environment

    def crc_mcrf4xx(data: bytes) -> int:
        """CRC-16/MCRF4XX (MAVLink's X.25 CRC) of ``data``."""
        return mavlink2.x25crc(data).crc


STX_V2 = mavlink2.PROTOCOL_MARKER_V2
HEADER_LEN = 10
_HDR = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_BYTE = [bytes((k,)) for k in range(256)]

# message ids and CRC extras of the hand-packed messages
ID_HEARTBEAT, CRC_HEARTBEAT = 0, 50
ID_SYSTEM_TIME, CRC_SYSTEM_TIME = 2, 137
ID_ATTITUDE, CRC_ATTITUDE = 30, 39
ID_ATTITUDE_QUATERNION, CRC_ATTITUDE_QUATERNION = 31, 246
ID_LOCAL_POSITION_NED, CRC_LOCAL_POSITION_NED = 32, 185
ID_GLOBAL_POSITION_INT, CRC_GLOBAL_POSITION_INT = 33, 104
ID_SET_ATTITUDE_TARGET, CRC_SET_ATTITUDE_TARGET = 82, 49
ID_ATTITUDE_TARGET, CRC_ATTITUDE_TARGET = 83, 22
ID_EXTENDED_SYS_STATE, CRC_EXTENDED_SYS_STATE = 245, 130
ID_DEBUG_FLOAT_ARRAY, CRC_DEBUG_FLOAT_ARRAY = 350, 232

P_HEARTBEAT = struct.Struct("<IBBBBB")
P_SYSTEM_TIME = struct.Struct("<QI")
P_ATTITUDE = struct.Struct("<Iffffff")
P_ATTITUDE_QUATERNION = struct.Struct("<Ifffffff")  # repr_offset_q (extension) = 0: trimmed anyway
P_LOCAL_POSITION_NED = struct.Struct("<Iffffff")
P_GLOBAL_POSITION_INT = struct.Struct("<IiiiihhhH")
P_SET_ATTITUDE_TARGET = struct.Struct("<IffffffffBBB")
P_ATTITUDE_TARGET = struct.Struct("<IffffffffB")
P_EXTENDED_SYS_STATE = struct.Struct("<BB")
P_SWING = struct.Struct("<QH10s5f")  # DEBUG_FLOAT_ARRAY with data[5:] = 0 (trimmed on the wire)


class FrameError(ValueError):
    """A frame that cannot be decoded; ``kind`` is "bad_crc" or "unknown_id"."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(detail)
        self.kind = kind


# ------------------------------------------------------------------------------------------------ packing
def frame_v2(seq: int, sysid: int, compid: int, msgid: int, crc_extra: int, payload: bytes) -> bytes:
    """One unsigned MAVLink 2 frame, exactly as pymavlink packs it (trailing zeros trimmed, ≥ 1 byte)."""
    body = payload.rstrip(b"\x00") or payload[:1]
    buf = _HDR.pack(STX_V2, len(body), 0, 0, seq, sysid, compid, msgid & 0xFFFF, msgid >> 16) + body
    return buf + _CRC.pack(crc_mcrf4xx(buf[1:] + _BYTE[crc_extra]))


def send_payload(mav: Any, msgid: int, crc_extra: int, payload: bytes) -> None:
    """Frame ``payload`` with ``mav``'s ids and sequence number and write it to ``mav.file`` (as
    ``MAVLink.send`` does: the sequence number and send counters advance; no signing)."""
    body = payload.rstrip(b"\x00") or payload[:1]
    buf = _HDR.pack(STX_V2, len(body), 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, msgid & 0xFFFF,
                    msgid >> 16) + body
    buf += _CRC.pack(crc_mcrf4xx(buf[1:] + _BYTE[crc_extra]))
    mav.file.write(buf)
    mav.seq = (mav.seq + 1) & 0xFF
    mav.total_packets_sent += 1
    mav.total_bytes_sent += len(buf)


def send_heartbeat(mav: Any, mav_type: int, autopilot: int, base_mode: int, custom_mode: int,
                   system_status: int) -> None:
    """HEARTBEAT (mavlink_version 3)."""
    send_payload(mav, ID_HEARTBEAT, CRC_HEARTBEAT,
                 P_HEARTBEAT.pack(custom_mode, mav_type, autopilot, base_mode, system_status, 3))


def send_system_time(mav: Any, time_unix_usec: int, time_boot_ms: int) -> None:
    """SYSTEM_TIME."""
    send_payload(mav, ID_SYSTEM_TIME, CRC_SYSTEM_TIME, P_SYSTEM_TIME.pack(time_unix_usec, time_boot_ms))


def send_attitude(mav: Any, t_ms: int, roll: float, pitch: float, yaw: float, p: float, q: float,
                  r: float) -> None:
    """ATTITUDE: Euler angles (rad) and body rates FRD (rad/s)."""
    send_payload(mav, ID_ATTITUDE, CRC_ATTITUDE, P_ATTITUDE.pack(t_ms, roll, pitch, yaw, p, q, r))


def send_attitude_quaternion(mav: Any, t_ms: int, q1: float, q2: float, q3: float, q4: float, p: float,
                             q: float, r: float) -> None:
    """ATTITUDE_QUATERNION (repr_offset_q = 0)."""
    send_payload(mav, ID_ATTITUDE_QUATERNION, CRC_ATTITUDE_QUATERNION,
                 P_ATTITUDE_QUATERNION.pack(t_ms, q1, q2, q3, q4, p, q, r))


def send_local_position_ned(mav: Any, t_ms: int, x: float, y: float, z: float, vx: float, vy: float,
                            vz: float) -> None:
    """LOCAL_POSITION_NED (m, m/s)."""
    send_payload(mav, ID_LOCAL_POSITION_NED, CRC_LOCAL_POSITION_NED,
                 P_LOCAL_POSITION_NED.pack(t_ms, x, y, z, vx, vy, vz))


def send_global_position_int(mav: Any, t_ms: int, lat: int, lon: int, alt: int, relative_alt: int, vx: int,
                             vy: int, vz: int, hdg: int) -> None:
    """GLOBAL_POSITION_INT (degE7, mm, cm/s, cdeg)."""
    send_payload(mav, ID_GLOBAL_POSITION_INT, CRC_GLOBAL_POSITION_INT,
                 P_GLOBAL_POSITION_INT.pack(t_ms, lat, lon, alt, relative_alt, vx, vy, vz, hdg))


def send_attitude_target(mav: Any, t_ms: int, type_mask: int, q: Any, roll_rate: float, pitch_rate: float,
                         yaw_rate: float, thrust: float) -> None:
    """ATTITUDE_TARGET (q = [w x y z])."""
    send_payload(mav, ID_ATTITUDE_TARGET, CRC_ATTITUDE_TARGET,
                 P_ATTITUDE_TARGET.pack(t_ms, q[0], q[1], q[2], q[3], roll_rate, pitch_rate, yaw_rate, thrust,
                                         type_mask))


def send_set_attitude_target(mav: Any, t_ms: int, target_system: int, target_component: int, type_mask: int,
                             q: Any, roll_rate: float, pitch_rate: float, yaw_rate: float, thrust: float) -> None:
    """SET_ATTITUDE_TARGET (q = [w x y z] NED→FRD, normalized thrust)."""
    send_payload(mav, ID_SET_ATTITUDE_TARGET, CRC_SET_ATTITUDE_TARGET,
                 P_SET_ATTITUDE_TARGET.pack(t_ms, q[0], q[1], q[2], q[3], roll_rate, pitch_rate, yaw_rate, thrust,
                                             target_system, target_component, type_mask))


def send_extended_sys_state(mav: Any, vtol_state: int, landed_state: int) -> None:
    """EXTENDED_SYS_STATE."""
    send_payload(mav, ID_EXTENDED_SYS_STATE, CRC_EXTENDED_SYS_STATE,
                 P_EXTENDED_SYS_STATE.pack(vtol_state, landed_state))


def send_debug_float_array5(mav: Any, time_usec: int, name: bytes, array_id: int, d0: float, d1: float,
                            d2: float, d3: float, d4: float) -> None:
    """DEBUG_FLOAT_ARRAY with data[0..4] given and data[5:] = 0 (the simulated cable-angle sensor)."""
    send_payload(mav, ID_DEBUG_FLOAT_ARRAY, CRC_DEBUG_FLOAT_ARRAY,
                 P_SWING.pack(time_usec, array_id, name, d0, d1, d2, d3, d4))


# ------------------------------------------------------------------------------------------------ decoding
class _Plan:
    """How to turn one message type's unpacked payload tuple into its constructor arguments."""

    __slots__ = ("cls", "crc_extra", "fieldnames", "has_bytes", "name", "orders", "simple", "size", "slices",
                 "unpacker", "wire_names", "wire_slices")

    def __init__(self, cls: Any) -> None:
        self.cls = cls
        self.name = cls.msgname
        self.crc_extra = bytes((cls.crc_extra,))
        self.unpacker = cls.unpacker
        self.size = cls.unpacker.size
        lengths = cls.lengths
        self.simple = sum(lengths) == len(lengths)
        self.orders = list(cls.orders)
        # for messages with arrays: (start index in the unpacked tuple, length) per constructor argument
        self.slices = [(sum(lengths[:o]), lengths[o]) for o in cls.orders]
        self.has_bytes = "s" in cls.unpacker.format
        self.fieldnames = list(cls.ordered_fieldnames)  # wire order = the unpacked tuple's order
        self.wire_names = list(cls.ordered_fieldnames)
        starts = [sum(lengths[:k]) for k in range(len(lengths))]
        self.wire_slices = list(zip(starts, lengths, strict=True))


_PLANS: dict[int, _Plan] = {}


def _plan(msgid: int) -> _Plan | None:
    p = _PLANS.get(msgid)
    if p is None:
        cls = mavlink2.mavlink_map.get(msgid)
        if cls is None:
            return None
        p = _PLANS[msgid] = _Plan(cls)
    return p


def message_name(msgid: int) -> str | None:
    """pymavlink's type name of ``msgid`` (None if the common dialect does not know it)."""
    p = _plan(msgid)
    return None if p is None else p.name


def frame_msgid(buf: bytes, i: int = 0) -> int:
    """Message id of the MAVLink 2 frame starting at ``buf[i]`` (header must be complete)."""
    return buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)


def check_crc(frame: bytes, msgid: int) -> bool:
    """True if the unsigned MAVLink 2 ``frame`` of a known ``msgid`` carries the right CRC."""
    p = _plan(msgid)
    if p is None:
        return False
    return crc_mcrf4xx(frame[1:-2] + p.crc_extra) == (frame[-2] | (frame[-1] << 8))


def _checked_plan(frame: bytes) -> _Plan:
    n = len(frame)
    plen = frame[1]
    if n != HEADER_LEN + plen + 2:
        raise FrameError("bad_crc", f"frame length {n} does not match payload length {plen}")
    msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    p = _PLANS.get(msgid) or _plan(msgid)
    if p is None:
        raise FrameError("unknown_id", f"message id {msgid}")
    if crc_mcrf4xx(frame[1:-2] + p.crc_extra) != frame[-2] | (frame[-1] << 8):
        raise FrameError("bad_crc", f"invalid MAVLink CRC in msgID {msgid}")
    return p


def _unpack(p: _Plan, frame: bytes) -> tuple:
    size = p.size
    plen = frame[1]
    payload = frame[HEADER_LEN:-2]
    if plen < size:
        payload = payload + bytes(size - plen)
    elif plen > size:
        payload = payload[:size]
    return p.unpacker.unpack(payload)


def decode_frame(frame: bytes) -> Any:
    """Decode one complete, unsigned MAVLink 2 frame (``frame`` is exactly the frame's bytes).

    Returns pymavlink's message object, as ``MAVLink.decode`` would; raises :class:`FrameError` with kind
    "unknown_id" (id not in the common dialect) or "bad_crc" (CRC or length mismatch).
    """
    return _build_full(_checked_plan(frame), frame)


def decode_fields(frame: bytes) -> tuple:
    """The payload fields of one complete, unsigned MAVLink 2 frame as a plain tuple in wire order (arrays
    flattened, as ``struct`` unpacks them; trailing zeros restored), CRC and length checked as in
    :func:`decode_frame` (:class:`FrameError` otherwise). No message object is made: for hot loops that
    read one or two known message types (e.g. SYSTEM_TIME → (time_unix_usec, time_boot_ms))."""
    return _unpack(_checked_plan(frame), frame)


def _build_full(p: _Plan, frame: bytes) -> Any:
    t = _unpack(p, frame)
    if p.simple:
        args = [t[o] for o in p.orders]
    else:
        args = []
        for tip, ln in p.slices:
            f = t[tip]
            args.append(f if ln == 1 or isinstance(f, bytes) else list(t[tip : tip + ln]))
    if p.has_bytes:
        args = [a.rstrip(b"\x00") if isinstance(a, bytes) else a for a in args]
    m = p.cls(*args)
    m._msgbuf = bytearray(frame)
    m._payload = m._msgbuf[6:-2]
    m._crc = frame[-2] | (frame[-1] << 8)
    m._header = mavlink2.MAVLink_header(p.cls.id, frame[2], frame[3], frame[1], frame[4], frame[5], frame[6])
    return m


class LiteMessage:
    """A decoded message: its fields as attributes (arrays as lists, text as str) and
    pymavlink's ``get_type/get_msgId/get_srcSystem/get_srcComponent/get_seq/get_msgbuf``. Anything else
    (``to_dict``, ``get_header``, ...) is answered by pymavlink's full message, decoded on first use."""

    __slots__ = ("__dict__", "_frame", "_full", "_msgid", "_type")

    def get_type(self) -> str:
        return self._type

    def get_msgId(self) -> int:
        return self._msgid

    def get_srcSystem(self) -> int:
        return self._frame[5]

    def get_srcComponent(self) -> int:
        return self._frame[6]

    def get_seq(self) -> int:
        return self._frame[4]

    def get_msgbuf(self) -> bytearray:
        return bytearray(self._frame)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        try:
            full = object.__getattribute__(self, "_full")
        except AttributeError:
            full = _build_full(_PLANS[self._msgid], self._frame)
            object.__setattr__(self, "_full", full)
        return getattr(full, name)

    def __repr__(self) -> str:
        return f"{self._type} {self.__dict__}"


# messages whose char fields pymavlink's constructor turns into str as ``raw.split(b"\0")[0].decode("ascii",
# errors="replace")`` (checked against pymavlink in tests/test_mavlink_fast.py); others with text stay full
_LITE_TEXT_IDS = frozenset({ID_DEBUG_FLOAT_ARRAY})


def decode_lite(frame: bytes) -> Any:
    """Like :func:`decode_frame`, but messages of numbers and number arrays (and DEBUG_FLOAT_ARRAY) come
    back as a cheaper :class:`LiteMessage` with the same field names and values; others as pymavlink's."""
    p = _checked_plan(frame)
    if p.has_bytes and p.cls.id not in _LITE_TEXT_IDS:
        return _build_full(p, frame)
    m = LiteMessage()
    m._frame = frame
    m._msgid = p.cls.id
    m._type = p.name
    t = _unpack(p, frame)
    if p.simple:
        m.__dict__.update(zip(p.fieldnames, t, strict=True))
        return m
    d = m.__dict__
    for name, (tip, ln) in zip(p.wire_names, p.wire_slices, strict=True):
        f = t[tip]
        if isinstance(f, bytes):
            f = f.split(b"\x00", 1)[0].decode("ascii", errors="replace")
        elif ln != 1:
            f = list(t[tip : tip + ln])
        d[name] = f
    return m


_CRC_EXTRA_EXTRA = {300: 217}  # PROTOCOL_VERSION, missing from pymavlink's common dialect


def crc_extra_of(msgid: int) -> int:
    """CRC extra byte of a message id (KeyError if neither pymavlink's common dialect nor we know it)."""
    cls = mavlink2.mavlink_map.get(msgid)
    return cls.crc_extra if cls is not None else _CRC_EXTRA_EXTRA[msgid]
