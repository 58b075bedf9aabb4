"""Real-time scheduling of the control thread (companion/flight/scheduling.py): granted or refused, never fatal."""

from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import threading
import weakref

import pytest

from companion.flight.scheduling import GcPacer, StallTracer, involuntary_switches, request_fifo, restore_normal

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_FIFO"), reason="POSIX real-time scheduling not available")


def test_granted_or_refused_in_a_thread_of_its_own():
    """Only the calling thread changes; granted -> SCHED_FIFO at that priority and back; refused -> a reason."""
    seen: dict[str, object] = {}

    def worker() -> None:
        seen["result"] = request_fifo(7)
        seen["policy"] = os.sched_getscheduler(0)
        seen["priority"] = os.sched_getparam(0).sched_priority
        restore_normal()
        seen["after"] = os.sched_getscheduler(0)

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    if seen["result"] == "SCHED_FIFO 7":
        assert seen["policy"] & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO and seen["priority"] == 7
    else:
        assert str(seen["result"]).startswith("SCHED_OTHER (SCHED_FIFO 7 refused")
    assert seen["after"] == os.SCHED_OTHER
    assert os.sched_getscheduler(0) == os.SCHED_OTHER, "the test's own thread was not touched"


def test_refused_without_privilege_says_how_to_get_it():
    """No CAP_SYS_NICE and `ulimit -r` 0: refused with the reason, and the process goes on."""
    code = (
        "import os, resource\n"
        "from companion.flight.scheduling import request_fifo\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "if os.getuid() == 0:  # root: become nobody, which has no CAP_SYS_NICE\n"
        "    os.setgid(65534); os.setuid(65534)\n"
        "print(request_fifo(10)); print(os.sched_getscheduler(0) == os.SCHED_OTHER)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.splitlines()
    assert first.startswith("SCHED_OTHER (SCHED_FIFO 10 refused") and "ulimit -r" in first
    assert second == "True"


def test_priority_out_of_range_is_an_error():
    with pytest.raises(ValueError, match=r"1\.\.99"):
        request_fifo(0)
    with pytest.raises(ValueError, match=r"1\.\.99"):
        request_fifo(100)


def test_involuntary_switches_counts_up():
    a = involuntary_switches()
    assert a >= 0 and involuntary_switches() >= a


def test_fly_refuses_an_out_of_range_priority(tmp_path):
    out = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--sitl", "--rt-priority", "100",
                          "--run-dir", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--rt-priority" in out.stderr


class _Cycle:
    """An object in a reference cycle: only the cyclic garbage collector frees it."""

    def __init__(self) -> None:
        self.me = self


def test_gc_pacer_collects_between_ticks_only_and_hands_back():
    """While the pacer runs, Python collects nothing by itself (a cycle survives any number of allocations
    until step()); step() runs the due generation and counts it; stop() gives automatic collection back."""
    assert gc.isenabled()
    pacer = GcPacer()
    try:
        pacer.start()
        assert pacer.active and not gc.isenabled() and gc.get_freeze_count() > 0
        victim = _Cycle()
        ref = weakref.ref(victim)
        del victim
        # far past the generation-0 threshold (kept alive: the count is allocations minus deallocations)
        junk = [[] for _ in range(5 * gc.get_threshold()[0])]
        assert ref() is not None  # no automatic collection happened in the "tick"
        pacer.step()
        del junk
        assert sum(pacer.collections) == 1 and len(pacer.pause_s) == 1
        pacer.step()  # nothing due right after a collection
        assert sum(pacer.collections) == 1
        if ref() is not None:  # collected generation 0 only; the cycle may sit in an older one by now
            gc.collect()
        assert ref() is None
        summary = pacer.summary()
        assert summary["gc_collections"] == pacer.collections and summary["gc_ms_max"] >= summary["gc_ms_p99"] > 0
    finally:
        pacer.stop()
    assert gc.isenabled() and gc.get_freeze_count() == 0 and not pacer.active
    pacer.stop()  # idempotent


def test_gc_pacer_starts_without_a_full_collection():
    """start() freezes what is alive without collecting first (a full collection costs 13-50 ms on a flight's
    heap): a cycle that was garbage before the start waits for stop(), then goes with the next collection."""
    gc.collect()  # generation counts at zero: nothing collects automatically before start()
    victim = _Cycle()
    ref = weakref.ref(victim)
    del victim
    pacer = GcPacer()
    try:
        pacer.start()
        assert ref() is not None and pacer.collections == [0, 0, 0]
    finally:
        pacer.stop()
    gc.collect()
    assert ref() is None


def test_gc_pacer_leaves_a_disabled_collector_alone():
    """A program that turned the collector off keeps it off: start() does nothing, step() never collects."""
    gc.disable()
    try:
        pacer = GcPacer()
        pacer.start()
        pacer.step()
        assert not pacer.active and pacer.collections == [0, 0, 0] and gc.get_freeze_count() == 0
        pacer.stop()
        assert not gc.isenabled()
    finally:
        gc.enable()


def _stuck_in_here(release: threading.Event) -> None:
    release.wait(10.0)


def test_a_stalled_loop_is_traced_where_it_stands():
    """The loop thread blocks inside a known function: the tracer records that function, once per stall."""
    tracer = StallTracer(threshold_s=0.05, poll_s=0.01)
    release = threading.Event()
    done = threading.Event()

    def loop() -> None:
        tracer.start()
        tracer.beat()
        _stuck_in_here(release)  # the stall: no beat until released
        tracer.beat()
        done.set()

    t = threading.Thread(target=loop)
    t.start()
    assert tracer.traced.wait(10.0), "no stall traced"
    release.set()
    t.join(10.0)
    assert done.is_set()
    tracer.stop()
    s = tracer.summary()
    assert s["stalls_traced"] == 1
    (rec,) = s["stall_traces"]
    assert rec["where"].endswith("in wait")  # threading.Event.wait, called from ...
    assert rec["ours"] is None  # no companion code on that stack
    assert any("in _stuck_in_here" in line for line in rec["stack"]), rec
    assert rec["stalled_s"] >= 0.05


def test_a_stopped_process_is_not_blamed_on_a_line_of_code():
    """The whole process stopped (SIGSTOP, as a VM pause): the tracer says so instead of showing a stack."""
    code = (
        "import os, signal, time, threading, json\n"
        "from companion.flight.scheduling import StallTracer\n"
        "t = StallTracer(threshold_s=0.05, poll_s=0.01)\n"
        "t.start()\n"
        "t.beat()\n"
        "os.kill(os.getpid(), signal.SIGSTOP)\n"  # resumed by the test's SIGCONT
        "assert t.traced.wait(10.0)\n"
        "t.stop()\n"
        "print(json.dumps(t.summary()))\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(1000):  # wait until it has stopped itself
            with open(f"/proc/{p.pid}/stat") as fh:
                if fh.read().split(") ")[1].startswith("T"):
                    break
            threading.Event().wait(0.01)
        threading.Event().wait(0.3)  # stopped for 0.3 s
        os.kill(p.pid, signal.SIGCONT)
        out, _ = p.communicate(timeout=30)
    finally:
        p.kill()
    s = json.loads(out)
    assert s["stalls_traced"] >= 1
    assert s["stall_traces"][0]["where"].startswith("the process was not running"), s


def test_a_loop_that_keeps_the_gil_is_not_taken_for_a_stopped_process():
    """One long call that never releases the GIL keeps the tracer from running: its CPU time shows the loop was
    busy, so the trace says so (and not that the process was stopped)."""
    import re

    tracer = StallTracer(threshold_s=0.05, poll_s=0.01)
    tracer.start()
    tracer.beat()
    re.match(r"(a+)+$", "a" * 24 + "b")  # catastrophic backtracking: a long C call, the GIL held throughout
    assert tracer.traced.wait(10.0)
    tracer.stop()
    assert tracer.traces[0]["where"].startswith("the loop thread kept the GIL"), tracer.traces


def test_a_lockstep_pair_is_pinned_to_the_cpu_it_runs_on_and_a_child_inherits_it():
    """pin_to_one_cpu narrows this process to one CPU (the vehicle it starts next inherits it: checked in a real
    child), and restore_affinity gives the old set back."""
    import os
    import subprocess
    import sys

    from companion.flight.scheduling import pin_to_one_cpu, restore_affinity

    before = os.sched_getaffinity(0)
    cpu, old = pin_to_one_cpu()
    try:
        if len(before) < 2:
            assert (cpu, old) == (None, None)  # one CPU: nothing to pin
            return
        assert old == before and os.sched_getaffinity(0) == {cpu}
        child = subprocess.run([sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)))"],
                               capture_output=True, text=True, check=True)
        assert child.stdout.strip() == str([cpu])
    finally:
        restore_affinity(old)
    assert os.sched_getaffinity(0) == before
