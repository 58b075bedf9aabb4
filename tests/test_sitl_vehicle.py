"""The bundled SITL vehicle over real UDP, in its own process, driven with pymavlink framing (lockstep)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)
M = mavlink2
TICK = 1 | 2 | 4 | 64 | 128  # SET_ATTITUDE_TARGET ignoring everything: advances lockstep time only
POSCTL_MODE = 3 << 16
OFFBOARD_MODE = 6 << 16
LOITER_MODE = (4 << 16) | (3 << 24)


@pytest.fixture
def vehicle():
    """A lockstep vehicle (no wind unless a test asks) and a connected client that saw the first marker."""
    procs = []

    def start(*args: str, wind: str = "none") -> MavClient:
        proc, port, _ = spawn_vehicle("--lockstep", "--wind", wind, *args)
        procs.append(proc)
        c = MavClient(port, target_sysid=_sysid(args))
        c.heartbeat()
        c.wait_marker(10.0)
        clients.append(c)
        return c

    clients: list[MavClient] = []
    yield start
    for c in clients:
        c.close()
    for p in procs:
        assert stop_vehicle(p) == 0  # SIGTERM → clean exit 0


def _sysid(args) -> int:
    args = list(args)
    if "--sysid" in args:
        return int(args[args.index("--sysid") + 1])
    return 1 + (int(args[args.index("--instance") + 1]) if "--instance" in args else 0)


def _offboard_hover(c: MavClient) -> None:
    for _ in range(5):
        c.step(thrust=0.0)
    assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED
    assert c.arm() == M.MAV_RESULT_ACCEPTED


def test_heartbeat_type_autopilot_and_mode(vehicle):
    c = vehicle()
    hb = c.wait_for("HEARTBEAT")
    assert hb.type == M.MAV_TYPE_QUADROTOR
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert hb.custom_mode == LOITER_MODE
    assert hb.get_srcComponent() == M.MAV_COMP_ID_AUTOPILOT1
    # the payload announces itself as ArduPilot's SITL slung payload does: system 2, component 35 (USER11),
    # HEARTBEAT type AIRSHIP / autopilot INVALID (not an autopilot), GLOBAL_POSITION_INT and ATTITUDE at 10 Hz
    phb = c.wait_for("HEARTBEAT", sysid=2)
    assert (phb.autopilot, phb.type, phb.base_mode, phb.system_status) == (M.MAV_AUTOPILOT_INVALID,
                                                                            M.MAV_TYPE_AIRSHIP, 0, 0)
    assert phb.get_srcComponent() == M.MAV_COMP_ID_USER11 == 35
    seen: dict[str, list[int]] = {}
    c.on_message = lambda m: seen.setdefault(m.get_type(), []).append(m.time_boot_ms) if (
        m.get_srcSystem() == 2 and m.get_type() in ("GLOBAL_POSITION_INT", "ATTITUDE")) else None
    t0 = c.sim_time_ms
    for _ in range(250):  # 1 s
        c.step(type_mask=TICK)
    for kind in ("GLOBAL_POSITION_INT", "ATTITUDE"):
        assert len([t for t in seen[kind] if t0 <= t < t0 + 1000]) == 10, kind
    gp = c.wait_for("GLOBAL_POSITION_INT", sysid=2, timeout_s=2.0)
    assert gp.relative_alt == 0  # it rests on the ground before take-off (no longer 1 m below it)


def test_arm_disarm_acked_and_forced_disarm(vehicle):
    c = vehicle()
    assert c.arm() == M.MAV_RESULT_ACCEPTED
    c.step(type_mask=TICK)
    assert c.wait_for("HEARTBEAT", timeout_s=2.0, cond=lambda m: True) is not None
    assert c.arm(False) == M.MAV_RESULT_ACCEPTED
    assert c.arm() == M.MAV_RESULT_ACCEPTED
    assert c.arm(False, force=True) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 1, 0) == M.MAV_RESULT_DENIED  # MANUAL: no RC here
    assert "not supported" in c.statustexts[-1]
    assert c.command(M.MAV_CMD_DO_FENCE_ENABLE, 1) == M.MAV_RESULT_UNSUPPORTED


def test_offboard_refused_without_stream_accepted_with_one_and_rolls_15deg(vehicle):
    c = vehicle()
    assert c.set_mode(6) == M.MAV_RESULT_DENIED
    assert "no setpoint stream" in c.statustexts[-1]
    _offboard_hover(c)
    for _ in range(250):  # climb a bit first
        c.step(thrust=0.45)
    r = math.radians(15.0)
    q = (math.cos(r / 2), math.sin(r / 2), 0.0, 0.0)
    t0 = c.sim_time_ms
    reached = None
    while c.sim_time_ms - t0 < 1000:
        c.step(q=q, thrust=0.42)
        if abs(math.degrees(c.last["ATTITUDE"].roll) - 15.0) < 1.0 and reached is None:
            reached = c.sim_time_ms - t0
    assert reached is not None and reached <= 1000
    assert abs(math.degrees(c.last["ATTITUDE"].roll) - 15.0) < 1.0
    assert c.last["ATTITUDE_TARGET"].thrust == pytest.approx(0.42, abs=1e-6)
    assert c.last["HEARTBEAT"].custom_mode == OFFBOARD_MODE


def test_offboard_entry_on_one_fresh_setpoint_as_px4(vehicle):
    """PX4 (offboardCheck.cpp) needs one setpoint younger than COM_OF_LOSS_T (default 1.0 s), not a rate."""
    c = vehicle()
    c.mav.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "COM_OF_LOSS_T").param_value == pytest.approx(1.0)
    c.step(thrust=0.0)  # exactly one setpoint
    assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HEARTBEAT) == M.MAV_RESULT_ACCEPTED
    assert c.wait_for("HEARTBEAT").custom_mode == OFFBOARD_MODE
    c2 = vehicle()  # a setpoint older than COM_OF_LOSS_T is not enough
    c2.step(thrust=0.0)
    for _ in range(260):  # 1.04 s without setpoints
        c2.step(type_mask=TICK)
    assert c2.set_mode(6) == M.MAV_RESULT_DENIED


def test_setpoint_loss_switches_to_hold_within_timeout(vehicle):
    c = vehicle("--offboard-timeout", "0.5")
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 4000) == M.MAV_RESULT_ACCEPTED
    _offboard_hover(c)
    for _ in range(100):
        c.step(thrust=0.45)
    last_sp_ms = c.sim_time_ms
    switched = None
    while c.sim_time_ms - last_sp_ms < 1000:
        c.step(type_mask=TICK)  # time goes on, setpoints do not
        if switched is None and c.last["HEARTBEAT"].custom_mode == POSCTL_MODE:
            switched = c.sim_time_ms - last_sp_ms
    assert switched is not None
    assert 500 <= switched <= 500 + 8  # within the timeout (+ the step that notices it)
    assert c.last["HEARTBEAT"].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED


def test_offboard_loss_holds_then_lands_and_disarms(vehicle):
    """Issue 9: never hover forever. COM_OF_LOSS_T 1 s → POSCTL hold; COM_FAIL_ACT_T later → AUTO.LAND."""
    c = vehicle("--offboard-loss-hold", "2.0")
    assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 4000) == M.MAV_RESULT_ACCEPTED
    _offboard_hover(c)
    z = vz = 0.0
    for _ in range(750):  # 3 s: climb towards 2 m
        c.step(thrust=min(0.9, max(0.05, 0.4 + 0.12 * (z + 2.0) + 0.12 * vz)))
        z, vz = c.last["LOCAL_POSITION_NED"].z, c.last["LOCAL_POSITION_NED"].vz
    t_last = c.sim_time_ms
    modes: dict[int, int] = {}
    while c.sim_time_ms - t_last < 12_000:
        c.step(type_mask=TICK)  # the companion is gone: time goes on, no setpoints
        modes.setdefault(c.last["HEARTBEAT"].custom_mode, c.sim_time_ms - t_last)
        if not c.last["HEARTBEAT"].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            break
    assert 1000 <= modes[POSCTL_MODE] <= 1008
    assert 3000 <= modes[(4 << 16) | (6 << 24)] <= 3008  # AUTO.LAND after the 2 s hold
    assert not c.last["HEARTBEAT"].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED  # landed and disarmed
    assert c.last["LOCAL_POSITION_NED"].z == pytest.approx(0.0, abs=1e-6)
    assert any("landing" in t for t in c.statustexts)


def test_param_set_then_read_round_trip(vehicle):
    c = vehicle()
    c.mav.param_set_send(1, 1, b"COM_OF_LOSS_T", 0.8, M.MAV_PARAM_TYPE_REAL32)
    assert c.wait_for("PARAM_VALUE").param_value == pytest.approx(0.8)
    c.mav.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    pv = c.wait_for("PARAM_VALUE", lambda m: m.param_id == "COM_OF_LOSS_T")
    assert pv.param_value == pytest.approx(0.8)
    # out of range: refused, value unchanged, said so
    c.mav.param_set_send(1, 1, b"MPC_THR_HOVER", 2.0, M.MAV_PARAM_TYPE_REAL32)
    assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MPC_THR_HOVER").param_value == pytest.approx(0.4)
    assert "outside" in c.statustexts[-1]
    # physical constants take effect at the next start (reboot)
    c.mav.param_set_send(1, 1, b"SIM_CABLE_LEN", 1.5, M.MAV_PARAM_TYPE_REAL32)
    c.wait_for("PARAM_VALUE", lambda m: m.param_id == "SIM_CABLE_LEN")
    assert "next start" in c.statustexts[-1]
    assert c.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == M.MAV_RESULT_ACCEPTED
    c.step(type_mask=TICK)
    # the new cable shows once it is taut: climb until the airframe lifts the payload off the ground
    _offboard_hover(c)
    for _ in range(2000):
        c.step(thrust=0.6)
        if abs(c.last["DEBUG_FLOAT_ARRAY"].data[4] - 1.5) < 1e-3:  # a 1 m cable would never get here
            break
    assert c.last["DEBUG_FLOAT_ARRAY"].data[4] == pytest.approx(1.5)
    c.arm(False, force=True)
    # the whole list, with the read-only counters of rejected input
    c.mav.param_request_list_send(1, 1)
    first = c.wait_for("PARAM_VALUE")
    names = {first.param_id}
    while len(names) < first.param_count:
        names.add(c.wait_for("PARAM_VALUE").param_id)
    assert {"MPC_THR_HOVER", "SIM_WIND_MODEL", "SMC_K_R", "RJ_BAD_CRC"} <= names


def test_airmode_flag_and_param_over_mavlink(vehicle):
    """``sitl --airmode 0`` starts the mixer as a stock PX4's; MC_AIRMODE reads back over MAVLink, can be set live,
    and 3 is refused with the value kept."""
    c = vehicle("--airmode", "0")
    c.mav.param_request_read_send(1, 1, b"MC_AIRMODE", -1)
    pv = c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MC_AIRMODE")
    assert pv.param_value == 0.0 and pv.param_type == M.MAV_PARAM_TYPE_INT32
    c.mav.param_set_send(1, 1, b"MC_AIRMODE", 1, M.MAV_PARAM_TYPE_INT32)
    assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MC_AIRMODE").param_value == 1.0
    c.mav.param_set_send(1, 1, b"MC_AIRMODE", 3, M.MAV_PARAM_TYPE_INT32)
    assert c.wait_for("PARAM_VALUE", lambda m: m.param_id == "MC_AIRMODE").param_value == 1.0
    assert "outside" in c.statustexts[-1]


def test_live_changes_that_put_eq49_beyond_the_mixer_are_refused(vehicle):
    """What the start refuses is refused live too, with the value kept and the reason in a STATUSTEXT: eq. 49 at 1.2
    flies at MC_AIRMODE 2 (up to 1.34) but not at 0 (up to 1.02); 2.0 not at all; with the wind off, anything."""
    c = vehicle("--wind", "paper", "--wind-scale", "1.2")

    said: list[str] = []

    def set_param(name: str, value: float) -> float:
        n = len(c.statustexts)
        c.mav.param_set_send(1, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32)
        v = c.wait_for("PARAM_VALUE", lambda m: m.param_id == name).param_value
        said.append("".join(c.statustexts[n:]))  # a long reason comes in 50-character chunks
        return v

    assert set_param("MC_AIRMODE", 0) == 2.0
    assert "MC_AIRMODE 0 refused" in said[-1] and "1.02" in said[-1], said[-1]
    assert set_param("SIM_WIND_SCALE", 2.0) == pytest.approx(1.2)
    assert "SIM_WIND_SCALE 2 refused" in said[-1], said[-1]
    assert set_param("SIM_WIND_SCALE", 1.0) == pytest.approx(1.0)  # within both limits
    assert set_param("MC_AIRMODE", 0) == 0.0
    assert set_param("SIM_WIND_SCALE", 1.2) == pytest.approx(1.0)  # now the scale is what would not fit
    assert set_param("SIM_WIND_MODEL", 0) == 0.0
    assert set_param("SIM_WIND_SCALE", 5.0) == pytest.approx(5.0)  # no eq. 49 flies: nothing to hold
    assert set_param("SIM_WIND_MODEL", 1) == 0.0  # switching it back on at 5 would not fit


def test_takeoff_to_2m_then_land_and_auto_disarm(vehicle):
    c = vehicle("--home-alt", "100")
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, 102.0) == M.MAV_RESULT_DENIED
    assert c.arm() == M.MAV_RESULT_ACCEPTED
    assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, 102.0) == M.MAV_RESULT_ACCEPTED
    for _ in range(int(8.0 / 0.004)):
        c.step(type_mask=TICK)
    assert -c.last["LOCAL_POSITION_NED"].z == pytest.approx(2.0, abs=0.15)
    assert c.last["GLOBAL_POSITION_INT"].alt == pytest.approx(102_000, abs=150)
    assert c.last["HEARTBEAT"].custom_mode == LOITER_MODE  # takeoff done → loiter, as PX4
    assert c.last["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_IN_AIR
    assert c.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
    for _ in range(int(9.0 / 0.004)):
        c.step(type_mask=TICK)
        if not c.last["HEARTBEAT"].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
            break
    assert not c.last["HEARTBEAT"].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert c.last["LOCAL_POSITION_NED"].z == pytest.approx(0.0, abs=1e-6)
    assert c.last["EXTENDED_SYS_STATE"].landed_state == M.MAV_LANDED_STATE_ON_GROUND


def test_request_message_autopilot_version_and_protocol_version(vehicle):
    c = vehicle()
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == M.MAV_RESULT_ACCEPTED
    caps = c.wait_for("AUTOPILOT_VERSION").capabilities
    for bit in (M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT,
                M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET, M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT):
        assert caps & bit
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, 300) == M.MAV_RESULT_ACCEPTED
    # pymavlink's common dialect lacks PROTOCOL_VERSION (id 300): it decodes as UNKNOWN_300 (CRC unchecked,
    # header not parsed, so srcSystem reads 0); check the raw frame
    buf = c.wait_for("UNKNOWN_300", sysid=0).get_msgbuf()
    assert buf[5] == 1 and buf[7:10] == (300).to_bytes(3, "little")
    assert buf[10:12] == (200).to_bytes(2, "little")
    assert c.command(M.MAV_CMD_REQUEST_MESSAGE, 12345) == M.MAV_RESULT_DENIED
    # COMMAND_INT is answered too
    c.mav.command_int_send(1, 1, 0, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 1, 0, 0, 0, 0, 0, 0)
    assert c.wait_for("COMMAND_ACK").result == M.MAV_RESULT_ACCEPTED


def test_two_vehicles_side_by_side(vehicle):
    a = vehicle()
    b = vehicle("--instance", "1")
    assert a.wait_for("HEARTBEAT").get_srcSystem() == 1
    assert b.wait_for("HEARTBEAT").get_srcSystem() == 2
    assert b.wait_for("HEARTBEAT", sysid=201).autopilot == M.MAV_AUTOPILOT_INVALID  # b's payload
    assert b.arm() == M.MAV_RESULT_ACCEPTED
    for c in (a, b):
        assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HEARTBEAT) == M.MAV_RESULT_ACCEPTED
    assert b.wait_for("HEARTBEAT").base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert not a.wait_for("HEARTBEAT").base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    # a command for system 2 sent to vehicle 1 is not answered (counted as other_target)
    a.mav.command_long_send(2, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    with pytest.raises(TimeoutError):
        a.wait_for("COMMAND_ACK", timeout_s=0.5)


def _scripted_flight() -> list[tuple]:
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "paper")
    trace = []
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker(10.0)
            _offboard_hover(c)
            for k in range(400):
                r = 0.1 * math.sin(k * 0.02)
                c.step(q=(math.cos(r / 2), math.sin(r / 2), 0.0, 0.0), thrust=0.44)
                lp, at, sw = c.last["LOCAL_POSITION_NED"], c.last["ATTITUDE"], c.last["DEBUG_FLOAT_ARRAY"]
                imu = c.last["HIGHRES_IMU"]  # with the default (seeded) noise and bias model
                trace.append((c.sim_time_ms, lp.time_boot_ms, lp.x, lp.y, lp.z, lp.vz, at.time_boot_ms, at.roll,
                              at.pitch, sw.time_usec, *sw.data[:5], imu.time_usec, imu.xacc, imu.zacc, imu.xgyro))
    finally:
        assert stop_vehicle(proc) == 0
    return trace


def test_lockstep_runs_are_bit_identical():
    a = _scripted_flight()
    b = _scripted_flight()
    assert len(a) == 400
    assert a == b
    assert a[-1][0] == 5 * 4 + 400 * 4  # one control period per answer
    assert a[-1][4] < -0.1  # it did fly
    assert len({row[-3] for row in a}) >= 30  # 50 Hz IMU samples, noisy, and the same in both runs


def test_broken_vehicle_file_exits_2_naming_file_and_key(tmp_path):
    bad = tmp_path / "vehicle.toml"
    bad.write_text("[vehicle]\nM = 1.25\ncable = 2.0\n")
    r = subprocess.run([sys.executable, "-m", "sim_bridge", "--vehicle", str(bad)], capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 2
    assert str(bad) in r.stderr and "cable" in r.stderr
    assert r.stderr.count("\n") == 1


def test_the_vehicle_starts_without_scipy_linalg():
    """Numba's first kernel load probes BLAS by importing ``scipy.linalg`` (~0.16 s of every start); the vehicle's
    kernels need no BLAS and skip the probe (``companion.core.kernel_cache.skip_numba_blas_probe``). Its settings check
    compiles the eq. 49 kernel, so the skip must come before it: a start with eq. 49 on, import log read."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "sim_bridge", "--onboard-port", "0",
                          "--gcs-port", "0", "--wind", "paper", "--duration", "0.2"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    imported = {line.rsplit("|", 1)[-1].strip() for line in out.stderr.splitlines() if line.startswith("import time")}
    assert "numba" in imported  # the kernels were loaded in this start
    assert "scipy.linalg" not in imported
