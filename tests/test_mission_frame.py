"""Mission coordinates are relative to home (issue 10): a vehicle far from the mission's start is refused with a
clear reason, and ``--start-here`` flies the mission from where the vehicle stands."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

ROOT = Path(__file__).resolve().parents[1]


def _mission(tmp: Path) -> Path:
    text = (ROOT / "config" / "missions" / "open_field.toml").read_text()
    text = text.replace("start_ned_m = [0.0, 0.0, -2.0]", "start_ned_m = [5.0, 3.0, -2.0]")
    text = text.replace("goal_ned_m = [10.0, 0.0, -2.0]", "goal_ned_m = [9.0, 3.0, -2.0]")
    f = tmp / "elsewhere.toml"
    f.write_text(text.replace('name = "open_field"', 'name = "elsewhere"'))
    return f


def _fly(tmp: Path, *extra: str) -> tuple[subprocess.CompletedProcess, dict]:
    run = tmp / ("run" + "".join(extra).replace("-", "_"))
    out = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                          "--mission", str(_mission(tmp)), "--run-dir", str(run), *extra],
                         capture_output=True, text=True, timeout=240, cwd=ROOT)
    return out, json.loads((run / "report.json").read_text())


@pytest.mark.slow
def test_a_vehicle_far_from_the_start_is_refused_before_arming(tmp_path):
    out, rep = _fly(tmp_path)
    assert out.returncode == 4, out.stderr[-2000:]
    assert rep["outcome"] == "refused" and "5.8 m from the mission's start" in rep["outcome_detail"]
    assert "--start-here" in out.stderr
    assert "arm" not in [t["to"] for t in rep["transitions"]]


@pytest.mark.slow
def test_start_here_moves_the_mission_under_the_vehicle(tmp_path):
    out, rep = _fly(tmp_path, "--start-here")
    assert out.returncode == 0, out.stderr[-2000:]
    assert rep["mission_frame"]["origin"] == "start-here"
    assert rep["mission_frame"]["origin_local_ned_m"][:2] == [-5.0, -3.0]
    pos = np.load(Path(rep["run_dir"]) / "flight_log.npz")["pos_ned_m"]
    assert abs(pos[0, 0] - 5.0) < 0.05 and abs(pos[0, 1] - 3.0) < 0.05  # logged in the mission frame


def test_a_pinned_frame_stays_where_the_mission_was_placed():
    """``fly --mission autopilot``: north and east are the download's home however home moves after it (PX4 SIH
    moved it 0.27-2.2 m while its estimator settled), heights follow home; the start is still checked against the
    home the autopilot reports."""
    from companion.flight.mission_frame import MissionFrame
    from companion.flight.phase import State

    frame = MissionFrame(np.array([0.0, 0.0, -2.0]), False, (1.0, 2.0, 0.5))
    moved_home = np.array([2.5, 2.0, 0.4])
    assert frame.update(np.array([2.5, 2.0, 0.4]), moved_home, True, State.WAIT_READY) == 0.0  # at its home
    assert frame.update(np.array([2.5, 2.0, 0.4]), moved_home, True, State.PRESTREAM) == 0.0
    assert frame.fixed and frame.origin_ned_m.tolist() == [1.0, 2.0, 0.4]  # heights above the home now
    frame.update(np.array([2.5, 2.0, 0.4]), np.array([5.0, 5.0, 0.0]), True, State.MISSION)
    assert frame.origin_ned_m.tolist() == [1.0, 2.0, 0.4]  # fixed
    assert frame.facts() == {"origin_local_ned_m": [1.0, 2.0, 0.4], "origin": "home at the mission's download",
                             "home_at_fix_local_ned_m": [2.5, 2.0, 0.4]}
    follows = MissionFrame(np.array([0.0, 0.0, -2.0]), False)  # a file mission's frame follows home, as before
    follows.update(None, moved_home, True, State.PRESTREAM)
    assert follows.origin_ned_m.tolist() == moved_home.tolist() and "home_at_fix_local_ned_m" not in follows.facts()
