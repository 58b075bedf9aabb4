"""Fly a mission in-process: the bundled vehicle's physics and the companion's FlightCore, in lockstep.

No MAVLink, no sockets: each control tick the runner builds an :class:`~companion.estimation.estimate.Estimate` from
the simulated state (swing from the sim's cable angles, as the bundled vehicle's SWING sensor would send),
calls the very same :class:`~companion.flight.core.FlightCore` the MAVLink app uses, applies the command
with ``VehicleSim.set_attitude_target`` and steps the physics for one control period. Used for tuning and
for the fast evaluation mode; the vehicle starts landed on the ground below the mission's start.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.control import ControllerConfig
from companion.core.mission import Mission
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from companion.report.metrics import FlightLog
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
) -> FlightLog:
    """Fly ``mission`` from take-off to the end of the hold (or timeout); returns the flight log.

    ``swing_sensor`` False flies without swing measurement (full-cable envelope, no feed-forward).
    With ``record`` False only the last tick is kept (for throughput measurements).
    """
    n_sub = max(1, round(control_period_s / physics_dt_s))
    x0 = np.zeros(16)
    x0[0:2] = mission.start_ned_m[:2]
    sim = VehicleSim(mission.vehicle, wind=mission.wind, dt_s=physics_dt_s, x0=x0)
    sim.armed = True
    core = FlightCore(mission, gains or ControllerConfig(), VehicleProfile())
    flog = FlightLog(
        planner=mission.planner, controller=mission.controller, mission=mission.name, obstacles=mission.obstacles
    )
    wall0 = time.perf_counter()
    t_end = mission.timeout_s + mission.hold_s + 1.0
    while sim.t_s < t_end:
        swing = sim.swing if swing_sensor else None
        est = Estimate(
            t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
            rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=swing,
            swing_source="cable_sensor" if swing_sensor else "none",
        )
        cmd = core.update(est, mission.obstacles)
        if record or len(flog) == 0:
            flog.append(sim.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, sim.swing, sim.payload_pos_ned_m, cmd)
        if stop_when_done and core.phase == "done":
            break
        sim.set_attitude_target(cmd.q_ned_frd_wxyz, cmd.thrust_n)
        sim.step(n_sub)
    flog.wall_time_s = time.perf_counter() - wall0
    return flog
