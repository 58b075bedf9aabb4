"""The limit-cycle guard: the detector on synthetic commands, and closed loop in lockstep with a slow, jittery link
(in-process, deterministic) where the loop-lag fade alone leaves the forest flight cycling at the tilt limit."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.control import ControllerConfig
from companion.control.params import CycleGuardGains, load_controller_config
from companion.core.mission import load_mission
from companion.errors import ConfigError
from companion.estimation.limit_cycle import LimitCycleDetector
from lab.inprocess import fly_inprocess
from sim_bridge.inner_loop import AIR_MODE_ALL

PERIOD_S = 0.004


def _feed(det: LimitCycleDetector, f_hz: float, amp_mps2: float, seconds: float, axis: int = 0) -> list[float]:
    """A correction that is a sine of ``f_hz`` and ``amp_mps2`` on one axis; the detector's scale after each tick."""
    out = []
    for n in range(int(seconds / PERIOD_S)):
        t = n * PERIOD_S
        v = amp_mps2 * math.sin(2 * math.pi * f_hz * t)
        det.correction(t, v if axis == 0 else 0.0, v if axis == 1 else 0.0)
        out.append(det.scale(t))
    return out


@pytest.mark.parametrize("axis", [0, 1])
def test_a_1_3_hz_cycle_at_the_tilt_limit_is_seen_at_its_second_peak(axis: int) -> None:
    det = LimitCycleDetector(CycleGuardGains())
    scales = _feed(det, 1.3, 6.0, 3.0, axis)  # ~g·tan(0.6): the correction of a cycle at the tilt limit
    assert det.detections >= 1 and det.t_first_s is not None
    assert det.t_first_s <= 0.75 / 1.3 + PERIOD_S  # peaks at 1/4 and 3/4 of a period
    assert scales[-1] == pytest.approx(0.4)


def test_a_pendulum_swing_a_small_wobble_and_a_steady_push_are_no_cycle() -> None:
    g = CycleGuardGains()
    pendulum = LimitCycleDetector(g)
    _feed(pendulum, 0.7, 5.0, 10.0)  # a 0.5 m cable's pendulum, large: half a period 0.71 s > window
    assert pendulum.detections == 0
    small = LimitCycleDetector(g)
    _feed(small, 1.5, 2.0, 10.0)  # fast but within the threshold
    assert small.detections == 0
    held = LimitCycleDetector(g)
    for n in range(2000):
        held.correction(n * PERIOD_S, 5.5, -5.5)  # pushing hard against a gust on both axes: one sign each
    assert held.detections == 0 and held.scale(8.0) == 1.0


def test_the_guard_holds_then_recovers_and_ignores_non_finite_commands() -> None:
    g = CycleGuardGains(peaks=3, scale=0.4, hold_s=2.0, recover_s=3.0)
    det = LimitCycleDetector(g)
    det.correction(0.0, math.nan, math.inf)
    det.correction(0.1, -math.inf, math.nan)
    assert det.detections == 0
    det.correction(1.0, 3.0, 0.0)
    det.correction(1.5, -3.0, 0.0)  # opposite peak 0.5 s later: with peaks = 3 not yet a cycle
    assert det.detections == 0
    det.correction(1.6, 0.0, 0.0)
    det.correction(2.0, 3.0, 0.0)  # the third alternating peak, 0.5 s after the second
    assert det.detections == 1 and det.t_detect_s == 2.0
    assert det.scale(2.0) == pytest.approx(0.4)  # held from the detection on
    assert det.scale(4.0) == pytest.approx(0.4)
    assert det.scale(5.5) == pytest.approx(0.4 + 0.6 * 1.5 / 3.0)
    assert det.scale(7.5) == 1.0
    det.correction(8.0, -3.0, 0.0)
    det.correction(8.4, 3.0, 0.0)  # two alternating peaks, but 6 s after the last: the run starts again
    assert det.detections == 1


def test_a_broken_guard_table_is_refused(tmp_path) -> None:
    bad = tmp_path / "gains.toml"
    bad.write_text("[cycle]\nscale = 1.5\n")
    with pytest.raises(ConfigError, match=r"\[cycle\].*scale"):
        load_controller_config(bad)
    bad.write_text("[cycle]\nwindow_s = 0\n")
    with pytest.raises(ConfigError, match="window_s"):
        load_controller_config(bad)


def _fly(gains: ControllerConfig, **link) -> tuple[object, dict]:
    """The forest in lockstep through a slow link; (flight log, the loop-margin facts of the report)."""
    mission = load_mission("config/missions/forest.toml")
    cores: list = []
    flog = fly_inprocess(mission, gains=gains, on_tick=lambda core, t: cores or cores.append(core), **link)
    return flog, cores[0].margin.facts(cores[0].profile.nominal_loop_lag_s)


def _hold_tilt_and_alt_error(flog) -> tuple[float, float]:
    e, z = np.array(flog.euler), np.array(flog.pos)[:, 2]
    hold = np.isin(np.array(flog.phase), ["hold", "done"])
    goal_z = -2.0
    flown = np.flatnonzero(z <= goal_z + 0.1)[0]
    return float(np.max(np.hypot(e[hold, 0], e[hold, 1]))), float(np.max(np.abs(z[flown:] - goal_z)))


def _guard(on: bool, soften: bool = False) -> ControllerConfig:
    """The feed-forward's lag fade kept; the position softening and the guard as asked; the slow link's narrower
    tilt limit off (these tests show the guard on its own)."""
    cfg = ControllerConfig()
    cfg = dataclasses.replace(cfg, limits=dataclasses.replace(cfg.limits, tilt_slow_link_rad=cfg.limits.tilt_max_rad))
    if not soften:
        cfg = dataclasses.replace(cfg, smc=dataclasses.replace(cfg.smc, lag_scale_start_s=10.0, lag_scale_end_s=11.0))
    return cfg if on else dataclasses.replace(cfg, cycle=dataclasses.replace(cfg.cycle, scale=1.0))


def test_the_guard_alone_stops_the_cycle_the_fade_leaves() -> None:
    """65 ± 25 ms each way, seed 6, the feed-forward faded but the position loop at full stiffness, a vehicle whose
    mixer lifts the collective for yaw (PX4's ``MC_AIRMODE`` 2): without the guard the hold cycles at the tilt limit
    (0.47 rad, 10 cycles) and the mixer lifts it 0.30 m; with it, the hold is steady (0.16 rad, altitude within
    0.12 m). Seed 5 until the swing observer's low-pass went to 0.25 s; until ``safe`` read the vehicle's own gap
    (2026-12-06) seed 6's cycle peaked at 0.56 rad and climbed 1.1 m (seeds 0-11 now: 0.18-0.56 rad, 0.14-0.32 m)."""
    link = {"link_delay_s": 0.065, "link_jitter_s": 0.025, "link_seed": 6, "air_mode": AIR_MODE_ALL}
    off, off_facts = _fly(_guard(False), **link)
    on, on_facts = _fly(_guard(True), **link)
    tilt_off, alt_off = _hold_tilt_and_alt_error(off)
    tilt_on, alt_on = _hold_tilt_and_alt_error(on)
    assert tilt_off > 0.45 and alt_off > 0.25, (tilt_off, alt_off)
    assert tilt_on < 0.2 and alt_on < 0.5 * alt_off, (tilt_on, alt_on)
    assert off_facts["limit_cycles"] > 0 and off_facts["cycle_guard_s"] == 0.0  # seen, but the guard was off
    assert on_facts["limit_cycles"] >= 1 and on_facts["cycle_guard_s"] > 0.0  # the report says it acted


def test_the_default_flight_on_a_clean_or_50_ms_link_never_trips_the_guard() -> None:
    for link in ({}, {"link_delay_s": 0.05, "link_jitter_s": 0.025, "link_seed": 0}):
        _, facts = _fly(ControllerConfig(), **link)
        assert facts["limit_cycles"] == 0 and facts["cycle_guard_s"] == 0.0, (link, facts)


def test_the_shaped_planners_own_stops_are_no_cycle() -> None:
    """0.1 kg on 2 m, calm: the shaped plan reverses a 0.39 rad commanded tilt within 0.4 s (its input-shaped stops),
    which a detector on the raw commands took for a cycle in every forest of the cell. The correction stays small.
    Flown with the 1 m cable's smoothing (``shaper_period_s`` beyond the 2 m pendulum's): with its own, scaled to
    the period, the same stops ask only 0.2 rad."""
    from companion.launch.fly import DEFAULT_GAINS, load_gains
    from lab.envelope import Cell, cell_mission
    from lab.forests import ForestSpec

    mission = cell_mission(Cell(0.1, 2.0, "calm"), 0, ForestSpec(density_per_100m2=4.0, width_m=6.0, planner="shaped"))
    cfg = load_gains(DEFAULT_GAINS)
    cfg = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, shaper_period_s=10.0))
    cores: list = []
    flog = fly_inprocess(mission, gains=cfg, on_tick=lambda core, t: cores or cores.append(core))
    cmd = np.array(flog.euler_cmd)[:, :2]
    assert np.max(cmd) > 0.3 and np.min(cmd) < -0.3  # the planned reversals are there
    assert cores[0].margin.cycle.detections == 0


def test_on_a_link_with_its_clean_margin_the_guard_does_not_look() -> None:
    """Reversals of the correction on a link whose loop lag is the autopilot's clean one are transients (a blind
    flight's trunk seen late reversed it 7 times and the softened loop then grazed a moving trunk): the guard looks
    only from ``min_excess_s`` of lag beyond the nominal."""
    from companion.flight.loop_margin import LoopMargin

    cfg = ControllerConfig()

    def cycle(margin: LoopMargin, nominal_s: float) -> None:
        for n in range(2000):
            t = n * PERIOD_S
            a = 6.0 * math.sin(2 * math.pi * 1.3 * t)
            r = 0.3 * math.sin(2 * math.pi * 1.3 * (t - 0.16))  # an attitude 0.16 s behind its commands
            margin.after(t, (r, 0.0), (0.3 * math.sin(2 * math.pi * 1.3 * t), 0.0), (a, 0.0), nominal_s)
            margin.factors(t, cfg, nominal_s, softens=True)

    clean = LoopMargin(PERIOD_S, cfg.cycle)
    cycle(clean, nominal_s=0.16)  # the lag measured is the nominal: no excess
    assert clean.lag.lag_s is not None and clean.cycle.detections == 0
    slow = LoopMargin(PERIOD_S, cfg.cycle)
    cycle(slow, nominal_s=0.08)  # 80 ms beyond a clean link
    assert slow.cycle.detections > 0 and slow.facts(0.08)["cycle_guard_s"] > 0.0
