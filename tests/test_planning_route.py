"""Route search among inflated discs (tangent graph + Dijkstra), the minimum-curvature path and its timing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.planning.path import path_clear, smooth_path
from companion.planning.route import find_route
from companion.planning.timing import sample_motion, speed_profile


def _ring(center, radius, n, r):
    ang = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.stack([center[0] + radius * np.cos(ang), center[1] + radius * np.sin(ang)], axis=1), np.full(n, r)


def _min_dist(points, c, r):
    """Smallest distance (m) from the polyline (densely resampled) to the disc boundaries (negative: inside)."""
    p = np.asarray(points)
    t = np.linspace(0.0, 1.0, 50)[None, :, None]
    dense = (p[:-1, None, :] * (1 - t) + p[1:, None, :] * t).reshape(-1, 2)
    d = np.hypot(dense[:, None, 0] - c[None, :, 0], dense[:, None, 1] - c[None, :, 1]) - r[None, :]
    return float(d.min())


def test_straight_when_nothing_is_in_the_way():
    rt = find_route(np.zeros(2), np.array([10.0, 0.0]), np.array([[5.0, 3.0]]), np.array([1.0]))
    assert rt is not None and len(rt.points) == 2 and rt.length_m == pytest.approx(10.0)


def test_around_one_disc_is_the_taut_string():
    # start (-d, 0), goal (d, 0), disc at the origin: 2 tangents + the arc between the tangent points
    d, r = 4.0, 1.5
    rt = find_route(np.array([-d, 0.0]), np.array([d, 0.0]), np.array([[0.0, 0.0]]), np.array([r]))
    expected = 2.0 * math.sqrt(d * d - r * r) + r * (math.pi - 2.0 * math.acos(r / d))
    assert rt is not None and rt.length_m == pytest.approx(expected, rel=1e-9)
    # arcs are sampled every 0.15 rad: chords dip inside by at most r·(1 − cos 0.075)
    sag = r * (1.0 - math.cos(0.075))
    assert _min_dist(rt.points, np.array([[0.0, 0.0]]), np.array([r])) > -sag - 1e-9
    # the sampled points add up to the same length
    assert np.sum(np.hypot(*np.diff(rt.points, axis=0).T)) == pytest.approx(expected, rel=2e-3)


def test_takes_the_gap_between_two_discs_when_it_is_shorter():
    c = np.array([[5.0, 1.2], [5.0, -1.2]])
    wide = find_route(np.zeros(2), np.array([10.0, 0.0]), c, np.array([1.0, 1.0]))
    assert wide is not None and wide.length_m == pytest.approx(10.0)  # 0.4 m gap on the straight line
    closed = find_route(np.zeros(2), np.array([10.0, 0.0]), c, np.array([1.25, 1.25]))
    assert closed is not None and closed.length_m > 10.5  # overlapping discs: around the pair
    assert _min_dist(closed.points, c, np.array([1.25, 1.25])) > -1.25 * (1.0 - math.cos(0.075)) - 1e-9


def test_random_fields_routes_stay_out_of_every_disc():
    rng = np.random.default_rng(3)
    found = 0
    for _ in range(40):
        c = rng.uniform([1.0, -4.0], [19.0, 4.0], (12, 2))
        r = rng.uniform(0.5, 1.2, 12)
        keep = (np.hypot(c[:, 0], c[:, 1]) > r + 0.1) & (np.hypot(c[:, 0] - 20.0, c[:, 1]) > r + 0.1)
        c, r = c[keep], r[keep]
        rt = find_route(np.zeros(2), np.array([20.0, 0.0]), c, r)
        if rt is None:
            continue
        found += 1
        assert _min_dist(rt.points, c, r) > -1.2 * (1.0 - math.cos(0.075)) - 1e-9  # arc chords
        assert rt.length_m >= 20.0 - 1e-9
    assert found >= 30


def test_no_route_to_a_fenced_goal_or_from_an_enclosed_start():
    c, r = _ring((10.0, 0.0), 1.3, 12, 0.55)  # overlapping discs around the goal
    assert find_route(np.zeros(2), np.array([10.0, 0.0]), c, r) is None
    assert find_route(np.array([10.0, 0.0]), np.zeros(2), c, r) is None
    # one trunk fewer: a way in
    assert find_route(np.zeros(2), np.array([10.0, 0.0]), c[1:], r[1:]) is not None


def test_a_start_inside_the_inflation_but_outside_the_hard_radius_may_leave():
    c, r, hard = np.array([[0.5, 0.0]]), np.array([1.0]), np.array([0.4])
    assert find_route(np.zeros(2), np.array([5.0, 0.0]), c, r, hard) is not None
    assert find_route(np.zeros(2), np.array([5.0, 0.0]), c, r, np.array([0.6])) is None  # inside the hard one


def test_minimum_curvature_path_is_smoother_and_still_clear():
    c = np.array([[3.0, -0.2], [6.0, 0.4]])
    r = np.array([0.9, 0.8])
    rt = find_route(np.zeros(2), np.array([10.0, 0.0]), c, r)
    path = smooth_path(rt.points, c, r, ds_m=0.4)
    assert np.allclose(path[0], [0.0, 0.0]) and np.allclose(path[-1], [10.0, 0.0])
    assert path_clear(path, c, r) > -0.02  # within the sagitta of a 0.4 m chord
    taut = speed_profile(rt.points, 0.0, a_max_mps2=1.85, v_max_mps=6.0)
    smooth = speed_profile(path, 0.0, a_max_mps2=1.85, v_max_mps=6.0)
    assert smooth.duration_s < 0.9 * taut.duration_s


def test_speed_profile_respects_the_acceleration_bound_and_stops_at_the_end():
    c = np.array([[4.0, 0.3]])
    r = np.array([1.0])
    rt = find_route(np.zeros(2), np.array([9.0, 0.0]), c, r)
    path = smooth_path(rt.points, c, r, ds_m=0.4)
    a_max = 1.85
    prof = speed_profile(path, 0.0, a_max_mps2=a_max, v_max_mps=6.0)
    t = np.arange(0.0, prof.duration_s + 0.5, 0.005)
    p, v, a = sample_motion(prof, t)
    # the profile is exact at its 0.1 m stations; between them speed and curvature change a little
    assert np.max(np.hypot(a[:, 0], a[:, 1])) <= 1.05 * a_max
    assert prof.a_peak_mps2 <= 1.05 * a_max
    assert np.allclose(p[-1], [9.0, 0.0], atol=1e-6) and np.allclose(v[-1], 0.0)
    # positions, velocities and accelerations agree with each other (finite differences)
    dt = t[1] - t[0]
    assert np.max(np.abs(np.diff(p, axis=0) / dt - 0.5 * (v[1:] + v[:-1]))) < 0.02
    # straight: the bang-bang time at a_max
    line = speed_profile(np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]]), 0.0, a_max_mps2=2.0, v_max_mps=50.0)
    assert line.duration_s == pytest.approx(2.0 * math.sqrt(10.0 / 2.0), rel=2e-3)


def test_a_route_turning_back_on_its_heading_reports_the_hook_it_samples():
    # a re-plan at speed whose route goes back the way it came: the spline clamped to the heading hooks at once,
    # where chord length and arc length part (|x'| << 1); the peak the profile reports is what it samples
    # (moderate turbulence, 0.25 kg on 3 m, forest 15: the profile said 23 m/s², its samples asked 156)
    pts = np.array([[0.0, 0.0], [-0.392, 0.035], [-0.77, 0.114], [-1.144, 0.239], [-1.525, 0.41], [-1.903, 0.612],
                    [-2.257, 0.827], [-2.592, 1.058]])
    prof = speed_profile(pts, 2.95, a_max_mps2=1.07, v_max_mps=6.0, heading=np.array([1.0, 0.0]), a_brake_mps2=3.0)
    _p, _v, a = sample_motion(prof, np.arange(0.0, prof.duration_s, 0.01))
    sampled = float(np.max(np.hypot(a[:, 0], a[:, 1])))
    assert sampled > 100.0
    assert prof.a_peak_mps2 >= 0.99 * sampled


def test_too_fast_for_the_first_bend_brakes_harder_and_says_so():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.6, 0.6], [1.6, 2.0]])
    prof = speed_profile(pts, 3.0, a_max_mps2=1.0, v_max_mps=6.0, heading=np.array([1.0, 0.0]),
                         a_brake_mps2=4.0)
    assert prof.v[0] == pytest.approx(3.0)
    assert prof.a_peak_mps2 > 1.0  # the bound was exceeded, and the profile reports it
