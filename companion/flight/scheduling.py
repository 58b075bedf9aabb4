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

When the loop stalls anyway, :class:`StallTracer` notes where: a deaf spell in the report then comes with the
loop thread's stack at the moment it had stalled for 0.1 s (that is how the journal's file rename on the event loop
was found to hold it for up to 0.8 s while another process kept the disk busy).
"""

from __future__ import annotations

import gc
import logging
import math
import os
import resource
import sys
import threading
import time
import traceback

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

    :meth:`start` freezes every object alive then (``gc.freeze``: never scanned again; cyclic garbage among them
    waits for :meth:`stop`, cheaper than the full collection that would find it: 13 ms in ``fly``, 25–50 ms in a
    batch worker) and turns the automatic collector off; :meth:`step`, called between ticks (and from the slower loops,
    so idle periods collect too), runs the collection CPython would have run by now (the oldest generation whose
    count is over its threshold, ``gc.get_threshold()``) and times it; :meth:`stop` turns the automatic
    collector back on and unfreezes. Reference counting still frees everything acyclic at once; cyclic garbage made
    during the flight waits at most until the next step. Does nothing when the collector was already off.
    """

    def __init__(self) -> None:
        self.active = False
        self.collections = [0, 0, 0]  # per generation
        self.pause_s: list[float] = []  # each collection's wall time (s)
        self._thresholds = (0, 0, 0)

    def start(self) -> None:
        """Freeze what is alive and take over from the automatic collector."""
        if self.active or not gc.isenabled():
            return
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


#: The least share of a stall's wall time the loop thread must have spent on a CPU for the stall to be its own
#: (one call that kept the GIL) rather than the process not running. A stopped or swapped-out process gets ~0; a
#: busy loop on a loaded machine gets its fair share of a core: ~0.4 at a load of 5 on 2 cores (the old 0.5 misread
#: such a loop as stopped in the test suite run beside other flights), so 0.2 leaves room to a load of ~10.
BUSY_SHARE = 0.2


class StallTracer:
    """A thread that notes where the control loop was when it stalled.

    The loop calls :meth:`beat` every time it comes round (each tick); the tracer thread wakes every ``poll_s``
    and, the first time in a stall that the last beat is more than ``threshold_s`` old, records the loop thread's
    stack (``sys._current_frames``). It needs the GIL for that: a loop blocked in a system call (a disk, a socket)
    has released it, and a loop busy in Python hands it over within the interpreter's switch interval (5 ms). When
    the tracer itself woke more than ``threshold_s`` late, either the whole process had not been running (a VM
    pause, SIGSTOP, swapped out) or the loop thread kept the GIL in one long call (a C function that does not
    release it); the loop thread's CPU time over the gap tells which, and that is recorded, without a stack (which
    would only show the loop catching up), even if the loop came round before the tracer did. ``stalled_s`` is how
    long the stall had lasted when seen. At most ``keep`` stalls are recorded (``stalls`` counts them all).
    """

    def __init__(self, threshold_s: float = 0.1, poll_s: float = 0.02, keep: int = 20) -> None:
        self.threshold_s = threshold_s
        self.poll_s = poll_s
        self.keep = keep
        self.traces: list[dict[str, object]] = []
        self.stalls = 0
        self.traced = threading.Event()  # set at the first trace (tests wait on it)
        self._beat_s = time.monotonic()
        self._traced_beat: float | None = None
        self._loop_ident: int | None = None
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Watch the calling thread (the loop's) from a thread of its own."""
        if self._thread is not None:
            return
        self._loop_ident = threading.get_ident()
        self._t0 = self._beat_s = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="stall-tracer", daemon=True)
        self._thread.start()

    def beat(self) -> None:
        """The loop came round (call once per tick)."""
        self._beat_s = time.monotonic()

    def stop(self) -> None:
        """Stop watching. Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)

    def _loop_cpu_s(self) -> float:
        """The loop thread's CPU time so far (s), or NaN where the platform cannot tell."""
        try:
            return time.clock_gettime(time.pthread_getcpuclockid(self._loop_ident or 0))
        except (AttributeError, OSError):
            return math.nan

    def _run(self) -> None:
        last_wake = time.monotonic()
        last_cpu = self._loop_cpu_s()
        while not self._stop.wait(self.poll_s):
            now = time.monotonic()
            cpu = self._loop_cpu_s()
            woke_late_s = now - last_wake - self.poll_s
            loop_cpu_s = cpu - last_cpu
            last_wake, last_cpu = now, cpu
            beat = self._beat_s
            if woke_late_s > self.threshold_s:  # the tracer could not run: the loop may have come round since
                self._traced_beat = beat
                if loop_cpu_s > BUSY_SHARE * woke_late_s:  # the loop ran all along: one call that kept the GIL
                    where = (f"the loop thread kept the GIL for {woke_late_s:.3f} s in one call "
                             f"({loop_cpu_s:.3f} s of its CPU); where is not known")
                else:
                    where = f"the process was not running (the tracer itself woke {woke_late_s:.3f} s late)"
                self._add({"t_s": round(now - woke_late_s - self._t0, 3), "stalled_s": round(woke_late_s, 3),
                           "where": where, "ours": None, "stack": []})
                continue
            if now - beat <= self.threshold_s or self._traced_beat == beat:
                continue
            self._traced_beat = beat  # one record per stall
            self._add(self._record(now, beat))

    def _add(self, rec: dict[str, object]) -> None:
        self.stalls += 1
        if len(self.traces) < self.keep:
            self.traces.append(rec)
        log.warning("control loop stalled %.3f s, in %s (ours: %s)", rec["stalled_s"], rec["where"], rec["ours"])
        self.traced.set()

    def _record(self, now: float, beat: float) -> dict[str, object]:
        rec: dict[str, object] = {"t_s": round(beat - self._t0, 3), "stalled_s": round(now - beat, 3)}
        frame = sys._current_frames().get(self._loop_ident or 0)
        stack = traceback.extract_stack(frame) if frame is not None else []
        lines = [f"{_short_path(f.filename)}:{f.lineno} in {f.name}" for f in stack[-12:]]
        rec["where"] = lines[-1] if lines else "unknown"
        ours = [ln for ln in lines if ln.startswith(("companion/", "sim_bridge/", "lab/"))]
        rec["ours"] = ours[-1] if ours else None
        rec["stack"] = lines
        return rec

    def summary(self) -> dict[str, object]:
        """For the report's ``loop``: how many stalls of ``threshold_s`` or more, and where the first ones were."""
        return {"stalls_traced": self.stalls, "stall_traces": self.traces}


def _short_path(filename: str) -> str:
    """``.../site-packages/zenoh/x.py`` → ``zenoh/x.py``; ``/work/main/companion/a.py`` → ``companion/a.py``."""
    parts = filename.replace("\\", "/").split("/")
    for anchor in ("site-packages", "companion", "sim_bridge", "lab"):
        if anchor in parts:
            i = len(parts) - 1 - parts[::-1].index(anchor)
            return "/".join(parts[i + 1:] if anchor == "site-packages" else parts[i:])
    return "/".join(parts[-2:])


def current_cpu() -> int | None:
    """The CPU this process last ran on (``/proc/self/stat`` field 39), None where that cannot be read."""
    try:
        with open("/proc/self/stat") as f:
            return int(f.read().rsplit(")", 1)[1].split()[36])
    except (OSError, ValueError, IndexError):
        return None


def pin_to_one_cpu() -> tuple[int | None, set[int] | None]:
    """Pin this process to the CPU it runs on now, for a lockstep flight whose vehicle it is about to start (the
    child inherits the affinity): the two processes only ever run one at a time, handing each step over by UDP, and
    a wake-up on the same CPU costs less than one across CPUs (measured on the 2-core VM: the forest flew 8.9-9.6x
    real time pinned against 7.3-8.3x free; docs/sitl.md). Returns (the CPU, the affinity to restore), or (None,
    None) where affinity cannot be set or there is one CPU anyway."""
    if not hasattr(os, "sched_setaffinity"):
        return None, None
    old = os.sched_getaffinity(0)
    cpu = current_cpu()
    if len(old) < 2 or cpu is None or cpu not in old:
        return None, None
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError:
        return None, None
    return cpu, old


def restore_affinity(old: set[int] | None) -> None:
    """Undo :func:`pin_to_one_cpu` (None: nothing was pinned)."""
    if old is not None:
        try:
            os.sched_setaffinity(0, old)
        except OSError:
            log.warning("could not restore the CPU affinity %s", sorted(old))
