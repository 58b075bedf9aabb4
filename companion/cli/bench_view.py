"""``slungpilot bench view``: what the 3-D view's recording costs, on a synthetic flight fed tick by tick.

Feeds ``seconds`` of mission time at 250 Hz (a circle through the forest with a swinging payload and a live
trunk arriving half way) through :class:`companion.viz.flight.FlightView` into a ``recording.rrd`` in a temporary
folder, paced in real time and at 12× (as fast as a lockstep flight runs here). Prints the control thread's cost per
``on_tick`` (p50/p99/max, µs, wall clock around the call), the logging thread's CPU time, the whole process's
CPU time (Rerun's own native threads included) per second of flight, drops, and the recording's size per minute.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from companion.config import shipped_config
from companion.core.mission import load_mission
from companion.core.obstacles import Obstacle
from companion.estimation.estimate import Estimate
from companion.flight.core import Command


def synthetic_tick(t: float) -> tuple[Estimate, Command]:
    w = 0.3
    pos = np.array([5.0 * math.sin(w * t), 5.0 * (1 - math.cos(w * t)), -2.0])
    vel = np.array([5.0 * w * math.cos(w * t), 5.0 * w * math.sin(w * t), 0.0])
    eul = np.array([0.1 * math.sin(2 * t), 0.1 * math.cos(2 * t), w * t])
    sw = np.array([0.2 * math.sin(2.3 * t), 0.1 * math.cos(2.3 * t), 0.0, 0.0])
    est = Estimate(t, pos, vel, eul, np.zeros(3), sw, "cable_sensor")
    cmd = Command(t, np.array([1.0, 0, 0, 0]), 14.0, 0.45, eul * 1.1, pos + 0.1, vel, np.zeros(3), np.zeros(2),
                  np.zeros(2), 0.4, "swing", "cruise", np.zeros(3))
    return est, cmd


def run(seconds: float = 60.0, rate_hz: float = 250.0, speedup: float = 1.0) -> dict[str, Any]:
    """Fly the synthetic flight through the recording at ``speedup`` × real time (1: a real-time flight; a
    lockstep flight runs at ≈ 12× on this machine); returns the measured numbers."""
    from companion.viz.flight import RECORDING_FILE, open_flight_recording
    from companion.viz.viewer import optimize_recording

    mission = load_mission(shipped_config("missions/forest.toml"))
    live = Obstacle(6.0, 0.1, 0.3, source="slungpilot/1/obstacles/in/bench")
    app = SimpleNamespace(phase="mission", state=SimpleNamespace(payload_pos_ned_m=None),
                          obstacles_seen=tuple(mission.obstacles))
    n = int(seconds * rate_hz)
    ticks = [synthetic_tick(k / rate_hz) for k in range(n)]
    with tempfile.TemporaryDirectory() as tmp:
        cpu0, wall0 = time.process_time(), time.perf_counter()
        view = open_flight_recording(mission, Path(tmp))
        setup_cpu = time.process_time() - cpu0
        cost = np.empty(n)
        cpu1, wall1 = time.process_time(), time.perf_counter()
        for k, (est, cmd) in enumerate(ticks):
            if k == n // 2:
                app.obstacles_seen = (*mission.obstacles, live)
            if k % 50 == 0:
                delay = wall1 + k / (rate_hz * speedup) - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            s = time.perf_counter()
            view.on_tick(est, cmd, app)
            cost[k] = time.perf_counter() - s
        fed_wall = time.perf_counter() - wall1
        view.recorder.close()
        cpu = time.process_time() - cpu1
        wall = time.perf_counter() - wall1
        size = (Path(tmp) / RECORDING_FILE).stat().st_size
        w0 = time.perf_counter()
        optimize_recording(Path(tmp) / RECORDING_FILE)
        opt_wall = time.perf_counter() - w0
        size_opt = (Path(tmp) / RECORDING_FILE).stat().st_size
        st = view.stats()
    return {
        "flight_s": seconds, "ticks": n, "setup_cpu_s": setup_cpu, "setup_wall_s": wall1 - wall0,
        "on_tick_us_p50": float(np.percentile(cost, 50) * 1e6), "on_tick_us_p99": float(np.percentile(cost, 99) * 1e6),
        "on_tick_us_max": float(cost.max() * 1e6), "feed_wall_s": fed_wall, "total_wall_s": wall,
        "worker_cpu_s": st["worker_cpu_s"], "process_cpu_s": cpu, "dropped": st["dropped"],
        "frames_3d": st["frames_3d"], "bytes": size, "mb_per_min": size / 1e6 * 60.0 / seconds,
        "mb_per_min_optimized": size_opt / 1e6 * 60.0 / seconds, "optimize_wall_s": opt_wall,
    }


def print_bench(seconds: float) -> int:
    """``slungpilot bench view``: run in real time and at 12× (``--seconds`` of flight; 60 by default)."""
    print("slungpilot bench view: the 3-D view's recording fed a synthetic 250 Hz flight tick by tick")
    print("  on_tick = the control thread's cost per tick; process CPU includes Rerun's native threads")
    for speedup in (1.0, 12.0):
        r = run(seconds=seconds, speedup=speedup)
        print(f"  at {speedup:.0f}x real time: {r['flight_s']:.0f} s flight, {r['ticks']} ticks, "
              f"{r['frames_3d']} 3-D frames, dropped {r['dropped']}")
        print(f"    on_tick            p50 {r['on_tick_us_p50']:.1f} us, p99 {r['on_tick_us_p99']:.1f} us, "
              f"max {r['on_tick_us_max']:.0f} us")
        print(f"    logging thread CPU {r['worker_cpu_s'] / r['flight_s'] * 1e3:.1f} ms per second of flight")
        print(f"    process CPU        {r['process_cpu_s'] / r['flight_s'] * 1e3:.1f} ms per second of flight "
              f"(opening the recording: {r['setup_cpu_s'] * 1e3:.0f} ms)")
        print(f"    recording          {r['mb_per_min']:.2f} MB per minute as written, "
              f"{r['mb_per_min_optimized']:.2f} after rerun rrd optimize ({r['optimize_wall_s']:.1f} s)")
    return 0
