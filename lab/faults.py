"""Fault scenarios against real processes: each starts the companion (``slungpilot fly``), the bundled vehicle
and whatever fault it needs (a kill signal, a fuzzer, a Zenoh flood, a lossy proxy), and returns the figures
the fault suite bounds (``tests/test_faults.py``) and ``slungpilot bench faults`` prints.

Everything runs on loopback with free ports. Scenarios write their run folders under the ``workdir`` given.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
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
        """SIGKILL the process and its children (cleanup)."""
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


def _done_wall(rep: dict[str, Any]) -> float | None:
    for t in rep.get("transitions", []):
        if t["to"] == "done":
            return float(t["wall_s"])
    return None


# ------------------------------------------------------------------------------------------------ scenarios
def vehicle_killed(workdir: Path, *, realtime: bool = False, after_s: float = 0.5) -> dict[str, Any]:
    """kill -9 the bundled vehicle mid-mission: the companion must end with ``link_lost`` within 2 s."""
    run_dir = workdir / f"vehicle-killed-{'rt' if realtime else 'ls'}"
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", *(["--realtime"] if realtime else [])))
    try:
        fly.wait_for("takeover → mission")
        time.sleep(after_s)
        (sim,) = fly.children()
        t_kill = time.monotonic()
        os.kill(sim, signal.SIGKILL)
        code = fly.finish(60)
        t_exit = time.monotonic()
    finally:
        fly.kill_all()
    rep = read_report(run_dir)
    done = _done_wall(rep)
    return {"exit_code": code, "outcome": rep["outcome"], "final_phase": rep["final_phase"],
            "detect_s": None if done is None else done - t_kill, "exit_s": t_exit - t_kill,
            "detail": rep.get("outcome_detail")}


def _mutations(rng: random.Random) -> list[bytes]:
    """Frames a local attacker would send: valid-CRC spoofs claiming to be the vehicle, and their mutations."""
    from pymavlink.dialects.v20 import common as mavlink2

    class _Buf:
        def __init__(self) -> None:
            self.frames: list[bytes] = []

        def write(self, b: bytes) -> None:
            self.frames.append(bytes(b))

    buf = _Buf()
    mav = mavlink2.MAVLink(buf, srcSystem=1, srcComponent=1)
    inf = float("inf")
    mav.heartbeat_send(2, 12, 129, (4 << 16) | (6 << 24), 4)  # "I am the vehicle, in AUTO.LAND"
    mav.attitude_send(10_000, 0.1, 0.0, inf, 0.0, 0.0, 0.0)  # yaw = inf (crashed the companion once)
    mav.attitude_send(10_000, float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0)
    mav.local_position_ned_send(10_000, 1e6, 0.0, -5.0, 0.0, 0.0, 0.0)
    mav.system_time_send(0, 3_000_000_000)  # a clock jump
    mav.command_ack_send(176, 0)
    mav.statustext_send(2, b"spoofed")
    base = buf.frames
    out = list(base)
    for _ in range(200):
        f = bytearray(rng.choice(base))
        for _ in range(rng.randint(1, 4)):
            f[rng.randrange(len(f))] = rng.randrange(256)
        out.append(bytes(f))
    out += [bytes(rng.randrange(256) for _ in range(rng.randint(1, 80))) for _ in range(50)]
    return out


def _companion_port(fly: Proc) -> int:
    """The companion's UDP port, from the vehicle's command line in the ``-v`` log of ``fly --sitl``."""
    fly.wait_for("starting the bundled vehicle")
    for _, line in fly.lines:
        if "--onboard-remote" in line:
            return int(line.split("--onboard-remote")[1].split()[0].rsplit(":", 1)[1])
    raise RuntimeError("no --onboard-remote in the log")


def fuzz(workdir: Path, *, n: int = 100_000, seed: int = 7) -> dict[str, Any]:
    """The forest in lockstep twice, the second time with ``n`` spoofed/mutated frames sent to the companion's
    port mid-flight from another socket: the flight must be bit-identical and the companion must not crash."""
    ref_dir, fz_dir = workdir / "fuzz-reference", workdir / "fuzz-attacked"
    ref = Proc.start(fly_argv(ref_dir, "--sitl", "--no-zenoh"))
    ref_code = ref.finish(180)
    fly = Proc.start(fly_argv(fz_dir, "--sitl", "--no-zenoh"))
    sent = 0
    try:
        port = _companion_port(fly)
        fly.wait_for("takeover → mission")
        frames = _mutations(random.Random(seed))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            rng = random.Random(seed)
            t0 = time.monotonic()
            while sent < n and fly.proc.poll() is None:
                try:
                    s.sendto(rng.choice(frames), ("127.0.0.1", port))
                    sent += 1
                except OSError:  # the companion's socket is gone (flight over)
                    break
                if sent % 2000 == 0:
                    time.sleep(0.005)  # spread over the flight rather than one burst the kernel drops
            fuzz_s = time.monotonic() - t0
        code = fly.finish(180)
    finally:
        fly.kill_all()
    a = np.load(ref_dir / "flight_log.npz")
    b = np.load(fz_dir / "flight_log.npz")
    same = all(np.array_equal(a[k], b[k], equal_nan=True) for k in a.files) and set(a.files) == set(b.files)
    rep = read_report(fz_dir)
    ref_rep = read_report(ref_dir)
    keys = ("time_to_goal_s", "max_swing_rad", "min_clearance_m", "collisions", "outcome")
    return {"sent": sent, "fuzz_s": fuzz_s, "exit_code": code, "reference_exit_code": ref_code,
            "identical_log": bool(same), "rejected": rep["link"]["rejected"],
            "metrics": {k: rep.get(k) for k in keys}, "reference_metrics": {k: ref_rep.get(k) for k in keys},
            "traceback": "Traceback" in fly.stderr}


def tick_exception(workdir: Path, *, at_s: float = 6.0) -> dict[str, Any]:
    """Every tick raises from ``at_s`` (vehicle time) on: hold, then land; never a fall."""
    run_dir = workdir / "tick-exception"
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh"), env={"SLUNGPILOT_INJECT_TICK_ERROR_AT_S": str(at_s)})
    code = fly.finish(180)
    rep = read_report(run_dir)
    vz_max, z_max = _descent_from_tlog(run_dir / "flight.tlog")
    return {"exit_code": code, "outcome": rep["outcome"], "final_phase": rep["final_phase"],
            "tick_errors": rep["loop"]["tick_errors"], "states": [t["to"] for t in rep["transitions"]],
            "max_descent_mps": vz_max, "max_altitude_m": z_max}


# Position SMC gains ~80x too high with a 30x thinner boundary layer: the loop chatters, the payload is pumped
# and the vehicle is thrown off its reference (a mis-tuned controller on a real vehicle)
UNSTABLE_GAINS = """[smc]
c = [20.0, 20.0, 2.0]
k = [200.0, 200.0, 3.0]
k_sat = [20.0, 20.0, 0.8]
boundary = [0.01, 0.01, 0.3]
"""


def diverged(workdir: Path, *, realtime: bool = False) -> dict[str, Any]:
    """The companion's own loop unstable (absurd position gains): more than 2 m from the reference for 1 s ->
    outcome ``diverged``, our setpoints stop, the vehicle's hold, then its landing; never a fall or a flyaway."""
    run_dir = workdir / ("diverged" + ("-rt" if realtime else ""))
    gains = workdir / "unstable-gains.toml"
    gains.write_text(UNSTABLE_GAINS)
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", "--gains", str(gains),
                              *(["--realtime"] if realtime else [])))
    code = fly.finish(180)
    rep = read_report(run_dir)
    vz_max, z_max = _descent_from_tlog(run_dir / "flight.tlog")
    times = {t["to"]: t["t_s"] for t in rep["transitions"]}
    return {"exit_code": code, "outcome": rep["outcome"], "detail": rep["outcome_detail"],
            "final_phase": rep["final_phase"], "states": [t["to"] for t in rep["transitions"]],
            "hold_at_s": times.get("hold"), "max_descent_mps": vz_max, "max_altitude_m": z_max,
            "collisions": rep["collisions"], "rejected_telemetry": rep["rejected_telemetry"]}


def _descent_from_tlog(tlog: Path) -> tuple[float, float]:
    """Fastest downward speed (m/s) and highest altitude (m above home) the vehicle reported."""
    from companion.mavlink_io.link import tlog_messages

    vz, z = 0.0, 0.0
    for _, m in tlog_messages(tlog):
        if m.get_type() == "LOCAL_POSITION_NED" and m.get_srcSystem() == 1:
            vz, z = max(vz, m.vz), max(z, -m.z)
    return vz, z


def companion_killed_report(workdir: Path, *, after_s: float = 3.0) -> dict[str, Any]:
    """kill -9 the companion mid-flight (real time), then ``slungpilot report RUN_DIR`` rebuilds the report
    from the journal: at most a second of flight may be missing."""
    run_dir = workdir / "companion-killed"
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", "--realtime"))
    try:
        t_mission = fly.wait_for("takeover → mission")
        time.sleep(after_s)
        kids = fly.children()
        t_kill = time.monotonic()
        fly.proc.kill()
        fly.proc.wait(10)
        for k in kids:  # the vehicle dies with its companion (companion.proclife); this is a second check
            with contextlib.suppress(ProcessLookupError):
                os.kill(k, signal.SIGKILL)
    finally:
        fly.kill_all()
    had_report = (run_dir / "report.json").exists()
    rb = subprocess.run([sys.executable, "-m", "companion.cli", "report", str(run_dir), "--no-plots"],
                        capture_output=True, text=True, timeout=120, cwd=ROOT)
    rep = read_report(run_dir)
    flown_s = t_kill - t_mission
    rows = rep.get("journal_rows", 0)
    return {"report_before_rebuild": had_report, "rebuild_exit_code": rb.returncode, "outcome": rep["outcome"],
            "reached_goal": rep["reached_goal"], "journal_rows": rows, "flown_s": flown_s,
            "lost_s": max(0.0, flown_s - rows / 250.0), "stderr": rb.stderr[-500:]}


def companion_paused(workdir: Path, *, pause_s: float = 0.7, after_s: float = 3.0) -> dict[str, Any]:
    """SIGSTOP the companion mid-flight (real time) for ``pause_s``, then SIGCONT, as a VM pause or a swapped-out
    process would: the vehicle went on streaming into the companion's socket, so the silence was the companion's
    own. The flight must go on (not ``link_lost``), and the report counts the deaf spell."""
    run_dir = workdir / "companion-paused"
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", "--realtime"))
    try:
        fly.wait_for("takeover → mission")
        time.sleep(after_s)
        os.kill(fly.proc.pid, signal.SIGSTOP)
        time.sleep(pause_s)
        os.kill(fly.proc.pid, signal.SIGCONT)
        code = fly.finish(120)
    finally:
        fly.kill_all()
    rep = read_report(run_dir)
    loop = rep["loop"]
    return {"exit_code": code, "outcome": rep["outcome"], "outcome_detail": rep.get("outcome_detail"),
            "reached_goal": rep["reached_goal"], "collisions": rep["collisions"], "max_swing_rad": rep["max_swing_rad"],
            "jitter_ms_max": loop["jitter_ms_max"], "deaf_spells": loop["deaf_spells"],
            "deaf_s_max": loop["deaf_s_max"], "stall_traces": loop["stall_traces"]}


def zenoh_flood(workdir: Path, *, rate_hz: float = 1000.0, trunks: int = 256, rt_priority: int = 0,
                vary: bool = False, disk_hog: bool = False) -> dict[str, Any]:
    """A local Zenoh peer floods valid obstacle lists (far-away trunks) at ``rate_hz`` during a real-time
    forest flight: the mission must complete with the tick's p99 under 1 ms. ``rt_priority`` > 0: fly with
    ``--rt-priority``; ``vary``: every list differs (no list can be adopted again unparsed); ``disk_hog``: with
    ``lab.disk_hog`` writing to the same disk meanwhile (:func:`disk_storm`)."""
    run_dir = workdir / ("zenoh-flood" + ("-vary" if vary else "") + (f"-rt{rt_priority}" if rt_priority else "")
                         + ("-disk-hog" if disk_hog else ""))
    port = free_tcp_port()
    ep = f"tcp/127.0.0.1:{port}"
    extra = ["--rt-priority", str(rt_priority)] if rt_priority else []
    hog = None
    if disk_hog:
        hog = subprocess.Popen([sys.executable, "-m", "lab.disk_hog", "--dir", str(workdir / "disk-hog")], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=proclife.preexec())
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--realtime", "--zenoh-listen", ep, *extra))
    flood = None
    try:
        fly.wait_for("zenoh: publishing under")
        flood_argv = [sys.executable, "-m", "lab.faults", "flood", "--connect", ep, "--rate-hz", str(rate_hz),
                      "--trunks", str(trunks), *(["--vary"] if vary else [])]
        flood = subprocess.Popen(flood_argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 preexec_fn=proclife.preexec())
        code = fly.finish(180)
    finally:
        flood_said = _stop(flood)
        hog_said = _stop(hog)
        fly.kill_all()
    sent = (flood_said or {}).get("sent", 0)
    rep = read_report(run_dir)
    return {"hog": hog_said,
            "journal": rep.get("journal"),
            "exit_code": code, "outcome": rep["outcome"], "reached_goal": rep["reached_goal"], "flood_sent": sent,
            "tick_ms_p99": rep["loop"]["tick_ms_p99"], "tick_ms_max": rep["loop"]["tick_ms_max"],
            "tick_cpu_ms_p99": rep["loop"]["tick_cpu_ms_p99"], "ingest_ms_p99": rep["loop"]["ingest_ms_p99"],
            "preempted_ticks": rep["loop"]["preempted_ticks"], "scheduling": rep["loop"]["scheduling"],
            "jitter_ms_p99": rep["loop"]["jitter_ms_p99"], "jitter_ms_max": rep["loop"]["jitter_ms_max"],
            "deaf_spells": rep["loop"]["deaf_spells"], "deaf_s_max": rep["loop"]["deaf_s_max"],
            "stalls_where": [t["ours"] or t["where"] for t in rep["loop"]["stall_traces"]],
            "late_ticks": rep["loop"]["late_ticks"], "max_swing_rad": rep["max_swing_rad"],
            "collisions": rep["collisions"], "zenoh": rep.get("zenoh", {}),
            "telemetry_age_ms_p99": rep["link"]["telemetry_age_ms_p99"]}


def disk_storm(workdir: Path) -> dict[str, Any]:
    """The 1 kHz Zenoh flood flight (:func:`zenoh_flood`) while another process keeps the same disk busy
    (``lab.disk_hog``: the venv's site-packages copied, synced and removed, round after round, as a ``git clone``
    or an install would). Before the journal's and the tlog's writes moved to threads of their own, the journal's
    file rename on the event loop waited in the kernel under such load and held the control loop for up to 0.8 s
    (2 of 5 flights with this hog on 2026-12-02; a ``git clone`` in a loop did it in 4 of 5). Reports the longest
    stall, where any stall was (``stalls_where``) and the journal's lag."""
    return zenoh_flood(workdir, disk_hog=True)


def _stop(proc: subprocess.Popen | None) -> dict[str, Any] | None:
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


def flood_main(argv: list[str]) -> int:
    """``python -m lab.faults flood``: put obstacle lists as fast as asked until SIGINT; prints the count."""
    import argparse

    import zenoh

    p = argparse.ArgumentParser(prog="python -m lab.faults flood")
    p.add_argument("--connect", required=True)
    p.add_argument("--rate-hz", type=float, default=1000.0)
    p.add_argument("--trunks", type=int, default=256, help="far-away trunks per list (without --payload)")
    p.add_argument("--payload", default=None, help="the JSON to put instead of far-away trunks")
    p.add_argument("--key", default="slungpilot/1/obstacles/in/flood")
    p.add_argument("--vary", action="store_true", help="the first trunk moves by 1 µm per list: every list differs")
    p.add_argument("--user", default=None, help="log in with this user (Zenoh usrpwd authentication) ...")
    p.add_argument("--password", default=None, help="... and password; client mode")
    a = p.parse_args(argv)
    payload = (a.payload.encode() if a.payload is not None else
               json.dumps({"obstacles": [{"x_m": 200.0 + 2.0 * i, "y_m": 150.0, "radius_m": 0.3}
                                         for i in range(a.trunks - (1 if a.vary else 0))]}).encode())
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"client"' if a.user else '"peer"')
    cfg.insert_json5("connect/endpoints", json.dumps([a.connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if a.user:
        cfg.insert_json5("transport/auth/usrpwd", json.dumps({"user": a.user, "password": a.password or ""}))
        cfg.insert_json5("connect/timeout_ms", "5000")  # a router still starting: keep trying for 5 s
        cfg.insert_json5("connect/retry", json.dumps({"period_init_ms": 250, "period_max_ms": 1000}))
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    sent = 0
    try:
        session = zenoh.open(cfg)
    except Exception as exc:  # e.g. the router refused our credentials
        print(json.dumps({"sent": 0, "error": str(exc)}), flush=True)
        return 3
    print("flooding", file=sys.stderr, flush=True)
    with session as s:
        pub = s.declare_publisher(a.key)
        period = 1.0 / a.rate_hz
        t_next = time.monotonic()
        while not stop:
            if a.vary and a.payload is None:
                head = json.dumps({"x_m": 100.0 + 1e-6 * sent, "y_m": 150.0, "radius_m": 0.3}).encode()
                pub.put(payload[:len(b'{"obstacles": [')] + head + b", " + payload[len(b'{"obstacles": ['):])
            else:
                pub.put(payload)
            sent += 1
            t_next += period
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    print(json.dumps({"sent": sent}), flush=True)
    return 0


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


def jitter(workdir: Path, *, delay_ms: float = 50.0, jitter_ms: float = 25.0, drop: float = 0.0,
           vehicle: str = "bundled") -> dict[str, Any]:
    """The forest in real time through a proxy that delays each datagram by ``delay ± jitter`` (reordering
    them): the altitude must stay within 0.5 m of the mission's and the outcome must be honest. ``vehicle``
    ``ardupilot``: ArduCopter SITL with its payload (``forest_arducopter_sitl``) instead of the bundled vehicle."""
    from lab.udp_proxy import _addr  # noqa: F401  (the proxy runs as its own process; imported to fail early)

    run_dir = workdir / (f"jitter-{delay_ms:g}-{jitter_ms:g}" + ("" if vehicle == "bundled" else f"-{vehicle}"))
    veh_port, vside, comp_port = free_udp_port(), free_udp_port(), free_udp_port()
    # the vehicle sends to the proxy's vehicle side (ArduCopter dials it from an ephemeral port)
    sim, extra = _start_vehicle(vehicle, vside, 0, workdir, onboard_port=veh_port)
    if vehicle == "ardupilot":
        extra = [*extra, "--mission", "forest_arducopter_sitl", "--ready-timeout", "120"]
    proxy = subprocess.Popen([sys.executable, "-m", "lab.udp_proxy", "--vehicle",
                              f"127.0.0.1:{veh_port}" if vehicle == "bundled" else "first",
                              "--companion", f"127.0.0.1:{comp_port}", "--listen-vehicle-side", str(vside),
                              "--delay-ms", str(delay_ms), "--jitter-ms", str(jitter_ms), "--drop", str(drop)],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                             preexec_fn=proclife.preexec())
    fly = None
    try:
        assert proxy.stdout is not None
        if not proxy.stdout.readline().startswith("PROXY"):
            raise RuntimeError("proxy did not start")
        fly = Proc.start(fly_argv(run_dir, "--connect", f"udpin://127.0.0.1:{comp_port}", "--no-zenoh", *extra))
        code = fly.finish(240 if vehicle == "bundled" else 400)
    finally:
        for p in (sim, proxy):
            p.send_signal(signal.SIGTERM)
        counts = {}
        try:
            out, _ = proxy.communicate(timeout=10)
            counts = json.loads(out.strip().splitlines()[-1])
        except (subprocess.TimeoutExpired, ValueError, IndexError):
            proxy.kill()
        sim.wait(10)
        if fly is not None:
            fly.kill_all()
    rep = read_report(run_dir)
    return {"exit_code": code, "outcome": rep["outcome"], "reached_goal": rep["reached_goal"],
            "goal_visited": rep.get("goal_visited"), "time_to_goal_s": rep["time_to_goal_s"],
            **flown_figures(run_dir, rep),
            "max_swing_rad": rep["max_swing_rad"], "collisions": rep["collisions"], "proxy": counts,
            "link": rep["link"], "loop_lag": rep.get("loop_lag")}


def _start_vehicle(kind: str, comp_port: int, instance: int, workdir: Path,
                   onboard_port: int | None = None) -> tuple[subprocess.Popen, list[str]]:
    """A real-time vehicle sending its onboard link to ``comp_port``: the bundled one (its onboard link bound to
    ``onboard_port``, any free one by default; returned once it says it is ready), PX4 SIH (port 14540+I) or
    ArduCopter SITL (:mod:`lab.sitl_external`); and the ``fly`` options it needs."""
    if kind == "bundled":
        argv = [sys.executable, "-m", "sim_bridge", "--onboard-port", str(onboard_port or free_udp_port()),
                "--onboard-remote", f"127.0.0.1:{comp_port}", "--gcs-port", str(free_udp_port()), "--gcs-remote",
                f"127.0.0.1:{free_udp_port()}"]
        sim = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               start_new_session=True, preexec_fn=proclife.preexec())
        assert sim.stdout is not None
        if not sim.stdout.readline().startswith("SITL READY"):
            sim.kill()
            raise RuntimeError("the bundled vehicle did not start")
        return sim, ["--profile", "bundled"]
    from lab import sitl_external

    if kind == "px4":
        return sitl_external.start_px4_sih(workdir, instance), []
    return sitl_external.start_arducopter(workdir, comp_port, instance=0), []


def companion_killed_vehicle_failsafe(workdir: Path, *, vehicle: str = "bundled", after_s: float = 3.0,
                                      watch_s: float = 60.0, instance: int = 6) -> dict[str, Any]:
    """kill -9 the companion while the vehicle flies its setpoints (real time), then watch the vehicle from the
    companion's port: how long until it leaves offboard, into which mode, and whether it lands and disarms."""
    from pymavlink.dialects.v20 import common as mavlink2

    from companion.autopilots.profile import profile_for_autopilot
    from companion.estimation.vehicle_state import px4_mode_name

    comp_port = 14540 + instance if vehicle == "px4" else free_udp_port()
    veh, extra = _start_vehicle(vehicle, comp_port, instance, workdir)
    run_dir = workdir / f"companion-killed-{vehicle}"
    fly = Proc.start(fly_argv(run_dir, "--connect", f"udpin://127.0.0.1:{comp_port}", "--no-zenoh",
                              "--ready-timeout", "120", *extra))
    events: list[tuple[float, str]] = []
    try:
        fly.wait_for("→ mission", timeout_s=180)
        time.sleep(after_s)
        fly.proc.kill()
        t_kill = time.monotonic()
        fly.proc.wait(10)
        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        last_mode, armed, z_min, vz_max = None, True, 0.0, 0.0
        t_land = t_disarm = None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", comp_port))
            s.settimeout(0.2)
            while time.monotonic() - t_kill < watch_s:
                try:
                    data, _ = s.recvfrom(65535)
                except TimeoutError:
                    continue
                for m in mav.parse_buffer(data) or []:
                    t = m.get_type()
                    if t == "HEARTBEAT" and m.autopilot != 8 and m.get_srcComponent() == 1:
                        fam = profile_for_autopilot(m.autopilot).family
                        name = px4_mode_name(m.custom_mode) if fam.name == "px4" else f"mode {m.custom_mode}"
                        if name != last_mode:
                            events.append((time.monotonic() - t_kill, f"{name} ({fam.mode_class(m.custom_mode)})"))
                            last_mode = name
                        was, armed = armed, bool(m.base_mode & 128)
                        if was and not armed and t_disarm is None:
                            t_disarm = time.monotonic() - t_kill
                    elif t == "EXTENDED_SYS_STATE" and m.landed_state == 1 and t_land is None:
                        t_land = time.monotonic() - t_kill
                    elif t == "LOCAL_POSITION_NED" and m.get_srcComponent() == 1:
                        z_min, vz_max = min(z_min, m.z), max(vz_max, m.vz)
                if t_disarm is not None:
                    break
    finally:
        fly.kill_all()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(veh.pid, signal.SIGTERM)
        try:
            veh.wait(15)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(veh.pid, signal.SIGKILL)
    leave = next((t for t, name in events if not name.endswith("(offboard)")), None)
    return {"vehicle": vehicle, "mode_changes_s": events, "left_offboard_s": leave, "landed_s": t_land,
            "disarmed_s": t_disarm, "max_descent_mps": vz_max, "max_altitude_m": -z_min}


def _vehicle_port(fly: Proc) -> int:
    """The bundled vehicle's onboard port, from its command line in the ``-v`` log of ``fly --sitl``."""
    fly.wait_for("starting the bundled vehicle")
    for _, line in fly.lines:
        if "--onboard-port" in line:
            return int(line.split("--onboard-port")[1].split()[0])
    raise RuntimeError("no --onboard-port in the log")


def signed_forced_disarm(workdir: Path, *, n: int = 20) -> dict[str, Any]:
    """With MAVLink signing on both ends, a local attacker sends forced disarms to the vehicle and spoofed
    telemetry to the companion, unsigned and signed with a wrong key, mid-flight: all must be dropped and counted,
    and the flight must go on as if nothing happened."""
    from pymavlink.dialects.v20 import common as mavlink2

    from companion.mavlink_io import signing

    key_file = workdir / "signing.key"
    if not key_file.exists():
        signing.write_new_key_file(key_file)
    run_dir = workdir / "signed-forced-disarm"
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", "--no-recording", "--signing-key", str(key_file)))
    try:
        veh_port, comp_port = _vehicle_port(fly), _companion_port(fly)
        fly.wait_for("takeover → mission")

        class _Out:
            def __init__(self) -> None:
                self.frames: list[bytes] = []

            def write(self, b: bytes) -> None:
                self.frames.append(bytes(b))

        out = _Out()
        mav = mavlink2.MAVLink(out, srcSystem=255, srcComponent=190)
        spoof = mavlink2.MAVLink(out, srcSystem=1, srcComponent=1)
        wrong = signing.LinkSigner(bytes(range(32)), link_id=7)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(n):
                out.frames.clear()
                mav.command_long_send(1, 1, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0, 0, 0)
                spoof.heartbeat_send(2, 12, 0, 0, 3)  # "disarmed, in another mode"
                cmd, hb = out.frames
                s.sendto(cmd, ("127.0.0.1", veh_port))
                s.sendto(wrong.sign(cmd, mavlink2.MAVLink_command_long_message.crc_extra), ("127.0.0.1", veh_port))
                s.sendto(hb, ("127.0.0.1", comp_port))
                s.sendto(wrong.sign(hb, mavlink2.MAVLink_heartbeat_message.crc_extra), ("127.0.0.1", comp_port))
                time.sleep(0.01)
        code = fly.finish(180)
    finally:
        fly.kill_all()
    rep = read_report(run_dir)
    sitl_log = (run_dir / "sitl.log").read_text(errors="replace") if (run_dir / "sitl.log").exists() else ""
    return {"exit_code": code, "outcome": rep["outcome"], "final_phase": rep["final_phase"],
            "companion_rejected": rep["link"]["rejected"], "disarmed_in_flight": "Disarmed (forced)" in sitl_log,
            "vehicle_rejected_unsigned": "rejected input (unsigned" in sitl_log,
            "vehicle_rejected_bad_signature": "rejected input (bad_signature" in sitl_log, "sent": 4 * n}


SCENARIOS = {
    "vehicle_killed": vehicle_killed,
    "fuzz": fuzz,
    "tick_exception": tick_exception,
    "diverged": diverged,
    "companion_killed_report": companion_killed_report,
    "companion_paused": companion_paused,
    "zenoh_flood": zenoh_flood,
    # the same flood, the control loops SCHED_FIFO (fly --rt-priority): what the kernel's preemption costs
    "zenoh_flood_rt": lambda workdir: zenoh_flood(workdir, rt_priority=10),
    # every list different: none can be adopted again unparsed (normal scheduling, and SCHED_FIFO)
    "zenoh_flood_varying": lambda workdir: zenoh_flood(workdir, vary=True),
    "zenoh_flood_varying_rt": lambda workdir: zenoh_flood(workdir, rt_priority=10, vary=True),
    "jitter": jitter,
    "signed_forced_disarm": signed_forced_disarm,
    "disk_storm": disk_storm,
}


def run_fault_bench(workdir: Path, names: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """Run the scenarios (all by default) and return their figures by name."""
    out = {}
    for name in names or list(SCENARIOS):
        out[name] = SCENARIOS[name](workdir)
    return out


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "flood":
        sys.exit(flood_main(sys.argv[2:]))
    print("usage: python -m lab.faults flood --connect ENDPOINT [--rate-hz R] [--trunks N]", file=sys.stderr)
    sys.exit(2)
