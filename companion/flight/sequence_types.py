"""The flight sequence's vocabulary: what it sends (:class:`Stream`), how flights end (:data:`OUTCOMES`), its
timeouts (:class:`SequenceConfig`), what it is told each step (:class:`Observation`) and what it answers
(:class:`Step`, :class:`Transition`). Pure data, no behaviour: the rules are in :mod:`companion.flight.sequence`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple

from companion.flight.phase import CoreOrder, State
from companion.flight.requests import Request


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
    # ... and while its position and attitude keep flowing the link is alive (telemetry_loss_s watches that):
    # a late HEARTBEAT alone is an autopilot whose clock runs slow (PX4 SIH at 0.7x wall time sent its 1 Hz
    # HEARTBEAT 1.25-1.57 s apart and two of four flights ended link_lost mid-mission with telemetry flowing)
    heartbeat_loss_streaming_s: float = 4.0
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


class Observation(NamedTuple):
    """What the app knows at this instant (a NamedTuple: built every control tick, ~3x cheaper than a frozen
    dataclass of 19 fields).

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
    unready: tuple[str, ...] = ()  # while waiting: the autopilot's readiness conditions still unmet, in words


@dataclass(frozen=True, slots=True)
class Step:
    """What to do now: the stream for this tick, requests to send, and (once) the configure answers."""

    stream: Stream
    send: tuple[Request, ...] = ()
    configured: dict[str, float | int] | None = None  # answers of the configure requests, handed over once
    core: CoreOrder | None = None  # re-aim the flight core (given once, on entering HOLD or DESCEND)


@dataclass(frozen=True, slots=True)
class Transition:
    """One state change, for the log, the status stream and the report."""

    now_s: float
    wall_s: float
    from_state: State
    to_state: State
    reason: str
