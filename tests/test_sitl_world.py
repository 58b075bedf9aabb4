"""The bundled vehicle in a world (``sitl --world``): its LiDAR's OBSTACLE_DISTANCE frames over real UDP on
127.0.0.1 (5 messages a scan, fields as PX4/ArduPilot read them, ranges as the vehicle's pose predicts, the same
bits every lockstep run), world files refused clearly, the raw scan on Zenoh over loopback, and a flight's report
scored against the world's trunks (the truth)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.obstacles import Obstacle
from companion.core.world import load_world, world_from_dict
from companion.errors import ConfigError
from companion.report.scoring import obstacle_clearances
from companion.zenoh_io import schema
from sim_bridge.lidar import Lidar, LidarConfig
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle
from sim_bridge.world import WorldArrays

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

M = mavlink2
ROOT = Path(__file__).resolve().parents[1]
FOREST = load_world("forest")


def _fly_and_collect(steps_up: int, *extra: str) -> tuple[list, dict[int, tuple]]:
    """A lockstep vehicle in the forest, armed and taking off for ``steps_up`` control periods: every
    OBSTACLE_DISTANCE of the vehicle's system, and its pose (LOCAL_POSITION_NED + ATTITUDE) by time_boot_ms."""
    proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none", "--world", "forest", *extra)
    scans: list = []
    pos: dict[int, tuple] = {}
    att: dict[int, tuple] = {}

    def on(m) -> None:
        t = m.get_type()
        if m.get_srcSystem() != 1:
            return
        if t == "OBSTACLE_DISTANCE":
            scans.append(m)
        elif t == "LOCAL_POSITION_NED":
            pos[m.time_boot_ms] = (m.x, m.y, m.z)
        elif t == "ATTITUDE":
            att[m.time_boot_ms] = (m.roll, m.pitch, m.yaw)

    try:
        with MavClient(port) as c:
            c.on_message = on
            c.heartbeat()
            c.wait_marker()
            assert c.arm() == M.MAV_RESULT_ACCEPTED
            assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
            for _ in range(steps_up):
                c.step()
    finally:
        assert stop_vehicle(proc) == 0
    return scans, {t: (pos[t], att[t]) for t in pos if t in att}


@pytest.fixture(scope="module")
def climb():
    return _fly_and_collect(1000, "--lidar-noise-m", "0")  # 4 s: from the ground to ~2.5 m


def test_each_scan_is_five_obstacle_distance_messages_as_the_autopilots_read_them(climb):
    scans, _ = climb
    assert len(scans) == 5 * 40  # 10 Hz for 4 s
    by_time: dict[int, list] = {}
    for m in scans:
        by_time.setdefault(m.time_usec, []).append(m)
    assert sorted(by_time) == [100_000 * k for k in range(1, 41)]
    for group in by_time.values():
        assert [m.angle_offset for m in group] == [0.0, 72.0, 144.0, 216.0, 288.0]
        for m in group:
            assert (m.get_srcSystem(), m.get_srcComponent()) == (1, M.MAV_COMP_ID_OBSTACLE_AVOIDANCE)
            assert (m.frame, m.sensor_type, m.increment, m.increment_f) == (M.MAV_FRAME_BODY_FRD, 0, 1, 1.0)
            assert (m.min_distance, m.max_distance) == (10, 1200) and len(m.distances) == 72


def test_ranges_are_those_the_vehicles_pose_predicts(climb):
    scans, poses = climb
    lid = Lidar(LidarConfig(noise_m=0.0))
    trunks = WorldArrays(FOREST).at(0.0)
    checked = 0
    for t_usec in sorted({m.time_usec for m in scans}):
        p, e = poses[t_usec // 1000]
        got = np.concatenate([m.distances for m in scans if m.time_usec == t_usec])
        want = lid.true_ranges(p, e, *trunks)
        want_cm = np.where(np.isfinite(want), np.rint(np.nan_to_num(want, posinf=0.0) * 100.0), 1201)
        assert np.max(np.abs(got - want_cm)) <= 1, t_usec  # float32 telemetry against the float64 truth: ≤ 1 cm
        checked += 1
    last = np.concatenate([m.distances for m in scans if m.time_usec == 4_000_000])
    assert p[2] < -2.0 and 280 <= last[0] <= 300  # at 2.4 m: obs1 ahead, 3 − 0.2 m away
    assert checked == 40


def test_the_same_lockstep_run_sends_the_same_bits_noise_included():
    a, _ = _fly_and_collect(300)
    b, _ = _fly_and_collect(300)
    assert len(a) == 5 * 12 and [m.get_msgbuf() for m in a] == [m.get_msgbuf() for m in b]
    c, _ = _fly_and_collect(300, "--lidar-seed", "1")
    assert [m.get_msgbuf() for m in c] != [m.get_msgbuf() for m in a]


def test_sectors_layout_is_one_message_of_72_five_degree_sectors():
    scans, _ = _fly_and_collect(100, "--lidar-mavlink", "sectors", "--lidar-rate-hz", "5")
    assert len(scans) == 2 and all(m.increment_f == 5.0 and m.angle_offset == 0.0 for m in scans)
    assert 260 <= scans[0].distances[0] <= 290  # obs1 just ahead: 2.7-2.8 m at -2..2 deg


@pytest.mark.parametrize("text, says", [
    ("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\nradius_m = -0.3\n", "#0 radius_m: must be in"),
    ("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\n", "missing required key 'radius_m'"),
    ("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\nradius_m = 0.3\ncolour = 2\n", "unknown key 'colour'"),
    ("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\nradius_m = 0.3\nsource = \"x\"\n", "unknown key 'source'"),
    ("[[obstacles]]\nx_m = 'a'\ny_m = 0.0\nradius_m = 0.3\n", "x_m"),
    ("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\nradius_m = 0.3\nvx_mps = 400.0\n", "speed above"),
    ("[world]\nname = 3\n", "[world] name"),
    ("[trees]\n", "unknown table or key 'trees'"),
    ("obstacles = 3\n", "expected an array of tables"),
    ("[[obstacles]\n", "not valid TOML"),
])
def test_a_broken_world_file_is_refused_naming_the_key(tmp_path, text, says):
    f = tmp_path / "w.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_world(f)
    assert str(f) in str(e.value) and says in str(e.value)


def test_the_vehicle_refuses_a_broken_world_or_lidar_flag_before_it_starts(tmp_path):
    f = tmp_path / "w.toml"
    f.write_text("[[obstacles]]\nx_m = 1.0\ny_m = 0.0\n")
    cases = ((["--world", str(f)], "missing required key 'radius_m'"),
             (["--world", "no_such_world"], "shipped: forest, forest_crossing"),
             (["--world", "forest", "--lidar-step-deg", "7"], "--lidar-step-deg"),
             (["--world", "forest", "--lidar-compid", "1"], "--lidar-compid: 1 is the autopilot's"),
             (["--world", "forest", "--lidar-compid", "300"], "--lidar-compid"),
             (["--lidar-range-m", "5"], "--lidar-range-m: needs --world"))
    procs = [subprocess.Popen([sys.executable, "-m", "sim_bridge", *args], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for args, _ in cases]  # side by side: ~1 s each
    for (args, says), p in zip(cases, procs, strict=True):
        out, err = p.communicate(timeout=60)
        assert p.returncode == 2 and says in err and "SITL READY" not in out, (args, err)


def test_fly_refuses_a_world_without_the_bundled_vehicle_or_a_broken_one(tmp_path):
    bad = tmp_path / "w.toml"
    bad.write_text("[[obstacles]]\nx_m = 1.0\n")
    for args, says in ((["--world", "forest"], "--world: only with --sitl"),
                       (["--sitl", "--world", str(bad)], "missing required key")):
        p = subprocess.run([sys.executable, "-m", "companion.cli.main", "fly", "--no-zenoh", "--no-recording", *args,
                            "--run-dir", str(tmp_path / "run")], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert p.returncode == 2 and says in p.stderr, (args, p.stderr[-2000:])
        assert not (tmp_path / "run").exists()  # refused before anything started


def test_shipped_worlds_are_the_table2_forest_and_a_crossing_trunk():
    from companion.core.mission import load_mission

    mission = load_mission(ROOT / "config" / "missions" / "forest.toml")
    assert [(o.x_m, o.y_m, o.radius_m, o.height_m) for o in FOREST.trunks] == [
        (o.x_m, o.y_m, o.radius_m, o.height_m) for o in mission.obstacles]
    crossing = load_world("forest_crossing.toml")
    mover = next(o for o in crossing.trunks if o.vy_mps)
    assert crossing.trunks[:5] == FOREST.trunks and mover.y_m + 10.0 * mover.vy_mps == 0.0  # on the line at 10 s
    assert world_from_dict({}, "empty.toml").trunks == ()


def test_a_world_trunk_is_scored_where_it_is_on_the_vehicle_clock():
    t = np.array([0.0, 5.0, 10.0])
    pos = np.array([[5.0, 0.0, -2.0]] * 3)
    pay = np.full((3, 3), np.nan)
    w = Obstacle(5.0, -10.0, 0.3, vy_mps=1.0, source="world")  # at (5, 0) at vehicle time 10 s
    m = Obstacle(5.0, -10.0, 0.3, vy_mps=1.0, source="mission")  # from the mission clock's zero (2 s): 8 s later
    assert obstacle_clearances(t, pos, pay, [w], 0.5, clock_t0_s=2.0)[0] == pytest.approx(-0.8)
    assert obstacle_clearances(t, pos, pay, [m], 0.5, clock_t0_s=2.0)[0] == pytest.approx(2.0 - 0.8)


def test_the_raw_scan_reaches_a_zenoh_subscriber_on_loopback():
    import zenoh

    from lab.procs import free_tcp_port

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    cfg = zenoh.Config()
    for k, v in (("listen/endpoints", [ep]), ("scouting/multicast/enabled", False)):
        cfg.insert_json5(k, json.dumps(v))
    got: list = []
    with zenoh.open(cfg) as session:
        sub = session.declare_subscriber("slungpilot/1/scan", lambda s: got.append(s.payload.to_bytes()))
        proc, _, _ = spawn_vehicle("--world", "forest", "--zenoh-scan", "--zenoh-scan-connect", ep,
                                   "--lidar-dropout", "0.2")
        try:
            end = time.monotonic() + 10.0
            while len(got) < 3 and time.monotonic() < end:
                time.sleep(0.05)
        finally:
            assert stop_vehicle(proc) == 0
        sub.undeclare()
    assert len(got) >= 3
    d = schema.decode(got[-1])
    assert d["schema"] == schema.SCAN and d["vehicle_id"] == "1" and d["frame"] == "body_frd"
    assert d["time_usec"] % 100_000 == 0 and d["t_s"] == pytest.approx(d["time_usec"] * 1e-6)
    assert d["angle_min_rad"] == 0.0 and d["angle_increment_rad"] == pytest.approx(math.radians(1.0))
    r = schema.scan_ranges(d)
    assert r.shape == (360,) and 0.1 < np.isnan(r).mean() < 0.3  # dropouts: valid false
    assert np.isinf(r[90])  # measured, nothing to the right within 12 m
    assert [schema.decode(g)["seq"] for g in got] == list(range(len(got)))


@pytest.mark.slow
def test_a_flight_in_a_world_is_scored_against_the_world(tmp_path):
    """A mission that lists no trunk, flown straight (planner none) through the forest world: the report scores the
    world's trunks, which the mission never knew, and says so."""
    text = (ROOT / "config" / "missions" / "forest.toml").read_text()
    blind = tmp_path / "blind.toml"
    blind.write_text(text[: text.index("[[obstacles]]")])
    run = tmp_path / "run"
    p = subprocess.run([sys.executable, "-m", "companion.cli.main", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                        "--no-recording", "--mission", str(blind), "--planner", "none", "--world", "forest",
                        "--run-dir", str(run)], capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert p.returncode in (0, 1), p.stderr[-3000:]
    rep = json.loads((run / "report.json").read_text())
    assert rep["obstacle_truth"] == "world:forest"
    assert rep["collisions"] >= 1 and rep["min_clearance_m"] < 0.0  # straight through obs1 at (3, -0.22)
    assert load_world(run / "world.toml").trunks == FOREST.trunks
