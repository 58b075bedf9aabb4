"""The flight sequence as a state machine: what the companion does with the vehicle, and what it does when
anything fails. Pure: no I/O, no clock of its own — the flight app calls :meth:`FlightSequence.step` once per
control tick (and from a watchdog when ticks stop) with an :class:`Observation`, and carries out the returned
:class:`Step`: which setpoint stream to send, which requests to send to the autopilot.

The normal path::

    CONNECT ─▶ CONFIGURE ─▶ WAIT_READY ─▶ PRESTREAM ─▶ ARM ─▶ TAKEOVER ─▶ MISSION ─▶ LAND ─▶ DONE
    (heartbeat)  (streams,    (telemetry,   (setpoints   (armed   (our mode    (climb,     (land mode
                  params)      ready to arm)  flowing)     seen)    confirmed)   cruise,     confirmed,
                                                                               hold)       landed)

(ArduPilot wants its guided mode before arming: ``takeover_before_arm`` swaps ARM and TAKEOVER.)

Failures, checked every step, first match wins:

==========================================  ============================================================
what                                        what the sequence does
==========================================  ============================================================
no HEARTBEAT for 1.5 s (5 s before          ``link_lost``: stop streaming (the autopilot's own offboard-loss
setpoints flow), or no position/attitude    failsafe takes over), finish
for 0.5 s (wall clock; the app leaves out
its own stalls, ``health.DeafSpells``)
the vehicle leaves our mode, or is          ``preempted``: stop streaming, finish (the vehicle's last
disarmed in flight, by someone else         STATUSTEXT says who/why when it said so)
Ctrl-C / abort                              HOLD, then LAND (unless told to hold only)
3 tick exceptions in a row                  HOLD (streaming stops: our setpoints are suspect), then LAND
position/attitude older than 0.3 s          HOLD with streaming stopped, then LAND
invalid estimate for longer than 0.3 s      HOLD with streaming stopped, then LAND
mission timeout (vehicle or wall clock),    LAND (or HOLD when the mission says not to land)
no route to the goal
==========================================  ============================================================

A mode counts as ours only once the vehicle's HEARTBEAT shows it. Mode requests are retried (3 attempts);
a HOLD that is never confirmed escalates to LAND, a LAND that is never confirmed to DESCEND: the companion
itself streams a gentle, closed-loop descent until the vehicle is on the ground, then disarms it. Zero
thrust is streamed only to a vehicle on the ground.

Clocks: ``now_s`` orders requests, retries and mission time (the vehicle's time in lockstep, so a flight is
repeatable bit for bit; the wall clock otherwise); ``wall_s`` drives every watchdog, so a vehicle whose
clock stopped is still noticed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from companion.flight.failsafes import STREAMING_STATES, FailureKind, FailureWatch
from companion.flight.mode_goal import MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS, GoalStatus, ModeGoal
from companion.flight.operator import OperatorReactions
from companion.flight.phase import CoreOrder, FinalPhase, State
from companion.flight.requests import Request, RequestTracker
from companion.flight.sequence_types import OUTCOMES, Observation, SequenceConfig, Step, Stream, Transition

__all__ = ["OUTCOMES", "FlightSequence", "Observation", "SequenceConfig", "State", "Step", "Stream", "Transition"]


@dataclass
class FlightSequence(OperatorReactions):
    """The state machine; :meth:`step` it, read ``state``, ``outcome``, ``transitions``; :meth:`order` it."""

    cfg: SequenceConfig = field(default_factory=SequenceConfig)
    state: State = State.CONNECT
    outcome: str = "running"
    final_phase: State | FinalPhase = State.CONNECT
    detail: str = ""  # why the flight ended the way it did, in words
    transitions: list[Transition] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.requests = RequestTracker(self.cfg.request_timeout_s, self.cfg.request_attempts)
        self._watch = FailureWatch(self.cfg)
        self._handlers: dict[State, Callable[[Observation, list[Request]], None]] = {
            State.CONNECT: self._on_connect, State.CONFIGURE: self._on_configure, State.WAIT_READY: self._on_wait_ready,
            State.PRESTREAM: self._on_prestream, State.ARM: self._on_arm, State.TAKEOVER: self._on_takeover,
            State.MISSION: self._on_mission, State.HOLD: self._on_hold, State.LAND: self._on_land,
            State.DESCEND: self._on_descend,
        }
        self._entered_now = 0.0
        self._entered_wall = 0.0
        self._start_wall: float | None = None
        self._goal: ModeGoal | None = None
        self._hold_stream = Stream.CORE
        self._mission_wall0 = 0.0
        self._armed_seen = False
        self._airborne = False
        self._arm_refusal = ""
        self._next_arm_s = 0.0
        self._configured_given = False
        self._core_order: CoreOrder | None = None
        self._disarm_sent = False
        self._configured: dict[str, float | int] = {}
        self._configure_done = False
        self._followup: Callable | None = None
        self._followed_up = False

    # ---------------------------------------------------------------------------------------------- public
    def plan(self, configure: tuple[tuple[str, float], ...], takeover_before_arm: bool,
             followup: Callable[[dict[str, float | int]], tuple[tuple[tuple[str, float], ...], str | None]]
             | None = None) -> None:
        """Once the vehicle is known: the set-up requests to ask, the autopilot family's arming order, and what
        the set-up's answers call for next (``followup(answers) -> (more requests, or a reason to refuse)``)."""
        self.cfg = replace(self.cfg, configure=configure, takeover_before_arm=takeover_before_arm)
        self._followup = followup

    def answer(self, key: str, result: int | float) -> bool:
        """The autopilot answered request ``key`` (COMMAND_ACK result, or a parameter's value)."""
        return self.requests.answer(key, result)

    @property
    def finished(self) -> bool:
        """True once the sequence is DONE."""
        return self.state is State.DONE

    @property
    def streaming_ours(self) -> bool:
        """True while the vehicle may be flying our setpoints (so the app must keep them flowing)."""
        return self.state in STREAMING_STATES

    def step(self, obs: Observation) -> Step:
        """Advance on ``obs``; returns what the app must do now."""
        if self._start_wall is None:
            self._start_wall = obs.wall_s
            self._entered_now, self._entered_wall = obs.now_s, obs.wall_s
        send: list[Request] = list(self.requests.due(obs.now_s))
        self._core_order = None
        if obs.armed:
            self._armed_seen = True
        if not obs.on_ground and obs.armed:
            self._airborne = True
        if self.state is not State.DONE:
            self._check_failures(obs)
        if self._orders and self.state is not State.DONE:
            self._apply_orders(obs)
        if self.state is not State.DONE:
            self._handlers[self.state](obs, send)
        configured = None
        if self._configure_done and not self._configured_given:
            configured = self._configured
            self._configured_given = True
        return Step(self._stream(obs), tuple(send), configured, self._core_order)

    # ---------------------------------------------------------------------------------------------- plumbing
    def _go(self, obs: Observation, to: State, reason: str) -> None:
        """Enter ``to``, with its entry action: HOLD (streaming the core) holds the core where its reference is,
        DESCEND starts the core's own descent. LAND gives no order: until the land mode is confirmed the core
        keeps flying what it flew (hovering at the goal after the mission, or where it was told to hold)."""
        if to == self.state:
            return
        self.transitions.append(Transition(obs.now_s, obs.wall_s, self.state, to, reason))
        self.state = to
        self._entered_now, self._entered_wall = obs.now_s, obs.wall_s
        self._goal = None
        if to is not State.DONE:
            self.final_phase = to
        if to is State.HOLD and self._hold_stream is Stream.CORE:
            self._core_order = CoreOrder.HOLD_HERE
        elif to is State.DESCEND:
            self._core_order = CoreOrder.DESCEND

    def _finish(self, obs: Observation, outcome: str | None, phase: State | FinalPhase, reason: str) -> None:
        if outcome is not None and self.outcome == "running":
            self.outcome = outcome
            self.detail = reason
        self.final_phase = phase
        self._go(obs, State.DONE, reason)

    def _fail(self, obs: Observation, outcome: str, reason: str, hold_stream: Stream) -> None:
        """A failure while the vehicle may be ours: record the first cause, then hold (if armed) or finish."""
        if self.outcome == "running":
            self.outcome = outcome
            self.detail = reason
        if self._armed_seen and obs.armed:
            self._hold_stream = hold_stream
            self._go(obs, State.HOLD, reason)
        else:
            self._finish(obs, None, self.state, reason)

    def _in_state_s(self, obs: Observation) -> float:
        return obs.now_s - self._entered_now

    def _in_state_wall_s(self, obs: Observation) -> float:
        return obs.wall_s - self._entered_wall

    def _stream(self, obs: Observation) -> Stream:
        s = self.state
        if s in (State.CONNECT, State.CONFIGURE, State.WAIT_READY, State.DONE):
            return Stream.NONE
        if s in (State.PRESTREAM, State.ARM):
            return Stream.IDLE if obs.on_ground or not obs.armed else Stream.CORE
        if s in (State.TAKEOVER, State.MISSION):
            if not obs.armed and obs.on_ground:
                return Stream.IDLE
            return Stream.CORE
        if s is State.HOLD:
            return self._hold_stream
        if s is State.LAND:
            return Stream.NONE if self._goal is not None and self._goal.confirmed else Stream.DESCENT
        if s is State.DESCEND:
            return Stream.IDLE if obs.on_ground else Stream.DESCENT
        return Stream.NONE

    def _want_mode(self, obs: Observation, mode: str, send: list[Request]) -> GoalStatus:
        """Work towards ``mode`` (see :class:`~companion.flight.mode_goal.ModeGoal`); a new mode cancels the
        requests for the one before."""
        g = self._goal
        if g is None or g.mode != mode:
            for k in self.requests.tracked_keys():
                if k.startswith("mode:"):
                    self.requests.cancel(k)
            g = self._goal = ModeGoal(mode)
        return g.pursue(obs, self.requests, self.cfg, send)

    def _check_failures(self, obs: Observation) -> None:
        """React to the first failure :class:`~companion.flight.failsafes.FailureWatch` sees."""
        f = self._watch.check(obs, self.state, self._goal, self._armed_seen, self._airborne)
        if f is None:
            return
        if f.kind is FailureKind.LINK_LOST:
            if self.outcome == "stale_telemetry":  # that was the first sign of this: name the real cause
                self.outcome = "running"
            self._finish(obs, f.outcome, FinalPhase.LINK_LOST, f.reason)
        elif f.kind is FailureKind.PREEMPTED:
            self._finish(obs, f.outcome, FinalPhase.PREEMPTED, f.reason)
        else:
            self._fail(obs, f.outcome, f.reason, f.hold_stream)

    # ---------------------------------------------------------------------------------------------- states
    def _on_connect(self, obs: Observation, send: list[Request]) -> None:
        if obs.heartbeat_wall_s is not None:
            self._go(obs, State.CONFIGURE, "autopilot heartbeat")
            self._on_configure(obs, send)
        elif obs.abort is not None:
            self._finish(obs, "aborted", State.CONNECT, obs.abort)
        elif obs.wall_s - self._start_wall > self.cfg.connect_timeout_s:
            self._finish(obs, "no_vehicle", State.CONNECT,
                         f"no autopilot heartbeat within {self.cfg.connect_timeout_s:g} s")

    def _on_configure(self, obs: Observation, send: list[Request]) -> None:
        """Ask the set-up requests one at a time: several share one MAVLink command (SET_MESSAGE_INTERVAL),
        whose COMMAND_ACK does not say which request it answers. Then the follow-ups their answers call for."""
        if not self._ask_in_turn(obs, send):
            return
        if self._followup is not None and not self._followed_up:
            self._followed_up = True
            more, refusal = self._followup(dict(self._configured))
            if refusal is not None:
                self._finish(obs, "refused", State.CONFIGURE, refusal)
                return
            if more:
                self.cfg = replace(self.cfg, configure=self.cfg.configure + tuple(more))
                if not self._ask_in_turn(obs, send):
                    return
        self._configure_done = True
        self._go(obs, State.WAIT_READY, "streams and parameters set up")

    def _ask_in_turn(self, obs: Observation, send: list[Request]) -> bool:
        """Ask the next unanswered set-up request; True once every one is answered (or given up)."""
        for key, value in self.cfg.configure:
            if key in self._configured:
                continue
            res = self.requests.result(key)
            if res is not None:
                self._configured[key] = res
                continue
            if self.requests.failed(key):
                self._configured[key] = math.nan  # never answered: the app says so and flies on
                continue
            if not self.requests.pending(key):
                send.extend(self.requests.ask(key, obs.now_s, value))
            return False
        return True

    def _on_wait_ready(self, obs: Observation, send: list[Request]) -> None:
        fresh = obs.telemetry_wall_s is not None and obs.wall_s - obs.telemetry_wall_s <= self.cfg.stale_s
        if obs.telemetry_ready and fresh and obs.vehicle_ready and obs.start_error_m > self.cfg.start_tolerance_m:
            self._finish(obs, "refused", State.WAIT_READY,
                         f"the vehicle stands {obs.start_error_m:.1f} m from the mission's start (tolerance "
                         f"{self.cfg.start_tolerance_m:g} m; coordinates are relative to home): fly it there, or "
                         "fly the mission from where it is with --start-here")
        elif obs.telemetry_ready and fresh and obs.vehicle_ready:
            if obs.armed and not obs.on_ground:
                self._armed_seen = True
            self._go(obs, State.PRESTREAM, "telemetry flowing, autopilot ready")
        elif self._in_state_wall_s(obs) > self.cfg.ready_timeout_s:
            why = ["no position/attitude telemetry" if not obs.telemetry_ready else
                   f"telemetry older than {self.cfg.stale_s:g} s"] if not (obs.telemetry_ready and fresh) else []
            if not obs.vehicle_ready:
                why += [f"the autopilot is not ready to arm: {w}" for w in obs.unready] or [
                    "the autopilot is not ready to arm"]
            said = f"; vehicle said: {obs.last_words!r}" if obs.last_words else "; the vehicle said nothing"
            self._finish(obs, "not_ready", State.WAIT_READY,
                         f"after {self.cfg.ready_timeout_s:.0f} s: {'; '.join(why)}{said}")

    def _on_prestream(self, obs: Observation, send: list[Request]) -> None:
        if self._in_state_s(obs) < self.cfg.prestream_s:
            return
        if self.cfg.takeover_before_arm or obs.armed:
            self._go(obs, State.TAKEOVER, "setpoints flowing")
        else:
            self._go(obs, State.ARM, "setpoints flowing")
            self._on_arm(obs, send)

    def _on_arm(self, obs: Observation, send: list[Request]) -> None:
        if obs.armed:
            nxt = State.MISSION if self.cfg.takeover_before_arm else State.TAKEOVER
            self._go(obs, nxt, "armed")
            if nxt == State.MISSION:
                self._begin_mission(obs)
            return
        res = self.requests.result("arm")
        if res is not None and int(res) not in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
            self._arm_refusal = obs.last_words or f"MAV_RESULT {int(res)}"
            self._next_arm_s = obs.now_s + self.cfg.arm_retry_s
        if self.requests.failed("arm"):
            self._finish(obs, "link_lost", State.ARM, "the autopilot never answered the arm command")
            return
        if self._in_state_wall_s(obs) > self.cfg.arm_timeout_s:
            self._finish(obs, "refused", State.ARM,
                         f"arming refused for {self.cfg.arm_timeout_s:.0f} s: {self._arm_refusal}")
            return
        if not self.requests.pending("arm") and obs.now_s >= self._next_arm_s:
            send.extend(self.requests.ask("arm", obs.now_s))
            self._next_arm_s = obs.now_s + self.cfg.arm_retry_s

    def _on_takeover(self, obs: Observation, send: list[Request]) -> None:
        r = self._want_mode(obs, "offboard", send)
        if r is GoalStatus.CONFIRMED:
            if not obs.armed:
                self._go(obs, State.ARM, "guided mode confirmed")
                self._goal = ModeGoal.already_confirmed("offboard", obs.heartbeats)
                self._on_arm(obs, send)
            else:
                self._go(obs, State.MISSION, "offboard mode confirmed by HEARTBEAT")
                self._goal = ModeGoal.already_confirmed("offboard", obs.heartbeats)
                self._begin_mission(obs)
        elif r in (GoalStatus.REFUSED, GoalStatus.FAILED):
            why = (f"refused (MAV_RESULT {self._goal.refused})" if r is GoalStatus.REFUSED else "never confirmed")
            said = f"; vehicle said: {obs.last_words!r}" if obs.last_words else ""
            if obs.armed and obs.on_ground:  # still on the ground: just let go of it, disarmed
                send.extend(self.requests.ask("disarm", obs.now_s))
                self._finish(obs, "refused", State.TAKEOVER, f"offboard mode {why}{said}")
            else:
                self._fail(obs, "refused", f"offboard mode {why}{said}", Stream.CORE)

    def _begin_mission(self, obs: Observation) -> None:
        self._mission_wall0 = obs.wall_s

    def _on_mission(self, obs: Observation, send: list[Request]) -> None:
        wall_limit = self.cfg.mission_wall_timeout_s or (3.0 * obs.mission_timeout_s + 30.0)
        result = obs.core_result
        if result is None and obs.wall_s - self._mission_wall0 > wall_limit:
            result = "timeout"
        if result is None:
            return
        if self.outcome == "running":
            self.outcome = result
            self.detail = {"completed": "goal reached and held", "timeout": "mission timeout",
                           "no_route": "no route to the goal"}.get(result, result)
        if self.cfg.land_at_end:
            self._go(obs, State.LAND, f"mission {result}")
        else:
            self._hold_stream = Stream.CORE
            self._go(obs, State.HOLD, f"mission {result}; holding (no landing asked)")

    def _on_hold(self, obs: Observation, send: list[Request]) -> None:
        r = self._want_mode(obs, "hold", send)
        end_hold = self.outcome in ("completed", "timeout", "no_route") and not self.cfg.land_at_end
        wants_land = not end_hold and (self.outcome != "aborted" or self.cfg.land_on_abort)
        if r is GoalStatus.CONFIRMED:
            if not wants_land:
                self._finish(obs, None, FinalPhase.HOLDING, "holding in the vehicle's own hold mode")
            elif self._in_state_s(obs) >= self.cfg.failsafe_hold_s:
                self._go(obs, State.LAND, "hold confirmed; landing")
        elif r in (GoalStatus.REFUSED, GoalStatus.FAILED):
            self._go(obs, State.LAND, f"hold mode {r}; landing instead")

    def _on_land(self, obs: Observation, send: list[Request]) -> None:
        r = self._want_mode(obs, "land", send)
        if obs.on_ground and not obs.armed:
            self._finish(obs, None, FinalPhase.LANDED, "landed and disarmed")
            return
        if r in (GoalStatus.REFUSED, GoalStatus.FAILED):
            self._go(obs, State.DESCEND, f"land mode {r}; descending on our own setpoints")
            return
        if r is not GoalStatus.CONFIRMED:
            return
        if self._in_state_s(obs) > self.cfg.land_timeout_s or self._in_state_wall_s(obs) > 2 * self.cfg.land_timeout_s:
            self._finish(obs, None, FinalPhase.LAND_TIMEOUT, "the vehicle did not report landed and disarmed in time")

    def _on_descend(self, obs: Observation, send: list[Request]) -> None:
        if obs.on_ground:
            if not obs.armed:
                self._finish(obs, None, FinalPhase.LANDED, "landed on our own descent and disarmed")
            elif not self._disarm_sent:
                self._disarm_sent = True
                send.extend(self.requests.ask("disarm", obs.now_s))
        if self._in_state_wall_s(obs) > 2 * self.cfg.land_timeout_s:
            self._finish(obs, None, FinalPhase.LAND_TIMEOUT, "our own descent did not end on the ground in time")
