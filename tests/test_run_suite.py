"""The side-by-side runner for daily work (tests/run_suite.py): both phases at once, one status, stopped by SIGTERM with
nothing left running. Each case runs the real runner on a test of this file (real pytest processes)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import run_suite

pytestmark = pytest.mark.shares_cores  # the runner's own pytest processes, no deadline (conftest.py)

HERE = Path(__file__).resolve().parent
SLEEPER_ENV = "SLUNGPILOT_RUN_SUITE_SLEEPER"  # set: the sleeper writes its pid there, then sleeps


def test_the_sleeper_sleeps_only_when_asked():
    """A test of the runner's own (``-k sleeper``): idle in ordinary runs."""
    path = os.environ.get(SLEEPER_ENV)
    if path:
        Path(path).write_text(str(os.getpid()))
        time.sleep(120)


@pytest.mark.parametrize(("codes", "status"), [
    ({"serial": 0, "shared": 0}, 0),
    ({"serial": 5, "shared": 0}, 0),  # a phase that selects nothing passes while the other ran
    ({"serial": 5, "shared": 5}, 5),
    ({"serial": 1, "shared": 0}, 1),
    ({"serial": 0, "shared": 2}, 2),
])
def test_one_status_for_both_phases(codes, status):
    assert run_suite._status(codes) == status


def test_a_marker_expression_is_joined_to_each_phase_s_own():
    assert run_suite._split_markers(["-x", "-m", "not slow", "-k", "fly"]) == ("not slow", ["-x", "-k", "fly"])
    assert run_suite._split_markers(["-x"]) == (None, ["-x"])


def _runner(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    """The runner on this file only (collecting the whole suite would take each phase ~7 s), with ``args``."""
    return subprocess.Popen([sys.executable, str(HERE / "run_suite.py"), str(Path(__file__)), *args], cwd=HERE.parent,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, **(env or {})})


def test_both_phases_run_and_the_runner_says_so():
    r = _runner("-k", "the_sleeper_sleeps_only_when_asked", "-p", "no:randomly")
    out, _ = r.communicate(timeout=300)
    assert r.returncode == 0, out
    assert "===== serial phase: exit 5" in out and "===== shared phase: exit 0" in out, out  # serial: none selected
    assert "1 passed" in out and "run_suite: passed" in out, out


def _sleeping_run(tmp_path: Path, psutil) -> tuple[subprocess.Popen, list]:
    """The runner on the sleeper, once the sleeper sleeps; (the runner, [the sleeper, the phases still running])."""
    pid_file = tmp_path / "sleeper.pid"
    r = _runner("-k", "the_sleeper_sleeps_only_when_asked", env={SLEEPER_ENV: str(pid_file)})
    deadline = time.monotonic() + 120
    while not pid_file.exists() or not pid_file.read_text():
        assert time.monotonic() < deadline and r.poll() is None, "the sleeper never started"
        time.sleep(0.2)
    sleeper = psutil.Process(int(pid_file.read_text()))
    phases: dict = {}  # the phases still running: process -> command line
    for p in psutil.Process(r.pid).children():
        try:
            cmd = " ".join(p.cmdline())
        except psutil.Error:  # gone already: the serial phase selects nothing here and exits at once
            continue
        if "pytest" in cmd:
            phases[p] = cmd
    assert any("not serial" in cmd for cmd in phases.values()), phases  # the serial one selected nothing
    return r, [sleeper, *phases]


def test_sigterm_stops_both_phases_and_nothing_is_left(tmp_path):
    psutil = pytest.importorskip("psutil")
    r, started = _sleeping_run(tmp_path, psutil)
    r.send_signal(signal.SIGTERM)
    out, _ = r.communicate(timeout=90)
    assert r.returncode == 130 and "interrupted; both phases stopped" in out, out
    _, alive = psutil.wait_procs(started, timeout=10)
    assert not alive, alive


def test_sigkill_of_the_runner_leaves_nothing_running_5_s_later(tmp_path):
    """Killed, the runner runs no code: the kernel kills the background phase's pytest, and its xdist worker (the
    sleeper's) is interrupted as its pytest goes (tests/conftest.py)."""
    psutil = pytest.importorskip("psutil")
    r, started = _sleeping_run(tmp_path, psutil)
    r.kill()
    r.communicate(timeout=30)
    _, alive = psutil.wait_procs(started, timeout=5)
    assert not alive, alive
