"""`slungpilot bench fly`: the forest mission end to end in lockstep — real-time factor and tick times."""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

from companion.cli.fly import fly_async, mission_from_args
from companion.cli.fly_args import DEFAULT_MISSION, add_fly_arguments


def run(mission_path: Path = DEFAULT_MISSION, repeats: int = 1) -> list[dict[str, float]]:
    """Fly the mission ``repeats`` times against the bundled vehicle (lockstep); one dict of numbers per run."""
    out = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            p = argparse.ArgumentParser()
            add_fly_arguments(p)
            args = p.parse_args(["--sitl", "--no-zenoh", "--mission", str(mission_path), "--run-dir", tmp,
                                 "--no-plots"])
            mission = mission_from_args(args)
            t0 = time.monotonic()
            res = asyncio.run(fly_async(args, mission))
            wall_total = time.monotonic() - t0
            rep = res.report
            loop = rep["loop"]
            sim = float(rep["sim_time_s"])  # the mission the companion flew (climb, cruise, hold)
            out.append({
                "sim_time_s": sim,
                "wall_time_s": wall_total,
                "realtime_factor": sim / wall_total,
                "flight_realtime_factor": loop["realtime_factor"],
                "ticks": loop["ticks"],
                "tick_ms_p50": loop["tick_ms_p50"],
                "tick_ms_p99": loop["tick_ms_p99"],
                "tick_ms_max": loop["tick_ms_max"],
                "reached_goal": bool(rep["reached_goal"]),
            })
    return out
