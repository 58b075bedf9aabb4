"""TwoModelEstimator: with payload fixes, the filter that predicts them better flies. On the project's own model
the full filter keeps the flight; where the airframe moves in a way the cable's pull cannot explain (ArduCopter
SITL's payload), the fixes-only filter takes over and the swing error drops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.core.model import accelerations, payload_offset_ned_m, rk4_step
from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_config import SwingEstimatorConfig
from companion.estimation.swing_estimator import SwingEstimator
from companion.estimation.two_model import TwoModelEstimator

P = VehicleParams()
DT = 0.004


def _truth(seconds: float = 10.0, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The project's model hovering with a free swing and a steady push: times, states, noisy fixes, noisy
    velocities."""
    rng = np.random.default_rng(seed)
    x = np.zeros(16)
    x[2] = -2.0
    x[6], x[7] = 0.2, -0.12
    u = np.array([P.hover_thrust_n, 0.0, 0.0, 0.0])
    d = np.array([0.3, -0.2, 0.1, 0.0, 0.0, 0.0])
    n = round(seconds / DT)
    xs = np.zeros((n, 16))
    for k in range(n):
        xs[k] = x
        accelerations(x[:8], x[8:], u, d, P)
        x = rk4_step(x, u, d, P, 1e-3, 4)
    t = np.arange(n) * DT
    fixes = np.array([payload_offset_ned_m(r[6], r[7], P.l) for r in xs]) + rng.normal(0.0, 0.02, (n, 3))
    return t, xs, fixes, xs[:, 8:11] + rng.normal(0.0, 0.02, (n, 3))


def _fly(est, t, xs, fixes, vel) -> float:
    """Feed 250 Hz attitude/thrust, 50 Hz velocity, 10 Hz fixes; the swing RMS error (rad) after 4 s."""
    errs = []
    for k, tk in enumerate(t):
        est.set_attitude_euler(tk, (0.0, 0.0, 0.0))
        est.set_thrust(tk, P.hover_thrust_n)
        if k % 5 == 0:
            est.update_velocity(tk, vel[k], xs[k, 0:3])
        if k % 25 == 0:
            est.update_payload_offset(tk, fixes[k])
        s = est.estimate(tk)
        if tk > 4.0:
            errs.append((s.swing[0] - xs[k, 6], s.swing[1] - xs[k, 7]))
    return float(np.sqrt(np.mean(np.square(errs))))


def _pair(t0: float = 0.0, **cfg):
    c = SwingEstimatorConfig(fix_sigma_m=0.02, vel_sigma_mps=0.02, **cfg)
    kw = {"t0_s": t0, "swing_sigma0_rad": 0.3}
    return SwingEstimator(P, c, **kw), TwoModelEstimator(P, c, **kw)


def test_where_the_model_fits_the_full_filter_keeps_the_flight_unchanged():
    t, xs, fixes, vel = _truth()
    single, two = _pair()
    e_single = _fly(single, t, xs, fixes, vel)
    e_two = _fly(two, t, xs, fixes, vel)
    assert two.selected == "full" and two.switches == 0 and two.ticks_on["fixes"] == 0
    assert e_two == pytest.approx(e_single, rel=1e-12), "the same filter, the same numbers"
    facts = two.selection_facts()
    assert facts["fixes_filter_share"] == 0.0 and facts["fix_prediction_rms_m"]["full"] < 0.05


def test_an_airframe_moved_by_what_the_cable_cannot_explain_hands_the_swing_to_the_fixes_filter():
    """The same payload swing, but the airframe's velocity carries a 1 m/s, 0.5 Hz sway the payload does not
    follow (as ArduCopter SITL's payload pulls the airframe with forces a pendulum has not): the full filter reads
    the sway as the cable's pull and misjudges the swing; the fixes-only filter predicts the fixes better, takes
    over, and the error drops."""
    t, xs, fixes, vel = _truth()
    w = 2.0 * math.pi * 0.5
    sway = np.column_stack([np.sin(w * t), np.cos(w * t), np.zeros_like(t)])
    single, two = _pair()
    e_single = _fly(single, t, xs, fixes, vel + sway)
    e_two = _fly(two, t, xs, fixes, vel + sway)
    assert two.selected == "fixes" and two.switches >= 1, two.selection_facts()
    assert two.selection_facts()["fixes_filter_share"] > 0.4
    assert e_two < 0.6 * e_single, (e_two, e_single)
    # the feed-forward comes from the full model: the full filter's verdict on its fit still bounds the fade
    t_end = float(t[-1]) + 0.004
    assert two.estimate(t_end).fade == min(two.fixes.estimate(t_end).fade, two.full.estimate(t_end).fade)


def test_the_report_counters_are_the_full_filters():
    _, two = _pair()
    assert (two.dropped_late, two.rejected_total, two.resets, two.q_swing_scale) == (0, 0, 0, 1.0)
    assert two.active is two.full
