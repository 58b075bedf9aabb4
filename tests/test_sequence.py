"""The flight sequence state machine, driven step by step (pure: no sockets, no clocks).

A scripted autopilot answers the sequence's requests the way PX4 or ArduPilot would (COMMAND_ACK at once,
the mode shown by the next 1 Hz HEARTBEAT) and can be told to misbehave: refuse, stay silent, change mode on
its own, disarm, stop sending. Every step also checks the one rule that holds in every state: zero thrust
(the IDLE stream) only ever goes to a vehicle on the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from companion.flight.sequence import FlightSequence, Observation, SequenceConfig, State, Stream

DT = 0.004
CONFIGURE = (("message_interval:ATTITUDE", 4000.0), ("message_interval:LOCAL_POSITION_NED", 4000.0),
             ("param_read:MPC_THR_HOVER", math.nan))


@dataclass
class ScriptedAutopilot:
    """A vehicle in words: answers requests, shows its mode in a HEARTBEAT once a second."""

    mode: str = "hold"
    armed: bool = False
    on_ground: bool = True
    ready: bool = True
    heartbeats: int = 0
    refuse: dict[str, int] = field(default_factory=dict)  # request key → MAV_RESULT to answer
    silent: set[str] = field(default_factory=set)  # request keys never answered
    ignore_mode: set[str] = field(default_factory=set)  # modes acknowledged but never entered
    alive: bool = True
    telemetry: bool = True
    t: float = 0.0
    last_hb: float | None = None
    last_tel: float | None = None
    shown_mode: str = "hold"
    pending_mode: str | None = None
    asked: list[str] = field(default_factory=list)
    flown: bool = False

    def handle(self, seq: FlightSequence, req) -> None:
        self.asked.append(req.key)
        if req.key in self.silent or not self.alive:
            return
        if req.key in self.refuse:
            seq.answer(req.key, self.refuse[req.key])
            return
        if req.key == "arm":
            self.armed = True
        elif req.key == "disarm":
            self.armed = False
        elif req.key.startswith("mode:"):
            m = req.key[5:]
            if m not in self.ignore_mode:
                self.mode = m
        seq.answer(req.key, 0.4 if req.key.startswith("param") else 0)

    def advance(self, dt: float) -> None:
        self.t += dt
        if not self.alive:
            return
        if self.armed and self.mode == "offboard" and self.on_ground and not self.flown:
            self.on_ground = False  # it takes off when flown (once)
            self.flown = True
        if self.mode == "land" and not self.on_ground:
            self.on_ground = True
            self.armed = False
        if self.last_hb is None or self.t - self.last_hb >= 1.0:
            self.last_hb = self.t
            self.heartbeats += 1
            self.shown_mode = self.mode
        if self.telemetry:
            self.last_tel = self.t


@dataclass
class Harness:
    seq: FlightSequence
    ap: ScriptedAutopilot
    core_result: str | None = None
    tick_errors: int = 0
    estimate_ok: bool = True
    abort: str | None = None
    tracking_error_m: float = 0.0
    wall_per_s: float = 1.0  # wall seconds per vehicle second (< 1: lockstep running faster than real time)
    streams: list[tuple[float, Stream, bool]] = field(default_factory=list)

    def step(self) -> Stream:
        ap = self.ap
        ap.advance(DT)
        wall = ap.t * self.wall_per_s
        hb = None if ap.last_hb is None else ap.last_hb * self.wall_per_s
        tel = None if ap.last_tel is None else ap.last_tel * self.wall_per_s
        obs = Observation(now_s=ap.t, wall_s=wall, heartbeat_wall_s=hb, telemetry_wall_s=tel,
                          telemetry_ready=ap.last_tel is not None, vehicle_ready=ap.ready, armed=ap.armed,
                          mode=ap.shown_mode, on_ground=ap.on_ground, heartbeats=ap.heartbeats,
                          estimate_ok=self.estimate_ok, core_result=self.core_result,
                          tick_errors_in_row=self.tick_errors, abort=self.abort, mission_timeout_s=30.0,
                          tracking_error_m=self.tracking_error_m)
        st = self.seq.step(obs)
        for req in st.send:
            ap.handle(self.seq, req)
        if st.stream == Stream.IDLE:
            assert ap.on_ground, f"zero thrust streamed to an airborne vehicle in {self.seq.state}"
        self.streams.append((ap.t, st.stream, ap.on_ground))
        return st.stream

    def run_until(self, cond, max_s: float = 60.0) -> None:
        t_end = self.ap.t + max_s
        while not cond():
            assert self.ap.t < t_end, f"stuck in {self.seq.state} ({self.seq.transitions[-3:]})"
            self.step()


def _harness(**cfg) -> Harness:
    seq = FlightSequence(SequenceConfig(**cfg))
    seq.plan(CONFIGURE, takeover_before_arm=cfg.get("takeover_before_arm", False))
    return Harness(seq, ScriptedAutopilot())


def _states(seq: FlightSequence) -> list[str]:
    return [t.to_state for t in seq.transitions]


def test_px4_order_from_heartbeat_to_landed():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    assert _states(h.seq) == ["configure", "wait_ready", "prestream", "arm", "takeover", "mission"]
    # set-up asked one at a time, then arm, then OFFBOARD: PX4's order
    assert h.ap.asked[:3] == [k for k, _ in CONFIGURE]
    assert h.ap.asked[3:5] == ["arm", "mode:offboard"]
    prestream = [s for t, s, _ in h.streams if t < 1.0]
    assert Stream.IDLE in prestream  # setpoints flow before arming
    h.core_result = "completed"
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "completed" and h.seq.final_phase == "landed"
    assert _states(h.seq)[-2:] == ["land", "done"]


def test_configure_answers_are_handed_over_once():
    h = _harness()
    got = []
    for _ in range(2000):
        h.ap.advance(DT)
        obs = Observation(now_s=h.ap.t, wall_s=h.ap.t, heartbeat_wall_s=h.ap.last_hb, telemetry_wall_s=h.ap.last_tel,
                          telemetry_ready=True, vehicle_ready=True, heartbeats=h.ap.heartbeats, estimate_ok=True)
        st = h.seq.step(obs)
        for r in st.send:
            h.ap.handle(h.seq, r)
        if st.configured is not None:
            got.append(st.configured)
    assert got == [{"message_interval:ATTITUDE": 0, "message_interval:LOCAL_POSITION_NED": 0,
                    "param_read:MPC_THR_HOVER": 0.4}]


def test_ardupilot_order_takes_the_guided_mode_before_arming():
    h = _harness(takeover_before_arm=True)
    h.run_until(lambda: h.seq.state == State.MISSION)
    assert h.ap.asked[3:5] == ["mode:offboard", "arm"]
    assert _states(h.seq) == ["configure", "wait_ready", "prestream", "takeover", "arm", "mission"]


def test_a_mode_counts_only_once_a_later_heartbeat_shows_it():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.TAKEOVER)
    t_takeover = h.ap.t
    h.run_until(lambda: h.seq.state == State.MISSION)
    assert h.ap.t - t_takeover > 0.05  # waited for a HEARTBEAT, not just the COMMAND_ACK


def test_heartbeat_loss_is_link_lost_and_streaming_stops():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.ap.alive = False
    t0 = h.ap.t
    h.run_until(lambda: h.seq.finished, max_s=5)
    assert h.seq.outcome == "link_lost"
    assert h.ap.t - t0 <= 0.6  # telemetry stopped too: 0.5 s
    assert h.streams[-1][1] == Stream.NONE


def test_heartbeat_loss_alone_takes_4_s_while_telemetry_flows():
    """A late HEARTBEAT with position and attitude still flowing is an autopilot on a slow clock (PX4 SIH), not a
    lost link; 4 s of it is."""
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.ap.last_hb = h.ap.t
    h.ap.heartbeats += 1

    def no_more_heartbeats(dt, ap=h.ap, orig=h.ap.advance):
        hb = ap.last_hb
        orig(dt)
        ap.last_hb = hb

    h.ap.advance = no_more_heartbeats
    t0 = h.ap.t
    h.run_until(lambda: h.seq.finished, max_s=5)
    assert h.seq.outcome == "link_lost" and 4.0 <= h.ap.t - t0 <= 4.02


def test_stale_telemetry_holds_without_streaming_then_lands():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.ap.telemetry = False
    t0 = h.ap.t
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=1)
    assert 0.3 <= h.ap.t - t0 <= 0.31
    assert h.step() == Stream.NONE  # our setpoints would be computed from stale data
    assert h.seq.outcome == "stale_telemetry"
    # the telemetry never comes back: 0.5 s is link loss
    h.run_until(lambda: h.seq.finished, max_s=2)
    assert h.seq.final_phase == "link_lost" and h.seq.outcome == "link_lost"


def test_stale_telemetry_that_recovers_stays_the_outcome():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.ap.telemetry = False
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=1)
    h.ap.telemetry = True
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "stale_telemetry" and h.seq.final_phase == "landed"


def test_preempted_by_a_mode_change_nobody_asked_for():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.ap.mode = "other"  # e.g. a pilot switched to POSCTL
    t0 = h.ap.t
    h.run_until(lambda: h.seq.finished, max_s=3)
    assert h.seq.outcome == "preempted" and h.ap.t - t0 <= 1.01  # within one HEARTBEAT
    assert h.streams[-1][1] == Stream.NONE


def test_preempted_by_a_disarm_in_flight():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.run_until(lambda: not h.ap.on_ground)
    h.ap.armed = False
    h.run_until(lambda: h.seq.finished, max_s=1)
    assert h.seq.outcome == "preempted" and "disarmed in flight" in h.seq.detail


def test_abort_holds_then_lands():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.abort = "operator abort (Ctrl-C)"
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "aborted" and h.seq.final_phase == "landed"
    assert _states(h.seq)[-3:] == ["hold", "land", "done"]
    assert "mode:hold" in h.ap.asked and "mode:land" in h.ap.asked


def test_abort_without_landing_holds_and_lets_go():
    h = _harness(land_on_abort=False)
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.abort = "stop"
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "aborted" and h.seq.final_phase == "holding" and h.ap.mode == "hold"


def test_abort_before_arming_never_arms():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.PRESTREAM)
    h.abort = "stop"
    h.run_until(lambda: h.seq.finished, max_s=1)
    assert h.seq.outcome == "aborted" and "arm" not in h.ap.asked


def test_hold_never_confirmed_lands_and_land_never_confirmed_descends_on_our_own():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.run_until(lambda: not h.ap.on_ground)
    h.ap.ignore_mode = {"hold", "land"}
    h.tick_errors = 3
    h.run_until(lambda: h.seq.state == State.DESCEND, max_s=30)
    assert _states(h.seq)[-3:] == ["hold", "land", "descend"]
    h.tick_errors = 0
    assert h.step() == Stream.DESCENT  # a closed-loop gentle descent, never zero thrust in the air
    h.ap.on_ground = True
    h.run_until(lambda: h.seq.finished, max_s=2)
    assert h.seq.final_phase == "landed" and "disarm" in h.ap.asked and h.seq.outcome == "tick_errors"


def test_tick_errors_hold_without_streaming():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.tick_errors = 3
    h.step()
    assert h.seq.state == State.HOLD and h.step() == Stream.NONE
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "tick_errors" and h.seq.final_phase == "landed"


def test_invalid_estimate_is_tolerated_for_0_3_s_then_holds():
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.estimate_ok = False
    t0 = h.ap.t
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=1)
    assert 0.3 <= h.ap.t - t0 <= 0.31 and h.seq.outcome == "invalid_estimate"


def test_a_vehicle_far_from_the_reference_for_a_second_is_handed_to_its_own_hold():
    """The companion's loop gone unstable (the vehicle > 2 m from the reference for > 1 s): outcome ``diverged``,
    no more of our setpoints, the vehicle's hold, then land. A shorter excursion is tolerated."""
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.tracking_error_m = 3.0
    for _ in range(int(0.8 / DT)):  # 0.8 s: tolerated
        h.step()
    h.tracking_error_m = 0.5
    h.step()
    assert h.seq.state == State.MISSION and h.seq.outcome == "running"
    h.tracking_error_m = 2.5
    t0 = h.ap.t
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=2)
    assert 1.0 <= h.ap.t - t0 <= 1.0 + 2 * DT and h.seq.outcome == "diverged"
    assert "2.5 m from the reference" in h.seq.detail and h.step() == Stream.NONE
    h.run_until(lambda: h.seq.finished)
    assert h.seq.final_phase == "landed"


@pytest.mark.parametrize("what", ["diverged", "invalid_estimate"])
def test_in_lockstep_faster_than_real_time_the_timers_run_on_vehicle_time(what: str):
    """Lockstep at 5x real time: a second of vehicle time far from the reference is 0.2 s of wall time. The old
    wall-only timer let a runaway climb for 4.6 s of vehicle time (to 44 m) before anything fired."""
    h = _harness()
    h.wall_per_s = 0.2
    h.run_until(lambda: h.seq.state == State.MISSION)
    if what == "diverged":
        h.tracking_error_m = 3.0
    else:
        h.estimate_ok = False
    t0 = h.ap.t
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=2)
    limit = 1.0 if what == "diverged" else 0.3
    assert limit <= h.ap.t - t0 <= limit + 2 * DT and h.seq.outcome == what


def test_arming_temporarily_refused_is_retried_then_works():
    h = _harness()
    h.ap.refuse["arm"] = 1  # TEMPORARILY_REJECTED
    h.run_until(lambda: h.seq.state == State.ARM)
    h.run_until(lambda: h.ap.asked.count("arm") >= 3)
    del h.ap.refuse["arm"]
    h.run_until(lambda: h.seq.state == State.MISSION, max_s=5)


def test_arming_refused_for_good_is_reported_with_the_vehicles_reason():
    h = _harness(arm_timeout_s=3.0)
    h.ap.refuse["arm"] = 2
    h.run_until(lambda: h.seq.finished, max_s=10)
    assert h.seq.outcome == "refused" and "arming refused" in h.seq.detail


def test_offboard_refused_on_the_ground_disarms_and_reports():
    h = _harness()
    h.ap.refuse["mode:offboard"] = 2
    h.run_until(lambda: h.seq.finished, max_s=10)
    assert h.seq.outcome == "refused" and h.ap.asked[-1] == "disarm"


def test_no_heartbeat_is_no_vehicle():
    seq = FlightSequence(SequenceConfig(connect_timeout_s=2.0))
    t = 0.0
    while not seq.finished:
        t += 0.1
        assert seq.step(Observation(now_s=t, wall_s=t)).stream == Stream.NONE
    assert seq.outcome == "no_vehicle" and 2.0 < t < 2.2


def test_not_ready_names_the_reason():
    h = _harness(ready_timeout_s=2.0)
    h.ap.ready = False
    h.run_until(lambda: h.seq.finished, max_s=5)
    assert h.seq.outcome == "not_ready" and "not ready to arm" in h.seq.detail


def test_lost_answers_are_asked_again_and_then_given_up():
    h = _harness()
    h.ap.silent = {"message_interval:ATTITUDE"}
    h.run_until(lambda: h.seq.state == State.WAIT_READY, max_s=5)
    assert h.ap.asked.count("message_interval:ATTITUDE") == 3


@pytest.mark.parametrize("result", ["completed", "timeout", "no_route"])
def test_mission_end_lands_with_the_cores_verdict(result):
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.core_result = result
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == result and h.seq.final_phase == "landed"


def test_no_landing_asked_holds_at_the_end():
    h = _harness(land_at_end=False)
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.core_result = "completed"
    h.run_until(lambda: h.seq.finished)
    assert h.seq.outcome == "completed" and h.seq.final_phase == "holding"


def test_mission_wall_clock_timeout_when_vehicle_time_stands_still():
    h = _harness(mission_wall_timeout_s=2.0)
    h.run_until(lambda: h.seq.state == State.MISSION)
    h.run_until(lambda: h.seq.finished, max_s=10)
    assert h.seq.outcome == "timeout"


def test_a_takeover_refused_in_the_air_holds_the_core_where_it_is():
    """Entry actions run on entering a state: a vehicle already flying whose OFFBOARD is refused goes to HOLD, and
    the flight core is told to hold where its reference is in that very step. (Before, the order was tied to
    'time in state == 0.0' inside HOLD's own handler, which does not run in the step a takeover's failure enters
    HOLD: the core never heard it and flew on with the mission.)"""
    h = _harness()
    h.ap.armed, h.ap.on_ground, h.ap.refuse = True, False, {"mode:offboard": 4}
    orders = []
    while h.seq.state != State.HOLD:
        assert h.ap.t < 30.0, h.seq.transitions
        h.ap.advance(DT)
        obs = Observation(now_s=h.ap.t, wall_s=h.ap.t, heartbeat_wall_s=h.ap.last_hb, telemetry_wall_s=h.ap.last_tel,
                          telemetry_ready=True, vehicle_ready=True, armed=h.ap.armed, mode=h.ap.shown_mode,
                          on_ground=h.ap.on_ground, heartbeats=h.ap.heartbeats, estimate_ok=True)
        st = h.seq.step(obs)
        for r in st.send:
            h.ap.handle(h.seq, r)
        orders.append((h.seq.state, st.core))
    assert h.seq.outcome == "refused" and orders[-1] == (State.HOLD, "hold_here")  # CoreOrder.HOLD_HERE
    assert [o for _, o in orders[:-1]] == [None] * (len(orders) - 1)


def test_invalid_estimate_spells_shorter_than_the_limit_are_each_forgiven():
    """Two invalid-estimate spells of 0.2 s (limit 0.3 s) a second apart are not a failure: the timer starts again
    with each spell. (Before, it was only ever reset when it was not consulted, so the second spell failed at once.)"""
    h = _harness()
    h.run_until(lambda: h.seq.state == State.MISSION)
    for _ in range(2):
        h.estimate_ok = False
        for _ in range(round(0.2 / DT)):
            h.step()
        h.estimate_ok = True
        for _ in range(round(1.0 / DT)):
            h.step()
    assert h.seq.state == State.MISSION and h.seq.outcome == "running"
    h.estimate_ok = False  # a spell past the limit still holds
    h.run_until(lambda: h.seq.state == State.HOLD, max_s=1.0)
    assert h.seq.outcome == "invalid_estimate"
