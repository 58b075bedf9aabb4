"""Score perception against the truth: replay a run folder's ``flight.tlog`` through the companion's perception
and compare what it mapped with the trunks of the run's ``world.toml`` (``fly --sitl --world``).

The replay feeds the vehicle's LOCAL_POSITION_NED, ATTITUDE and OBSTACLE_DISTANCE frames, as recorded, to a
:class:`~companion.perception.pipeline.Perception` exactly as the pilot does in lockstep (poses in the mission
frame: the report's ``mission_frame.origin_local_ned_m`` removed), so it maps the same scans the flight mapped.
Per scan, each detection and each published trunk is matched to the nearest true trunk at the scan's time (moving
ones moved by their velocity from the vehicle's boot), within its radius plus :data:`MATCH_M`.

    python -m lab.perception_replay RUN_DIR [RUN_DIR ...]

Prints per run: detections (count, centre error median/p90, radius error median), published trunks as the planner
reads them (precision: the share matching a true trunk; their centre error median; recall: of the true trunks that
came within the sensor's range, the share that was published at some time), and the perception facts' refusals.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.world import load_world
from companion.mavlink_io import telemetry as tm
from companion.perception.pipeline import Perception
from companion.perception.scan import ScanPart

MATCH_M = 0.3  # a detection this far beyond a true trunk's radius from its centre matches nothing


def _truth_at(world: Any, t_s: float) -> np.ndarray:
    """(N, 3) true trunks (north, east, radius; m) at vehicle time ``t_s`` (s)."""
    return np.array([(o.x_m + o.vx_mps * t_s, o.y_m + o.vy_mps * t_s, o.radius_m) for o in world.trunks])


def _match(x: float, y: float, truth: np.ndarray) -> tuple[int, float]:
    """The nearest true trunk's index and the centre distance (m); index −1 when none is within its radius plus
    :data:`MATCH_M`."""
    d = np.hypot(truth[:, 0] - x, truth[:, 1] - y)
    k = int(np.argmin(d))
    return (k if d[k] <= truth[k, 2] + MATCH_M else -1), float(d[k])


def replay(run_dir: Path) -> dict[str, Any]:
    """Replay one run folder; returns the scores (see the module docstring)."""
    from pymavlink import mavutil

    world = load_world(run_dir / "world.toml")
    report = json.loads((run_dir / "report.json").read_text())
    origin = report.get("mission_frame", {}).get("origin_local_ned_m", [0.0, 0.0, 0.0])
    sysid = report.get("autopilot", {}).get("system_id") or 1
    p = Perception(sysid)
    det_err, rad_err, pub_err, pub_ok, pub_n = [], [], [], 0, 0
    in_range: set[int] = set()
    published: set[int] = set()
    log = mavutil.mavlink_connection(str(run_dir / "flight.tlog"), dialect="common")
    while (msg := log.recv_match(blocking=False)) is not None:
        ev = tm.decode(msg) if msg.get_srcSystem() == sysid else None
        if ev is None:
            continue
        if ev.__class__ is tm.LocalPositionNed:
            x, y, z = ev.pos_ned_m
            p.on_position(ev.t_boot_s, (x - origin[0], y - origin[1], z - origin[2]))
        elif ev.__class__ is tm.Attitude:
            p.on_attitude(ev.t_boot_s, ev.euler_rad)
        elif ev.__class__ is tm.ObstacleDistance:
            n0 = p.scans_mapped
            p.on_part(ScanPart(ev.time_usec, ev.distances_cm, ev.min_distance_cm, ev.max_distance_cm,
                               ev.increment_deg, ev.angle_offset_deg, ev.frame, ev.src_system))
            if p.scans_mapped == n0 or p.last_points is None:
                continue
            pts = p.last_points
            truth = _truth_at(world, pts.t_s)
            near = np.hypot(truth[:, 0] - pts.origin_m[0], truth[:, 1] - pts.origin_m[1]) - truth[:, 2]
            in_range.update(np.flatnonzero(near <= pts.range_max_m).tolist())
            for d in p.last_detections:
                k, e = _match(d.x_m, d.y_m, truth)
                if k >= 0:
                    det_err.append(e)
                    rad_err.append(abs(d.radius_m - truth[k, 2]))
            for o in p.obstacles_at(pts.t_s):  # as the planner reads them: moving ones advanced
                k, e = _match(o.x_m, o.y_m, truth)
                pub_n += 1
                if k >= 0:
                    pub_err.append(e)
                pub_ok += k >= 0
                if k >= 0:
                    published.add(k)
    facts = p.facts()
    return {
        "run": str(run_dir), "scans_mapped": p.scans_mapped, "detections_matched": len(det_err),
        "centre_error_m_median": float(np.median(det_err)) if det_err else math.nan,
        "centre_error_m_p90": float(np.percentile(det_err, 90)) if det_err else math.nan,
        "radius_error_m_median": float(np.median(rad_err)) if rad_err else math.nan,
        "published_precision": pub_ok / pub_n if pub_n else math.nan,
        "published_centre_error_m_median": float(np.median(pub_err)) if pub_err else math.nan,
        "recall": len(published & in_range) / len(in_range) if in_range else math.nan,
        "trunks_in_range": len(in_range), "refused": facts["refused"], "map": facts["map"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.perception_replay", description=__doc__.split("\n")[0])
    ap.add_argument("run_dirs", nargs="+", type=Path, help="run folders of fly --sitl --world flights")
    for d in ap.parse_args(argv).run_dirs:
        print(json.dumps(replay(d), default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
