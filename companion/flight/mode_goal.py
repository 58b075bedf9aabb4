"""Getting the vehicle into one mode: asked, accepted, shown by HEARTBEAT — or refused, or never shown.

A mode counts as the companion's only once the request was accepted *and* a HEARTBEAT that came after the
acceptance shows it. A vehicle that already shows the mode is still asked (an earlier request of ours may be on its
way to it), and a lost answer is asked again, at most ``request_attempts`` times. Pure: the sequence owns one goal
at a time and steps it with each observation.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from companion.flight.requests import Request, RequestTracker
from companion.flight.sequence_types import Observation, SequenceConfig

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_IN_PROGRESS = 5


class GoalStatus(StrEnum):
    """Where a mode goal stands after a step."""

    CONFIRMED = "confirmed"
    WAITING = "waiting"
    REFUSED = "refused"
    FAILED = "failed"


@dataclass
class ModeGoal:
    """One mode the sequence wants (in its own words: ``offboard``, ``hold``, ``land``)."""

    mode: str
    asked: int = 0
    accepted_s: float | None = None
    confirmed: bool = False
    refused: int | None = None  # MAV_RESULT of a refusal
    heartbeats_at_accept: int = 0
    heartbeats_at_confirm: int = 0

    @classmethod
    def already_confirmed(cls, mode: str, heartbeats: int) -> ModeGoal:
        """A goal met now (the mode carried over from the state before), confirmed at ``heartbeats``."""
        return cls(mode, confirmed=True, heartbeats_at_confirm=heartbeats)

    def pursue(self, obs: Observation, requests: RequestTracker, cfg: SequenceConfig,
               send: list[Request]) -> GoalStatus:
        """Work towards the mode: read the answer, watch the HEARTBEAT, ask (again) when due."""
        if self.confirmed:
            return GoalStatus.CONFIRMED
        key = f"mode:{self.mode}"
        res = requests.result(key)
        if res is not None:
            if int(res) in (MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS):
                self.accepted_s = obs.now_s
                self.heartbeats_at_accept = obs.heartbeats
            else:
                self.refused = int(res)
                return GoalStatus.REFUSED
        if self.accepted_s is not None and obs.mode == self.mode and obs.heartbeats > self.heartbeats_at_accept:
            self.confirmed = True
            self.heartbeats_at_confirm = obs.heartbeats
            return GoalStatus.CONFIRMED
        if requests.failed(key):
            return GoalStatus.FAILED
        if requests.pending(key):
            return GoalStatus.WAITING
        if self.asked == 0 or (self.accepted_s is not None and obs.now_s - self.accepted_s > cfg.mode_confirm_s):
            if self.asked >= cfg.request_attempts:
                return GoalStatus.FAILED
            self.asked += 1
            self.accepted_s = None
            send.extend(requests.ask(key, obs.now_s))
        return GoalStatus.WAITING
