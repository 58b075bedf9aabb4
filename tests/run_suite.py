"""The suite's two phases at once, one beside the other (the README's test command runs them one after the other,
the serial tests in two runs: ``paired`` ones two at a time, the rest alone; this runner keeps them one at a time).

``tests/conftest.py`` marks a test ``serial`` when it needs the wall clock (real-time flights, the fault suite,
ground stations); the rest (no process, or lockstep ones: ``shares_cores``) has no deadline. This runs

* the serial phase, one test at a time, at normal priority, and
* the rest on both cores (``-n 2 --dist loadfile``) at ``SCHED_IDLE`` (and idle I/O) beside it,

so a real-time flight gets a CPU whenever it wants one and the lockstep flights fill what it leaves. (At nice 19
instead, a real-time vehicle fell 0.66 s behind and the Zenoh flood test ended ``link_lost``: docs/measurements.md,
2026-12-04. At SCHED_IDLE one full run in five failed a real-time test: a paused and resumed MAVProxy flight grazed
a trunk at its goal, with 72 ms of loop jitter; so CI keeps the phases apart.) Each phase writes its own log,
printed whole when it ends, and a line a minute says how far both are.
Extra arguments go to both pytest runs (``python tests/run_suite.py -x -k fly``); a ``-m`` expression is joined to
each phase's own (``-m "not slow"``: the daily check).

Exit status: 0 when both phases pass (a phase that selects nothing counts as passing while the other ran), else
the first failure's. Ctrl-C or SIGTERM stops both the way a terminal's Ctrl-C does (SIGINT: pytest finishes its
teardown); whatever kills this process, nothing it started outlives it (:func:`_preexec`).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from conftest import WORKERS_DIE_WITH_PYTEST

from companion import proclife

ROOT = Path(__file__).resolve().parent.parent
NO_TESTS = 5  # pytest's exit status when nothing was selected
PROGRESS_S = 60.0
STOP_WAIT_S = 60.0  # after SIGINT, how long a phase may take to tear down before it is killed

PHASES = {  # name: (pytest arguments, its marker expression, in the background)
    "serial": (["-q"], "serial", False),
    "shared": (["-q", "-n", "2", "--dist", "loadfile"], "not serial", True),
}


def _preexec(background: bool):
    """Between fork and exec in a phase's process: the background one runs SCHED_IDLE (a CPU only when nothing
    else wants it; inherited by every process it starts). Both die with us: the serial phase runs its tests itself
    and gets SIGINT (its teardown stops what the test started); the background one is killed, and its xdist workers
    are interrupted when it goes (``WORKERS_DIE_WITH_PYTEST``, tests/conftest.py): interrupted, its pytest would
    wait for them to finish their tests."""
    tie = proclife.preexec(signal.SIGKILL if background else signal.SIGINT)

    def pre() -> None:
        if background and hasattr(os, "SCHED_IDLE"):
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        if tie is not None:
            tie()

    return pre


def _split_markers(extra: list[str]) -> tuple[str | None, list[str]]:
    """(the ``-m`` expression among ``extra`` or None, the other arguments)."""
    if "-m" in extra:
        i = extra.index("-m")
        if i + 1 < len(extra):
            return extra[i + 1], extra[:i] + extra[i + 2:]
    return None, extra


def _start(name: str, extra: list[str], logdir: Path) -> tuple[subprocess.Popen, Path]:
    args, phase_markers, background = PHASES[name]
    markers, extra = _split_markers(extra)
    args = [*args, "-m", phase_markers if markers is None else f"({phase_markers}) and ({markers})"]
    log_path = logdir / f"{name}.log"
    idle_io = ["ionice", "-c", "3"] if background and shutil.which("ionice") else []  # disk time only when idle
    cmd = [*idle_io, sys.executable, "-m", "pytest", *args, "--basetemp", str(logdir / f"tmp-{name}"),
           "-o", f"cache_dir=.pytest_cache/{name}", *extra]
    out = log_path.open("w")
    # a session of its own: a terminal's Ctrl-C reaches this runner, which stops each phase once (_stop)
    env = {**os.environ, WORKERS_DIE_WITH_PYTEST: "1"} if background else None
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, preexec_fn=_preexec(background),
                            start_new_session=True, env=env)
    out.close()
    return proc, log_path


def _progress(log_path: Path) -> str:
    """How far a pytest -q log is: its newest ``[ nn%]``, else the tests done on its first line."""
    text = log_path.read_text(errors="replace")
    found = re.findall(r"\[\s*(\d+)%\]", text[-4000:])
    if found:
        return f"{found[-1]}%"
    first = text.splitlines()[0] if text.strip() else ""
    return f"{sum(c in '.sFExX' for c in first)} tests" if re.fullmatch(r"[.sFExX]*", first) else "starting"


def _status(codes: dict[str, int]) -> int:
    ran = [c for c in codes.values() if c != NO_TESTS]
    if not ran:
        return NO_TESTS
    return next((c for c in ran if c != 0), 0)


def _stop(procs: dict[str, subprocess.Popen]) -> None:
    """SIGINT to each phase's process group (its pytest and xdist workers, as a terminal's Ctrl-C), then SIGKILL
    to what is left after :data:`STOP_WAIT_S`."""
    for p in procs.values():
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGINT)
    deadline = time.monotonic() + STOP_WAIT_S
    for p in procs.values():
        try:
            p.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def main(extra: list[str]) -> int:
    logdir = Path(tempfile.mkdtemp(prefix="slungpilot-tests-"))
    t0 = time.monotonic()
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    codes: dict[str, int] = {}
    print(f"run_suite: serial and shared phases side by side; logs in {logdir}", flush=True)
    try:
        with proclife.sigterm_as_interrupt():
            for name in PHASES:
                procs[name], logs[name] = _start(name, extra, logdir)
            next_note = t0 + PROGRESS_S
            while len(codes) < len(procs):
                for name, p in procs.items():
                    if name not in codes and p.poll() is not None:
                        codes[name] = p.returncode
                        print(f"\n===== {name} phase: exit {p.returncode} after "
                              f"{(time.monotonic() - t0) / 60:.1f} min =====", flush=True)
                        print(logs[name].read_text(errors="replace"), end="", flush=True)
                if time.monotonic() >= next_note and len(codes) < len(procs):
                    next_note += PROGRESS_S
                    state = ", ".join(f"{n} {_progress(logs[n]) if n not in codes else 'done'}" for n in procs)
                    print(f"run_suite: {(time.monotonic() - t0) / 60:.0f} min: {state}", flush=True)
                time.sleep(0.5)
    except KeyboardInterrupt:
        _stop(procs)
        print(f"run_suite: interrupted; both phases stopped (logs in {logdir})", flush=True)
        return 130
    status = _status(codes)
    if status == 0:
        shutil.rmtree(logdir, ignore_errors=True)
    print(f"run_suite: {'passed' if status == 0 else 'FAILED'} in {(time.monotonic() - t0) / 60:.1f} min "
          f"({', '.join(f'{n} exit {c}' for n, c in codes.items())})"
          + ("" if status == 0 else f"; logs and temporary files kept in {logdir}"), flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
