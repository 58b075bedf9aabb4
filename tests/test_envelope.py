"""The payload envelope (issue 28): adaptation of the swing-bounded accelerations, the grid's cells, and a tiny
grid flown in-process end to end (files, table, heat map)."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from companion.control.adapt import accel_scale, adapt_to_payload
from companion.control.params import ControllerConfig
from companion.core.vehicle_params import VehicleParams
from lab.envelope import Cell, cell_mission, cell_spec, envelope, parse_grid, wind_config
from lab.forests import ForestSpec


def test_table1_payload_flies_the_tuned_limits_unchanged():
    cfg = ControllerConfig()
    assert adapt_to_payload(cfg, VehicleParams()) is cfg
    assert adapt_to_payload(cfg, replace(VehicleParams(), m=0.8, l=0.5)) is cfg  # short cable: never raised


def test_long_cable_scales_the_swing_bounded_accelerations_with_the_pendulum_frequency():
    cfg = ControllerConfig()
    vp = replace(VehicleParams(), l=4.0)
    k = accel_scale(vp)
    assert k == pytest.approx(0.5, rel=1e-3)  # ω ∝ 1/√l for a point payload under a held airframe
    out = adapt_to_payload(cfg, vp).planner
    assert out.shaped_a_max_mps2 == pytest.approx(cfg.planner.shaped_a_max_mps2 * k)
    assert out.a_max_mps2 == pytest.approx(cfg.planner.a_max_mps2 * k)
    assert out.a_brake_mps2 == pytest.approx(cfg.planner.a_brake_mps2 * k)  # the braking safe's barrier counts on
    assert out.shaped_v_max_mps == cfg.planner.shaped_v_max_mps  # only the accelerations change


@pytest.mark.parametrize(("cell", "seed"), [(Cell(0.8, 3.0, "calm"), 0), (Cell(0.25, 3.0, "paper"), 1)])
def test_safe_with_a_long_cable_brakes_as_its_reference_can_and_clears_the_trunks(cell, seed):
    """The ``safe`` planner on envelope cells whose payload it swung into a trunk (flown in-process): its barrier
    counted on braking at 1.2 m/s² while a 3 m cable's reference brakes at 0.58 of Table 1's (0.13 m and 0.03 m
    into the trunk before). Clean now, the goal reached."""
    from companion.launch.fly import DEFAULT_GAINS, load_gains
    from companion.report.metrics import clearances, compute_metrics
    from lab.inprocess import fly_inprocess

    mission = cell_mission(cell, seed, ForestSpec(density_per_100m2=4.0, width_m=6.0)).with_(planner="safe")
    flog = fly_inprocess(mission, gains=load_gains(DEFAULT_GAINS))
    assert min(clearances(flog, mission.obstacles, mission.vehicle.r_uav + mission.vehicle.L_uav)) > 0.0
    assert compute_metrics(flog, mission)["reached_goal"]


def test_cells_fly_high_enough_for_the_payload_and_under_the_canopy():
    base = ForestSpec(density_per_100m2=4.0)
    s = cell_spec(Cell(0.25, 3.0, "calm"), base)
    assert s.altitude_m == pytest.approx(4.0) and s.trunk_height_m == pytest.approx(7.0)
    assert cell_spec(Cell(0.25, 0.5, "calm"), base).altitude_m == base.altitude_m
    m = cell_mission(Cell(0.8, 2.0, "paper"), 3, base)
    assert (m.vehicle.m, m.vehicle.l, m.wind.model) == (0.8, 2.0, "paper")
    assert -m.start_ned_m[2] - m.vehicle.l >= 1.0 - 1e-9  # the hanging payload clears the ground by 1 m
    assert all(o.height_m > -m.start_ned_m[2] for o in m.obstacles)


def test_cells_declare_the_payload_s_drag_where_the_wind_drags():
    base = ForestSpec(density_per_100m2=4.0)
    light = cell_mission(Cell(0.1, 1.0, "light"), 2, base)
    k_air, k = map(float, light.wind.drag_coefficients())
    assert k > 0.0 and light.payload.drag_n_per_mps2 == pytest.approx(k)
    assert k_air > 0.0 and light.payload.airframe_drag_n_per_mps2 == pytest.approx(k_air)  # the lift-off gate
    assert light.companion_params().m == 0.1  # only the drag is declared: mass and cable are the vehicle's
    ident = cell_mission(Cell(0.1, 1.0, "light"), 2, base, drags="identified").payload
    assert ident.drag_n_per_mps2 == 0.0 and ident.airframe_drag_n_per_mps2 == pytest.approx(k_air)
    assert cell_mission(Cell(0.1, 1.0, "light"), 2, base, drags="none").payload.is_default  # a user's first mission
    with pytest.raises(ValueError, match="drags"):
        cell_mission(Cell(0.1, 1.0, "light"), 2, base, drags="guessed")
    for wind in ("calm", "paper"):  # no drag in the world: nothing to declare (and those flights fly as before)
        assert cell_mission(Cell(0.1, 1.0, wind), 2, base).payload.is_default
    from companion.core.mission import mission_to_toml

    assert "drag_n_per_mps2" in mission_to_toml(light)  # the run folder's mission.toml replays it as flown


def test_grid_arguments_are_checked():
    assert len(parse_grid(None, None, None)) == 64
    with pytest.raises(ValueError, match="unknown wind 'gale'"):
        parse_grid("0.25", "1", "gale")
    with pytest.raises(ValueError, match="outside"):
        parse_grid("-1", "1", "calm")
    assert wind_config("calm").model == "none" and wind_config("paper").scale == 1.0


def test_a_small_grid_flies_and_writes_its_table_and_figure(tmp_path):
    cells = [Cell(0.25, 1.0, "calm"), Cell(0.25, 2.0, "paper")]
    summary = envelope(cells, 1, base=ForestSpec(density_per_100m2=4.0, length_m=10.0, planner="shaped"),
                       mode="inprocess", workers=1, out=tmp_path, progress=False, drags="none")
    assert summary["missions"] == 2 and summary["payload_drag"] == "none"
    md = (tmp_path / "envelope.md").read_text()
    assert "no drag declared" in md.splitlines()[0]
    assert "| 0.25 | 2 | paper |" in md
    assert (tmp_path / "envelope.png").stat().st_size > 10_000
    cells_out = json.loads((tmp_path / "envelope.json").read_text())["cells"]
    assert [c["collisions"] for c in cells_out] == [0, 0]
    assert all(c["clean_rate"] == 1.0 for c in cells_out)
