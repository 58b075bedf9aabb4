"""Real-time scheduling for the companion's control thread (Linux ``SCHED_FIFO``), as flight stacks run their loops.

On a shared machine the kernel's fair scheduler preempts a control tick whenever another process is due: with
four vehicle + companion pairs on two cores, ~16 % of ticks were switched out mid-computation and the tick's wall
time p99 was 4-7 ms for 0.6 ms of CPU. PX4 on Linux runs its tasks ``SCHED_FIFO`` for the same reason. A
``SCHED_FIFO`` thread is never preempted by normal threads; it still sleeps between ticks, and the kernel's RT
throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default) keeps a runaway loop from locking a core.

Only the calling thread changes (the asyncio thread that runs ticks and MAVLink I/O). ``SCHED_RESET_ON_FORK``
keeps threads and processes created afterwards (Zenoh's, the bundled vehicle) at normal priority. It needs
``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` (``ulimit -r``) at least the priority asked for; without either the
request is refused and the flight goes on at normal priority, saying so.

The same concern, a pause inside a tick, has a second source in the process itself: Python's cyclic garbage
collector runs whenever enough container objects have been allocated, wherever that happens, and on the
development VM a full collection with numpy, scipy, Zenoh and Rerun imported took ~80 ms (twenty control
periods; generation-1 collections at start-up 1.2-2.8 ms). :class:`GcPacer` runs
the collector between ticks instead, with CPython's own thresholds, after freezing what was allocated before
the flight (the configuration, the imported modules) so the collections scan only the flight's own objects.
"""

from __future__ import annotations

import gc
import logging
import os
import resource
import time

import numpy as np

log = logging.getLogger(__name__)

RT_PRIORITY_MAX = 99


def request_fifo(priority: int) -> str:
    """Put the calling thread in ``SCHED_FIFO`` at ``priority`` (1..99); returns what the thread now runs as,
    e.g. ``"SCHED_FIFO 10"`` or ``"SCHED_OTHER (SCHED_FIFO 10 refused: ...)"``. Never raises for a refusal."""
    if not 1 <= priority <= RT_PRIORITY_MAX:
        raise ValueError(f"real-time priority must be in 1..{RT_PRIORITY_MAX}, got {priority}")
    if not hasattr(os, "SCHED_FIFO"):
        return f"SCHED_OTHER (SCHED_FIFO {priority} refused: not available on this platform)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except OSError as exc:
        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
        why = (f"{exc.strerror}; needs CAP_SYS_NICE or `ulimit -r` >= {priority} (now {soft})"
               if exc.errno == 1 else str(exc))
        log.warning("real-time priority refused (%s): the control loop runs at normal priority", why)
        return f"SCHED_OTHER (SCHED_FIFO {priority} refused: {why})"
    log.info("control thread runs SCHED_FIFO at priority %d", priority)
    return f"SCHED_FIFO {priority}"


def restore_normal() -> None:
    """Back to ``SCHED_OTHER`` for the calling thread (after the flight: the report and plots need no priority)."""
    if hasattr(os, "SCHED_OTHER") and os.sched_getscheduler(0) != os.SCHED_OTHER:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def involuntary_switches() -> int:
    """How many times the kernel has preempted the calling thread so far (``ru_nivcsw`` of RUSAGE_THREAD)."""
    if not hasattr(resource, "RUSAGE_THREAD"):
        return 0
    return resource.getrusage(resource.RUSAGE_THREAD).ru_nivcsw


class GcPacer:
    """Python's cyclic garbage collector moved out of the control ticks.

    :meth:`start` collects once, freezes every object alive then (``gc.freeze``: never scanned again) and turns
    the automatic collector off; :meth:`step`, called between ticks (and from the slower loops, so idle
    periods collect too), runs the collection CPython would have run by now (the oldest generation whose
    count is over its threshold, ``gc.get_threshold()``) and times it; :meth:`stop` turns the automatic
    collector back on and unfreezes. Reference counting still frees everything acyclic at once, so only
    cyclic garbage waits, at most until the next step. Does nothing when the collector was already off.
    """

    def __init__(self) -> None:
        self.active = False
        self.collections = [0, 0, 0]  # per generation
        self.pause_s: list[float] = []  # each collection's wall time (s)
        self._thresholds = (0, 0, 0)

    def start(self) -> None:
        """Collect, freeze what is alive, and take over from the automatic collector."""
        if self.active or not gc.isenabled():
            return
        gc.collect()
        gc.freeze()
        gc.disable()
        self._thresholds = gc.get_threshold()
        self.active = True

    def step(self) -> None:
        """Run the collection that is due, if any (µs when none is)."""
        if not self.active:
            return
        counts = gc.get_count()
        for gen in (2, 1, 0):
            if counts[gen] > self._thresholds[gen]:
                t0 = time.perf_counter()
                gc.collect(gen)
                self.pause_s.append(time.perf_counter() - t0)
                self.collections[gen] += 1
                return

    def stop(self) -> None:
        """Hand collection back to Python (automatic again, nothing frozen). Idempotent."""
        if not self.active:
            return
        self.active = False
        gc.unfreeze()
        gc.enable()

    def summary(self) -> dict[str, object]:
        """Collections per generation and their pause p99/max (ms, percentiles as the loop's own), all outside
        the ticks."""
        p = self.pause_s
        return {"gc_collections": list(self.collections),
                "gc_ms_p99": float(np.percentile(p, 99) * 1e3) if p else 0.0,
                "gc_ms_max": max(p) * 1e3 if p else 0.0}
