"""Flights and measurement series for the swing estimator's tests and benchmark (issue 11).

* :func:`record_truth`: fly a mission in-process (cable sensor in the loop, as today) and keep every tick's truth;
* :func:`replay_estimator`: feed an :class:`~lab.swing_sim.EstimatorDriver` a recorded flight offline and measure
  the estimation error against the truth;
* :func:`hop_mission` and :func:`imu_attitude_series`: the identification excitation (a lateral hop at hover,
  flown without feed-forward since the payload is not known yet) and the IMU/attitude samples the autopilot sends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from companion.core.mission import Mission
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig
from companion.estimation.swing_config import SwingEstimatorConfig
from lab.inprocess import fly_inprocess
from lab.swing_sim import EstimatorDriver, SensorConfig, SensorSuite, TruthLog

#: The swing-input paths measured: which simulated messages the estimator gets.
PATHS: dict[str, dict[str, bool]] = {
    "fixes": {"use_imu": False, "use_velocity": False, "use_fixes": True},
    "fixes+vel": {"use_imu": False, "use_velocity": True, "use_fixes": True},
    "imu": {"use_imu": True, "use_velocity": False, "use_fixes": False},
    "imu+vel": {"use_imu": True, "use_velocity": True, "use_fixes": False},
    "fused": {"use_imu": True, "use_velocity": True, "use_fixes": True},
}


def sensors_for(path: str, base: SensorConfig | None = None) -> SensorConfig:
    """The sensor configuration of one of :data:`PATHS` (on top of ``base``)."""
    return replace(base or SensorConfig(), **PATHS[path])


def record_truth(mission: Mission) -> TruthLog:
    """Fly ``mission`` in-process with the cable sensor (today's flight) and return every tick's truth."""
    tl = TruthLog(mission.vehicle)
    fly_inprocess(mission, truth=tl)
    return tl


@dataclass(frozen=True)
class EstimationError:
    """Swing-angle estimation error over a flight (from lift-off to the end), rad.

    rms: √(mean over ticks and both angles of e²); rms_alpha / rms_beta per angle; max: largest |e| of either
    angle; rms_rate: the same as rms for α̇, β̇ (rad/s); within_3sigma: share of ticks with |e| <= 3σ;
    fade_mean: mean trust; cpu_us_per_tick: estimator CPU per control tick (process time, µs);
    updates: measurements fused; ticks: estimates made.
    """

    rms: float
    rms_alpha: float
    rms_beta: float
    max: float
    rms_rate: float
    within_3sigma: float
    fade_mean: float
    cpu_us_per_tick: float
    updates: int
    ticks: int


def error_of(driver: EstimatorDriver) -> EstimationError:
    """The error figures of a driver's history."""
    H = driver.history
    if not H:
        raise ValueError("the estimator never ran (no lift-off?)")
    e = np.array([h[1][:2] - h[2][:2] for h in H])
    er = np.array([h[1][2:] - h[2][2:] for h in H])
    sig = np.array([h[3] for h in H])
    fade = np.array([h[4] for h in H])
    return EstimationError(
        rms=float(np.sqrt(np.mean(e * e))), rms_alpha=float(np.sqrt(np.mean(e[:, 0] ** 2))),
        rms_beta=float(np.sqrt(np.mean(e[:, 1] ** 2))), max=float(np.max(np.abs(e))),
        rms_rate=float(np.sqrt(np.mean(er * er))), within_3sigma=float(np.mean(np.hypot(e[:, 0], e[:, 1]) <= 3 * sig)),
        fade_mean=float(np.mean(fade)), cpu_us_per_tick=1e6 * driver.cpu_s / len(H), updates=driver.updates,
        ticks=len(H),
    )


def replay_estimator(truth: TruthLog, sensors: SensorConfig, seed: int = 0,
                     est_config: SwingEstimatorConfig | None = None,
                     model_params: VehicleParams | None = None) -> tuple[EstimationError, EstimatorDriver]:
    """Feed a recorded flight to a fresh estimator (offline) and measure its error."""
    d = EstimatorDriver(truth.params, sensors, seed=seed, est_config=est_config, model_params=model_params)
    for s in truth.samples:
        d.step(s)
    return error_of(d), d


def hop_mission(params: VehicleParams, hop_m: float = 2.0, wind_scale: float = 1.0,
                controller: str = "smc") -> Mission:
    """Climb to 2 m, hop ``hop_m`` north (no planner), hold 8 s: the identification excitation."""
    return Mission(
        name="payload-id-hop", start_ned_m=np.array([0.0, 0.0, -2.0]), goal_ned_m=np.array([hop_m, 0.0, -2.0]),
        planner="none", controller=controller, timeout_s=20.0,
        wind=WindConfig("paper" if wind_scale > 0.0 else "none", wind_scale), vehicle=params, hold_s=8.0,
    )


def cruise_start_s(truth: TruthLog, altitude_m: float, tol_m: float = 0.25) -> float:
    """First time the airframe is within ``tol_m`` of the mission altitude (z = −altitude_m)."""
    for s in truth.samples:
        if abs(s.x[2] + altitude_m) < tol_m:
            return s.t_s
    raise ValueError("never reached the mission altitude")


def imu_attitude_series(truth: TruthLog, sensors: SensorConfig | None = None, seed: int = 0,
                        t_from_s: float = -math.inf, t_to_s: float = math.inf
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, accel FRD, euler) at the IMU messages' times in [t_from_s, t_to_s], each IMU sample paired with the
    latest ATTITUDE received (what a companion logging HIGHRES_IMU and ATTITUDE has)."""
    suite = SensorSuite(truth.params, sensors, seed)
    t, f, e = [], [], []
    last_att = None
    for s in truth.samples:
        suite.observe(s)
        for msg in suite.arrived(s.t_s):
            if msg.kind == "att":
                last_att = msg
            elif msg.kind == "imu" and last_att is not None and t_from_s <= msg.t_valid <= t_to_s:
                t.append(msg.t_valid)
                f.append(msg.data[0])
                e.append(last_att.data[0])
    return np.array(t), np.array(f), np.array(e)
