"""One evaluation flight and what the evaluator measures beyond its report.

* :func:`scenario_spec`: the forest of a scenario — ``static`` (as given), ``moving`` (plus crossing trunks),
  ``fenced`` (the goal ringed by trunks, no route exists).
* :func:`run_eval_job`: fly a :class:`lab.runner.Job` (MAVLink lockstep through :func:`lab.runner.run_job`, or
  in-process), then add the clearance and collisions against moving obstacles where they are at each instant
  (the flight report treats every obstacle as standing still), the ``no_route`` class, and the physical bound
  of :mod:`lab.compare`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import mission_to_toml
from lab.compare import bound_time_s
from lab.forests import ForestSpec
from lab.runner import REPORT_KEYS, Job, classify, process_facts, run_job

log = logging.getLogger(__name__)

SCENARIOS = ("static", "moving", "fenced")


def scenario_spec(spec: ForestSpec, scenario: str, movers: int = 2) -> ForestSpec:
    """The forest spec of a scenario: ``static`` as given, ``moving`` with ``movers`` crossing trunks,
    ``fenced`` with the goal ringed (see module docstring)."""
    if scenario == "static":
        return spec
    if scenario == "moving":
        return spec.with_(movers=movers)
    if scenario == "fenced":
        return spec.with_(trap="fence")
    raise ValueError(f"scenario: must be one of {', '.join(SCENARIOS)}, got {scenario!r}")


def clearances_moving(t_s: np.ndarray, pos_ned_m: np.ndarray, payload_ned_m: np.ndarray, obstacles,
                      airframe_r_m: float) -> np.ndarray:
    """Per obstacle, the minimum clearance (m) over the flight with each obstacle where it is at each row's time:
    its file position at the mission clock's zero — the first row, the first setpoint — moved at its velocity
    (the convention of :mod:`companion.flight.core`). Airframe circle and payload point, each only while below
    the obstacle's top, as in :func:`companion.report.metrics.clearances`; +inf if never below."""
    t = np.asarray(t_s, dtype=np.float64)
    dt = t - t[0]
    pos = np.asarray(pos_ned_m, dtype=np.float64)
    pay = np.asarray(payload_ned_m, dtype=np.float64)
    out = np.full(len(obstacles), math.inf)
    for i, o in enumerate(obstacles):
        ox, oy = o.x_m + o.vx_mps * dt, o.y_m + o.vy_mps * dt
        below = pos[:, 2] > -o.height_m
        if np.any(below):
            d = np.hypot(pos[below, 0] - ox[below], pos[below, 1] - oy[below]) - o.radius_m - airframe_r_m
            out[i] = min(out[i], float(np.min(d)))
        pb = np.isfinite(pay[:, 2]) & (pay[:, 2] > -o.height_m)
        if np.any(pb):
            d = np.hypot(pay[pb, 0] - ox[pb], pay[pb, 1] - oy[pb]) - o.radius_m
            out[i] = min(out[i], float(np.min(d)))
    return out


def _fly_inprocess(job: Job) -> dict[str, Any]:
    """The in-process flight of :func:`lab.runner.run_job`, plus the flight's ``no_route`` outcome (from the
    flight core's phases, which the report does not keep)."""
    from companion.cli.fly import load_gains
    from companion.cli.fly_args import DEFAULT_GAINS
    from companion.report.run_folder import write_run
    from lab.inprocess import fly_inprocess

    gains = load_gains(job.gains or DEFAULT_GAINS)
    flog = fly_inprocess(job.mission, gains=gains)
    outcome = "no_route" if "no_route" in flog.phase else "completed"
    extra = {"outcome": outcome, "wall_time_s": flog.wall_time_s, "mode": "inprocess",
             "wind": {"model": job.mission.wind.model, "scale": job.mission.wind.scale},
             "vehicle": job.mission.vehicle.as_dict(), "run_dir": str(job.run_dir)}
    return write_run(flog, job.mission, extra, job.run_dir, plots=job.plots)


def run_eval_job(job: Job) -> dict[str, Any]:
    """Fly ``job`` (:func:`lab.runner.run_job`'s result keys) and add what the evaluator measures beyond the
    flight report: collisions and clearance against moving obstacles where they are at each instant, the
    ``no_route`` class, the physical bound. Successful runs' folders are removed afterwards unless kept."""
    if job.mode == "inprocess":
        job.run_dir.mkdir(parents=True, exist_ok=True)
        mission_file = job.run_dir / "mission.toml"
        mission_file.write_text(mission_to_toml(job.mission))
        wall0 = time.perf_counter()
        try:
            rep = _fly_inprocess(job)
        except Exception as exc:  # a worker must report, not die
            log.exception("job %s failed", job.key)
            rep = {"error": f"{type(exc).__name__}: {exc}"}
        out = {k: rep.get(k) for k in REPORT_KEYS}
        out.update(error=rep.get("error"), key=job.key, mode=job.mode, job_wall_s=time.perf_counter() - wall0,
                   run_dir=str(job.run_dir), mission_file=str(mission_file), **process_facts())
    else:
        out = run_job(replace(job, keep_run_dir=True))
    m = job.mission
    moving = [i for i, o in enumerate(m.obstacles) if o.vx_mps != 0.0 or o.vy_mps != 0.0]
    npz = Path(out["run_dir"]) / "flight_log.npz" if out.get("run_dir") else None
    if moving and not out.get("error") and npz is not None and npz.exists():
        with np.load(npz) as z:
            clear = clearances_moving(z["t_s"], z["pos_ned_m"], z["payload_pos_ned_m"], m.obstacles,
                                      m.vehicle.r_uav + m.vehicle.L_uav)
        finite = clear[np.isfinite(clear)]
        out["min_clearance_m"] = float(finite.min()) if finite.size else None
        out["collisions"] = int(np.sum(clear < 0.0))
        out["collisions_moving"] = int(np.sum(clear[moving] < 0.0))
    else:
        out["collisions_moving"] = 0
    out["class"] = classify(out)
    if out["class"] == "stuck" and out.get("outcome") == "no_route":
        out["class"] = "no_route"
    d = float(np.hypot(*(m.goal_ned_m[:2] - m.start_ned_m[:2])))
    out["bound_s"] = bound_time_s(d)
    t = out.get("time_to_goal_s")
    out["time_over_bound"] = None if t is None or out["bound_s"] <= 0.0 else t / out["bound_s"]
    if not job.keep_run_dir and out["class"] == "success" and out.get("run_dir"):
        import shutil

        shutil.rmtree(out["run_dir"], ignore_errors=True)
        out["run_dir"] = None
        out["mission_file"] = None
    return out
