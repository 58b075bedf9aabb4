"""Issue 28: a payload the vehicle cannot lift with margin is refused before take-off with the numbers; a
mis-declared payload reaches the bundled vehicle (its physics flies the true one); a short lockstep flight in
light turbulence completes."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.mission import load_mission
from companion.core.payload_check import HOVER_FRACTION_LIMIT, thrust_margin
from companion.core.vehicle_params import VehicleParams
from companion.report.journal import rebuild_run
from companion.report.wind_truth import held_swing_rad
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

M = mavlink2
ROOT = Path(__file__).resolve().parents[1]
FOREST = (ROOT / "config" / "missions" / "forest.toml").read_text()


def _mission(tmp_path: Path, vehicle: str = "m = 0.25\nl = 1.0\n", wind: str = 'model = "paper"\nscale = 1.0\n'
             ) -> Path:
    head, rest = FOREST.split("[wind]", 1)
    obstacles = rest[rest.index("[[obstacles]]"):]
    p = tmp_path / "mission.toml"
    p.write_text(f"{head}[wind]\n{wind}\n[vehicle]\n{vehicle}\n{obstacles}")
    return p


def _fly(mission: Path, run_dir: Path, *extra: str, timeout: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--mission", str(mission),
                           "--no-zenoh", "--no-plots", "--run-dir", str(run_dir), *extra],
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def test_margin_numbers_and_limit():
    ok = thrust_margin(VehicleParams())  # the paper's vehicle: 14.7 N of 36.8 N
    assert ok.ok and ok.fraction == pytest.approx(0.4)
    heavy = thrust_margin(VehicleParams(m=0.8, max_thrust_n=24.8))
    assert not heavy.ok and heavy.fraction == pytest.approx(2.05 * 9.81 / 24.8)
    assert heavy.detail() == ("refused before take-off: hover needs 0.81 of maximum thrust (limit 0.75): payload "
                              "0.8 kg + vehicle 1.25 kg = 20.1 N of 24.8 N")
    edge = VehicleParams(m=HOVER_FRACTION_LIMIT * VehicleParams().max_thrust_n / 9.81 - 1.25)
    assert thrust_margin(edge).ok  # exactly at the limit still flies


def test_too_heavy_payload_is_refused_before_anything_starts(tmp_path):
    run = tmp_path / "run"
    r = _fly(_mission(tmp_path, "m = 2.0\nl = 1.0\n"), run)
    assert r.returncode == 4, r.stderr  # exit code of "refused"
    assert "hover needs 0.87 of maximum thrust (limit 0.75): payload 2 kg + vehicle 1.25 kg = 31.9 N of 36.8 N" \
        in r.stderr + r.stdout
    rep = json.loads((run / "report.json").read_text())
    assert rep["outcome"] == "refused" and rep["thrust_margin"]["hover_fraction"] == pytest.approx(31.8825 / 36.7875)
    assert not (run / "sitl.log").exists() and not (run / "vehicle.toml").exists()  # no vehicle was started
    assert rep["sim_time_s"] == 0.0


def _read_param(c: MavClient, name: bytes) -> float:
    c.mav.param_request_read_send(1, 1, name, -1)
    return c.wait_for("PARAM_VALUE", lambda m: m.param_id == name.decode()).param_value


def _climb_rate_at(c: MavClient, thrust: float) -> float:
    for _ in range(5):
        c.step(thrust=0.0)
    assert c.set_mode(6) == M.MAV_RESULT_ACCEPTED and c.arm() == M.MAV_RESULT_ACCEPTED
    for _ in range(500):  # 2 s of climb (payload lifted after ~1 m), then 1 s at the thrust under test
        c.step(thrust=0.5)
    z0 = c.last["LOCAL_POSITION_NED"].vz
    for _ in range(250):
        c.step(thrust=thrust)
    return c.last["LOCAL_POSITION_NED"].vz - z0  # change of the downward speed over 1 s, m/s


def test_true_payload_flags_reach_the_vehicle_physics():
    """The declared payload (0.25 kg: the thrust calibration, MPC_THR_HOVER 0.4) hovers at 0.4; a true payload of
    0.5 kg reads back as such and makes the same normalized thrust sink at (M+m_true−(M+m_decl))/(M+m_true)·g."""
    out = {}
    for label, args in (("declared", ()), ("true", ("--payload-mass-kg", "0.5", "--cable-length-m", "1.3"))):
        proc, port, _ = spawn_vehicle("--lockstep", "--wind", "none", *args)
        c = MavClient(port)
        try:
            c.heartbeat()
            c.wait_marker(10.0)
            out[label] = (_read_param(c, b"SIM_PLD_MASS"), _read_param(c, b"SIM_CABLE_LEN"), _climb_rate_at(c, 0.4))
        finally:
            c.close()
            assert stop_vehicle(proc) == 0
    assert out["declared"][:2] == pytest.approx((0.25, 1.0))
    assert out["true"][:2] == pytest.approx((0.5, 1.3))
    assert abs(out["declared"][2]) < 0.1  # hovers (the payload hangs below after the climb's swing)
    sink = (1.75 - 1.5) / 1.75 * 9.81
    assert out["true"][2] == pytest.approx(sink, rel=0.25)  # heavier than told: sinks ~1.4 m/s²


def test_true_payload_flags_need_sitl():
    r = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--mission", "forest", "--true-payload-mass-kg",
                        "0.4", "--no-zenoh"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode == 2 and "--true-payload-mass-kg: only with --sitl" in r.stderr


@pytest.mark.slow
def test_lockstep_flight_in_light_turbulence_completes_the_same_twice(tmp_path):
    wind = 'model = "turbulence"\nmean_speed_mps = 3.0\ndirection_deg = 90.0\nintensity = "light"\nseed = 1\n'
    run = tmp_path / "run"
    r = _fly(_mission(tmp_path, wind=wind), run, "--planner", "shaped", "--true-payload-mass-kg", "0.3")
    rep = json.loads((run / "report.json").read_text())
    assert r.returncode == 0, (rep.get("outcome"), rep.get("outcome_detail"), r.stderr[-2000:])
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    assert "intensity" in (run / "wind.toml").read_text()  # the vehicle got the whole [wind] table
    assert rep["payload_declared"]["mass_kg"] == 0.25 and rep["payload_true"]["mass_kg"] == 0.3
    assert rep["wind"]["intensity"] == "light" and math.isfinite(rep["max_swing_rad"])
    # what the vehicle's wind alone did, for the payload it carried (0.3 kg, not the declared 0.25 kg): the payload
    # held still over the span in which the flown one hung (the vehicle's times, from the first swing reading)
    truth = rep["wind_truth"]
    assert (truth["payload_kg"], truth["cable_m"]) == (0.3, 1.0)
    flown = load_mission(tmp_path / "mission.toml").wind
    with np.load(run / "flight_log.npz") as z:
        t, sw = z["t_s"], z["swing"]
    hung = np.flatnonzero(np.nan_to_num(np.abs(sw[:, :2])).max(axis=1) > 0.0)
    assert 0 < hung[0] < len(t) - 1  # the payload lay on the ground first, then hung
    held = held_swing_rad(flown, 0.3, 1.0, float(t[hung[0]]), float(t[-1]))
    assert truth["held_swing_max_rad"] == pytest.approx(held, rel=1e-9)
    assert held != pytest.approx(held_swing_rad(flown, 0.25, 1.0, float(t[hung[0]]), float(t[-1])), rel=1e-3)
    assert 0.0 < truth["drag_angle_max_rad"] < held  # a gust swings the held payload past its drag angle
    assert "the wind alone      held still" in (run / "summary.txt").read_text()
    copy = tmp_path / "rebuilt"  # `slungpilot report RUN_DIR` (after a kill -9) reckons it from the journal alike
    shutil.copytree(run, copy)
    rebuilt = rebuild_run(copy, plots=False)
    assert rebuilt["rebuilt_from_journal"] and rebuilt["wind_truth"] == pytest.approx(truth, rel=1e-6)
    again = tmp_path / "again"
    _fly(_mission(tmp_path, wind=wind), again, "--planner", "shaped", "--true-payload-mass-kg", "0.3")
    assert (again / "flight_log.npz").read_bytes() == (run / "flight_log.npz").read_bytes()  # seeded: same bits


def test_payload_that_would_drag_on_the_ground_is_refused_before_anything_starts(tmp_path):
    """Issue 28's table: 0.25 kg on 2.5 m flown at 2 m dragged its payload into two trunks; now refused."""
    run = tmp_path / "run"
    r = _fly(_mission(tmp_path, "m = 0.25\nl = 2.5\n"), run)
    assert r.returncode == 4, r.stderr
    assert "start_ned_m: the payload would hang -0.50 m above the ground (altitude 2.00 m, cable 2.50 m); fly at " \
        "least 2.80 m high" in r.stderr
    rep = json.loads((run / "report.json").read_text())
    assert rep["outcome"] == "refused" and "payload would hang" in rep["outcome_detail"]
    assert not (run / "sitl.log").exists()  # no vehicle was started
