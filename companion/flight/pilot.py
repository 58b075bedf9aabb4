"""The pilot: one flight's decisions, pure and synchronous.

It owns the vehicle state, the swing feed, the flight sequence and the flight core. A runner feeds it what arrives
(:meth:`Pilot.on_telemetry`, :meth:`Pilot.on_answer`) and the time, asks it for a tick (:meth:`Pilot.tick`), sends
what the tick returns (requests first, then the setpoint), and then lets it finish the tick
(:meth:`Pilot.after_setpoint`, :meth:`Pilot.finish_tick`). Data flows one way, once per control tick::

    telemetry ─▶ VehicleState ─▶ Estimate ─▶ FlightSequence (what to stream, what to ask)
                                          └─▶ FlightCore (plan ▶ control) ─▶ setpoint

Every decision — when to arm, when our mode counts as ours, when to hold, land or let go — is made by the
:class:`~companion.flight.sequence.FlightSequence`; the pilot carries its orders to the core, keeps the mission
frame, hands the planner the obstacles around the vehicle and records the flight. No I/O, no clock of its own:
the runner's :class:`~companion.flight.health.RealtimeClock` or :class:`~companion.flight.health.LockstepClock`
says how the sequence sees time. An exception inside a tick is caught at the tick's boundary, counted and logged
at most once a second; the sequence holds and lands after three in a row.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from companion.autopilots.family import SetupOptions
from companion.autopilots.profile import VehicleProfile, profile_by_name, profile_for_autopilot
from companion.core.mission import Mission
from companion.core.rotations import quat_from_euler
from companion.estimation.estimate import Estimate
from companion.estimation.swing_feed import SwingFeed, estimator_config
from companion.estimation.vehicle_state import VehicleState
from companion.flight.command import Setpoint
from companion.flight.core import Command, FlightCore
from companion.flight.flight_record import FlightRecord
from companion.flight.health import LinkHealth, LockstepClock, RealtimeClock
from companion.flight.identification import Identification
from companion.flight.mission_frame import MissionFrame
from companion.flight.obstacle_view import ObstacleView
from companion.flight.operator import Answer, OperatorDesk
from companion.flight.phase import CoreOrder, Phase, State, flight_phase
from companion.flight.requests import Request
from companion.flight.sensing import Sensing
from companion.flight.sequence import FlightSequence
from companion.flight.sequence_types import Observation, SequenceConfig, Stream, Transition
from companion.flight.setup import FlightSetup
from companion.mavlink_io.telemetry import TelemetryEvent
from companion.perception.pipeline import Perception
from companion.perception.scan import Scan

log = logging.getLogger(__name__)

MAV_RESULT_ACCEPTED = 0
OPTIONAL_STREAMS = {"message_interval:ESTIMATOR_STATUS"}  # nice to have: refusing them is no warning
#: (s) lockstep: no position or attitude for this long (wall time) is a lost link: longer than a loaded machine
#: stalls a process (1.02 s seen), shorter than the fault suite's 2 s to tell a dead vehicle (docs/measurements.md)
LOCKSTEP_TELEMETRY_LOSS_S = 1.5
SWING_WAIT_S = 5.0  # with a swing estimator: the longest the climb waits at the start altitude for its trust (s)


@dataclass(frozen=True, slots=True)
class TickOut:
    """What one tick asks the runner to do: send ``requests``, then ``setpoint`` (None: stream nothing; a lockstep
    runner then answers the step with a tick-only frame). ``est`` (mission frame) and ``cmd`` are for the record
    and the sinks."""

    requests: tuple[Request, ...]
    setpoint: Setpoint | None
    stream: Stream
    est: Estimate | None
    cmd: Command | None


@dataclass(frozen=True, slots=True)
class Arrival:
    """What a message changed that the runner must act on: the vehicle was just found (lock the link onto it),
    or a new lockstep end-of-step marker arrived (answer it with a tick)."""

    vehicle_found: bool = False
    marker: bool = False


class Pilot:
    """One mission flown: feed it messages and answers, tick it, send what it returns."""

    def __init__(self, mission: Mission, setup: FlightSetup) -> None:
        self.mission = mission
        self.setup = setup
        #: how the sequence sees time: the vehicle's in lockstep, the wall clock otherwise (its runner feeds it)
        self.clock: RealtimeClock | LockstepClock = LockstepClock() if setup.lockstep else RealtimeClock()
        self.state = VehicleState(
            cable_length_m=mission.vehicle.l, payload_sysid=setup.payload_sysid, swing_input=setup.swing_input,
            max_time_rate=1e4 if setup.lockstep else 2.0,
        )
        self.swing_feed = SwingFeed(mission.companion_params(), setup.swing_input, estimator_config(mission))
        self.profile: VehicleProfile = setup.profile or profile_by_name("px4", setup.hover_thrust_norm)
        self.period_s = setup.period_s
        self.core = FlightCore(mission, gains=setup.gains, profile=self.profile, period_s=self.period_s)
        if self.swing_feed.wants_estimator:
            self.core.swing_wait_s = SWING_WAIT_S
        self.seq = FlightSequence(self._sequence_config())
        #: the ground station's pause/resume/land/return, answered (companion.flight.operator)
        self.desk = OperatorDesk(setup.gcs_sysid, signing=setup.signing_key is not None)
        self.orders_log: list[dict] = []  # its orders as carried out: vehicle time t_s, monotonic wall_s (s)
        self.health = LinkHealth(period_s=self.period_s)
        self.record = FlightRecord(mission, self.state, setup.scored_cable_m)
        self.frame = MissionFrame(mission.start_ned_m, setup.start_here, setup.mission_origin_ned_m)
        self.obstacles = ObstacleView(mission.obstacles)
        #: the map of what the vehicle's own range sensors saw, and its feed (see ``FlightSetup.perception``)
        self.sensing = Sensing(setup.perception, setup.lockstep, self.frame, self.obstacles, self.core,
                               lambda: self.state.vehicle_sysid, self.record.error_log_due)
        self.params: dict[str, dict[str, float]] = {"read": {}, "set": {}}  # the autopilot parameters read/set
        #: the payload identified from the IMU: in the report, and before the cruise when the mission says it is
        #: unknown (issue 28; the runner runs it when ``identification.due``, then calls :meth:`identified`)
        self.identification = Identification(mission)
        self.abort_reason: str | None = None
        self.tick_errors = 0
        self.tick_errors_in_row = 0
        self._tracking_error_m = 0.0  # distance from the last command's reference (m, the sequence's divergence)
        self._last_valid: tuple[float, np.ndarray, float, float] | None = None  # (t_s, q, thrust, wall) sent last
        self._last_marker_ms = -1
        self._marker_seen_wall = 0.0
        self._transitions_taken = 0

    def _sequence_config(self) -> SequenceConfig:
        s, m = self.setup, self.mission
        base = s.sequence or SequenceConfig()
        if s.lockstep:
            # Simulated time waits for both processes: a stall of either is not staleness (the vehicle's
            # telemetry is measured from our last answer), and a loaded machine can pause a process for longer
            # than 0.5 s (LOCKSTEP_TELEMETRY_LOSS_S).
            base = replace(base, stale_s=float("inf"),
                           telemetry_loss_s=max(base.telemetry_loss_s, LOCKSTEP_TELEMETRY_LOSS_S))
        return replace(
            base, connect_timeout_s=s.heartbeat_timeout_s, ready_timeout_s=s.ready_timeout_s,
            prestream_s=s.prestream_s, land_on_abort=s.land_on_abort, land_at_end=m.land,
            land_timeout_s=s.land_timeout_s, mission_wall_timeout_s=s.wall_timeout_s,
        )

    # ------------------------------------------------------------------ views
    @property
    def phase(self) -> Phase:
        """Where the flight is (see :func:`companion.flight.phase.flight_phase`)."""
        return flight_phase(self.seq.state, self.seq.final_phase, self.core.phase)

    @property
    def outcome(self) -> str:
        """The flight's outcome so far (see :data:`companion.flight.sequence.OUTCOMES`)."""
        return self.seq.outcome

    @property
    def finished(self) -> bool:
        """True once the flight sequence is done."""
        return self.seq.finished

    # ------------------------------------------------------------------ input
    def on_telemetry(self, ev: TelemetryEvent, wall_s: float) -> Arrival:
        """One decoded MAVLink message (:func:`companion.mavlink_io.telemetry.decode`), received at monotonic time
        ``wall_s`` (s)."""
        st = self.state
        known = st.vehicle_sysid is not None
        kind = st.ingest(ev, wall_s)
        if kind != "REJECTED":
            self.swing_feed.ingest(ev, st)
            if kind == "GLOBAL_POSITION_INT":  # ArduPilot's payload: fixes relative to the airframe, once paired
                for t_fix, off, vel in self.swing_feed.take_fresh_offsets():
                    if st.pos_ned_m is not None:  # the angles come from ``off`` alone
                        st.set_payload_fix(t_fix, st.pos_ned_m + off, vel)
        found = not known and st.vehicle_sysid is not None
        if found:
            self._vehicle_found()
        self.sensing.on_event(ev, wall_s)
        marker = False
        src = ev.src_system
        if src == st.vehicle_sysid:
            self.health.on_frame(src, ev.src_component, ev.seq)
            self.identification.on_event(kind, ev)
            if kind == "LOCAL_POSITION_NED":
                self.health.on_sample("position", st.pos_t_s)
            elif kind == "ATTITUDE":
                self.health.on_sample("attitude", st.att_t_s)
            elif kind == "SYSTEM_TIME" and (
                    ev.t_boot_ms != self._last_marker_ms or wall_s - self._marker_seen_wall > 0.5):
                # A repeated marker (same time) is the vehicle re-asking after a lost answer: answer again only if
                # we have not answered for 0.5 s, so duplicates never double-step a lockstep simulation.
                self._last_marker_ms = ev.t_boot_ms
                self._marker_seen_wall = wall_s
                marker = True
        return Arrival(found, marker)

    @property
    def perception(self) -> Perception | None:
        """The perception map (None until it is on)."""
        return self.sensing.perception

    def on_scan(self, scan: Scan, vehicle_clock: bool = True) -> None:
        """A whole range scan from Zenoh, between ticks (see :meth:`companion.flight.sensing.Sensing.on_scan`)."""
        self.sensing.on_scan(scan, vehicle_clock)

    def on_unread_frame(self, src_system: int, src_component: int, seq: int) -> None:
        """A message nothing reads: still a frame of the vehicle's stream (its sequence numbers count for loss)."""
        if src_system == self.state.vehicle_sysid:
            self.health.on_frame(src_system, src_component, seq)

    def on_answer(self, key: str, value: int | float) -> None:
        """The autopilot answered a request: ``key`` as :meth:`RequestLink.answer_of` names it."""
        if key.startswith("param:"):  # a PARAM_VALUE: ours only if it answers a read or a write we asked for
            name = key[6:]
            if self.seq.answer(f"param_read:{name}", value):
                self.params["read"][name] = float(value)
            elif self.seq.answer(f"param_set:{name}", value):
                self.params["set"][name] = float(value)
        else:
            self.seq.answer(key, value)

    def on_command(self, ev: TelemetryEvent) -> Answer | None:
        """A COMMAND_LONG/COMMAND_INT: what to answer when it is addressed to the companion (None otherwise); an
        accepted order goes to the sequence, carried out at the next tick."""
        ans = self.desk.on_command(ev, self.state.vehicle_sysid, self.seq.state, self.seq.paused)
        if ans is not None and ans.order is not None:
            self.seq.order(ans.order, f"{ans.order} ordered by the ground station (system {ev.src_system})")
        return ans

    def identified(self) -> None:
        """The runner ran the due identification: the flight goes on with what it found (or lands when the
        vehicle cannot lift it with margin)."""
        reason = self.identification.conclude(self.core, self.swing_feed, self.state)
        if reason is not None:
            self.request_abort(reason)

    def request_abort(self, reason: str = "operator abort (Ctrl-C)") -> None:
        """Stop the mission: hold, land if configured, finish. Safe to call from a signal handler."""
        if self.abort_reason is None:
            log.warning("abort requested: %s", reason)
            self.abort_reason = reason

    def _vehicle_found(self) -> None:
        """The first autopilot HEARTBEAT: pick the profile, plan the set-up (the runner locks the link)."""
        st, s = self.state, self.setup
        if s.profile is None:
            self.profile = profile_for_autopilot(st.autopilot, s.hover_thrust_norm)
            self.core.profile = self.profile
        st.mode_class = self.profile.mode_class
        family = self.profile.family
        opts = SetupOptions(rate_hz=s.rate_hz, swing_sensor=s.swing_input in ("auto", "cable_sensor"),
                            read_hover_thrust=s.hover_thrust_norm is None, allow_param_writes=s.allow_param_writes)
        self.seq.plan(configure=family.setup(opts), takeover_before_arm=family.takeover_before_arm,
                      followup=lambda answers: family.followup(answers, opts))
        log.info("vehicle: system %s component %s, %s autopilot, mode %s", st.vehicle_sysid, st.vehicle_compid,
                 self.profile.autopilot, st.mode_name)

    # ------------------------------------------------------------------ the tick
    def _observe(self, est: Estimate | None, wall_s: float) -> Observation:
        st = self.state
        now_s, hb_wall, tel_wall = self.clock.times(st.heartbeat_wall_s, st.telemetry_wall_s, st.t_s, st.pos_t_s,
                                                    st.att_t_s, wall_s)
        start_error_m = self.frame.update(st.pos_ned_m, st.home_ned_m, st.on_ground, self.seq.state)
        return Observation(
            now_s=now_s, wall_s=wall_s, heartbeat_wall_s=hb_wall, telemetry_wall_s=tel_wall,
            telemetry_ready=st.ready(), vehicle_ready=st.ready_to_arm(self.profile.family.prearm_bit),
            armed=st.armed, mode=st.mode, on_ground=st.on_ground, heartbeats=st.heartbeats,
            estimate_ok=est is not None, core_result=self.core.result, tick_errors_in_row=self.tick_errors_in_row,
            abort=self.abort_reason, mission_timeout_s=self.mission.timeout_s, last_words=st.last_words,
            start_error_m=start_error_m, tracking_error_m=self._tracking_error_m,
            unready=st.unready(self.profile.family.prearm_bit) if self.seq.state is State.WAIT_READY else (),
        )

    def tick(self, wall_s: float) -> TickOut:
        """One control tick at monotonic time ``wall_s`` (s): observe → sequence → (flight core) → setpoint. A
        runner's watchdog step is a tick whose setpoint it does not send."""
        est: Estimate | None = None
        cmd: Command | None = None
        setpoint: Setpoint | None = None
        stream = Stream.NONE
        send: tuple[Request, ...] = ()
        try:
            est = self.state.estimate()
            step = self.seq.step(self._observe(est, wall_s))
            if len(self.seq.orders_done) != len(self.orders_log):  # a ground station's order carried out
                self.orders_log += [{"order": str(o), "t_s": self.state.t_s, "wall_s": wall_s}
                                    for _, o in self.seq.orders_done[len(self.orders_log):]]
            if est is not None:
                self.swing_feed.maybe_start(self.state)
                self.identification.on_tick(self.core.phase, est.t_s)
                est = self.frame.to_mission(self.swing_feed.choose(est))
            stream, send = step.stream, step.send
            if step.configured is not None:
                self._apply_configured(step.configured)
            if step.core is CoreOrder.HOLD_HERE:
                self.core.hold_here()
            elif step.core is CoreOrder.DESCEND:
                self.core.descend()
            elif step.core is CoreOrder.PAUSE:
                self.core.hold_here(brake=True)
            elif step.core is CoreOrder.RESUME and not self.core.resume():
                log.warning("the ground station's resume found nothing to resume (core phase %s)", self.core.phase)
            setpoint, cmd = self._setpoint(stream, est, wall_s)
            self.tick_errors_in_row = 0
        except Exception as exc:  # the loop boundary: count, log once a second, keep the vehicle safe
            self.tick_errors_in_row += 1
            self.tick_errors += 1
            if self.record.error_log_due(wall_s):
                log.error("control tick failed (%d in a row, %d in all): %r", self.tick_errors_in_row,
                          self.tick_errors, exc, exc_info=self.tick_errors == 1)
            setpoint = self._recent_valid(wall_s) if stream in (Stream.CORE, Stream.DESCENT) else None
            cmd = None
        return TickOut(send, setpoint, stream, est, cmd)

    def _setpoint(self, stream: Stream, est: Estimate | None, wall_s: float) -> tuple[Setpoint | None, Command | None]:
        """What to stream for ``stream``: the core's command, the last valid one (briefly, while the estimate is
        invalid), or idle (level, zero thrust: only ever to a vehicle on the ground)."""
        if stream in (Stream.CORE, Stream.DESCENT):
            if est is None:
                return self._recent_valid(wall_s), None
            inject = self.setup.inject_tick_error_at_s
            if inject is not None and est.t_s >= inject:
                raise RuntimeError("injected tick fault (SLUNGPILOT_INJECT_TICK_ERROR_AT_S)")
            obstacles = self.obstacles.around(est.t_s, float(est.pos_ned_m[0]), float(est.pos_ned_m[1]))
            cmd = self.core.setpoint(est, obstacles)
            if self.core.arrival["t_s"] is not None:  # the report's "at the goal" follows the flight's
                self.record.log.goal_tol_m = self.core.arrival["tolerance_m"]
            self.swing_feed.commanded(est.t_s, cmd.thrust_n)
            self._tracking_error_m = math.dist(est.pos_ned_m.tolist(), cmd.ref_pos_ned_m.tolist())
            return Setpoint(est.t_s, cmd.q_ned_frd_wxyz, cmd.thrust_norm), cmd
        if stream is Stream.IDLE:
            yaw = float(est.euler_rad[2]) if est is not None else 0.0
            return Setpoint(self.state.t_s, quat_from_euler(0.0, 0.0, yaw), 0.0), None
        return None, None

    def _recent_valid(self, wall_s: float) -> Setpoint | None:
        """The last valid setpoint if it is at most one telemetry timeout old, else None (stream nothing)."""
        lv = self._last_valid
        if lv is None or wall_s - lv[3] > self.seq.cfg.invalid_estimate_s:
            return None
        return Setpoint(lv[0], lv[1], lv[2])

    def sent(self, out: TickOut, wall_s: float) -> None:
        """The runner sent ``out.setpoint``: remember it as the last valid one (core commands only)."""
        if out.setpoint is not None and out.stream is not Stream.IDLE and out.cmd is not None:
            self._last_valid = (*out.setpoint, wall_s)

    def after_setpoint(self, out: TickOut, wall_s: float) -> None:
        """The core's bookkeeping once the setpoint is out (the loop-lag measurement). A failure is counted with the
        tick errors and logged, but does not escalate as failing ticks do: the setpoint went out."""
        if out.cmd is None or out.est is None:
            return
        try:
            self.core.after_setpoint(out.est, out.cmd)
        except Exception as exc:
            self.tick_errors += 1
            if self.record.error_log_due(wall_s):
                log.error("control bookkeeping failed (%d tick errors in all): %r", self.tick_errors, exc)

    def take_transitions(self) -> list[Transition]:
        """The sequence's state changes since the last call (logged here; the runner tells its sinks)."""
        tr = self.seq.transitions
        new = tr[self._transitions_taken:]
        self._transitions_taken = len(tr)
        for t in new:
            level = logging.INFO if t.to_state not in ("hold", "descend") else logging.WARNING
            log.log(level, "%s → %s: %s", t.from_state, t.to_state, t.reason)
            if t.to_state == "done":
                log.log(logging.INFO if self.outcome == "completed" else logging.WARNING,
                        "flight ended: %s (%s)", self.outcome, self.seq.detail)
        return new

    def finish_tick(self, out: TickOut, wall_s: float) -> None:
        """After a (non-watchdog) tick with an estimate: link health and the flight log's row."""
        est = out.est
        if est is None:
            return
        self.health.on_tick(est.t_s, wall_s - (self.state.telemetry_wall_s or wall_s))
        flog = self.record.log
        if flog.obstacle_clock_t0_s is None and self.core.t0_s is not None:
            flog.obstacle_clock_t0_s = self.core.t0_s  # the report places moving mission trunks from here
        if self.seq.streaming_ours or out.cmd is not None:
            self.record.append(est, out.cmd, self.frame.origin_ned_m)

    def _apply_configured(self, answers: dict[str, float | int]) -> None:
        """Use what the set-up learned: the hover thrust parameter; say which streams were refused."""
        for key, value in answers.items():
            if key.startswith("message_interval:") and (value != value or int(value) != MAV_RESULT_ACCEPTED):
                (log.info if key in OPTIONAL_STREAMS else log.warning)(
                    "the vehicle refused or ignored %s (answer %s); flying with the rates it sends", key, value)
        if self.setup.hover_thrust_norm is None:
            value = answers.get(f"param_read:{self.profile.hover_param}")
            if value is not None and 0.05 <= float(value) <= 0.95:  # NaN (never answered) fails this too
                self.profile = replace(self.profile, hover_thrust_norm=float(value))
                self.core.profile = self.profile
            else:
                log.warning("could not read %s from the autopilot; assuming hover thrust %.2f (--hover-thrust)",
                            self.profile.hover_param, self.profile.hover_thrust_norm)
        log.info("thrust and modes as profile %r (hover %.2f)", self.profile.name, self.profile.hover_thrust_norm)
