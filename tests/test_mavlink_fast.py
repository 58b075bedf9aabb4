"""companion.mavlink_io.codec: hand-packed frames are byte-identical to pymavlink's; decode_frame agrees with
pymavlink's decoder; bad frames raise FrameError, never anything else."""

from __future__ import annotations

import math
import random

import pytest
from pymavlink.dialects.v20 import common as M

from companion.mavlink_io import codec as mf


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.frames.append(bytes(buf))


def _pair(sysid: int = 7, compid: int = 42, seq0: int = 250) -> tuple[M.MAVLink, M.MAVLink]:
    a, b = _Sink(), _Sink()
    ref = M.MAVLink(a, srcSystem=sysid, srcComponent=compid)
    fast = M.MAVLink(b, srcSystem=sysid, srcComponent=compid)
    ref.seq = fast.seq = seq0
    return ref, fast


def _f32(x: float) -> float:
    return M.struct.unpack("<f", M.struct.pack("<f", x))[0]


def _cases(rng: random.Random):
    """(pymavlink send call, fast send call) pairs with random arguments, including all-zero payloads."""
    for k in range(40):
        z = k == 0  # one all-zero case per message: pymavlink keeps one payload byte
        r = (lambda: 0.0) if z else (lambda: rng.uniform(-1e3, 1e3))
        ri = (lambda lo, hi: 0) if z else rng.randint
        t_ms = ri(0, 2**32 - 1)
        q = [r() for _ in range(4)]
        a6 = [r() for _ in range(6)]
        hb = (ri(0, 255), ri(0, 255), ri(0, 255), ri(0, 2**32 - 1), ri(0, 255))
        yield (lambda m, a=hb: m.heartbeat_send(*a), lambda m, a=hb: mf.send_heartbeat(m, *a))
        tu = ri(0, 2**63)
        yield (lambda m, tu=tu, t=t_ms: m.system_time_send(tu, t),
               lambda m, tu=tu, t=t_ms: mf.send_system_time(m, tu, t))
        yield (lambda m, t=t_ms, a=a6: m.attitude_send(t, *a), lambda m, t=t_ms, a=a6: mf.send_attitude(m, t, *a))
        yield (lambda m, t=t_ms, q=q, a=a6: m.attitude_quaternion_send(t, *q, *a[:3]),
               lambda m, t=t_ms, q=q, a=a6: mf.send_attitude_quaternion(m, t, *q, *a[:3]))
        yield (lambda m, t=t_ms, a=a6: m.local_position_ned_send(t, *a),
               lambda m, t=t_ms, a=a6: mf.send_local_position_ned(m, t, *a))
        gi = (ri(-900_000_000, 900_000_000), ri(-1_800_000_000, 1_800_000_000), ri(-10**6, 10**7), ri(-10**6, 10**7),
              ri(-32768, 32767), ri(-32768, 32767), ri(-32768, 32767), ri(0, 35999))
        yield (lambda m, t=t_ms, g=gi: m.global_position_int_send(t, *g),
               lambda m, t=t_ms, g=gi: mf.send_global_position_int(m, t, *g))
        mask = ri(0, 255)
        yield (lambda m, t=t_ms, q=q, a=a6, k=mask: m.attitude_target_send(t, k, q, a[0], a[1], a[2], a[3]),
               lambda m, t=t_ms, q=q, a=a6, k=mask: mf.send_attitude_target(m, t, k, q, a[0], a[1], a[2], a[3]))
        ts, tc = ri(0, 255), ri(0, 255)
        yield (lambda m, t=t_ms, q=q, a=a6, k=mask, s=ts, c=tc: m.set_attitude_target_send(t, s, c, k, q, *a[:4]),
               lambda m, t=t_ms, q=q, a=a6, k=mask, s=ts, c=tc: mf.send_set_attitude_target(m, t, s, c, k, q, *a[:4]))
        es = (ri(0, 4), ri(0, 4))
        yield (lambda m, e=es: m.extended_sys_state_send(*e), lambda m, e=es: mf.send_extended_sys_state(m, *e))
        d5 = [r() for _ in range(5)]
        yield (lambda m, t=tu, d=d5: m.debug_float_array_send(t, b"SWING", 1, d + [0.0] * 53),
               lambda m, t=tu, d=d5: mf.send_debug_float_array5(m, t, b"SWING", 1, *d))


def test_fast_packing_is_byte_identical_to_pymavlink() -> None:
    rng = random.Random(1234)
    ref, fast = _pair()
    n = 0
    for ref_call, fast_call in _cases(rng):
        ref_call(ref)
        fast_call(fast)
        n += 1
    assert n >= 400
    assert fast.file.frames == ref.file.frames  # same bytes, sequence numbers wrapping through 255
    assert fast.seq == ref.seq and fast.total_packets_sent == ref.total_packets_sent
    assert fast.total_bytes_sent == ref.total_bytes_sent


def test_decode_frame_matches_pymavlink_decode() -> None:
    rng = random.Random(99)
    ref, _ = _pair(seq0=0)
    for ref_call, _f in _cases(rng):
        ref_call(ref)
    ref.statustext_send(M.MAV_SEVERITY_INFO, b"Mode: OFFBOARD", 0, 0)  # a char field
    ref.command_ack_send(400, 0, 0, 0, 1, 191)
    ref.param_value_send(b"MPC_THR_HOVER", 0.4, 9, 10, 1)
    dec = M.MAVLink(None)
    for frame in ref.file.frames:
        want = dec.decode(bytearray(frame))
        got = mf.decode_frame(frame)
        assert type(got) is type(want)
        assert got.get_type() == want.get_type() and got.get_msgId() == want.get_msgId()
        assert (got.get_srcSystem(), got.get_srcComponent(), got.get_seq()) == (
            want.get_srcSystem(), want.get_srcComponent(), want.get_seq())
        assert got.to_dict() == want.to_dict()
        assert bytes(got.get_msgbuf()) == frame and got.get_crc() == want.get_crc()


def test_decode_frame_rejects_bad_frames_with_frame_error() -> None:
    ref, _ = _pair()
    ref.attitude_send(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    good = ref.file.frames[0]
    bad_crc = good[:-1] + bytes(((good[-1] + 1) & 0xFF,))
    with pytest.raises(mf.FrameError) as e:
        mf.decode_frame(bad_crc)
    assert e.value.kind == "bad_crc"
    flipped = bytearray(good)
    flipped[12] ^= 0x40
    with pytest.raises(mf.FrameError):
        mf.decode_frame(bytes(flipped))
    with pytest.raises(mf.FrameError) as e:
        mf.decode_frame(good[:-3])  # length does not match the header
    assert e.value.kind == "bad_crc"
    unknown = bytearray(good)
    unknown[7:10] = (300 & 0xFF, 300 >> 8, 0)  # PROTOCOL_VERSION: not in pymavlink's common dialect
    with pytest.raises(mf.FrameError) as e:
        mf.decode_frame(bytes(unknown))
    assert e.value.kind == "unknown_id"
    rng = random.Random(5)
    for _ in range(2000):  # random corruption: FrameError or a message, nothing else
        b = bytearray(good)
        b[rng.randrange(1, len(b))] = rng.randrange(256)
        if b[1] != good[1]:
            b = b[: 12 + b[1]] if len(b) >= 12 + b[1] else b
        try:
            m = mf.decode_frame(bytes(b))
        except mf.FrameError:
            continue
        assert m.get_msgbuf() == b


def test_nonfinite_floats_survive_the_round_trip() -> None:
    ref, _ = _pair()
    mf.send_attitude(ref, 5, math.nan, math.inf, -math.inf, 0.0, 1.0, 2.0)
    m = M.MAVLink(None).decode(bytearray(ref.file.frames[0]))
    assert math.isnan(m.roll) and m.pitch == math.inf and m.yaw == -math.inf
    assert mf.decode_frame(ref.file.frames[0]).yawspeed == _f32(2.0)


def test_decode_lite_matches_pymavlink_for_every_message() -> None:
    rng = random.Random(7)
    ref, _ = _pair(seq0=3)
    for ref_call, _f in _cases(rng):
        ref_call(ref)
    ref.command_ack_send(400, 4, 0, 0, 1, 191)
    ref.statustext_send(M.MAV_SEVERITY_INFO, b"Armed", 0, 0)
    dec = M.MAVLink(None)
    lite_types = set()
    for frame in ref.file.frames:
        want = dec.decode(bytearray(frame))
        got = mf.decode_lite(frame)
        if isinstance(got, mf.LiteMessage):
            lite_types.add(got.get_type())
            assert got.__dict__ == {k: getattr(want, k) for k in want.ordered_fieldnames}
        assert got.get_type() == want.get_type() and got.get_msgId() == want.get_msgId()
        assert (got.get_srcSystem(), got.get_srcComponent(), got.get_seq()) == (7, 42, want.get_seq())
        assert got.to_dict() == want.to_dict()  # through the full message, decoded on demand
        assert bytes(got.get_msgbuf()) == frame and got.get_header().msgId == want.get_msgId()
    assert {"ATTITUDE", "LOCAL_POSITION_NED", "SYSTEM_TIME", "HEARTBEAT", "COMMAND_ACK"} <= lite_types
    assert "DEBUG_FLOAT_ARRAY" in lite_types and "SET_ATTITUDE_TARGET" in lite_types
    assert "STATUSTEXT" not in lite_types
    with pytest.raises(AttributeError):
        _ = mf.decode_lite(ref.file.frames[0]).no_such_field


def _vehicle_datagram(seq0: int = 0) -> bytes:
    """What the bundled vehicle sends in one control period: several frames in one datagram."""
    mav, _ = _pair(sysid=1, compid=1, seq0=seq0)
    mf.send_attitude(mav, 1000, 0.01, -0.02, 0.3, 0.0, 0.1, 0.2)
    mf.send_local_position_ned(mav, 1000, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3)
    mf.send_debug_float_array5(mav, 1_000_000, b"SWING", 1, 0.1, -0.1, 0.0, 0.0, 1.0)
    mav.statustext_send(M.MAV_SEVERITY_INFO, b"Mode: OFFBOARD", 0, 0)
    mf.send_system_time(mav, 0, 1000)
    return b"".join(mav.file.frames)


def _link(tmp_path=None):
    from companion.mavlink_io.link import MavlinkLink

    got: list = []
    link = MavlinkLink("udpin://127.0.0.1:14999", got.append, tlog=None if tmp_path is None else tmp_path / "t.tlog")
    done: list = []
    link.on_datagram_done = lambda: done.append(len(got))
    return link, got, done


def test_companion_link_fast_path_gives_what_pymavlink_gives(tmp_path) -> None:
    data = _vehicle_datagram()
    link, got, done = _link(tmp_path)
    link._on_datagram(data, ("127.0.0.1", 14580))
    ref = list(M.MAVLink(None).parse_buffer(data))
    assert [m.get_type() for m in got] == [m.get_type() for m in ref] == [
        "ATTITUDE", "LOCAL_POSITION_NED", "DEBUG_FLOAT_ARRAY", "STATUSTEXT", "SYSTEM_TIME"]
    for g, r in zip(got, ref, strict=True):
        assert g.to_dict() == r.to_dict() and g.get_srcSystem() == r.get_srcSystem() == 1
    assert got[2].name == "SWING" and got[2].data[:5] == [_f32(x) for x in (0.1, -0.1, 0.0, 0.0, 1.0)]
    assert link.received == 5 and not link.rejected and done == [5]
    assert not link.connected  # nothing is sent before the app has locked onto the vehicle
    link.lock_to_last_sender()
    assert link.connected
    link.close()
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(tmp_path / "t.tlog"))  # every frame recorded, readable by mavutil
    types = []
    while (m := log.recv_match()) is not None:
        types.append(m.get_type())
    assert types == [m.get_type() for m in ref]


def test_signed_input_is_recorded_as_signed_frames_that_tlog_readers_parse(tmp_path) -> None:
    """With signing on, each accepted frame goes to the .tlog whole, signature included: mavutil and
    companion.mavlink_io.link.tlog_frames read back every message (a frame with the signed flag but no
    signature would make both misread the records after it)."""
    import time as _time

    from pymavlink import mavutil

    from companion.mavlink_io.codec import decode_lite
    from companion.mavlink_io.link import MavlinkLink, tlog_frames

    key = bytes(range(32))
    sink = _Sink()
    mav = M.MAVLink(sink, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = key
    mav.signing.link_id = 0
    mav.signing.timestamp = int((_time.time() - 1420070400) * 1e5)
    mav.signing.sign_outgoing = True
    mav.attitude_send(1000, 0.01, -0.02, 0.3, 0.0, 0.1, 0.2)  # pymavlink's own senders sign
    mav.local_position_ned_send(1000, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3)
    mav.system_time_send(0, 1000)
    got: list = []
    link = MavlinkLink("udpin://127.0.0.1:14999", got.append, tlog=tmp_path / "t.tlog", signing_key=key)
    link._on_datagram(b"".join(sink.frames), ("127.0.0.1", 14580))
    link.close()
    expected = ["ATTITUDE", "LOCAL_POSITION_NED", "SYSTEM_TIME"]
    assert [m.get_type() for m in got] == expected and not link.rejected
    frames = [f for _, f in tlog_frames(tmp_path / "t.tlog")]
    assert frames == sink.frames  # as received, signatures and all
    assert [decode_lite(f[:-13]).get_type() for f in frames] == expected
    log = mavutil.mavlink_connection(str(tmp_path / "t.tlog"))
    types = []
    while (m := log.recv_match()) is not None:
        types.append(m.get_type())
    assert types == expected


def test_companion_link_counts_bad_input_and_still_delivers_good_frames() -> None:
    good = _vehicle_datagram()
    rng = random.Random(3)
    link, got, _ = _link()
    bad_crc = bytearray(good)
    bad_crc[15] ^= 0xFF  # inside the first frame's payload
    link._on_datagram(bytes(bad_crc), ("127.0.0.1", 14580))
    assert link.rejected["bad_data"] >= 1
    assert [m.get_type() for m in got] == ["LOCAL_POSITION_NED", "DEBUG_FLOAT_ARRAY", "STATUSTEXT", "SYSTEM_TIME"]
    got.clear()
    link2, got2, _ = _link()
    link2._on_datagram(b"\x00garbage" + good, ("127.0.0.1", 14580))  # garbage first: pymavlink's parser
    assert "SYSTEM_TIME" in [m.get_type() for m in got2] and sum(link2.rejected.values()) >= 1
    link3, _got3, _ = _link()
    for _ in range(300):  # random damage never raises out of the datagram handler
        b = bytearray(good)
        for _k in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        link3._on_datagram(bytes(b[: rng.randint(0, len(b))]), ("127.0.0.1", 14580))
    assert sum(link3.rejected.values()) > 0 and link3.received > 0


def test_vehicle_state_takes_lite_messages_and_refuses_nonfinite_swing() -> None:
    from companion.estimation.vehicle_state import VehicleState
    from companion.mavlink_io.telemetry import decode

    mav, _ = _pair(sysid=1, compid=1)
    mf.send_heartbeat(mav, M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 128 | 1, 6 << 16, M.MAV_STATE_ACTIVE)
    mf.send_attitude(mav, 2000, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    mf.send_local_position_ned(mav, 2000, 1.0, 2.0, -3.0, 0.1, 0.2, -0.3)
    mf.send_debug_float_array5(mav, 2_000_000, b"SWING", 1, 0.05, -0.05, 0.0, 0.1, 1.0)
    mf.send_debug_float_array5(mav, 2_004_000, b"SWING", 1, math.nan, 0.0, 0.0, 0.0, 1.0)
    st = VehicleState(cable_length_m=1.0)
    for frame in mav.file.frames:
        st.ingest(decode(mf.decode_lite(frame)))
    assert st.vehicle_sysid == 1 and st.armed and st.mode_name == "OFFBOARD"
    est = st.estimate()
    assert est is not None and est.swing_source == "cable_sensor"
    assert list(est.swing) == [_f32(0.05), _f32(-0.05), 0.0, _f32(0.1)]  # the NaN sample was refused
    assert st.rejected["nonfinite"] == 1 and st.swing_sensor_t_s == 2.0
    assert list(est.pos_ned_m) == [1.0, 2.0, -3.0] and est.t_s == 2.0


def test_sim_bridge_hand_packed_highres_imu_is_byte_identical_to_pymavlink() -> None:
    """sim_bridge.telemetry packs HIGHRES_IMU itself (50 Hz on the onboard link): same frames as pymavlink."""
    from sim_bridge.telemetry import CRC_HIGHRES_IMU, HIGHRES_FIELDS, P_HIGHRES_IMU

    rng = random.Random(99)
    ref, fast = _pair()
    for k in range(200):
        z = k == 0
        vals = [0.0 if z else rng.uniform(-50, 50) for _ in range(13)]
        t = 0 if z else rng.randint(0, 2**63)
        fields = 0 if z else HIGHRES_FIELDS
        ref.highres_imu_send(t, *vals, fields, 0)
        mf.send_payload(fast, M.MAVLINK_MSG_ID_HIGHRES_IMU, CRC_HIGHRES_IMU, P_HIGHRES_IMU.pack(t, *vals, fields, 0))
    assert fast.file.frames == ref.file.frames


def test_sim_bridge_streamed_messages_are_byte_identical_to_pymavlink() -> None:
    """sim_bridge.telemetry packs the streamed vehicle messages from one Snapshot per instant (Python floats, each
    message once for all links): the frames equal pymavlink's packing of VehicleSim's own properties, in flight
    with the payload swinging, in wind."""
    import numpy as np

    from companion.core.rotations import quat_from_euler
    from sim_bridge import telemetry as tm
    from sim_bridge.sitl_config import SitlConfig
    from sim_bridge.vehicle import SitlVehicle

    v = SitlVehicle(SitlConfig())
    sim = v.sim
    sim.armed = True
    ref, fast = _pair(sysid=1, compid=1)
    grounded = set()
    for k in range(30):
        sim.set_attitude_target(quat_from_euler(0.1 * math.sin(k), -0.05, 0.3), 1.3 * v.hover_thrust_n,
                                np.array([0.05, -0.02, 0.1]) if k % 3 == 0 else None)
        sim.step(40)
        v.t_us += 40_000
        t_ms = v.t_us // 1000
        snap = tm.Snapshot(v)
        e, w, p, vel = sim.euler_rad, sim.body_rates_frd_rad_s, sim.pos_ned_m, sim.vel_ned_mps
        q = sim.quat_wxyz
        ref.attitude_send(t_ms, *e, *w)
        ref.attitude_quaternion_send(t_ms, *q, *w)
        ref.local_position_ned_send(t_ms, *p, *vel)
        lat, lon, alt = tm.ned_to_geodetic(p, *v.origin)
        ref.global_position_int_send(t_ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0),
                                     round((v.home_local_ned_m[2] - p[2]) * 1000.0),
                                     *(tm._i16(c * 100.0) for c in vel), round(math.degrees(e[2]) * 100.0) % 36000)
        reach = float(np.linalg.norm(sim.payload_pos_ned_m - p)) if sim.payload_on_ground else sim.params.l
        ref.debug_float_array_send(v.t_us, b"SWING", 1, [*sim.swing, reach] + [0.0] * 53)
        ref.system_time_send(0, t_ms)
        for msgid in (tm.MSG_ATTITUDE, tm.MSG_ATTITUDE_QUATERNION, tm.MSG_LOCAL_POSITION_NED,
                      tm.MSG_GLOBAL_POSITION_INT, tm.MSG_DEBUG_FLOAT_ARRAY, tm.MSG_SYSTEM_TIME):
            crc, payload = tm.hot_payload(msgid, v, snap)
            mf.send_payload(fast, msgid, crc, payload)
        grounded.add(sim.payload_on_ground)
    assert grounded == {True, False}  # the payload lifted off during the run
    assert abs(sim.swing[0]) + abs(sim.swing[1]) > 1e-3 and sim.pos_ned_m[2] < -0.5  # flying, swinging
    assert fast.file.frames == ref.file.frames


def test_decode_fields_gives_pymavlink_values_in_wire_order_and_checks_crc() -> None:
    """decode_fields (the bench client's hot path): the unpacked payload tuple, arrays flattened, equals the
    fields pymavlink decodes, in wire order; a damaged frame raises FrameError like decode_frame."""
    rng = random.Random(77)
    _, fast = _pair()
    for _ref_call, fast_call in _cases(rng):
        fast_call(fast)
    checked = 0
    for frame in fast.file.frames:
        ref = M.MAVLink(None).decode(bytearray(frame))
        if any(ref.fieldtypes[k] == "char" for k in range(len(ref.fieldtypes))):
            continue  # text fields stay bytes here
        want: list = []
        for name in ref.ordered_fieldnames:
            val = getattr(ref, name)
            want.extend(val if isinstance(val, list) else [val])
        assert list(mf.decode_fields(frame)) == want
        checked += 1
    assert checked >= 300
    bad = bytearray(fast.file.frames[3])
    bad[12] ^= 0x55
    with pytest.raises(mf.FrameError):
        mf.decode_fields(bytes(bad))


def test_link_hands_checked_frames_to_a_frame_handler_and_bad_ones_to_pymavlink() -> None:
    """With ``frame_handler`` set, the fast path passes each CRC-valid frame as bytes (the runner decodes it to a typed
    event, the same event pymavlink's message gives); a frame with a broken CRC is not handed over but goes the slow
    way, where pymavlink refuses it and it is counted."""
    from companion.mavlink_io.telemetry import decode, decode_frame

    data = _vehicle_datagram()
    link, got, _ = _link()
    frames: list[bytes] = []
    link.frame_handler = frames.append
    link._on_datagram(data, ("127.0.0.1", 14580))
    assert got == [] and b"".join(frames) == data and len(frames) == 5
    ref = list(M.MAVLink(None).parse_buffer(data))
    assert [decode_frame(f) for f in frames] == [decode(m) for m in ref]
    bad = bytearray(frames[0])
    bad[-1] ^= 0xFF
    link._on_datagram(bytes(bad), ("127.0.0.1", 14580))
    assert len(frames) == 5 and got == [] and sum(link.rejected.values()) == 1
    link.close()
