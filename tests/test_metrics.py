"""compute_metrics on hand-made logs."""

import json
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


# --- moving obstacles: scored where they are at each logged time (issue 25, "a wrong report") ---------------------

T0 = 10.0  # the mission clock's zero (vehicle time of the first setpoint, s)
AIRFRAME = 0.28  # r_uav + L_uav of the default vehicle (m)


def _crossing_log(obstacles, clock_t0_s=T0):
    """One second on the ground-level start before the first setpoint (no command), then 6 s flying along y = 0
    from x = 0 to x = 6 at 1 m/s, rows every 10 ms; the payload hangs 1 m straight below."""
    log = FlightLog(planner="shaped", controller="smc_ff", obstacles=tuple(obstacles), obstacle_clock_t0_s=clock_t0_s)
    for k in range(100):
        log.append(T0 - 1.0 + 0.01 * k, np.array([0.0, 0.0, -2.0]), np.zeros(3), np.zeros(3), np.zeros(4),
                   np.array([0.0, 0.0, -1.0]), None)
    for k in range(601):
        x = 0.01 * k
        log.append(T0 + 0.01 * k, np.array([x, 0.0, -2.0]), np.array([1.0, 0.0, 0.0]), np.zeros(3), np.zeros(4),
                   np.array([x, 0.0, -1.0]), _Cmd("cruise"))
    return log


def _crossing_trunk(**kw):
    """A 0.2 m trunk whose file position (3, 0) is on the path, moving +y at 0.5 m/s from the clock's zero: when
    the vehicle reaches x = 3 (3 s after the zero) it is at (3, 1.5)."""
    return Obstacle(3.0, 0.0, 0.2, vy_mps=0.5, **kw)


# relative to the vehicle the trunk starts 3 m ahead and moves at (−1, 0.5) m/s: closest 3·0.5/√1.25 m at 2.4 s
CROSSING_MISS_M = 3.0 * 0.5 / math.sqrt(1.25)


def _crossing_mission(obstacles=()):
    return Mission("crossing", np.array([0.0, 0.0, -2.0]), np.array([6.0, 0.0, -2.0]), "shaped", "smc_ff", 30.0,
                   obstacles=tuple(obstacles))


def test_a_trunk_crossing_the_path_is_scored_where_it_was(tmp_path):
    """The vehicle flies through the trunk's file position, but the trunk has moved on: 1.34 m centre to centre,
    0.86 m of airframe clearance. The report (compute_metrics and the run folder's report.json) says so."""
    from companion.report.run_folder import write_run

    obs = [_crossing_trunk()]
    log = _crossing_log(obs)
    r = compute_metrics(log, _crossing_mission(obs))
    assert r["collisions"] == 0 and r["collisions_moving"] == 0
    assert r["min_clearance_m"] == pytest.approx(CROSSING_MISS_M - 0.2 - AIRFRAME, abs=1e-9)
    assert r["obstacle_clock_t0_s"] == T0
    rep = write_run(log, _crossing_mission(obs), {"outcome": "completed"}, tmp_path, plots=False)
    assert rep["collisions"] == 0 and rep["min_clearance_m"] == pytest.approx(0.8616, abs=1e-4)
    assert json.loads((tmp_path / "report.json").read_text())["collisions"] == 0


def test_a_moving_trunk_that_meets_the_vehicle_is_a_collision():
    """The same trunk timed to be on the path when the vehicle gets there (file position 1.5 m to the side)."""
    obs = [Obstacle(3.0, -1.5, 0.2, vy_mps=0.5), Obstacle(3.0, 3.0, 0.2)]
    r = compute_metrics(_crossing_log(obs), _crossing_mission(obs))
    assert r["collisions"] == 1 and r["collisions_moving"] == 1
    assert r["min_clearance_m"] == pytest.approx(-0.2 - AIRFRAME, abs=1e-9)


def test_before_the_clock_zero_a_moving_trunk_stands_at_its_file_position():
    """Rows logged before the first setpoint (the vehicle waiting at the start) see the trunk where the file puts
    it, as the flight core does, not where its velocity would have carried it before the zero."""
    trunk = Obstacle(0.0, 1.0, 0.2, vy_mps=1.0)  # would have been on the start 1 s before the zero
    log = _crossing_log([trunk])
    r = compute_metrics(log, _crossing_mission([trunk]))
    assert r["collisions"] == 0
    assert r["min_clearance_m"] == pytest.approx(1.0 - 0.2 - AIRFRAME, abs=1e-9)  # at the zero, on the start


def test_without_a_clock_zero_the_old_report_is_kept():
    """A log without the mission clock's zero (run folders written before it was logged) scores every obstacle at
    its file position, as the report always did; so do live obstacles, logged where they were seen."""
    r = compute_metrics(_crossing_log([_crossing_trunk()], clock_t0_s=None), _crossing_mission([_crossing_trunk()]))
    assert r["collisions"] == 1 and r["collisions_moving"] == 1 and r["obstacle_clock_t0_s"] is None
    assert r["min_clearance_m"] == pytest.approx(-0.2 - AIRFRAME, abs=1e-9)
    live = _crossing_trunk(source="zenoh/obstacles/cam")
    r = compute_metrics(_crossing_log([live]), _crossing_mission([live]))
    assert r["collisions"] == 1


def test_static_trunks_score_as_before():
    """Standing trunks are untouched by the clock zero: the same numbers with and without it."""
    obs = [Obstacle(3.0, 0.9, 0.2), Obstacle(5.0, -0.7, 0.3, height_m=1.5)]
    a = compute_metrics(_crossing_log(obs), _crossing_mission(obs))
    b = compute_metrics(_crossing_log(obs, clock_t0_s=None), _crossing_mission(obs))
    # the airframe flies above the 1.5 m trunk; the payload, 1 m lower, passes it at 0.7 m
    assert a["min_clearance_m"] == b["min_clearance_m"] == pytest.approx(0.7 - 0.3)
    assert a["collisions"] == b["collisions"] == 0


def test_the_journal_keeps_the_clock_zero_and_old_run_folders_still_read(tmp_path):
    """``slungpilot report RUN_DIR`` rebuilds the report from the journal: with the clock zero the journal kept,
    the crossing trunk is missed; from a run folder whose partial report has none, the old report comes back."""
    from companion.report.journal import PARTIAL, Journal, rebuild_run

    obs = [_crossing_trunk()]
    for name, clock, collisions in (("new", T0, 0), ("old", None, 1)):
        run = tmp_path / name
        log = _crossing_log(obs, clock_t0_s=clock)
        j = Journal(run, log, _crossing_mission(obs))
        assert j.close({"outcome": "completed"})
        partial = json.loads((run / PARTIAL).read_text())
        assert partial.get("obstacle_clock_t0_s") == clock
        rep = rebuild_run(run, plots=False)
        assert rep["collisions"] == collisions and rep["obstacle_clock_t0_s"] == clock


def test_the_flight_log_file_reads_back_exactly_with_numpy(tmp_path):
    """save_npz writes what ``np.load`` reads back bit for bit (NaN, dtypes, shapes), deflated."""
    from companion.report.run_folder import save_npz

    rng = np.random.default_rng(3)
    arrays = {"t_s": np.arange(0.0, 10.0, 0.004), "pos_ned_m": rng.normal(size=(2500, 3)),
              "swing": np.full((2500, 4), np.nan), "phase": np.array(["mission"] * 2500),
              "ticks": np.arange(2500, dtype=np.int32)}
    path = tmp_path / "log.npz"
    save_npz(path, arrays)
    with np.load(path) as back:
        assert sorted(back.files) == sorted(arrays)
        for name, arr in arrays.items():
            assert back[name].dtype == arr.dtype and back[name].shape == arr.shape
            assert np.array_equal(back[name], arr, equal_nan=arr.dtype.kind == "f")
    assert path.stat().st_size < sum(a.nbytes for a in arrays.values()) / 2  # the NaN and the strings deflate
