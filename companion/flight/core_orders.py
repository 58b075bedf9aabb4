"""The flight sequence's orders to the flight core: hold here, resume after a pause, descend; and the planner's
"no route" (pure).

A mixin of :class:`~companion.flight.core.FlightCore`: it reads and sets the core's phase, reference, hold point
and planner.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from companion.flight.phase import CorePhase

if TYPE_CHECKING:
    from companion.core.mission import Mission
    from companion.planning import Planner, ReferenceGenerator

log = logging.getLogger(__name__)

DESCENT_MPS = 0.5  # the companion's own landing descent (when the autopilot's land mode is not confirmed)
#: where a time-parameterised planner gives the reference
TIMED_PHASES = (CorePhase.CRUISE, CorePhase.HOLD, CorePhase.NO_ROUTE, CorePhase.DONE)


class CoreOrders:
    """hold_here / resume / descend of a :class:`~companion.flight.core.FlightCore`."""

    phase: CorePhase
    ref: ReferenceGenerator | None
    planner: Planner
    _timed: bool
    _timed_stop: bool
    _braking: bool
    _hold_ned_m: np.ndarray
    _paused_from: tuple[CorePhase, np.ndarray] | None
    no_route: bool
    t_no_route_s: float | None
    mission: Mission

    def hold_here(self, brake: bool = False) -> None:
        """Stop the mission and hover where the reference is now (a hold the flight sequence asked for);
        ``brake`` (a ground station's pause, velocity planners): where the reference stops braking at its own
        acceleration and jerk limits, without coming back (from 2 m/s a hold at "now" overshot 1.1 m and flew back).

        With a time-parameterised planner flying, "now" is the planner's own stop: along its checked path at
        the swing-bounded deceleration (from 3.6 m/s a straight-line stop at the reference generator's limits
        overshoots by 6 m, through whatever is ahead, and flies back)."""
        resumable = self.phase in (CorePhase.CLIMB, CorePhase.IDENTIFY, CorePhase.CRUISE, CorePhase.HOLD)
        self._paused_from = (self.phase, self._hold_ned_m) if resumable else None
        if self.ref is not None:
            self._hold_ned_m = np.array(self.ref.p, dtype=np.float64)
        self._stop_timed()
        self._braking = brake and not self._timed_stop
        self.phase = CorePhase.HOLD_HERE

    def resume(self) -> bool:
        """Fly the mission on from where :meth:`hold_here` stopped it, from the phase it stopped (a ground
        station's pause ended); False when there is nothing to resume."""
        if self.phase != CorePhase.HOLD_HERE or self._paused_from is None:
            return False
        if self._timed_stop:
            self.planner.resume()
            self._timed_stop = False
        (self.phase, self._hold_ned_m), self._paused_from = self._paused_from, None
        self._braking = False
        return True

    def descend(self) -> None:
        """Stop the mission and descend at :data:`DESCENT_MPS` over where the reference is now (the
        companion's own landing, when the autopilot's land mode was not confirmed); with a time-parameterised
        planner, over the end of its stop (see :meth:`hold_here`)."""
        if self.ref is not None:
            self._hold_ned_m = np.array(self.ref.p, dtype=np.float64)
        self._stop_timed()
        self.phase = CorePhase.DESCEND

    def _stop_timed(self) -> None:
        if self._timed and (self.phase in TIMED_PHASES or self._timed_stop):
            self.planner.stop()
            self._timed_stop = True

    def no_route_here(self, t_s: float) -> None:
        """The planner found no route: from the cruise, the no_route phase from ``t_s``, held where the reference
        stops (a velocity planner's reference brakes at its own limits; a time-parameterised planner holds at the
        end of its own stop). Once per flight: later calls do nothing."""
        if self.no_route:
            return
        self.no_route = True
        if self.phase == CorePhase.CRUISE and self.ref is not None:
            self.phase, self.t_no_route_s = CorePhase.NO_ROUTE, t_s
            self._braking = not self._timed
            log.warning("mission %s: no route to the goal; holding at (%.2f, %.2f)", self.mission.name,
                        self.ref.p[0], self.ref.p[1])
