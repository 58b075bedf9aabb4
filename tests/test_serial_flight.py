"""Whole flights over serial links (issue 27): the bundled vehicle on one end of a real pseudo-terminal pair (socat
when it is on PATH, else lab/pty_pair.py's relay), the companion on the other, or behind a router (MAVProxy).
The link itself, piece by piece: tests/test_serial_link.py. A pty's baud rate is nominal (no 921600 bit/s limit).
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lab.procs import free_udp_port
from lab.pty_pair import PtyPair

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


# ------------------------------------------------------------------------------------------------ whole flights
def _start_vehicle(tmp_path: Path, device: Path, *extra: str) -> subprocess.Popen:
    vfile = tmp_path / "vehicle.toml"
    from companion.core.mission import load_mission
    from companion.launch.sitl import vehicle_toml

    vfile.write_text(vehicle_toml(load_mission(ROOT / "config" / "missions" / "forest.toml")))
    with open(tmp_path / "sitl.log", "wb") as log:  # the child keeps its own descriptor
        proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--serial", f"{device}:921600",
                                 "--gcs-port", str(free_udp_port()), "--vehicle", str(vfile), *extra],
                                stdout=subprocess.PIPE, stderr=log, text=True, cwd=ROOT)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("SITL READY onboard=serial:"), line
    return proc


def _fly(run_dir: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "companion.cli", "-v", "fly", "--no-zenoh", "--no-plots",
                             "--no-recording", "--run-dir", str(run_dir), *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def _stop(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            return proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait(10)


@pytest.mark.slow
@pytest.mark.shares_cores  # lockstep
def test_table2_forest_over_a_serial_pty_pair_flies_as_over_udp(tmp_path):
    """Lockstep: the same flight, bit for bit, as ``fly --sitl`` over UDP (the link carries the same frames in the
    same order; only the carrier differs)."""
    udp = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                          "--no-recording", "--planner", "safe", "--run-dir", str(tmp_path / "udp")],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert udp.returncode == 0, udp.stderr[-2000:]
    with PtyPair(tmp_path / "fc", tmp_path / "cc"):
        sim = _start_vehicle(tmp_path, tmp_path / "fc", "--lockstep")
        try:
            fly = _fly(tmp_path / "serial", "--connect", f"serial://{tmp_path}/cc:921600", "--lockstep",
                       "--profile", "bundled", "--planner", "safe")
            _out, err = fly.communicate(timeout=300)
        finally:
            assert _stop(sim) == 0  # the vehicle outlived the flight and stops cleanly
        assert fly.returncode == 0, err[-2000:]
    auto = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--serial", "--no-zenoh",
                           "--no-plots", "--no-recording", "--planner", "safe", "--run-dir", str(tmp_path / "auto")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert auto.returncode == 0, auto.stderr[-2000:]
    assert not (tmp_path / "auto" / "pty-companion").exists()  # the pair it made is gone with its links
    a = json.loads((tmp_path / "udp" / "report.json").read_text())
    la = np.load(tmp_path / "udp" / "flight_log.npz")
    for run in ("serial", "auto"):  # wired by hand (sitl --serial + fly --connect serial://), and fly --sitl --serial
        b = json.loads((tmp_path / run / "report.json").read_text())
        assert a["outcome"] == b["outcome"] == "completed" and b["reached_goal"]
        for k in ("time_to_goal_s", "max_swing_rad", "min_clearance_m", "path_length_m", "sim_time_s"):
            assert a[k] == b[k], k
        assert b["link"]["rejected"] == {} and b["link"]["lost"] == 0
        lb = np.load(tmp_path / run / "flight_log.npz")
        for k in la.files:
            assert np.array_equal(la[k], lb[k], equal_nan=True), (run, k)


@pytest.mark.slow
@pytest.mark.shares_cores  # lockstep
def test_a_signed_flight_over_serial(tmp_path):
    """``fly --sitl --serial --signing-key``: both ends sign over the pty; the forest completes, nothing rejected."""
    key = tmp_path / "link.key"
    from companion.mavlink_io import signing as sg

    sg.write_new_key_file(key)
    proc = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--serial", "--signing-key",
                           str(key), "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(tmp_path / "run")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["reached_goal"]
    assert not {k: v for k, v in rep["link"]["rejected"].items() if v}, rep["link"]
    from companion.mavlink_io.tlog import tlog_frames

    frames = [f for _, f in tlog_frames(tmp_path / "run" / "flight.tlog")]
    assert len(frames) > 1000 and all(f[2] & sg.IFLAG_SIGNED for f in frames)  # in and out, every frame signed


@pytest.mark.slow
@pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)
def test_fly_sitl_serial_sigkilled_leaves_no_vehicle_and_no_pty_pair(tmp_path):
    """``fly --sitl --serial`` SIGKILLed in flight: its vehicle and its pty pair (tied to it) are gone within 5 s."""
    import psutil

    fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "-v", "fly", "--sitl", "--serial", "--realtime",
                            "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(tmp_path / "run")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    kids: list = []
    try:
        assert fly.stderr is not None
        for line in fly.stderr:
            if "takeover → mission" in line:
                break
        kids = psutil.Process(fly.pid).children(recursive=True)
        cmds = [f"{k.name()} {' '.join(k.cmdline())}" for k in kids]  # a vehicle forked ahead: its name says it
        assert any("sim_bridge" in c for c in cmds), cmds  # a forked vehicle's rewritten command line may be cut
        assert any("socat" in c or "lab.pty_pair" in c for c in cmds), cmds
        fly.kill()
        fly.wait(5)
        _gone, alive = psutil.wait_procs(kids, timeout=5)
        assert alive == [], [k.cmdline() for k in alive]
    finally:
        for k in kids:
            with contextlib.suppress(psutil.Error):
                k.kill()
        if fly.poll() is None:
            fly.kill()


@pytest.mark.slow
@pytest.mark.parametrize("victim", ["pty_pair", "vehicle"])
@pytest.mark.parametrize("realtime", [pytest.param(False, marks=pytest.mark.shares_cores),
                                      pytest.param(True, marks=pytest.mark.paired)],
                         ids=["lockstep", "realtime"])
def test_serial_link_loss_mid_flight_is_link_lost(tmp_path, victim, realtime):
    """SIGKILL the pty pair (the device vanishes under the companion) or the vehicle mid-mission: ``link_lost``
    (exit 3) as on UDP, the report says so; the companion exits by itself and nothing of the test is left running."""
    pair = PtyPair(tmp_path / "fc", tmp_path / "cc").start()
    sim = _start_vehicle(tmp_path, tmp_path / "fc", *([] if realtime else ["--lockstep"]))
    fly = _fly(tmp_path / "run", "--connect", f"serial://{tmp_path}/cc:921600", "--profile", "bundled",
               *([] if realtime else ["--lockstep"]))
    try:
        assert fly.stderr is not None
        for line in fly.stderr:
            if "takeover → mission" in line:
                break
        time.sleep(0.5)
        t_kill = time.monotonic()
        if victim == "pty_pair":
            pair.stop(signal.SIGKILL)
        else:
            sim.kill()
        fly.communicate(timeout=30)
        exit_s = time.monotonic() - t_kill
    finally:
        for p in (fly, sim):
            if p.poll() is None:
                p.kill()
        pair.stop()
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert fly.returncode == 3 and rep["outcome"] == "link_lost" and rep["final_phase"] == "link_lost", rep["outcome"]
    assert exit_s < 10.0
    closed = rep["link"]["rejected"].get("link_closed", 0)
    if victim == "pty_pair":
        assert closed == 1, rep["link"]  # the device vanished: seen at once, counted once
    else:  # silence, as on UDP (socat also ends 0.5 s after the vehicle's side closed: may or may not be seen)
        assert closed == (closed if pair.tool == "socat" else 0) <= 1, rep["link"]
    assert sim.wait(10) is not None and pair.proc.poll() is not None


MAVPROXY = Path(sys.executable).parent / "mavproxy.py"


@pytest.mark.slow
@pytest.mark.paired  # outcomes only, 0.4 of a core over 25 s: may run beside one other such test (tests/conftest.py)
@pytest.mark.skipif(not MAVPROXY.exists(), reason="MAVProxy is not installed in this environment")
def test_a_router_shares_the_serial_port_mavproxy(tmp_path):
    """The usual bench wiring: the autopilot on a serial TELEM port owned by a router (MAVProxy, master on the pty at
    921600 baud), the companion on one of its UDP outputs; real time. The forest completes."""
    from lab.procs import free_udp_port as udp_port

    comp = udp_port()
    pair = PtyPair(tmp_path / "fc", tmp_path / "cc").start()
    procs: list[subprocess.Popen] = []
    try:
        procs.append(_start_vehicle(tmp_path, tmp_path / "fc"))
        procs.append(subprocess.Popen(
            [sys.executable, str(MAVPROXY), "--master", f"{tmp_path / 'cc'},921600", "--out", f"udp:127.0.0.1:{comp}",
             "--non-interactive", "--daemon", "--nowait", "--default-modules", "", "--state-basedir", str(tmp_path)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path))
        fly = _fly(tmp_path / "run", "--connect", f"udpin://127.0.0.1:{comp}", "--profile", "bundled",
                   "--planner", "safe")
        procs.append(fly)
        _out, err = fly.communicate(timeout=300)
        assert fly.returncode == 0, err[-2000:]
    finally:
        for p in reversed(procs):
            _stop(p)
        pair.stop()
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["reached_goal"] and rep["collisions"] == 0
