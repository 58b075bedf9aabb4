"""Perception, pure: a trunk crossing the path is published with its velocity as soon as two scans show it moving,
even when a nearer trunk hides it before a third one could (seed 10 of the moving forests: seen twice, then hidden
for 0.8 s behind a still trunk while it crossed towards the path)."""

from __future__ import annotations

import math

import numpy as np

from companion.perception.pipeline import Perception
from lab.bench_perception import obstacle_distance_parts, raycast

DT = 0.1  # 10 Hz scans


def _scan(p: Perception, t: float, trunks, pos=(0.0, 0.0, -2.0)) -> None:
    for dt in (-0.02, 0.02):
        p.on_position(t + dt, pos)
        p.on_attitude(t + dt, (0.0, 0.0, 0.0))
    rays = raycast(pos[:2], 0.0, trunks, noise_m=0.01, rng=np.random.default_rng(round(t * 10)))
    for part in obstacle_distance_parts(rays, round(t * 1e6), 1):
        p.on_part(part)


def test_a_crossing_trunk_seen_twice_then_hidden_is_published_moving():
    """Two scans of a trunk 4 m ahead crossing at 1.2 m/s, then a nearer trunk hides it: published after the
    second scan with its velocity (within 0.4 m/s), still there while hidden, moved on by it; a still trunk seen
    twice is not published before its third scan."""
    still = (3.0, 2.0, 0.3)

    def crossing(t: float) -> tuple[float, float, float]:  # 4 m ahead, crossing east at 1.2 m/s
        return (4.0, -1.2 + 1.2 * (t - 1.0), 0.25)

    hider = (2.0, -0.32, 0.3)  # from the third scan on, between the sensor and the crossing trunk (-13°..-5°)
    p = Perception(1)
    for k in range(2):
        t = 1.0 + k * DT
        _scan(p, t, [still, crossing(t)])
    moving = [o for o in p.obstacles if o.vy_mps != 0.0]
    assert len(moving) == 1 and not any(abs(o.x_m - 2.0) < 0.3 for o in p.obstacles)  # the still one: tentative
    assert abs(moving[0].vy_mps - 1.2) < 0.4 and abs(moving[0].vx_mps) < 0.4
    for k in range(2, 8):  # hidden behind the nearer trunk from here on
        t = 1.0 + k * DT
        _scan(p, t, [still, hider, crossing(t)])
        assert any(o.vy_mps != 0.0 for o in p.obstacles)
    assert sorted(tr.hits for tr in p.map.tracks.values() if tr.moving) == [2]  # hidden: never seen again
    o = next(o for o in p.obstacles_at(1.7) if o.vy_mps != 0.0)
    assert math.hypot(o.x_m - 4.0, o.y_m - crossing(1.7)[1]) < 0.3
