"""companion.mavlink_io.telemetry: every message the companion reads decodes to the same typed event by all three
paths (the codec's LiteMessage, pymavlink's own message object, the frame's bytes), in SI units; non-finite values
become Rejected events that the vehicle state counts; messages nobody reads decode to None. Real frames, packed by
pymavlink."""

from __future__ import annotations

import dataclasses
import math
import random

import pytest
from pymavlink.dialects.v20 import common as M

from companion.estimation.vehicle_state import VehicleState
from companion.mavlink_io import codec
from companion.mavlink_io import telemetry as tm
from companion.mavlink_io.commands import RequestLink


class _Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.frames.append(bytes(buf))


def _frame(msg, sysid: int = 1, compid: int = 1, seq: int = 0) -> bytes:
    mav = M.MAVLink(_Sink(), srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    return bytes(msg.pack(mav))


def _all_paths(frame: bytes):
    """The event by each decoding path; they must agree."""
    lite = tm.decode(codec.decode_lite(frame))
    full = tm.decode(M.MAVLink(None).parse_char(frame))
    raw = tm.decode_frame(frame)
    assert repr(lite) == repr(full) == repr(raw), (lite, full, raw)  # repr: NaN equals NaN
    return lite


def _f32(x: float) -> float:
    return M.struct.unpack("<f", M.struct.pack("<f", x))[0]


def _messages(rng: random.Random):
    """(pymavlink message, expected event fields) of every message read here, with random values."""
    f = lambda: _f32(rng.uniform(-3.0, 3.0))  # noqa: E731
    ms, us = rng.randint(0, 2**32 - 1), rng.randint(0, 2**63)
    a = [f() for _ in range(7)]
    yield (M.MAVLink_heartbeat_message(2, 12, 129, 6 << 16, 4, 3),
           tm.Heartbeat, dict(mav_type=2, autopilot=12, base_mode=129, custom_mode=6 << 16, system_status=4))
    yield (M.MAVLink_sys_status_message(7, 5, 0x10000003, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
           tm.SysStatus, dict(sensors_present=7, sensors_health=0x10000003, sensors_enabled=5))
    yield (M.MAVLink_attitude_message(ms, *a[:6]), tm.Attitude,
           dict(t_boot_s=ms * 1e-3, euler_rad=tuple(a[:3]), rates_frd_rad_s=tuple(a[3:6])))
    yield (M.MAVLink_local_position_ned_message(ms, *a[:6]), tm.LocalPositionNed,
           dict(t_boot_s=ms * 1e-3, pos_ned_m=tuple(a[:3]), vel_ned_mps=tuple(a[3:6])))
    lat, lon, alt = rng.randint(-900_000_000, 900_000_000), rng.randint(-1_800_000_000, 1_800_000_000), 488123
    yield (M.MAVLink_global_position_int_message(ms, lat, lon, alt, 3000, -250, 31, 7, 9000), tm.GlobalPositionInt,
           dict(t_boot_s=ms * 1e-3, lat_deg=lat * 1e-7, lon_deg=lon * 1e-7, alt_amsl_m=488.123,
                vel_ned_mps=(-2.5, 0.31, 0.07)))
    yield (M.MAVLink_home_position_message(lat, lon, alt, a[0], a[1], a[2], [1, 0, 0, 0], 0, 0, 0, us),
           tm.HomePosition, dict(pos_ned_m=tuple(a[:3]), lat_deg=lat * 1e-7, lon_deg=lon * 1e-7, alt_amsl_m=488.123))
    yield (M.MAVLink_gps_global_origin_message(lat, lon, alt, us), tm.GpsGlobalOrigin,
           dict(lat_deg=lat * 1e-7, lon_deg=lon * 1e-7, alt_amsl_m=488.123))
    n = rng.randint(0, 65535)
    yield M.MAVLink_mission_count_message(1, 191, n, 1), tm.MissionCount, dict(count=n, mission_type=1)
    yield M.MAVLink_mission_ack_message(1, 191, 13, 1), tm.MissionAck, dict(result=13, mission_type=1)
    yield (M.MAVLink_mission_item_int_message(1, 191, n, 6, 16, 1, 1, a[0], a[1], a[2], math.nan, lat, lon, a[3], 0),
           tm.MissionItemInt, dict(item_seq=n, frame=6, command=16, current=1, autocontinue=1, x=lat, y=lon, z=a[3],
                                   mission_type=0))
    yield M.MAVLink_extended_sys_state_message(0, 2), tm.ExtendedSysState, dict(landed_state=2)
    yield M.MAVLink_system_time_message(us, ms), tm.SystemTime, dict(t_boot_ms=ms)
    yield (M.MAVLink_highres_imu_message(us, a[0], a[1], a[2], *a[3:6], 0, 0, 0, 1013.0, 0, 0, 25.0, 0x1FFF, 0),
           tm.HighresImu, dict(t_s=us * 1e-6, accel_frd_mps2=tuple(a[:3])))
    yield (M.MAVLink_scaled_imu_message(ms, 12, -34, -1000, 0, 0, 0, 0, 0, 0, 0), tm.ScaledImu,
           dict(t_boot_s=ms * 1e-3, accel_frd_mps2=(12 * 9.80665e-3, -34 * 9.80665e-3, -1000 * 9.80665e-3)))
    yield (M.MAVLink_estimator_status_message(us, 0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.25, 0.5), tm.EstimatorStatus,
           dict(pos_horiz_accuracy_m=0.25))
    yield (M.MAVLink_statustext_message(4, b"Takeoff detected", 0, 0), tm.StatusText,
           dict(severity=4, text="Takeoff detected", id=0, chunk_seq=0))
    yield (M.MAVLink_statustext_message(2, b"Arming denied: Resolve system health failures firs", 7, 0),
           tm.StatusText, dict(severity=2, text="Arming denied: Resolve system health failures firs", id=7,
                               chunk_seq=0))
    yield M.MAVLink_command_ack_message(400, 0, 0, 0, 0, 0), tm.CommandAck, dict(command=400, result=0)
    yield (M.MAVLink_command_long_message(1, 191, 193, 0, 0.0, 1.5, 2.0, 3.0, 4.0, 5.0, -6.0), tm.CommandLong,
           dict(command=193, target_system=1, target_component=191, params=(0.0, 1.5, 2.0, 3.0, 4.0, 5.0, -6.0)))
    yield (M.MAVLink_command_int_message(1, 191, 6, 193, 0, 0, 1.0, 0.0, 0.0, 0.0, lat, lon, 12.5), tm.CommandInt,
           dict(command=193, target_system=1, target_component=191, frame=6,
                params=(1.0, 0.0, 0.0, 0.0, float(lat), float(lon), 12.5)))
    yield (M.MAVLink_param_value_message(b"MPC_THR_HOVER", 0.5, 9, 100, 3), tm.ParamValue,
           dict(param_id="MPC_THR_HOVER", value=0.5))
    yield (M.MAVLink_debug_float_array_message(us, b"SWING", 1, a[:4] + [1.0] + [0.0] * 53), tm.SwingSensor,
           dict(t_s=us * 1e-6, swing=tuple(a[:4]), reach_m=1.0))
    yield (M.MAVLink_autopilot_version_message(
        capabilities=0xE4EF, flight_sw_version=0x01_0F_02_FF, middleware_sw_version=0, os_sw_version=0,
        board_version=0, flight_custom_version=[0xAB, 0xCD, 1, 2, 3, 4, 5, 6], middleware_custom_version=[0] * 8,
        os_custom_version=[0] * 8, vendor_id=0x26AC, product_id=0x11, uid=7, uid2=[0] * 18),
           tm.AutopilotVersion, dict(capabilities=0xE4EF, flight_sw_version=0x01_0F_02_FF, vendor_id=0x26AC,
                                     product_id=0x11, flight_custom_version=bytes([0xAB, 0xCD, 1, 2, 3, 4, 5, 6])))
    dist = [rng.randint(0, 1201) for _ in range(70)] + [65535, 65535]
    yield (M.MAVLink_obstacle_distance_message(us, 0, dist, 0, 10, 1200, 1.0, 144.0, 12), tm.ObstacleDistance,
           dict(time_usec=us, distances_cm=tuple(dist), min_distance_cm=10, max_distance_cm=1200, increment_deg=1.0,
                angle_offset_deg=144.0, frame=12))
    yield (M.MAVLink_obstacle_distance_message(us, 0, dist, 5, 20, 4000, 0.0, 0.0, 0), tm.ObstacleDistance,
           dict(increment_deg=5, frame=0))  # PX4's 72 sectors of 5 deg, integer increment, north-aligned


def test_every_message_decodes_alike_by_each_path_in_si_units():
    rng = random.Random(25)
    seen = set()
    for k in range(30):
        for msg, cls, expected in _messages(rng):
            ev = _all_paths(_frame(msg, sysid=3, compid=7, seq=k))
            assert type(ev) is cls and (ev.src_system, ev.src_component, ev.seq) == (3, 7, k)
            for name, value in expected.items():
                assert getattr(ev, name) == value, (cls.__name__, name, getattr(ev, name), value)
            assert ev.message == msg.get_type()
            seen.add(msg.get_msgId())
    assert seen == tm.DECODED_IDS  # every message read here is checked


def test_trimmed_payloads_decode_with_their_zeros():
    """MAVLink 2 drops a payload's trailing zeros on the wire: an attitude at rest and a swing sample with data[1:]
    all zero are frames shorter than the fields read; the zeros come back."""
    att = _frame(M.MAVLink_attitude_message(1000, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert att[1] < 28
    ev = _all_paths(att)
    assert ev.euler_rad == (_f32(0.1), 0.0, 0.0) and ev.rates_frd_rad_s == (0.0, 0.0, 0.0)
    sw = _frame(M.MAVLink_debug_float_array_message(2_000_000, b"SWING", 1, [0.25] + [0.0] * 57))
    ev = _all_paths(sw)
    assert ev.swing == (0.25, 0.0, 0.0, 0.0) and ev.reach_m == 0.0


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nonfinite_fields_are_rejected_while_decoding(bad):
    cases = []
    for i in range(6):
        v = [0.1] * 6
        v[i] = bad
        cases.append(M.MAVLink_attitude_message(1000, *v))
        cases.append(M.MAVLink_local_position_ned_message(1000, *v))
    for i in range(3):
        v = [1.0, 2.0, 3.0]
        v[i] = bad
        cases.append(M.MAVLink_home_position_message(0, 0, 0, *v, [1, 0, 0, 0], 0, 0, 0, 0))
        cases.append(M.MAVLink_highres_imu_message(1, *v, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    for i in range(4):
        d = [0.1, 0.2, 0.3, 0.4, 1.0] + [0.0] * 53
        d[i] = bad
        cases.append(M.MAVLink_debug_float_array_message(1, b"SWING", 1, d))
    cases.append(M.MAVLink_estimator_status_message(1, 0, 0, 0, 0, 0, 0, 0, bad, 0))
    cases.append(M.MAVLink_param_value_message(b"X", bad, 9, 1, 0))
    for msg in cases:
        ev = _all_paths(_frame(msg, sysid=1, seq=9))
        assert ev == tm.Rejected(1, 1, 9, msg.get_type(), "nonfinite"), (msg, ev)
    # an unknown reach (data[4]) is not a reason to refuse the angles: the state decides what it means
    ok = _all_paths(_frame(M.MAVLink_debug_float_array_message(1, b"SWING", 1, [0.1] * 4 + [bad] + [0.0] * 53)))
    assert type(ok) is tm.SwingSensor and not math.isfinite(ok.reach_m)


def test_messages_nobody_reads_decode_to_none():
    assert _all_paths(_frame(M.MAVLink_attitude_quaternion_message(1, 1, 0, 0, 0, 0, 0, 0, [0, 0, 0, 0]))) is None
    assert _all_paths(_frame(M.MAVLink_vfr_hud_message(1.0, 1.0, 90, 50, -1.0, 0.0))) is None
    other = M.MAVLink_debug_float_array_message(1, b"SWINGX", 1, [0.1] * 58)  # another array, not the sensor
    assert _all_paths(_frame(other)) is None


def test_text_is_read_as_pymavlink_shows_it():
    """Up to the first NUL, ASCII with undecodable bytes replaced (the codec's and pymavlink's reading)."""
    ev = _all_paths(_frame(M.MAVLink_statustext_message(6, b"caf\xe9 ok\x00junk", 0, 0)))
    assert ev.text == "caf\ufffd ok"


def test_events_are_frozen_slotted_and_built_as_their_constructor_builds_them():
    ev = _all_paths(_frame(M.MAVLink_attitude_message(1000, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6), seq=5))
    assert ev == tm.Attitude(1, 1, 5, ev.t_boot_s, ev.euler_rad, ev.rates_frd_rad_s)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ev.t_boot_s = 0.0
    assert not hasattr(ev, "__dict__")


def _state_with_vehicle() -> VehicleState:
    st = VehicleState(cable_length_m=1.0, payload_sysid=2, max_time_rate=1e4)
    st.ingest(_all_paths(_frame(M.MAVLink_heartbeat_message(2, 12, 129, 0, 4, 3))), 0.0)
    return st


def test_the_vehicle_state_counts_rejected_events_from_the_vehicle_and_its_payload_only():
    st = _state_with_vehicle()
    assert st.ingest(_all_paths(_frame(M.MAVLink_attitude_message(1000, 0.1, 0.2, 0.3, 0, 0, 0))), 0.0) == "ATTITUDE"
    nan_att = M.MAVLink_attitude_message(1004, math.nan, 0.2, 0.3, 0, 0, 0)
    assert st.ingest(_all_paths(_frame(nan_att)), 0.0) == "REJECTED"
    assert st.rejected == {"nonfinite": 1} and st.att_t_s == 1.0 and st.euler_rad[0] == _f32(0.1)
    assert st.ingest(_all_paths(_frame(nan_att, sysid=9)), 0.0) == "ATTITUDE"  # a stranger's: ignored
    assert st.ingest(_all_paths(_frame(nan_att, sysid=2)), 0.0) == "ATTITUDE"  # the payload's attitude: not read
    nan_pos = M.MAVLink_local_position_ned_message(1004, 0.0, math.inf, -1.0, 0, 0, 0)
    assert st.ingest(_all_paths(_frame(nan_pos, sysid=2)), 0.0) == "REJECTED"  # the payload's position is
    assert st.rejected == {"nonfinite": 2} and st.payload_pos_ned_m is None
    assert st.counts["ATTITUDE"] == 4 and st.counts["LOCAL_POSITION_NED"] == 1
    version = M.MAVLink_autopilot_version_message(
        capabilities=0xE4EF, flight_sw_version=0x010F02FF, middleware_sw_version=0, os_sw_version=0, board_version=0,
        flight_custom_version=[0xAB, 0xCD, 1, 2, 3, 4, 5, 6], middleware_custom_version=[0] * 8,
        os_custom_version=[0] * 8, vendor_id=0x26AC, product_id=0x11, uid=7, uid2=[0] * 18)
    st.ingest(_all_paths(_frame(version)), 0.0)
    assert st.autopilot_version == {"flight_sw_version": "1.15.2", "release_type": 255, "vendor_id": 0x26AC,
                                    "product_id": 0x11, "capabilities": 0xE4EF,
                                    "flight_custom_version": "abcd010203040506"}


def test_request_answers_come_from_typed_events():
    st = _state_with_vehicle()
    mav = M.MAVLink(_Sink(), srcSystem=1, srcComponent=191)
    req = RequestLink(mav, lambda: (st.vehicle_sysid, st.vehicle_compid), lambda what: [1.0, 6.0, 0.0])
    from companion.flight.requests import Request

    req.send(Request("arm", 0.0, 1))
    ack = _all_paths(_frame(M.MAVLink_command_ack_message(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0)))
    assert req.answer_of(ack) == ("arm", 0)
    stranger = _all_paths(_frame(M.MAVLink_command_ack_message(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0), 5))
    assert req.answer_of(stranger) is None
    pv = _all_paths(_frame(M.MAVLink_param_value_message(b"MPC_THR_HOVER", 0.42, 9, 100, 3)))
    assert req.answer_of(pv) == ("param:MPC_THR_HOVER", _f32(0.42))
    nan_pv = _all_paths(_frame(M.MAVLink_param_value_message(b"MPC_THR_HOVER", math.nan, 9, 100, 3)))
    assert type(nan_pv) is tm.Rejected and req.answer_of(nan_pv) is None
