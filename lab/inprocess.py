"""Fly a mission in-process: the bundled vehicle's physics and the companion's FlightCore, in lockstep.

No MAVLink, no sockets: each control tick the runner builds an :class:`~companion.estimation.estimate.Estimate` from
the simulated state (swing from the sim's cable angles, as the bundled vehicle's SWING sensor would send),
calls the very same :class:`~companion.flight.core.FlightCore` the MAVLink app uses, applies the command
with ``VehicleSim.set_attitude_target`` and steps the physics for one control period. Used for tuning and
for the fast evaluation mode; the vehicle starts landed on the ground below the mission's start.

``swing_source="estimate"`` replaces the cable sensor by the swing estimator (issue 11) fed with the messages
a real autopilot would send, simulated from the physics by :mod:`lab.swing_sim` (IMU, attitude, velocity,
delayed and dropped payload fixes); ``truth`` records every tick for offline estimation.

``link_delay_s`` puts a delay line on both directions (whole control periods): the core sees the estimate of
that long ago and the vehicle gets each command that much later, like a slow link (the loop-lag tests).
"""

from __future__ import annotations

import logging
import time
from collections import deque

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.control import ControllerConfig
from companion.core.mission import Mission
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from companion.report.metrics import FlightLog
from lab.swing_sim import EstimatorDriver, TruthLog, TruthRecorder
from sim_bridge.physics import VehicleSim

log = logging.getLogger(__name__)


def fly_inprocess(
    mission: Mission,
    *,
    control_period_s: float = 0.004,
    record: bool = True,
    gains: ControllerConfig | None = None,
    swing_sensor: bool = True,
    physics_dt_s: float = 1e-3,
    stop_when_done: bool = True,
    swing_source: str | None = None,
    estimator: EstimatorDriver | None = None,
    truth: TruthLog | None = None,
    link_delay_s: float = 0.0,
) -> FlightLog:
    """Fly ``mission`` from take-off to the end of the hold (or timeout); returns the flight log.

    ``swing_sensor`` False flies without swing measurement (full-cable envelope, no feed-forward).
    ``swing_source`` overrides it: ``"cable_sensor"``, ``"none"`` or ``"estimate"`` (the swing estimator fed
    by ``estimator``, default :class:`~lab.swing_sim.EstimatorDriver` with its default sensors, seed 0).
    ``truth``: if given, every tick's true state, commanded thrust and specific force is appended to it.
    With ``record`` False only the last tick is kept (for throughput measurements).
    """
    source = swing_source or ("cable_sensor" if swing_sensor else "none")
    if source not in ("cable_sensor", "none", "estimate"):
        raise ValueError(f"swing_source: must be cable_sensor, none or estimate, got {swing_source!r}")
    if source == "estimate" and estimator is None:
        estimator = EstimatorDriver(mission.vehicle, seed=0)
    driver = estimator if source == "estimate" else None
    recorder = TruthRecorder() if (driver is not None or truth is not None) else None
    n_sub = max(1, round(control_period_s / physics_dt_s))
    x0 = np.zeros(16)
    x0[0:2] = mission.start_ned_m[:2]
    sim = VehicleSim(mission.vehicle, wind=mission.wind, dt_s=physics_dt_s, x0=x0)
    sim.armed = True
    core = FlightCore(mission, gains or ControllerConfig(), VehicleProfile(), period_s=control_period_s)
    n_delay = max(0, round(link_delay_s / control_period_s))
    seen: deque[Estimate] = deque()  # estimates on their way to the core
    sent: deque = deque()  # commands on their way to the vehicle
    flog = FlightLog(
        planner=mission.planner, controller=mission.controller, mission=mission.name, obstacles=mission.obstacles
    )
    wall0 = time.perf_counter()
    t_end = mission.timeout_s + mission.hold_s + 1.0
    while sim.t_s < t_end:
        sample = recorder.sample(sim) if recorder is not None else None
        if driver is not None:
            se = driver.step(sample)
            est = Estimate(
                t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
                rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=None if se is None else se.swing,
                swing_source="none" if se is None else "estimate",
                swing_fade=1.0 if se is None else se.fade, swing_bound_rad=None if se is None else se.bound_rad,
            )
        else:
            swing = sim.swing if source == "cable_sensor" else None
            est = Estimate(
                t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
                rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=swing, swing_source=source,
            )
        if n_delay:
            seen.append(est)
            est = seen.popleft() if len(seen) > n_delay else seen[0]
        cmd = core.update(est, mission.obstacles)
        if driver is not None:
            driver.command(sim.t_s, cmd.thrust_n)
        if truth is not None and sample is not None:
            truth.samples.append(TruthRecorder.commanded(sample, cmd.thrust_n))
        if record or len(flog) == 0:
            flog.append(sim.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, sim.swing, sim.payload_pos_ned_m, cmd)
        if stop_when_done and core.phase == "done":
            break
        applied = cmd
        if n_delay:
            sent.append(cmd)
            applied = sent.popleft() if len(sent) > n_delay else None
        if applied is not None:
            sim.set_attitude_target(applied.q_ned_frd_wxyz, applied.thrust_n)
        sim.step(n_sub)
    flog.wall_time_s = time.perf_counter() - wall0
    return flog
