"""``slungpilot evaluate --perception``: random forests flown blind (LiDAR only) and mapped, side by side.

Every forest (:func:`lab.forests.generate_forest`, seeds ``seed0 ..``) is flown twice per planner, both as full
lockstep MAVLink flights against the bundled vehicle (``fly --sitl``):

* **blind**: the mission with no obstacles, the vehicle started in a world (:mod:`companion.core.world`) holding the
  forest's trunks; the companion knows only what its LiDAR's scans put in its map; the report scores against the
  world's trunks (the truth);
* **mapped**: the mission with its trunks, no world (the planners know every trunk from the start).

Scenario ``moving`` adds ``--movers`` trunks crossing the path (:mod:`lab.forests`). A mission's moving trunk is at
its file position at the mission clock's zero, a world's at the vehicle's boot: the blind world places it
:data:`CLOCK_T0_S` earlier on its track (the mission clock's zero in a lockstep flight, vehicle time; each blind
flight's own zero is in its result, ``clock_t0_s``, so a drift would show).

Scored per blind flight (:mod:`lab.perception_score`): the map's final confirmed trunks (the report's
``perception.tracks_final``) against the world's static trunks — precision, recall over the trunks that came
within range and line of sight of the flown path, centre and radius errors of the matched ones. Output in
``--out``: ``summary.md``/``summary.json``, ``results.jsonl`` (one line per flight), ``perception.png``, and the run
folders of failures (``runs/<scenario>/<arm>/<planner>/s<seed>``; ``--keep-runs`` keeps them all).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import Mission
from companion.core.world import WORLD_SOURCE, World
from lab.evaljob import SCENARIOS, run_eval_job, scenario_spec
from lab.forests import ForestSpec, generate_forest
from lab.perception_report import summarise_perception, write_outputs
from lab.perception_score import match_trunks, sightable
from lab.pool import run_jobs
from lab.runner import Job

log = logging.getLogger(__name__)

DEFAULT_PLANNERS = ("shaped", "safe")  # every planner that is not one of the paper's
DEFAULT_DENSITY = 8.0  # trunks per 100 m² (the target density)
ARMS = ("blind", "mapped")
FRESH_S = 1.0  # a map trunk seen within this (s) of the map's last scan is "fresh"
CLOCK_T0_S = 2.0  # vehicle time (s) of the mission clock's zero in a lockstep flight (measured: report t0)


def blind_world(mission: Mission, name: str, t0_s: float = CLOCK_T0_S) -> World:
    """The world of a blind flight: the mission's trunks as world trunks (source ``world``), moving ones moved
    back by ``t0_s`` (s) on their track so that they are where the mission has them at its clock's zero."""
    trunks = tuple(replace(o, x_m=o.x_m - o.vx_mps * t0_s, y_m=o.y_m - o.vy_mps * t0_s, source=WORLD_SOURCE)
                   for o in mission.obstacles)
    return World(name=name, trunks=trunks)


def build_jobs(planners: list[str], n: int, seed0: int, spec: ForestSpec, out: Path,
               scenarios: tuple[str, ...] = ("static",), movers: int = 2) -> list[Job]:
    """Two jobs (blind, mapped) per (scenario, planner, seed); key ``planner|density|seed|scenario|arm``."""
    jobs = []
    for sc in scenarios:
        sspec = scenario_spec(spec, sc, movers)
        for seed in range(seed0, seed0 + n):
            for p in planners:
                mission = generate_forest(seed, sspec.with_(planner=p))
                d = f"{sspec.density_per_100m2:g}"
                for arm in ARMS:
                    run_dir = out / "runs" / sc / arm / p / f"s{seed}"
                    if arm == "blind":
                        world = blind_world(mission, f"{mission.name}-{sc}-s{seed}")
                        job = Job(key=f"{p}|{d}|{seed}|{sc}|{arm}", mission=replace(mission, obstacles=()),
                                  run_dir=run_dir, keep_run_dir=False, world=world)
                    else:
                        job = Job(key=f"{p}|{d}|{seed}|{sc}|{arm}", mission=mission, run_dir=run_dir,
                                  keep_run_dir=False)
                    jobs.append(job)
    return jobs


def _flight_path(run_dir: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """Vehicle times (s) and NED positions (m) from the run folder's ``flight_log.npz`` (None if absent)."""
    path = run_dir / "flight_log.npz"
    if not path.exists():
        return None
    with np.load(path) as z:
        return np.array(z["t_s"]), np.array(z["pos_ned_m"])


def score_blind(run_dir: Path, world: World) -> dict[str, Any]:
    """The map of a blind flight (its report's perception facts) against ``world``'s trunks."""
    rep_path = run_dir / "report.json"
    if not rep_path.exists():
        return {"error": "no report"}
    rep = json.loads(rep_path.read_text())
    facts = rep.get("perception") or {}
    est = facts.get("tracks_final") or []
    static = [o for o in world.trunks if o.vx_mps == 0.0 and o.vy_mps == 0.0]
    moving = [o for o in world.trunks if o.vx_mps != 0.0 or o.vy_mps != 0.0]
    path = _flight_path(run_dir)
    sight = sightable(static, *path) if path is not None else np.zeros(len(static), dtype=bool)
    score = match_trunks(static, sight.tolist(), est, movers=moving)
    # a track unseen for long is predicted on (its filter's velocity): its centre error apart from the fresh ones'
    t_end = facts.get("map_t_s")
    age = [None if t_end is None else t_end - est[k].get("last_seen_s", t_end) for _, k in score["pairs"]]
    score["centre_err_fresh_m"] = [c for c, a in zip(score["centre_err_m"], age, strict=True)
                                   if a is not None and a <= FRESH_S]
    score["centre_err_stale_m"] = [c for c, a in zip(score["centre_err_m"], age, strict=True)
                                   if a is not None and a > FRESH_S]
    score.update(clock_t0_s=rep.get("obstacle_clock_t0_s"), scans_mapped=facts.get("scans_mapped"),
                 map_t_s=facts.get("map_t_s"), map_counts=facts.get("map"),
                 tracks_final=est, truth=[[o.x_m, o.y_m, o.radius_m, o.vx_mps, o.vy_mps] for o in world.trunks])
    return score


def run_perception_job(job: Job) -> dict[str, Any]:
    """Worker: fly ``job`` (:func:`lab.evaljob.run_eval_job`), score a blind flight's map, prune a successful
    run's folder unless kept."""
    out = run_eval_job(replace(job, keep_run_dir=True))
    if job.world is not None and out.get("run_dir"):
        try:
            out["perception"] = score_blind(Path(out["run_dir"]), job.world)
        except Exception as exc:  # a worker must report, not die
            log.exception("scoring %s failed", job.key)
            out["perception"] = {"error": f"{type(exc).__name__}: {exc}"}
    if not job.keep_run_dir and out["class"] == "success" and out.get("run_dir"):
        import shutil

        shutil.rmtree(out["run_dir"], ignore_errors=True)
        out["run_dir"] = out["mission_file"] = None
    return out


def evaluate_perception(planners: list[str], n: int, *, seed0: int = 0, spec: ForestSpec, out: Path,
                        workers: int = 2, scenarios: tuple[str, ...] = ("static",), movers: int = 2,
                        keep_runs: bool = False, progress: bool = True) -> dict[str, Any]:
    """Fly every pair, write the outputs into ``out``, return the summary."""
    out.mkdir(parents=True, exist_ok=True)
    jobs = build_jobs(planners, n, seed0, spec, out, scenarios, movers)
    if keep_runs:
        jobs = [replace(j, keep_run_dir=True) for j in jobs]
    wall0 = time.monotonic()
    results = run_jobs(jobs, workers, progress, fn=run_perception_job)
    for r in results:
        p, d, s, sc, arm = r["key"].split("|")
        r.update(planner=p, density=float(d), seed=int(s), scenario=sc, arm=arm)
    summary = summarise_perception(results, planners, list(scenarios))
    summary.update(n=n, seed0=seed0, workers=workers, movers=movers, wall_s=time.monotonic() - wall0,
                   missions=len(results), spec={"density_per_100m2": spec.density_per_100m2,
                                                "length_m": spec.length_m, "width_m": spec.width_m,
                                                "timeout_s": spec.timeout_s, "controller": spec.controller},
                   clock_t0_s=CLOCK_T0_S)
    write_outputs(results, summary, out)
    return summary


def run_perception(args: argparse.Namespace) -> int:
    """``slungpilot evaluate --perception``: parse the shared evaluate options, fly, print the summary."""
    from companion.errors import ConfigError

    planners = ([p.strip() for p in args.planners.split(",") if p.strip()] if args.planners
                else list(DEFAULT_PLANNERS))
    scenarios = tuple(x.strip() for x in args.scenarios.split(",") if x.strip())
    bad = [x for x in scenarios if x not in SCENARIOS or x == "fenced"]
    if bad or not scenarios:
        raise ConfigError(f"--scenarios: with --perception, static and/or moving (got {args.scenarios!r})")
    density = float(args.densities.split(",")[0]) if args.densities else (
        args.density if args.density != 3.0 else DEFAULT_DENSITY)  # evaluate's default 3 → this one's 8
    try:
        spec = ForestSpec(density_per_100m2=density, length_m=args.length, width_m=args.width,
                          timeout_s=args.timeout, controller=args.controller, wind_scale=args.wind_scale)
        spec.validate()
        spec.with_(movers=args.movers)
    except ValueError as exc:
        raise ConfigError(f"evaluate --perception: {exc}") from None
    if args.n < 1 or args.workers < 1:
        raise ConfigError("--n and --workers: must be >= 1")
    out = args.out or Path("runs") / f"perception-{datetime.now(UTC).strftime('%Y%m%d-%H%M%S')}"
    evaluate_perception(planners, args.n, seed0=args.seed0, spec=spec, out=out, workers=args.workers,
                        scenarios=scenarios, movers=args.movers, keep_runs=args.keep_runs,
                        progress=not args.no_progress)
    print((out / "summary.md").read_text())
    print(f"written: {out}/summary.md, summary.json, results.jsonl, perception.png")
    return 0
