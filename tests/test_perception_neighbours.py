"""Perception, pure: two trunks side by side with no ray between them (two crossing trunks passing each other,
a moving one passing a still one) are two detections, not one circle over both; a lone trunk is never cut."""

from __future__ import annotations

import math

import numpy as np

from companion.perception.clusters import Clusterer
from companion.perception.points import PointFilter
from companion.perception.pose_history import Pose
from companion.perception.scan import Scan
from lab.bench_perception import raycast


def _detect(trunks, sensor=(0.0, 0.0), seed=0, noise=0.01):
    """The detections of one level 1° scan from ``sensor`` (ranges rounded to cm, as OBSTACLE_DISTANCE sends them),
    and the clusterer."""
    rays = raycast(sensor, 0.0, trunks, noise_m=noise, rng=np.random.default_rng(seed))
    rays = np.where(np.isfinite(rays), np.round(rays * 100.0) / 100.0, rays)
    scan = Scan(1.0, np.radians(np.arange(360.0)), rays, 0.1, 12.0, math.radians(1.0))
    pose = Pose(1.0, np.array([sensor[0], sensor[1], -2.0]), (0.0, 0.0, 0.0), np.eye(3))
    c = Clusterer()
    return c.detect(PointFilter().place(scan, pose)), c


def _pair(d: float, bearing_deg: float, gap_m: float, r1: float, r2: float, turn_deg: float):
    """Two trunks ``gap_m`` apart (surface to surface) around the point ``d`` m away at ``bearing_deg``, their
    centre line turned ``turn_deg`` from across the line of sight (0: side by side, 90: one behind the other)."""
    b = math.radians(bearing_deg)
    cx, cy = d * math.cos(b), d * math.sin(b)
    a = b + math.pi / 2 + math.radians(turn_deg)
    h = 0.5 * (r1 + r2 + gap_m)
    return [(cx - h * math.cos(a), cy - h * math.sin(a), r1), (cx + h * math.cos(a), cy + h * math.sin(a), r2)]


def test_two_touching_trunks_are_two_detections_each_near_its_centre():
    """Seed 13 of the moving forests: two crossing trunks (r 0.28, 0.30) 2-6 m away with a gap of 2-6 cm, side by
    side or turned up to 40°: both found within 5 cm in 9 of 10 scans, and no detection off both by more than
    0.15 m (one circle over two trunks sat between them, 0.2-0.4 m off either, with a radius of 0.45-0.68 m)."""
    rng = np.random.default_rng(13)
    found = trials = 0
    for k in range(60):
        d, bearing = rng.uniform(2.0, 6.0), rng.uniform(-40.0, 40.0)
        trunks = _pair(d, bearing, rng.uniform(0.02, 0.06), 0.28, 0.30, rng.uniform(-40.0, 40.0))
        dets, _ = _detect(trunks, seed=k)
        trials += 1
        near = [min(math.hypot(t[0] - x.x_m, t[1] - x.y_m) for x in dets) for t in trunks]
        found += max(near) < 0.05
        for x in dets:
            assert min(math.hypot(t[0] - x.x_m, t[1] - x.y_m) for t in trunks) < 0.15, (k, x)
    assert found >= 0.9 * trials, (found, trials)


def test_a_lone_trunk_is_never_cut_and_keeps_its_accuracy():
    """300 lone trunks (r 0.15-0.35 m, 1.5-9 m): one detection each, within 8 cm when 6 rays or more see it;
    cuts are rare (under 2 %)."""
    rng = np.random.default_rng(26)
    cuts = 0
    for k in range(300):
        d, b, r = rng.uniform(1.5, 9.0), rng.uniform(0.0, 2.0 * math.pi), rng.uniform(0.15, 0.35)
        x, y = d * math.cos(b), d * math.sin(b)
        dets, c = _detect([(x, y, r)], seed=k)
        if not dets:  # a thin far trunk seen by fewer than 3 rays
            continue
        assert len(dets) == 1, (k, dets)
        assert dets[0].n_points < 6 or math.hypot(dets[0].x_m - x, dets[0].y_m - y) < 0.08, (k, dets)
        cuts += c.cuts
    assert cuts <= 6, cuts


def test_two_far_neighbours_seen_by_a_few_rays_give_no_circle_across_both():
    """Seed 14 of the moving forests: two still trunks 10-11 m away, one half behind the other, seen by 5 rays
    (2 + 3): a cut into 3 + 2 fits three returns across both trunks as well as the right one (three returns fit
    any circle), and that detection, 0.4 m off both, made a still trunk a 4.5 m/s mover in the map. Pairs at
    7-11 m: under 4 % of the detections lie more than 0.15 m off the nearer true centre (one circle per segment:
    48 %; cutting by the residuals alone: 10 %; what stays are segments of 3-4 returns that one circle fits)."""
    rng = np.random.default_rng(14)
    off = n = 0
    for k in range(200):
        d, bearing = rng.uniform(7.0, 11.0), rng.uniform(-40.0, 40.0)
        trunks = _pair(d, bearing, rng.uniform(0.02, 0.3), rng.uniform(0.15, 0.35), rng.uniform(0.15, 0.35),
                       rng.uniform(30.0, 75.0) * rng.choice([-1.0, 1.0]))
        dets, _ = _detect(trunks, seed=k)
        n += len(dets)
        off += sum(min(math.hypot(t[0] - x.x_m, t[1] - x.y_m) for t in trunks) > 0.15 for x in dets)
    assert n > 200 and off < 0.04 * n, (off, n)
