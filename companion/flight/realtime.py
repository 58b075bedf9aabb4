"""The real-time runner: the pilot ticked on a monotonic schedule inside asyncio.

Three coroutines share the work inside a ``TaskGroup``: the **tick loop** (deadlines ``t0 + k·period``; a tick more
than one period late is counted and missed deadlines are skipped, no catch-up burst); the **watchdog**, which steps
the pilot from the wall clock whenever ticks stop for 0.1 s (nothing is streamed), so a lost vehicle is noticed;
and **housekeeping** (our HEARTBEAT at 1 Hz, the journal's flush, the ``on_connected`` hook). Python's garbage
collector runs between ticks (:class:`~companion.flight.scheduling.GcPacer`); when the loop stalls for 0.1 s anyway,
:class:`~companion.flight.scheduling.StallTracer` records where, and the silence meanwhile is not the vehicle's
(:class:`~companion.flight.health.DeafSpells`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from companion.flight.health import RealtimeClock
from companion.flight.pilot import Pilot
from companion.flight.runner import Runner, Wiring
from companion.flight.scheduling import StallTracer, request_fifo, restore_normal

log = logging.getLogger(__name__)


class RealtimeRunner(Runner):
    """Fly the pilot's mission in real time: ``outcome = await RealtimeRunner(pilot, wiring).run()``."""

    lockstep = False

    def __init__(self, pilot: Pilot, wiring: Wiring | None = None) -> None:
        super().__init__(pilot, wiring)
        assert isinstance(pilot.clock, RealtimeClock)
        self.clock: RealtimeClock = pilot.clock
        self.stall_tracer = StallTracer()
        self._done = asyncio.Event()

    async def run(self) -> str:
        """Fly the mission; returns the outcome (see :data:`companion.flight.sequence.OUTCOMES`)."""
        fifo = self.setup.rt_priority > 0
        if fifo:
            self.stats.scheduling = request_fifo(self.setup.rt_priority)
        self.gc_pacer.start()
        self.stall_tracer.start()
        try:
            async with self.link, asyncio.TaskGroup() as tg:
                tg.create_task(self._tick_loop())
                tg.create_task(self._watchdog_loop())
                tg.create_task(self._housekeeping_loop())
        finally:
            self.stall_tracer.stop()
            self.gc_pacer.stop()
            if fifo:
                restore_normal()
            if self.journal is not None:
                self.journal.close(self.provisional_facts())
        return self.pilot.outcome

    def _finished(self) -> None:
        self._done.set()

    async def _tick_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.pilot.period_s
        t0 = loop.time()
        k = 0
        while not self._done.is_set():
            k += 1
            deadline = t0 + k * period
            delay = deadline - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            self.stall_tracer.beat()
            lateness = loop.time() - deadline
            self.stats.jitter_s.append(lateness)
            self.clock.deaf.add(deadline, deadline + lateness)
            if lateness > period:
                self.stats.late_ticks += 1
                k += int(lateness // period)  # skip the missed deadlines, no catch-up burst
            self._tick()
            self._between_ticks()
        self.stall_tracer.stop()  # what follows the last tick (closing files, the report) is not a stall

    async def _watchdog_loop(self) -> None:
        """Step the pilot from the wall clock whenever ticks stop for 0.1 s (nothing is streamed)."""
        while not self._done.is_set():
            due = time.monotonic() + 0.1
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(0.1):
                    await self._done.wait()
            self.clock.deaf.add(due, time.monotonic())  # a stalled loop wakes the watchdog late
            if not self._done.is_set() and time.monotonic() - self._last_tick_wall > 0.1:
                self.stats.watchdog_steps += 1
                self._tick(watchdog=True)
            self.gc_pacer.step()  # garbage is collected while ticks stop too

    async def _housekeeping_loop(self) -> None:
        """Once a second the HEARTBEAT and the journal; every 20 ms until the vehicle is known, the hook's check."""
        next_s = time.monotonic()
        while not self._done.is_set():
            self._connected_hook()
            if time.monotonic() >= next_s:
                next_s += 1.0
                self._housekeeping()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0 if self._connected_hook_done else 0.02):
                    await self._done.wait()

    def loop_facts(self, provisional: bool = False) -> dict[str, Any]:
        return super().loop_facts(provisional) | self.clock.deaf.summary() | self.stall_tracer.summary()
