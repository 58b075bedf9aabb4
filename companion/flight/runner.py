"""What both runners do with the pilot: carry a tick out over the link, time it, tell the sinks, keep the
journal. The runners differ only in *when* they tick: :mod:`companion.flight.realtime` on a monotonic schedule
inside asyncio, :mod:`companion.flight.lockstep` whenever the simulated vehicle ends a step, in a plain blocking
loop. Neither decides anything: the :class:`~companion.flight.pilot.Pilot` does.

Each tick: the pilot's requests go out first, then the setpoint (so a lockstep vehicle handles them at the same
simulated time in every run); then the core's after-send bookkeeping, the sequence's transitions to the sinks, the
flight log's row and the sinks' per-tick samples. ``tick`` time is the pilot's own work; the send is timed apart,
because on a busy machine the kernel may run the receiving simulator inside our sendto().
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.obstacles import Obstacle
from companion.flight.command import Setpoint
from companion.flight.facts import pilot_facts
from companion.flight.loop_stats import PROVISIONAL_WINDOW_TICKS, LoopStats
from companion.flight.pilot import Pilot, TickOut
from companion.flight.scheduling import GcPacer, involuntary_switches
from companion.flight.sequence_types import Transition
from companion.mavlink_io.codec import send_set_attitude_target
from companion.mavlink_io.commands import RequestLink
from companion.mavlink_io.link import MavlinkLink
from companion.mavlink_io.statustext import StatusTextOut
from companion.mavlink_io.telemetry import CommandInt, CommandLong, TelemetryEvent, decode, decode_frame
from companion.report.journal import Journal

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
PERCEPTION_BUDGET_S = 1.0e-3  # mapping a deferred scan after a tick (plus one slice: a stage or a few circle fits)


class TelemetrySink(Protocol):
    """Where a flight publishes as it goes (the Zenoh streams, the live view, the terminal's narration).

    Both run on the control thread and must be cheap and never block: ``on_tick`` after each tick's setpoint went
    out, ``on_transition`` on every state change of the flight sequence (even before telemetry flows).
    """

    def on_tick(self, est: Any, cmd: Any, run: Runner) -> None: ...

    def on_transition(self, t: Transition, run: Runner) -> None: ...


class Wiring:
    """What a flight is plugged into besides its link: telemetry sinks, live obstacle input (``obstacle_source(t_s)``
    and ``obstacle_ingest(t_s)``, which parses what waits, after each tick), ``on_connected(run)`` (once the vehicle
    is known, outside the tick: it may open sessions, add sinks and set the obstacle input), and ``provisional(run)``
    (extra facts for the journal's provisional report)."""

    def __init__(self, sinks: Sequence[TelemetrySink] = (),
                 obstacle_source: Callable[[float], Sequence[Obstacle]] | None = None,
                 obstacle_ingest: Callable[[float], None] | None = None,
                 on_connected: Callable[[Runner], None] | None = None,
                 provisional: Callable[[Runner], dict[str, Any]] | None = None) -> None:
        self.sinks = list(sinks)
        self.obstacle_source = obstacle_source
        self.obstacle_ingest = obstacle_ingest
        self.on_connected = on_connected
        self.provisional = provisional


class Runner:
    """The part of a runner that does not depend on when it ticks. Subclasses call :meth:`_tick`."""

    lockstep: bool  #: which flights a subclass runs (the pilot's set-up must say the same)

    def __init__(self, pilot: Pilot, wiring: Wiring | None = None) -> None:
        if pilot.setup.lockstep is not self.lockstep:
            raise ValueError(f"{type(self).__name__} runs {'lockstep' if self.lockstep else 'real-time'} flights; "
                             f"the pilot was set up with lockstep={pilot.setup.lockstep}")
        self.pilot = pilot
        self.setup = pilot.setup
        w = wiring or Wiring()
        self.sinks: list[TelemetrySink] = w.sinks
        self.obstacle_ingest = w.obstacle_ingest
        self.on_connected = w.on_connected
        self.provisional = w.provisional
        if w.obstacle_source is not None:
            pilot.obstacles.use_source(w.obstacle_source)
        s = self.setup
        self.link = MavlinkLink(s.connect, self._on_message, tlog=s.tlog_path, sock=s.sock, signing_key=s.signing_key,
                                accept_unsigned=s.accept_unsigned)
        self.link.frame_handler = self._on_frame
        self.texts = StatusTextOut(self.link.mav)  # our phases, failsafes and answers, to the ground station
        self._core_phase_said = ""  # the mission's phase (climb, cruise, hold, ...) last said to the GCS
        st = pilot.state
        self.requests = RequestLink(self.link.mav, lambda: (st.vehicle_sysid, st.vehicle_compid),
                                    lambda what: pilot.profile.mode_params(what))
        self.journal = Journal(s.run_dir, pilot.record.log, pilot.mission) if s.run_dir is not None else None
        self.stats = LoopStats()
        self.gc_pacer = GcPacer()  # the garbage collector runs between ticks, not inside them
        self._marker_pending = False
        self._last_tick_wall = 0.0
        self._identifying: threading.Thread | None = None  # the payload identification running beside the loop
        self._connected_hook_done = False

    # ------------------------------------------------------------------ views for sinks and reports
    @property
    def state(self) -> Any:
        return self.pilot.state

    @property
    def mission(self) -> Any:
        return self.pilot.mission

    @property
    def profile(self) -> Any:
        return self.pilot.profile

    @property
    def outcome(self) -> str:
        return self.pilot.outcome

    @property
    def phase(self) -> str:
        return self.pilot.phase

    @property
    def obstacles_seen(self) -> tuple[Obstacle, ...]:
        return self.pilot.obstacles.seen

    def request_abort(self, reason: str = "operator abort (Ctrl-C)") -> None:
        """Stop the mission: hold, land if configured, finish. Safe to call from a signal handler."""
        self.pilot.request_abort(reason)

    # ------------------------------------------------------------------ input
    def _on_frame(self, frame: bytes) -> None:
        """A CRC-checked unsigned frame (the link's fast path): decoded straight to its typed event."""
        ev = decode_frame(frame)
        if ev is None:
            self.pilot.on_unread_frame(frame[5], frame[6], frame[4])
            return
        self._on_event(ev)

    def _on_message(self, msg: Any) -> None:
        """A message pymavlink decoded (signed frames, and anything off the fast path)."""
        ev = decode(msg)
        if ev is None:
            self.pilot.on_unread_frame(msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq())
            return
        self._on_event(ev)

    def _on_event(self, ev: TelemetryEvent) -> None:
        arrival = self.pilot.on_telemetry(ev, time.monotonic())
        if arrival.vehicle_found:
            self.link.lock_to_last_sender()
            # a companion shares its vehicle's system id, with its own component (191), as MAVLink recommends
            self.link.mav.srcSystem = self.pilot.state.vehicle_sysid
        if arrival.marker:
            self._marker_pending = True
        ans = self.requests.answer_of(ev)
        if ans is not None:
            self.pilot.on_answer(*ans)
        elif ev.__class__ is CommandLong or ev.__class__ is CommandInt:
            self._answer_command(ev)

    def _answer_command(self, ev: CommandLong) -> None:
        """A ground station's command addressed to us: COMMAND_ACK to its sender, and a STATUSTEXT saying why."""
        answer = self.pilot.on_command(ev)
        if answer is None:
            return
        log.info("ground station (system %d): command %d answered %d %s", ev.src_system, ev.command, answer.result,
                 answer.text)
        self.link.mav.command_ack_send(answer.command, answer.result, 0, 0, answer.to_system, answer.to_component)
        if answer.text:
            self.texts.say(answer.severity, answer.text, time.monotonic())

    # ------------------------------------------------------------------ the tick
    def _tick(self, watchdog: bool = False) -> None:
        """One tick carried out (see the module docstring); a watchdog tick sends no setpoint."""
        start = time.perf_counter()
        cpu_start = time.thread_time()
        switches = involuntary_switches()
        wall = time.monotonic()
        self._last_tick_wall = wall
        out = self.pilot.tick(wall)
        computed = time.perf_counter()
        computed_cpu = time.thread_time()
        preempted = involuntary_switches() > switches
        self._send_requests(out, wall)
        if not watchdog:
            self._send_setpoint(out.setpoint, wall, out)
        sent = time.perf_counter()
        if out.cmd is not None and out.est is not None:
            self.pilot.after_setpoint(out, wall)
            self.stats.after_s.append(time.perf_counter() - sent)
        self._tell_transitions()
        if self.pilot.finished:
            self._finished()
        if watchdog:
            return
        st = self.stats
        st.ticks += 1
        st.tick_s.append(computed - start)
        st.tick_cpu_s.append(computed_cpu - cpu_start)
        st.preempted_ticks += preempted
        st.send_s.append(sent - computed)
        if out.est is None:
            return
        st.last = (sent, out.est.t_s)
        if st.first is None:
            st.first = st.last
        self.pilot.finish_tick(out, wall)
        for sink in self.sinks:
            try:
                sink.on_tick(out.est, out.cmd, self)
            except Exception:
                log.exception("telemetry sink %s failed; continuing", type(sink).__name__)

    def _send_requests(self, out: TickOut, wall: float) -> None:
        try:
            for req in out.requests:
                self.requests.send(req)
        except Exception as exc:  # a request we cannot pack: counted like a failing tick
            self.pilot.tick_errors += 1
            if self.pilot.record.error_log_due(wall):
                log.error("cannot send a request (%d tick errors in all): %r", self.pilot.tick_errors, exc)
        while self.requests.instant_answers:
            self.pilot.on_answer(*self.requests.instant_answers.pop())

    def _send_setpoint(self, sp: Setpoint | None, wall: float, out: TickOut) -> None:
        """Stream ``sp``; with nothing to stream, a lockstep runner still answers the step (tick-only frame)."""
        if not self.link.connected:
            return
        st = self.pilot.state
        if sp is not None:
            send_set_attitude_target(self.link.mav, int(sp.t_s * 1e3) & 0xFFFFFFFF, st.vehicle_sysid or 1,
                                     st.vehicle_compid, ATT_TYPE_MASK, sp.q_ned_frd_wxyz, 0.0, 0.0, 0.0,
                                     float(sp.thrust_norm))
            self.pilot.sent(out, wall)
        elif self.setup.lockstep:
            send_set_attitude_target(self.link.mav, int(st.t_s * 1e3) & 0xFFFFFFFF, st.vehicle_sysid or 1,
                                     st.vehicle_compid, TICK_ONLY_MASK, _LEVEL_Q, 0.0, 0.0, 0.0, 0.0)

    def _tell_transitions(self) -> None:
        if self.texts.waiting:
            self.texts.pump(time.monotonic())
        for t in self.pilot.take_transitions():
            self._say_transition(t)
            for sink in self.sinks:
                try:
                    sink.on_transition(t, self)
                except Exception:
                    log.exception("telemetry sink %s failed; continuing", type(sink).__name__)
        core_phase = self.pilot.core.phase
        if core_phase != self._core_phase_said and self.pilot.seq.state == "mission":
            self._core_phase_said = core_phase
            self.texts.say(6, f"slungpilot mission phase: {core_phase}", time.monotonic())

    def _say_transition(self, t: Transition) -> None:
        """A phase change as STATUSTEXT for the ground station (holds and failsafes as warnings)."""
        if t.to_state == "done":
            ok = self.pilot.outcome == "completed"
            text, sev = f"slungpilot done: {self.pilot.outcome}: {self.pilot.seq.detail}", 5 if ok else 4
        else:
            text, sev = f"slungpilot {t.to_state}: {t.reason}", 4 if t.to_state in ("hold", "descend") else 6
        self.texts.say(sev, text, time.monotonic())

    def _between_ticks(self) -> None:
        """After a tick's setpoint is out: obstacle input (its own time budget, timed apart from the tick; its
        failures counted, never raised into the loop), a slice of a deferred scan's mapping (real time), then any
        garbage collection that is due."""
        if self.obstacle_ingest is not None:
            start = time.perf_counter()
            try:
                self.obstacle_ingest(self.pilot.state.t_s)
            except Exception:
                self.stats.ingest_errors += 1
                if self.pilot.record.error_log_due(time.monotonic()):
                    log.exception("obstacle input failed (%d times); flying with the obstacles adopted so far",
                                  self.stats.ingest_errors)
            self.stats.ingest_s.append(time.perf_counter() - start)
        # real time: a deferred scan, a slice at a time (a failure drops it and is counted with perception's)
        self.pilot.sensing.work(time.perf_counter() + PERCEPTION_BUDGET_S, time.perf_counter, time.monotonic())
        self._identify()
        self.gc_pacer.step()

    def _identify(self) -> None:
        """A due payload identification (companion.flight.identification): in lockstep at once (simulated time
        waits); in real time in a thread (the compiled fit runs without the GIL), concluded at the first gap between
        ticks after it ends. A daemon thread: it never outlives the process."""
        pilot = self.pilot
        if not pilot.identification.due:
            return
        if self.setup.lockstep:
            pilot.identification.watch.identify()
            pilot.identified()
        elif self._identifying is None:
            self._identifying = threading.Thread(target=pilot.identification.watch.identify, daemon=True,
                                                 name="payload-identification")
            self._identifying.start()
        elif not self._identifying.is_alive():
            self._identifying = None
            pilot.identified()

    def _finished(self) -> None:
        """The sequence is done: the subclass stops its loop."""
        raise NotImplementedError

    # ------------------------------------------------------------------ housekeeping
    def _connected_hook(self) -> None:
        """``on_connected`` once the vehicle is known (outside the tick: it may open sessions)."""
        if self._connected_hook_done or self.pilot.state.vehicle_sysid is None:
            return
        self._connected_hook_done = True
        if self.on_connected is None:
            return
        try:
            self.on_connected(self)
        except Exception:
            log.exception("on_connected hook failed; flying without it")

    def _housekeeping(self) -> None:
        """Once a second: our HEARTBEAT (an onboard controller, component 191, the vehicle's system id once it is
        known; docs/autopilots.md says what each autopilot then sends us), and the journal's flush (bytes handed
        to its own thread: no disk wait here)."""
        if self.link.connected:
            mav_type = self.pilot.profile.family.heartbeat_type if self.pilot.state.vehicle_sysid is not None \
                else mavlink2.MAV_TYPE_ONBOARD_CONTROLLER
            self.link.mav.heartbeat_send(mav_type, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE)
        if self.journal is not None:
            try:
                self.journal.flush(self.provisional_facts())
            except Exception:  # housekeeping must outlive a bug in the report's facts
                log.exception("cannot hand the journal its flush")

    def use_obstacle_input(self, source: Callable[[float], Sequence[Obstacle]],
                           ingest: Callable[[float], None] | None) -> None:
        """Live obstacles from now on: ``source(t_s)`` for the planner, ``ingest(t_s)`` after each tick."""
        self.pilot.obstacles.use_source(source)
        self.obstacle_ingest = ingest

    # ------------------------------------------------------------------ the report's view
    def loop_facts(self, provisional: bool = False) -> dict[str, Any]:
        """The loop's timing (``loop`` in the report); the subclass adds its own."""
        return (self.stats.summary(PROVISIONAL_WINDOW_TICKS if provisional else None)
                | {"tick_errors": self.pilot.tick_errors} | self.gc_pacer.summary())

    def run_facts(self, provisional: bool = False) -> dict[str, Any]:
        """What happened, for the report; ``provisional``: for the journal's provisional report, made every second,
        so its loop timings cover only the last :data:`PROVISIONAL_WINDOW_TICKS` ticks."""
        link = self.link
        return pilot_facts(self.pilot) | {
            "loop": self.loop_facts(provisional),
            "link": {"received": link.received, "sent": link.sent, "rejected": dict(link.rejected),
                     **self.pilot.health.summary(),
                     "signing": link.verifier.summary() if link.verifier is not None else None},
            "journal": self.journal.summary() if self.journal is not None else None,
            "operator": self.pilot.desk.summary() | {"orders": self.pilot.orders_log,
                                                     "statustext_sent": self.texts.sent,
                                                     "statustext_dropped": self.texts.dropped},
        }

    def provisional_facts(self) -> dict[str, Any]:
        facts = self.run_facts(provisional=True)
        if self.provisional is not None:
            facts.update(self.provisional(self))
        return facts
