"""Fault scenarios about the vehicle's side of the link: a lossy, late, reordering proxy between companion and
vehicle (:func:`jitter`), and the companion killed while the vehicle flies on its own failsafe
(:func:`companion_killed_vehicle_failsafe`); bundled, PX4 SIH or ArduCopter SITL vehicles. Harness: :mod:`lab.procs`."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from companion import proclife
from lab.procs import ROOT, Proc, flown_figures, fly_argv, free_udp_port, read_report


def jitter(workdir: Path, *, delay_ms: float = 50.0, jitter_ms: float = 25.0, drop: float = 0.0,
           vehicle: str = "bundled", air_mode: int | None = None) -> dict[str, Any]:
    """The forest in real time through a proxy that delays each datagram by ``delay ± jitter`` (reordering
    them): the altitude must stay within 0.5 m of the mission's and the outcome must be honest. ``vehicle``
    ``ardupilot``: ArduCopter SITL with its payload (``forest_arducopter_sitl``) instead of the bundled vehicle.
    ``air_mode``: the bundled vehicle's ``MC_AIRMODE`` (``sitl --airmode``; None: its default, 2)."""
    from lab.udp_proxy import _addr  # noqa: F401  (the proxy runs as its own process; imported to fail early)

    run_dir = workdir / (f"jitter-{delay_ms:g}-{jitter_ms:g}" + ("" if vehicle == "bundled" else f"-{vehicle}"))
    veh_port, vside, comp_port = free_udp_port(), free_udp_port(), free_udp_port()
    # the vehicle sends to the proxy's vehicle side (ArduCopter dials it from an ephemeral port)
    sim, extra = _start_vehicle(vehicle, vside, 0, workdir, onboard_port=veh_port,
                                vehicle_args=() if air_mode is None else ("--airmode", str(air_mode)))
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


def _start_vehicle(kind: str, comp_port: int, instance: int, workdir: Path, onboard_port: int | None = None,
                   vehicle_args: tuple[str, ...] = ()) -> tuple[subprocess.Popen, list[str]]:
    """A real-time vehicle sending its onboard link to ``comp_port``: the bundled one (its onboard link bound to
    ``onboard_port``, any free one by default; returned once it says it is ready), PX4 SIH (port 14540+I) or
    ArduCopter SITL (:mod:`lab.sitl_external`); and the ``fly`` options it needs. ``vehicle_args``: more
    ``sitl`` options for the bundled one."""
    if kind == "bundled":
        argv = [sys.executable, "-m", "sim_bridge", "--onboard-port", str(onboard_port or free_udp_port()),
                "--onboard-remote", f"127.0.0.1:{comp_port}", "--gcs-port", str(free_udp_port()), "--gcs-remote",
                f"127.0.0.1:{free_udp_port()}", *vehicle_args]
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


def _watch_vehicle(comp_port: int, t_kill: float, watch_s: float,
                   events: list[tuple[float, str]]) -> tuple[float | None, float | None, float, float]:
    """Listen on the companion's port for up to ``watch_s`` (s) after ``t_kill`` (monotonic s), or until the
    vehicle disarms: its mode changes go to ``events`` (s after the kill, name and class); returns (landed s,
    disarmed s after the kill, lowest z m NED, fastest descent m/s)."""
    from pymavlink.dialects.v20 import common as mavlink2

    from companion.autopilots.profile import profile_for_autopilot
    from companion.estimation.vehicle_state import px4_mode_name

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
    return t_land, t_disarm, z_min, vz_max


def _stop_vehicle(veh: subprocess.Popen) -> None:
    """SIGTERM the vehicle's process group; SIGKILL it when it has not ended within 15 s."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(veh.pid, signal.SIGTERM)
    try:
        veh.wait(15)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(veh.pid, signal.SIGKILL)


def companion_killed_vehicle_failsafe(workdir: Path, *, vehicle: str = "bundled", after_s: float = 3.0,
                                      watch_s: float = 60.0, instance: int = 6) -> dict[str, Any]:
    """kill -9 the companion while the vehicle flies its setpoints (real time), then watch the vehicle from the
    companion's port: how long until it leaves offboard, into which mode, and whether it lands and disarms."""
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
        t_land, t_disarm, z_min, vz_max = _watch_vehicle(comp_port, t_kill, watch_s, events)
    finally:
        fly.kill_all()
        _stop_vehicle(veh)
    leave = next((t for t, name in events if not name.endswith("(offboard)")), None)
    return {"vehicle": vehicle, "mode_changes_s": events, "left_offboard_s": leave, "landed_s": t_land,
            "disarmed_s": t_disarm, "max_descent_mps": vz_max, "max_altitude_m": -z_min}
