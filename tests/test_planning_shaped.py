"""The shaped planner: limits of its reference, moving obstacles, no route, and short closed-loop flights."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.core.mission import Mission, load_mission
from companion.core.model import VehicleParams
from companion.core.obstacles import Obstacle
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from companion.planning import PlanInput, PlannerParams, make_planner
from companion.planning.clearance import Predicted, clearance
from companion.planning.shaping import pendulum_omega_rad_s
from companion.report.metrics import clearances, compute_metrics
from companion.report.scoring import obstacle_clearances
from lab.forests import ForestSpec, generate_forest
from lab.inprocess import fly_inprocess

MISSIONS = Path(__file__).resolve().parents[1] / "config" / "missions"
DT = 0.004
AIRFRAME = 0.28


def _fly_reference(goal, obstacles, t_end, start=(0.0, 0.0), params=None, sigma=0.0):
    """The planner alone, its reference flown perfectly (no physics); rows [t, p(2), v(2), a(2), j(2), swing(6)]
    and the planner. Moving obstacles are advanced to each tick's time, as the flight core does."""
    pl = make_planner("shaped", params or PlannerParams(), VehicleParams())
    pos = np.array(start, float)
    vel = np.zeros(2)
    swing = np.zeros(4)
    rows = []
    for k in range(int(t_end / DT)):
        t = k * DT
        obs = [o.at_time(t) for o in obstacles]
        inp = PlanInput(t_s=t, pos_m=pos, vel_mps=vel, ref_pos_m=pos, ref_vel_mps=vel, goal_m=np.array(goal, float),
                        r_max_m=AIRFRAME, swing=swing, cable_l_m=1.0, airframe_r_m=AIRFRAME, z_ned_m=-2.0,
                        swing_sigma_rad=sigma)
        out = pl.plan(inp, obs)
        r = out.reference
        pos, vel = np.array(r.pos_m), np.array(r.vel_mps)
        swing = np.array(r.swing_nom[:4])
        rows.append([t, *r.pos_m, *r.vel_mps, *r.acc_mps2, *r.jerk_mps3, *r.swing_nom])
    return np.array(rows), pl


def _clearance_of(rows, obstacles):
    """Per obstacle, min over time of airframe-circle and nominal payload clearance (moving ones where they are)."""
    pay = np.stack([rows[:, 1] + np.sin(rows[:, 9]) * np.cos(rows[:, 10]), rows[:, 2] - np.sin(rows[:, 10])], 1)
    pos3 = np.c_[rows[:, 1:3], np.full(len(rows), -2.0)]
    pay3 = np.c_[pay, np.full(len(rows), -1.0)]
    return obstacle_clearances(rows[:, 0], pos3, pay3, obstacles, AIRFRAME, clock_t0_s=0.0)


def test_reference_respects_its_limits_through_the_table2_forest():
    m = load_mission(MISSIONS / "forest.toml")
    p = PlannerParams()
    rows, pl = _fly_reference(m.goal_ned_m[:2], m.obstacles, 9.0, params=p)
    a_max = p.shaped_a_max_mps2
    omega = pendulum_omega_rad_s(VehicleParams(), "held")
    t1, t2, t3 = p.shaper_tau_s
    a_lat = np.hypot(rows[:, 9], rows[:, 10]) * 9.81  # the payload's acceleration, from the nominal swing
    assert a_lat.max() <= 1.06 * a_max  # the profile's 0.1 m discretisation; swing <= atan(a/g)
    # the airframe leads by a_L/ω²: |a_q| <= a_max + 2·a_max/(τ2·τ3·ω²)
    assert np.hypot(rows[:, 5], rows[:, 6]).max() <= 1.06 * a_max * (1.0 + 2.0 / (t2 * t3 * omega**2))
    # jerk: |a_L'| <= 2·a_max/τ1 plus the lead's |a_L'''|/ω² <= 2·a_max·4/(τ1·τ2·τ3·ω²)
    jerk_bound = 1.06 * 2.0 * a_max * (1.0 / t1 + 4.0 / (t1 * t2 * t3 * omega**2))
    assert np.hypot(rows[:, 7], rows[:, 8]).max() <= jerk_bound
    # continuous from tick to tick, whatever the replans did
    dp = np.hypot(*np.diff(rows[:, 1:3], axis=0).T)
    dv = np.hypot(*np.diff(rows[:, 3:5], axis=0).T)
    assert dp.max() <= p.shaped_v_max_mps * DT * 1.01
    assert dv.max() <= np.hypot(rows[:, 5], rows[:, 6]).max() * DT * 1.05
    assert pl.replans >= int(9.0 * p.replan_rate_hz) - 1  # replanned at the configured rate
    # arrives at rest, without swing, and never inside a safety ring
    assert np.hypot(*(rows[-1, 1:3] - m.goal_ned_m[:2])) < 1e-6 and np.hypot(*rows[-1, 3:5]) < 1e-9
    assert np.max(np.abs(rows[-1, 9:15])) < 1e-9
    ring = np.array([o.safe_distance_m for o in m.obstacles])
    assert np.all(_clearance_of(rows, m.obstacles) > ring)


def test_clearance_kernel_predicts_when_a_moving_obstacle_arrives():
    rows = np.zeros((2000, 14))  # a reference at rest at the origin, one row per 10 ms
    obs = Predicted(cx=np.array([10.0]), cy=np.zeros(1), vx=np.array([-1.0]), vy=np.zeros(1),
                    ring_airframe=np.array([1.0]), ring_payload=np.array([0.5]), growth=np.zeros(1),
                    moving=np.array([True]))
    first, worst = clearance(rows, 0.0, 0.01, 0.0, 1.0, obs)
    assert first[0] == pytest.approx(9.0, abs=0.011)  # 10 m away at 1 m/s, ring 1 m
    assert worst[0] == pytest.approx(-1.0)  # it passes right through the reference at t = 10 s
    grown = Predicted(obs.cx, obs.cy, obs.vx, obs.vy, obs.ring_airframe, obs.ring_payload, np.array([0.1]), obs.moving)
    first_g, _ = clearance(rows, 0.0, 0.01, 0.0, 1.0, grown)
    assert first_g[0] == pytest.approx(9.0 / 1.1, abs=0.011)  # 10 − t = 1 + 0.1·t


def _crossing_trunk(x_c=6.0, t_c=3.2, speed=1.5):
    """A trunk crossing y from −∞ to +∞ at x_c, on the straight path at t_c (s)."""
    return Obstacle(x_m=x_c, y_m=-speed * t_c, radius_m=0.3, vx_mps=0.0, vy_mps=speed)


def test_a_trunk_crossing_the_path_is_flown_around_where_it_will_be():
    goal = (12.0, 0.0)
    trunk = _crossing_trunk()
    # without it, the reference is on the straight line exactly when the trunk crosses there
    free, _ = _fly_reference(goal, [], 9.0)
    assert _clearance_of(free, [trunk])[0] < 0.0
    # with it (predicted from its velocity), the reference keeps the safety ring from where the trunk is
    rows, _pl = _fly_reference(goal, [trunk], 10.0)
    assert _clearance_of(rows, [trunk])[0] > trunk.safe_distance_m
    assert np.hypot(*(rows[-1, 1:3] - np.array(goal))) < 1e-6
    # the same trunk believed static at its first position would not have been avoided
    still = Obstacle(x_m=trunk.x_m, y_m=trunk.y_m, radius_m=trunk.radius_m)
    blind, _ = _fly_reference(goal, [still], 9.0)
    assert _clearance_of(blind, [trunk])[0] < 0.0


def _est(t, pos, vel=(0.0, 0.0, 0.0), swing=(0.0, 0.0, 0.0, 0.0)):
    return Estimate(t, np.array(pos, float), np.array(vel, float), np.zeros(3), np.zeros(3), np.array(swing, float),
                    "cable_sensor")


def _fenced(gap_m):
    n = 12
    r = 0.25
    radius = (n * (2 * r + gap_m)) / (2 * math.pi)
    obs = tuple(Obstacle(10.0 + radius * math.cos(2 * math.pi * k / n), radius * math.sin(2 * math.pi * k / n), r)
                for k in range(n))
    return Mission("fenced", np.array([0.0, 0.0, -2.0]), np.array([10.0, 0.0, -2.0]), "shaped", "smc_ff", 30.0,
                   obstacles=obs, hold_s=1.0)


def _tick_core(core, seconds, t0=0.0):
    """Fly the core's own reference perfectly (no physics) for ``seconds``; returns the commands."""
    cmds = []
    pos = core.mission.start_ned_m.copy()
    vel = np.zeros(3)
    for k in range(int(seconds / DT)):
        cmd = core.update(_est(t0 + k * DT, pos, vel))
        cmds.append(cmd)
        pos, vel = cmd.ref_pos_ned_m.copy(), cmd.ref_vel_ned_mps.copy()
    return cmds


def test_no_route_to_a_fenced_goal_is_declared_within_a_second_and_held():
    core = FlightCore(_fenced(0.2))  # gaps of 0.2 m: narrower than the 0.56 m airframe
    cmds = _tick_core(core, 3.0)
    t_decl = next(c.t_s for c in cmds if c.no_route)
    assert t_decl <= 1.0
    assert core.no_route and core.phase == "done"  # held for hold_s, then done: the mission ends
    assert core.result == "no_route"  # the verdict the flight sequence ends the mission with
    phases = [c.phase for c in cmds]
    assert "no_route" in phases and phases.index("no_route") == next(i for i, c in enumerate(cmds) if c.no_route)
    # it held at a safe point (where it started; nothing was ever flown towards the fence)
    assert max(np.hypot(*c.ref_pos_ned_m[:2]) for c in cmds) < 0.05
    assert cmds[-1].plan_mode == "no_route"


def test_a_fence_with_a_gap_wide_enough_is_not_a_dead_end():
    m = _fenced(0.2)
    obs = list(m.obstacles)
    del obs[6]  # the trunk facing the start: a 0.9 m opening
    core = FlightCore(m.with_(obstacles=tuple(obs)))
    cmds = _tick_core(core, 12.0)
    assert not core.no_route and not any(c.no_route for c in cmds)
    assert core.phase in ("hold", "done")


def test_a_hold_asked_mid_cruise_takes_over_the_shaped_reference_smoothly():
    m = Mission("line", np.array([0.0, 0.0, -2.0]), np.array([12.0, 0.0, -2.0]), "shaped", "smc_ff", 30.0, hold_s=1.0)
    core = FlightCore(m)
    cmds = _tick_core(core, 2.5)
    v_before = cmds[-1].ref_vel_ned_mps.copy()
    assert v_before[0] > 1.0 and core.phase == "cruise"
    core.hold_here()
    pos = cmds[-1].ref_pos_ned_m.copy()
    vel = cmds[-1].ref_vel_ned_mps.copy()
    after = []
    for k in range(1, 1500):
        cmd = core.update(_est(2.5 + k * DT - DT, pos, vel))
        after.append(cmd)
        pos, vel = cmd.ref_pos_ned_m.copy(), cmd.ref_vel_ned_mps.copy()
    assert core.phase == "hold_here" and core.result is None
    dv = np.linalg.norm(after[0].ref_vel_ned_mps - v_before)
    assert dv < 0.1  # no jump in the reference velocity at the hand-over
    vx = np.array([c.ref_vel_ned_mps[0] for c in after])
    assert vx.min() > -1e-6  # the planner's own stop along its path: no overshoot and flying back
    assert np.linalg.norm(after[-1].ref_vel_ned_mps) < 1e-6  # and it came to rest
    assert after[-1].ref_pos_ned_m[0] < 12.0 and np.max(np.abs([c.ref_pos_ned_m[1] for c in after])) < 1e-9
    # within the swing bound all the way (the nominal swing is |a_L|/g)
    assert max(abs(c.ref_acc_ned_mps2[0]) for c in after) < 1.85 * (1.0 + 2.0 / (0.35 * 0.4 * 9.81)) + 1e-6


def test_flight_core_moves_mission_obstacles_from_its_clock_zero():
    trunk = Obstacle(5.0, -3.0, 0.3, vx_mps=0.0, vy_mps=1.0)
    m = Mission("mv", np.array([0.0, 0.0, -2.0]), np.array([10.0, 0.0, -2.0]), "safe", "smc_ff", 30.0,
                obstacles=(trunk, Obstacle(3.0, 2.0, 0.3)), hold_s=1.0)
    core = FlightCore(m)
    core.update(_est(7.0, [0.0, 0.0, -2.0]))  # the mission clock starts here
    moved = core._advance_obstacles(m.obstacles, 9.0)
    assert (moved[0].x_m, moved[0].y_m) == pytest.approx((5.0, -1.0))
    assert moved[1] is m.obstacles[1]  # standing trunks untouched
    static = FlightCore(m.with_(obstacles=(Obstacle(3.0, 2.0, 0.3),)))
    static.update(_est(0.0, [0.0, 0.0, -2.0]))
    assert static._advance_obstacles(static.mission.obstacles, 5.0) is static.mission.obstacles


def test_swing_uncertainty_widens_the_envelope():
    pl = make_planner("shaped", PlannerParams(), VehicleParams())
    base = dict(t_s=0.0, pos_m=np.zeros(2), vel_mps=np.zeros(2), ref_pos_m=np.zeros(2), ref_vel_mps=np.zeros(2),
                goal_m=np.array([5.0, 0.0]), r_max_m=AIRFRAME, swing=np.zeros(4), cable_l_m=1.0,
                airframe_r_m=AIRFRAME)
    pl.plan(PlanInput(**base), [])
    exact = pl.envelope_m(PlanInput(**base))
    assert pl.envelope_m(PlanInput(**base, swing_sigma_rad=0.0)) == exact
    wide = pl.envelope_m(PlanInput(**base, swing_sigma_rad=0.3))
    assert wide > exact and wide == pytest.approx(math.sin(math.atan(1.85 / 9.81) + 0.6), rel=1e-6)
    assert pl.envelope_m(PlanInput(**{**base, "swing": None})) == pytest.approx(1.0)  # no sensing: whole cable


@pytest.mark.slow
def test_table2_forest_in_process_meets_the_issue_targets():
    m = load_mission(MISSIONS / "forest.toml").with_(planner="shaped", hold_s=3.0)
    r = compute_metrics(fly_inprocess(m), m)
    assert r["reached_goal"] and r["collisions"] == 0 and r["min_clearance_m"] > 0.0
    assert r["time_to_goal_s"] <= 6.0
    assert r["max_swing_rad"] <= 0.20
    assert r["swing_settle_after_arrival_s"] is not None and r["swing_settle_after_arrival_s"] <= 1.0


@pytest.mark.slow
def test_random_forest_with_crossing_trunks_in_process_is_clean():
    m = generate_forest(3, ForestSpec(density_per_100m2=8.0, length_m=15.0, width_m=4.0, movers=2,
                                      planner="shaped"))
    assert sum(1 for o in m.obstacles if o.vy_mps or o.vx_mps) == 2
    log = fly_inprocess(m)
    r = compute_metrics(log, m)
    clear = clearances(log, m.obstacles, AIRFRAME)
    assert r["reached_goal"] and np.all(clear > 0.0)
    assert r["max_swing_rad"] <= 0.25


def test_the_flight_core_hands_the_planner_the_swing_estimate_uncertainty():
    from dataclasses import replace

    from companion.estimation.estimate import swing_sigma_rad

    assert swing_sigma_rad(_est(0.0, [0, 0, -2])) == 0.0  # the cable sensor: exact
    # a 3σ bound around |(α, β)| = 0.05: σ = (0.2 − 0.05)/3
    bounded = replace(_est(0.0, [0, 0, -2]), swing=np.array([0.03, 0.04, 0.0, 0.0]), swing_source="estimate",
                      swing_bound_rad=0.2)
    assert swing_sigma_rad(bounded) == pytest.approx(0.05)


@pytest.mark.slow
def test_table2_forest_in_process_on_the_swing_estimate():
    """The swing estimator instead of the cable sensor: its 3σ bound widens the envelope, its fade scales the
    feed-forward and the compensation of the planned swing alike."""
    m = load_mission(MISSIONS / "forest.toml").with_(planner="shaped", hold_s=2.0)
    r = compute_metrics(fly_inprocess(m, swing_source="estimate"), m)
    assert r["reached_goal"] and r["collisions"] == 0 and r["min_clearance_m"] > 0.0
    assert r["time_to_goal_s"] <= 6.0 and r["max_swing_rad"] <= 0.20
