"""lab.evaluate: classification and summary on hand-made results; tiny real runs in both modes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.core.mission import load_mission
from lab.eval_report import summarise
from lab.evaluate import evaluate
from lab.forests import ForestSpec
from lab.runner import classify

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)


def _r(cls_inputs: dict, seed: int, **kw) -> dict:
    base = {"reached_goal": True, "collisions": 0, "time_to_goal_s": 10.0, "max_swing_rad": 0.2,
            "min_clearance_m": 0.3, "seed": seed, "density": 3.0, "mission_file": f"m{seed}.toml", "error": None}
    base.update(cls_inputs)
    base.update(kw)
    base["class"] = classify(base)
    return base


def test_classify_success_collision_stuck_error():
    assert classify({"reached_goal": True, "collisions": 0}) == "success"
    assert classify({"reached_goal": True, "collisions": 1}) == "collision"
    assert classify({"reached_goal": False, "collisions": 2}) == "collision"
    assert classify({"reached_goal": False, "collisions": 0}) == "stuck"
    assert classify({"reached_goal": False, "collisions": 0, "max_swing_rad": 2.0}) == "lost_control"
    assert classify({"reached_goal": False, "collisions": 0, "max_swing_rad": 0.6}) == "stuck"
    assert classify({"error": "LinkError: x"}) == "error"


def test_summarise_rates_quantiles_and_failure_seeds():
    res = [_r({}, s, time_to_goal_s=float(s)) for s in range(1, 9)]
    res.append(_r({"collisions": 1, "min_clearance_m": -0.2}, 20))
    res.append(_r({"reached_goal": False, "time_to_goal_s": None}, 21))
    s = summarise(res)
    assert s["n"] == 10
    assert (s["success_rate"], s["collision_rate"], s["stuck_rate"]) == (0.8, 0.1, 0.1)
    assert s["time_to_goal_s"]["median"] == pytest.approx(4.5)  # successes only: 1..8
    assert s["time_to_goal_s"]["p90"] == pytest.approx(7.3)
    assert s["min_clearance_m"]["min"] == pytest.approx(-0.2)
    assert [(f["seed"], f["class"]) for f in s["failures"]] == [(20, "collision"), (21, "stuck")]


def _check_out(out: Path, summary: dict, n_missions: int) -> None:
    assert summary["missions"] == n_missions
    for name in ("summary.md", "summary.json", "results.jsonl", "success_vs_density.png"):
        assert (out / name).exists(), name
    lines = (out / "results.jsonl").read_text().splitlines()
    assert len(lines) == n_missions
    md = (out / "summary.md").read_text()
    assert summary["mode"] in md and "missions/min" in md
    for r in map(json.loads, lines):
        assert r["class"] in ("success", "collision", "stuck", "lost_control")  # never "error"
        if r["class"] != "success":  # every failure keeps a replayable mission file
            assert load_mission(r["mission_file"]).planner == r["planner"]
            assert str(r["seed"]) in md


@pytest.mark.slow
def test_evaluate_inprocess_tiny(tmp_path):
    out = tmp_path / "ev"
    s = evaluate(["safe", "improved"], [1.0, 3.0], 2, seed0=10, spec=ForestSpec(length_m=12.0), mode="inprocess",
                 workers=1, out=out, progress=False)
    _check_out(out, s, 8)
    assert set(s["per_density"]["safe"]) == {"1", "3"}
    assert s["per_planner"]["safe"]["n"] == 4
    # the same seeds for every planner
    seeds = {(r["planner"], r["seed"]) for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}
    assert seeds == {(p, k) for p in ("safe", "improved") for k in (10, 11)}


def test_a_fenced_goal_flown_in_process_is_classed_no_route(tmp_path):
    # the shaped planner proves there is no route and holds: the flight core's phases say so, and the in-process
    # report's outcome carries it (lab.runner), as the MAVLink flight's does
    out = tmp_path / "ev"
    evaluate(["shaped"], [3.0], 1, spec=ForestSpec(length_m=12.0), mode="inprocess", workers=1, out=out,
             progress=False, scenarios=("fenced",))
    (r,) = map(json.loads, (out / "results.jsonl").read_text().splitlines())
    assert (r["class"], r["outcome"], r["collisions"]) == ("no_route", "no_route", 0)


@pytest.mark.slow
def test_evaluate_mavlink_two_missions_in_workers(tmp_path):
    out = tmp_path / "evm"
    proc = subprocess.run(
        [sys.executable, "-m", "lab", "evaluate", "--n", "2", "--planners", "safe", "--mode", "mavlink",
         "--workers", "2", "--out", str(out), "--length", "12"],
        capture_output=True, text=True, timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    _check_out(out, s, 2)
    assert s["mode"] == "mavlink" and s["spec"]["length_m"] == 12.0
    assert "2/2" in proc.stderr  # the progress bar ran to the end
    assert "lockstep MAVLink" in proc.stdout
    # memory is reported per worker (after its first and its last job) and for the evaluating process
    mem = s["memory"]
    assert mem["parent_start_mb"] > 0 and mem["parent_end_mb"] > 0
    ws = mem["workers"].values()
    assert sum(w["jobs"] for w in ws) == 2 and all(w["last_mb"] > 0 for w in ws)
    assert "Memory (RSS)" in proc.stdout


def test_evaluate_cli_refuses_bad_arguments(tmp_path, capsys):
    from lab.cli import main

    for argv, key in ((["--planners", "astar"], "--planners"), (["--density", "99"], "density_per_100m2"),
                      (["--n", "0"], "--n")):
        assert main(["evaluate", *argv, "--out", str(tmp_path / "x")]) == 2, argv
        assert key in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # refused before anything was flown


def test_forest_spec_defaults_match_the_issue():
    s = ForestSpec()
    assert (s.length_m, s.r_min_m, s.r_max_m, s.density_per_100m2, s.wind_scale) == (20.0, 0.15, 0.35, 3.0, 1.0)


def _brute_clearance(npz: Path, obstacle, airframe_r_m: float, clock_t0_s: float | None) -> float:
    """The trunk's clearance over the logged rows, row by row with Obstacle.at_time (the independent reckoning)."""
    import math

    import numpy as np

    best = math.inf
    with np.load(npz) as z:
        for t, p, q in zip(z["t_s"], z["pos_ned_m"], z["payload_pos_ned_m"], strict=True):
            o = obstacle if clock_t0_s is None else obstacle.at_time(max(0.0, float(t) - clock_t0_s))
            if p[2] > -o.height_m:
                best = min(best, math.hypot(p[0] - o.x_m, p[1] - o.y_m) - o.radius_m - airframe_r_m)
            if np.isfinite(q[2]) and q[2] > -o.height_m:
                best = min(best, math.hypot(q[0] - o.x_m, q[1] - o.y_m) - o.radius_m)
    return best


def test_evaluate_and_the_flight_report_score_a_crossing_trunk_alike(tmp_path):
    """A trunk stands on the path at (5, 0) at the mission clock's zero and crosses it at 1.5 m/s, long gone when
    the vehicle gets there. evaluate's result and the flight's own report.json give the same clearance and no
    collision, and that clearance is the trunk's where it was at each logged time; at its file position the
    vehicle would have flown through it (what the report said before it placed moving trunks)."""
    from companion.config import shipped_config
    from companion.core.obstacles import Obstacle
    from lab.evaljob import run_eval_job
    from lab.runner import Job

    trunk = Obstacle(5.0, 0.0, 0.3, vy_mps=1.5)
    m = load_mission(shipped_config("missions/forest.toml")).with_(planner="shaped", obstacles=(trunk,), hold_s=1.0,
                                                                   land=False)
    out = run_eval_job(Job("crossing", m, tmp_path / "run", mode="inprocess", keep_run_dir=True))
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert out["class"] == "success" and out["collisions"] == rep["collisions"] == 0
    assert out["collisions_moving"] == rep["collisions_moving"] == 0
    assert out["min_clearance_m"] == rep["min_clearance_m"]
    airframe = m.vehicle.r_uav + m.vehicle.L_uav
    clock = rep["obstacle_clock_t0_s"]
    assert clock is not None
    npz = tmp_path / "run" / "flight_log.npz"
    assert rep["min_clearance_m"] == pytest.approx(_brute_clearance(npz, trunk, airframe, clock), abs=1e-9)
    assert _brute_clearance(npz, trunk, airframe, None) < 0.0


def test_a_flight_out_of_time_in_process_reports_timeout(tmp_path):
    # the Table 2 forest with 3 s to fly it: the in-process report's outcome is the flight core's verdict
    # ("timeout", as fly reports it), not "completed"
    from dataclasses import replace

    from lab.runner import Job, run_job

    mission = replace(load_mission(Path(__file__).parents[1] / "config" / "missions" / "forest.toml"), timeout_s=3.0)
    r = run_job(Job("short", mission, tmp_path / "run", mode="inprocess"))
    assert (r["class"], r["outcome"], r["reached_goal"], r["collisions"]) == ("stuck", "timeout", False, 0)
