"""Properties of the seeded random-forest generator (lab.forests)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.mission import load_mission, mission_to_toml
from lab.forests import ForestSpec, generate_forest


def _same(a, b) -> bool:
    return (a.obstacles == b.obstacles and a.vehicle == b.vehicle and a.wind == b.wind
            and np.array_equal(a.start_ned_m, b.start_ned_m) and np.array_equal(a.goal_ned_m, b.goal_ned_m))


def test_same_seed_same_forest_other_seed_other_forest():
    spec = ForestSpec(vary=True, trap="mixed")
    assert _same(generate_forest(7, spec), generate_forest(7, spec))
    assert not _same(generate_forest(7, spec), generate_forest(8, spec))


@pytest.mark.parametrize("density", [1.0, 3.0, 5.0])
def test_trunk_count_follows_density(density):
    spec = ForestSpec(density_per_100m2=density)
    for seed in range(10):
        m = generate_forest(seed, spec)
        assert len(m.obstacles) == round(density * 20.0 * 6.0 / 100.0)


def test_radii_inside_corridor_no_overlap_clear_start_and_goal():
    spec = ForestSpec(density_per_100m2=5.0)
    for seed in range(30):
        m = generate_forest(seed, spec)
        assert m.start_ned_m.tolist() == [0.0, 0.0, -2.0] and m.goal_ned_m.tolist() == [20.0, 0.0, -2.0]
        for i, o in enumerate(m.obstacles):
            assert 0.15 - 1e-9 <= o.radius_m <= 0.35 + 1e-9
            assert 0.0 <= o.x_m <= 20.0 and abs(o.y_m) <= 3.0
            for p in (m.start_ned_m, m.goal_ned_m):
                assert math.hypot(o.x_m - p[0], o.y_m - p[1]) - o.radius_m >= spec.clear_radius_m - 1e-3
            for q in m.obstacles[i + 1:]:
                assert math.hypot(o.x_m - q.x_m, o.y_m - q.y_m) - o.radius_m - q.radius_m >= spec.min_gap_m - 1e-3


def test_fixed_variation_is_table1_and_vary_stays_in_ranges():
    m = generate_forest(3)
    assert (m.vehicle.m, m.vehicle.l, m.wind.model, m.wind.scale) == (0.25, 1.0, "paper", 1.0)
    seen_wind = []
    for seed in range(40):
        v = generate_forest(seed, ForestSpec(vary=True))
        assert 0.1 <= v.vehicle.m <= 0.5 and 0.5 <= v.vehicle.l <= 1.5 and 0.0 <= v.wind.scale <= 1.3
        seen_wind.append(v.wind.scale)
    assert max(seen_wind) - min(seen_wind) > 0.8  # actually varied


def test_pair_trap_blocks_the_path_for_the_airframe():
    for seed in range(10):
        m = generate_forest(seed, ForestSpec(trap="pair", density_per_100m2=0.0))
        a, b = m.obstacles
        assert a.x_m == b.x_m and 20.0 / 3.0 <= a.x_m <= 40.0 / 3.0
        gap = abs(a.y_m - b.y_m) - a.radius_m - b.radius_m
        airframe = m.vehicle.r_uav + m.vehicle.L_uav
        assert 0.0 < gap < 2.0 * airframe  # the vehicle cannot pass between
        assert min(a.y_m, b.y_m) < 0.0 < max(a.y_m, b.y_m)  # straddles the straight path


def test_cluster_trap_is_a_cup_open_towards_the_start():
    m = generate_forest(4, ForestSpec(trap="cluster", density_per_100m2=0.0))
    xs = np.array([o.x_m for o in m.obstacles])
    ys = np.array([o.y_m for o in m.obstacles])
    assert 5 <= len(xs) <= 7
    assert ys.min() < 0.0 < ys.max()
    i_mid = int(np.argmin(np.abs(ys)))
    assert xs[i_mid] == pytest.approx(xs.max())  # bottom of the cup is on the path, towards the goal
    assert xs[np.argmin(ys)] < xs[i_mid] and xs[np.argmax(ys)] < xs[i_mid]


def test_toml_round_trip_through_load_mission(tmp_path):
    for seed, spec in ((0, ForestSpec()), (5, ForestSpec(vary=True, trap="mixed", planner="improved"))):
        m = generate_forest(seed, spec)
        path = tmp_path / f"s{seed}.toml"
        path.write_text(mission_to_toml(m))
        back = load_mission(path)
        assert _same(m, back)
        assert (back.planner, back.controller, back.timeout_s, back.hold_s, back.land) == (
            m.planner, m.controller, m.timeout_s, m.hold_s, m.land)


def test_bad_spec_is_refused_naming_the_key():
    with pytest.raises(ValueError, match=r"^payload_kg:"):
        generate_forest(0, ForestSpec(payload_kg=0.9))
    with pytest.raises(ValueError, match=r"^trap:"):
        ForestSpec(trap="maze").validate()
