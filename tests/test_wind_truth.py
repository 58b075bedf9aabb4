"""The evaluator's truth about a physical wind (lab.wind_truth): the angle the wind alone hangs a still payload at,
and the envelope's count of flights over their swing bound where no controller could have met it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from companion.core.wind import WindConfig
from lab.envelope import Cell, _cell_summary, cell_mission, envelope
from lab.forests import ForestSpec
from lab.wind_truth import drag_angle_rad, flight_drag_angle_max_rad


def _steady(mean_mps: float, **kw) -> WindConfig:
    return WindConfig("turbulence", 1.0, mean_speed_mps=mean_mps, direction_deg=90.0, intensity="none", **kw)


def test_a_steady_wind_hangs_the_payload_at_its_drag_angle():
    cfg = _steady(6.0)
    k = float(cfg.drag_coefficients()[1])
    a = drag_angle_rad(cfg, 0.1, 2.0, np.array([0.0, 1.0, 5.0, 20.0]))
    assert a == pytest.approx(np.full(4, math.atan(k * 36.0 / (0.1 * 9.81))), rel=1e-9)
    assert drag_angle_rad(cfg, 0.8, 2.0, np.array([5.0]))[0] < a[0] / 5.0  # 8x the weight, the same drag


def test_a_gust_counts_in_full_only_once_the_pendulum_had_time_to_swing_to_it():
    # a 1-cosine gust of 6 m/s on a 3 m/s mean over 1 m (0.33 s at 3 m/s): 0.5 s into it the 3 m cable's half
    # period (1.7 s) has seen mostly the mean wind, a 0.1 m cable's (0.32 s) mostly the gust; 8 s on, both all gust
    gust = _steady(3.0, gust_amplitude_mps=6.0, gust_length_m=1.0, gust_start_s=2.0)
    k = float(gust.drag_coefficients()[1])
    peak = math.atan(k * 81.0 / (0.1 * 9.81))
    at = np.array([2.5, 10.0])
    long_cable, short_cable = drag_angle_rad(gust, 0.1, 3.0, at), drag_angle_rad(gust, 0.1, 0.1, at)
    assert long_cable[0] < 0.6 * peak < 0.9 * peak < short_cable[0]
    assert long_cable[1] == pytest.approx(peak, rel=1e-9) and short_cable[1] == pytest.approx(peak, rel=1e-9)


def test_only_a_physical_wind_and_a_logged_flight_have_one(tmp_path):
    base = ForestSpec(density_per_100m2=4.0)
    assert flight_drag_angle_max_rad(cell_mission(Cell(0.1, 1.0, "paper"), 1, base), tmp_path) is None
    assert flight_drag_angle_max_rad(cell_mission(Cell(0.1, 1.0, "light"), 1, base), tmp_path) is None  # no log
    assert flight_drag_angle_max_rad(cell_mission(Cell(0.1, 1.0, "light"), 1, base), None) is None


def test_the_cell_counts_flights_over_the_bound_where_the_wind_alone_was_beyond_it():
    rs = [{"class": "success", "max_swing_rad": s, "wind_drag_angle_max_rad": d}
          for s, d in ((0.40, 0.38), (0.40, 0.20), (0.30, 0.50), (0.20, None))]
    out = _cell_summary(rs, 0.35)
    assert (out["over_swing_bound"], out["over_swing_bound_wind"]) == (2, 1)
    assert out["wind_drag_angle_worst_rad"] == 0.50


def test_the_grid_reports_the_wind_s_own_angle_from_the_flight_s_log(tmp_path):
    # one moderate-turbulence flight in-process: the angle is the wind's along the logged (simulated) times
    cell = Cell(0.1, 1.0, "moderate")
    base = ForestSpec(density_per_100m2=4.0, length_m=10.0, planner="shaped")
    summary = envelope([cell], 1, base=base, mode="inprocess", workers=1, out=tmp_path, progress=False)
    (r,) = [json.loads(line) for line in (tmp_path / "results.jsonl").read_text().splitlines()]
    mis = cell_mission(cell, 0, base)
    t_end = r["sim_time_s"]  # the log runs from the first tick, within a control period of t = 0
    expect = drag_angle_rad(mis.wind, 0.1, 1.0, np.arange(0.0, t_end, 0.004)).max()
    assert 0.1 < r["wind_drag_angle_max_rad"] == pytest.approx(expect, abs=0.01)
    assert summary["cells"][0]["wind_drag_angle_worst_rad"] == r["wind_drag_angle_max_rad"]
    assert "| 0.1 | 1 | moderate |" in (tmp_path / "envelope.md").read_text()
