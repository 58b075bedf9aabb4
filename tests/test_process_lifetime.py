"""Nothing a command starts outlives it, whatever kills it (issue 25, "Orphans"; docs/companion.md).

Real commands in their own sessions, real kill signals, loopback only. Each test collects the command's
descendants while it runs (psutil), kills the command, and asserts that every one of them is gone within
5 s. The commands are run from the ``companion`` package that is imported here, so
``PYTHONPATH=/path/to/other/checkout pytest tests/test_process_lifetime.py`` runs them against other code.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import psutil
import pytest

import companion

ROOT = Path(companion.__file__).resolve().parents[1]
GONE_WITHIN_S = 5.0

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux's PR_SET_PDEATHSIG"),
              pytest.mark.paired]  # wall clock, light: may run beside one other such test (tests/conftest.py)


def _start(*args: str, stderr: Path) -> subprocess.Popen:
    """``python -m companion.cli ARGS`` in its own session, stdout piped (text), stderr to a file."""
    with stderr.open("w") as err:
        return subprocess.Popen([sys.executable, "-m", "companion.cli", *args], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=err, stdin=subprocess.DEVNULL, text=True, start_new_session=True)


def _first_line(proc: subprocess.Popen, prefix: str, stderr: Path) -> None:
    """Read the command's first line of output; it must start with ``prefix``."""
    line = proc.stdout.readline()
    assert line.startswith(prefix), f"{line!r}; stderr: {stderr.read_text(errors='replace')[-1500:]}"


def _descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _wait_for_descendants(proc: subprocess.Popen, pred, timeout_s: float) -> list[psutil.Process]:
    """The descendants of ``proc`` once ``pred(cmdlines)`` holds (the list of their joined command lines)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        kids = _descendants(proc.pid)
        cmds = []
        for k in kids:
            try:  # the name first: a vehicle forked ahead (sim_bridge.prefork) rewrites its command line cut to fit
                cmds.append(f"{k.name()} {' '.join(k.cmdline())}")
            except psutil.Error:
                cmds.append("")
        if pred(cmds):
            return kids
        assert proc.poll() is None, f"the command exited ({proc.returncode}) before its children were seen"
        time.sleep(0.05)
    raise AssertionError(f"no such descendants within {timeout_s} s: {cmds}")


def _survivors(kids: list[psutil.Process], timeout_s: float = GONE_WITHIN_S) -> list[str]:
    """Those of ``kids`` still running after ``timeout_s`` (zombies count as gone), as 'pid ppid cmdline'."""
    end = time.monotonic() + timeout_s
    while True:
        alive = []
        for k in kids:
            try:
                if k.is_running() and k.status() != psutil.STATUS_ZOMBIE:
                    alive.append(f"{k.pid} (parent {k.ppid()}) {' '.join(k.cmdline())[:120]}")
            except psutil.NoSuchProcess:
                pass
        if not alive or time.monotonic() > end:
            return alive
        time.sleep(0.05)


def _kill_all(proc: subprocess.Popen, kids: list[psutil.Process]) -> None:
    """Clean up after a failed test: nothing of ours left behind."""
    if proc.poll() is None:
        proc.kill()
    for k in kids:
        with contextlib.suppress(psutil.Error):
            k.kill()  # psutil checks that the pid still names the same process
    proc.wait(5)
    if proc.stdout is not None:
        proc.stdout.close()

def _sigkill_leaves_nothing(proc: subprocess.Popen, vehicles: int, timeout_s: float,
                            before_kill: Callable[[], None] | None = None) -> None:
    """Wait until ``proc`` has ``vehicles`` bundled vehicles among its descendants, SIGKILL it, and assert that every
    descendant seen is gone (cleaning up after a failure either way)."""
    kids: list[psutil.Process] = []
    try:
        if before_kill is not None:
            before_kill()
        kids = _wait_for_descendants(proc, lambda cmds: sum("sim_bridge" in c for c in cmds) >= vehicles, timeout_s)
        proc.kill()
        proc.wait(5)
        assert _survivors(kids) == []
    finally:
        _kill_all(proc, kids)



# ------------------------------------------------------------------------------------------------ the helper
def test_a_tied_child_dies_with_its_parent_killed_and_one_started_too_late_exits(tmp_path):
    """The helper alone: a parent starts a long sleeper with proclife.preexec() and is SIGKILLed; a child told
    that its parent is a pid that is not its parent (the parent died before the request) exits at once."""
    parent_code = textwrap.dedent("""
        import subprocess, sys, time
        from companion import proclife
        p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True,
                             preexec_fn=proclife.preexec())
        print(p.pid, flush=True)
        time.sleep(60)
    """)
    parent = subprocess.Popen([sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True,
                              start_new_session=True)
    kids = [psutil.Process(int(parent.stdout.readline()))]
    try:
        parent.kill()
        parent.wait(5)
        assert _survivors(kids) == []
    finally:
        _kill_all(parent, kids)
    late = subprocess.run([sys.executable, "-c", "import os, time\nfrom companion import proclife\n"
                           "proclife.die_with_parent(os.getppid() + 1_000_000)\ntime.sleep(30)"],
                          timeout=20, capture_output=True)
    assert late.returncode == 1


# ------------------------------------------------------------------------------------------------ fly --sitl
def test_fly_sitl_killed_takes_its_vehicle_with_it(tmp_path):
    """``fly --sitl`` (lockstep) SIGKILLed in flight: its vehicle does not wait for step markers for ever."""
    err = tmp_path / "stderr.txt"
    proc = _start("fly", "--sitl", "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(tmp_path / "run"),
                  stderr=err)
    # the narration's first line: the vehicle answered
    _sigkill_leaves_nothing(proc, 1, 10.0, before_kill=lambda: _first_line(proc, "connected", err))


# ------------------------------------------------------------------------------------------------ evaluate
@pytest.mark.slow
def test_evaluate_killed_takes_its_workers_and_their_vehicles_with_it(tmp_path):
    """``evaluate`` (MAVLink mode, 2 workers, 4 missions so that both always fly) SIGKILLed while both workers
    fly: workers and vehicles go."""
    proc = _start("evaluate", "--n", "4", "--planners", "safe", "--workers", "2", "--mode", "mavlink",
                  "--timeout", "30", "--no-progress", "--out", str(tmp_path / "eval"), stderr=tmp_path / "stderr.txt")
    _sigkill_leaves_nothing(proc, 2, 60.0)


# ------------------------------------------------------------------------------------------------ replay --web
@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A tiny .rrd file (a few points), enough for the viewer to serve."""
    rr = pytest.importorskip("rerun")
    path = tmp_path_factory.mktemp("rec") / "recording.rrd"
    rec = rr.RecordingStream("slungpilot-test")
    rec.save(str(path))
    for k in range(10):
        rec.set_time("t", duration=0.1 * k)
        rec.log("points", rr.Points3D([[0.0, 0.0, 0.1 * k]]))
    rec.flush()
    del rec
    assert path.stat().st_size > 0
    return path


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_replay_web_stopped_stops_its_viewer(recording, sig, tmp_path):
    """``replay --web`` stopped by SIGTERM (it stops its viewer, exit 0) or SIGKILL: the viewer goes too."""
    err = tmp_path / "stderr.txt"
    proc = _start("replay", str(recording), "--web", "--port", "0", stderr=err)
    kids: list[psutil.Process] = []
    try:
        _first_line(proc, "replay of", err)  # printed once the viewer listens
        kids = _wait_for_descendants(proc, lambda cmds: any("--serve-web" in c for c in cmds), 10.0)
        proc.send_signal(sig)
        code = proc.wait(GONE_WITHIN_S)
        assert _survivors(kids) == []
        assert code == (0 if sig == signal.SIGTERM else -signal.SIGKILL)
    finally:
        _kill_all(proc, kids)


# ------------------------------------------------------------------------------------------------ fleet
@pytest.mark.slow
def test_fleet_killed_takes_its_companions_and_their_vehicles_with_it(tmp_path):
    """``fleet 2`` SIGKILLed while its pairs fly in real time: every companion and vehicle goes."""
    proc = _start("fleet", "2", "--rt-priority", "0", "--run-dir", str(tmp_path / "fleet"), stderr=tmp_path / "err.txt")
    _sigkill_leaves_nothing(proc, 2, 60.0)
