"""The simulator's truth about a physical wind (companion.report.wind_truth): the angle the wind alone hangs a still
payload at, the swing of a payload hung from a pivot held still in the same wind, and the envelope's counts of
flights over their swing bound where the wind alone, or the held payload, was beyond it too."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from companion.core.wind import WindConfig
from companion.report.wind_truth import drag_angle_rad, held_swing_rad, report_wind_truth
from lab.envelope import Cell, _cell_summary, cell_mission, envelope
from lab.forests import ForestSpec


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


def test_a_payload_held_still_in_a_steady_wind_stays_at_its_drag_angle():
    cfg = _steady(6.0)
    k = float(cfg.drag_coefficients()[1])
    assert held_swing_rad(cfg, 0.1, 2.0, 1.0, 10.0) == pytest.approx(math.atan(k * 36.0 / (0.1 * 9.81)), abs=1e-9)


def _planar_held_swing(cfg: WindConfig, m: float, l: float, t_from: float, t_to: float) -> float:
    """The same held pendulum in a wind along x, written apart in its angle α (x = l·sin α, z = l·cos α) and
    integrated by scipy: l·α̈ = −g·sin α + (F_x·cos α − F_z·sin α)/m, F = k·|w − v|·(w − v)."""
    k, g = float(cfg.drag_coefficients()[1]), 9.81
    from companion.core.turbulence import WindField

    field = WindField(cfg)
    w0 = field.velocity(0.0)
    assert abs(w0[1]) < 1e-12 and abs(w0[2]) < 1e-12  # a wind along x only

    def f(t, y):
        al, dal = y
        v = l * dal * np.array([math.cos(al), -math.sin(al)])  # payload velocity (x, z)
        a = np.array([field.velocity(t)[0], 0.0]) - v
        fx, fz = k * math.hypot(*a) * a
        return [dal, (-g * math.sin(al) + (fx * math.cos(al) - fz * math.sin(al)) / m) / l]

    al0 = math.atan(k * w0[0] * abs(w0[0]) / (m * g))
    ts = np.arange(t_from, t_to, 0.001)
    sol = solve_ivp(f, (0.0, t_to), [al0, 0.0], t_eval=ts, rtol=1e-9, atol=1e-11, max_step=0.002)
    return float(np.abs(sol.y[0]).max())


def test_a_gust_faster_than_the_pendulum_swings_the_held_payload_past_its_new_drag_angle():
    # a wind along x (from the south) of 3 m/s stepping to 9 m/s over 1 m (0.33 s) at 2 s; 0.1 kg on 2 m (half
    # period 1.4 s): the held payload swings past the new equilibrium, where the quasi-static angle only reaches it
    gust = WindConfig("turbulence", 1.0, mean_speed_mps=3.0, direction_deg=180.0, intensity="none",
                      gust_amplitude_mps=6.0, gust_length_m=1.0, gust_start_s=2.0)
    held = held_swing_rad(gust, 0.1, 2.0, 0.0, 8.0)
    assert held == pytest.approx(_planar_held_swing(gust, 0.1, 2.0, 0.0, 8.0), rel=2e-3)
    static = float(drag_angle_rad(gust, 0.1, 2.0, np.arange(0.0, 8.0, 0.01)).max())
    assert held > static + 0.1, (held, static)


def test_only_a_simulated_vehicle_in_a_physical_wind_and_a_logged_flight_have_one():
    base = ForestSpec(density_per_100m2=4.0)
    light, paper = cell_mission(Cell(0.1, 1.0, "light"), 1, base), cell_mission(Cell(0.1, 1.0, "paper"), 1, base)
    t, hung = np.arange(0.0, 5.0, 0.004), np.full((1250, 4), 0.1)
    assert report_wind_truth(paper, {"simulated": True}, t, hung) is None  # eq. 49 drags nothing
    assert report_wind_truth(light, {}, t, hung) is None  # a real vehicle: its wind is not the mission's
    assert report_wind_truth(light, {"simulated": True}, t[:0], hung[:0]) is None  # nothing logged
    truth = report_wind_truth(light, {"simulated": True, "payload_true": {"mass_kg": 0.3}}, t, hung)
    assert truth is not None and (truth["payload_kg"], truth["cable_m"]) == (0.3, 1.0)
    assert truth["held_swing_max_rad"] == pytest.approx(held_swing_rad(light.wind, 0.3, 1.0, 0.0, t[-1]), rel=1e-12)


def test_the_cell_counts_flights_over_the_bound_where_the_wind_alone_or_the_held_payload_was_beyond_it():
    rs = [{"class": "success", "max_swing_rad": s, "wind_drag_angle_max_rad": d, "held_swing_max_rad": h}
          for s, d, h in ((0.40, 0.38, 0.45), (0.40, 0.20, 0.37), (0.40, 0.20, 0.30), (0.30, 0.50, 0.6),
                          (0.20, None, None))]
    out = _cell_summary(rs, 0.35)
    assert (out["over_swing_bound"], out["over_swing_bound_wind"], out["over_swing_bound_held"]) == (3, 1, 2)
    assert out["wind_drag_angle_worst_rad"] == 0.50 and out["held_swing_worst_rad"] == 0.6


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
    # the held payload over the span in which the flown one hung (the cable sensor reads 0 before the lift-off,
    # which comes within the first 4 s): between its largest swing from t = 0 and from 4 s on
    held = r["held_swing_max_rad"]
    assert held_swing_rad(mis.wind, 0.1, 1.0, 4.0, t_end) <= held <= held_swing_rad(mis.wind, 0.1, 1.0, 0.0, t_end)
    assert held > 0.1
    assert summary["cells"][0]["held_swing_worst_rad"] == r["held_swing_max_rad"]
    text = (tmp_path / "envelope.md").read_text()
    assert "| 0.1 | 1 | moderate |" in text and "held still, worst rad" in text
