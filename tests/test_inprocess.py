"""Closed loop in-process: the FlightCore flying the bundled physics (lockstep, wind of eq. 49 on)."""

from pathlib import Path

import pytest

from companion.core.mission import load_mission
from companion.report.metrics import compute_metrics
from lab.inprocess import fly_inprocess

MISSIONS = Path(__file__).resolve().parents[1] / "config" / "missions"


@pytest.mark.slow
def test_forest_safe_smc_ff_meets_targets():
    m = load_mission(MISSIONS / "forest.toml")
    r = compute_metrics(fly_inprocess(m), m)
    assert r["reached_goal"]
    assert r["collisions"] == 0 and r["min_clearance_m"] > 0.0
    assert r["max_swing_rad"] <= 0.3
    assert r["time_to_goal_s"] <= 10.0


@pytest.mark.slow
def test_group1_smc_ff_settles_faster_than_smc():
    m = load_mission(MISSIONS / "group1.toml")
    ff = compute_metrics(fly_inprocess(m), m)
    smc = compute_metrics(fly_inprocess(m.with_(controller="smc")), m)
    assert ff["reached_goal"] and smc["reached_goal"]
    assert ff["swing_settle_after_arrival_s"] is not None and ff["swing_settle_after_arrival_s"] <= 3.5
    assert smc["swing_settle_after_arrival_s"] is None or (
        smc["swing_settle_after_arrival_s"] > ff["swing_settle_after_arrival_s"]
    )


def test_without_swing_sensor_flies_full_cable_envelope():
    m = load_mission(MISSIONS / "forest.toml").with_(timeout_s=5.0, hold_s=0.0)
    log = fly_inprocess(m, swing_sensor=False)
    assert set(log.envelope_mode) == {"full_cable"}
    assert all(r == 1.0 for r in log.r_max_m)
