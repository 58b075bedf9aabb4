"""The payload identified from the flight's own IMU, next to the declared one (issue 28's mis-declared payloads):
the watch on its own (samples from the bundled physics, lab.swing_sim) and a lockstep flight over real MAVLink
whose bundled vehicle carries a payload 40 % heavier on a cable 30 % longer than the mission declares."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from companion.core.vehicle_params import VehicleParams
from companion.estimation.payload_id import autocorrelation_time
from companion.estimation.payload_watch import IMU_STEP_S, PayloadWatch
from lab.swing_scenarios import cruise_start_s, hop_mission, imu_attitude_series, record_truth
from lab.swing_sim import SensorConfig

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

ROOT = Path(__file__).resolve().parents[1]


@cache
def _hop_series(m: float, l: float, wind: float):
    vp = replace(VehicleParams(), m=m, l=l)
    truth = record_truth(hop_mission(vp, hop_m=2.0, wind_scale=wind))
    t0 = cruise_start_s(truth, 2.0)
    t, f, e = imu_attitude_series(truth, SensorConfig(), seed=1, t_from_s=t0 - 1.0, t_to_s=t0 + 10.0)
    return vp, t0, t, f, e


def _watched(m: float, l: float, wind: float) -> tuple[VehicleParams, PayloadWatch]:
    vp, t0, t, f, e = _hop_series(m, l, wind)
    w = PayloadWatch(vp.M, vp.g)
    for ti, fi, ei in zip(t, f, e, strict=True):  # before the start: not kept
        w.on_imu(float(ti), tuple(fi))
        w.on_attitude(float(ti), tuple(ei))
        if ti >= t0:
            w.start(float(ti))
    return vp, w


def test_identifies_a_heavier_longer_payload_and_says_it_differs_from_the_declared_one():
    _, w = _watched(0.35, 1.3, wind=0.0)
    out = w.facts(declared_mass_kg=0.25, declared_cable_m=1.0)
    idf = out["identified"]
    assert idf["ok"], idf
    assert idf["mass_kg"] == pytest.approx(0.35, rel=0.05) and idf["cable_length_m"] == pytest.approx(1.3, rel=0.03)
    assert out["declared"] == {"mass_kg": 0.25, "cable_length_m": 1.0}
    assert [s.split(":")[0] for s in out["mismatch"]] == ["payload mass", "cable length"]
    # thinned to ~50 Hz from the start only: the hop's IMU comes at 50 Hz, so (nearly) every sample after t0
    assert idf["samples"] >= 0.9 * 10.0 / 0.02 and idf["window_s"] <= 10.0 + IMU_STEP_S
    assert w.facts(0.35, 1.3)["mismatch"] == []  # declared right: no mismatch


def test_in_eq49_wind_the_sigma_covers_the_truth():
    """Wind colours the residual: the corrected σ must cover the true values (the white-residual σ did not)."""
    _, w = _watched(0.25, 1.0, wind=1.0)
    idf = w.facts(0.25, 1.0)["identified"]
    assert idf["residual_tau_samples"] > 1.5
    assert abs(idf["mass_kg"] - 0.25) <= 2.0 * idf["mass_sigma_kg"]
    assert abs(idf["cable_length_m"] - 1.0) <= 2.0 * idf["cable_length_sigma_m"]


def test_without_a_cruise_or_samples_it_says_why():
    w = PayloadWatch(1.25)
    assert w.facts(0.25, 1.0)["identified_detail"] == "the cruise never started"
    w = PayloadWatch(1.25)
    w.start(0.0)
    for k in range(30):
        w.on_imu(0.02 * k, (0.0, 0.0, -9.81))
    w.on_imu(math.nan, (0.0, 0.0, -9.81))
    w.on_imu(5.0, (math.nan, 0.0, -9.81))
    out = w.facts(0.25, 1.0)
    assert out["identified"] is None and "too few samples: 30 IMU, 0 attitude" in out["identified_detail"]
    assert "HIGHRES_IMU" in out["identified_detail"]


def test_samples_out_of_order_before_the_start_or_after_the_window_are_not_kept():
    w = PayloadWatch(1.25, window_s=1.0)
    w.on_imu(0.5, (0.0, 0.0, -9.81))  # before the cruise
    w.start(1.0)
    w.start(3.0)  # the first start counts
    for t in (1.0, 1.01, 1.1, 1.05, 1.2, 2.5):  # 1.01: closer than IMU_STEP_S; 1.05: back in time; 2.5: past 1 s
        w.on_imu(t, (0.0, 0.0, -9.81))
    assert [s[0] for s in w._imu] == [1.0, 1.1, 1.2]


def test_autocorrelation_time_of_white_and_coloured_residuals():
    rng = np.random.default_rng(3)
    white = rng.normal(size=20000)
    assert autocorrelation_time(np.concatenate([white[:10000], white[10000:]]), 10000) == pytest.approx(1.0, abs=0.2)
    rho = 0.9  # AR(1): τ = (1 + ρ) / (1 − ρ) = 19
    x = np.zeros(20000)
    for k in range(1, len(x)):
        x[k] = rho * x[k - 1] + white[k]
    assert autocorrelation_time(x, 10000) == pytest.approx(19.0, rel=0.2)


@pytest.mark.slow
def test_lockstep_flight_reports_the_identified_payload_beside_the_declared_one(tmp_path):
    """Table 2's forest without wind, the bundled vehicle carrying 0.35 kg on 1.3 m while the mission says 0.25 kg
    on 1 m: flies clean, and the report and summary give the identified payload next to the declared one."""
    forest = (ROOT / "config" / "missions" / "forest.toml").read_text().replace('model = "paper"', 'model = "none"')
    mission = tmp_path / "calm.toml"
    mission.write_text(forest)
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--mission", str(mission),
                        "--no-zenoh", "--no-plots", "--planner", "shaped", "--run-dir", str(run),
                        "--true-payload-mass-kg", "0.35", "--true-cable-length-m", "1.3"],
                       capture_output=True, text=True, timeout=240, cwd=ROOT)
    rep = json.loads((run / "report.json").read_text())
    assert r.returncode == 0, (rep.get("outcome"), r.stderr[-2000:])
    assert rep["outcome"] == "completed" and rep["collisions"] == 0
    pay = rep["payload"]
    assert pay["declared"] == {"mass_kg": 0.25, "cable_length_m": 1.0}
    assert pay["true"] == {"mass_kg": 0.35, "cable_length_m": 1.3}
    # the clearance and collisions are scored where the true payload hung: 1.3 m below the airframe, not 1 m
    log = np.load(run / "flight_log.npz")
    hang = np.linalg.norm(log["payload_pos_ned_m"] - log["pos_ned_m"], axis=1)
    assert np.nanmin(hang) == pytest.approx(1.3) and np.nanmax(hang) == pytest.approx(1.3)
    idf = pay["identified"]
    assert idf["ok"], idf
    assert idf["mass_kg"] == pytest.approx(0.35, rel=0.05) and idf["cable_length_m"] == pytest.approx(1.3, rel=0.05)
    assert len(pay["mismatch"]) == 2 and "the payload is not what the mission declares" in r.stderr
    summary = (run / "summary.txt").read_text()
    assert "declared 0.250 kg on 1.00 m; identified 0.3" in summary and "true 0.350 kg on 1.30 m" in summary
