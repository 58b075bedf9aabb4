"""One evaluation flight and what the evaluator measures beyond its report.

* :func:`scenario_spec`: the forest of a scenario — ``static`` (as given), ``moving`` (plus crossing trunks),
  ``fenced`` (the goal ringed by trunks, no route exists).
* :func:`run_eval_job`: fly a :class:`lab.runner.Job` through :func:`lab.runner.run_job` (MAVLink lockstep or
  in-process), then add the collisions with moving obstacles, the ``no_route`` class, the physical bound of
  :mod:`lab.compare`, and in a physical wind what the wind alone did to the payload (the report's ``wind_truth``,
  :mod:`companion.report.wind_truth`).

Clearance and collisions are the flight report's own (:mod:`companion.report.scoring`, moving obstacles where they
are at each logged time): ``evaluate`` scores no flight itself, so it cannot disagree with ``fly``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from companion.report.scoring import is_moving
from lab.compare import bound_time_s
from lab.forests import ForestSpec
from lab.runner import Job, classify, run_job

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


def _report_facts(run_dir: str | None, moving: bool) -> dict[str, Any]:
    """``collisions_moving`` and what the wind alone did (``wind_drag_angle_max_rad``, ``held_swing_max_rad``: the
    report's ``wind_truth``, :mod:`companion.report.wind_truth`) from the run folder's ``report.json`` (0 and None
    when there is none: the flight failed before its report). Warns when the report had no mission clock zero to
    place ``moving`` obstacles by (it then scored them at their file positions, :mod:`companion.report.scoring`)."""
    path = Path(run_dir) / "report.json" if run_dir else None
    rep = json.loads(path.read_text()) if path is not None and path.exists() else {}
    if rep and moving and rep.get("obstacle_clock_t0_s") is None:
        log.warning("%s: no mission clock zero in the flight log; moving obstacles scored at their file positions",
                    path)
    truth = rep.get("wind_truth") or {}
    return {"collisions_moving": int(rep.get("collisions_moving") or 0),
            "wind_drag_angle_max_rad": truth.get("drag_angle_max_rad"),
            "held_swing_max_rad": truth.get("held_swing_max_rad")}


def run_eval_job(job: Job) -> dict[str, Any]:
    """Fly ``job`` (:func:`lab.runner.run_job`'s result keys) and add what the evaluator classifies by beyond
    :func:`lab.runner.classify`: the report's collisions with moving obstacles, the ``no_route`` class, the
    physical bound. Successful runs' folders are removed afterwards unless kept."""
    out = run_job(replace(job, keep_run_dir=True))
    m = job.mission
    out.update(_report_facts(None if out.get("error") else out.get("run_dir"), any(map(is_moving, m.obstacles))))
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
