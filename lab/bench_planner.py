"""``python -m lab.bench_planner``: what a control tick costs with each planner (printed, never asserted).

Flies missions in-process (the bundled physics and the companion's :class:`~companion.flight.core.FlightCore`,
as :func:`lab.inprocess.fly_inprocess` does) and times every ``FlightCore.update`` — estimate in, setpoint
out: planning, reference, control, attitude — in CPU time (``time.process_time``, so other processes on the
machine do not inflate it) and wall time. Reported per planner and mission set:

* per tick: p50, p99 and max;
* amortised: the mean CPU per tick over each replan period (1/``replan_rate_hz``; a replan cycle's work
  spread over the ticks it serves), p99 and max over the periods, and the overall mean;
* the shaped planner's replan cycles and route searches per second of planning (from the start of the
  cruise).

Before timing, the objects of the start-up (modules, compiled kernels, configuration) are moved out of the
garbage collector's reach with ``gc.freeze()``, as a real-time loop should do: otherwise a full collection of
that heap (~110 000 objects, ~50 ms) lands in whichever tick happens to trigger it, whatever the planner.
``--no-gc-freeze`` measures without.

Missions: the Table 2 forest, and ``--seeds`` random forests of issue 12 (8 trunks/100 m², 4 m × 15 m
corridor) without and with two trunks crossing the path.
"""

from __future__ import annotations

import argparse
import gc
import time

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.config import shipped_config
from companion.control import load_controller_config
from companion.core.mission import Mission, load_mission
from companion.estimation.estimate import Estimate
from companion.flight.core import FlightCore
from lab.forests import ForestSpec, generate_forest
from sim_bridge.physics import VehicleSim


def time_ticks(mission: Mission, control_period_s: float = 0.004) -> dict[str, object]:
    """Fly ``mission`` in-process; CPU and wall seconds of every ``FlightCore.update`` and the core."""
    gains = load_controller_config()
    x0 = np.zeros(16)
    x0[0:2] = mission.start_ned_m[:2]
    sim = VehicleSim(mission.vehicle, wind=mission.wind, dt_s=1e-3, x0=x0)
    sim.armed = True
    core = FlightCore(mission, gains, VehicleProfile())
    n_sub = max(1, round(control_period_s / 1e-3))
    cpu, wall = [], []
    t_end = mission.timeout_s + mission.hold_s + 1.0
    while sim.t_s < t_end:
        est = Estimate(t_s=sim.t_s, pos_ned_m=sim.pos_ned_m, vel_ned_mps=sim.vel_ned_mps, euler_rad=sim.euler_rad,
                       rates_frd_rad_s=sim.body_rates_frd_rad_s, swing=sim.swing, swing_source="cable_sensor")
        c0, w0 = time.process_time(), time.perf_counter()
        cmd = core.update(est, mission.obstacles)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        if core.phase == "done":
            break
        sim.set_attitude_target(cmd.q_ned_frd_wxyz, cmd.thrust_n)
        sim.step(n_sub)
    return {"cpu": np.array(cpu), "wall": np.array(wall), "core": core, "sim_s": sim.t_s}


def summarise(runs: list[dict[str, object]], window: int) -> dict[str, float]:
    """Per-tick and amortised statistics (ms) over several runs; ``window`` ticks per replan period."""
    cpu = np.concatenate([r["cpu"] for r in runs]) * 1e3  # type: ignore[misc]
    wall = np.concatenate([r["wall"] for r in runs]) * 1e3  # type: ignore[misc]
    means = []
    for r in runs:
        c = np.asarray(r["cpu"]) * 1e3
        k = len(c) // window
        if k:
            means.append(c[: k * window].reshape(k, window).mean(axis=1))
    am = np.concatenate(means) if means else np.zeros(1)
    cores = [r["core"] for r in runs]
    tls = [getattr(c.planner, "tl", None) for c in cores]
    sim = sum(float(r["sim_s"]) - (tl.t0_s if tl is not None else float(r["sim_s"])) for r, tl in zip(runs, tls,
                                                                                                       strict=True))
    replans = sum(getattr(c.planner, "replans", 0) for c in cores)
    searches = sum(getattr(c.planner, "searches", 0) for c in cores)
    return {
        "ticks": int(cpu.size), "cpu_p50": float(np.percentile(cpu, 50)), "cpu_p99": float(np.percentile(cpu, 99)),
        "cpu_max": float(cpu.max()), "wall_p50": float(np.percentile(wall, 50)),
        "wall_p99": float(np.percentile(wall, 99)), "wall_max": float(wall.max()),
        "amortised_mean": float(cpu.mean()), "amortised_p99": float(np.percentile(am, 99)),
        "amortised_max": float(am.max()), "replans_per_s": replans / sim if sim else 0.0,
        "searches_per_s": searches / sim if sim else 0.0,
    }


def main(argv: list[str] | None = None) -> int:
    """Print the tick costs per planner and mission set."""
    p = argparse.ArgumentParser(prog="python -m lab.bench_planner", description=__doc__.splitlines()[0])
    p.add_argument("--planners", default="shaped,safe", help="comma-separated planners (default shaped,safe)")
    p.add_argument("--seeds", type=int, default=5, help="random forests per set (default 5)")
    p.add_argument("--no-gc-freeze", action="store_true", help="leave the start-up heap to the garbage collector")
    args = p.parse_args(argv)
    table2 = load_mission(shipped_config("missions/forest.toml")).with_(hold_s=2.0)
    spec = ForestSpec(density_per_100m2=8.0, length_m=15.0, width_m=4.0)
    gains = load_controller_config()
    window = max(1, round(1.0 / (gains.planner.replan_rate_hz * 0.004)))
    print(f"slungpilot bench planner: CPU (and wall) ms per FlightCore.update, in-process, 250 Hz; amortised = mean "
          f"over each replan period ({window} ticks); start-up heap "
          f"{'left to the garbage collector' if args.no_gc_freeze else 'frozen (gc.freeze)'}")
    print("| planner | missions | ticks | tick p50 / p99 / max (CPU) | tick p99 / max (wall) | amortised mean / p99 / "
          "max | replans/s | searches/s |")
    print("|---|---|---|---|---|---|---|---|")
    for planner in [x.strip() for x in args.planners.split(",") if x.strip()]:
        sets = {
            "Table 2 forest": [table2.with_(planner=planner)],
            f"{args.seeds} forests": [generate_forest(s, spec.with_(planner=planner)) for s in range(args.seeds)],
            f"{args.seeds} forests + 2 crossing": [generate_forest(s, spec.with_(planner=planner, movers=2))
                                                   for s in range(args.seeds)],
        }
        time_ticks(sets["Table 2 forest"][0].with_(timeout_s=1.0))  # compile / load every kernel first
        gc.collect()
        if not args.no_gc_freeze:
            gc.freeze()
        for name, missions in sets.items():
            st = summarise([time_ticks(m) for m in missions], window)
            print(f"| {planner} | {name} | {st['ticks']} | {st['cpu_p50']:.3f} / {st['cpu_p99']:.3f} / "
                  f"{st['cpu_max']:.2f} | {st['wall_p99']:.3f} / {st['wall_max']:.2f} | {st['amortised_mean']:.3f} / "
                  f"{st['amortised_p99']:.3f} / {st['amortised_max']:.2f} | {st['replans_per_s']:.1f} | "
                  f"{st['searches_per_s']:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())



