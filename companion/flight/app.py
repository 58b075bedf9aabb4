"""The companion's flight application: asyncio around the pure flight core.

Data flows one way, once per control tick::

    MAVLink telemetry ─▶ VehicleState ─▶ Estimate ─▶ FlightCore (plan ▶ control) ─▶ SET_ATTITUDE_TARGET

Two coroutines share the work inside a ``TaskGroup``:

* the **tick loop** answers every control period with a setpoint. In real time it runs on a monotonic
  schedule (deadlines ``t0 + k·period``, no drift; a tick that starts more than one period late is counted
  as late and skipped deadlines are not made up). In lockstep it is driven by the vehicle's end-of-step
  marker (``SYSTEM_TIME``): every new marker is answered by exactly one setpoint, which is what advances
  simulated time.
* the **sequencer** does what a pilot would, PX4's way: wait for the autopilot's HEARTBEAT, request the
  message rates it needs, let setpoints stream for a second, arm, switch to OFFBOARD, fly the mission
  (the flight core climbs, cruises and holds at the goal), then command AUTO.LAND and wait for landed and
  disarmed. Ctrl-C (or :meth:`FlightApp.request_abort`) switches the vehicle to AUTO.LOITER (hold), lands
  if asked, and ends the run; the caller then writes the report.

Our own HEARTBEAT (MAV_TYPE_ONBOARD_CONTROLLER, component 191) goes out at 1 Hz.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots.profile import VehicleProfile, profile_by_name, profile_for_autopilot
from companion.core.mission import Mission
from companion.core.model import payload_offset_ned_m
from companion.core.obstacles import Obstacle
from companion.core.rotations import quat_from_euler
from companion.errors import LinkError
from companion.estimation.estimate import Estimate
from companion.estimation.vehicle_state import VehicleState
from companion.flight.core import Command, FlightCore
from companion.mavlink_io.codec import send_set_attitude_target
from companion.mavlink_io.commands import MavCommander
from companion.mavlink_io.link import MavlinkLink
from companion.report.metrics import FlightLog

log = logging.getLogger(__name__)

# SET_ATTITUDE_TARGET type_mask: attitude + thrust used, body rates ignored
ATT_TYPE_MASK = (
    mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
    | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
    | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
)


class TelemetrySink(Protocol):
    """Where the app publishes per-tick data (the Zenoh streams implement this)."""

    def on_tick(self, est: Any, cmd: Command | None, app: FlightApp) -> None: ...


@dataclass
class FlyOptions:
    """Everything a flight needs besides the mission itself."""

    connect: str = "udpin://0.0.0.0:14540"
    rate_hz: float = 250.0
    lockstep: bool = False
    profile: VehicleProfile | None = None  # None: chosen from the autopilot's HEARTBEAT
    hover_thrust_norm: float | None = None  # overrides the chosen profile's hover thrust
    gains: Any = None
    payload_sysid: int | None = 2
    swing_input: str = "auto"
    heartbeat_timeout_s: float = 20.0
    prestream_s: float = 1.0
    land_on_abort: bool = True
    land_timeout_s: float = 30.0
    tlog_path: Path | None = None
    wall_timeout_s: float | None = None
    obstacle_source: Callable[[float], Sequence[Obstacle]] | None = None
    telemetry: TelemetrySink | None = None
    # Awaited once the autopilot is known, before arming (its system id decides e.g. the Zenoh vehicle id);
    # may set ``app.telemetry`` and ``app.obstacle_source``.
    on_connected: Callable[[FlightApp], Awaitable[None]] | None = None
    sock: socket.socket | None = None  # an already bound UDP socket for the link (fly --sitl reserves one)


@dataclass
class LoopStats:
    """Tick timing: compute time per tick (receive → setpoint sent) and lateness in real time."""

    ticks: int = 0
    late_ticks: int = 0
    tick_s: list[float] = field(default_factory=list)
    send_s: list[float] = field(default_factory=list)
    jitter_s: list[float] = field(default_factory=list)
    first: tuple[float, float] | None = None  # (wall monotonic s, vehicle time s) of the first tick with telemetry
    last: tuple[float, float] | None = None

    def summary(self) -> dict[str, float | int]:
        """ticks; tick (compute) and send time p50/p99/max (ms); late ticks; jitter p99 (ms, real time only)."""
        t = np.array(self.tick_s) if self.tick_s else np.zeros(1)
        snd = np.array(self.send_s) if self.send_s else np.zeros(1)
        j = np.array(self.jitter_s) if self.jitter_s else np.zeros(1)
        return {
            "ticks": self.ticks,
            "tick_ms_p50": float(np.percentile(t, 50) * 1e3),
            "tick_ms_p99": float(np.percentile(t, 99) * 1e3),
            "tick_ms_max": float(t.max() * 1e3),
            "send_ms_p50": float(np.percentile(snd, 50) * 1e3),
            "send_ms_p99": float(np.percentile(snd, 99) * 1e3),
            "late_ticks": self.late_ticks,
            "jitter_ms_p99": float(np.percentile(np.abs(j), 99) * 1e3),
            "realtime_factor": self.realtime_factor(),
        }

    def realtime_factor(self) -> float | None:
        """Vehicle seconds flown per wall second between the first and the last tick (lockstep speed)."""
        if self.first is None or self.last is None or self.last[0] <= self.first[0]:
            return None
        return (self.last[1] - self.first[1]) / (self.last[0] - self.first[0])


class FlightApp:
    """One mission flown over one MAVLink link. Use ``await app.run()``; then read ``app.log`` etc."""

    def __init__(self, mission: Mission, opts: FlyOptions) -> None:
        self.mission = mission
        self.opts = opts
        self.state = VehicleState(
            cable_length_m=mission.vehicle.l, payload_sysid=opts.payload_sysid, swing_input=opts.swing_input
        )
        self.swing_sources: dict[str, int] = {}
        self._last_swing_source = ""
        self.link = MavlinkLink(opts.connect, self._on_message, tlog=opts.tlog_path, sock=opts.sock)
        self.link.on_datagram_done = self._on_datagram_done
        self.profile = opts.profile or profile_by_name("px4", opts.hover_thrust_norm)
        self.core = FlightCore(mission, gains=opts.gains, profile=self.profile)
        self.log = FlightLog(
            planner=mission.planner, controller=mission.controller, mission=mission.name, obstacles=mission.obstacles
        )
        self.stats = LoopStats()
        self.phase = "connect"
        self.outcome = "running"
        self.abort_reason: str | None = None
        self.last_cmd: Command | None = None
        self.telemetry: TelemetrySink | None = opts.telemetry
        self.obstacle_source: Callable[[float], Sequence[Obstacle]] | None = opts.obstacle_source
        self._last_obstacles: Sequence[Obstacle] | None = None
        self._obstacles_seen: dict[tuple, Obstacle] = {}
        self._marker = asyncio.Event()
        self._marker_pending = False  # a new lockstep marker arrived in the datagram being handled
        self._woke_sequencer = False  # ... and so did an answer (COMMAND_ACK, PARAM_VALUE) someone awaits
        self._tick_error: Exception | None = None
        self._last_marker_ms = -1
        self._marker_seen_wall = 0.0
        self.commander = MavCommander(self.link, lambda: (self.state.vehicle_sysid, self.state.vehicle_compid))
        self._abort = asyncio.Event()
        self._waiting: tuple[Callable[[], bool], asyncio.Future] | None = None  # lockstep: sequencer's condition
        self._held: tuple[float, np.ndarray, float] | None = None  # lockstep: setpoint held for the sequencer
        self._held_since = 0.0
        self._done = asyncio.Event()
        self._core_active = False

    # ------------------------------------------------------------------ input
    def _on_message(self, msg: Any) -> None:
        mtype = self.state.ingest(msg)
        if self.commander.on_message(msg):
            self._woke_sequencer = True
        if mtype == "SYSTEM_TIME" and msg.get_srcSystem() == self.state.vehicle_sysid:
            now = time.monotonic()
            # A repeated marker (same time) is the vehicle re-asking after a lost answer: answer again only
            # if we have not answered for 0.5 s, so duplicates never double-step a lockstep simulation.
            if msg.time_boot_ms != self._last_marker_ms or now - self._marker_seen_wall > 0.5:
                self._last_marker_ms = msg.time_boot_ms
                self._marker_seen_wall = now
                self._marker_pending = True

    def _on_datagram_done(self) -> None:
        """Lockstep: answer a new marker right after its datagram, without a trip through the event loop —
        unless the same datagram woke the sequencer (an awaited COMMAND_ACK or PARAM_VALUE), which then runs
        first, as before."""
        woke, self._woke_sequencer = self._woke_sequencer, False
        if not self._marker_pending:
            return
        self._marker_pending = False
        if woke or not self.opts.lockstep or self._done.is_set():
            self._marker.set()
            return
        try:
            self._tick()
        except Exception as exc:  # raised in the tick loop, so a failing tick still ends the run as before
            self._tick_error = exc
            self._marker.set()

    # ------------------------------------------------------------------ public
    def request_abort(self, reason: str = "operator abort (Ctrl-C)") -> None:
        """Stop the mission: hold, land if configured, finish. Safe to call from a signal handler."""
        if not self._abort.is_set():
            log.warning("abort requested: %s", reason)
            self.abort_reason = reason
            self._abort.set()

    async def run(self) -> str:
        """Fly the mission; returns the outcome ("completed", "aborted", "timeout", "link_lost", ...)."""
        async with self.link:
            try:
                async with asyncio.TaskGroup() as tg:
                    tg.create_task(self._tick_loop())
                    tg.create_task(self._heartbeat_loop())
                    tg.create_task(self._sequencer())
            except* LinkError as eg:
                self.outcome = "link_error"
                raise eg.exceptions[0] from None
        return self.outcome

    # ------------------------------------------------------------------ loops
    async def _heartbeat_loop(self) -> None:
        while not self._done.is_set():
            if self._held is not None and time.monotonic() - self._held_since > 0.5:
                log.warning("lockstep: a setpoint was held 0.5 s for the sequencer; releasing it")
                self._release_setpoint()
            if self.link.connected:
                self.link.mav.heartbeat_send(
                    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink2.MAV_STATE_ACTIVE,
                )
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0):
                    await self._done.wait()

    async def _tick_loop(self) -> None:
        period = 1.0 / self.opts.rate_hz
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        k = 0
        while not self._done.is_set():
            if self.opts.lockstep:
                await self._marker.wait()  # the sequencer also sets it when the run is done
                if self._tick_error is not None:
                    raise self._tick_error
                if self._done.is_set():
                    break
                self._marker.clear()
            else:
                k += 1
                deadline = t0 + k * period
                delay = deadline - loop.time()
                if delay > 0:
                    await asyncio.sleep(delay)
                lateness = loop.time() - deadline
                self.stats.jitter_s.append(lateness)
                if lateness > period:
                    self.stats.late_ticks += 1
                    k += int(lateness // period)  # skip the missed deadlines, no catch-up burst
            self._tick()

    def _tick(self) -> None:
        """One control tick: estimate → (plan → control) → setpoint out; then log and publish.

        ``tick`` time is the companion's own work (telemetry folded in → setpoint packed); the send is timed
        apart, because on a busy machine the kernel may run the receiving simulator inside our sendto().
        """
        start = time.perf_counter()
        est = self.state.estimate()
        cmd: Command | None = None
        if est is not None and self._core_active:
            obstacles = self.obstacle_source(est.t_s) if self.obstacle_source else self.mission.obstacles
            if obstacles is not self._last_obstacles:
                self._last_obstacles = obstacles
                for o in obstacles:
                    self._obstacles_seen.setdefault((o.x_m, o.y_m, o.radius_m, o.height_m), o)
            cmd = self.core.update(est, obstacles)
            self.last_cmd = cmd
            t_s, q, thrust = est.t_s, cmd.q_ned_frd_wxyz, cmd.thrust_norm
        else:
            # Idle stream (before OFFBOARD, or while the vehicle flies an internal mode): level, zero thrust.
            yaw = float(est.euler_rad[2]) if est is not None else 0.0
            t_s, q, thrust = (est.t_s if est is not None else 0.0), quat_from_euler(0.0, 0.0, yaw), 0.0
        computed = time.perf_counter()
        if self.opts.lockstep and self._check_waiting():
            self._held = (t_s, q, thrust)  # the sequencer acts first; it releases this when it waits again
            self._held_since = time.monotonic()
        else:
            self._send_setpoint(t_s, q, thrust)
        sent = time.perf_counter()
        self.stats.ticks += 1
        self.stats.tick_s.append(computed - start)
        self.stats.send_s.append(sent - computed)
        if est is None:
            return
        self.stats.last = (sent, est.t_s)
        if self.stats.first is None:
            self.stats.first = self.stats.last
        if cmd is not None or self.phase in ("land", "abort"):
            self._record(est, cmd)
        if self.telemetry is not None:
            try:
                self.telemetry.on_tick(est, cmd, self)
            except Exception:
                log.exception("telemetry sink failed; continuing")

    @property
    def obstacles_seen(self) -> tuple[Obstacle, ...]:
        """Every obstacle the planner has been given during the flight (mission and live ones)."""
        return tuple(self._obstacles_seen.values())

    def _record(self, est: Estimate, cmd: Command | None) -> None:
        """One log row; the payload point from the cable angles when known, else the payload's own stream."""
        src = est.swing_source
        self.swing_sources[src] = self.swing_sources.get(src, 0) + 1
        if src != self._last_swing_source:
            if src == "none":
                log.warning("no swing input: flying without feed-forward, envelope = full cable length")
            else:
                log.info("swing input: %s", src)
            self._last_swing_source = src
        # The log keeps the best swing measurement even when the controller was told to ignore it, so the
        # report's swing and clearance numbers describe the flight, not the controller's view of it.
        swing = self.state.measured_swing()
        if swing is not None:
            payload = est.pos_ned_m + payload_offset_ned_m(swing[0], swing[1], self.mission.vehicle.l)
        else:
            payload = self.state.payload_pos_ned_m
        self.log.append(est.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, swing, payload, cmd)

    def _send_setpoint(self, t_s: float, q: np.ndarray, thrust_norm: float) -> None:
        if not self.link.connected:
            return
        send_set_attitude_target(
            self.link.mav, int(t_s * 1e3) & 0xFFFFFFFF, self.state.vehicle_sysid or 1, self.state.vehicle_compid,
            ATT_TYPE_MASK, q, 0.0, 0.0, 0.0, float(thrust_norm),
        )

    # ------------------------------------------------------------------ sequencer
    async def _set_mode(self, what: str) -> int:
        """Switch to the profile's ``offboard``, ``hold`` or ``land`` mode; returns MAV_RESULT."""
        return await self.commander.command(mavlink2.MAV_CMD_DO_SET_MODE, self.profile.mode_params(what))

    async def _wait_until(self, cond: Callable[[], bool], timeout_s: float, what: str) -> bool:
        """Wait (at most ``timeout_s`` wall seconds) until ``cond()``; False on timeout or abort.

        Lockstep: the condition is checked by the tick itself, after it has folded in the step's telemetry and
        before its setpoint goes out; when it holds, the setpoint is held back until the sequencer has acted
        (sent its commands, had them acknowledged) and waits again. So every command lands at the same
        simulated time in every run — the flight is repeatable, not subject to wall-clock polling.
        """
        if cond():
            return True
        if self._abort.is_set():
            return False
        try:
            async with asyncio.timeout(timeout_s):
                if self.opts.lockstep:
                    fut: asyncio.Future = asyncio.get_running_loop().create_future()
                    self._waiting = (cond, fut)
                    self._release_setpoint()  # the sequencer is idle now: let simulated time go on
                    await fut
                    return not self._abort.is_set()
                while not cond():
                    if self._abort.is_set():
                        return False
                    await asyncio.sleep(0.01)
        except TimeoutError:
            log.warning("timed out waiting for %s", what)
            return False
        finally:
            self._waiting = None
        return True

    def _check_waiting(self) -> bool:
        """Lockstep tick hook: resolve the sequencer's condition if it now holds; True if the setpoint
        must be held back for the sequencer's turn."""
        w = self._waiting
        if w is None or w[1].done():
            return False
        cond, fut = w
        if cond() or self._abort.is_set():
            fut.set_result(True)
            return True
        return False

    def _release_setpoint(self) -> None:
        """Send a setpoint held back for the sequencer (lockstep), which advances simulated time."""
        held, self._held = self._held, None
        if held is not None:
            self._held_since = 0.0
            self._send_setpoint(*held)

    def _sim_time(self) -> float:
        return self.state.t_s

    async def _sequencer(self) -> None:
        try:
            await self._fly_sequence()
        finally:
            self._release_setpoint()
            self._done.set()
            self._marker.set()  # release a lockstep tick loop waiting for the next step

    async def _fly_sequence(self) -> None:
        o = self.opts
        self.phase = "connect"
        if not await self._wait_until(lambda: self.state.heartbeats > 0 and self.state.ready(), o.heartbeat_timeout_s,
                                      "the autopilot's heartbeat and telemetry"):
            if self._abort.is_set():
                self.outcome = "aborted"
                return
            raise LinkError(f"no autopilot heartbeat/telemetry on {o.connect} within {o.heartbeat_timeout_s:.0f} s")
        if self.opts.profile is None:
            self.profile = profile_for_autopilot(self.state.autopilot, self.opts.hover_thrust_norm)
        if self.opts.hover_thrust_norm is None:
            # The autopilot knows its hover thrust (PX4 MPC_THR_HOVER, ArduPilot MOT_THST_HOVER): ask for it.
            name = "MOT_THST_HOVER" if self.profile.autopilot == "ardupilot" else "MPC_THR_HOVER"
            value = await self.commander.read_param(name)
            if value is not None and 0.05 <= value <= 0.95:
                self.profile = replace(self.profile, hover_thrust_norm=float(value))
            else:
                log.warning("could not read %s from the autopilot; assuming hover thrust %.2f (--hover-thrust)",
                            name, self.profile.hover_thrust_norm)
        self.core.profile = self.profile
        if self.opts.on_connected is not None:
            await self.opts.on_connected(self)
        log.info("connected to system %s (%s autopilot) in mode %s; thrust and modes as profile %r (hover %.2f)",
                 self.state.vehicle_sysid, self.profile.autopilot, self.state.mode_name, self.profile.name,
                 self.profile.hover_thrust_norm)
        interval_us = 1e6 / o.rate_hz
        for msg_id, us in ((mavlink2.MAVLINK_MSG_ID_ATTITUDE, interval_us),
                           (mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, interval_us),
                           (mavlink2.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY, interval_us),
                           (mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 1e5)):
            res = await self.commander.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, [msg_id, us])
            if res != mavlink2.MAV_RESULT_ACCEPTED:
                log.warning("vehicle refused message interval for id %d (result %d)", msg_id, res)
        self.phase = "prestream"
        t_start = self._sim_time()
        await self._wait_until(lambda: self._sim_time() - t_start >= o.prestream_s, 30.0, "setpoint pre-stream")
        if self._abort.is_set():
            return await self._abort_sequence()
        self.phase = "arm"
        res = await self.commander.command(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0])
        if res != mavlink2.MAV_RESULT_ACCEPTED:
            raise LinkError(f"arming refused (MAV_RESULT {res}); vehicle said: {self.state.statustext[-3:]}")
        self.phase = "offboard"
        self._core_active = True
        res = await self._set_mode("offboard")
        if res != mavlink2.MAV_RESULT_ACCEPTED:
            self._core_active = False
            raise LinkError(f"OFFBOARD refused (MAV_RESULT {res}); vehicle said: {self.state.statustext[-3:]}")
        self.phase = "mission"
        t_mission0 = self._sim_time()
        finished = await self._wait_until(
            lambda: self.core.phase == "done" or self._sim_time() - t_mission0 > self.mission.timeout_s,
            self.opts.wall_timeout_s or 1e9, "the mission",
        )
        if self._abort.is_set():
            return await self._abort_sequence()
        completed = finished and self.core.phase == "done" and not self.core.timed_out
        self.outcome = "completed" if completed else "timeout"
        if self.mission.land:
            await self._land()

    async def _land(self) -> None:
        self.phase = "land"
        self._core_active = False
        res = await self.commander.command(mavlink2.MAV_CMD_NAV_LAND, [0, 0, 0, math.nan, math.nan, math.nan, math.nan])
        if res != mavlink2.MAV_RESULT_ACCEPTED:
            log.warning("NAV_LAND refused (result %d); trying AUTO.LAND mode", res)
            await self._set_mode("land")
        t0 = self._sim_time()
        await self._wait_until(
            lambda: (self.state.on_ground and not self.state.armed) or self._sim_time() - t0 > self.opts.land_timeout_s,
            120.0, "landing",
        )
        self.phase = "landed" if self.state.on_ground else "land_timeout"

    async def _abort_sequence(self) -> None:
        self.outcome = "aborted"
        self.phase = "abort"
        self._core_active = False
        with contextlib.suppress(LinkError):
            await self._set_mode("hold")
            if self.opts.land_on_abort and self.state.armed:
                self._abort.clear()  # let the landing wait run
                await self._land()
                self.outcome = "aborted"
