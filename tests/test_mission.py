"""Mission files: the shipped ones load; bad ones are refused naming file and key."""

from pathlib import Path

import numpy as np
import pytest

from companion.core.mission import load_mission, mission_to_toml
from companion.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
FOREST = ROOT / "config" / "missions" / "forest.toml"

GOOD = """
[mission]
name = "t"
start_ned_m = [0.0, 0.0, -2.0]
goal_ned_m = [10.0, 0.0, -2.0]
planner = "safe"
controller = "smc_ff"
timeout_s = 40.0
[wind]
model = "paper"
scale = 1.0
[[obstacles]]
x_m = 5.0
y_m = 2.0
radius_m = 0.3
height_m = 4.0
safe_distance_m = 0.1
"""


def _write(tmp_path, text):
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


def test_forest_is_table_2():
    m = load_mission(FOREST)
    assert m.planner == "safe" and m.controller == "smc_ff" and m.wind.model == "paper"
    np.testing.assert_allclose(m.start_ned_m, [0, 0, -2])
    np.testing.assert_allclose(m.goal_ned_m, [10, 0, -2])
    xs = [(o.x_m, o.y_m, o.radius_m) for o in m.obstacles]
    assert xs == [(3.0, -0.22, 0.3), (6.0, 0.5, 0.2), (5.0, 1.2, 0.3), (4.0, -1.0, 0.3), (8.0, -0.4, 0.3)]
    assert all(o.height_m == 4.0 and o.safe_distance_m == 0.1 for o in m.obstacles)


def test_group1():
    m = load_mission(ROOT / "config" / "missions" / "group1.toml")
    assert m.planner == "none" and not m.obstacles
    np.testing.assert_allclose(m.goal_ned_m, [3, 4, -5])


def test_good_and_roundtrip(tmp_path):
    m = load_mission(_write(tmp_path, GOOD))
    m2 = load_mission(_write(tmp_path, mission_to_toml(m)))
    assert m2.obstacles == m.obstacles and m2.vehicle == m.vehicle and m2.wind == m.wind
    np.testing.assert_allclose(m2.goal_ned_m, m.goal_ned_m)


@pytest.mark.parametrize(
    "old,new,needle",
    [
        ('timeout_s = 40.0', 'timeout_s = 40.0\nspeed = 3.0', "[mission]: unknown key 'speed'"),
        ('timeout_s = 40.0\n', '', "missing required key 'timeout_s'"),
        ('timeout_s = 40.0', 'timeout_s = "long"', "[mission] timeout_s: expected float"),
        ('radius_m = 0.3', 'radius_m = -0.3', "[[obstacles]] #0 radius_m: must be in"),
        ('goal_ned_m = [10.0, 0.0, -2.0]', 'goal_ned_m = [5.0, 2.5, -2.0]', "[mission] goal_ned_m:"),
        ('start_ned_m = [0.0, 0.0, -2.0]', 'start_ned_m = [5.1, 1.9, -2.0]', "[mission] start_ned_m:"),
        ('planner = "safe"', 'planner = "magic"', "[mission] planner: must be one of"),
        ('height_m = 4.0', 'height_m = 4.0\nsource = "x"', "unknown key 'source'"),
        ('[wind]', '[weather]\nx = 1\n[wind]', "unknown table or key 'weather'"),
        ('model = "paper"', 'model = "gale"', "[wind] model:"),
    ],
)
def test_bad_missions_name_file_and_key(tmp_path, old, new, needle):
    assert old in GOOD
    p = _write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(ConfigError) as ei:
        load_mission(p)
    assert str(p) in str(ei.value)
    assert needle in str(ei.value)


def test_goal_above_obstacle_top_is_fine(tmp_path):
    m = load_mission(_write(tmp_path, GOOD.replace("goal_ned_m = [10.0, 0.0, -2.0]", "goal_ned_m = [5.0, 2.0, -6.0]")))
    np.testing.assert_allclose(m.goal_ned_m, [5, 2, -6])


def test_payload_table_absent_keeps_the_vehicle(tmp_path):
    m = load_mission(_write(tmp_path, GOOD))
    assert m.payload.is_default and not m.payload.identify
    assert m.companion_params() == m.vehicle
    assert "[payload]" not in mission_to_toml(m)


def test_payload_table_overrides_the_companions_model_not_the_vehicle(tmp_path):
    text = GOOD + "[payload]\nmass_kg = 0.4\ncable_length_m = 1.3\nidentify = true\n"
    m = load_mission(_write(tmp_path, text))
    assert (m.payload.mass_kg, m.payload.cable_length_m, m.payload.identify) == (0.4, 1.3, True)
    assert (m.vehicle.m, m.vehicle.l) == (0.25, 1.0)  # the physical vehicle (what the bundled sim flies)
    cp = m.companion_params()
    assert (cp.m, cp.l, cp.M) == (0.4, 1.3, m.vehicle.M)
    m2 = load_mission(_write(tmp_path, mission_to_toml(m)))
    assert m2.payload == m.payload
    only_l = load_mission(_write(tmp_path, GOOD + "[payload]\ncable_length_m = 0.8\n"))
    assert (only_l.companion_params().m, only_l.companion_params().l) == (0.25, 0.8)
    assert not only_l.payload.identify
    assert only_l.payload.drag_n_per_mps2 == 0.0  # no drag said: the estimator holds the payload's drag at 0


def test_payload_drag_coefficient_round_trips(tmp_path):
    m = load_mission(_write(tmp_path, GOOD + "[payload]\ndrag_n_per_mps2 = 0.043\nairframe_drag_n_per_mps2 = 0.0245\n"))
    assert m.payload.drag_n_per_mps2 == 0.043 and m.payload.airframe_drag_n_per_mps2 == 0.0245
    assert not m.payload.is_default
    assert not load_mission(_write(tmp_path, GOOD + "[payload]\nairframe_drag_n_per_mps2 = 0.02\n")).payload.is_default
    assert m.companion_params() == m.vehicle  # drag alone changes nothing of the model's masses and lengths
    assert load_mission(_write(tmp_path, mission_to_toml(m))).payload == m.payload


@pytest.mark.parametrize(
    "table,needle",
    [
        ("mass_kg = -0.1", "[payload] mass_kg: must be in (0, 100]"),
        ("cable_length_m = 25.0", "[payload] cable_length_m: must be in (0, 20]"),
        ("mass_kg = 20.0", "[payload] mass_kg: 20.0 kg is more than ten times"),
        ("identify = 1", "[payload] identify: expected bool"),
        ("length = 1.0", "[payload]: unknown key 'length'"),
        ("mass_kg = nan", "[payload] mass_kg: must be finite"),
        ("drag_n_per_mps2 = -0.01", "[payload] drag_n_per_mps2: must be in [0, 10]"),
        ("airframe_drag_n_per_mps2 = 11.0", "[payload] airframe_drag_n_per_mps2: must be in [0, 10]"),
    ],
)
def test_bad_payload_table_names_file_and_key(tmp_path, table, needle):
    p = _write(tmp_path, GOOD + "[payload]\n" + table + "\n")
    with pytest.raises(ConfigError) as ei:
        load_mission(p)
    assert str(p) in str(ei.value) and needle in str(ei.value)


def test_shipped_missions_still_load():
    for name in ("forest.toml", "group1.toml"):
        m = load_mission(ROOT / "config" / "missions" / name)
        assert m.payload.is_default
