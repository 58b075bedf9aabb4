"""evaluate --perception: the scoring definitions on synthetic inputs (pure), the blind world, and a tiny real run."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.core.obstacles import Obstacle
from lab.forests import ForestSpec, generate_forest
from lab.perception_eval import CLOCK_T0_S, blind_world, build_jobs
from lab.perception_report import summarise_cell
from lab.perception_score import match_trunks, sightable

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)


def _path(x0: float, x1: float, n: int = 101, z: float = -2.0) -> tuple[np.ndarray, np.ndarray]:
    """A straight flight along y = 0 from x0 to x1 (m) in 10 s at height -z."""
    t = np.linspace(0.0, 10.0, n)
    pos = np.zeros((n, 3))
    pos[:, 0] = np.linspace(x0, x1, n)
    pos[:, 2] = z
    return t, pos


def test_sightable_range_occlusion_width_and_ground():
    t, pos = _path(0.0, 1.0)
    trunks = [Obstacle(5.0, 0.0, 0.3),  # straight ahead, in range
              Obstacle(9.0, 0.0, 0.3),  # right behind the first: occluded all the way
              Obstacle(14.0, 3.0, 0.3),  # near side beyond 12 m from every point of the path
              Obstacle(5.0, 3.0, 0.05)]  # in range but too thin for 3 one-degree rays at ~5.8 m
    seen = sightable(trunks, t, pos, range_m=12.0, step_deg=1.0)
    assert seen.tolist() == [True, False, False, False]
    # the same trunks from a path that passes beside the first: the second comes into view
    t2, pos2 = _path(0.0, 1.0)
    pos2[:, 1] = 2.0
    assert sightable(trunks[:2], t2, pos2).tolist() == [True, True]
    # a path on the ground (below 1 m) sees nothing
    _, low = _path(0.0, 1.0, z=-0.5)
    assert not sightable(trunks, t, low).any()


def test_sightable_needs_half_a_second_and_moving_blockers_move():
    t, pos = _path(0.0, 1.0)
    far = Obstacle(5.0, 0.0, 0.3)
    # a blocker that drifts too slowly to leave the line of sight within the flight: never in view
    blocker = Obstacle(2.5, -0.97 * 0.1, 0.1, vy_mps=0.01)
    assert sightable([far, blocker], t, pos)[0] == False  # noqa: E712
    blocker_fast = Obstacle(2.5, -1.0, 0.1, vy_mps=0.2)  # crosses in front at 4.5-5.5 s: in view the rest
    assert sightable([far, blocker_fast], t, pos)[0] == True  # noqa: E712


def test_match_precision_recall_and_errors():
    truth = [Obstacle(3.0, 0.0, 0.2), Obstacle(6.0, 1.0, 0.3), Obstacle(9.0, -1.0, 0.25)]
    sight = [True, True, False]
    est = [{"x_m": 3.03, "y_m": 0.04, "radius_m": 0.21},  # 0.05 m off, radius +0.01
           {"x_m": 6.0, "y_m": 1.2, "radius_m": 0.28},  # 0.2 m off, radius -0.02
           {"x_m": 6.1, "y_m": 1.0, "radius_m": 0.3},  # a second candidate for trunk 2, nearer: wins
           {"x_m": 0.0, "y_m": 2.5, "radius_m": 0.2}]  # nothing there: a false positive
    s = match_trunks(truth, sight, est)
    assert s["matched"] == 2 and s["matched_sightable"] == 2 and s["sightable"] == 2
    assert s["false_positives"] == 2  # the losing candidate and the phantom
    assert s["precision"] == pytest.approx(2 / 4)
    assert s["recall"] == pytest.approx(1.0)
    assert sorted(s["centre_err_m"]) == pytest.approx([0.05, 0.1], abs=1e-4)
    assert sorted(s["radius_err_m"]) == pytest.approx([0.0, 0.01], abs=1e-4)
    # beyond 0.3 m nothing matches; a map trunk on a crossing trunk's track is counted apart, not as false
    mover = Obstacle(0.0, -5.0, 0.3, vy_mps=1.0)  # walks along x = 0
    s2 = match_trunks(truth, sight, [{"x_m": 3.4, "y_m": 0.0, "radius_m": 0.2},
                                     {"x_m": 0.2, "y_m": 2.5, "radius_m": 0.3}], movers=[mover])
    assert s2["matched"] == 0 and s2["recall"] == 0.0 and s2["false_positives"] == 1 and s2["mover_tracks"] == 1
    assert match_trunks(truth, [False] * 3, [])["recall"] is None


def test_blind_world_moves_crossing_trunks_back_to_the_vehicle_clock():
    m = generate_forest(3, ForestSpec(density_per_100m2=8.0, movers=2))
    w = blind_world(m, "x")
    assert len(w.trunks) == len(m.obstacles) and all(o.source == "world" for o in w.trunks)
    for o, mo in zip(w.trunks, m.obstacles, strict=True):
        # at the mission clock's zero (vehicle time CLOCK_T0_S) the world trunk is where the mission has it
        at = o.at_time(CLOCK_T0_S)
        assert math.hypot(at.x_m - mo.x_m, at.y_m - mo.y_m) < 1e-9
    assert any(o.vx_mps or o.vy_mps for o in w.trunks)


def test_jobs_pair_blind_and_mapped_on_the_same_forest(tmp_path):
    jobs = build_jobs(["shaped", "safe"], 2, 5, ForestSpec(density_per_100m2=8.0), tmp_path)
    assert len(jobs) == 2 * 2 * 2
    by = {j.key: j for j in jobs}
    blind, mapped = by["shaped|8|5|static|blind"], by["shaped|8|5|static|mapped"]
    assert blind.mission.obstacles == () and blind.world is not None and mapped.world is None
    assert [(o.x_m, o.y_m, o.radius_m) for o in blind.world.trunks] == [
        (o.x_m, o.y_m, o.radius_m) for o in mapped.mission.obstacles]


def test_summary_ratio_only_on_seeds_clean_both_ways():
    def r(seed, arm, cls, t):
        return {"seed": seed, "arm": arm, "class": cls, "time_to_goal_s": t, "min_clearance_m": 0.2,
                "collisions_moving": 1 if cls == "collision" else 0}
    rs = [r(0, "blind", "success", 6.0), r(0, "mapped", "success", 5.0),
          r(1, "blind", "success", 9.0), r(1, "mapped", "stuck", None),
          r(2, "blind", "collision", 7.0), r(2, "mapped", "success", 5.0)]
    c = summarise_cell(rs)
    assert c["blind"]["clean"] == 2 and c["mapped"]["clean"] == 2
    assert c["time_ratio"]["n"] == 1 and c["time_ratio"]["median"] == pytest.approx(1.2)
    assert c["blind"]["collisions_moving"] == 1


@pytest.mark.slow
def test_evaluate_perception_tiny_real_run(tmp_path):
    """One sparse, short forest flown blind and mapped (shaped) through the CLI: the map is scored."""
    out = tmp_path / "ev"
    cp = subprocess.run([sys.executable, "-m", "companion.cli", "evaluate", "--perception", "--n", "1",
                         "--planners", "shaped", "--density", "4", "--length", "10", "--workers", "1",
                         "--no-progress", "--seed0", "2", "--keep-runs", "--out", str(out)],
                        capture_output=True, text=True, timeout=600)
    assert cp.returncode == 0, cp.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert sorted(r["arm"] for r in rows) == ["blind", "mapped"]
    blind = next(r for r in rows if r["arm"] == "blind")
    sc = blind["perception"]
    assert sc["true_trunks"] == len(generate_forest(2, ForestSpec(density_per_100m2=4, length_m=10)).obstacles)
    assert sc["map_trunks"] >= 1 and sc["matched"] >= 1 and sc["sightable"] >= 1
    assert all(e < 0.3 for e in sc["centre_err_m"])
    assert (Path(blind["run_dir"]) / "world.toml").exists()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cells"]["static"]["shaped"]["blind"]["n"] == 1
    assert (out / "perception.png").exists() and "Targets" in (out / "summary.md").read_text()
