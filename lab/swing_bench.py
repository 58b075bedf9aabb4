"""Benchmark of the swing estimator (issue 11): prints the estimation error figures, the closed-loop flights, the
payload identification and the estimator's cost per update. Numbers are printed, never asserted.

    python -m lab.swing_bench                  # everything on the Table 2 forest (a few minutes)
    python -m lab.swing_bench --forests 30     # plus the error and the closed loop over 30 random forests
    python -m lab.swing_bench --forests 30 --only forests --planner shaped   # that closed loop, another planner
    python -m lab.swing_bench --only cost      # one section: error | sih | forests | closed | id | sensitivity | cost

Truth: the bundled physics (sim_bridge.physics.VehicleSim) under eq. 49's wind, in-process; measurements:
lab.swing_sim (PX4 SITL Gazebo IMU noise unless said otherwise, 50 Hz IMU, 100 Hz attitude, 50 Hz velocity,
10 Hz payload fixes 0.1–0.2 s late, 15 % dropped, none from 9 to 11.5 s). CPU is process time on this machine.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from companion import proclife
from companion.config import shipped_config
from companion.core.mission import load_mission
from companion.core.vehicle_params import VehicleParams
from companion.estimation.payload_id import identify_payload
from companion.estimation.swing_estimator import SwingEstimator
from companion.report.metrics import compute_metrics
from lab.forests import generate_forest
from lab.inprocess import fly_inprocess
from lab.swing_scenarios import (
    PATHS,
    cruise_start_s,
    hop_mission,
    imu_attitude_series,
    record_truth,
    replay_estimator,
    sensors_for,
)
from lab.swing_sim import EstimatorDriver, ImuNoise, SensorConfig

SECTIONS = ("error", "sih", "forests", "closed", "id", "sensitivity", "cost")


def _pool(workers: int) -> ProcessPoolExecutor:
    """A process pool whose workers die with this process, however it dies (companion.proclife)."""
    return ProcessPoolExecutor(workers, initializer=proclife.die_with_parent, initargs=(os.getpid(),))


def _forest():
    return load_mission(shipped_config("missions/forest.toml"))


def section_error(truth) -> None:
    print("\n## Estimation error, Table 2 forest, eq. 49 wind, PX4 SITL (Gazebo) IMU noise, seed 0\n")
    print("| path | RMS (rad) | RMS α / β | max | RMS rate (rad/s) | |e| <= 3σ | fade mean | µs/tick | target |")
    print("|---|---|---|---|---|---|---|---|---|")
    targets = {"fixes": "<= 0.02 (fixes)", "fixes+vel": "<= 0.02 (fixes)", "imu": "<= 0.03 (sensorless)",
               "imu+vel": "<= 0.03 (sensorless)", "fused": "<= 0.02"}
    for path in PATHS:
        e, _ = replay_estimator(truth, sensors_for(path))
        print(f"| {path} | {e.rms:.4f} | {e.rms_alpha:.4f} / {e.rms_beta:.4f} | {e.max:.3f} | {e.rms_rate:.3f} | "
              f"{e.within_3sigma:.3f} | {e.fade_mean:.2f} | {e.cpu_us_per_tick:.0f} | {targets[path]} |")


def section_sih(truth) -> None:
    print("\n## Sensorless with PX4 SIH's accelerometer noise (0.5, 1.7, 1.4 m/s² per sample), Table 2 forest\n")
    print("| path | IMU rate | RMS (rad) | max | |e| <= 3σ |")
    print("|---|---|---|---|---|")
    for path in ("imu+vel", "imu", "fused"):
        for hz in (50.0, 250.0):
            e, _ = replay_estimator(truth, replace(sensors_for(path), imu=ImuNoise.px4_sih(), imu_hz=hz))
            print(f"| {path} | {hz:.0f} Hz | {e.rms:.4f} | {e.max:.3f} | {e.within_3sigma:.3f} |")


def _forest_job(seed: int) -> dict:
    m = generate_forest(seed)
    truth = record_truth(m)
    return {p: replay_estimator(truth, sensors_for(p))[0].rms for p in PATHS}


def _p90(sorted_values: list[float]) -> float:
    """The 90th percentile of an ascending list (the value at rank 0.9·n, no interpolation)."""
    return sorted_values[min(len(sorted_values) - 1, int(0.9 * len(sorted_values)))]


def section_forests(n: int, workers: int) -> None:
    print(f"\n## Estimation error over {n} random forests (lab.forests seeds 0..{n - 1}, eq. 49 wind)\n")
    with _pool(workers) as ex:
        res = list(ex.map(_forest_job, range(n)))
    print("| path | RMS median | RMS p90 | RMS worst |")
    print("|---|---|---|---|")
    for p in PATHS:
        v = sorted(r[p] for r in res)
        print(f"| {p} | {statistics.median(v):.4f} | {_p90(v):.4f} | {v[-1]:.4f} |")


def _closed_job(path: str | None, seed: int | None = None,
                planner: str | None = None) -> tuple[str, dict, float | None]:
    """One in-process flight of the Table 2 forest (``seed`` None) or of random forest ``seed``: on the cable
    sensor (``path`` None), on no swing input (``"none"``) or on the estimate from ``path``'s sensors; with
    ``planner`` instead of the mission's own."""
    m = _forest() if seed is None else generate_forest(seed)
    if planner is not None:
        m = m.with_(planner=planner)
    if path is None:
        r = compute_metrics(fly_inprocess(m), m)
        return "cable sensor", r, None
    if path == "none":
        r = compute_metrics(fly_inprocess(m, swing_source="none"), m)
        return "none", r, None
    d = EstimatorDriver(m.vehicle, sensors_for(path), seed=0)
    r = compute_metrics(fly_inprocess(m, swing_source="estimate", estimator=d), m)
    e = np.array([h[1][:2] - h[2][:2] for h in d.history])
    return f"estimate ({path})", r, float(np.sqrt(np.mean(e * e)))


def section_closed(workers: int) -> None:
    print("\n## Closed loop: Table 2 forest, feed-forward and envelope on the estimate (in-process, eq. 49)\n")
    print("| swing input | max swing (true) | time to goal | min clearance | collisions | estimate RMS | target |")
    print("|---|---|---|---|---|---|---|")
    targets = {"imu+vel": "<= 0.27", "imu": "<= 0.27", "fixes+vel": "<= 0.26", "fixes": "<= 0.26",
               "fused": "<= 0.26"}
    jobs = [None, "imu+vel", "imu", "fixes+vel", "fixes", "fused", "none"]
    with _pool(workers) as ex:
        res = list(ex.map(_closed_job, jobs))
    for (name, r, rms), path in zip(res, jobs, strict=True):
        print(f"| {name} | {r['max_swing_rad']:.3f} rad | {r['time_to_goal_s']:.3f} s | {r['min_clearance_m']:.3f} m "
              f"| {r['collisions']} | {'' if rms is None else f'{rms:.4f}'} | {targets.get(path, '')} |")


CLOSED_FOREST_PATHS = ("imu", "fixes+vel", "fused")


def _closed_forest_job(args: tuple[int, str | None, str | None]) -> tuple[int, str | None, dict]:
    seed, path, planner = args
    return seed, path, _closed_job(path, seed, planner)[1]


def section_closed_forests(n: int, workers: int, planner: str | None = None) -> None:
    """Issue 11's closed-loop targets over random forests: per swing input the max swing (median / p90 / worst),
    its excess over the same forest flown on the cable sensor, and the time to goal and clearance lost."""
    print(f"\n## Closed loop over {n} random forests (lab.forests seeds 0..{n - 1}, eq. 49, in-process, planner "
          f"{planner or 'safe, the missions own'})\n")
    jobs = [(seed, path, planner) for seed in range(n) for path in (None, *CLOSED_FOREST_PATHS)]
    with _pool(workers) as ex:
        res = {(seed, path): r for seed, path, r in ex.map(_closed_forest_job, jobs)}
    targets = {"imu": 0.27, "fixes+vel": 0.26, "fused": 0.26}
    print("| swing input | goal reached | max swing median / p90 / worst | over the sensor's, median / worst | "
          "time to goal, median excess / worst | min clearance, worst | collisions | within issue 11's bound |")
    print("|---|---|---|---|---|---|---|---|")
    for path in (None, *CLOSED_FOREST_PATHS):
        rows = [res[(seed, path)] for seed in range(n)]
        base = [res[(seed, None)] for seed in range(n)]
        sw = sorted(r["max_swing_rad"] for r in rows)
        over = sorted(r["max_swing_rad"] - b["max_swing_rad"] for r, b in zip(rows, base, strict=True))
        dt = sorted(r["time_to_goal_s"] - b["time_to_goal_s"] for r, b in zip(rows, base, strict=True)
                    if r["reached_goal"] and b["reached_goal"])
        reached = sum(r["reached_goal"] for r in rows)
        clear = min(r["min_clearance_m"] for r in rows)
        hits = sum(r["collisions"] for r in rows)
        p90 = _p90(sw)
        within = ", ".join(f"{sum(v <= b for v in sw)}/{n} (<= {b})" for b in
                           ((0.26, 0.27) if path is None else (targets[path],)))
        name = "cable sensor" if path is None else f"estimate ({path})"
        dts = f"{statistics.median(dt):+.3f} / {dt[-1]:+.3f} s" if dt and path is not None else ""
        overs = f"{statistics.median(over):+.3f} / {over[-1]:+.3f}" if path is not None else ""
        print(f"| {name} | {reached}/{n} | {statistics.median(sw):.3f} / {p90:.3f} / {sw[-1]:.3f} rad | {overs} | "
              f"{dts} | {clear:.3f} m | {hits} | {within} |")


def _id_job(args: tuple[float, float, float, str, str]) -> tuple:
    l, m, wind, noise, flight = args
    vp = replace(VehicleParams(), l=l, m=m)
    if flight == "hop":
        mission = hop_mission(vp, hop_m=2.0, wind_scale=wind)
    else:  # the first seconds of the forest's cruise, flown without feed-forward (the payload is not known yet)
        mission = _forest().with_(controller="smc", vehicle=vp, wind=replace(_forest().wind, scale=wind))
    truth = record_truth(mission)
    t0 = cruise_start_s(truth, 2.0)
    sensors = SensorConfig(imu=ImuNoise.px4_sih() if noise == "sih" else ImuNoise())
    t, f, e = imu_attitude_series(truth, sensors, seed=1, t_from_s=t0, t_to_s=t0 + 8.0)
    c0 = time.process_time()
    r = identify_payload(t, f, e, vp.M, vp.g)
    return l, m, wind, noise, flight, r, time.process_time() - c0


def section_id(workers: int) -> None:
    print("\n## Payload identification: 8 s from reaching 2 m, no feed-forward, 50 Hz IMU + attitude\n")
    print("(hop: a 2 m lateral hop at hover; forest: the first 8 s of the Table 2 cruise)\n")
    print("| flight | true l / m | wind | IMU noise | l (err) | m (err) | 1σ l / m | ok | CPU |")
    print("|---|---|---|---|---|---|---|---|---|")
    cases = [(1.0, 0.25, 1.0, "gazebo", "hop"), (1.0, 0.25, 0.0, "gazebo", "hop"),
             (0.5, 0.1, 1.0, "gazebo", "hop"), (1.5, 0.5, 1.0, "gazebo", "hop"), (0.7, 0.4, 1.0, "gazebo", "hop"),
             (1.0, 0.25, 2.0, "gazebo", "hop"), (1.0, 0.25, 1.0, "sih", "hop"),
             (1.0, 0.25, 1.0, "gazebo", "forest")]
    with _pool(workers) as ex:
        res = list(ex.map(_id_job, cases))
    for l, m, wind, noise, flight, r, cpu in res:
        el = 100.0 * (r.cable_length_m / l - 1.0)
        em = 100.0 * (r.payload_mass_kg / m - 1.0)
        print(f"| {flight} | {l} m / {m} kg | {wind:g} | {noise} | {r.cable_length_m:.3f} ({el:+.1f} %)"
              f" | {r.payload_mass_kg:.3f} ({em:+.1f} %) | {r.cable_length_sigma_m:.3f}"
              f" / {r.payload_mass_sigma_kg:.3f} | {'yes' if r.ok else 'no: ' + r.reason} | {cpu:.2f} s |")


def section_sensitivity(truth) -> None:
    print("\n## Model error: the estimator's l and m off by a factor (imu+vel / fixes+vel), Table 2 forest\n")
    print("| estimator's l, m | imu+vel RMS | fixes+vel RMS | fused RMS |")
    print("|---|---|---|---|")
    p = truth.params
    for kl, km in ((1.0, 1.0), (1.05, 1.0), (0.95, 1.0), (1.0, 1.2), (1.0, 0.8), (1.1, 1.2)):
        mp = replace(p, l=p.l * kl, m=p.m * km)
        row = [replay_estimator(truth, sensors_for(path), model_params=mp)[0].rms
               for path in ("imu+vel", "fixes+vel", "fused")]
        print(f"| l×{kl:g}, m×{km:g} | " + " | ".join(f"{v:.4f}" for v in row) + " |")


def _time_calls(fn, n: int) -> tuple[float, float]:
    """(median, min) over 7 repeats of the mean process time per call (µs); the min is the closest to an idle
    machine."""
    runs = []
    for _ in range(7):
        c0 = time.process_time()
        for i in range(n):
            fn(i)
        runs.append((time.process_time() - c0) / n * 1e6)
    return statistics.median(runs), min(runs)


def section_tick_cost(truth) -> None:
    print("\n## Estimator CPU per control tick over the Table 2 forest (250 Hz ticks; all calls of the tick)\n")
    print("(process time; per tick the minimum over 4 replays, which strips most of the other processes' noise)\n")
    print("| path | mean | p50 | p99 | max |")
    print("|---|---|---|---|---|")
    for path in ("imu+vel", "fixes+vel", "fused"):
        runs = [np.array(replay_estimator(truth, sensors_for(path))[1].tick_cpu_s) for _ in range(4)]
        c = np.min(np.vstack(runs), axis=0) * 1e6
        print(f"| {path} | {c.mean():.0f} µs | {np.percentile(c, 50):.0f} µs | {np.percentile(c, 99):.0f} µs | "
              f"{c.max():.0f} µs |")


def section_cost() -> None:
    print("\n## Cost per call in a realistic stream (20 s: inputs at 250 Hz, ATTITUDE 100 Hz, IMU and velocity 50 Hz,")
    print("payload fixes 10 Hz arriving 0.15 s late; each call timed alone, process time)\n")
    p = VehicleParams()
    est = SwingEstimator(p)
    hover = p.hover_thrust_n
    calls: dict[str, list[float]] = {}

    def timed(name: str, fn, *args) -> None:
        c0 = time.process_time()
        fn(*args)
        calls.setdefault(name, []).append(time.process_time() - c0)

    late: list[tuple[float, float]] = []
    for k in range(5000):
        t = k * 0.004
        w = 0.3 * math.sin(0.7 * t)
        timed("set_thrust", est.set_thrust, t, hover * (1.0 + 0.05 * math.sin(t)))
        if k % 5 in (0, 2):
            timed("set_attitude_euler", est.set_attitude_euler, t, (0.1 * w, -0.1 * w, 0.0), (0.05, 0.0, 0.0))
        if k % 5 == 0:
            timed("update_imu", est.update_imu, t - 0.002, (0.3 * w, -0.2 * w, -9.81))
            timed("update_velocity", est.update_velocity, t, (w, 0.0, 0.0), (0.0, 0.0, -2.0))
        if k % 25 == 0:
            late.append((t + 0.15, t))
        while late and late[0][0] <= t:
            _, tv = late.pop(0)
            timed("update_payload_offset (0.15 s late)", est.update_payload_offset, tv, (0.01 * w, 0.0, 1.0))
        timed("estimate", est.estimate, t)
    print("| call | per second | mean | p99 | max |")
    print("|---|---|---|---|---|")
    total = 0.0
    for name, v in calls.items():
        a_us = np.array(v) * 1e6
        total += float(np.sum(v))
        print(f"| {name} | {len(v) / 20.0:.0f} | {a_us.mean():.0f} µs | {np.percentile(a_us, 99):.0f} µs | "
              f"{a_us.max():.0f} µs |")
    print(f"\ntotal: {1e3 * total / 20.0:.1f} ms of CPU per second of flight ({100 * total / 20.0:.1f} % of one core)")
    try:
        import os

        print(f"load average during the run: {os.getloadavg()[0]:.1f} (2 cores)")
    except OSError:
        pass


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.swing_bench", description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=SECTIONS, action="append", help="run only this section (repeatable)")
    ap.add_argument("--forests", type=int, default=0,
                    help="random forests for the error and closed-loop sections (default 0)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--planner", choices=("safe", "shaped", "improved", "traditional"),
                    help="the random forests' closed loop flown with this planner (default: the missions' own, safe)")
    a = ap.parse_args(argv)
    only = set(a.only or SECTIONS)
    if a.forests <= 0:
        only.discard("forests")
    w0 = time.perf_counter()
    truth = record_truth(_forest()) if only & {"error", "sih", "sensitivity", "cost"} else None
    if "error" in only:
        section_error(truth)
    if "sih" in only:
        section_sih(truth)
    if "forests" in only:
        section_forests(a.forests, a.workers)
        section_closed_forests(a.forests, a.workers, a.planner)
    if "closed" in only:
        section_closed(a.workers)
    if "id" in only:
        section_id(a.workers)
    if "sensitivity" in only:
        section_sensitivity(truth)
    if "cost" in only:
        section_tick_cost(truth)
        section_cost()
    print(f"\n(wall time {time.perf_counter() - w0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
