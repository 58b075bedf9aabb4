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
