"""lab.experiments: generated disagreement sentences from numbers; ``--quick`` end to end over MAVLink."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from lab.experiments import findings, report_markdown

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)


def _row(**kw) -> dict:
    r = {"class": "success", "reached_goal": True, "time_to_goal_s": 10.0, "max_swing_rad": 0.2,
         "swing_settle_s": 5.0, "swing_settle_after_arrival_s": 2.0, "path_length_m": 11.0, "collisions": 0,
         "min_clearance_m": 0.3, "mission_file": "m.toml", "run_dir": "r", "error": None}
    r.update(kw)
    return r


def _groups(**g2_changes):
    g1 = {"pid": _row(), "smc": _row(swing_settle_after_arrival_s=None, swing_settle_s=None, max_swing_rad=0.39),
          "smc_ff": _row(swing_settle_s=4.0, swing_settle_after_arrival_s=1.5)}
    g2 = {"traditional": _row(time_to_goal_s=13.5, swing_settle_s=18.0, path_length_m=14.0),
          "improved": _row(time_to_goal_s=10.3, max_swing_rad=0.25, swing_settle_s=12.0),
          "safe": _row(time_to_goal_s=6.5, max_swing_rad=0.22),
          "shaped": _row(time_to_goal_s=5.9, max_swing_rad=0.19)}
    for k, v in g2_changes.items():
        g2[k] = _row(**{**g2[k], **v})
    return g1, g2


def test_agreement_gives_no_disagreement_sentences():
    g1, g2 = _groups()
    g1["smc"] = _row(swing_settle_after_arrival_s=3.0)
    fs = findings(g1, g2)
    assert not [f for f in fs if "exceeds" in f or "touches" in f or "misses" in f or "slower" in f]
    assert any("damps the swing, as the paper says" in f for f in fs)
    assert any("shorter than `traditional`" in f for f in fs)


def test_disagreements_are_spelled_out_with_the_numbers():
    g1, g2 = _groups(improved={"collisions": 2, "min_clearance_m": -0.104, "path_length_m": 15.0,
                               "max_swing_rad": 0.337, "time_to_goal_s": 7.7},
                     safe={"time_to_goal_s": 7.4}, shaped={"max_swing_rad": 0.21})
    fs = "\n".join(findings(g1, g2))
    assert "`improved`: touches 2 obstacle(s), min clearance -0.104 m" in fs
    assert "max swing 0.337 rad exceeds the paper (Fig. 9) bound of 0.3 rad" in fs
    assert "reaches the goal in 7.70 s, faster than the paper's ≈10 s" in fs
    assert "path 15.00 m is not shorter than `traditional`'s 14.00 m" in fs
    assert "`safe`: time to goal 7.40 s misses the issue 5 target (ours) of <= 7 s" in fs
    assert "`shaped`: max swing 0.210 rad exceeds the issue 12 target (ours) bound of 0.2 rad" in fs
    assert "without feed-forward (`smc`) the swing never settles" in fs


def test_report_has_both_tables_and_every_row():
    g1, g2 = _groups()
    md = report_markdown({"quick": True, "wall_s": 1.0, "group1": g1, "group2": g2, "findings": findings(g1, g2)})
    assert "## Group 1" in md and "## Group 2" in md
    for name in ("pid", "smc", "smc_ff", "traditional", "improved", "safe", "shaped"):
        assert f"| {name} | yes |" in md


@pytest.mark.slow
def test_experiments_quick_over_mavlink(tmp_path):
    out = tmp_path / "exp"
    proc = subprocess.run([sys.executable, "-m", "lab", "experiments", "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    md = (out / "report.md").read_text()
    res = json.loads((out / "experiments.json").read_text())
    assert set(res["group1"]) == {"pid", "smc", "smc_ff"}
    assert set(res["group2"]) == {"traditional", "improved", "safe", "shaped"}
    assert set(res["group3"]) == {"estimate_imu"}  # --quick: the sensorless estimate (the sensor is Group 2's safe)
    est = res["group3"]["estimate_imu"]["swing_estimation_error"]
    assert est["ticks"] > 1000 and est["rms_rad"] < 0.1  # scored against the cable sensor's truth
    assert "## Group 3" in md and "| estimate_imu | yes |" in md
    for group in ("group1", "group2", "group3"):
        for name, r in res[group].items():
            assert r["class"] != "error", (name, r["error"])
            assert isinstance(r["reached_goal"], bool) and r["collisions"] >= 0
            assert f"| {name} | " in md
            assert (tmp_path / "exp" / "runs" / f"{group}-{name}" / "flight.tlog").stat().st_size > 0  # real MAVLink
    for fig in ("group1_swing", "group1_position", "group1_3d", "group2_plan", "group2_swing", "group2_3d",
                "group3_estimate"):
        p = out / f"{fig}.png"
        assert p.stat().st_size > 5_000, fig
        assert f"({fig}.png)" in md
    assert "## Where we disagree with the paper" in md
    assert res["findings"] and all(f in md for f in res["findings"])
