"""Pure parts of the SITL vehicle: PX4 mode codes, rates, geodesy, setpoint checks, framing, hold controller,
and the real-time clock's offboard-loss rule over UDP."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from companion.core.rotations import euler_from_quat
from sim_bridge.commands import parse_attitude_target
from sim_bridge.link import MavUdpLink, RejectCounters
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle
from sim_bridge.position_hold import PositionHoldGains, position_hold_target
from sim_bridge.stream_rates import RateScheduler
from sim_bridge.telemetry import ned_to_geodetic

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

M = mavlink2


def test_px4_custom_mode_encoding():
    assert px4_modes.OFFBOARD.custom_mode == 6 << 16
    assert px4_modes.AUTO_LAND.custom_mode == (4 << 16) | (6 << 24)
    assert px4_modes.Px4Mode.from_custom_mode((4 << 16) | (3 << 24)) == px4_modes.AUTO_LOITER
    assert px4_modes.Px4Mode.from_custom_mode(3 << 16).name == "POSCTL"


def test_rate_scheduler_intervals_and_set_message_interval_semantics():
    s = RateScheduler({30: 10_000, 0: 1_000_000})
    sent = [t for t in range(0, 100_000, 4000) if 30 in s.due(t)]
    assert sent[:4] == [0, 12_000, 20_000, 32_000]  # 100 Hz on a 4 ms grid, no drift
    assert len(sent) == 10
    s.set_interval(30, 4000, 100_000)
    assert all(30 in s.due(t) for t in range(100_000, 120_000, 4000))
    s.set_interval(30, -1, 120_000)
    assert not any(30 in s.due(t) for t in range(120_000, 200_000, 4000))
    s.set_interval(30, 0, 200_000)
    assert s.intervals_us[30] == 10_000
    assert not s.set_interval(99999, 1000, 0)


def test_ned_to_geodetic_offsets():
    # WGS-84 degree lengths at 47° latitude (geodesy tables): 111 170 m of latitude, 76 056 m of longitude
    lat, lon, alt = ned_to_geodetic(np.array([1000.0, 0.0, -10.0]), 47.0, 8.0, 0.0)
    assert lat - 47.0 == pytest.approx(1000.0 / 111_170.0, rel=1e-4)
    assert lon == 8.0 and alt == 10.0
    _, lon, _ = ned_to_geodetic(np.array([0.0, 1000.0, 0.0]), 47.0, 8.0, 0.0)
    assert lon - 8.0 == pytest.approx(1000.0 / 76_056.0, rel=1e-4)


def _sat(mask=7, q=(1.0, 0.0, 0.0, 0.0), thrust=0.5, rates=(0.0, 0.0, 0.0)):
    return M.MAVLink_set_attitude_target_message(0, 1, 1, mask, list(q), *rates, thrust)


def test_parse_attitude_target_checks_only_used_fields():
    assert parse_attitude_target(_sat())[0] is None
    assert parse_attitude_target(_sat(q=(1.0005, 0, 0, 0)))[0] is None
    assert parse_attitude_target(_sat(q=(1.002, 0, 0, 0)))[0] == "bad_quaternion"
    assert parse_attitude_target(_sat(thrust=1.0001))[0] == "thrust_range"
    assert parse_attitude_target(_sat(thrust=math.nan))[0] == "nonfinite"
    assert parse_attitude_target(_sat(mask=7 | 64, thrust=math.nan))[0] is None  # ignored thrust may be NaN
    kind, q, rates, thrust = parse_attitude_target(_sat(mask=128, q=(math.nan,) * 4, rates=(0.1, 0.2, 0.3)))
    assert kind is None and q is None and rates.tolist() == pytest.approx([0.1, 0.2, 0.3]) and thrust == 0.5
    assert parse_attitude_target(_sat(mask=0, rates=(math.inf, 0, 0)))[0] == "nonfinite"


def _frames(data: bytes):
    counters = RejectCounters()
    link = MavUdpLink("test", ("127.0.0.1", 9), 1, 1, counters, lambda lk, m: None)
    msgs = link._frames(data)
    return [m.get_type() for m, _ in msgs], {k: v for k, v in counters.counts.items() if v}


def test_framing_counts_each_kind_and_keeps_good_frames():
    enc = M.MAVLink(None, 255, 190)
    hb = bytes(enc.heartbeat_encode(6, 8, 0, 0, 4).pack(enc))
    assert _frames(hb + hb) == (["HEARTBEAT", "HEARTBEAT"], {})
    assert _frames(b"xx" + hb) == (["HEARTBEAT"], {"garbage": 1})
    bad = bytearray(hb)
    bad[-1] ^= 0xFF
    assert _frames(bytes(bad) + hb) == (["HEARTBEAT"], {"bad_crc": 1})
    assert _frames(hb + hb[:-3]) == (["HEARTBEAT"], {"truncated": 1})
    v1 = bytes(enc.heartbeat_encode(6, 8, 0, 0, 4).pack(enc, force_mavlink1=True))
    assert _frames(v1 + hb) == (["HEARTBEAT"], {"mavlink1": 1})
    unknown = bytes([0xFD, 1, 0, 0, 0, 1, 1, 0x39, 0x30, 0, 7, 0, 0])
    assert _frames(unknown) == ([], {"unknown_id": 1})


def test_position_hold_tilts_towards_target_and_hovers_at_it():
    g = PositionHoldGains()
    q, t = position_hold_target(np.zeros(3), np.zeros(3), np.zeros(3), 0.3, 1.5, 9.81, g)
    assert t == pytest.approx(1.5 * 9.81)
    assert euler_from_quat(q) == pytest.approx([0.0, 0.0, 0.3], abs=1e-12)
    q, t = position_hold_target(np.zeros(3), np.zeros(3), np.array([10.0, 0.0, 0.0]), 0.0, 1.5, 9.81, g)
    phi, theta, _ = euler_from_quat(q)
    assert theta < -0.1 and abs(phi) < 1e-9 and abs(theta) <= g.tilt_max_rad + 1e-9  # nose down to go north
    _, t_up = position_hold_target(np.zeros(3), np.zeros(3), np.array([0.0, 0.0, -2.0]), 0.0, 1.5, 9.81, g)
    assert t_up > 1.5 * 9.81


def test_realtime_mode_offboard_loss_switches_to_hold():
    """Real-time clock (no lockstep): stream setpoints, enter OFFBOARD, stop; the vehicle holds in POSCTL."""
    proc, port, _ = spawn_vehicle("--wind", "none", "--offboard-timeout", "0.3")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_for("HEARTBEAT", timeout_s=5.0)
            end = time.monotonic() + 0.6
            while time.monotonic() < end:
                c.send_attitude_target(thrust=0.0)
                c.poll(0.02)
            assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED
            hb = c.wait_for("HEARTBEAT", lambda m: m.custom_mode == 3 << 16, timeout_s=5.0)
            assert hb.custom_mode == px4_modes.POSCTL.custom_mode
            assert any("lost" in t for t in c.statustexts)
            t1 = c.wait_for("ATTITUDE", timeout_s=2.0).time_boot_ms
            time.sleep(0.3)
            t2 = c.wait_for("ATTITUDE", timeout_s=2.0).time_boot_ms
            assert t2 > t1  # simulated time runs by itself
    finally:
        assert stop_vehicle(proc) == 0


def test_attitude_angles_are_sent_in_mavlinks_range_even_when_the_model_has_spun():
    """The model's Euler angles are unwrapped: a vehicle spun by a runaway loop had yaw 61.9 rad, which the
    companion rightly refused (``attitude_range``), so it lost the attitude and could not hand over. ATTITUDE
    carries roll and yaw in ±π, the same orientation."""
    import math

    from pymavlink.dialects.v20 import common as M

    from sim_bridge import telemetry as tm
    from sim_bridge.sitl_config import SitlConfig
    from sim_bridge.vehicle import SitlVehicle

    v = SitlVehicle(SitlConfig())
    v.sim.x[3], v.sim.x[4], v.sim.x[5] = 3.5, 0.2, 61.85
    _crc, payload = tm.hot_payload(tm.MSG_ATTITUDE, v)
    msg = M.MAVLink_attitude_message(*M.MAVLink_attitude_message.unpacker.unpack(payload))
    assert math.isclose(msg.roll, 3.5 - 2 * math.pi, abs_tol=1e-6)
    assert math.isclose(msg.yaw, 61.85 - 20 * math.pi, abs_tol=1e-5) and abs(msg.yaw) <= math.pi
    assert math.isclose(msg.pitch, 0.2, abs_tol=1e-6)
