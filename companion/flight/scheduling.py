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
"""

from __future__ import annotations

import logging
import os
import resource

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
