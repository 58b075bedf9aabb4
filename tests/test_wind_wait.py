"""The shaped planner's waits for the wind, and a goal the wind puts within the payload's reach of a trunk
(:mod:`companion.planning.wind_wait`): it waits, then says there is no route; the report says why."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.core.model import VehicleParams
from companion.core.obstacles import Obstacle
from companion.planning import PlanInput, PlannerParams, make_planner
from companion.report.run_folder import wait_lines
from lab.envelope import Cell, cell_mission
from lab.forests import ForestSpec
from lab.runner import Job, run_job

pytestmark = pytest.mark.shares_cores  # lockstep and in-process flights: no deadline (conftest.py)

ROOT = Path(__file__).resolve().parents[1]
DT = 0.02
GOAL = (10.0, 0.0)
TRUNK = Obstacle(x_m=10.0, y_m=-1.5, radius_m=0.15, height_m=7.0)  # 1.5 m beside the goal, downwind of it


def _fly_reference(drift_ned_m, t_end_s, params=None):
    """The planner alone with a steady payload drift (m, NED x y), its reference flown perfectly; (the planner,
    [(t, pos, mode, no_route)])."""
    pl = make_planner("shaped", params or PlannerParams(), VehicleParams())
    pos, vel, out_rows = np.zeros(2), np.zeros(2), []
    for k in range(int(t_end_s / DT)):
        t = k * DT
        inp = PlanInput(t_s=t, pos_m=pos, vel_mps=vel, ref_pos_m=pos, ref_vel_mps=vel, goal_m=np.array(GOAL),
                        r_max_m=0.28, swing=np.zeros(4), cable_l_m=1.0, airframe_r_m=0.28, z_ned_m=-2.0,
                        drift_ned_m=drift_ned_m)
        out = pl.plan(inp, [TRUNK])
        pos, vel = np.array(out.reference.pos_m), np.array(out.reference.vel_mps)
        out_rows.append((t, pos.copy(), out.mode, out.no_route))
    return pl, out_rows


def test_a_goal_the_wind_holds_within_reach_of_a_trunk_is_waited_for_then_has_no_route():
    # the payload held 0.8 m toward the trunk: at the goal the wind would hold it 1.5 m that way, onto the trunk
    pl, rows = _fly_reference((0.0, -0.8), 34.0)
    t_nr = next(t for t, _p, _m, nr in rows if nr)
    assert 30.0 <= t_nr <= 31.0  # goal_wind_wait_s of waiting, from the first replan on
    assert all(m == "wait" for t, _p, m, _nr in rows if 0.1 < t < t_nr)
    f = pl.facts()
    assert f["no_route_goal_in_wind_reach"] and f["goal_in_wind_reach_s"] >= 30.0
    assert (f["trunk_x_m"], f["trunk_y_m"]) == (10.0, -1.5) and f["downwind_m"] == 1.5
    assert "the goal lay within its reach of the trunk at (10.0, -1.5)" in wait_lines(f)[0]
    # it never set off for a goal it could not hold the payload at
    assert max(np.hypot(*p) for _t, p, _m, _nr in rows) < 0.01


def test_the_same_wind_blowing_away_from_the_trunk_does_not_stop_the_flight():
    pl, rows = _fly_reference((0.0, 0.8), 12.0)
    assert np.hypot(*(rows[-1][1] - GOAL)) < 1e-6 and not any(nr for *_r, nr in rows)
    assert pl.facts()["waited_s"] == 0.0 and not pl.facts()["no_route_goal_in_wind_reach"]
    assert wait_lines(pl.facts()) == []


def test_the_summary_says_how_long_the_goal_lay_in_reach_when_a_lull_let_the_flight_through():
    waited = {"waited_s": 23.61, "goal_in_wind_reach_s": 23.6, "no_route_goal_in_wind_reach": False,
              "trunk_x_m": 19.7, "trunk_y_m": -1.68}
    assert wait_lines(waited) == ["  waited              23.6 s in all for the wind to leave a gap the payload fits; "
                                  "the goal lay within its reach of the trunk at (19.7, -1.7) for 23.6 s"]
    gap = {"waited_s": 1.2, "goal_in_wind_reach_s": 0.0, "no_route_goal_in_wind_reach": False}
    assert wait_lines(gap) == ["  waited              1.2 s in all for the wind to leave a gap the payload fits"]


def test_the_wait_for_the_goal_is_a_configured_time():
    pl, rows = _fly_reference((0.0, -0.8), 8.0, PlannerParams(goal_wind_wait_s=5.0))
    t_nr = next(t for t, _p, _m, nr in rows if nr)
    assert 5.0 <= t_nr <= 6.0 and pl.facts()["no_route_goal_in_wind_reach"]


def test_forest_73_where_gusts_hold_the_payload_on_3_m_by_the_goals_trunk_ends_no_route_and_says_why(tmp_path):
    # 0.1 kg on 3 m in moderate turbulence, its drag identified in flight: the goal is 1.7 m from a trunk downwind.
    # Before the wait had a limit the flight crept on in the lulls and stopped in every gust until its 60 s timeout.
    mis = cell_mission(Cell(0.1, 3.0, "moderate"), 73, ForestSpec(density_per_100m2=4.0, width_m=6.0),
                       drags="identified").with_(planner="shaped")
    res = run_job(Job(key="f73", mission=mis, run_dir=tmp_path / "run", mode="inprocess"))
    assert res["outcome"] == "no_route" and res["collisions"] == 0 and res["sim_time_s"] < 59.0
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["planning"]["no_route_goal_in_wind_reach"] is True
    assert (rep["planning"]["trunk_x_m"], rep["planning"]["trunk_y_m"]) == (19.7, -1.68)
    summary = (tmp_path / "run" / "summary.txt").read_text()
    assert "the goal lay within its reach of the trunk at (19.7, -1.7) for 30.0 s: no route" in summary


#: a steady 10 m/s wind across the path and a trunk 1.5 m beside the goal: 0.1 kg on 3 m hangs 0.97 m downwind
GOAL_IN_WIND = """
[mission]
name = "goal_in_wind"
start_ned_m = [0.0, 0.0, -4.5]
goal_ned_m = [10.0, 0.0, -4.5]
planner = "shaped"
controller = "smc_ff"
timeout_s = 60.0
hold_s = 2.0
land = true

[wind]
model = "turbulence"
mean_speed_mps = 10.0
direction_deg = {direction}
intensity = "none"
altitude_m = 4.5
payload_drag_area_m2 = 0.0054

[vehicle]
m = 0.1
l = 3.0

[payload]
drag_n_per_mps2 = 0.0033
airframe_drag_n_per_mps2 = 0.0245

[[obstacles]]
x_m = 10.0
y_m = -1.5
radius_m = 0.15
height_m = 7.0
"""


@pytest.mark.parametrize(("direction", "outcome", "code"), [(90.0, "no_route", 1), (270.0, "completed", 0)])
def test_fly_against_the_bundled_vehicle_holds_off_a_goal_the_wind_blows_the_payload_from_onto_a_trunk(
        tmp_path, direction, outcome, code):
    # from the east the wind holds the payload toward the trunk at the goal: the flight waits 30 s, then ends
    # no_route (exit 1) with the payload never near the trunk; from the west it flies to the goal
    mission = tmp_path / "goal_in_wind.toml"
    mission.write_text(GOAL_IN_WIND.format(direction=direction))
    r = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--mission", str(mission),
                        "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(tmp_path / "run")],
                       capture_output=True, text=True, timeout=240, cwd=ROOT)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert (r.returncode, rep["outcome"], rep["collisions"]) == (code, outcome, 0), r.stderr[-2000:]
    assert rep["planning"]["no_route_goal_in_wind_reach"] is (outcome == "no_route")
    if outcome == "no_route":
        assert rep["planning"]["goal_in_wind_reach_s"] >= 30.0 and rep["min_clearance_m"] > 5.0
        assert "no route" in (tmp_path / "run" / "summary.txt").read_text()
