"""After a flight: the JSON report, the per-tick log as .npz, the plots and the one-screen summary."""

from __future__ import annotations

import json
import logging
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.mission import Mission
from companion.core.wind import WindConfig
from companion.report.metrics import FlightLog, compute_metrics, estimation_error
from companion.report.wind_truth import report_wind_truth

log = logging.getLogger(__name__)


def log_arrays(flog: FlightLog) -> dict[str, np.ndarray]:
    """The per-tick columns under the names :mod:`companion.report.plots` expects."""
    names = {
        "t_s": "t", "pos_ned_m": "pos", "vel_ned_mps": "vel", "euler_rad": "euler", "swing": "swing",
        "swing_estimate": "swing_used",
        "payload_pos_ned_m": "payload_pos", "ref_pos_ned_m": "ref_pos", "ref_vel_ned_mps": "ref_vel",
        "euler_cmd_rad": "euler_cmd", "thrust_n": "thrust_n", "r_max_m": "r_max_m", "ff_accel_mps2": "ff_accel",
        "force_att_n": "force_att", "force_rep_n": "force_rep",
    }
    out = {k: flog.arr(v) for k, v in names.items()}
    no_cmd = np.array([not p for p in flog.phase], dtype=bool)  # ticks without a command (landing, idle)
    if no_cmd.any():
        for k in ("ref_pos_ned_m", "ref_vel_ned_mps", "euler_cmd_rad", "r_max_m"):
            out[k][no_cmd] = np.nan
    return out


def _clean(v: Any) -> Any:
    """JSON-safe: NaN/inf become null, numpy scalars and arrays become Python values."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def build_report(flog: FlightLog, mission: Mission, extra: dict[str, Any]) -> dict[str, Any]:
    """Issue 4's report keys (from :func:`compute_metrics`) plus run facts in ``extra``."""
    if len(flog) == 0:
        rep: dict[str, Any] = {
            "mission": mission.name, "planner": mission.planner, "controller": mission.controller,
            "reached_goal": False, "time_to_goal_s": None, "path_length_m": 0.0, "payload_path_length_m": 0.0,
            "max_swing_rad": None, "swing_settle_s": None, "min_clearance_m": None, "collisions": 0,
            "collisions_moving": 0, "obstacle_clock_t0_s": flog.obstacle_clock_t0_s, "sim_time_s": 0.0,
        }
    else:
        # Metrics describe the mission the companion flew (climb, cruise, hold), not the autopilot's own landing
        # afterwards; the plots and the .npz keep every row.
        flown = np.array([bool(p) for p in flog.phase], dtype=bool)
        mission_log = flog.select(flown) if flown.any() else flog
        rep = compute_metrics(mission_log, mission)
    err = estimation_error(mission_log) if len(flog) else None
    if err is not None:
        rep["swing_estimation_error"] = err
    swing_modes = [m for m in flog.envelope_mode if m]
    rep["envelope_modes"] = {m: swing_modes.count(m) for m in sorted(set(swing_modes))}
    rep.update(extra)
    if len(flog) and (truth := report_wind_truth(mission, extra, flog.arr("t"), flog.arr("swing"))) is not None:
        rep["wind_truth"] = truth  # a simulated vehicle in a physical wind: what that wind alone did
    # One meaning for ``reached_goal``: the flight's outcome is ``completed`` (goal reached and held). Being near
    # the goal at some moment is ``goal_visited``; a failed flight never claims the goal.
    rep["goal_visited"] = bool(rep.get("reached_goal"))
    if "outcome" in extra:
        rep["reached_goal"] = rep["goal_visited"] and extra["outcome"] == "completed"
    return _clean(rep)


def save_npz(path: Path, arrays: dict[str, np.ndarray], level: int = 1) -> None:
    """``arrays`` as a compressed ``.npz`` that ``np.load`` reads, deflated at ``level`` (numpy's own
    ``savez_compressed`` takes zlib's default, 6: three times the CPU of level 1 for 1 % less on a flight log)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=level) as zf:
        for name, arr in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)


def write_run(
    flog: FlightLog,
    mission: Mission,
    extra: dict[str, Any],
    run_dir: Path,
    report_path: Path | None = None,
    plots: bool = True,
) -> dict[str, Any]:
    """Write report.json (and ``report_path`` if given), flight_log.npz and the PNG plots into ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    rep = build_report(flog, mission, extra)
    arrays = log_arrays(flog)
    save_npz(run_dir / "flight_log.npz", arrays)
    if plots and len(flog) > 1:
        from companion.report.plots import plot_flight

        title = f"{mission.name}: {rep['planner']} + {rep['controller']}"
        paths = plot_flight(arrays, flog.obstacles or mission.obstacles, mission.start_ned_m, mission.goal_ned_m,
                            run_dir, title, mission.waypoints, mission.fence)
        rep["plots"] = [str(p) for p in paths]
    text = json.dumps(rep, indent=2, sort_keys=False)
    (run_dir / "report.json").write_text(text + "\n")
    if report_path is not None:
        report_path.parent.mkdir(parents=True, exist_ok=True)
        report_path.write_text(text + "\n")
    (run_dir / "summary.txt").write_text(summary_text(rep) + "\n")
    return rep


def _fmt(v: Any, unit: str = "", digits: int = 2) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{digits}f}{unit}"
    return f"{v}{unit}"


def summary_text(rep: dict[str, Any]) -> str:
    """The one-screen summary printed at the end of a flight."""
    loop = rep.get("loop", {})
    lines = [
        f"mission {rep.get('mission')}  planner {rep.get('planner')}  controller {rep.get('controller')}  "
        f"outcome {rep.get('outcome', '?')}",
        f"  reached goal        {_fmt(rep.get('reached_goal'))}   time to goal {_fmt(rep.get('time_to_goal_s'), ' s')}",
        f"  path length         {_fmt(rep.get('path_length_m'), ' m')} (payload "
        f"{_fmt(rep.get('payload_path_length_m'), ' m')})",
        f"  max swing           {_fmt(rep.get('max_swing_rad'), ' rad', 3)}   settled after "
        f"{_fmt(rep.get('swing_settle_s'), ' s')} "
        f"(after arrival {_fmt(rep.get('swing_settle_after_arrival_s'), ' s')})",
        f"  min clearance       {_fmt(rep.get('min_clearance_m'), ' m', 3)}   collisions {rep.get('collisions')}",
        f"  sim time            {_fmt(rep.get('sim_time_s'), ' s')}   wall time {_fmt(rep.get('wall_time_s'), ' s')}",
    ]
    lines += waypoint_lines(rep) + payload_lines(rep.get("payload")) + lift_off_lines(rep.get("lift_off"))
    lines += wait_lines(rep.get("planning")) + vehicle_lines(rep)
    lines += drag_lines(rep.get("payload_drag"), rep.get("wind"))
    truth = rep.get("wind_truth")
    if truth:  # a flight against the bundled vehicle in a physical wind (companion.report.wind_truth)
        lines.append(f"  the wind alone      held still {_fmt(truth.get('held_swing_max_rad'), ' rad', 3)}, drag angle "
                     f"{_fmt(truth.get('drag_angle_max_rad'), ' rad', 3)} (the same payload under an airframe that "
                     "never moves)")
    if loop:
        lines.append(
            f"  loop                {loop.get('ticks')} ticks, tick p50 {_fmt(loop.get('tick_ms_p50'), ' ms', 3)}, "
            f"p99 {_fmt(loop.get('tick_ms_p99'), ' ms', 3)}, late {loop.get('late_ticks')}, preempted "
            f"{loop.get('preempted_ticks')} ({loop.get('scheduling', 'SCHED_OTHER')})"
        )
    if rep.get("run_dir"):
        lines.append(f"  run folder          {rep['run_dir']}")
    return "\n".join(lines)


def waypoint_lines(rep: dict[str, Any]) -> list[str]:
    """The summary's per-waypoint lines (none for a mission without waypoints) and its fence line."""
    lines = []
    for k, w in enumerate(rep.get("waypoints") or []):
        at = "never" if w.get("reached_at_s") is None else f"{w['reached_at_s']:.2f} s"
        sw, cl = w.get("leg_max_swing_rad"), w.get("leg_min_clearance_m")
        label = "goal" if w["name"] == "goal" else f"waypoint {k + 1} {w['name'][:24]}"
        lines.append(f"  {label:<36}reached {at:<9} leg: max swing {'—' if sw is None else f'{sw:.3f} rad'}, "
                     f"min clearance {'—' if cl is None else f'{cl:.3f} m'}")
    f = rep.get("fence")
    if f:
        def m(v: float | None) -> str:
            return "—" if v is None else f"{v:.3f} m"
        lines.append(f"  fence               min margin airframe {m(f.get('min_margin_airframe_m'))}, payload "
                     f"{m(f.get('min_margin_payload_m'))}, breaches {f.get('breaches')}")
    return lines


def lift_off_lines(lift: dict[str, Any] | None) -> list[str]:
    """The summary's lift-off lines when the wind held the payload on the ground, or the climb leaned upwind of it
    to lift it at its drag angle (:mod:`companion.flight.liftoff`)."""
    if not lift:
        return []
    out = []
    if lift.get("waited_s"):
        held = lift.get("held_by") or {}
        why = "" if lift.get("payload_drag_declared", True) else ", its drag not declared: judged at the cap"
        if not lift.get("airframe_drag_declared", True):
            k_a = _fmt(lift.get("airframe_drag_n_per_mps2"), "", 4)
            why += f"; the airframe's drag assumed: {k_a} N per (m/s)², a typical quadrotor's"
        out.append(f"  lift-off            held {_fmt(lift['waited_s'], ' s', 1)} for the wind: the payload would have "
                   f"swung {_fmt(held.get('reach_m'), ' m')} downwind, into the trunk at "
                   f"({_fmt(held.get('trunk_x_m'), '', 1)}, {_fmt(held.get('trunk_y_m'), '', 1)})" + why)
    if (lift.get("lean_m") or 0.0) >= 0.01:
        angle = "its drag angle" if lift.get("payload_drag_declared", True) else "the angle of half the cap's drag"
        out.append(f"  lift-off            leaned {_fmt(lift['lean_m'], ' m')} upwind of the payload, to lift it at "
                   + angle)
    return out


def wait_lines(planning: dict[str, Any] | None) -> list[str]:
    """The summary's line when the shaped planner waited for the wind (a gap the payload's swing fits): how long,
    how long of it the goal lay within the wind's reach of a trunk, and whether that ended the flight
    (:mod:`companion.planning.wind_wait`); or when the safe planner came no closer to the goal (its no route)."""
    if planning and planning.get("no_route_no_progress_s"):
        return [f"  stalled             {_fmt(planning.get('no_route_closest_to_goal_m'), ' m', 2)} from the goal at "
                f"best, no closer for {_fmt(planning['no_route_no_progress_s'], ' s', 0)}: no route"]
    if not planning or (planning.get("waited_s") or 0.0) < 0.05:
        return []
    line = (f"  waited              {_fmt(planning['waited_s'], ' s', 1)} in all for the wind to leave a gap the "
            "payload fits")
    if (planning.get("goal_in_wind_reach_s") or 0.0) >= 0.05:
        line += (f"; the goal lay within its reach of the trunk at ({_fmt(planning.get('trunk_x_m'), '', 1)}, "
                 f"{_fmt(planning.get('trunk_y_m'), '', 1)}) for {_fmt(planning.get('goal_in_wind_reach_s'), ' s', 1)}"
                 + (": no route" if planning.get("no_route_goal_in_wind_reach") else ""))
    return [line]


def vehicle_lines(rep: dict[str, Any]) -> list[str]:
    """The summary's line on the bundled vehicle's process (``fly --sitl``) when it had exited before the flight
    ended, or the link to it was lost while it still ran (``sitl_vehicle.at_stop``: its scheduler state then)."""
    at = (rep.get("sitl_vehicle") or {}).get("at_stop") or {}
    if "exited" in at or str(at.get("state", "")).startswith("Z"):  # Z: exited, not yet reaped
        how = (f"killed by {at['signal']}" if at.get("signal") else
               f"exit code {at['exited']}" if "exited" in at else "a zombie, not yet reaped")
        return [f"  vehicle process     had exited ({how}) before the flight ended"]
    if rep.get("outcome") == "link_lost" and at:
        return [f"  vehicle process     still running when the link was lost: {at.get('state', '?')}, waiting in "
                f"{at.get('wchan', '?')}"]
    return []


def drag_lines(drag: dict[str, Any] | None, wind: dict[str, Any] | None) -> list[str]:
    """The summary's payload-drag line (N per (m/s)²): declared, identified in flight (or why not), from the push's
    ratio (:mod:`companion.control.drag_id`), and the world's own where the bundled vehicle flew a physical wind
    (``wind``, the report's); none when there is nothing to say."""
    world = None
    if wind and wind.get("model") == "turbulence":
        world = float(WindConfig(**wind).drag_coefficients()[1])
    keys = ("declared_n_per_mps2", "identified_n_per_mps2", "from_push_n_per_mps2")
    said = [drag.get(k) for k in keys] if drag else []
    if not drag or (world is None and all(v is None for v in said)):
        return []
    ident, push = said[1], said[2]
    parts = [f"declared {_fmt(said[0], '', 4)}"]
    parts += [] if ident is None else [f"identified {ident:.4f}"]
    parts += [] if push is None else [f"from the push {push:.4f}"]
    parts += [] if world is None else [f"world {world:.4f}"]
    line = "  payload drag        " + ", ".join(parts) + " N per (m/s)²"
    return [line if ident is not None else f"{line}; not identified: {drag.get('identified_detail')}"]


def payload_lines(pay: dict[str, Any] | None) -> list[str]:
    """The summary's payload line: declared, identified (± 1σ, or why not), true when the simulator says."""
    if not pay or "declared" not in pay:
        return []
    d = pay["declared"]
    line = f"  payload             declared {_fmt(d.get('mass_kg'), ' kg', 3)} on {_fmt(d.get('cable_length_m'), ' m')}"
    idf = pay.get("identified")
    if idf is None:
        line += f"; not identified ({pay.get('identified_detail', '')})"
    elif not idf.get("ok"):
        line += f"; identification unsure ({idf.get('reason')})"
    else:
        line += (f"; identified {_fmt(idf.get('mass_kg'), '', 3)} ± {_fmt(idf.get('mass_sigma_kg'), ' kg', 3)} on "
                 f"{_fmt(idf.get('cable_length_m'))} ± {_fmt(idf.get('cable_length_sigma_m'), ' m')}")
    if pay.get("true"):
        t = pay["true"]
        line += f"; true {_fmt(t.get('mass_kg'), ' kg', 3)} on {_fmt(t.get('cable_length_m'), ' m')}"
    return [line] + [f"  payload mismatch    {m}" for m in pay.get("mismatch", [])]
