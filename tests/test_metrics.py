"""compute_metrics on hand-made logs."""

import math

import numpy as np
import pytest

from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.report.metrics import FlightLog, compute_metrics


class _Cmd:
    def __init__(self, phase):
        z = np.zeros(3)
        self.ref_pos_ned_m = self.ref_vel_ned_mps = self.ref_acc_ned_mps2 = self.euler_cmd_rad = self.ff_accel = z
        self.force_att_n = self.force_rep_n = np.zeros(2)
        self.thrust_n = 14.7
        self.r_max_m = 0.28
        self.phase = phase
        self.envelope_mode = "swing"


def _mission(obstacles=()):
    return Mission("t", np.array([0.0, 0.0, -2.0]), np.array([3.0, 0.0, -2.0]), "safe", "smc_ff", 30.0,
                   obstacles=tuple(obstacles))


def _log(rows, obstacles=()):
    log = FlightLog(planner="safe", controller="smc_ff", obstacles=tuple(obstacles))
    for t, phase, xy, sw, pay_xy in rows:
        pos = np.array([xy[0], xy[1], -2.0])
        pay = np.array([pay_xy[0], pay_xy[1], -1.0])
        log.append(t, pos, np.zeros(3), np.zeros(3), np.array([*sw, 0.0, 0.0]), pay, _Cmd(phase))
    return log


def test_straight_flight_metrics():
    obs = [Obstacle(1.5, 1.0, 0.2)]
    rows = [
        (0.0, "climb", (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),
        (1.0, "cruise", (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),
        (2.0, "cruise", (1.5, 0.0), (0.2, -0.1), (1.4, 0.3)),
        (3.0, "cruise", (2.95, 0.0), (0.06, 0.0), (2.95, 0.0)),
        (4.0, "hold", (3.0, 0.0), (0.01, 0.02), (3.0, 0.0)),
        (5.0, "hold", (3.0, 0.0), (0.0, 0.0), (3.0, 0.0)),
    ]
    r = compute_metrics(_log(rows, obs), _mission(obs))
    assert r["reached_goal"] is True
    assert r["time_to_goal_s"] == pytest.approx(2.0)  # goal first within 0.1 m at t = 3, cruise from t = 1
    assert r["time_to_goal_from_start_s"] == pytest.approx(3.0)
    assert r["path_length_m"] == pytest.approx(2.95)
    assert r["payload_path_length_m"] == pytest.approx(math.hypot(1.4, 0.3) + math.hypot(1.55, 0.3))
    assert r["max_swing_rad"] == pytest.approx(0.2)
    assert r["swing_settle_s"] == pytest.approx(3.0)  # last >= 0.05 at t = 3 -> settled from t = 4
    assert r["swing_settle_after_arrival_s"] == pytest.approx(1.0)
    # airframe: at (1.5, 0): 1.0 - 0.2 - 0.28 = 0.52; payload at (1.4, 0.3): hypot(0.1, 0.7) - 0.2
    assert r["min_clearance_m"] == pytest.approx(math.hypot(0.1, 0.7) - 0.2)
    assert r["collisions"] == 0
    assert r["planner"] == "safe" and r["controller"] == "smc_ff"
    assert r["sim_time_s"] == pytest.approx(5.0)


def test_collisions_and_never_reached():
    obs = [Obstacle(1.0, 0.0, 0.3), Obstacle(2.0, 0.5, 0.3, height_m=0.5), Obstacle(9.0, 9.0, 0.3)]
    rows = [
        (0.0, "cruise", (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),
        (1.0, "cruise", (1.0, 0.5), (0.3, 0.0), (1.0, 0.2)),  # airframe 0.5-0.3-0.28 < 0, payload inside obs 0
        (2.0, "cruise", (2.0, 0.6), (0.3, 0.0), (2.0, 0.5)),  # obs 1 is only 0.5 m tall: flying over it
    ]
    r = compute_metrics(_log(rows, obs), _mission(obs))
    assert r["reached_goal"] is False and r["time_to_goal_s"] is None
    assert r["collisions"] == 1
    assert r["min_clearance_m"] == pytest.approx(0.2 - 0.3)
    assert r["swing_settle_s"] is None  # still swinging at the end
    assert r["path_length_m"] == pytest.approx(math.hypot(1.0, 0.5) + math.hypot(1.0, 0.1))


def test_empty_log_refused():
    with pytest.raises(ValueError):
        compute_metrics(FlightLog(), _mission())


def test_select_keeps_rows_and_columns_aligned():
    from companion.report.metrics import FlightLog

    log = FlightLog(planner="safe", controller="smc_ff", mission="m")
    for k in range(5):
        log.append(float(k), [k, 0, -2], [1, 0, 0], [0, 0, 0], [0.01 * k, 0, 0, 0], [k, 0, -1], None)
    sub = log.select(np.array([True, False, True, False, True]))
    assert len(sub) == 3 and sub.planner == "safe"
    np.testing.assert_array_equal(sub.arr("t"), [0.0, 2.0, 4.0])
    np.testing.assert_array_equal(sub.arr("pos")[:, 0], [0.0, 2.0, 4.0])
    np.testing.assert_allclose(sub.arr("swing")[:, 0], [0.0, 0.02, 0.04])
    assert len(sub.phase) == 3 and len(sub.r_max_m) == 3


def test_columns_read_like_the_lists_they_replace_across_chunk_boundaries():
    """FlightLog's numeric columns are float64 chunks (Column.CHUNK rows each), not a Python object per value; they
    read as lists did: len, index, slices, iteration, numpy conversion, truthiness; select keeps rows and chunks."""
    from companion.report.metrics import Column

    n = Column.CHUNK * 2 + 7
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(n, 3))
    col, t = Column(3), Column(1)
    assert not col and len(col) == 0 and np.asarray(col).shape == (0, 3)
    for i, r in enumerate(rows):
        col.append(r)
        t.append(i * 0.004)
    assert col and len(col) == n
    np.testing.assert_array_equal(np.asarray(col), rows)
    np.testing.assert_array_equal(col[Column.CHUNK - 3 : Column.CHUNK + 5], rows[Column.CHUNK - 3 : Column.CHUNK + 5])
    np.testing.assert_array_equal(col[-1], rows[-1])
    row = col[5]
    row[:] = 0.0  # a copy: the column is unchanged
    np.testing.assert_array_equal(col[5], rows[5])
    assert t[Column.CHUNK] == pytest.approx(Column.CHUNK * 0.004) and isinstance(t[3], float)
    assert [float(v) for v in t][:3] == [0.0, 0.004, 0.008]
    np.testing.assert_array_equal(col[::1000], rows[::1000])
    with pytest.raises(IndexError):
        col[n]
    keep = np.zeros(n, dtype=bool)
    keep[[0, Column.CHUNK, n - 1]] = True
    taken = col.take(np.flatnonzero(keep))
    np.testing.assert_array_equal(np.asarray(taken), rows[keep])
    taken.append(np.ones(3))  # a taken column keeps growing
    assert len(taken) == 4 and np.asarray(taken)[-1].tolist() == [1.0, 1.0, 1.0]
    col.append(np.nan)  # a scalar fills the row (NaN: unknown)
    assert np.all(np.isnan(col[-1]))


def test_a_log_of_many_ticks_selects():
    log = _log([(0.004 * i, "cruise", (0.001 * i, 0.0), (0.0, 0.0), (0.001 * i, 0.0)) for i in range(9000)])
    assert len(log) == 9000 and log.arr("pos").shape == (9000, 3)
    half = log.select(np.arange(9000) % 2 == 0)
    assert len(half) == 4500 and half.phase[0] == "cruise"
    np.testing.assert_array_equal(half.arr("t"), log.arr("t")[::2])
