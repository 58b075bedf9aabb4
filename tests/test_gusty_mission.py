"""The shipped ``forest_gusty`` mission (issue 28): the Table 2 forest in moderate turbulence across the path, a
payload whose drag nobody declared, flown by ``fly --sitl`` against the bundled vehicle in lockstep. The report
says what the companion knew and learnt: the lift-off it leaned for at the provisional cap, the drag declared,
identified (or why not) and the world's own. Deterministic: lockstep, a seeded wind."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.report.run_folder import drag_lines

pytestmark = pytest.mark.shares_cores  # a lockstep flight: no deadline (conftest.py)

ROOT = Path(__file__).resolve().parents[1]


def test_the_gusty_forest_is_flown_clean_and_calmer_than_a_payload_held_still(tmp_path):
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--mission", "forest_gusty",
                        "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(run)],
                       capture_output=True, text=True, timeout=240, cwd=ROOT)
    rep = json.loads((run / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["collisions"] == 0, r.stderr[-2000:]
    assert rep["wind"]["model"] == "turbulence" and rep["wind"]["intensity"] == "moderate"
    # the bound of issue 28 in moderate turbulence, and below what the wind alone does to a payload held still
    assert rep["max_swing_rad"] < 0.35 and rep["max_swing_rad"] < rep["wind_truth"]["held_swing_max_rad"]
    # the planner's own facts reach the report over MAVLink too: its searches, and no goal the wind held in reach
    assert rep["planning"]["searches"] > 0 and rep["planning"]["no_route_goal_in_wind_reach"] is False
    lift = rep["lift_off"]
    assert lift["armed"] and not lift["payload_drag_declared"] and lift["lean_m"] > 0.05
    drag = rep["payload_drag"]
    assert drag["declared_n_per_mps2"] is None
    assert (drag["identified_n_per_mps2"] is None) != (drag["identified_detail"] is None)
    summary = (run / "summary.txt").read_text()
    assert "payload drag        declared —, " in summary and ", world 0.0061 N per (m/s)²" in summary
    # the ratio of the payload's drag angle to the airframe's push: within 15 % of the world's 0.0061
    assert drag["from_push_n_per_mps2"] == pytest.approx(0.5 * 1.225 * 0.01, rel=0.15)
    assert "to lift it at the angle of half the cap's drag" in summary


def test_the_drag_line_is_left_out_when_there_is_nothing_to_say():
    none = {"declared_n_per_mps2": None, "identified_n_per_mps2": None, "identified_detail": "too little"}
    assert drag_lines(none, {"model": "paper"}) == [] and drag_lines(None, None) == []
    known = drag_lines(none | {"declared_n_per_mps2": 0.0061}, None)
    assert known == ["  payload drag        declared 0.0061 N per (m/s)²; not identified: too little"]
    fit = {"declared_n_per_mps2": None, "identified_n_per_mps2": 0.0049, "identified_detail": None,
           "from_push_n_per_mps2": 0.0058}
    world = {"model": "turbulence", "payload_drag_area_m2": 0.01, "air_density_kgpm3": 1.225}
    assert drag_lines(fit, world) == ["  payload drag        declared —, identified 0.0049, from the push 0.0058, "
                                      "world 0.0061 N per (m/s)²"]
