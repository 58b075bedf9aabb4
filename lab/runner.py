"""Fly one mission in a worker: over MAVLink against the bundled vehicle (lockstep) or in-process.

``mavlink`` mode is exactly ``slungpilot fly --sitl --mission FILE`` (``companion.cli.fly.fly_async`` with the
``fly`` parser's defaults, the vehicle started as a separate process on free loopback ports, lockstep);
``inprocess`` mode runs ``lab.inprocess.fly_inprocess``: the same FlightCore (planner, controller,
envelope) and the same vehicle physics, without MAVLink. Both return issue 4's report keys.

The functions here are top-level so that ``concurrent.futures`` spawn workers can pickle them.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from companion.autopilots.profile import profile_by_name
from companion.core.mission import Mission, mission_to_toml
from companion.launch.spec import FlySpec

log = logging.getLogger(__name__)

MODES = ("mavlink", "inprocess")
REPORT_KEYS = (
    "reached_goal", "time_to_goal_s", "path_length_m", "payload_path_length_m", "max_swing_rad",
    "swing_settle_s", "swing_settle_after_arrival_s", "min_clearance_m", "collisions", "sim_time_s",
    "wall_time_s", "outcome", "time_to_goal_from_start_s", "swing_estimation_error",
)


def fly_spec(run_dir: Path, plots: bool, gains: Path | None = None, swing_input: str | None = None,
             world: Any = None) -> FlySpec:
    """What ``slungpilot fly --sitl --no-zenoh --no-recording -q --run-dir RUN_DIR [--no-plots] [--gains FILE]
    [--swing-input S] [--world FILE]`` flies (lockstep, no narration), built in code. ``world``: a
    :class:`companion.core.world.World` the vehicle is started in (its LiDAR sees its trunks; the report scores
    against them), None for none.

    No Zenoh: batch flights run side by side and would all want the default listen port. No 3-D recording: it costs
    ~1 s of import and its CPU per flight, and a batch has its own figures."""
    from companion.flight.setup import FlightSetup
    from companion.launch.fly import DEFAULT_GAINS, load_gains

    setup = FlightSetup(lockstep=True, gains=load_gains(gains or DEFAULT_GAINS),
                        swing_input=swing_input or "auto", profile=profile_by_name("bundled"))
    return FlySpec(setup=setup, sitl=True, run_dir=run_dir, plots=plots, narrate=False, world=world,
                   identify_payload=False)


LOST_CONTROL_SWING_RAD = math.pi / 2  # the model's own bound on the swing angles (eq. 1)


def classify(rep: dict[str, Any]) -> str:
    """``success`` (goal reached, zero collisions), ``collision`` (any obstacle touched, goal or not),
    ``lost_control`` (goal never reached and the payload swung past the model's ±π/2 bound: a divergence,
    not a planning failure), ``stuck`` (goal never reached, nothing touched, control kept before the timeout:
    a local minimum, an orbit or a stall), or ``error`` (the flight did not produce metrics)."""
    if rep.get("error"):
        return "error"
    if (rep.get("collisions") or 0) > 0:
        return "collision"
    if rep.get("reached_goal"):
        return "success"
    if (rep.get("max_swing_rad") or 0.0) >= LOST_CONTROL_SWING_RAD:
        return "lost_control"
    return "stuck"


@dataclass(frozen=True)
class Job:
    """One flight for a worker: the mission, where its run folder goes, which mode, whether to plot, and (MAVLink
    mode only) the companion's ``--swing-input`` and the world it flies in."""

    key: str
    mission: Mission
    run_dir: Path
    mode: str = "mavlink"
    plots: bool = False
    keep_run_dir: bool = True
    gains: Path | None = None
    swing_input: str | None = None
    #: MAVLink mode only: the simulated world (:class:`companion.core.world.World`) the vehicle flies in, None: none
    world: Any = None


def _fly_mavlink(job: Job) -> dict[str, Any]:
    from companion.launch.fly import fly_mission_sync

    spec = fly_spec(job.run_dir, job.plots, job.gains, job.swing_input, job.world)
    spec = replace(spec, vehicle_fork=_warm_vehicle())
    try:
        result = fly_mission_sync(spec, job.mission)
    finally:
        if spec.vehicle_fork is not None:
            spec.vehicle_fork.discard()
    rep = dict(result.report)
    rep["outcome"] = result.outcome
    return rep


def _warm_vehicle() -> Any:
    """The job's vehicle forked from this process, which loaded the vehicle's code and kernels once
    (:mod:`sim_bridge.prefork`): a batch's flights start their vehicles without ~0.44 s of CPU each. None where
    forking is not safe (e.g. a Dask worker's threads): the flight then starts ``python -m sim_bridge``."""
    from sim_bridge import prefork

    if not prefork.can_fork():
        return None
    prefork.preload()
    return prefork.PreforkedVehicle()


def _fly_inprocess(job: Job) -> dict[str, Any]:
    """The flight of ``job`` by :func:`lab.inprocess.fly_inprocess`, its report written as ``fly``'s is, with the
    flight core's verdict as the outcome (``completed``, ``timeout``, ``no_route``), as ``fly`` reports it."""
    from companion.launch.fly import DEFAULT_GAINS, load_gains
    from companion.report.run_folder import write_run
    from lab.inprocess import fly_inprocess

    gains = load_gains(job.gains or DEFAULT_GAINS)
    flog = fly_inprocess(job.mission, gains=gains)
    extra = {"outcome": flog.outcome or "timeout", "wall_time_s": flog.wall_time_s, "mode": "inprocess",
             "simulated": True, "wind": {"model": job.mission.wind.model, "scale": job.mission.wind.scale},
             "vehicle": job.mission.vehicle.as_dict(), "run_dir": str(job.run_dir), "planning": flog.planning}
    return write_run(flog, job.mission, extra, job.run_dir, plots=job.plots)


def run_job(job: Job) -> dict[str, Any]:
    """Fly ``job`` and return a compact result: the report keys, ``class`` (see :func:`classify`), the
    mission file written into the run folder (``mission.toml``, replayable with ``fly --sitl --mission``)."""
    job.run_dir.mkdir(parents=True, exist_ok=True)
    mission_file = job.run_dir / "mission.toml"
    mission_file.write_text(mission_to_toml(job.mission))
    wall0 = time.perf_counter()
    try:
        rep = _fly_mavlink(job) if job.mode == "mavlink" else _fly_inprocess(job)
    except Exception as exc:  # a worker must report, not die
        log.exception("job %s failed", job.key)
        rep = {"error": f"{type(exc).__name__}: {exc}"}
    out = {k: rep.get(k) for k in REPORT_KEYS}
    out["error"] = rep.get("error")
    out["key"] = job.key
    out["mode"] = job.mode
    out["class"] = classify(rep)
    out["job_wall_s"] = time.perf_counter() - wall0
    out.update(process_facts())
    out["run_dir"] = str(job.run_dir)
    out["mission_file"] = str(mission_file)
    if not job.keep_run_dir and out["class"] == "success":
        _prune(job.run_dir)
        out["run_dir"] = None
        out["mission_file"] = None
    return out


def rss_mb() -> float | None:
    """This process's resident set size now (MB; Linux /proc), None where unknown."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return None


def process_facts() -> dict[str, Any]:
    """Which worker process finished a job, its RSS then (MB) and when (Unix s): for :func:`memory_summary`."""
    return {"worker_pid": os.getpid(), "worker_rss_mb": rss_mb(), "finished_unix_s": time.time()}


def memory_summary(results: list[dict[str, Any]], parent_start_mb: float | None,
                   parent_end_mb: float | None) -> dict[str, Any]:
    """RSS of the parent at start and end, and per worker process its RSS after its first and its last job (MB),
    in completion order: a flat line means no leak over the batch."""
    workers: dict[str, dict[str, Any]] = {}
    for r in sorted(results, key=lambda r: r.get("finished_unix_s") or 0.0):
        pid, mb = r.get("worker_pid"), r.get("worker_rss_mb")
        if pid is None or mb is None:
            continue
        w = workers.setdefault(str(pid), {"jobs": 0, "first_mb": mb, "last_mb": mb, "max_mb": mb})
        w["jobs"] += 1
        w["last_mb"] = mb
        w["max_mb"] = max(w["max_mb"], mb)
    return {"parent_start_mb": parent_start_mb, "parent_end_mb": parent_end_mb, "workers": workers}


def _prune(run_dir: Path) -> None:
    """Remove a successful run's folder (keeps evaluation output small; failures keep theirs)."""
    import shutil

    shutil.rmtree(run_dir, ignore_errors=True)
