"""Ctrl-C in ``slungpilot evaluate`` and ``slungpilot experiments`` (issue 14), with real processes.

Each test starts the command in its own session (as a terminal would: the command leads its process group),
waits until at least one mission has finished, sends SIGINT (to the whole process group, as a terminal's Ctrl-C
does, or to the main process only), and checks: exit 130 within 5 s, a partial summary of the finished missions
in the usual files, and nothing left behind, neither in the session (pool workers) nor anywhere else (the
bundled vehicles run in sessions of their own: they are found by an environment tag every descendant inherits).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find leftover processes")

STOP_LIMIT_S = 5.0
ROOT = Path(__file__).resolve().parents[1]


def _tagged(tag: str) -> list[tuple[int, str]]:
    """Every live process whose environment carries ``tag`` (the command and all its descendants), as
    (pid, name and command line); zombies excluded (they hold no resources and their parent reaps them)."""
    out = []
    needle = f"SLUNGPILOT_TEST_TAG={tag}".encode()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if needle not in (d / "environ").read_bytes():
                continue
            stat = (d / "stat").read_text()
            if stat[stat.rindex(")") + 2] == "Z":
                continue
            name = stat[stat.index("(") + 1:stat.rindex(")")]  # a forked vehicle: its command line may be cut
            out.append((int(d.name), name + " " + (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(
                errors="replace")))
        except OSError:
            continue
    return out


def _in_session(sid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if int(fields[3]) == sid and fields[0] != "Z":  # state ppid pgrp session
                out.append(int(d.name))
    return out


class _Cmd:
    """The command in a new session with its stderr collected by a thread."""

    def __init__(self, argv: list[str]) -> None:
        self.tag = uuid.uuid4().hex
        env = dict(os.environ, SLUNGPILOT_TEST_TAG=self.tag, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen([sys.executable, "-m", "companion.cli", *argv], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, env=env, cwd=ROOT, start_new_session=True)
        self.err = b""
        self.out = b""
        self._t = [threading.Thread(target=self._pump, args=(s, n), daemon=True)
                   for s, n in ((self.proc.stderr, "err"), (self.proc.stdout, "out"))]
        for t in self._t:
            t.start()

    def _pump(self, stream, name: str) -> None:
        while chunk := stream.read1(4096):
            setattr(self, name, getattr(self, name) + chunk)

    def wait_for(self, text: str, timeout_s: float) -> None:
        t_end = time.monotonic() + timeout_s
        while text.encode() not in self.err:
            assert self.proc.poll() is None, f"exited early ({self.proc.returncode}): {self.err.decode()[-2000:]}"
            assert time.monotonic() < t_end, f"no {text!r} within {timeout_s} s: {self.err.decode()[-2000:]}"
            time.sleep(0.1)

    def interrupt(self, group: bool) -> float:
        """SIGINT, then the seconds until the command exited."""
        t0 = time.monotonic()
        if group:
            os.killpg(self.proc.pid, signal.SIGINT)
        else:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=30)
        finally:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
        dt = time.monotonic() - t0
        for t in self._t:
            t.join(5)
        return dt

    def leftovers(self) -> list:
        """What is left, after a moment for the kernel to reap (reparented children go to init)."""
        left: list = []
        for _ in range(20):
            left = _tagged(self.tag) + [(p, "session") for p in _in_session(self.proc.pid)]
            if not left:
                break
            time.sleep(0.1)
        return left

    def cleanup(self) -> None:
        for pid, _ in _tagged(self.tag):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _interrupt_evaluate(out: Path, *extra: str, wait_s: float = 120.0) -> tuple[_Cmd, float, list, list, dict]:
    """Start ``evaluate`` on six 12 m forests over MAVLink, Ctrl-C its process group once the first mission has
    finished and a vehicle flies: (command, seconds to stop, vehicles running at the time, processes left, the
    summary)."""
    cmd = _Cmd(["evaluate", "--n", "6", "--planners", "safe", "--mode", "mavlink", "--length", "12",
                "--out", str(out), *extra])
    try:
        cmd.wait_for("1/6", wait_s)
        time.sleep(0.5)  # the freed worker has started its next vehicle
        running = [c for _, c in _tagged(cmd.tag) if "sim_bridge" in c]
        dt = cmd.interrupt(group=True)
        left = cmd.leftovers()
    finally:
        cmd.cleanup()
    assert cmd.proc.returncode == 130, cmd.err.decode()[-3000:]
    assert dt < STOP_LIMIT_S
    assert running, "the test should interrupt while a bundled vehicle flies"
    assert left == [], left
    assert "Traceback" not in cmd.err.decode()
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] and s["missions_planned"] == 6 and 1 <= s["missions"] < 6
    return cmd, dt, running, left, s


@pytest.mark.slow
def test_evaluate_ctrl_c_to_the_process_group_stops_with_a_partial_summary(tmp_path):
    out = tmp_path / "ev"
    cmd, dt, running, _, s = _interrupt_evaluate(out, "--workers", "2")
    print(f"evaluate stopped {dt:.2f} s after SIGINT; vehicles running at the time: {len(running)}")
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert len(lines) == s["missions"] and all(r["class"] != "error" for r in lines)
    assert s["per_planner"]["safe"]["n"] == s["missions"]
    md = (out / "summary.md").read_text()
    assert f"interrupted after {s['missions']} of 6 missions" in md and "PARTIAL" in md
    assert md in cmd.out.decode()  # printed too
    assert f"interrupted after {s['missions']} of 6 missions" in cmd.err.decode()


@pytest.mark.slow
def test_experiments_ctrl_c_to_the_main_process_stops_with_a_partial_report(tmp_path):
    out = tmp_path / "exp"
    cmd = _Cmd(["experiments", "--quick", "--out", str(out)])
    try:
        cmd.wait_for("1/8", 120)  # --quick: 3 + 4 + 1 flights
        dt = cmd.interrupt(group=False)
        left = cmd.leftovers()
    finally:
        cmd.cleanup()
    print(f"experiments stopped {dt:.2f} s after SIGINT")
    assert cmd.proc.returncode == 130, cmd.err.decode()[-3000:]
    assert dt < STOP_LIMIT_S
    assert left == [], left
    res = json.loads((out / "experiments.json").read_text())
    done = {**res["group1"], **res["group2"], **res["group3"]}
    assert res["interrupted"] and res["flights_planned"] == 8 and 1 <= res["flights"] == len(done) < 8
    md = (out / "report.md").read_text()
    assert f"interrupted after {res['flights']} of 8 flights" in md
    for name in done:
        assert f"| {name} | " in md


@pytest.mark.slow
def test_evaluate_ctrl_c_with_a_local_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    _, dt, running, _, s = _interrupt_evaluate(tmp_path / "evc", "--workers", "2", "--cluster", "local",
                                               wait_s=150.0)
    print(f"evaluate --cluster local stopped {dt:.2f} s after SIGINT; vehicles running: {len(running)}")
    assert s["cluster"] == "local"


@pytest.mark.slow
def test_evaluate_ctrl_c_without_workers_drops_the_flight_it_cut_short(tmp_path):
    """--workers 1 flies in the command itself: a MAVLink flight takes the SIGINT (holds, lands, returns
    'aborted'); that flight is not counted, the finished ones are."""
    out = tmp_path / "ev1"
    _, dt, _, _, _ = _interrupt_evaluate(out, "--workers", "1")
    print(f"evaluate --workers 1 stopped {dt:.2f} s after SIGINT")
    lines = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert all(r["outcome"] != "aborted" for r in lines)
