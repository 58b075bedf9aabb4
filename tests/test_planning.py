"""Planners (APF eqs. 22-28 as printed, safe planner) and the reference generator."""

import math

import numpy as np
import pytest

from companion.core.obstacles import Obstacle
from companion.planning import (
    PLANNER_NAMES,
    PlanInput,
    Planner,
    PlannerParams,
    ReferenceGenerator,
    SafePlanner,
    make_planner,
)
from companion.planning.apf import attractive_force, repulsive_force, rho0_traditional_m, rho_star_improved_m
from companion.planning.safe import predicted_envelope_m

OBS = Obstacle(x_m=2.0, y_m=0.0, radius_m=0.3, height_m=4.0, safe_distance_m=0.1)


def _inp(pos, goal=(10.0, 0.0), swing=(0.0, 0.0, 0.0, 0.0), r_max=0.28, ref_vel=(0.0, 0.0), t=0.0, ref=None):
    pos = np.array(pos, dtype=float)
    return PlanInput(
        t_s=t, pos_m=pos, vel_mps=np.array(ref_vel, float), ref_pos_m=pos if ref is None else np.array(ref, float),
        ref_vel_mps=np.array(ref_vel, float), goal_m=np.array(goal, float), r_max_m=r_max,
        swing=None if swing is None else np.array(swing, float), cable_l_m=1.0, airframe_r_m=0.28, z_ned_m=-2.0,
    )


def test_attractive_force_eq_23():
    np.testing.assert_allclose(attractive_force(np.array([1.0, 1.0]), np.array([4.0, 5.0]), 2.0), [6.0, 8.0])


def test_repulsive_force_eq_25_hand_value():
    # rho = 0.5, rho0 = 1.0, kr = 2: 2*(2 - 1)/0.25 = 8, pointing away from the obstacle (-x)
    f = repulsive_force(np.array([1.5, 0.0]), np.array([2.0, 0.0]), 2.0, 1.0)
    np.testing.assert_allclose(f, [-8.0, 0.0])
    assert np.all(repulsive_force(np.array([0.9, 0.0]), np.array([2.0, 0.0]), 2.0, 1.0) == 0.0)


def test_influence_distances():
    assert rho0_traditional_m(OBS, 1.0) == pytest.approx(1.4)
    assert rho_star_improved_m(OBS, 0.28) == pytest.approx(0.68)


def test_traditional_vs_improved_range():
    # at 1.0 m from the obstacle's axis: inside rho0 = 1.4 (traditional), outside rho* = 0.68 (improved)
    trad = make_planner("traditional").plan(_inp([1.0, 0.0]), [OBS])
    imp = make_planner("improved").plan(_inp([1.0, 0.0]), [OBS])
    assert trad.force_rep[0] < 0.0
    assert np.all(imp.force_rep == 0.0)
    # the desired velocity is the saturated resultant force
    p = PlannerParams()
    assert np.linalg.norm(trad.v_des_mps) <= p.v_max_mps + 1e-12


def test_none_planner_goes_straight():
    out = make_planner("none").plan(_inp([1.0, 0.0]), [OBS])
    assert out.v_des_mps[1] == 0.0 and out.v_des_mps[0] > 0.0


def test_unknown_planner():
    with pytest.raises(ValueError, match="planner"):
        make_planner("astar")


def test_reference_generator_respects_limits():
    p = PlannerParams()
    g = ReferenceGenerator(p, np.zeros(3))
    dt = 0.004
    prev_a = g.acc_ned_mps2.copy()
    max_a = max_j = max_v = 0.0
    for _ in range(2000):
        g.step(np.array([5.0, 5.0, -3.0]), dt)
        max_a = max(max_a, float(np.linalg.norm(g.acc_ned_mps2[:2])))
        max_j = max(max_j, float(np.linalg.norm(g.acc_ned_mps2 - prev_a)) / dt)
        max_v = max(max_v, float(np.linalg.norm(g.vel_ned_mps[:2])))
        prev_a = g.acc_ned_mps2.copy()
    assert max_a <= p.a_max_mps2 + 1e-9
    assert max_j <= p.j_max_mps3 + 1e-6
    assert max_v <= p.v_max_mps * 1.02
    assert g.vel_ned_mps[2] == pytest.approx(-p.vz_max_mps, abs=1e-3)
    # and it comes to rest when asked
    for _ in range(1000):
        g.step(np.zeros(3), dt)
    assert np.linalg.norm(g.vel_ned_mps) < 1e-3


def test_gentle_start_limits_the_jerk_only_when_speeding_up_from_rest():
    """start_jerk_frac 0.4: from rest the horizontal jerk is at most 0.4·j_max (rising with speed to the full limit
    at start_ramp_mps); braking from speed has the full limit; the default is 0.5 of the limit at rest; 1 turns the
    gentle start off (the full jerk at once)."""
    from dataclasses import replace

    dt = 0.004

    def jerks(params, v_des, steps, start_v=None):
        g = ReferenceGenerator(params, np.zeros(3))
        if start_v is not None:
            g.reset(np.zeros(3), np.array(start_v))
        out, prev = [], g.acc_ned_mps2.copy()
        for _ in range(steps):
            g.step(np.array(v_des), dt)
            out.append((float(np.linalg.norm(g.acc_ned_mps2[:2] - prev[:2])) / dt, float(np.linalg.norm(g.v[:2]))))
            prev = g.acc_ned_mps2.copy()
        return out

    p = PlannerParams()
    gentle = replace(p, start_jerk_frac=0.4)
    start = jerks(gentle, [2.0, 0.0, 0.0], 400)
    assert start[0][0] <= 0.4 * p.j_max_mps3 + 1e-6
    assert all(j <= p.j_max_mps3 * (0.4 + 0.6 * min(v, 1.0)) + 0.05 for j, v in start)
    assert p.start_jerk_frac == 0.5
    default = jerks(p, [2.0, 0.0, 0.0], 400)
    assert 0.45 * p.j_max_mps3 < default[0][0] <= 0.5 * p.j_max_mps3 + 1e-6
    off = replace(p, start_jerk_frac=1.0)
    assert max(j for j, _ in jerks(off, [2.0, 0.0, 0.0], 400)) > 0.9 * p.j_max_mps3  # off: full jerk at once
    brake = jerks(gentle, [0.0, 0.0, 0.0], 100, start_v=[0.5, 0.0, 0.0])  # slow, slowing down: full limit
    assert max(j for j, _ in brake) > 0.9 * p.j_max_mps3
    with pytest.raises(ValueError, match="start_jerk_frac"):
        replace(p, start_jerk_frac=1.5).validate()


def test_predicted_envelope():
    w = math.sqrt(9.81)
    # at rest: airframe circle; swinging through zero at 0.5*w rad/s -> amplitude 0.5 rad
    assert predicted_envelope_m(_inp([0, 0])) == pytest.approx(0.28)
    assert predicted_envelope_m(_inp([0, 0], swing=(0.0, 0.0, 0.5 * w, 0.0))) == pytest.approx(math.sin(0.5))
    assert predicted_envelope_m(_inp([0, 0], swing=None)) == pytest.approx(1.0)


def test_safe_barrier_blocks_approach_at_zero_gap():
    sp = SafePlanner(PlannerParams())
    # place the reference exactly at gap 0 on the obstacle's left, goal straight through it
    need = 0.3 + 0.1 + 0.28 + PlannerParams().track_margin_m
    out = sp.plan(_inp([2.0 - need, 0.0], goal=(4.0, 0.0)), [OBS])
    assert out.v_des_mps[0] <= 1e-9  # no approach component
    assert abs(out.v_des_mps[1]) > 0.1  # slides around instead of stalling


def test_safe_never_lets_reference_into_ring():
    """Kinematic check: the reference driven by the safe planner keeps its gap >= 0 around a wall of trunks."""
    p = PlannerParams()
    obstacles = [OBS, Obstacle(2.5, 0.8, 0.3), Obstacle(2.5, -0.8, 0.3), Obstacle(5.0, 0.3, 0.25)]
    sp = SafePlanner(p)
    g = ReferenceGenerator(p, np.zeros(3))
    dt = 0.004
    min_gap = math.inf
    for k in range(6000):
        inp = _inp(g.pos_ned_m[:2], goal=(8.0, 0.0), ref_vel=g.vel_ned_mps[:2], t=k * dt)
        out = sp.plan(inp, obstacles)
        g.step(np.array([*out.v_des_mps, 0.0]), dt)
        gaps = [gap for gap, _, _ in sp.gaps(inp, obstacles)]
        min_gap = min(min_gap, *gaps)
    assert np.linalg.norm(g.pos_ned_m[:2] - [8.0, 0.0]) < 0.1
    # the gap includes the tracking margin; the reference may dip into that margin by a few cm at most
    assert min_gap > -0.03


def test_safe_escapes_trap():
    """A concave cluster (U open away from the goal) straight across the path: the safe planner gets out."""
    p = PlannerParams()
    trap = [Obstacle(3.0, y, 0.3) for y in (-1.5, -0.75, 0.0, 0.75, 1.5)] + [
        Obstacle(2.2, -1.9, 0.3), Obstacle(2.2, 1.9, 0.3)
    ]
    sp = SafePlanner(p)
    g = ReferenceGenerator(p, np.zeros(3))
    dt = 0.01
    for k in range(6000):
        inp = _inp(g.pos_ned_m[:2], goal=(7.0, 0.0), ref_vel=g.vel_ned_mps[:2], t=k * dt)
        g.step(np.array([*sp.plan(inp, trap).v_des_mps, 0.0]), dt)
        if np.linalg.norm(g.pos_ned_m[:2] - [7.0, 0.0]) < 0.1:
            break
    assert np.linalg.norm(g.pos_ned_m[:2] - [7.0, 0.0]) < 0.1


def test_side_choice_prefers_room():
    sp = SafePlanner(PlannerParams())
    # head-on to OBS; a second trunk right beside it at -y: the planner must pass on +y
    other = Obstacle(2.0, -0.9, 0.3)
    out = sp.plan(_inp([0.9, 0.0], goal=(6.0, 0.0), ref_vel=(1.0, 0.0)), [OBS, other])
    assert sp.side != 0
    assert out.v_des_mps[1] > 0.0


@pytest.mark.parametrize("name", PLANNER_NAMES)
def test_every_planner_implements_what_the_flight_core_uses(name):
    """The Planner protocol in full: name, time_parameterised (a reference exactly when declared), stop()."""
    pl = make_planner(name)
    assert isinstance(pl, Planner) and pl.name == name
    assert pl.time_parameterised is (name == "shaped")
    out = pl.plan(_inp([0.0, 0.0]), [Obstacle(5.0, 0.5, 0.3)])
    assert (out.reference is not None) is pl.time_parameterised
    pl.stop()
    after = pl.plan(_inp([0.0, 0.0], t=0.004), [Obstacle(5.0, 0.5, 0.3)])
    if pl.time_parameterised:
        assert out.mode == "track" and after.mode == "hold"  # the shaped planner stops along its plan
    else:
        assert after.mode == out.mode and np.array_equal(after.v_des_mps, out.v_des_mps)  # a no-op

