"""The ``safe`` planner and trunks that cross its path (issue 26): its barrier acts on the velocity relative to a
moving obstacle, so a trunk coming at the reference pushes it away in time instead of running it down.

In-process flights of the random forests (:func:`lab.forests.generate_forest`, 8 trunks/100 m², two crossing
trunks, fixed seeds) are deterministic; the seeds are those where ``safe`` hit a crossing trunk before the fix
(docs/measurements.md, "A forest nobody mapped", and ``evaluate --mode inprocess --density 8``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.obstacles import Obstacle
from companion.planning.base import PlanInput
from companion.planning.params import PlannerParams
from companion.planning.safe import SafePlanner
from companion.report.metrics import clearances, compute_metrics
from companion.report.scoring import is_moving


def _inp(ref_xy, ref_v, goal=(20.0, 0.0)) -> PlanInput:
    """A plan input with the vehicle on its reference (no tracking error), payload hanging still."""
    p, v = np.array(ref_xy, dtype=float), np.array(ref_v, dtype=float)
    return PlanInput(t_s=5.0, pos_m=p, vel_mps=v, ref_pos_m=p.copy(), ref_vel_mps=v.copy(), goal_m=np.array(goal),
                     r_max_m=0.28, swing=np.zeros(4), cable_l_m=1.0, airframe_r_m=0.28, z_ned_m=-2.0)


def _closing_mps(out_v, o: Obstacle, ref_xy) -> float:
    """How fast (m/s) the reference flying ``out_v`` closes on ``o`` (positive: closing)."""
    dx, dy = ref_xy[0] - o.x_m, ref_xy[1] - o.y_m
    d = math.hypot(dx, dy)
    return -((out_v[0] - o.vx_mps) * dx + (out_v[1] - o.vy_mps) * dy) / d


def test_trunk_coming_from_the_side_is_not_closed_on_faster_than_the_barrier_allows() -> None:
    """A trunk beside the reference (which is at rest, the goal ahead along x), crossing towards it at 1.2 m/s:
    the desired velocity must not close the gap faster than the barrier's allowance min(γ·g, sqrt(2·a_brake·g)).
    Before the fix the barrier saw a still trunk: the reference set off along the path and the trunk closed on it
    at its own 1.2 m/s."""
    params = PlannerParams()
    planner = SafePlanner(params)
    ref = (8.0, 0.0)
    o = Obstacle(x_m=8.0, y_m=1.2, radius_m=0.25, height_m=4.0, safe_distance_m=0.1, vx_mps=0.0, vy_mps=-1.2)
    out = planner.plan(_inp(ref, (0.0, 0.0)), [o])
    gap = planner.gaps(_inp(ref, (0.0, 0.0)), [o])[0][0]
    allow = min(params.gamma * gap, math.sqrt(2.0 * params.a_brake_mps2 * gap))
    assert 0.0 < allow < 1.2  # the trunk alone would close faster than allowed
    assert _closing_mps(out.v_des_mps, o, ref) <= allow + 1e-9


def test_the_same_trunk_standing_still_is_planned_as_before() -> None:
    """With no velocity the obstacle is planned exactly as a standing one (the rule acts on moving ones only): the
    output equals the one for an obstacle built without velocity fields, bit for bit."""
    ref = (8.0, 0.0)
    still = Obstacle(x_m=8.6, y_m=0.9, radius_m=0.25, height_m=4.0, safe_distance_m=0.1)
    zero_v = Obstacle(x_m=8.6, y_m=0.9, radius_m=0.25, height_m=4.0, safe_distance_m=0.1, vx_mps=0.0, vy_mps=0.0)
    a = SafePlanner(PlannerParams()).plan(_inp(ref, (1.8, 0.3)), [still])
    b = SafePlanner(PlannerParams()).plan(_inp(ref, (1.8, 0.3)), [zero_v])
    assert np.array_equal(a.v_des_mps, b.v_des_mps)


def test_a_trunk_moving_away_lets_the_reference_follow_it() -> None:
    """The relative barrier is not one-sided caution: a trunk ahead moving away at 1 m/s may be approached at the
    allowance plus its own speed (a still trunk there would brake the reference more)."""
    ref = (8.0, 0.0)
    moving = Obstacle(x_m=9.05, y_m=0.0, radius_m=0.2, height_m=4.0, safe_distance_m=0.1, vx_mps=1.0, vy_mps=0.0)
    still = Obstacle(x_m=9.05, y_m=0.0, radius_m=0.2, height_m=4.0, safe_distance_m=0.1)
    vm = SafePlanner(PlannerParams()).plan(_inp(ref, (1.5, 0.0)), [moving]).v_des_mps
    vs = SafePlanner(PlannerParams()).plan(_inp(ref, (1.5, 0.0)), [still]).v_des_mps
    assert vm[0] > vs[0] + 0.5


@pytest.mark.parametrize("seed", [2, 5, 6, 7, 19, 22])
def test_random_forest_with_crossing_trunks_is_flown_without_touching_them(seed: int) -> None:
    """The seeds where ``safe`` hit a crossing trunk (in-process, 8 trunks/100 m², two crossers at 0.5–1.5 m/s):
    the goal is reached and no moving trunk is touched (clearance of airframe circle and payload, the trunk where it
    is at that instant)."""
    from companion.launch.fly import DEFAULT_GAINS, load_gains
    from lab.forests import ForestSpec, generate_forest
    from lab.inprocess import fly_inprocess

    mission = generate_forest(seed, ForestSpec(density_per_100m2=8.0, movers=2, planner="safe"))
    assert any(is_moving(o) for o in mission.obstacles)
    flog = fly_inprocess(mission, gains=load_gains(DEFAULT_GAINS))
    ra = mission.vehicle.r_uav + mission.vehicle.L_uav
    clear = clearances(flog, mission.obstacles, ra)
    moving = [c for c, o in zip(clear, mission.obstacles, strict=True) if is_moving(o)]
    assert flog.obstacle_clock_t0_s is not None
    assert min(moving) > 0.0
    assert compute_metrics(flog, mission)["reached_goal"]
