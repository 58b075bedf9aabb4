"""The swing estimator against the truth of whole flights: the Table 2 forest on the bundled physics under eq. 49's
wind, with the messages real autopilots send (lab.swing_sim: PX4-SITL-like IMU noise and bias, attitude with noise
and bias, 10 Hz payload fixes 0.1–0.2 s late with 15 % dropped and a 2.5 s gap). Issue 11's targets: RMS <= 0.02
rad with payload fixes, <= 0.03 rad sensorless; closed loop max swing <= 0.26 / 0.27 rad with no loss of clearance
or time against the cable sensor. Deterministic (fixed seeds, lockstep in-process flights)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from companion.config import shipped_config
from companion.core.mission import load_mission
from companion.report.metrics import compute_metrics
from lab.inprocess import fly_inprocess
from lab.swing_scenarios import replay_estimator, sensors_for
from lab.swing_sim import EstimatorDriver, ImuNoise, TruthLog

pytestmark = pytest.mark.slow

FOREST = load_mission(shipped_config("missions/forest.toml"))


@pytest.fixture(scope="module")
def forest():
    """The forest flown on the cable sensor (today's flight): its truth and its report."""
    truth = TruthLog(FOREST.vehicle)
    report = compute_metrics(fly_inprocess(FOREST, truth=truth), FOREST)
    return truth, report


@pytest.mark.parametrize("path,target", [
    ("fixes+vel", 0.02),  # measured 0.0096: payload fixes with the vehicle's own velocity (every autopilot sends it)
    ("fused", 0.02),  # measured 0.0049
    ("imu+vel", 0.03),  # measured 0.0026: sensorless (IMU, attitude, commanded thrust, velocity)
    ("imu", 0.03),  # measured 0.0047: the IMU path alone, without the velocity
])
def test_estimation_error_meets_issue_11_targets(forest, path, target):
    truth, _ = forest
    e, d = replay_estimator(truth, sensors_for(path))
    assert e.rms <= target, e
    assert e.within_3sigma >= 0.98  # the covariance does not claim more than it knows
    assert e.ticks > 3000 and e.updates > 100
    assert d.est is not None and d.est.dropped_late <= 2  # fixes taken before the cable went taut, arriving after


def test_fixes_alone_miss_the_fixes_target_but_stay_usable(forest):
    """Payload fixes without any vehicle data but attitude and thrust: 0.0234 rad, above the 0.02 target (the force
    on the airframe is then only seen through the swing itself); kept as a regression bound."""
    e, _ = replay_estimator(forest[0], sensors_for("fixes"))
    assert 0.015 < e.rms <= 0.03 and e.within_3sigma >= 0.98


def test_sensorless_with_px4_sih_accelerometer_noise(forest):
    """SIH's accelerometer noise is 17–60× Gazebo's (0.5, 1.7, 1.4 m/s² per sample); with the velocity the
    sensorless path still meets 0.03 rad (measured 0.0100)."""
    sensors = replace(sensors_for("imu+vel"), imu=ImuNoise.px4_sih())
    e, _ = replay_estimator(forest[0], sensors)
    assert e.rms <= 0.03 and e.within_3sigma >= 0.98


@pytest.mark.parametrize("path,max_swing", [("imu+vel", 0.27), ("fixes+vel", 0.26)])
def test_feedforward_on_the_estimate_flies_the_forest(forest, path, max_swing):
    """Feed-forward and envelope on the estimate instead of the cable sensor (in-process: cable sensor 0.249 rad,
    7.000 s, 0.604 m; measured on the estimate: imu+vel 0.248 rad, 7.004 s, 0.606 m; fixes+vel 0.247 rad,
    7.004 s, 0.602 m)."""
    _, cable = forest
    d = EstimatorDriver(FOREST.vehicle, sensors_for(path), seed=0)
    log = fly_inprocess(FOREST, swing_source="estimate", estimator=d)
    r = compute_metrics(log, FOREST)
    modes = log.envelope_mode
    first = modes.index("swing")  # until the cable is taut there is no estimate: full cable
    assert first < 400 and set(modes[first:]) == {"swing"}  # from lift-off on the estimate stood in throughout
    assert r["reached_goal"] and r["collisions"] == 0
    assert r["max_swing_rad"] <= max_swing, r["max_swing_rad"]
    assert r["time_to_goal_s"] <= cable["time_to_goal_s"] + 0.05
    assert r["min_clearance_m"] >= cable["min_clearance_m"] - 0.02
