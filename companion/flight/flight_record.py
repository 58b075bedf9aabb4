"""The flight's record as the pilot keeps it: the per-tick flight log, which swing source each row flew on, and a
once-a-second gate for error logs (a failure every tick would flood them)."""

from __future__ import annotations

import logging

import numpy as np

from companion.core.mission import Mission
from companion.core.model import payload_offset_ned_m
from companion.estimation.estimate import Estimate
from companion.estimation.vehicle_state import VehicleState
from companion.flight.core import Command
from companion.report.metrics import FlightLog

log = logging.getLogger(__name__)


class FlightRecord:
    """The :class:`~companion.report.metrics.FlightLog` of one flight and the counts the report adds to it."""

    def __init__(self, mission: Mission, state: VehicleState, true_cable_m: float | None = None) -> None:
        self.true_cable_m = true_cable_m  # the cable the log places the payload on (m); None: the one flown
        self.state = state
        self.log = FlightLog(planner=mission.planner, controller=mission.controller, mission=mission.name,
                             obstacles=mission.obstacles)
        self.swing_sources: dict[str, int] = {}
        self._last_swing_source = ""
        self._last_error_log = -1e9

    def error_log_due(self, wall_s: float) -> bool:
        """Whether a failure at monotonic time ``wall_s`` (s) gets logged: failing ticks, obstacle input and the
        after-send bookkeeping share one log at most once a second."""
        if wall_s - self._last_error_log < 1.0:
            return False
        self._last_error_log = wall_s
        return True

    def append(self, est: Estimate, cmd: Command | None, origin_ned_m: np.ndarray) -> None:
        """One log row; the payload point from the cable angles when known (on the true cable where the set-up gives
        it, else on the one flown: the mission's, or the identified one after a hop), else the payload's own stream
        (its position in the autopilot's local frame, moved by the mission frame's ``origin_ned_m``)."""
        src = est.swing_source
        self.swing_sources[src] = self.swing_sources.get(src, 0) + 1
        if src != self._last_swing_source:
            if src == "none":
                log.warning("no swing input: flying without feed-forward, envelope = full cable length")
            else:
                log.info("swing input: %s", src)
            self._last_swing_source = src
        # The log keeps the best swing measurement even when the controller was told to ignore it, so the
        # report's swing and clearance numbers describe the flight, not the controller's view of it.
        st = self.state
        swing = st.measured_swing()
        if swing is not None:
            cable_m = st.cable_length_m if self.true_cable_m is None else self.true_cable_m
            payload = est.pos_ned_m + payload_offset_ned_m(swing[0], swing[1], cable_m)
        elif st.payload_pos_ned_m is not None:
            payload = st.payload_pos_ned_m - origin_ned_m
        else:
            payload = None
        self.log.append(est.t_s, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, swing, payload, cmd,
                        swing_used=est.swing if src == "estimate" else None)
