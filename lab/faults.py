"""Fault scenarios against real processes: each starts the companion (``slungpilot fly``), the bundled vehicle
and whatever fault it needs (a kill signal, a fuzzer, a Zenoh flood, a lossy proxy), and returns the figures
the fault suite bounds (``tests/test_faults.py``) and ``slungpilot bench faults`` prints.

Everything runs on loopback with free ports. Scenarios write their run folders under the ``workdir`` given. The
harness (ports, processes, run folders): :mod:`lab.procs`; the scenarios on the vehicle's side of the link:
:mod:`lab.faults_vehicle`; the flooding Zenoh peer: :mod:`lab.zenoh_flooder`.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from companion import proclife
from lab.faults_vehicle import jitter
from lab.procs import (
    ROOT,
    Proc,
    companion_port,
    descent_from_tlog,
    done_wall,
    fly_argv,
    free_tcp_port,
    read_report,
    stop_helper,
    vehicle_port,
)


# ------------------------------------------------------------------------------------------------ scenarios
def vehicle_killed(workdir: Path, *, realtime: bool = False, after_s: float = 0.5) -> dict[str, Any]:
    """kill -9 the bundled vehicle mid-mission: the companion must end with ``link_lost`` within 2 s."""
    return _signal_the_vehicle(workdir / f"vehicle-killed-{'rt' if realtime else 'ls'}", signal.SIGKILL,
                               realtime=realtime, after_s=after_s)


def vehicle_paused(workdir: Path, *, after_s: float = 0.5) -> dict[str, Any]:
    """SIGSTOP the bundled vehicle mid-mission (lockstep) and leave it stopped: the companion must end with
    ``link_lost`` within 2 s, and its report must tell a vehicle that is there but silent (``T (stopped)``) from a
    dead one; the companion then stops it all the same."""
    return _signal_the_vehicle(workdir / "vehicle-paused", signal.SIGSTOP, realtime=False, after_s=after_s)


def _signal_the_vehicle(run_dir: Path, sig: int, *, realtime: bool, after_s: float) -> dict[str, Any]:
    """Fly the forest with the bundled vehicle, send it ``sig`` ``after_s`` into the mission, and return how the
    companion took it (:func:`_lost_vehicle_facts`)."""
    fly = Proc.start(fly_argv(run_dir, "--sitl", "--no-zenoh", *(["--realtime"] if realtime else [])))
    try:
        fly.wait_for("takeover → mission")
        time.sleep(after_s)
        (sim,) = fly.children()
        t_fault = time.monotonic()
        os.kill(sim, sig)
        code = fly.finish(60)
        t_exit = time.monotonic()
    finally:
        fly.kill_all()
    return _lost_vehicle_facts(run_dir, code, t_fault, t_exit)


def _lost_vehicle_facts(run_dir: Path, code: int, t_fault: float, t_exit: float) -> dict[str, Any]:
    rep = read_report(run_dir)
    done = done_wall(rep)
    return {"exit_code": code, "outcome": rep["outcome"], "final_phase": rep["final_phase"],
            "detect_s": None if done is None else done - t_fault, "exit_s": t_exit - t_fault,
            "detail": rep.get("outcome_detail"), "watchdog_since_rx": rep["loop"].get("watchdog_steps_since_rx"),
            "vehicle_at_stop": (rep.get("sitl_vehicle") or {}).get("at_stop"),
            "summary": (run_dir / "summary.txt").read_text()}


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


def fuzz(workdir: Path, *, n: int = 100_000, seed: int = 7) -> dict[str, Any]:
    """The forest in lockstep twice, the second time with ``n`` spoofed/mutated frames sent to the companion's
    port mid-flight from another socket: the flight must be bit-identical and the companion must not crash."""
    ref_dir, fz_dir = workdir / "fuzz-reference", workdir / "fuzz-attacked"
    ref = Proc.start(fly_argv(ref_dir, "--sitl", "--no-zenoh"))
    ref_code = ref.finish(180)
    fly = Proc.start(fly_argv(fz_dir, "--sitl", "--no-zenoh"))
    sent = 0
    try:
        port = companion_port(fly)
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
    vz_max, z_max = descent_from_tlog(run_dir / "flight.tlog")
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
    vz_max, z_max = descent_from_tlog(run_dir / "flight.tlog")
    times = {t["to"]: t["t_s"] for t in rep["transitions"]}
    return {"exit_code": code, "outcome": rep["outcome"], "detail": rep["outcome_detail"],
            "final_phase": rep["final_phase"], "states": [t["to"] for t in rep["transitions"]],
            "hold_at_s": times.get("hold"), "max_descent_mps": vz_max, "max_altitude_m": z_max,
            "collisions": rep["collisions"], "rejected_telemetry": rep["rejected_telemetry"]}


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
        flood_argv = [sys.executable, "-m", "lab.zenoh_flooder", "--connect", ep, "--rate-hz", str(rate_hz),
                      "--trunks", str(trunks), *(["--vary"] if vary else [])]
        flood = subprocess.Popen(flood_argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 preexec_fn=proclife.preexec())
        code = fly.finish(180)
    finally:
        flood_said = stop_helper(flood)
        hog_said = stop_helper(hog)
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
        veh_port, comp_port = vehicle_port(fly), companion_port(fly)
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
    "vehicle_paused": vehicle_paused,
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
