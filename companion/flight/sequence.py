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
from enum import StrEnum

from companion.flight.requests import Request, RequestTracker

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_IN_PROGRESS = 5


class State(StrEnum):
    """Where the sequence is."""

    CONNECT = "connect"
    CONFIGURE = "configure"
    WAIT_READY = "wait_ready"
    PRESTREAM = "prestream"
    ARM = "arm"
    TAKEOVER = "takeover"
    MISSION = "mission"
    HOLD = "hold"
    LAND = "land"
    DESCEND = "descend"
    DONE = "done"


class Stream(StrEnum):
    """What the tick sends to the vehicle."""

    NONE = "none"  # nothing: the link is gone, the vehicle is someone else's, or our setpoints are suspect
    IDLE = "idle"  # level attitude, zero thrust: only ever to a vehicle on the ground
    CORE = "core"  # the flight core's setpoint (the mission, or holding where it is)
    DESCENT = "descent"  # the flight core's gentle descent over the current position


#: Outcomes and what they mean (the report's ``outcome``; ``reached_goal`` is true only for ``completed``).
OUTCOMES = {
    "running": "the flight has not ended (a provisional report)",
    "completed": "the goal was reached and held; the vehicle landed (or holds, if the mission says so)",
    "timeout": "the mission timed out before reaching the goal; the vehicle was landed",
    "no_route": "the planner found no way to the goal; the vehicle held at a safe point and was landed",
    "aborted": "stopped on request (Ctrl-C, SIGTERM); the vehicle held, then landed unless told to hold",
    "link_lost": "the vehicle's heartbeat or telemetry stopped; streaming stopped so its own failsafe acts",
    "preempted": "someone else took the vehicle (mode change, disarm); the companion let go",
    "stale_telemetry": "telemetry stopped arriving in time; the companion handed over to the vehicle's hold",
    "invalid_estimate": "the state estimate was not finite or not physical; hold, then land",
    "tick_errors": "the control tick failed repeatedly; hold, then land",
    "diverged": "the vehicle stayed far from the companion's reference (a control loop gone unstable); the "
                "companion handed over to the vehicle's hold, then landed",
    "no_vehicle": "no autopilot heartbeat arrived",
    "not_ready": "the autopilot never reported ready to arm (its reasons are in the report)",
    "refused": "the autopilot refused to arm or to give control (its reasons are in the report)",
}


@dataclass(frozen=True)
class SequenceConfig:
    """Timeouts (s) and choices of the flight sequence."""

    connect_timeout_s: float = 60.0  # first autopilot HEARTBEAT
    ready_timeout_s: float = 90.0  # telemetry and "ready to arm" (PX4 SITL can take ~40 s after boot)
    prestream_s: float = 1.0  # setpoints stream this long before arming / taking over (PX4 needs >= 1)
    heartbeat_loss_s: float = 1.5  # no HEARTBEAT for this long: link lost
    # ... before setpoints flow (CONFIGURE, WAIT_READY) nothing depends on us yet, and PX4 SIH was seen to miss
    # its 1 Hz HEARTBEAT for over 1.5 s while its estimator started: only this long ends the wait then
    heartbeat_loss_waiting_s: float = 5.0
    telemetry_loss_s: float = 0.5  # no position or attitude for this long: link lost
    stale_s: float = 0.3  # position or attitude older than this in flight: hold
    invalid_estimate_s: float = 0.3  # invalid estimates for this long: hold (the last valid setpoint until then)
    tick_error_limit: int = 3  # consecutive tick exceptions before hold
    diverged_m: float = 2.0  # the vehicle this far from the reference (m) ...
    diverged_s: float = 1.0  # ... for this long (wall s): our loop has gone unstable, hand over to the vehicle
    request_timeout_s: float = 1.0  # no answer to a request within this: ask again
    request_attempts: int = 3
    mode_confirm_s: float = 2.0  # a mode accepted but not shown by HEARTBEAT within this: ask again
    arm_timeout_s: float = 30.0  # keep retrying a temporarily refused arm this long
    arm_retry_s: float = 1.0
    failsafe_hold_s: float = 2.0  # after a failsafe hold is confirmed, land after this long
    land_timeout_s: float = 45.0  # landing (vehicle clock; twice this on the wall clock)
    mission_wall_timeout_s: float | None = None  # None: 3 × the mission timeout + 30 s
    takeover_before_arm: bool = False  # ArduPilot: switch to the guided mode first, then arm
    land_at_end: bool = True  # after the mission: land (else hold and finish)
    land_on_abort: bool = True  # after Ctrl-C: land (else hold and finish)
    configure: tuple[tuple[str, float], ...] = ()  # requests asked once connected (streams, parameters)
    start_tolerance_m: float = 1.0  # refuse to start a mission this far from its start point


@dataclass(frozen=True, slots=True)
class Observation:
    """What the app knows at this instant.

    now_s: the sequence clock (s); wall_s: monotonic wall clock (s); heartbeat_wall_s / telemetry_wall_s: wall
    time of the last autopilot HEARTBEAT and of the older of the last position and attitude (None: never);
    telemetry_ready: position and attitude have arrived; vehicle_ready: the autopilot says it can arm;
    armed / mode / on_ground: from HEARTBEAT and EXTENDED_SYS_STATE (mode in the sequence's words:
    ``offboard``, ``hold``, ``land``, ``takeoff`` or ``other``); heartbeats: count so far; estimate_ok: this
    tick's estimate is valid; core_result: the flight core's verdict once it is done (``completed``,
    ``timeout``, ``no_route``) else None; tick_errors_in_row; abort: the reason when an abort was requested;
    mission_timeout_s: the mission's own timeout (vehicle time); last_words: the vehicle's last STATUSTEXT.
    """

    now_s: float
    wall_s: float
    heartbeat_wall_s: float | None = None
    telemetry_wall_s: float | None = None
    telemetry_ready: bool = False
    vehicle_ready: bool = False
    armed: bool = False
    mode: str = "other"
    on_ground: bool = True
    heartbeats: int = 0
    estimate_ok: bool = False
    core_result: str | None = None
    tick_errors_in_row: int = 0
    abort: str | None = None
    mission_timeout_s: float = math.inf
    last_words: str = ""
    start_error_m: float = 0.0  # horizontal distance of the vehicle from the mission start (mission frame)
    tracking_error_m: float = 0.0  # the vehicle's distance from the reference of the last command (m)


@dataclass(frozen=True, slots=True)
class Step:
    """What to do now: the stream for this tick, requests to send, and (once) the configure answers."""

    stream: Stream
    send: tuple[Request, ...] = ()
    configured: dict[str, float | int] | None = None  # answers of the configure requests, handed over once
    core: str | None = None  # "hold_here" or "descend": re-aim the flight core (once, on entering)


@dataclass(frozen=True, slots=True)
class Transition:
    """One state change, for the log, the status stream and the report."""

    now_s: float
    wall_s: float
    from_state: str
    to_state: str
    reason: str


@dataclass
class _ModeGoal:
    """Getting the vehicle into one mode: asked, accepted, shown by HEARTBEAT — or refused / never shown."""

    mode: str
    asked: int = 0
    accepted_s: float | None = None
    confirmed: bool = False
    refused: int | None = None  # MAV_RESULT of a refusal
    heartbeats_at_accept: int = 0
    heartbeats_at_confirm: int = 0


def _lasting(condition: bool, start: tuple[float, float] | None,
             obs: Observation) -> tuple[tuple[float, float] | None, float]:
    """How long ``condition`` has held: (its start as (now_s, wall_s), or None once it stops; seconds on the wall
    clock or the vehicle's, whichever has run longer: lockstep runs vehicle time faster than the wall clock)."""
    if not condition:
        return None, 0.0
    if start is None:
        start = (obs.now_s, obs.wall_s)
    return start, max(obs.now_s - start[0], obs.wall_s - start[1])


@dataclass
class FlightSequence:
    """The state machine; :meth:`step` it, read ``state``, ``outcome``, ``transitions``."""

    cfg: SequenceConfig = field(default_factory=SequenceConfig)
    state: State = State.CONNECT
    outcome: str = "running"
    final_phase: str = "connect"
    detail: str = ""  # why the flight ended the way it did, in words
    transitions: list[Transition] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.requests = RequestTracker(self.cfg.request_timeout_s, self.cfg.request_attempts)
        self._entered_now = 0.0
        self._entered_wall = 0.0
        self._start_wall: float | None = None
        self._goal: _ModeGoal | None = None
        self._hold_stream = Stream.CORE
        self._mission_now0 = 0.0
        self._mission_wall0 = 0.0
        self._armed_seen = False
        self._airborne = False
        self._arm_refusal = ""
        self._next_arm_s = 0.0
        self._configured_given = False
        self._core_cmd: str | None = None
        self._disarm_sent = False
        self._configured: dict[str, float | int] = {}
        self._configure_done = False
        self._followup: Callable | None = None
        self._followed_up = False
        self._bad_start: tuple[float, float] | None = None
        self._div_start: tuple[float, float] | None = None  # (now_s, wall_s) when it went beyond diverged_m

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
        return self.state == State.DONE

    @property
    def streaming_ours(self) -> bool:
        """True while the vehicle may be flying our setpoints (so the app must keep them flowing)."""
        return self.state in (State.TAKEOVER, State.MISSION, State.HOLD, State.LAND, State.DESCEND)

    def step(self, obs: Observation) -> Step:
        """Advance on ``obs``; returns what the app must do now."""
        if self._start_wall is None:
            self._start_wall = obs.wall_s
            self._entered_now, self._entered_wall = obs.now_s, obs.wall_s
        send: list[Request] = list(self.requests.due(obs.now_s))
        self._core_cmd = None
        if obs.armed:
            self._armed_seen = True
        if not obs.on_ground and obs.armed:
            self._airborne = True
        if self.state != State.DONE:
            self._check_failures(obs, send)
        if self.state != State.DONE:
            handler = getattr(self, f"_on_{self.state.value}")
            handler(obs, send)
        configured = None
        if self._configure_done and not self._configured_given:
            configured = self._configured
            self._configured_given = True
        return Step(self._stream(obs), tuple(send), configured, self._core_cmd)

    # ---------------------------------------------------------------------------------------------- plumbing
    def _go(self, obs: Observation, to: State, reason: str) -> None:
        if to == self.state:
            return
        self.transitions.append(Transition(obs.now_s, obs.wall_s, self.state.value, to.value, reason))
        self.state = to
        self._entered_now, self._entered_wall = obs.now_s, obs.wall_s
        self._goal = None
        if to != State.DONE:
            self.final_phase = to.value

    def _finish(self, obs: Observation, outcome: str | None, phase: str, reason: str) -> None:
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
            self._finish(obs, None, self.state.value, reason)

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
        if s == State.HOLD:
            return self._hold_stream
        if s == State.LAND:
            return Stream.NONE if self._goal is not None and self._goal.confirmed else Stream.DESCENT
        if s == State.DESCEND:
            return Stream.IDLE if obs.on_ground else Stream.DESCENT
        return Stream.NONE

    def _want_mode(self, obs: Observation, mode: str, send: list[Request]) -> str:
        """Work towards ``mode``; returns ``"confirmed"``, ``"waiting"``, ``"refused"`` or ``"failed"``.

        Confirmed means: the request was accepted and a HEARTBEAT that came after the acceptance shows the
        mode. A vehicle that already shows the mode is still asked (an earlier request of ours may be on its way
        to it), and a lost answer is asked again, at most ``request_attempts`` times.
        """
        g = self._goal
        if g is None or g.mode != mode:
            for k in self.requests.tracked_keys():
                if k.startswith("mode:"):
                    self.requests.cancel(k)
            g = self._goal = _ModeGoal(mode)
        if g.confirmed:
            return "confirmed"
        key = f"mode:{mode}"
        res = self.requests.result(key)
        if res is not None:
            if int(res) in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
                g.accepted_s = obs.now_s
                g.heartbeats_at_accept = obs.heartbeats
            else:
                g.refused = int(res)
                return "refused"
        if g.accepted_s is not None and obs.mode == mode and obs.heartbeats > g.heartbeats_at_accept:
            g.confirmed = True
            g.heartbeats_at_confirm = obs.heartbeats
            return "confirmed"
        if self.requests.failed(key):
            return "failed"
        if self.requests.pending(key):
            return "waiting"
        if g.asked == 0 or (g.accepted_s is not None and obs.now_s - g.accepted_s > self.cfg.mode_confirm_s):
            if g.asked >= self.cfg.request_attempts:
                return "failed"
            g.asked += 1
            g.accepted_s = None
            send.extend(self.requests.ask(key, obs.now_s))
        return "waiting"

    # ---------------------------------------------------------------------------------------------- failures
    def _check_failures(self, obs: Observation, send: list[Request]) -> None:
        s = self.state
        if s == State.CONNECT:
            return
        hb_age = math.inf if obs.heartbeat_wall_s is None else obs.wall_s - obs.heartbeat_wall_s
        tel_age = math.inf if obs.telemetry_wall_s is None else obs.wall_s - obs.telemetry_wall_s
        # Before setpoints flow, an autopilot that pauses its telemetry (PX4 while its estimator starts) is only
        # not ready yet; from then on the vehicle may depend on us, and silence is a lost link.
        telemetry_counts = s not in (State.CONFIGURE, State.WAIT_READY)
        hb_limit = self.cfg.heartbeat_loss_s if telemetry_counts else max(self.cfg.heartbeat_loss_s,
                                                                         self.cfg.heartbeat_loss_waiting_s)
        if hb_age > hb_limit or (telemetry_counts and obs.telemetry_ready and tel_age > self.cfg.telemetry_loss_s):
            what = (f"no HEARTBEAT for {hb_age:.1f} s" if hb_age > hb_limit
                    else f"no position/attitude for {tel_age:.2f} s")
            if self.outcome == "stale_telemetry":  # that was the first sign of this: name the real cause
                self.outcome = "running"
            self._finish(obs, "link_lost", "link_lost", f"vehicle lost: {what}")
            return
        owned = self._goal is not None and self._goal.confirmed and s in (State.MISSION, State.HOLD, State.LAND)
        if owned and obs.heartbeats > self._goal.heartbeats_at_confirm and obs.mode != self._goal.mode and not (
                s == State.LAND and obs.on_ground):
            said = f"; vehicle said: {obs.last_words!r}" if obs.last_words else ""
            self._finish(obs, "preempted", "preempted",
                         f"the vehicle left {self._goal.mode} for {obs.mode} without being asked{said}")
            return
        if self._armed_seen and self._airborne and not obs.armed and not obs.on_ground and s not in (
                State.LAND, State.DESCEND):
            said = f"; vehicle said: {obs.last_words!r}" if obs.last_words else ""
            self._finish(obs, "preempted", "preempted", f"the vehicle was disarmed in flight{said}")
            return
        if s in (State.HOLD, State.LAND, State.DESCEND):
            return  # already on the way down or holding: only link loss and preemption can end it sooner
        if obs.abort is not None:
            if self._armed_seen and obs.armed:
                self._fail(obs, "aborted", obs.abort, Stream.CORE if obs.estimate_ok else Stream.NONE)
            else:
                self._finish(obs, "aborted", s.value, obs.abort)
            return
        if not self.streaming_ours:
            return
        if obs.tick_errors_in_row >= self.cfg.tick_error_limit:
            self._fail(obs, "tick_errors", f"{obs.tick_errors_in_row} control ticks failed in a row", Stream.NONE)
        elif tel_age > self.cfg.stale_s:
            self._fail(obs, "stale_telemetry", f"position/attitude {tel_age:.2f} s old", Stream.NONE)
        elif not obs.estimate_ok and self._bad_since(obs) > self.cfg.invalid_estimate_s:
            self._fail(obs, "invalid_estimate", "the state estimate stayed invalid", Stream.NONE)
        elif self._diverged_for(obs) > self.cfg.diverged_s:
            self._fail(obs, "diverged", f"{obs.tracking_error_m:.1f} m from the reference for more than "
                       f"{self.cfg.diverged_s:g} s", Stream.NONE)

    def _diverged_for(self, obs: Observation) -> float:
        """Seconds the vehicle has been farther than ``diverged_m`` from the reference (see :func:`_lasting`)."""
        self._div_start, s = _lasting(obs.tracking_error_m > self.cfg.diverged_m, self._div_start, obs)
        return s

    def _bad_since(self, obs: Observation) -> float:
        """Seconds the estimate has been invalid (see :func:`_lasting`); tracked here so the app need not."""
        self._bad_start, s = _lasting(not obs.estimate_ok, self._bad_start, obs)
        return s

    # ---------------------------------------------------------------------------------------------- states
    def _on_connect(self, obs: Observation, send: list[Request]) -> None:
        if obs.heartbeat_wall_s is not None:
            self._go(obs, State.CONFIGURE, "autopilot heartbeat")
            self._on_configure(obs, send)
        elif obs.abort is not None:
            self._finish(obs, "aborted", "connect", obs.abort)
        elif obs.wall_s - self._start_wall > self.cfg.connect_timeout_s:
            self._finish(obs, "no_vehicle", "connect",
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
                self._finish(obs, "refused", "configure", refusal)
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
            self._finish(obs, "refused", "wait_ready",
                         f"the vehicle stands {obs.start_error_m:.1f} m from the mission's start (tolerance "
                         f"{self.cfg.start_tolerance_m:g} m; coordinates are relative to home): fly it there, or "
                         "fly the mission from where it is with --start-here")
        elif obs.telemetry_ready and fresh and obs.vehicle_ready:
            if obs.armed and not obs.on_ground:
                self._armed_seen = True
            self._go(obs, State.PRESTREAM, "telemetry flowing, autopilot ready")
        elif self._in_state_wall_s(obs) > self.cfg.ready_timeout_s:
            why = "no position/attitude telemetry" if not obs.telemetry_ready else "the autopilot is not ready to arm"
            said = f" (vehicle said: {obs.last_words!r})" if obs.last_words else ""
            self._finish(obs, "not_ready", "wait_ready", f"{why} after {self.cfg.ready_timeout_s:.0f} s{said}")

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
            self._finish(obs, "link_lost", "arm", "the autopilot never answered the arm command")
            return
        if self._in_state_wall_s(obs) > self.cfg.arm_timeout_s:
            self._finish(obs, "refused", "arm",
                         f"arming refused for {self.cfg.arm_timeout_s:.0f} s: {self._arm_refusal}")
            return
        if not self.requests.pending("arm") and obs.now_s >= self._next_arm_s:
            send.extend(self.requests.ask("arm", obs.now_s))
            self._next_arm_s = obs.now_s + self.cfg.arm_retry_s

    def _on_takeover(self, obs: Observation, send: list[Request]) -> None:
        r = self._want_mode(obs, "offboard", send)
        if r == "confirmed":
            if not obs.armed:
                self._go(obs, State.ARM, "guided mode confirmed")
                self._goal = _ModeGoal("offboard", confirmed=True, heartbeats_at_confirm=obs.heartbeats)
                self._on_arm(obs, send)
            else:
                self._go(obs, State.MISSION, "offboard mode confirmed by HEARTBEAT")
                self._goal = _ModeGoal("offboard", confirmed=True, heartbeats_at_confirm=obs.heartbeats)
                self._begin_mission(obs)
        elif r in ("refused", "failed"):
            why = (f"refused (MAV_RESULT {self._goal.refused})" if r == "refused" else "never confirmed")
            said = f"; vehicle said: {obs.last_words!r}" if obs.last_words else ""
            if obs.armed and obs.on_ground:  # still on the ground: just let go of it, disarmed
                send.extend(self.requests.ask("disarm", obs.now_s))
                self._finish(obs, "refused", "takeover", f"offboard mode {why}{said}")
            else:
                self._fail(obs, "refused", f"offboard mode {why}{said}", Stream.CORE)

    def _begin_mission(self, obs: Observation) -> None:
        self._mission_now0, self._mission_wall0 = obs.now_s, obs.wall_s

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
            self._core_cmd = "hold_here"

    def _on_hold(self, obs: Observation, send: list[Request]) -> None:
        if self._in_state_s(obs) == 0.0 and self._hold_stream == Stream.CORE:
            self._core_cmd = "hold_here"
        r = self._want_mode(obs, "hold", send)
        end_hold = self.outcome in ("completed", "timeout", "no_route") and not self.cfg.land_at_end
        wants_land = not end_hold and (self.outcome != "aborted" or self.cfg.land_on_abort)
        if r == "confirmed":
            if not wants_land:
                self._finish(obs, None, "holding", "holding in the vehicle's own hold mode")
            elif self._in_state_s(obs) >= self.cfg.failsafe_hold_s:
                self._go(obs, State.LAND, "hold confirmed; landing")
        elif r in ("refused", "failed"):
            self._go(obs, State.LAND, f"hold mode {r}; landing instead")

    def _on_land(self, obs: Observation, send: list[Request]) -> None:
        r = self._want_mode(obs, "land", send)
        if obs.on_ground and not obs.armed:
            self._finish(obs, None, "landed", "landed and disarmed")
            return
        if r in ("refused", "failed"):
            self._go(obs, State.DESCEND, f"land mode {r}; descending on our own setpoints")
            self._core_cmd = "descend"
            return
        if r != "confirmed":
            if self._in_state_s(obs) == 0.0:
                self._core_cmd = "descend"
            return
        if self._in_state_s(obs) > self.cfg.land_timeout_s or self._in_state_wall_s(obs) > 2 * self.cfg.land_timeout_s:
            self._finish(obs, None, "land_timeout", "the vehicle did not report landed and disarmed in time")

    def _on_descend(self, obs: Observation, send: list[Request]) -> None:
        if obs.on_ground:
            if not obs.armed:
                self._finish(obs, None, "landed", "landed on our own descent and disarmed")
            elif not self._disarm_sent:
                self._disarm_sent = True
                send.extend(self.requests.ask("disarm", obs.now_s))
        if self._in_state_wall_s(obs) > 2 * self.cfg.land_timeout_s:
            self._finish(obs, None, "land_timeout", "our own descent did not end on the ground in time")
