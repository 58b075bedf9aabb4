"""`slungpilot bench fly`: the forest mission end to end in lockstep — real-time factors, tick times, CPU.

Each flight is a real ``slungpilot fly --sitl`` command (its own processes, as a user runs it). With ``--against
DIR`` the same flight is also flown by another checkout of the project (``PYTHONPATH=DIR``), interleaved run by
run, so both trees see the same machine: the numbers compare code, not the VM's mood of the minute. The other
tree flies with its own ``config/`` (mission and gains) where it has them: an editable install points the shipped
configuration at this tree's files, whose keys an older tree may not know.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from companion.config import shipped_config

DEFAULT_MISSION = shipped_config("missions/forest.toml")


def fly_once(tree: Path | None, mission: Path = DEFAULT_MISSION, planner: str | None = None) -> dict[str, Any]:
    """One lockstep forest flight by the code in ``tree`` (None: this one); its numbers."""
    env = dict(os.environ)
    own: list[str] = []
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
        if (tree / "config" / "missions" / mission.name).exists():
            mission = tree / "config" / "missions" / mission.name
        if (tree / "config" / "controller.toml").exists():
            own = ["--gains", str(tree / "config" / "controller.toml")]
    with tempfile.TemporaryDirectory(prefix="slungpilot-bench-fly-") as tmp:
        run_dir = Path(tmp) / "run"
        argv = [sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                "--no-recording", "--mission", str(mission), "--run-dir", str(run_dir), *own]
        if planner:
            argv += ["--planner", planner]
        t0 = time.monotonic()
        proc = subprocess.run(argv, env=env, cwd=tree or Path.cwd(), capture_output=True, text=True, timeout=600)
        wall = time.monotonic() - t0
        if proc.returncode != 0 or not (run_dir / "report.json").exists():
            return {"error": proc.stderr[-500:], "returncode": proc.returncode}
        rep = json.loads((run_dir / "report.json").read_text())
    loop = rep["loop"]
    sim = float(rep["sim_time_s"])
    return {"sim_time_s": sim, "command_wall_s": wall, "end_to_end_x": sim / wall,
            "in_flight_x": loop["realtime_factor"], "ticks": loop["ticks"], "tick_ms_p50": loop["tick_ms_p50"],
            "tick_ms_p99": loop["tick_ms_p99"], "tick_cpu_ms_p50": loop["tick_cpu_ms_p50"],
            "reached_goal": bool(rep["reached_goal"])}


def run(repeats: int = 3, against: Path | None = None, planner: str | None = None) -> list[tuple[str, dict]]:
    """``repeats`` flights of this tree, interleaved with as many of ``against`` when given."""
    out = []
    for _ in range(repeats):
        out.append(("this", fly_once(None, planner=planner)))
        if against is not None:
            out.append((str(against), fly_once(against, planner=planner)))
    return out


def print_bench(repeats: int, against: Path | None, planner: str | None) -> int:
    print("slungpilot bench fly: forest mission (Table 2, eq. 49 wind) against the bundled vehicle, lockstep, each")
    print("  flight a real `slungpilot fly --sitl` command; end to end = mission sim time / wall time of the whole")
    print("  command (start-up, vehicle, connect, landing, report); in flight = vehicle time / wall time between the")
    print("  first and last tick; tick = the companion's work per tick (wall and CPU), telemetry in to setpoint")
    for who, r in run(repeats, against, planner):
        if "error" in r:
            print(f"  {who}: failed ({r['returncode']}): {r['error']}")
            continue
        print(f"  {who}: end to end {r['end_to_end_x']:.1f}x (sim {r['sim_time_s']:.1f} s in {r['command_wall_s']:.2f} "
              f"s), in flight {r['in_flight_x']:.1f}x; {r['ticks']} ticks, tick p50 {r['tick_ms_p50']:.3f} ms "
              f"(CPU {r['tick_cpu_ms_p50']:.3f} ms), p99 {r['tick_ms_p99']:.3f} ms; goal: {r['reached_goal']}")
    return 0
