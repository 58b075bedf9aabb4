"""The mission frame: where the mission's coordinates sit in the autopilot's local NED frame.

Missions are written relative to home. Until setpoints flow, the frame's origin follows what the vehicle reports:
home when it has one; else the take-off point (the vehicle on the ground); with ``start_here`` the point that puts
the mission's start under the vehicle. Once the sequence is past waiting for the vehicle, the origin is fixed.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from companion.estimation.estimate import Estimate
from companion.flight.phase import State

log = logging.getLogger(__name__)

_UNFIXED_STATES = (State.CONNECT, State.CONFIGURE, State.WAIT_READY)


class MissionFrame:
    """The mission frame's origin (``origin_ned_m``, local NED, m) and where it came from (``source``)."""

    def __init__(self, start_ned_m: np.ndarray, start_here: bool) -> None:
        self.start_ned_m = start_ned_m
        self.start_here = start_here
        self.origin_ned_m = np.zeros(3)
        self.source = "local origin"
        self.fixed = False

    def update(self, pos_ned_m: np.ndarray | None, home_ned_m: np.ndarray | None, on_ground: bool,
               state: State) -> float:
        """Follow the vehicle's home / position until the sequence leaves ``state`` in CONNECT..WAIT_READY;
        returns the vehicle's horizontal distance from the mission's start (m; 0 without a position)."""
        start = self.start_ned_m
        if not self.fixed:
            if self.start_here and pos_ned_m is not None:
                z0 = home_ned_m[2] if home_ned_m is not None else (pos_ned_m[2] if on_ground else 0.0)
                self.origin_ned_m = np.array([pos_ned_m[0] - start[0], pos_ned_m[1] - start[1], z0])
                self.source = "start-here"
            elif home_ned_m is not None:
                self.origin_ned_m, self.source = home_ned_m.copy(), "home"
            elif pos_ned_m is not None and on_ground:
                self.origin_ned_m, self.source = pos_ned_m.copy(), "take-off point"
            if state not in _UNFIXED_STATES:
                self.fixed = True
                log.info("mission frame: origin at %s of the autopilot's local frame (%s)",
                         np.round(self.origin_ned_m, 3).tolist(), self.source)
        if pos_ned_m is None:
            return 0.0
        o = self.origin_ned_m
        return math.hypot(pos_ned_m[0] - o[0] - start[0], pos_ned_m[1] - o[1] - start[1])

    def to_mission(self, est: Estimate) -> Estimate:
        """An estimate in the mission frame (positions relative to :attr:`origin_ned_m`)."""
        if not self.origin_ned_m.any():
            return est
        return est.with_position(est.pos_ned_m - self.origin_ned_m)

    def facts(self) -> dict[str, object]:
        """For the report: the origin in the autopilot's local frame and its source."""
        return {"origin_local_ned_m": self.origin_ned_m.tolist(), "origin": self.source}
