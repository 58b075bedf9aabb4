"""The companion app end to end: real processes, real UDP, real MAVLink, the bundled vehicle in lockstep."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.shares_cores  # lockstep flights; the two in real time are marked serial

ROOT = Path(__file__).resolve().parents[1]
FOREST = ROOT / "config" / "missions" / "forest.toml"


def _slungpilot(*args: str, timeout: float = 240.0, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "companion.cli.main", *args], capture_output=True, text=True, timeout=timeout,
        cwd=cwd or ROOT,
    )


@pytest.fixture(scope="module")
def forest_run(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    run_dir = tmp_path_factory.mktemp("forest")
    proc = _slungpilot("fly", "--sitl", "--mission", str(FOREST), "--run-dir", str(run_dir),
                       "--report", str(run_dir / "copy.json"))
    return proc, run_dir


def test_forest_mission_flies_over_mavlink_in_lockstep(forest_run):
    proc, run_dir = forest_run
    assert proc.returncode == 0, proc.stderr[-3000:]
    rep = json.loads((run_dir / "report.json").read_text())
    assert rep == json.loads((run_dir / "copy.json").read_text())
    assert rep["reached_goal"] is True
    assert rep["collisions"] == 0 and rep["min_clearance_m"] > 0.0
    assert rep["time_to_goal_s"] <= 10.0
    assert rep["lockstep"] is True and rep["outcome"] == "completed"
    # the arrival rule is recorded: 0.1 m (the bundled vehicle reports no accuracy), held for the dwell time
    assert rep["arrival"]["tolerance_m"] == 0.1 and rep["arrival"]["dwell_s"] > 0 and rep["arrival"]["t_s"] is not None
    assert rep["loop"]["ticks"] > 1000
    assert sum(rep["loop"]["gc_collections"]) > 0  # the garbage collector ran, between ticks (GcPacer)
    assert rep["loop"]["scheduling"] == "SCHED_OTHER"  # lockstep: no deadlines, no real-time priority
    # the loop lag over MAVLink is the bundled vehicle's clean-link lag: measured, and the feed-forward never faded
    lag = rep["loop_lag"]
    assert 50.0 <= lag["lag_ms_min"] <= lag["lag_ms_max"] <= 110.0 and lag["nominal_ms"] == 80.0
    assert lag["faded_s"] == 0.0 and lag["ff_trust_min"] == 1.0
    for key in ("path_length_m", "payload_path_length_m", "max_swing_rad", "swing_settle_s", "sim_time_s",
                "wall_time_s", "planner", "controller"):
        assert key in rep
    assert "reached goal" in proc.stdout  # the one-screen summary
    for png in ("plan.png", "timeseries.png", "trajectory3d.png"):
        assert (run_dir / png).stat().st_size > 10_000


def test_tlog_is_readable_by_pymavlink(forest_run):
    from pymavlink import mavutil

    _, run_dir = forest_run
    mlog = mavutil.mavlink_connection(str(run_dir / "flight.tlog"))
    types: dict[str, int] = {}
    while True:
        msg = mlog.recv_match()
        if msg is None:
            break
        types[msg.get_type()] = types.get(msg.get_type(), 0) + 1
    assert types.get("SET_ATTITUDE_TARGET", 0) > 1000  # what we sent
    assert types.get("ATTITUDE", 0) > 1000 and types.get("HEARTBEAT", 0) > 5  # what we received
    assert types.get("COMMAND_ACK", 0) >= 3


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda s: s.replace('name = "forest"', 'name = "forest"\ncolour = "red"'), "unknown key 'colour'"),
        (lambda s: s.replace('timeout_s = 40.0', ''), "missing required key 'timeout_s'"),
        (lambda s: s.replace('timeout_s = 40.0', 'timeout_s = "long"'), "timeout_s"),
        (lambda s: s.replace('radius_m = 0.2', 'radius_m = -0.2'), "radius_m"),
        (lambda s: s.replace('goal_ned_m = [10.0, 0.0, -2.0]', 'goal_ned_m = [3.0, -0.22, -2.0]'), "goal"),
    ],
)
def test_bad_mission_file_refused_before_takeoff_with_exit_2(tmp_path, edit, match):
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(FOREST.read_text()))
    proc = _slungpilot("fly", "--sitl", "--no-zenoh", "--mission", str(bad), "--run-dir", str(tmp_path / "run"),
                       timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert str(bad) in proc.stderr and match in proc.stderr
    assert proc.stderr.count("\n") <= 2, "one clear message, no traceback"
    assert not (tmp_path / "run" / "flight.tlog").exists(), "nothing was flown"


@pytest.mark.slow
@pytest.mark.serial  # --realtime
@pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)
def test_ctrl_c_mid_flight_holds_lands_and_leaves_report_and_log(tmp_path):
    run_dir = tmp_path / "abort"
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "-v", "fly", "--sitl", "--realtime", "--no-zenoh", "--mission",
         str(FOREST), "--rt-priority", "5",  # Ctrl-C works the same with the control loops SCHED_FIFO (or refused)
         "--run-dir", str(run_dir)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        deadline = time.monotonic() + 90
        assert proc.stderr is not None
        for line in proc.stderr:
            if "Mode: OFFBOARD" in line:
                break
            assert time.monotonic() < deadline, "never reached OFFBOARD"
        time.sleep(3.0)  # mid-flight, in the air
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err[-2000:]
    rep = json.loads((run_dir / "report.json").read_text())
    assert rep["outcome"] == "aborted" and rep["reached_goal"] is False
    assert rep["final_phase"] in ("landed", "land_timeout")
    assert rep["sim_time_s"] > 1.0  # it was flying (mission rows only; the landing is not counted)
    sched = rep["loop"]["scheduling"]
    assert sched == "SCHED_FIFO 5" or sched.startswith("SCHED_OTHER (SCHED_FIFO 5 refused"), sched
    assert rep["loop"]["preempted_ticks"] >= 0
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(run_dir / "flight.tlog"))
    n = 0
    while mlog.recv_match(type="SET_ATTITUDE_TARGET") is not None:
        n += 1
    assert n > 100


@pytest.mark.slow
@pytest.mark.parametrize(("swing_input", "envelope"), [("none", "full_cable"), ("payload_position", "swing")])
def test_flies_without_the_cable_sensor(tmp_path, swing_input, envelope):
    """No cable-angle sensor: fall back to the payload's position stream, or to nothing (full-cable envelope)."""
    proc = _slungpilot("fly", "--sitl", "--no-zenoh", "--mission", str(FOREST), "--run-dir", str(tmp_path),
                       "--no-plots", "--swing-input", swing_input)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["reached_goal"] and rep["collisions"] == 0
    sources, envelopes = rep["swing_sources"], rep["envelope_modes"]
    assert set(sources) <= {swing_input, "none"} and sources[swing_input] > 1000
    assert set(envelopes) <= {envelope, "full_cable"} and envelopes[envelope] > 1000
    # the payload now starts on the ground right under the airframe: on the first ticks its offset is zero and
    # gives no angles (no swing source, full-cable envelope), a handful before take-off
    if swing_input != "none":
        assert sources.get("none", 0) <= 0.01 * sum(sources.values())
        assert envelopes.get("full_cable", 0) <= 0.01 * sum(envelopes.values())
    assert rep["max_swing_rad"] is not None  # the log still records the measured swing
    if swing_input == "none":
        assert "no swing input" in proc.stderr


@pytest.mark.slow
def test_flies_an_autopilot_it_did_not_start_reading_its_hover_thrust(tmp_path):
    """The path a real PX4 takes: vehicle started separately, companion listens (udpin), picks the PX4 profile
    from the HEARTBEAT and reads MPC_THR_HOVER instead of assuming it."""
    from companion.launch.sitl import free_udp_port

    comp_port, veh_port, gcs_port = free_udp_port(), free_udp_port(), free_udp_port()
    veh = subprocess.Popen(
        [sys.executable, "-m", "sim_bridge", "--lockstep", "--thr-hover", "0.55", "--onboard-port", str(veh_port),
         "--onboard-remote", f"127.0.0.1:{comp_port}", "--gcs-port", str(gcs_port)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=ROOT,
    )
    try:
        assert veh.stdout is not None and veh.stdout.readline().startswith("SITL READY")
        proc = _slungpilot("fly", "--connect", f"udpin://127.0.0.1:{comp_port}", "--lockstep", "--no-zenoh",
                           "--mission", str(FOREST), "--run-dir", str(tmp_path), "--no-plots")
    finally:
        veh.send_signal(signal.SIGINT)
        veh.wait(timeout=20)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["profile"] == "px4" and rep["hover_thrust_norm"] == pytest.approx(0.55, abs=1e-6)
    assert rep["reached_goal"] and rep["collisions"] == 0


def test_no_autopilot_fails_clearly_in_bounded_time(tmp_path):
    from companion.launch.sitl import free_udp_port

    proc = _slungpilot("fly", "--connect", f"udpin://127.0.0.1:{free_udp_port()}", "--heartbeat-timeout", "1.5",
                       "--no-zenoh", "--run-dir", str(tmp_path), timeout=30)
    assert proc.returncode == 3  # LinkError
    assert "no autopilot heartbeat" in proc.stderr and "Traceback" not in proc.stderr
    assert json.loads((tmp_path / "report.json").read_text())["reached_goal"] is False


@pytest.mark.slow
def test_lockstep_flight_is_repeatable_bit_for_bit(forest_run, tmp_path):
    """The same mission flown twice in lockstep gives the identical per-tick log: commands land at the same
    simulated time, never at a wall-clock-dependent one."""
    import numpy as np

    _, first = forest_run
    proc = _slungpilot("fly", "--sitl", "--no-zenoh", "--no-plots", "--mission", str(FOREST), "--run-dir",
                       str(tmp_path))
    assert proc.returncode == 0, proc.stderr[-2000:]
    a, b = np.load(first / "flight_log.npz"), np.load(tmp_path / "flight_log.npz")
    assert a.files == b.files and len(a["t_s"]) > 1000
    for k in a.files:
        assert np.array_equal(a[k], b[k], equal_nan=True), k


@pytest.mark.slow
def test_ctrl_c_in_lockstep_holds_and_lands(tmp_path):
    """In lockstep the sequencer runs at the tick's pace: Ctrl-C still switches to hold and lands."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "-v", "fly", "--sitl", "--no-zenoh", "--no-plots", "--mission",
         str(FOREST), "--run-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "Mode: OFFBOARD" in line:
                break
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err[-2000:]
    assert "Mode: AUTO.LOITER" in err and "Mode: AUTO.LAND" in err
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["outcome"] == "aborted" and rep["final_phase"] == "landed" and rep["reached_goal"] is False


@pytest.mark.slow
@pytest.mark.serial  # --realtime
@pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)
def test_ctrl_c_in_the_terminal_reaches_the_companion_only_which_lands_the_vehicle(tmp_path):
    """A terminal sends SIGINT to the whole foreground process group: the bundled vehicle runs in its own, so it is
    still flying while the companion holds and lands it, and is stopped last (issue 14)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion.cli.main", "-v", "fly", "--sitl", "--realtime", "--no-zenoh", "--no-plots",
         "--mission", str(FOREST), "--run-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True,
    )
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "takeover → mission" in line:
                break
        time.sleep(2.0)
        os.killpg(os.getpgid(proc.pid), signal.SIGINT)  # what Ctrl-C in a terminal does
        _out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(os.getpgid(proc.pid), signal.SIGKILL)
    assert proc.returncode == 130, err[-2000:]
    assert "Mode: AUTO.LOITER" in err and "Mode: AUTO.LAND" in err and "no COMMAND_ACK" not in err
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["outcome"] == "aborted" and rep["final_phase"] == "landed"


def test_the_provisional_loop_timings_cover_a_window_and_the_final_ones_everything():
    """The journal's provisional report is made on the loop every second: its percentiles must not grow with the
    flight (a 30 min flight made them cost 150 ms); the final report's cover every tick."""
    from companion.flight.loop_stats import LoopStats

    s = LoopStats()
    s.ticks = 6
    s.tick_s = [9.0, 9.0, 9.0, 0.001, 0.001, 0.001]
    s.tick_cpu_s, s.send_s, s.jitter_s, s.ingest_s = list(s.tick_s), list(s.tick_s), list(s.tick_s), list(s.tick_s)
    w = s.summary(window=3)
    assert w["window_ticks"] == 3 and w["tick_ms_max"] == 1.0 and w["jitter_ms_max"] == 1.0
    assert w["ingest_ms_p99"] == pytest.approx(1.0)
    full = s.summary()
    assert full["window_ticks"] is None and full["tick_ms_max"] == 9000.0 and full["ticks"] == 6


CROSSING = """[mission]
name = "crossing"
start_ned_m = [0.0, 0.0, -2.0]
goal_ned_m = [10.0, 0.0, -2.0]
planner = "shaped"
controller = "smc_ff"
timeout_s = 40.0
hold_s = 1.0
land = true

[vehicle]
m = 0.25
l = 1.0

[[obstacles]]
x_m = 5.0
y_m = 0.0
radius_m = 0.3
vx_mps = 0.0
vy_mps = 1.5
"""


@pytest.mark.slow
def test_fly_scores_a_moving_trunk_where_it_was(tmp_path):
    """A trunk that stands on the path at the mission's start and crosses away at 1.5 m/s: the vehicle flies
    through its file position long after it left. The report scores it where it was at each time (issue 25: it
    used to say `collisions 1, min_clearance_m -0.546` for this flight)."""
    mission = tmp_path / "crossing.toml"
    mission.write_text(CROSSING)
    proc = _slungpilot("-q", "fly", "--sitl", "--no-zenoh", "--no-plots", "--no-recording", "--mission", str(mission),
                       "--run-dir", str(tmp_path / "run"))
    assert proc.returncode == 0, proc.stderr[-3000:]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["obstacle_clock_t0_s"] is not None  # the mission clock's zero, from the flight core
    assert rep["collisions"] == 0 and rep["collisions_moving"] == 0
    assert rep["min_clearance_m"] > 1.0
