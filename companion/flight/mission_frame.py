"""The mission frame: where the mission's coordinates sit in the autopilot's local NED frame.

Missions are written relative to home. Until setpoints flow, the frame's origin follows what the vehicle reports:
home when it has one; else the take-off point (the vehicle on the ground); with ``start_here`` the point that puts
the mission's start under the vehicle. Once the sequence is past waiting for the vehicle, the origin is fixed.
A mission the autopilot holds (``fly --mission autopilot``) was placed about home as its download found it: its
frame's north and east are pinned there from the start (``pinned_ned_m``), whatever home the autopilot reports
later (PX4 SIH moved home 0.27-2.2 m while its estimator settled, which would shift the whole route off the points
on the earth); its down axis follows home like any frame's, as altitudes relative to home do (PX4 SIH's home moved
1.5-1.7 m in height too).
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

    def __init__(self, start_ned_m: np.ndarray, start_here: bool,
                 pinned_ned_m: tuple[float, float, float] | None = None) -> None:
        self.start_ned_m = start_ned_m
        self.start_here = start_here
        self.pinned = pinned_ned_m is not None
        self.origin_ned_m = np.array(pinned_ned_m, dtype=float) if self.pinned else np.zeros(3)
        self.source = "home at the mission's download" if self.pinned else "local origin"
        self.fixed = False
        #: pinned frames: the home the vehicle reported when the frame was fixed (local NED, m; None without one)
        self.home_at_fix_ned_m: np.ndarray | None = None

    def update(self, pos_ned_m: np.ndarray | None, home_ned_m: np.ndarray | None, on_ground: bool,
               state: State) -> float:
        """Follow the vehicle's home / position until the sequence leaves ``state`` in CONNECT..WAIT_READY (a
        pinned frame does not move); returns the vehicle's horizontal distance from the mission's start (m; 0
        without a position; pinned: the start's offset from the autopilot's current home)."""
        start = self.start_ned_m
        if not self.fixed:
            if self.pinned:  # north and east stay on the download's home; heights are above the home now
                if home_ned_m is not None:
                    self.origin_ned_m[2] = home_ned_m[2]
            elif self.start_here and pos_ned_m is not None:
                z0 = home_ned_m[2] if home_ned_m is not None else (pos_ned_m[2] if on_ground else 0.0)
                self.origin_ned_m = np.array([pos_ned_m[0] - start[0], pos_ned_m[1] - start[1], z0])
                self.source = "start-here"
            elif home_ned_m is not None:
                self.origin_ned_m, self.source = home_ned_m.copy(), "home"
            elif pos_ned_m is not None and on_ground:
                self.origin_ned_m, self.source = pos_ned_m.copy(), "take-off point"
            if state not in _UNFIXED_STATES:
                self.fixed = True
                if self.pinned and home_ned_m is not None:
                    self.home_at_fix_ned_m = home_ned_m.copy()
                log.info("mission frame: origin at %s of the autopilot's local frame (%s)",
                         np.round(self.origin_ned_m, 3).tolist(), self.source)
        if pos_ned_m is None:
            return 0.0
        # pinned: the start is checked against the home the autopilot reports now, where it takes off (as an
        # unpinned frame checks it); only the route stays where the download placed it
        o = home_ned_m if self.pinned and home_ned_m is not None else self.origin_ned_m
        (px, py), (ox, oy), (sx, sy) = pos_ned_m[:2].tolist(), o[:2].tolist(), start[:2].tolist()
        return math.hypot(px - ox - sx, py - oy - sy)

    def to_mission(self, est: Estimate) -> Estimate:
        """An estimate in the mission frame (positions relative to :attr:`origin_ned_m`)."""
        o = self.origin_ned_m
        if o[0] == 0.0 and o[1] == 0.0 and o[2] == 0.0:  # (ndarray.any() costs ~6 % of a lockstep tick)
            return est
        return est.with_position(est.pos_ned_m - self.origin_ned_m)

    def facts(self) -> dict[str, object]:
        """For the report: the origin in the autopilot's local frame and its source."""
        out: dict[str, object] = {"origin_local_ned_m": self.origin_ned_m.tolist(), "origin": self.source}
        if self.pinned:
            out["home_at_fix_local_ned_m"] = None if self.home_at_fix_ned_m is None else \
                self.home_at_fix_ned_m.tolist()
        return out
