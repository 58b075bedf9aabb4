"""``slungpilot bench view``: what the 3-D view's recording costs, on a synthetic flight fed tick by tick.

Feeds ``seconds`` of mission time at 250 Hz (a circle through the forest with a swinging payload and a live
trunk arriving half way) through :class:`companion.viz.flight.FlightView` into a ``recording.rrd`` in a temporary
folder, as fast as it can or paced in real time. Prints the control thread's cost per ``on_tick`` (p50/p99/max,
µs, wall clock around the call), the logging thread's CPU time, the whole process's CPU time (Rerun's own
native threads included) per second of flight, drops, and the recording's size per minute of flight.
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


def run(seconds: float = 60.0, rate_hz: float = 250.0, realtime: bool = False) -> dict[str, Any]:
    """Fly the synthetic flight through the recording; returns the measured numbers."""
    from companion.viz.flight import RECORDING_FILE, open_flight_recording

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
            if realtime:
                delay = wall1 + k / rate_hz - time.perf_counter()
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
        st = view.stats()
    return {
        "flight_s": seconds, "ticks": n, "setup_cpu_s": setup_cpu, "setup_wall_s": wall1 - wall0,
        "on_tick_us_p50": float(np.percentile(cost, 50) * 1e6), "on_tick_us_p99": float(np.percentile(cost, 99) * 1e6),
        "on_tick_us_max": float(cost.max() * 1e6), "feed_wall_s": fed_wall, "total_wall_s": wall,
        "worker_cpu_s": st["worker_cpu_s"], "process_cpu_s": cpu, "dropped": st["dropped"],
        "frames_3d": st["frames_3d"], "bytes": size, "mb_per_min": size / 1e6 * 60.0 / seconds,
    }
