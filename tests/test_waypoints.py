"""Multi-leg missions (issue 27): the waypoint and fence tables of a mission file and each refusal, the legs as the
flight core flies them (goal sequence, pass-through without stopping, holds), the fence kept with the swing
envelope, the per-waypoint report, and forest_waypoints flown over MAVLink through the bundled vehicle."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.core.fence import Fence, FenceCircle, FencePolygon
from companion.core.mission import MAX_WAYPOINTS, Mission, Waypoint, load_mission, mission_to_toml
from companion.errors import ConfigError
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from companion.planning.fence_guard import fence_margin_m, fence_obstacles
from companion.report.metrics import compute_metrics
from companion.report.run_folder import waypoint_lines
from lab.inprocess import fly_inprocess

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

ROOT = Path(__file__).resolve().parents[1]
FOREST_WP = ROOT / "config" / "missions" / "forest_waypoints.toml"

HEAD = """
[mission]
name = "t"
start_ned_m = [0.0, 0.0, -2.0]
goal_ned_m = [10.0, 0.0, -2.0]
planner = "safe"
controller = "smc_ff"
timeout_s = 40.0
hold_s = 1.0
[[obstacles]]
x_m = 5.0
y_m = 2.0
radius_m = 0.3
height_m = 4.0
safe_distance_m = 0.1
"""
WP = "\n[[waypoints]]\nned_m = [4.0, -2.0, -2.0]\n"


def _load(tmp_path, text: str) -> Mission:
    p = tmp_path / "m.toml"
    p.write_text(text)
    return load_mission(p)


# ------------------------------------------------------------------------------------------------ the file
def test_forest_waypoints_loads_and_round_trips(tmp_path):
    m = load_mission(FOREST_WP)
    assert len(m.obstacles) == 5 and len(m.waypoints) == 3 and m.fence is None
    assert [w.hold_s for w in m.waypoints] == [0.0, 2.0, 0.0]
    assert m.waypoints[2].speed_max_mps == 1.5 and m.waypoints[1].name == "clearing"
    fenced = m.with_(fence=Fence(circles=(FenceCircle((5.0, -3.0), 1.0, False),)))
    back = _load(tmp_path, mission_to_toml(fenced))
    assert back.fence == fenced.fence
    for a, b in zip(back.waypoints, m.waypoints, strict=True):
        assert np.array_equal(a.pos_ned_m, b.pos_ned_m) and (a.hold_s, a.speed_max_mps, a.name) == (
            b.hold_s, b.speed_max_mps, b.name)


def test_waypoints_and_fence_parse(tmp_path):
    m = _load(tmp_path, HEAD + WP + 'hold_s = 2.5\nspeed_max_mps = 1.0\nname = "a"\n' + """
[[fence.polygons]]
vertices_ne_m = [[-3.0, -5.0], [13.0, -5.0], [13.0, 5.0], [-3.0, 5.0]]
inclusion = true
[[fence.circles]]
center_ne_m = [7.0, -3.0]
radius_m = 0.5
inclusion = false
""")
    w = m.waypoints[0]
    assert np.array_equal(w.pos_ned_m, [4.0, -2.0, -2.0]) and (w.hold_s, w.speed_max_mps, w.name) == (2.5, 1.0, "a")
    assert m.fence is not None and m.fence.polygons[0].inclusion and not m.fence.circles[0].inclusion
    assert _load(tmp_path, HEAD).waypoints == () and _load(tmp_path, HEAD).fence is None


@pytest.mark.parametrize("extra, match", [
    (WP + "speed = 2.0\n", r"\[\[waypoints\]\] #0: unknown key 'speed'"),
    ("\n[[waypoints]]\nhold_s = 1.0\n", r"\[\[waypoints\]\] #0: missing required key 'ned_m'"),
    ("\n[[waypoints]]\nned_m = [4.0, nan, -2.0]\n", r"\[\[waypoints\]\] #0 ned_m: must be finite"),
    ("\n[[waypoints]]\nned_m = [4.0, 1.0, 0.5]\n", r"\[\[waypoints\]\] #0 ned_m: z = 0.5 m is below the ground"),
    ("\n[[waypoints]]\nned_m = [4.0, 1.0]\n", r"\[\[waypoints\]\] #0 ned_m: expected"),
    (WP + "\n[[waypoints]]\nned_m = [5.0, 1.7, -2.0]\n",
     r"\[\[waypoints\]\] #1 ned_m: \(5, 1.7\) is 0.300 m from obstacle 0"),
    (WP + "hold_s = -1.0\n", r"\[\[waypoints\]\] #0 hold_s: must be in \[0, 600\]"),
    (WP + "speed_max_mps = 0.0\n", r"\[\[waypoints\]\] #0 speed_max_mps: must be in \(0, 20\]"),
    (WP + "hold_s = inf\n", r"\[\[waypoints\]\] #0 hold_s: must be finite"),
    ("\n[waypoints]\nned_m = [4.0, 1.0, -2.0]\n", r"waypoints: expected an array of tables"),
    ("\n[[fence.polygons]]\nvertices_ne_m = [[0.0, 0.0], [1.0, 0.0]]\ninclusion = true\n",
     r"\[\[fence.polygons\]\] #0 vertices_ne_m: expected 3 to"),
    ("\n[[fence.polygons]]\nvertices_ne_m = [[0.0, 0.0], [1.0, nan], [1.0, 1.0]]\ninclusion = true\n",
     r"\[\[fence.polygons\]\] #0 vertices_ne_m: expected a finite"),
    ("\n[[fence.circles]]\ncenter_ne_m = [5.0, 0.0]\nradius_m = 1.0\n",
     r"\[\[fence.circles\]\] #0 inclusion: required"),
    ("\n[[fence.circles]]\ncenter_ne_m = [5.0, 0.0]\nradius_m = -1.0\ninclusion = false\n",
     r"\[\[fence.circles\]\] #0 radius_m"),
    ("\n[[fence.circles]]\ncenter_ne_m = [5.0, 0.0]\nradius_m = 1.0\ninclusion = false\nheight_m = 3.0\n",
     r"\[\[fence.circles\]\] #0: unknown key 'height_m'"),
    ("\n[fence]\nlines = []\n", r"\[fence\]: unknown key 'lines'"),
    ("\n[[fence.polygons]]\nvertices_ne_m = [[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]\ninclusion = false\n",
     r"\[\[fence.polygons\]\] #0 vertices_ne_m: self-intersecting"),
    ("\n[[fence.circles]]\ncenter_ne_m = [10.0, 0.5]\nradius_m = 0.4\ninclusion = false\n",
     r"goal_ned_m \(10.00, 0.00\) m is within the margin of the fence's exclusion circle 0"),
    ("\n[[fence.circles]]\ncenter_ne_m = [0.0, 0.0]\nradius_m = 1.0\ninclusion = false\n",
     r"\[mission\] start_ned_m \(0.00, 0.00\) m is inside the fence's exclusion circle 0"),
    ("\n[[fence.circles]]\ncenter_ne_m = [0.0, 0.0]\nradius_m = 5.0\ninclusion = true\n",
     r"\[mission\] goal_ned_m \(10.00, 0.00\) m is outside the fence's inclusion circle 0"),
    (WP + "\n[[fence.polygons]]\nvertices_ne_m = [[3.0, -3.0], [5.0, -3.0], [4.0, -1.0]]\ninclusion = false\n",
     r"\[\[waypoints\]\] #0 ned_m \(4.00, -2.00\) m is inside the fence's exclusion polygon 0"),
])
def test_bad_waypoints_and_fences_are_refused_naming_file_table_and_key(tmp_path, extra, match):
    with pytest.raises(ConfigError, match=match) as e:
        _load(tmp_path, HEAD + extra)
    assert str(e.value).startswith(str(tmp_path / "m.toml"))


def test_too_many_waypoints_are_refused(tmp_path):
    rows = "".join(f"\n[[waypoints]]\nned_m = [{1.0 + k * 1e-3}, -3.0, -2.0]\n" for k in range(MAX_WAYPOINTS + 1))
    n = MAX_WAYPOINTS + 1
    with pytest.raises(ConfigError, match=rf"\[\[waypoints\]\]: {n} waypoints, at most {MAX_WAYPOINTS}"):
        _load(tmp_path, HEAD + rows)
    assert len(_load(tmp_path, HEAD + rows.rsplit("\n[[waypoints]]", 1)[0]).waypoints) == MAX_WAYPOINTS


# ------------------------------------------------------------------------------------------------ the flight core
def _est(t, pos):
    return Estimate(t, np.array(pos, float), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(4), "cable_sensor")


def _square(planner="safe", hold_s=0.0):
    """Start (0, 0), pass (6, 0), turn left to (6, 6) (held ``hold_s``), goal (0, 6): no trunks."""
    return Mission("sq", np.array([0.0, 0.0, -2.0]), np.array([0.0, 6.0, -2.0]), planner, "smc_ff", 60.0,
                   hold_s=1.0, waypoints=(Waypoint(np.array([6.0, 0.0, -2.0]), name="a"),
                                          Waypoint(np.array([6.0, 6.0, -2.0]), hold_s=hold_s, name="b")))


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_the_planner_is_given_the_waypoints_in_order(planner):
    core = FlightCore(_square(planner, hold_s=1.0))
    core.update(_est(0.0, [0.0, 0.0, -2.0]))
    assert core.phase == "cruise" and core.legs.index == 0
    # a pass-through waypoint is passed within the radius, without a dwell; the hold waypoint needs the dwell
    core.update(_est(0.1, [5.6, 0.1, -2.0]))
    assert core.legs.index == 1 and core.legs.reached_t_s[0] == 0.1
    core.update(_est(0.2, [6.0, 5.95, -2.0]))
    core.update(_est(0.4, [6.0, 5.97, -2.0]))
    assert core.legs.index == 1 and not core.legs.holding  # within the tolerance, not yet for the dwell time
    core.update(_est(0.55, [6.0, 5.98, -2.0]))
    assert core.legs.holding and core.legs.reached_t_s[1] == 0.2 and core.phase == "cruise"
    core.update(_est(1.1, [6.0, 6.0, -2.0]))
    assert core.legs.index == 1  # hold_s = 1 s from the arrival at 0.2 s
    core.update(_est(1.25, [6.0, 6.0, -2.0]))
    assert core.legs.at_goal and core.phase == "cruise"
    core.update(_est(1.3, [0.0, 5.95, -2.0]))
    core.update(_est(1.7, [0.0, 5.97, -2.0]))
    assert core.phase == "hold"  # the goal's own rule as before
    assert [f["name"] for f in core.legs.facts()] == ["a", "b"]


def test_a_waypoint_a_timed_plan_flew_past_counts_even_with_the_vehicle_off():
    from companion.flight.legs import Legs

    legs = Legs(_square("shaped"), 2.0)
    far = _est(1.0, [4.0, -1.3, -2.0])  # 2.4 m from "a" (6, 0): neither rule of the vehicle's holds
    assert not legs.update(far) and legs.index == 0
    assert not legs.update(far, (5.6, -0.3)) and legs.index == 0  # the plan is not beyond it yet
    assert legs.update(far, (6.3, 0.5)) and legs.index == 1 and legs.reached_t_s[0] == 1.0


def test_a_mission_without_waypoints_has_no_legs():
    m = _square().with_(waypoints=())
    assert FlightCore(m).legs is None


def _speeds(log):
    t, v = log.arr("t"), log.arr("vel")
    return t, np.hypot(v[:, 0], v[:, 1])


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_pass_through_keeps_speed_and_a_hold_stops(planner):
    m = _square(planner, hold_s=2.0)
    log = fly_inprocess(m)
    rep = compute_metrics(log, m)
    wps = rep["waypoints"]
    assert [w["name"] for w in wps] == ["a", "b", "goal"] and all(w["reached_at_s"] is not None for w in wps)
    assert wps[0]["reached_at_s"] < wps[1]["reached_at_s"] < wps[2]["reached_at_s"]
    t, sp = _speeds(log)
    t0 = float(t[np.flatnonzero(np.array(log.phase) == "cruise")[0]])
    i_a = int(np.searchsorted(t, t0 + wps[0]["reached_at_s"]))
    cruise = float(np.max(sp[:i_a]))
    assert sp[i_a] > 0.5 * cruise, (sp[i_a], cruise)  # the corner is turned, not stopped at
    assert float(np.min(sp[i_a - 125:i_a + 125])) > 0.5 * cruise  # within 0.5 s either side
    # the hold: hovering at the waypoint for hold_s from the arrival (damping the swing: the airframe moves a little)
    i_b = int(np.searchsorted(t, t0 + wps[1]["reached_at_s"]))
    # from first within 0.1 m: braking the last few cm takes ~0.5 s, then still until hold_s = 2 s is over
    hold = slice(i_b + 125, i_b + 500)
    pos = log.arr("pos")[hold]
    assert float(np.max(np.hypot(pos[:, 0] - 6.0, pos[:, 1] - 6.0))) < 0.2
    assert float(np.max(sp[hold])) < 0.2  # hovering (the anti-swing control moves the airframe a little)
    assert float(np.max(sp[i_b + 600:i_b + 850])) > 0.5  # and then it leaves
    assert rep["reached_goal"] and rep["collisions"] == 0


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_a_legs_speed_limit_is_kept(planner):
    m = _square(planner).with_(waypoints=(Waypoint(np.array([6.0, 0.0, -2.0]), speed_max_mps=0.8, name="slow"),))
    log = fly_inprocess(m)
    t, sp = _speeds(log)
    rv = log.arr("ref_vel")
    ref_sp = np.hypot(rv[:, 0], rv[:, 1])
    rep = compute_metrics(log, m)
    t0 = float(t[np.flatnonzero(np.array(log.phase) == "cruise")[0]])
    i_a = int(np.searchsorted(t, t0 + rep["waypoints"][0]["reached_at_s"]))
    # the reference keeps the limit (shaped: up to its profile's discretisation); the airframe swings about it
    assert float(np.max(ref_sp[:i_a])) <= 0.8 * 1.05 and float(np.max(sp[:i_a])) < 0.8 * 1.3
    assert float(np.max(sp[i_a:])) > 1.5  # the next leg is not limited
    assert rep["reached_goal"]


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_a_pass_through_waypoint_is_a_horizontal_gate_its_altitude_the_legs(planner):
    up = Waypoint(np.array([6.0, 0.0, -4.0]), name="up")  # 2 m above the start and the goal
    m = _square(planner).with_(waypoints=(up,))
    log = fly_inprocess(m)
    rep = compute_metrics(log, m)
    assert rep["reached_goal"] and rep["waypoints"][0]["reached_at_s"] is not None
    t, pos = log.arr("t"), log.arr("pos")
    t0 = float(t[np.flatnonzero(np.array(log.phase) == "cruise")[0]])
    i_up = int(np.searchsorted(t, t0 + rep["waypoints"][0]["reached_at_s"]))
    assert pos[i_up, 2] < -3.0 and float(np.min(pos[:, 2])) > -4.3  # climbing towards it, not waiting there


def test_a_flight_that_ends_before_its_waypoints_reports_them_never_reached():
    m = _square("safe").with_(timeout_s=4.0)  # climb ~2.5 s, then 1.5 s towards the first waypoint
    rep = compute_metrics(fly_inprocess(m), m)
    assert [w["name"] for w in rep["waypoints"]] == ["a", "b", "goal"]
    assert all(w["reached_at_s"] is None for w in rep["waypoints"]) and not rep["reached_goal"]
    first, *rest = rep["waypoints"]
    assert first["closest_m"] > 0.6 and first["leg_max_swing_rad"] is not None  # the leg it was flying
    assert all(w["closest_m"] is None and w["leg_max_swing_rad"] is None for w in rest)  # legs never flown
    assert "reached never" in "\n".join(waypoint_lines(rep))


# ------------------------------------------------------------------------------------------------ shaped's path
def test_shaped_plans_one_path_through_the_waypoints_each_leg_under_its_cap():
    from companion.planning.legs_route import PIN_M, remaining_vias, timed_through
    from companion.planning.params import PlannerParams

    c = np.array([[3.0, 0.2], [6.0, 3.0]])
    ring = np.array([0.9, 0.9])
    vias = (np.array([6.0, 0.0]), np.array([6.0, 6.0]))
    cands = timed_through(np.zeros(2), np.zeros(2), vias, (math.inf, 1.0, math.inf), np.array([0.0, 6.0]),
                          c, ring, ring, 1.85, PlannerParams(), [0.0, 0.2])
    assert cands
    prof, _ = cands[0]
    t = np.arange(0.0, prof.duration_s, 0.01)
    from companion.planning.timing import sample_motion
    pos, vel, _acc = sample_motion(prof, t)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    near = [int(np.argmin(np.hypot(*(pos - v).T))) for v in vias]
    for k, v in zip(near, vias, strict=True):
        assert float(np.hypot(*(pos[k] - v))) < PIN_M + 0.1  # through each waypoint, the corner cut a little
        assert speed[k] > 0.3  # and not stopped there
    assert near[0] < near[1]
    assert float(np.max(speed[near[0] + 20:near[1] - 20])) <= 1.03  # the middle leg's limit (3 %: stations 0.1 m apart)
    assert float(np.max(speed[:near[0] - 50])) > 1.5 and float(np.max(speed[near[1] + 50:])) > 1.3
    assert float(np.min(np.hypot(pos[:, None, 0] - c[None, :, 0], pos[:, None, 1] - c[None, :, 1]) - ring)) > -0.05
    # a waypoint the plan state is already beyond is dropped from the next search (with its leg's cap)
    assert remaining_vias(np.array([6.5, 0.4]), vias, np.array([0.0, 6.0]), (2.0, 1.0, 3.0)) == ((vias[1],), (1.0, 3.0))
    assert remaining_vias(np.array([5.0, 0.0]), vias, np.array([0.0, 6.0]), ())[0] == vias


# ------------------------------------------------------------------------------------------------ the fence
def _fenced(planner: str) -> Mission:
    box = FencePolygon(((-3.0, -4.0), (13.0, -4.0), (13.0, 4.0), (-3.0, 4.0)), True)  # walls 0.5 m into it
    fence = Fence(polygons=(box,), circles=(FenceCircle((5.0, 0.3), 1.0, False),))
    return Mission("fence", np.array([0.0, 0.0, -2.0]), np.array([10.0, 0.0, -2.0]), planner, "smc_ff", 40.0,
                   hold_s=1.0, fence=fence)


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_an_exclusion_circle_on_the_straight_line_is_flown_around_inside_the_fence_envelope_included(planner):
    m = _fenced(planner)
    log = fly_inprocess(m)
    rep = compute_metrics(log, m)
    assert rep["reached_goal"] and rep["fence"]["breaches"] == 0
    pos, pay = log.arr("pos"), log.arr("payload_pos")
    vp = m.vehicle
    assert float(np.min(fence_margin_m(m.fence, pos[:, :2]))) > vp.r_uav + vp.L_uav  # the airframe's circle
    ok = np.all(np.isfinite(pay), axis=1)
    assert ok.sum() > 1000 and float(np.min(fence_margin_m(m.fence, pay[ok, :2]))) > 0.0  # the payload
    assert rep["fence"]["min_margin_airframe_m"] > 0.0 and rep["fence"]["min_margin_payload_m"] > 0.0
    assert float(np.max(np.abs(pos[:, 1]))) > 1.0  # it went around, not through


def test_fence_zones_become_keep_out_discs_that_cover_their_boundary():
    square = ((0.0, 0.0), (20.0, 0.0), (20.0, 10.0), (0.0, 10.0))
    for inclusion in (True, False):
        obs = fence_obstacles(Fence(polygons=(FencePolygon(square, inclusion),)))
        edge = np.array([(x, 0.0) for x in np.linspace(0.0, 20.0, 81)] + [(20.0, y) for y in np.linspace(0, 10, 41)])
        d = np.min(np.hypot(edge[:, None, 0] - np.array([o.x_m for o in obs])[None, :],
                            edge[:, None, 1] - np.array([o.y_m for o in obs])[None, :])
                   - np.array([o.radius_m for o in obs])[None, :], axis=1)
        assert float(np.max(d)) <= 0.0  # every boundary point is inside a disc
        centre_in = fence_margin_m(Fence(polygons=(FencePolygon(square, True),)),
                                   np.array([(o.x_m, o.y_m) for o in obs]))
        assert np.all(centre_in < 0.0) if inclusion else np.all(np.abs(centre_in) < 1e-9)
    assert fence_obstacles(None) == ()
    assert math.isinf(fence_margin_m(None, np.zeros((1, 2)))[0])


# ------------------------------------------------------------------------------------------------ over MAVLink
@pytest.mark.slow
@pytest.mark.parametrize("planner", ["shaped", "safe"])
def test_forest_waypoints_flies_over_mavlink_in_lockstep(tmp_path, planner):
    proc = subprocess.run([sys.executable, "-m", "companion.cli.main", "fly", "--sitl", "--no-zenoh", "--mission",
                           str(FOREST_WP), "--planner", planner, "--run-dir", str(tmp_path)],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["reached_goal"] and rep["collisions"] == 0
    wps = rep["waypoints"]
    assert [w["name"] for w in wps] == ["north-west gap", "clearing", "east gap", "goal"]
    times = [w["reached_at_s"] for w in wps]
    assert None not in times and times == sorted(times)
    assert all(w["leg_max_swing_rad"] is not None and w["leg_min_clearance_m"] > 0.0 for w in wps)
    flown = rep["waypoints_flown"]  # the flight core's own record, in vehicle time
    assert [f["name"] for f in flown] == ["north-west gap", "clearing", "east gap"]
    assert all(f["reached_t_s"] is not None for f in flown)
    summary = (tmp_path / "summary.txt").read_text()
    for line in waypoint_lines(rep):
        assert line in summary
    assert "waypoint 2 clearing" in summary and (tmp_path / "plan.png").stat().st_size > 10_000
