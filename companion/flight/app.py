"""The companion's flight application: asyncio around the pure flight core and the flight sequence.

Data flows one way, once per control tick::

    MAVLink telemetry ─▶ VehicleState ─▶ Estimate ─▶ FlightSequence (what to stream, what to ask)
                                                 └─▶ FlightCore (plan ▶ control) ─▶ SET_ATTITUDE_TARGET

Every decision — when to arm, when our mode counts as ours, when to hold, land or let go — is made by the
pure :class:`~companion.flight.sequence.FlightSequence` (read that file for the rules); this module only
measures, carries out and records. Three coroutines share the work inside a ``TaskGroup``:

* the **tick loop** answers every control period. In real time it runs on a monotonic schedule (deadlines
  ``t0 + k·period``; a tick more than one period late is counted, missed deadlines are skipped). In lockstep
  it runs inside the datagram handler of each new end-of-step marker (``SYSTEM_TIME``): every marker is
  answered by exactly one SET_ATTITUDE_TARGET (a "tick only" frame when nothing may be streamed), which is
  what advances simulated time. Requests the sequence makes go out in the same tick, before the setpoint,
  so the vehicle handles them at the same simulated time in every run.
* the **watchdog** steps the sequence from the wall clock when ticks stop (a lockstep vehicle that died
  sends no more markers), so a lost vehicle is noticed within the sequence's timeouts.
* the **housekeeping** loop sends our HEARTBEAT at 1 Hz and flushes the journal (per-tick log and
  provisional report) once a second. The loop only hands the bytes over; the journal's own thread writes them
  (:mod:`companion.disk_writer`), because a disk busy with another process's writes held a file rename for up
  to 0.8 s.

Python's garbage collector never runs inside a tick: :class:`~companion.flight.scheduling.GcPacer` runs it
after each tick (and from the watchdog every 0.1 s), and the report's ``loop`` says how long it took. When the
loop stalls for 0.1 s anyway, :class:`~companion.flight.scheduling.StallTracer` records where
(``loop.stall_traces``).

An exception inside a tick is caught at the tick's boundary, counted and logged at most once a second; the
sequence holds and lands after three in a row. Nothing received from the link can raise into the loop.
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

from companion.autopilots.family import SetupOptions
from companion.autopilots.profile import VehicleProfile, profile_by_name, profile_for_autopilot
from companion.core.mission import Mission
from companion.core.model import payload_offset_ned_m
from companion.core.obstacles import Obstacle
from companion.core.rotations import quat_from_euler
from companion.estimation.estimate import Estimate
from companion.estimation.swing_feed import SwingFeed, estimator_config
from companion.estimation.vehicle_state import VehicleState
from companion.flight.core import Command, FlightCore
from companion.flight.health import DeafSpells, LinkHealth, lockstep_telemetry_wall_s
from companion.flight.scheduling import GcPacer, StallTracer, involuntary_switches, request_fifo, restore_normal
from companion.flight.sequence import FlightSequence, Observation, SequenceConfig, Stream
from companion.mavlink_io.codec import send_set_attitude_target
from companion.mavlink_io.commands import RequestLink
from companion.mavlink_io.link import MavlinkLink
from companion.mavlink_io.telemetry import decode
from companion.report.journal import Journal
from companion.report.metrics import FlightLog

log = logging.getLogger(__name__)

# SET_ATTITUDE_TARGET type_mask: attitude + thrust used, body rates ignored
ATT_TYPE_MASK = (
    mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
    | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
    | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
)
# everything ignored: a lockstep "tick" that carries no setpoint (does not count as an offboard stream)
TICK_ONLY_MASK = ATT_TYPE_MASK | mavlink2.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE | \
    mavlink2.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE
_LEVEL_Q = np.array([1.0, 0.0, 0.0, 0.0])
OPTIONAL_STREAMS = {"message_interval:ESTIMATOR_STATUS"}  # nice to have: refusing them is no warning
SWING_WAIT_S = 5.0  # with a swing estimator: the longest the climb waits at the start altitude for its trust (s)
RELEVANT_RADIUS_M = 20.0  # obstacles farther than this from the vehicle are not given to the planner
MAX_OBSTACLES_SEEN = 4096  # the report's record of obstacles met is bounded too
PROVISIONAL_WINDOW_TICKS = 2_500  # the provisional report's loop timings: the last 10 s at 250 Hz (LoopStats.summary)


class TelemetrySink(Protocol):
    """Where the app publishes per-tick data (the Zenoh streams, the live view and the terminal implement this).

    ``on_tick`` runs inside the control tick after the setpoint went out: it must be cheap and must not block.
    ``on_transition`` (optional) hears every state change of the flight sequence, even before telemetry flows.
    """

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
    heartbeat_timeout_s: float = 60.0
    ready_timeout_s: float = 90.0
    prestream_s: float = 1.0
    land_on_abort: bool = True
    land_timeout_s: float = 45.0
    tlog_path: Path | None = None
    run_dir: Path | None = None  # where the journal (per-tick log, provisional report) is flushed each second
    wall_timeout_s: float | None = None
    obstacle_source: Callable[[float], Sequence[Obstacle]] | None = None
    # Parses waiting live obstacle input at app time t_s; called right after each tick, outside its timing
    obstacle_ingest: Callable[[float], None] | None = None
    sinks: list[TelemetrySink] = field(default_factory=list)
    # Awaited once the autopilot is known, outside the tick (its system id decides e.g. the Zenoh vehicle id);
    # may add to ``app.sinks`` and set ``app.obstacle_source``.
    on_connected: Callable[[FlightApp], Awaitable[None]] | None = None
    sock: socket.socket | None = None  # an already bound UDP socket for the link (fly --sitl reserves one)
    sequence: SequenceConfig | None = None  # timeouts of the flight sequence (defaults otherwise)
    provisional: Callable[[FlightApp], dict[str, Any]] | None = None  # the journal's provisional report
    allow_param_writes: bool = True  # False: refuse a vehicle whose parameters would have to change (ArduPilot)
    start_here: bool = False  # fly the mission from where the vehicle stands (its start moved there)
    signing_key: bytes | None = None  # MAVLink 2 signing: sign everything sent, accept only signed frames
    rt_priority: int = 0  # > 0: the control thread runs SCHED_FIFO at this priority while flying (scheduling.py)
    # Fault injection for the fault suite: from this vehicle time (s) on, every tick that would compute a setpoint
    # raises (``SLUNGPILOT_INJECT_TICK_ERROR_AT_S`` sets it for ``slungpilot fly``). None in normal use.
    inject_tick_error_at_s: float | None = None


@dataclass
class LoopStats:
    """Tick timing: compute time per tick (receive → setpoint sent) and lateness in real time."""

    ticks: int = 0
    late_ticks: int = 0
    preempted_ticks: int = 0  # ticks during which the kernel switched the control thread out
    scheduling: str = "SCHED_OTHER"  # what the control thread ran as
    tick_errors: int = 0
    ingest_errors: int = 0
    watchdog_steps: int = 0
    tick_s: list[float] = field(default_factory=list)
    tick_cpu_s: list[float] = field(default_factory=list)  # the same ticks in this thread's CPU time
    send_s: list[float] = field(default_factory=list)
    ingest_s: list[float] = field(default_factory=list)  # live obstacle parsing after each tick (outside it)
    after_s: list[float] = field(default_factory=list)  # the flight core's bookkeeping after the send (outside it)
    jitter_s: list[float] = field(default_factory=list)
    first: tuple[float, float] | None = None  # (wall monotonic s, vehicle time s) of the first tick with telemetry
    last: tuple[float, float] | None = None

    def summary(self, window: int | None = None) -> dict[str, float | int | None]:
        """ticks; tick (compute) and send time p50/p99/max (ms); the tick's CPU time p50/p99 (ms: what it costs
        when not preempted; on a busy machine the wall time includes other processes' time slices); late ticks;
        preempted ticks and the thread's scheduling policy; jitter p99 and max (ms, real time only); p99 of the
        obstacle input's parsing and of the flight core's bookkeeping, both after the send (ms).

        ``window``: the timings of the last ``window`` ticks only (``window_ticks`` says so). The journal's
        provisional report, made on the event loop once a second, uses it: over a whole long flight the
        percentiles cost 50 ms at 150,000 ticks (10 min) and 150 ms at 450,000 (30 min), a stall every second;
        over the last 2,500 ticks, ~1.2 ms whatever the flight's length."""
        def arr(xs: list[float]) -> np.ndarray:
            xs = xs[-window:] if window else xs
            return np.array(xs) if xs else np.zeros(1)

        t, tc, snd, j = arr(self.tick_s), arr(self.tick_cpu_s), arr(self.send_s), arr(self.jitter_s)
        ingest = self.ingest_s[-window:] if window else self.ingest_s
        after = self.after_s[-window:] if window else self.after_s
        return {
            "ticks": self.ticks,
            "window_ticks": window,
            "tick_ms_p50": float(np.percentile(t, 50) * 1e3),
            "tick_ms_p99": float(np.percentile(t, 99) * 1e3),
            "tick_ms_max": float(t.max() * 1e3),
            "tick_cpu_ms_p50": float(np.percentile(tc, 50) * 1e3),
            "tick_cpu_ms_p99": float(np.percentile(tc, 99) * 1e3),
            "send_ms_p50": float(np.percentile(snd, 50) * 1e3),
            "send_ms_p99": float(np.percentile(snd, 99) * 1e3),
            "ingest_ms_p99": float(np.percentile(ingest, 99) * 1e3) if ingest else 0.0,
            "after_ms_p99": float(np.percentile(after, 99) * 1e3) if after else 0.0,
            "late_ticks": self.late_ticks,
            "preempted_ticks": self.preempted_ticks,
            "scheduling": self.scheduling,
            "tick_errors": self.tick_errors,
            "ingest_errors": self.ingest_errors,
            "watchdog_steps": self.watchdog_steps,
            "jitter_ms_p99": float(np.percentile(np.abs(j), 99) * 1e3),
            "jitter_ms_max": float(np.abs(j).max() * 1e3),  # the longest the loop kept a tick waiting (a stall)
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
            cable_length_m=mission.vehicle.l, payload_sysid=opts.payload_sysid, swing_input=opts.swing_input,
            max_time_rate=1e4 if opts.lockstep else 2.0,
        )
        self.swing_feed = SwingFeed(mission.companion_params(), opts.swing_input, estimator_config(mission))
        self.swing_sources: dict[str, int] = {}
        self._last_swing_source = ""
        self.link = MavlinkLink(opts.connect, self._on_message, tlog=opts.tlog_path, sock=opts.sock,
                                signing_key=opts.signing_key)
        self.link.on_datagram_done = self._on_datagram_done
        self.profile = opts.profile or profile_by_name("px4", opts.hover_thrust_norm)
        self.period_s = 1.0 / opts.rate_hz
        self.core = FlightCore(mission, gains=opts.gains, profile=self.profile, period_s=self.period_s)
        if self.swing_feed.wants_estimator:
            self.core.swing_wait_s = SWING_WAIT_S
        base = opts.sequence or SequenceConfig()
        if opts.lockstep:
            # Simulated time waits for both processes: a stall of either is not staleness (the vehicle's
            # telemetry is measured from our last answer), and a loaded machine can pause a process for longer
            # than 0.5 s; the vehicle's own wall-clock HEARTBEAT (1 Hz) still tells a dead vehicle in 1.5 s.
            base = replace(base, stale_s=float("inf"), telemetry_loss_s=max(base.telemetry_loss_s, 1.0))
        self.seq = FlightSequence(replace(
            base, connect_timeout_s=opts.heartbeat_timeout_s, ready_timeout_s=opts.ready_timeout_s,
            prestream_s=opts.prestream_s, land_on_abort=opts.land_on_abort, land_at_end=mission.land,
            land_timeout_s=opts.land_timeout_s, mission_wall_timeout_s=opts.wall_timeout_s,
        ))
        self.requests = RequestLink(self.link.mav, lambda: (self.state.vehicle_sysid, self.state.vehicle_compid),
                                    lambda what: self.profile.mode_params(what))
        self.health = LinkHealth(period_s=self.period_s)
        self.log = FlightLog(
            planner=mission.planner, controller=mission.controller, mission=mission.name, obstacles=mission.obstacles
        )
        self.journal = Journal(opts.run_dir, self.log, mission) if opts.run_dir is not None else None
        self.stats = LoopStats()
        self.gc_pacer = GcPacer()  # the garbage collector runs between ticks, not inside them
        self.deaf = DeafSpells()  # real time: when our own loop stalled, the vehicle's silence is not its own
        self.stall_tracer = StallTracer()  # real time: where the loop was when it stalled for 0.1 s
        self.abort_reason: str | None = None
        self.last_cmd: Command | None = None
        self.sinks: list[TelemetrySink] = list(opts.sinks)
        self.obstacle_source: Callable[[float], Sequence[Obstacle]] | None = opts.obstacle_source
        self.obstacle_ingest: Callable[[float], None] | None = opts.obstacle_ingest
        self.params: dict[str, dict[str, float]] = {"read": {}, "set": {}}  # the autopilot parameters we read/set
        self._last_obstacles: Sequence[Obstacle] | None = None
        self._obstacles_seen: dict[tuple, Obstacle] = {}
        self._culled: Sequence[Obstacle] = ()
        self._cull_xy = (float("inf"), float("inf"))
        self._marker_pending = False
        self._last_marker_ms = -1
        self._marker_seen_wall = 0.0
        self._last_tick_wall = 0.0
        self._last_answer_wall = 0.0  # lockstep: when we last answered a marker (the vehicle waits on us after)
        self._tick_errors_in_row = 0
        self._last_error_log = -1e9
        self._tracking_error_m = 0.0  # distance from the last command's reference (m, the sequence's divergence)
        self._last_valid: tuple[float, np.ndarray, float, float] | None = None  # (t_s, q, thrust, wall) sent last
        self._connected_hook_started = False
        self._done = asyncio.Event()
        self._transitions_logged = 0
        self.origin_ned_m = np.zeros(3)  # the mission frame's origin in the autopilot's local NED frame
        self.origin_source = "local origin"
        self._origin_fixed = False

    # ------------------------------------------------------------------ views
    @property
    def phase(self) -> str:
        """Where the flight is: the sequence state, refined by the flight core's phase during the mission."""
        if self.seq.finished:
            return self.seq.final_phase
        if self.seq.state.value == "mission":
            return self.core.phase
        return self.seq.state.value

    @property
    def outcome(self) -> str:
        """The flight's outcome so far (see :data:`companion.flight.sequence.OUTCOMES`)."""
        return self.seq.outcome

    @property
    def obstacles_seen(self) -> tuple[Obstacle, ...]:
        """Every obstacle the planner has been given during the flight (mission and live ones)."""
        return tuple(self._obstacles_seen.values())

    # ------------------------------------------------------------------ input
    def _on_message(self, msg: Any) -> None:
        wall = time.monotonic()
        ev = decode(msg)
        if ev is None:  # a message nothing reads: still a frame of the vehicle's stream (sequence numbers)
            if msg.get_srcSystem() == self.state.vehicle_sysid:
                self.health.on_frame(msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
            return
        known = self.state.vehicle_sysid is not None
        kind = self.state.ingest(ev, wall)
        if kind != "REJECTED":
            self.swing_feed.ingest(ev, self.state)
            if kind == "GLOBAL_POSITION_INT":  # ArduPilot's payload: fixes relative to the airframe, once paired
                for t_fix, off, vel in self.swing_feed.take_fresh_offsets():
                    if self.state.pos_ned_m is not None:  # the angles come from ``off`` alone
                        self.state.set_payload_fix(t_fix, self.state.pos_ned_m + off, vel)
        if not known and self.state.vehicle_sysid is not None:
            self._vehicle_found()
        src = ev.src_system
        if src == self.state.vehicle_sysid:
            self.health.on_frame(src, ev.src_component, ev.seq)
            if kind == "LOCAL_POSITION_NED":
                self.health.on_sample("position", self.state.pos_t_s)
            elif kind == "ATTITUDE":
                self.health.on_sample("attitude", self.state.att_t_s)
            elif kind == "SYSTEM_TIME" and (
                    ev.t_boot_ms != self._last_marker_ms or wall - self._marker_seen_wall > 0.5):
                # A repeated marker (same time) is the vehicle re-asking after a lost answer: answer again only if
                # we have not answered for 0.5 s, so duplicates never double-step a lockstep simulation.
                self._last_marker_ms = ev.t_boot_ms
                self._marker_seen_wall = wall
                self._marker_pending = True
        ans = self.requests.answer_of(ev)
        if ans is not None:
            key, value = ans
            if key.startswith("param:"):  # a PARAM_VALUE: ours only if it answers a read or a write we asked for
                name = key[6:]
                if self.seq.answer(f"param_read:{name}", value):
                    self.params["read"][name] = float(value)
                elif self.seq.answer(f"param_set:{name}", value):
                    self.params["set"][name] = float(value)
            else:
                self.seq.answer(key, value)

    def _vehicle_found(self) -> None:
        """The first autopilot HEARTBEAT: lock the link onto its sender, pick the profile, plan the set-up."""
        self.link.lock_to_last_sender()
        if self.opts.profile is None:
            self.profile = profile_for_autopilot(self.state.autopilot, self.opts.hover_thrust_norm)
            self.core.profile = self.profile
        self.state.mode_class = self.profile.mode_class
        family = self.profile.family
        setup = SetupOptions(rate_hz=self.opts.rate_hz, swing_sensor=self.opts.swing_input in ("auto", "cable_sensor"),
                             read_hover_thrust=self.opts.hover_thrust_norm is None,
                             allow_param_writes=self.opts.allow_param_writes)
        self.seq.plan(configure=family.setup(setup), takeover_before_arm=family.takeover_before_arm,
                      followup=lambda answers: family.followup(answers, setup))
        log.info("vehicle: system %s component %s, %s autopilot, mode %s", self.state.vehicle_sysid,
                 self.state.vehicle_compid, self.profile.autopilot, self.state.mode_name)

    def _on_datagram_done(self) -> None:
        """Lockstep: answer a new marker right after its datagram (telemetry of that step folded in)."""
        if not self._marker_pending:
            return
        self._marker_pending = False
        if self.opts.lockstep and not self._done.is_set():
            self._tick()
            self._between_ticks()

    # ------------------------------------------------------------------ public
    def request_abort(self, reason: str = "operator abort (Ctrl-C)") -> None:
        """Stop the mission: hold, land if configured, finish. Safe to call from a signal handler."""
        if self.abort_reason is None:
            log.warning("abort requested: %s", reason)
            self.abort_reason = reason

    async def run(self) -> str:
        """Fly the mission; returns the outcome (see :data:`companion.flight.sequence.OUTCOMES`)."""
        # lockstep has no deadlines, and its loop runs flat out: SCHED_FIFO would starve every other thread
        fifo = self.opts.rt_priority > 0 and not self.opts.lockstep
        if fifo:
            self.stats.scheduling = request_fifo(self.opts.rt_priority)
        elif self.opts.rt_priority > 0:
            log.info("lockstep: --rt-priority ignored (no deadlines to meet)")
            self.stats.scheduling = "SCHED_OTHER (lockstep: --rt-priority ignored)"
        self.gc_pacer.start()
        if not self.opts.lockstep:
            self.stall_tracer.start()
        try:
            async with self.link, asyncio.TaskGroup() as tg:
                if not self.opts.lockstep:
                    tg.create_task(self._tick_loop())
                tg.create_task(self._watchdog_loop())
                tg.create_task(self._housekeeping_loop())
                tg.create_task(self._connected_hook())
        finally:
            self.stall_tracer.stop()
            self.gc_pacer.stop()
            if fifo:
                restore_normal()
            if self.journal is not None:
                self.journal.close(self._provisional())
        return self.outcome

    # ------------------------------------------------------------------ loops
    async def _connected_hook(self) -> None:
        """Run ``opts.on_connected`` once the vehicle is known (outside the tick: it may open sessions)."""
        if self.opts.on_connected is None:
            return
        while self.state.vehicle_sysid is None and not self._done.is_set():
            await asyncio.sleep(0.02)
        if not self._done.is_set():
            try:
                await self.opts.on_connected(self)
            except Exception:
                log.exception("on_connected hook failed; flying without it")

    async def _housekeeping_loop(self) -> None:
        while not self._done.is_set():
            if self.link.connected:
                # announced the way the autopilot family wants (PX4 tells its reasons only to a GCS-typed link)
                mav_type = self.profile.family.heartbeat_type if self.state.vehicle_sysid is not None else \
                    mavlink2.MAV_TYPE_ONBOARD_CONTROLLER
                self.link.mav.heartbeat_send(mav_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink2.MAV_STATE_ACTIVE)
            if self.journal is not None:
                try:  # hands bytes to the journal's thread: no disk wait here
                    self.journal.flush(self._provisional())
                except Exception:  # the housekeeping loop must outlive a bug in the report's facts
                    log.exception("cannot hand the journal its flush")
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0):
                    await self._done.wait()

    async def _watchdog_loop(self) -> None:
        """Step the sequence from the wall clock whenever ticks stop for 0.1 s (nothing is streamed)."""
        while not self._done.is_set():
            due = time.monotonic() + 0.1
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(0.1):
                    await self._done.wait()
            if not self.opts.lockstep:  # a stalled loop wakes the watchdog late, maybe before the tick loop
                self.deaf.add(due, time.monotonic())
            if not self._done.is_set() and time.monotonic() - self._last_tick_wall > 0.1:
                self.stats.watchdog_steps += 1
                self._tick(watchdog=True)
            self.gc_pacer.step()  # garbage is collected while ticks stop too

    async def _tick_loop(self) -> None:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        k = 0
        while not self._done.is_set():
            k += 1
            deadline = t0 + k * self.period_s
            delay = deadline - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            self.stall_tracer.beat()
            lateness = loop.time() - deadline
            self.stats.jitter_s.append(lateness)
            self.deaf.add(deadline, deadline + lateness)
            if lateness > self.period_s:
                self.stats.late_ticks += 1
                k += int(lateness // self.period_s)  # skip the missed deadlines, no catch-up burst
            self._tick()
            self._between_ticks()
        self.stall_tracer.stop()  # what follows the last tick (closing files, the report) is not a stall

    def _between_ticks(self) -> None:
        """After a tick's setpoint is out: obstacle input, then any garbage collection that is due."""
        self._ingest()
        self.gc_pacer.step()

    def _ingest(self) -> None:
        """After a tick: let the obstacle input parse what waits (its own time budget), timed apart from the tick;
        its failures are counted like a tick's, never raised into the loop."""
        if self.obstacle_ingest is None:
            return
        start = time.perf_counter()
        try:
            self.obstacle_ingest(self.state.t_s)
        except Exception:
            self.stats.ingest_errors += 1
            wall = time.monotonic()
            if self._error_log_due(wall):
                log.exception("obstacle input failed (%d times); flying with the obstacles adopted so far",
                              self.stats.ingest_errors)
        self.stats.ingest_s.append(time.perf_counter() - start)

    # ------------------------------------------------------------------ the tick
    def _update_origin(self) -> float:
        """Until setpoints flow: the mission frame's origin (home; else the take-off point; with ``start_here``
        the point that puts the mission's start under the vehicle); returns the vehicle's distance from the
        mission's start (m, horizontal)."""
        st = self.state
        start = self.mission.start_ned_m
        pos = st.pos_ned_m
        if not self._origin_fixed:
            if self.opts.start_here and pos is not None:
                z0 = st.home_ned_m[2] if st.home_ned_m is not None else (pos[2] if st.on_ground else 0.0)
                self.origin_ned_m = np.array([pos[0] - start[0], pos[1] - start[1], z0])
                self.origin_source = "start-here"
            elif st.home_ned_m is not None:
                self.origin_ned_m, self.origin_source = st.home_ned_m.copy(), "home"
            elif pos is not None and st.on_ground:
                self.origin_ned_m, self.origin_source = pos.copy(), "take-off point"
            if self.seq.state.value not in ("connect", "configure", "wait_ready"):
                self._origin_fixed = True
                log.info("mission frame: origin at %s of the autopilot's local frame (%s)",
                         np.round(self.origin_ned_m, 3).tolist(), self.origin_source)
        if pos is None:
            return 0.0
        return math.hypot(pos[0] - self.origin_ned_m[0] - start[0], pos[1] - self.origin_ned_m[1] - start[1])

    def _to_mission(self, est: Estimate) -> Estimate:
        """An estimate in the mission frame (positions relative to :attr:`origin_ned_m`)."""
        if not self.origin_ned_m.any():
            return est
        return est.with_position(est.pos_ned_m - self.origin_ned_m)

    def _observe(self, est: Estimate | None, wall: float) -> Observation:
        st = self.state
        tel_wall = st.telemetry_wall_s
        hb_wall = st.heartbeat_wall_s
        if self.opts.lockstep:
            tel_wall = lockstep_telemetry_wall_s(wall, tel_wall, self._last_answer_wall, st.t_s, st.pos_t_s,
                                                 st.att_t_s)
            if hb_wall is not None:
                # its HEARTBEAT runs on simulated time, which may run slower than the wall clock on a loaded
                # machine: in lockstep any datagram from the vehicle shows it is alive
                hb_wall = max(hb_wall, self.link.last_rx_wall)
        else:  # silence while our own loop stalled is not the vehicle's: ages count only time we listened
            tel_wall = self.deaf.heard_at(tel_wall, wall)
            hb_wall = self.deaf.heard_at(hb_wall, wall)
        return Observation(
            now_s=st.t_s if self.opts.lockstep else wall, wall_s=wall, heartbeat_wall_s=hb_wall,
            telemetry_wall_s=tel_wall, telemetry_ready=st.ready(),
            vehicle_ready=st.ready_to_arm(self.profile.family.prearm_bit),
            armed=st.armed, mode=st.mode, on_ground=st.on_ground, heartbeats=st.heartbeats,
            estimate_ok=est is not None, core_result=self.core.result, tick_errors_in_row=self._tick_errors_in_row,
            abort=self.abort_reason, mission_timeout_s=self.mission.timeout_s, last_words=st.last_words,
            start_error_m=self._update_origin(), tracking_error_m=self._tracking_error_m,
        )

    def _tick(self, watchdog: bool = False) -> None:
        """One control tick: observe → sequence → (flight core) → setpoint; then log and publish.

        ``tick`` time is the companion's own work (telemetry folded in → setpoint packed); the send is timed
        apart, because on a busy machine the kernel may run the receiving simulator inside our sendto().
        """
        start = time.perf_counter()
        cpu_start = time.thread_time()
        switches = involuntary_switches()
        wall = time.monotonic()
        self._last_tick_wall = wall
        est: Estimate | None = None
        cmd: Command | None = None
        setpoint: tuple[float, np.ndarray, float] | None = None
        stream = Stream.NONE
        try:
            est = self.state.estimate()
            step = self.seq.step(self._observe(est, wall))
            if est is not None:
                self.swing_feed.maybe_start(self.state)
                est = self._to_mission(self.swing_feed.choose(est))
            stream = step.stream
            for req in step.send:
                self.requests.send(req)
            while self.requests.instant_answers:
                self.seq.answer(*self.requests.instant_answers.pop())
            if step.configured is not None:
                self._apply_configured(step.configured)
            if step.core == "hold_here":
                self.core.hold_here()
            elif step.core == "descend":
                self.core.descend()
            if stream in (Stream.CORE, Stream.DESCENT):
                if est is not None:
                    if self.opts.inject_tick_error_at_s is not None and est.t_s >= self.opts.inject_tick_error_at_s:
                        raise RuntimeError("injected tick fault (SLUNGPILOT_INJECT_TICK_ERROR_AT_S)")
                    obstacles = self._obstacles(est)
                    cmd = self.core.setpoint(est, obstacles)
                    if self.core.arrival["t_s"] is not None:  # the report's "at the goal" follows the flight's
                        self.log.goal_tol_m = self.core.arrival["tolerance_m"]
                    self.swing_feed.commanded(est.t_s, cmd.thrust_n)
                    self._tracking_error_m = math.dist(est.pos_ned_m, cmd.ref_pos_ned_m)
                    self.last_cmd = cmd
                    setpoint = (est.t_s, cmd.q_ned_frd_wxyz, cmd.thrust_norm)
                else:
                    setpoint = self._recent_valid(wall)
            elif stream == Stream.IDLE:
                yaw = float(est.euler_rad[2]) if est is not None else 0.0
                setpoint = (self.state.t_s, quat_from_euler(0.0, 0.0, yaw), 0.0)
            self._tick_errors_in_row = 0
        except Exception as exc:  # the loop boundary: count, log once a second, keep the vehicle safe
            self._tick_errors_in_row += 1
            self.stats.tick_errors += 1
            if self._error_log_due(wall):
                log.error("control tick failed (%d in a row, %d in all): %r", self._tick_errors_in_row,
                          self.stats.tick_errors, exc, exc_info=self.stats.tick_errors == 1)
            setpoint = self._recent_valid(wall) if stream in (Stream.CORE, Stream.DESCENT) else None
            cmd = None
        computed = time.perf_counter()
        computed_cpu = time.thread_time()
        preempted = involuntary_switches() > switches
        if not watchdog:
            if setpoint is not None:
                self._send_setpoint(*setpoint)
                if stream != Stream.IDLE:
                    self._last_valid = (*setpoint, wall) if cmd is not None else self._last_valid
            elif self.opts.lockstep:
                self._send_tick_only()
            self._last_answer_wall = time.monotonic()
        sent = time.perf_counter()
        if cmd is not None and est is not None:
            self._after_setpoint(est, cmd)
        self._log_transitions()
        if self.seq.finished:
            self._done.set()
        if watchdog:
            return
        self.stats.ticks += 1
        self.stats.tick_s.append(computed - start)
        self.stats.tick_cpu_s.append(computed_cpu - cpu_start)
        self.stats.preempted_ticks += preempted
        self.stats.send_s.append(sent - computed)
        if est is None:
            return
        self.health.on_tick(est.t_s, wall - (self.state.telemetry_wall_s or wall))
        self.stats.last = (sent, est.t_s)
        if self.stats.first is None:
            self.stats.first = self.stats.last
        if self.seq.streaming_ours or cmd is not None:
            self._record(est, cmd)
        for sink in self.sinks:
            try:
                sink.on_tick(est, cmd, self)
            except Exception:
                log.exception("telemetry sink %s failed; continuing", type(sink).__name__)

    def _error_log_due(self, wall: float) -> bool:
        """Whether a failure at monotonic time ``wall`` (s) gets logged: failing ticks, obstacle input and the
        after-send bookkeeping share one log at most once a second (a failure every tick would flood it)."""
        if wall - self._last_error_log < 1.0:
            return False
        self._last_error_log = wall
        return True

    def _after_setpoint(self, est: Estimate, cmd: Command) -> None:
        """The flight core's bookkeeping once the setpoint is out (the loop-lag measurement), timed apart from
        the tick; a failure there is counted with the tick errors and logged, but does not escalate as failing
        ticks do: the setpoint went out (only the loop-lag measurement stands still)."""
        start = time.perf_counter()
        try:
            self.core.after_setpoint(est, cmd)
        except Exception as exc:
            self.stats.tick_errors += 1
            wall = time.monotonic()
            if self._error_log_due(wall):
                log.error("control bookkeeping failed (%d tick errors in all): %r", self.stats.tick_errors, exc)
        self.stats.after_s.append(time.perf_counter() - start)

    def _recent_valid(self, wall: float) -> tuple[float, np.ndarray, float] | None:
        """The last valid setpoint if it is at most one telemetry timeout old, else None (stream nothing)."""
        lv = self._last_valid
        if lv is None or wall - lv[3] > self.seq.cfg.invalid_estimate_s:
            return None
        return lv[0], lv[1], lv[2]

    def _obstacles(self, est: Estimate) -> Sequence[Obstacle]:
        """The obstacles the planner gets this tick: those within :data:`RELEVANT_RADIUS_M` of the vehicle.

        Culling keeps the tick's cost bounded when a perception node publishes hundreds of far-away trunks
        (the planner's cost grows with every obstacle it is given); it is redone when the set changes or the
        vehicle has moved 2 m since the last time.
        """
        obstacles = self.obstacle_source(est.t_s) if self.obstacle_source else self.mission.obstacles
        x, y = float(est.pos_ned_m[0]), float(est.pos_ned_m[1])
        if obstacles is not self._last_obstacles:
            self._last_obstacles = obstacles
            if len(self._obstacles_seen) < MAX_OBSTACLES_SEEN:
                for o in obstacles:
                    self._obstacles_seen.setdefault((o.x_m, o.y_m, o.radius_m, o.height_m), o)
        elif (x - self._cull_xy[0]) ** 2 + (y - self._cull_xy[1]) ** 2 < 4.0:
            return self._culled
        self._cull_xy = (x, y)
        if len(obstacles) <= 16:
            self._culled = obstacles
        else:
            r = RELEVANT_RADIUS_M
            self._culled = tuple(o for o in obstacles if (o.x_m - x) ** 2 + (o.y_m - y) ** 2 < (r + o.radius_m) ** 2)
        return self._culled

    def _apply_configured(self, answers: dict[str, float | int]) -> None:
        """Use what the set-up learned: the hover thrust parameter; say which streams were refused."""
        for key, value in answers.items():
            if key.startswith("message_interval:") and (value != value or int(value) != mavlink2.MAV_RESULT_ACCEPTED):
                (log.info if key in OPTIONAL_STREAMS else log.warning)(
                    "the vehicle refused or ignored %s (answer %s); flying with the rates it sends", key, value)
        if self.opts.hover_thrust_norm is None:
            value = answers.get(f"param_read:{self.profile.hover_param}")
            if value is not None and 0.05 <= float(value) <= 0.95:  # NaN (never answered) fails this too
                self.profile = replace(self.profile, hover_thrust_norm=float(value))
                self.core.profile = self.profile
            else:
                log.warning("could not read %s from the autopilot; assuming hover thrust %.2f (--hover-thrust)",
                            self.profile.hover_param, self.profile.hover_thrust_norm)
        log.info("thrust and modes as profile %r (hover %.2f)", self.profile.name, self.profile.hover_thrust_norm)

    def _log_transitions(self) -> None:
        tr = self.seq.transitions
        while self._transitions_logged < len(tr):
            t = tr[self._transitions_logged]
            self._transitions_logged += 1
            level = logging.INFO if t.to_state not in ("hold", "descend") else logging.WARNING
            log.log(level, "%s → %s: %s", t.from_state, t.to_state, t.reason)
            for sink in self.sinks:
                hear = getattr(sink, "on_transition", None)
                if hear is not None:
                    try:
                        hear(t, self)
                    except Exception:
                        log.exception("telemetry sink %s failed; continuing", type(sink).__name__)
            if t.to_state == "done":
                log.log(logging.INFO if self.outcome == "completed" else logging.WARNING,
                        "flight ended: %s (%s)", self.outcome, self.seq.detail)

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
        elif self.state.payload_pos_ned_m is not None:
            payload = self.state.payload_pos_ned_m - self.origin_ned_m
        else:
            payload = None
        self.log.append(est.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, swing, payload, cmd,
                        swing_used=est.swing if src == "estimate" else None)

    def _send_setpoint(self, t_s: float, q: np.ndarray, thrust_norm: float) -> None:
        if not self.link.connected:
            return
        send_set_attitude_target(
            self.link.mav, int(t_s * 1e3) & 0xFFFFFFFF, self.state.vehicle_sysid or 1, self.state.vehicle_compid,
            ATT_TYPE_MASK, q, 0.0, 0.0, 0.0, float(thrust_norm),
        )

    def _send_tick_only(self) -> None:
        if not self.link.connected:
            return
        send_set_attitude_target(
            self.link.mav, int(self.state.t_s * 1e3) & 0xFFFFFFFF, self.state.vehicle_sysid or 1,
            self.state.vehicle_compid, TICK_ONLY_MASK, _LEVEL_Q, 0.0, 0.0, 0.0, 0.0,
        )

    # ------------------------------------------------------------------ the report's view
    def run_facts(self, provisional: bool = False) -> dict[str, Any]:
        """What happened, for the report; ``provisional``: for the journal's provisional report, made on the loop
        every second, so its loop timings cover only the last :data:`PROVISIONAL_WINDOW_TICKS` ticks."""
        return {
            "outcome": self.outcome,
            "outcome_detail": self.seq.detail,
            "final_phase": self.phase,
            "abort_reason": self.abort_reason,
            "transitions": [
                {"t_s": t.now_s, "wall_s": t.wall_s, "from": t.from_state, "to": t.to_state, "reason": t.reason}
                for t in self.seq.transitions
            ],
            "loop": (self.stats.summary(PROVISIONAL_WINDOW_TICKS if provisional else None)
                     | self.gc_pacer.summary() | self.deaf.summary()
                     | self.stall_tracer.summary()),
            "link": {"received": self.link.received, "sent": self.link.sent, "rejected": dict(self.link.rejected),
                     **self.health.summary()},
            "rejected_telemetry": dict(self.state.rejected),
            "vehicle_statustext": self.state.statustext[-20:],
            "swing_sources": self.swing_sources,
            "swing_estimator": self._estimator_facts(),
            "loop_lag": self.core.lag_stats.facts(self.profile.nominal_loop_lag_s),
            "autopilot": {"family": self.profile.autopilot, "system_id": self.state.vehicle_sysid,
                          "component_id": self.state.vehicle_compid, "mav_autopilot": self.state.autopilot,
                          "mav_type": self.state.vehicle_type, "version": self.state.autopilot_version},
            "autopilot_params": self.params,
            "mission_frame": {"origin_local_ned_m": self.origin_ned_m.tolist(), "origin": self.origin_source},
            "arrival": dict(self.core.arrival),
            "journal": self.journal.summary() if self.journal is not None else None,
        }

    def _estimator_facts(self) -> dict[str, Any] | None:
        """What the swing estimator ran on, when it ran."""
        feed = self.swing_feed
        if feed.ran is None:
            return None
        last = feed.last_seen
        return {"inputs": dict(feed.counts), "rejected": None if last is None else last.rejected,
                "dropped_late": feed.ran.dropped_late, "rejected_total": feed.ran.rejected_total,
                "swing_resets": feed.ran.resets, "q_swing_scale": round(feed.ran.q_swing_scale, 3),
                # each taut payload fix against the estimate of its own time (what the controller flew on then)
                "error_at_fixes": feed.fix_error_summary(),
                "sources_last_second": None if last is None else list(last.sources),
                "fade_last": None if last is None else last.fade,
                # what it learnt of the drags (the airframe's N per m/s, the payload's N per (m/s)²)
                "drag_n_per_mps": None if last is None else round(last.drag_n_per_mps, 4),
                "payload_drag_n_per_mps2": None if last is None else round(last.payload_drag_n_per_mps2, 5),
                "filters": feed.ran.selection_facts() if hasattr(feed.ran, "selection_facts") else None}

    def _provisional(self) -> dict[str, Any]:
        facts = self.run_facts(provisional=True)
        if self.opts.provisional is not None:
            facts.update(self.opts.provisional(self))
        return facts
