"""The bundled vehicle's 2-D LiDAR (sim_bridge.lidar) and the OBSTACLE_DISTANCE layouts of its scans
(sim_bridge.scan_sender): geometry at the airframe's attitude, occlusion, ground strikes, trunk tops, range limits,
noise and dropouts with a fixed seed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim_bridge.lidar import Lidar, LidarConfig
from sim_bridge.scan_sender import UINT16_MAX, ScanSender, sector_message, split_messages, to_cm
from sim_bridge.world import World

LEVEL = (0.0, 0.0, 0.0)
AT_2M = (0.0, 0.0, -2.0)


def _trunks(*rows):
    """Arrays (x, y, radius, height) of trunks given as (x, y, radius, height) rows."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return a[:, 0], a[:, 1], a[:, 2], a[:, 3]


def test_a_trunk_at_known_range_and_bearing_returns_range_minus_radius():
    lid = Lidar(LidarConfig(noise_m=0.0))
    # 6 m away at bearing 30° east of north, the airframe yawed 10°: the ray 20° right of its nose hits it
    b = math.radians(30.0)
    tr = _trunks((6.0 * math.cos(b), 6.0 * math.sin(b), 0.3, 4.0))
    r = lid.true_ranges(AT_2M, (0.0, 0.0, math.radians(10.0)), *tr)
    assert r[20] == pytest.approx(5.7, abs=1e-9)
    assert np.all(np.isinf(np.delete(r, range(17, 24))))  # nothing else within 12 m at 2 m altitude, level
    noisy = Lidar(LidarConfig(noise_m=0.01, seed=3)).scan(AT_2M, (0.0, 0.0, math.radians(10.0)), *tr)
    assert abs(noisy[20] - 5.7) < 0.05  # 5 σ


def test_bearings_are_clockwise_from_the_nose_seen_from_above():
    lid = Lidar(LidarConfig(noise_m=0.0))
    east = lid.true_ranges(AT_2M, LEVEL, *_trunks((0.0, 4.0, 0.5, 4.0)))  # NED +y: to the right of a north nose
    assert east[90] == pytest.approx(3.5) and math.isinf(east[270])


def test_a_near_trunk_occludes_the_one_behind_it():
    lid = Lidar(LidarConfig(noise_m=0.0))
    r = lid.true_ranges(AT_2M, LEVEL, *_trunks((8.0, 0.0, 0.3, 4.0), (4.0, 0.0, 0.3, 4.0)))
    assert r[0] == pytest.approx(3.7)
    alone = lid.true_ranges(AT_2M, LEVEL, *_trunks((8.0, 0.0, 0.3, 4.0)))
    assert alone[0] == pytest.approx(7.7)


def test_a_pitched_scan_hits_the_ground_at_altitude_over_sine():
    lid = Lidar(LidarConfig(noise_m=0.0, range_max_m=20.0))
    r = lid.true_ranges(AT_2M, (0.0, math.radians(10.0), 0.0), *_trunks())  # nose up 10°: the tail ray goes down
    assert r[180] == pytest.approx(2.0 / math.sin(math.radians(10.0)), rel=1e-12)
    assert math.isinf(r[0]) and math.isinf(r[90]) and math.isinf(r[270])  # up or level: nothing
    rolled = lid.true_ranges(AT_2M, (math.radians(-10.0), 0.0, 0.0), *_trunks())  # right wing up: its ray goes up
    assert rolled[270] == pytest.approx(2.0 / math.sin(math.radians(10.0))) and math.isinf(rolled[90])
    short = Lidar(LidarConfig(noise_m=0.0)).true_ranges(AT_2M, (0.0, math.radians(10.0), 0.0), *_trunks())
    assert short[180] == pytest.approx(11.518, abs=1e-3)  # 11.5 m is within the default 12 m ...
    far = Lidar(LidarConfig(noise_m=0.0)).true_ranges((0, 0, -3.0), (0.0, math.radians(10.0), 0.0), *_trunks())
    assert math.isinf(far[180])  # ... 17.3 m is not


def test_a_ray_above_a_short_trunk_passes_and_a_tall_one_stops_it():
    lid = Lidar(LidarConfig(noise_m=0.0))
    assert math.isinf(lid.true_ranges(AT_2M, LEVEL, *_trunks((5.0, 0.0, 0.3, 1.0)))[0])
    assert lid.true_ranges(AT_2M, LEVEL, *_trunks((5.0, 0.0, 0.3, 2.5)))[0] == pytest.approx(4.7)
    # tilted down 20°, a ray from 2 m reaches z = -1 at 2.92 m: it strikes the 1 m trunk's top disc there
    down = lid.true_ranges(AT_2M, (0.0, math.radians(-20.0), 0.0), *_trunks((3.0, 0.0, 0.3, 1.0)))
    assert down[0] == pytest.approx(1.0 / math.sin(math.radians(20.0)))


def test_out_of_range_is_no_return_and_too_close_is_not_measured():
    lid = Lidar(LidarConfig(noise_m=0.0, range_max_m=5.0, range_min_m=0.5))
    r = lid.scan(AT_2M, LEVEL, *_trunks((6.0, 0.0, 0.3, 4.0), (-0.5, 0.0, 0.2, 4.0)))
    assert math.isinf(r[0])  # 5.7 m > 5 m: measured, nothing within range
    assert math.isnan(r[180])  # 0.3 m < 0.5 m: the sensor cannot measure it
    assert np.all(np.isnan(r[170:191])) and np.isinf(r[90]) and np.isinf(r[270])  # it spans ±23.6°


def test_noise_and_dropouts_follow_their_settings_and_repeat_with_the_seed():
    cfg = LidarConfig(noise_m=0.02, dropout=0.1, seed=7, range_max_m=30.0)
    ring = _trunks(*[(10.0 * math.cos(a), 10.0 * math.sin(a), 0.5, 4.0) for a in np.radians(np.arange(0, 360, 2.0))])
    lid = Lidar(cfg)
    true = lid.true_ranges(AT_2M, LEVEL, *ring)
    scans = np.array([lid.scan(AT_2M, LEVEL, *ring) for _ in range(200)])
    hit = np.isfinite(true)
    lost = np.isnan(scans)
    assert lost.mean() == pytest.approx(0.1, abs=0.01)
    err = (scans - true)[:, hit][~lost[:, hit]]
    assert abs(err.mean()) < 0.002 and err.std() == pytest.approx(0.02, rel=0.05)
    again = Lidar(cfg)
    assert np.array_equal(np.array([again.scan(AT_2M, LEVEL, *ring) for _ in range(200)]), scans, equal_nan=True)


@pytest.mark.parametrize("bad", [dict(step_deg=7.0), dict(step_deg=0.0), dict(range_max_m=700.0),
                                 dict(range_min_m=13.0), dict(rate_hz=0.0), dict(noise_m=-1.0),
                                 dict(dropout=1.5), dict(noise_m=math.nan)])
def test_impossible_settings_are_refused_by_name(bad):
    key = next(iter(bad))
    with pytest.raises(ValueError, match=key):
        LidarConfig(**bad).validate()


def test_obstacle_distance_cm_no_return_and_unknown():
    cm, lo, hi = to_cm(np.array([2.344, 2.346, math.inf, math.nan, 0.05, 50.0]), 0.1, 12.0)
    assert (lo, hi) == (10, 1200)
    assert cm == [234, 235, 1201, UINT16_MAX, 10, 1200]  # nearest cm; clipped into [min, max]


def test_a_360_ray_scan_is_five_messages_of_72_and_sectors_one_of_72_by_5_degrees():
    r = np.full(360, math.inf)
    r[3] = 2.0  # 3° right of the nose
    r[359] = math.nan
    msgs = split_messages(r, 1.0, 0.1, 12.0)
    assert [m[2] for m in msgs] == [0.0, 72.0, 144.0, 216.0, 288.0]
    assert all(len(m[0]) == 72 and m[1] == 1.0 for m in msgs)
    assert msgs[0][0][3] == 200 and msgs[4][0][71] == UINT16_MAX and msgs[2][0][0] == 1201
    dist, inc, off, _, _ = sector_message(r, 1.0, 0.1, 12.0)
    assert (inc, off, len(dist)) == (5.0, 0.0, 72)
    assert dist[1] == 200  # the ray at 3° is in the sector centred on 5°
    assert dist[0] == 1201  # the ray at 359° (lost) shares the 0° sector with free rays
    coarse = split_messages(np.full(36, math.inf), 10.0, 0.1, 12.0)
    assert len(coarse) == 1 and coarse[0][0][36:] == [UINT16_MAX] * 36  # unused elements are unknown


class _Buf:
    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, buf: bytes) -> None:
        self.frames.append(bytes(buf))


def test_the_packed_frames_are_those_pymavlink_packs():
    from pymavlink.dialects.v20 import common as mavlink2

    r = Lidar(LidarConfig(dropout=0.1, seed=2)).scan(AT_2M, (0.1, -0.2, 1.0), *_trunks((3.0, 1.0, 0.3, 4.0)))
    ours, ref = _Buf(), _Buf()
    mine = mavlink2.MAVLink(ours, srcSystem=1, srcComponent=196)
    ScanSender(Lidar(LidarConfig()), World("empty", ())).send(r, 123_456_789, [mine])
    theirs = mavlink2.MAVLink(ref, srcSystem=1, srcComponent=196)
    for dist, inc, off, lo, hi in split_messages(r, 1.0, 0.1, 12.0):
        theirs.obstacle_distance_send(123_456_789, 0, dist, 1, lo, hi, inc, off, mavlink2.MAV_FRAME_BODY_FRD)
    assert len(ours.frames) == 5 and ours.frames == ref.frames
