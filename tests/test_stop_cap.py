"""The speed cap inside the space seen free (issue 26): the formula, a wall of unseen space stopped short of with
the in-process physics (safe and shaped), and a blind lockstep flight past a trunk hidden behind another (slow)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from companion.autopilots.profile import VehicleProfile
from companion.control import ControllerConfig
from companion.core.mission import Mission
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from companion.planning.stop_cap import SeenFree, stop_cap_mps
from sim_bridge.physics import VehicleSim

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

WALL_M = 5.0  # the scan saw free this far ahead of the start, and nothing beyond (m)


def test_cap_formula():
    assert stop_cap_mps(None, 0.0, 0.0, 1.0, 0.5, 1.8) == math.inf
    seen = SeenFree(0.0, 0.0, 0.0, 5.0, 0.0)
    # 5 m free, flown 1 m, margin 1 m, 2 m/s for 0.2 s: 2.6 m left at 1.8 m/s²
    assert stop_cap_mps(seen, 1.0, 0.0, 2.0, 1.0, 1.8) == pytest.approx(math.sqrt(2 * 1.8 * 2.6))
    # the distance flown counts whatever its direction; at the margin the cap is 0
    assert stop_cap_mps(seen, 0.0, 1.0, 2.0, 1.0, 1.8) == pytest.approx(math.sqrt(2 * 1.8 * 2.6))
    assert stop_cap_mps(seen, 4.0, 0.0, 0.0, 1.0, 1.8) == 0.0


def _fly(planner: str, seen: SeenFree | None, seconds: float = 14.0) -> tuple[np.ndarray, np.ndarray, FlightCore]:
    """Fly start (0, 0) → goal (12, 0) at 2 m in-process with the cable sensor; the core's seen-free space fixed to
    ``seen`` (never refreshed: nothing beyond it is ever seen). Returns airframe and payload positions (n, 3)."""
    mission = Mission("wall", np.array([0.0, 0.0, -2.0]), np.array([12.0, 0.0, -2.0]), planner, "smc_ff", 30.0,
                      obstacles=(), hold_s=1.0)
    sim = VehicleSim(mission.vehicle, wind=mission.wind, dt_s=1e-3, x0=np.zeros(16))
    sim.armed = True
    core = FlightCore(mission, ControllerConfig(), VehicleProfile(), period_s=0.004)
    core.cap.seen = seen
    pos, pay = [], []
    while sim.t_s < seconds:
        est = Estimate(t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
                       rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=sim.swing, swing_source="cable_sensor")
        cmd = core.update(est, ())
        sim.set_attitude_target(cmd.q_ned_frd_wxyz, cmd.thrust_n)
        sim.step(4)
        pos.append(np.array(sim.pos_ned_m))
        pay.append(np.array(sim.payload_pos_ned_m))
    return np.array(pos), np.array(pay), core


@pytest.mark.parametrize("planner", ["safe", "shaped"])
def test_a_wall_of_unseen_space_is_stopped_short_of(planner):
    pos, pay, core = _fly(planner, SeenFree(0.0, 0.0, 0.0, WALL_M, 0.0))
    airframe_r = core.params.r_uav + core.params.L_uav
    # the airframe's circle and the payload stay inside the space seen free, and the vehicle got well on its way
    assert pos[:, 0].max() + airframe_r <= WALL_M
    assert pay[:, 0].max() <= WALL_M
    assert pos[:, 0].max() >= 2.0
    assert float(np.hypot(*pos[-1, :2]) - np.hypot(*pos[-200, :2])) < 0.05  # it stands there (last 0.8 s)
    # without the cap the same flight goes straight through where the wall of unseen space was
    free, _, _ = _fly(planner, None, seconds=9.0)
    assert free[:, 0].max() > WALL_M + 1.0


@pytest.mark.slow
@pytest.mark.parametrize("planner", ["shaped", "safe"])
def test_blind_flight_past_a_trunk_hidden_behind_another(tmp_path, planner):
    """From the start, the trunk at (6.5, 0.25) hides entirely behind the one at (4, 0) (0.3 m radius at 4 m covers
    ±4.3°, the hidden one is at 2.2° ± 2.6°): it is seen only once the vehicle swerves past the first. The blind
    flight (forest_blind: start (0, 0), goal (10, 0)) must stay clean and map it."""
    assert math.degrees(math.asin(0.3 / 4.0)) > math.degrees(math.atan2(0.25, 6.5) + math.asin(0.15 / 6.5))
    world = tmp_path / "hidden.toml"
    world.write_text('[world]\nname = "hidden"\n'
                     '[[obstacles]]\nx_m = 4.0\ny_m = 0.0\nradius_m = 0.3\nheight_m = 4.0\n'
                     '[[obstacles]]\nx_m = 6.5\ny_m = 0.25\nradius_m = 0.15\nheight_m = 4.0\n')
    run = tmp_path / "run"
    cp = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                         "--world", str(world), "--mission", "forest_blind", "--planner", planner,
                         "--run-dir", str(run)], capture_output=True, text=True, timeout=600)
    assert cp.returncode == 0, cp.stderr[-2000:]
    rep = json.loads((run / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["reached_goal"] and rep["collisions"] == 0
    assert rep["min_clearance_m"] > 0.0
    mapped = rep["perception"]["tracks_final"]
    assert any(math.hypot(t["x_m"] - 6.5, t["y_m"] - 0.25) < 0.3 for t in mapped), mapped


def test_free_along_is_the_free_distance_the_map_marches_from_the_sensor():
    """free_along (the nearest ray's free distance) against LocalMap.free_distance_m's march from the sensor."""
    from companion.perception.local_map import LocalMap
    from companion.perception.points import ScanPoints
    from companion.planning.stop_cap import free_along

    rng = np.random.default_rng(1)
    bearing = np.radians(np.arange(360.0)) - math.pi
    free = rng.uniform(0.5, 12.0, 360)
    pts = ScanPoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0, int), np.zeros(0), bearing, free, (1.0, -2.0), 12.0,
                     0.0, math.radians(1.0))
    m = LocalMap()
    m.last = pts
    for h in rng.uniform(-math.pi, math.pi, 50):
        assert free_along(bearing, free, h) == pytest.approx(m.free_distance_m((1.0, -2.0), h), abs=0.051)


def test_a_return_on_a_known_trunk_is_not_unseen_space():
    """The ray ahead ends on a trunk: a mapped one is the planner's to fly around (free to the range limit for the
    cap); one not mapped yet is a wall of unseen space at its range."""
    from companion.planning.stop_cap import free_along

    bearing = np.radians(np.arange(360.0)) - math.pi
    free = np.full(360, 12.0)
    k = int(np.argmin(np.abs(bearing)))  # the ray due north
    free[k] = 3.0
    ray = np.array([k])
    ret = np.array([[3.0, 0.0]])
    kw = {"ray_of_return": ray, "return_xy_m": ret, "range_max_m": 12.0}
    assert free_along(bearing, free, 0.0, **kw, known_xy_m=np.array([[3.25, 0.0]]), known_r_m=np.array([0.25])) == 12.0
    assert free_along(bearing, free, 0.0, **kw, known_xy_m=np.array([[6.0, 2.0]]), known_r_m=np.array([0.25])) == 3.0
    assert free_along(bearing, free, 0.0, **kw, known_xy_m=np.zeros((0, 2)), known_r_m=np.zeros(0)) == 3.0
