"""The flight sequence's failure checks, apart from its reactions: :class:`FailureWatch` looks at each
observation and names the first failure it sees (first match wins, in the order of the table in
:mod:`companion.flight.sequence`); the sequence decides what to do about it. Pure, no clocks of its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from companion.flight.mode_goal import ModeGoal
from companion.flight.phase import State
from companion.flight.sequence_types import Observation, SequenceConfig, Stream

#: States in which the vehicle may be flying the companion's setpoints.
STREAMING_STATES = (State.TAKEOVER, State.MISSION, State.HOLD, State.LAND, State.DESCEND)


class FailureKind(Enum):
    """What the sequence does about a failure."""

    LINK_LOST = "link_lost"  # stop streaming, finish (the vehicle's own failsafe acts)
    PREEMPTED = "preempted"  # someone else took the vehicle: let go, finish
    HOLD = "hold"  # hold (if armed), then land; else finish


@dataclass(frozen=True, slots=True)
class Failure:
    """One failure: its kind, the outcome it gives the flight, why, and what to stream while holding."""

    kind: FailureKind
    outcome: str
    reason: str
    hold_stream: Stream = Stream.NONE


def _lasting(condition: bool, start: tuple[float, float] | None,
             obs: Observation) -> tuple[tuple[float, float] | None, float]:
    """How long ``condition`` has held: (its start as (now_s, wall_s), or None once it stops; seconds on the wall
    clock or the vehicle's, whichever has run longer: lockstep runs vehicle time faster than the wall clock)."""
    if not condition:
        return None, 0.0
    if start is None:
        start = (obs.now_s, obs.wall_s)
    return start, max(obs.now_s - start[0], obs.wall_s - start[1])


class FailureWatch:
    """Checks each observation for link loss, preemption, abort, failing ticks, stale telemetry, an invalid
    estimate and divergence from the reference; keeps the timers the last two need."""

    def __init__(self, cfg: SequenceConfig) -> None:
        self.cfg = cfg
        self._bad_start: tuple[float, float] | None = None
        self._div_start: tuple[float, float] | None = None  # (now_s, wall_s) when it went beyond diverged_m

    def check(self, obs: Observation, state: State, goal: ModeGoal | None, armed_seen: bool,
              airborne: bool) -> Failure | None:
        """The first failure ``obs`` shows in ``state`` (with the sequence's current mode goal), or None."""
        if state is State.CONNECT:
            return None
        lost = self._link_lost(obs, state)
        if lost is not None:
            return lost
        owned = goal is not None and goal.confirmed and state in (State.MISSION, State.HOLD, State.LAND)
        if owned and obs.heartbeats > goal.heartbeats_at_confirm and obs.mode != goal.mode and not (
                state is State.LAND and obs.on_ground):
            return Failure(FailureKind.PREEMPTED, "preempted",
                           f"the vehicle left {goal.mode} for {obs.mode} without being asked{_said(obs)}")
        if armed_seen and airborne and not obs.armed and not obs.on_ground and state not in (
                State.LAND, State.DESCEND):
            return Failure(FailureKind.PREEMPTED, "preempted", f"the vehicle was disarmed in flight{_said(obs)}")
        if state in (State.HOLD, State.LAND, State.DESCEND):
            return None  # already on the way down or holding: only link loss and preemption can end it sooner
        if obs.abort is not None:
            return Failure(FailureKind.HOLD, "aborted", obs.abort, Stream.CORE if obs.estimate_ok else Stream.NONE)
        if state not in STREAMING_STATES:
            return None
        return self._flying_failure(obs)

    def _link_lost(self, obs: Observation, state: State) -> Failure | None:
        hb_age = math.inf if obs.heartbeat_wall_s is None else obs.wall_s - obs.heartbeat_wall_s
        tel_age = math.inf if obs.telemetry_wall_s is None else obs.wall_s - obs.telemetry_wall_s
        # Before setpoints flow, an autopilot that pauses its telemetry (PX4 while its estimator starts) is only
        # not ready yet; from then on the vehicle may depend on us, and silence is a lost link.
        telemetry_counts = state not in (State.CONFIGURE, State.WAIT_READY)
        cfg = self.cfg
        streaming = telemetry_counts and obs.telemetry_ready and tel_age <= cfg.telemetry_loss_s
        hb_limit = max(cfg.heartbeat_loss_s, cfg.heartbeat_loss_streaming_s if streaming else
                       cfg.heartbeat_loss_s if telemetry_counts else cfg.heartbeat_loss_waiting_s)
        if hb_age > hb_limit or (telemetry_counts and obs.telemetry_ready and tel_age > cfg.telemetry_loss_s):
            what = (f"no HEARTBEAT for {hb_age:.1f} s" if hb_age > hb_limit
                    else f"no position/attitude for {tel_age:.2f} s")
            return Failure(FailureKind.LINK_LOST, "link_lost", f"vehicle lost: {what}")
        return None

    def _flying_failure(self, obs: Observation) -> Failure | None:
        """While our setpoints may be flown: failing ticks, stale telemetry, an invalid estimate, divergence."""
        cfg = self.cfg
        tel_age = math.inf if obs.telemetry_wall_s is None else obs.wall_s - obs.telemetry_wall_s
        if obs.tick_errors_in_row >= cfg.tick_error_limit:
            return Failure(FailureKind.HOLD, "tick_errors", f"{obs.tick_errors_in_row} control ticks failed in a row")
        if tel_age > cfg.stale_s:
            return Failure(FailureKind.HOLD, "stale_telemetry", f"position/attitude {tel_age:.2f} s old")
        self._bad_start, bad_s = _lasting(not obs.estimate_ok, self._bad_start, obs)
        if not obs.estimate_ok and bad_s > cfg.invalid_estimate_s:
            return Failure(FailureKind.HOLD, "invalid_estimate", "the state estimate stayed invalid")
        self._div_start, div_s = _lasting(obs.tracking_error_m > cfg.diverged_m, self._div_start, obs)
        if div_s > cfg.diverged_s:
            return Failure(FailureKind.HOLD, "diverged", f"{obs.tracking_error_m:.1f} m from the reference for "
                           f"more than {cfg.diverged_s:g} s")
        return None


def _said(obs: Observation) -> str:
    """The vehicle's last STATUSTEXT for a failure's text ("" without one)."""
    return f"; vehicle said: {obs.last_words!r}" if obs.last_words else ""
