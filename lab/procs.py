"""The fault and integration harness's plumbing: free loopback ports, a subprocess whose stderr is collected with
arrival times, the ``fly`` command line, and what a run folder or a ``-v`` log says (report, ports, figures)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion import proclife
from companion.core.mission import load_mission

ROOT = Path(__file__).resolve().parents[1]


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Proc:
    """A subprocess whose stderr lines are collected by a thread (with the monotonic time each arrived)."""

    proc: subprocess.Popen
    lines: list[tuple[float, str]] = field(default_factory=list)

    @classmethod
    def start(cls, argv: list[str], env: dict[str, str] | None = None, cwd: Path = ROOT) -> Proc:
        p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd,
                             env={**os.environ, **(env or {})}, preexec_fn=proclife.preexec())
        me = cls(p)
        threading.Thread(target=me._pump, daemon=True).start()
        return me

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append((time.monotonic(), line.rstrip("\n")))

    def wait_for(self, text: str, timeout_s: float = 120.0) -> float:
        """Monotonic time of the first stderr line containing ``text``; raises TimeoutError."""
        end = time.monotonic() + timeout_s
        i = 0
        while time.monotonic() < end:
            while i < len(self.lines):
                t, line = self.lines[i]
                i += 1
                if text in line:
                    return t
            if self.proc.poll() is not None and i >= len(self.lines):
                time.sleep(0.2)
                if i >= len(self.lines):
                    break
            time.sleep(0.01)
        tail = "\n".join(line for _, line in self.lines[-30:])
        raise TimeoutError(f"never saw {text!r} (exit {self.proc.poll()}); last lines:\n{tail}")

    def children(self) -> list[int]:
        """Process ids of the direct children (the bundled vehicle of ``fly --sitl``)."""
        pid = self.proc.pid
        try:
            return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
        except OSError:
            return []

    def finish(self, timeout_s: float = 120.0) -> int:
        """Wait for the exit code (kill after ``timeout_s``)."""
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait(10)

    def kill_all(self) -> None:
        """SIGKILL the process and its children (cleanup); nothing once it has been reaped: its PID may be another
        process's by then (PIDs wrap, at 32768 on the test VMs), and its children are no longer found by it."""
        if self.proc.poll() is not None:
            return
        for pid in [*self.children(), self.proc.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)

    @property
    def stderr(self) -> str:
        return "\n".join(line for _, line in self.lines)


def fly_argv(run_dir: Path, *args: str) -> list[str]:
    """``slungpilot -v fly`` with a run folder, no plots (faster), plus ``args``."""
    return [sys.executable, "-m", "companion.cli", "-v", "fly", "--no-plots", "--run-dir", str(run_dir), *args]


def read_report(run_dir: Path) -> dict[str, Any]:
    return json.loads((run_dir / "report.json").read_text())


def done_wall(rep: dict[str, Any]) -> float | None:
    for t in rep.get("transitions", []):
        if t["to"] == "done":
            return float(t["wall_s"])
    return None


def companion_port(fly: Proc) -> int:
    """The companion's UDP port, from the vehicle's command line in the ``-v`` log of ``fly --sitl``."""
    fly.wait_for("starting the bundled vehicle")
    for _, line in fly.lines:
        if "--onboard-remote" in line:
            return int(line.split("--onboard-remote")[1].split()[0].rsplit(":", 1)[1])
    raise RuntimeError("no --onboard-remote in the log")


def vehicle_port(fly: Proc) -> int:
    """The bundled vehicle's onboard port, from its command line in the ``-v`` log of ``fly --sitl``."""
    fly.wait_for("starting the bundled vehicle")
    for _, line in fly.lines:
        if "--onboard-port" in line:
            return int(line.split("--onboard-port")[1].split()[0])
    raise RuntimeError("no --onboard-port in the log")


def stop_helper(proc: subprocess.Popen | None) -> dict[str, Any] | None:
    """SIGINT a helper process of a scenario; returns the JSON object its last stdout line holds (its counts), or
    None if there was no process or it printed nothing."""
    if proc is None:
        return None
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return json.loads(out.strip().splitlines()[-1]) if out.strip() else None


def descent_from_tlog(tlog: Path) -> tuple[float, float]:
    """Fastest downward speed (m/s) and highest altitude (m above home) the vehicle reported."""
    from companion.mavlink_io.link import tlog_messages

    vz, z = 0.0, 0.0
    for _, m in tlog_messages(tlog):
        if m.get_type() == "LOCAL_POSITION_NED" and m.get_srcSystem() == 1:
            vz, z = max(vz, m.vz), max(z, -m.z)
    return vz, z


def flown_figures(run_dir: Path, rep: dict[str, Any]) -> dict[str, float | None]:
    """What a flight did while the companion flew its mission, from the run folder's log:

    - ``max_alt_error_m``: largest altitude error (m) from the mission altitude, from the moment the climb reached
      it to the end of the hold (arrival + the mission's hold_s, vehicle time) or, without an arrival, as long as
      the companion recorded a reference. Not the autopilot's landing after the hold: on a slow link the land mode
      is confirmed up to a second after the vehicle has started down, and those rows are not ours (they once made
      up the whole 0.25–0.45 m this figure read).
    - ``max_tilt_in_hold_rad``: largest tilt (rad) during the hold (None without an arrival): a steady hold tilts
      against the wind by a few hundredths, a loop out of margin cycles at the 0.6 rad tilt limit.
    """
    log = np.load(run_dir / "flight_log.npz")
    mission = load_mission(run_dir / "mission.toml")
    t = log["t_s"]
    z = log["pos_ned_m"][:, 2]
    goal_z = float(mission.goal_ned_m[2])
    reached = np.flatnonzero(z <= goal_z + 0.1)
    flown = np.zeros(len(z), dtype=bool)
    if reached.size:
        flown[reached[0]:] = True
    flown &= np.isfinite(log["ref_pos_ned_m"][:, 2])
    arrival = (rep.get("arrival") or {}).get("t_s")
    tilt = None
    if arrival is not None:
        hold_end = float(arrival) + mission.hold_s
        flown &= t <= hold_end
        e = log["euler_rad"][(t >= float(arrival)) & (t <= hold_end)]
        tilt = float(np.max(np.hypot(e[:, 0], e[:, 1]))) if e.size else None
    return {"max_alt_error_m": float(np.max(np.abs(z[flown] - goal_z))) if flown.any() else None,
            "max_tilt_in_hold_rad": tilt}
