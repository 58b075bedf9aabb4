"""Fly a mission in-process: the bundled vehicle's physics and the companion's FlightCore, in lockstep.

No MAVLink, no sockets: each control tick the runner builds an :class:`~companion.estimation.estimate.Estimate` from
the simulated state (swing from the sim's cable angles, as the bundled vehicle's SWING sensor would send),
calls the very same :class:`~companion.flight.core.FlightCore` the MAVLink app uses, applies the command
with ``VehicleSim.set_attitude_target`` and steps the physics for one control period. Used for tuning and
for the fast evaluation mode; the vehicle starts landed on the ground below the mission's start.

``swing_source="estimate"`` replaces the cable sensor by the swing estimator (issue 11) fed with the messages
a real autopilot would send, simulated from the physics by :mod:`lab.swing_sim` (IMU, attitude, velocity,
delayed and dropped payload fixes); ``truth`` records every tick for offline estimation.

``link_delay_s`` / ``link_jitter_s`` put a slow link on both directions (:class:`SlowLink`: each estimate and
each command takes delay ± jitter, whole control periods; the core flies on the newest estimate that has arrived,
the vehicle applies commands in the order they arrive), for the loop-lag tests.
"""

from __future__ import annotations

import heapq
import logging
import time
from collections.abc import Callable

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.control import ControllerConfig
from companion.core.mission import Mission
from companion.core.vehicle_params import VehicleParams
from companion.estimation.estimate import Estimate
from companion.estimation.swing_measurement import SLACK_FRACTION
from companion.flight.core import FlightCore
from companion.flight.phase import CorePhase
from companion.report.metrics import FlightLog
from lab.swing_sim import EstimatorDriver, TruthLog, TruthRecorder
from sim_bridge.inner_loop import AIR_MODE_ALL
from sim_bridge.physics import VehicleSim

log = logging.getLogger(__name__)


class SlowLink:
    """Both directions of a slow, jittery link, counted in control ticks (seeded, deterministic).

    Each estimate and each command takes ``delay_s`` ± ``jitter_s`` (uniform), rounded to whole ticks. The core
    flies on the newest estimate that has arrived (the companion refuses time markers that go backwards); the
    vehicle applies commands in the order they arrive, older ones too (PX4 and ArduPilot check no order), so jitter
    makes it fly a reshuffled command stream: in real time that costs more margin than the same mean delay.
    """

    def __init__(self, delay_s: float, jitter_s: float, period_s: float, seed: int = 0) -> None:
        self.delay_s, self.jitter_s, self.period_s = delay_s, jitter_s, period_s
        self._rng = np.random.default_rng(seed)
        self._up: list[tuple[int, int, Estimate]] = []  # (arrival tick, sent tick, estimate)
        self._down: list[tuple[int, int, object]] = []  # (arrival tick, sent tick, command)
        self._first: Estimate | None = None
        self._newest: tuple[int, Estimate] | None = None

    def _ticks(self) -> int:
        d = self.delay_s + (self._rng.uniform(-self.jitter_s, self.jitter_s) if self.jitter_s > 0.0 else 0.0)
        return max(0, round(d / self.period_s))

    def to_core(self, tick: int, est: Estimate) -> Estimate:
        """Send this tick's estimate; returns the one the core flies on now."""
        if self._first is None:
            self._first = est
        heapq.heappush(self._up, (tick + self._ticks(), tick, est))
        while self._up and self._up[0][0] <= tick:
            _, sent, e = heapq.heappop(self._up)
            if self._newest is None or sent > self._newest[0]:
                self._newest = (sent, e)
        return self._first if self._newest is None else self._newest[1]

    def to_vehicle(self, tick: int, cmd) -> list:
        """Send this tick's command; returns the commands arriving now, in arrival order."""
        heapq.heappush(self._down, (tick + self._ticks(), tick, cmd))
        out = []
        while self._down and self._down[0][0] <= tick:
            out.append(heapq.heappop(self._down)[2])
        return out


def _cable_sensor(sim: VehicleSim) -> np.ndarray:
    """The swing [α, β, α̇, β̇] (rad, rad/s) the companion reads from the bundled vehicle's cable-angle sensor: the
    sim's angles, and zeros while the payload lies on the ground nearer than
    :data:`~companion.estimation.swing_measurement.SLACK_FRACTION` of the cable (the sensor sends that reach and the
    companion reads a slack cable as no swing; the direction of a cable a few micrometres long is not one)."""
    if sim.payload_on_ground:
        reach = float(np.linalg.norm(sim.payload_pos_ned_m - sim.pos_ned_m))
        if reach < SLACK_FRACTION * sim.params.l:
            return np.zeros(4)
    return sim.swing


def _swing_input(mission: Mission, swing_source: str | None, swing_sensor: bool,
                 estimator: EstimatorDriver | None) -> tuple[str, EstimatorDriver | None]:
    """(the swing source, the estimator driver when it is ``"estimate"``) of :func:`fly_inprocess`'s arguments."""
    source = swing_source or ("cable_sensor" if swing_sensor else "none")
    if source not in ("cable_sensor", "none", "estimate"):
        raise ValueError(f"swing_source: must be cable_sensor, none or estimate, got {swing_source!r}")
    if source == "estimate" and estimator is None:
        estimator = EstimatorDriver(mission.vehicle, seed=0)
    return source, (estimator if source == "estimate" else None)


def _estimate(sim: VehicleSim, source: str, driver: EstimatorDriver | None, sample) -> Estimate:
    """What the core is told this tick: the true state of ``sim`` with the swing of ``source`` (the cable sensor,
    none, or the estimator ``driver`` stepped with this tick's ``sample``)."""
    if driver is not None:
        se = driver.step(sample)
        return Estimate(
            t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
            rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=None if se is None else se.swing,
            swing_source="none" if se is None else "estimate",
            swing_fade=1.0 if se is None else se.fade, swing_bound_rad=None if se is None else se.bound_rad,
        )
    swing = _cable_sensor(sim) if source == "cable_sensor" else None
    return Estimate(
        t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
        rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=swing, swing_source=source,
    )


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
    link_jitter_s: float = 0.0,
    link_seed: int = 0,
    true_vehicle: VehicleParams | None = None,
    on_tick: Callable[[FlightCore, float], None] | None = None,
    air_mode: int = AIR_MODE_ALL,
) -> FlightLog:
    """Fly ``mission`` from take-off to the end of the hold (or timeout); returns the flight log, its ``outcome``
    the core's verdict (``completed``, ``timeout``, ``no_route``; None if it had not ended).

    ``swing_sensor`` False flies without swing measurement (full-cable envelope, no feed-forward).
    ``swing_source`` overrides it: ``"cable_sensor"``, ``"none"`` or ``"estimate"`` (the swing estimator fed
    by ``estimator``, default :class:`~lab.swing_sim.EstimatorDriver` with its default sensors, seed 0).
    ``on_tick(core, t_s)``: called before each tick's update (orders the sequence would give: a pause, a resume).
    ``truth``: if given, every tick's true state, commanded thrust and specific force is appended to it.
    With ``record`` False only the last tick is kept (for throughput measurements). ``true_vehicle``: the vehicle
    the physics flies when it differs from the mission's (a mis-declared payload: the companion flies
    ``mission.vehicle``); the wind is the mission's ``[wind]``, eq. 49 or physical drag, never told to the core.
    ``air_mode``: the vehicle mixer's PX4 ``MC_AIRMODE`` (:mod:`sim_bridge.inner_loop`; the bundled vehicle's 2).
    """
    source, driver = _swing_input(mission, swing_source, swing_sensor, estimator)
    recorder = TruthRecorder() if (driver is not None or truth is not None) else None
    n_sub = max(1, round(control_period_s / physics_dt_s))
    x0 = np.zeros(16)
    x0[0:2] = mission.start_ned_m[:2]
    sim = VehicleSim(true_vehicle or mission.vehicle, wind=mission.wind, dt_s=physics_dt_s, x0=x0)
    sim.armed = True
    sim.air_mode = air_mode
    core = FlightCore(mission, gains or ControllerConfig(), VehicleProfile(), period_s=control_period_s)
    link = SlowLink(link_delay_s, link_jitter_s, control_period_s, link_seed) if link_delay_s > 0.0 else None
    tick = 0
    flog = FlightLog(
        planner=mission.planner, controller=mission.controller, mission=mission.name, obstacles=mission.obstacles
    )
    wall0 = time.perf_counter()
    t_end = mission.timeout_s + mission.hold_s + 1.0
    while sim.t_s < t_end:
        sample = recorder.sample(sim) if recorder is not None else None
        est = _estimate(sim, source, driver, sample)
        if link is not None:
            est = link.to_core(tick, est)
        if on_tick is not None:  # what the flight sequence would order now (a test's pause, a hold)
            on_tick(core, sim.t_s)
        cmd = core.update(est, mission.obstacles)
        if core.phase == CorePhase.IDENTIFY:  # no IMU stream here: the hop is skipped, the declared payload flies
            log.info("in-process flights do not identify the payload ([payload] identify): flying the declared one")
            core.end_identify(None)
        if driver is not None:
            driver.command(sim.t_s, cmd.thrust_n)
        if truth is not None and sample is not None:
            truth.samples.append(TruthRecorder.commanded(sample, cmd.thrust_n))
        if record or len(flog) == 0:
            flog.append(sim.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, _cable_sensor(sim),
                        sim.payload_pos_ned_m, cmd)
        if stop_when_done and core.phase == "done":
            break
        for applied in (link.to_vehicle(tick, cmd) if link is not None else (cmd,)):
            sim.set_attitude_target(applied.q_ned_frd_wxyz, applied.thrust_n)
        sim.step(n_sub)
        tick += 1
    flog.wall_time_s = time.perf_counter() - wall0
    flog.obstacle_clock_t0_s = core.t0_s  # where the report places the moving obstacles (report.scoring)
    flog.outcome = core.result
    flog.planning = core.planner.facts()
    return flog
