"""The lockstep runner: the pilot ticked whenever the simulated vehicle ends a step, in a plain blocking loop.

The vehicle's simulated time advances only when the companion answers: after each step it sends its telemetry and
an end-of-step marker (SYSTEM_TIME); every new marker is answered by exactly one SET_ATTITUDE_TARGET (a "tick
only" frame when nothing may be streamed), right after the datagram that carried it. No event loop and no
deadlines: the loop waits on the socket, and runs as fast as the vehicle answers. Between datagrams it does what
the real-time runner's other coroutines do: a watchdog tick when ticks stop for 0.1 s (a vehicle that died sends
no more markers), our HEARTBEAT and the journal's flush once a second, the ``on_connected`` hook.
"""

from __future__ import annotations

import logging
import time

from companion.flight.health import LockstepClock
from companion.flight.pilot import Pilot
from companion.flight.runner import Runner, Wiring

log = logging.getLogger(__name__)

WATCHDOG_S = 0.1  # no tick for this long: step the pilot from the wall clock
HOUSEKEEPING_S = 1.0


class LockstepRunner(Runner):
    """Fly the pilot's mission against a lockstep vehicle: ``outcome = LockstepRunner(pilot, wiring).run()``."""

    lockstep = True

    def __init__(self, pilot: Pilot, wiring: Wiring | None = None) -> None:
        super().__init__(pilot, wiring)
        assert isinstance(pilot.clock, LockstepClock)
        self.clock: LockstepClock = pilot.clock
        self.link.on_datagram_done = self._on_datagram_done
        self._done = False
        self.stats.watchdog_since_rx = 0
        if self.setup.rt_priority > 0:  # lockstep runs flat out: SCHED_FIFO would starve every other thread
            log.info("lockstep: --rt-priority ignored (no deadlines to meet)")
            self.stats.scheduling = "SCHED_OTHER (lockstep: --rt-priority ignored)"

    def run(self) -> str:
        """Fly the mission; returns the outcome (see :data:`companion.flight.sequence.OUTCOMES`)."""
        self.gc_pacer.start()
        self.link.open_blocking()
        try:
            next_housekeeping = time.monotonic()
            while not self._done:
                self.link.poll(WATCHDOG_S)
                now = time.monotonic()
                if now >= next_housekeeping:
                    next_housekeeping = now + HOUSEKEEPING_S
                    self._connected_hook()
                    self._housekeeping()
                elif not self._connected_hook_done:
                    self._connected_hook()
                if not self._done and now - self._last_tick_wall > WATCHDOG_S:
                    self.stats.watchdog_steps += 1
                    self.stats.watchdog_since_rx += 1
                    self.clock.last_rx_wall_s = self.link.last_rx_wall
                    self._tick(watchdog=True)
                    self.gc_pacer.step()
            if self.pilot.outcome == "link_lost":  # which process went quiet: the vehicle, or this one
                log.warning("lockstep: %d watchdog ticks since the vehicle's last datagram (about one per %.1f s "
                            "while this loop listens)", self.stats.watchdog_since_rx, WATCHDOG_S)
        finally:
            self.link.close()
            self.gc_pacer.stop()
            if self.journal is not None:
                self.journal.close(self.provisional_facts())
        return self.pilot.outcome

    def _finished(self) -> None:
        self._done = True

    def _on_datagram_done(self) -> None:
        """Answer a new marker right after its datagram (the telemetry of that step folded in)."""
        self.clock.last_rx_wall_s = self.link.last_rx_wall
        self.stats.watchdog_since_rx = 0
        if not self._marker_pending or self._done:
            return
        self._marker_pending = False
        self._tick()
        self.clock.last_answer_wall_s = time.monotonic()
        self._between_ticks()
