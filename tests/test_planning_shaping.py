"""Swing-free shaping: the pendulum frequency against the model, no residual swing on the model, the time line.

The residual-swing tests fly the full Lagrangian model (companion.core.model.rk4_step) with the airframe's
horizontal acceleration prescribed: a very heavy airframe (M = 10⁶·m, hover thrust) pushed by an inertial
force (M+m)·a(t), so the payload sees exactly the commanded support acceleration, as it does behind the
position controller that cancels the payload's reaction.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.core.model import VehicleParams, rk4_step
from companion.planning.shaping import box_widths, cascade_lag, pendulum_omega_rad_s, shape_reference, shaper_taus_s
from companion.planning.timeline import Timeline

H = 0.01
A_MAX = 1.85


def _zero_crossing_period(t: np.ndarray, s: np.ndarray) -> float:
    i = np.flatnonzero(np.sign(s[:-1]) != np.sign(s[1:]))
    tc = t[i] - s[i] * (t[i + 1] - t[i]) / (s[i + 1] - s[i])
    return float(2.0 * np.mean(np.diff(tc)))


def _simulate(p: VehicleParams, x0: np.ndarray, acc_x: np.ndarray | None, dt: float, n: int) -> np.ndarray:
    """The model from x0, hover thrust, horizontal force (M+m)·acc_x[k] (N) held over step k; states (n+1, 16)."""
    xs = np.empty((n + 1, 16))
    xs[0] = x0
    u = np.array([p.hover_thrust_n, 0.0, 0.0, 0.0])
    d = np.zeros(6)
    for k in range(n):
        d[0] = 0.0 if acc_x is None else p.total_mass * acc_x[min(k, len(acc_x) - 1)]
        xs[k + 1] = rk4_step(xs[k], u, d, p, dt, 1)
    return xs


@pytest.mark.parametrize("support", ["held", "free"])
def test_pendulum_frequency_matches_the_model(support):
    """held: acceleration-prescribed airframe (M → ∞); free: the coupled two-body mode of Table 1."""
    p = VehicleParams() if support == "free" else replace(VehicleParams(), M=0.25e6)
    x0 = np.zeros(16)
    x0[2] = -10.0
    x0[6] = 0.02
    dt = 0.002
    xs = _simulate(p, x0, None, dt, int(8.0 / dt))
    period = _zero_crossing_period(np.arange(len(xs)) * dt, xs[:, 6])
    omega = pendulum_omega_rad_s(VehicleParams() if support == "free" else p, support)
    assert 2.0 * math.pi / omega == pytest.approx(period, rel=1e-3)
    if support == "free":  # the formula, sqrt(g(M+m)/(M·l)), up to the payload's tiny inertia
        q = VehicleParams()
        assert omega == pytest.approx(math.sqrt(q.g * (q.M + q.m) / (q.M * q.l)), rel=1e-5)
    else:
        assert omega == pytest.approx(math.sqrt(p.g / p.l), rel=1e-5)


def _shaped_run(omega_notch: float | None, taus=(0.3, 0.35, 0.4)) -> tuple[np.ndarray, np.ndarray]:
    """Rest-to-rest 1-D move: bang-bang ±A_MAX for 1.5 s each way, shaped; returns (time, reference rows)."""
    widths = box_widths(taus, H)
    n_move = int(1.5 / H)
    pre = cascade_lag(widths) + 10
    a = np.r_[np.zeros(pre), np.full(n_move, A_MAX), np.full(n_move, -A_MAX), np.zeros(int(4.0 / H))]
    u = np.zeros((len(a), 6))
    u[:, 4] = a
    for k in range(1, len(a)):  # exact kinematics of a piecewise-constant acceleration
        u[k, 2] = u[k - 1, 2] + a[k - 1] * H
        u[k, 0] = u[k - 1, 0] + u[k - 1, 2] * H + 0.5 * a[k - 1] * H * H
    if omega_notch is None:  # smoothing only: the airframe flies the payload's path itself
        ref = shape_reference(u, widths, H, 1e9, 9.81)
    else:
        ref = shape_reference(u, widths, H, omega_notch, 9.81)
    return np.arange(len(a)) * H, ref


def _swing_on_model(ref: np.ndarray) -> np.ndarray:
    """α(t) of the model whose airframe accelerates as the reference says (sub-stepped 5×)."""
    p = replace(VehicleParams(), M=0.25e6)
    x0 = np.zeros(16)
    x0[2] = -10.0
    acc = np.repeat(ref[:, 4], 5)
    xs = _simulate(p, x0, acc, H / 5, len(acc))
    return xs[::5, 6][: len(ref)]


def test_the_notch_at_the_model_frequency_leaves_no_residual_swing():
    omega = pendulum_omega_rad_s(VehicleParams(), "held")
    t, ref = _shaped_run(omega)
    alpha = _swing_on_model(ref)
    moving = np.flatnonzero(np.abs(ref[:, 4]) > 1e-9)
    after = t > t[moving[-1]] + 0.05
    residual = float(np.max(np.abs(alpha[after])))
    peak = float(np.max(np.abs(alpha)))
    # the swing while accelerating is the quasi-static tilt atan(a/g) and no more; nothing is left afterwards
    assert peak == pytest.approx(math.atan(A_MAX / 9.81), rel=0.03)
    assert residual < 0.005  # 2.5 % of the swing while accelerating (the 10 ms grid, the small-angle map)
    # the nominal swing the planner hands the controller is what the model does
    assert np.max(np.abs(alpha - ref[:, 8])) < 0.006
    # without the notch, the same smoothed motion leaves the payload swinging
    _, plain = _shaped_run(None)
    alpha_plain = _swing_on_model(plain)
    assert float(np.max(np.abs(alpha_plain[after]))) > 10.0 * residual
    # a notch at the coupled (free-airframe) frequency is the wrong one behind an acceleration-level loop
    _, wrong = _shaped_run(pendulum_omega_rad_s(VehicleParams(), "free"))
    assert float(np.max(np.abs(_swing_on_model(wrong)[after]))) > 3.0 * residual


def test_shaped_reference_is_bounded_and_consistent():
    omega = pendulum_omega_rad_s(VehicleParams(), "held")
    _t, ref = _shaped_run(omega)
    taus = (0.3, 0.35, 0.4)
    # |a_L| <= A_MAX (averages of a bang-bang), so the nominal swing stays within atan-free A/g
    assert np.max(np.abs(ref[:, 8])) <= A_MAX / 9.81 + 1e-9
    # airframe acceleration a_L + a_L''/ω²: |a_L''| <= Δa/(τ2·τ3) with Δa = 2·A at the reversal
    bound = A_MAX + 2.0 * A_MAX / (taus[1] * taus[2]) / omega**2
    assert np.max(np.abs(ref[:, 4])) <= bound
    # velocity is the derivative of position, acceleration of velocity (central differences)
    assert np.max(np.abs((ref[2:, 0] - ref[:-2, 0]) / (2 * H) - ref[1:-1, 2])) < 5e-3
    assert np.max(np.abs((ref[2:, 2] - ref[:-2, 2]) / (2 * H) - ref[1:-1, 4])) < 0.1  # kinks of a_L''
    # ends at rest where the unshaped motion ended, no swing
    assert abs(ref[-3, 2]) < 1e-9 and abs(ref[-3, 8]) < 1e-9


def test_timeline_splice_keeps_the_flown_reference_continuous():
    widths = box_widths((0.3, 0.35, 0.4), H)
    tl = Timeline(0.0, np.zeros(2), H, widths, 3.13, 9.81)
    n = 300
    rows = np.zeros((n, 6))
    tt = np.arange(n) * H
    rows[:, 4] = np.where(tt < 1.5, 1.0, -1.0)
    rows[:, 2] = np.cumsum(rows[:, 4]) * H
    rows[:, 0] = np.cumsum(rows[:, 2]) * H
    tl.splice(5, rows, 0)
    t_now = 1.234
    before = [tl.sample(t_now + k * H) for k in range(3)]
    k_now = tl.index(t_now)
    k_r = k_now + 5
    u0 = tl.unshaped_at(k_r)
    turn = np.zeros((200, 6))
    turn[:, 0:2] = u0[0:2] + np.outer(np.arange(200) * H, u0[2:4])
    turn[:, 2:4] = u0[2:4]
    turn[:, 5] = 1.5  # a new plan: turn sideways from k_r on
    tl.splice(k_r, turn, k_now)
    after = [tl.sample(t_now + k * H) for k in range(3)]
    # what is being flown now is untouched (a replan changes rows from 5 steps ahead: position, velocity and
    # acceleration from 3 steps ahead, the jerk's third difference from 2)
    assert np.allclose(np.array(before)[:2], np.array(after)[:2], rtol=0.0, atol=1e-12)
    assert np.allclose(np.array(before)[:, :6], np.array(after)[:, :6], rtol=0.0, atol=1e-12)
    later = np.array([tl.sample(t_now + k * H) for k in range(3, 200)])
    assert np.max(np.abs(np.diff(later[:, 4]))) < 0.2  # and it bends smoothly into the new plan


def _lead_ratio(l_m: float, taus: tuple[float, ...]) -> float:
    """Peak airframe acceleration over peak planned acceleration for a plan whose acceleration flips sign at the
    cascade's rhythm (re-plans in turbulence), on a cable of ``l_m``."""
    omega = pendulum_omega_rad_s(VehicleParams(l=l_m), "held")
    widths = box_widths(taus, H)
    n = 800
    rows = np.zeros((n, 6))
    half = round(0.5 * (taus[1] + taus[2]) / H)  # the worst rhythm for the cascade's second derivative
    rows[100:700, 4] = np.where((np.arange(600) // half) % 2 == 0, 1.0, -1.0)
    rows[:, 2] = np.cumsum(rows[:, 4]) * H
    rows[:, 0] = np.cumsum(rows[:, 2]) * H
    ref = shape_reference(rows, widths, H, omega, 9.81)
    return float(np.max(np.abs(ref[:-2, 4])))


def test_longer_cables_scale_the_cascade_so_the_lead_keeps_its_share():
    taus, period = (0.3, 0.35, 0.4), 2.01
    one = pendulum_omega_rad_s(VehicleParams(l=1.0), "held")
    assert shaper_taus_s(taus, one, period) == taus  # Table 1's cable (period 2.006 s): as configured
    assert shaper_taus_s(taus, pendulum_omega_rad_s(VehicleParams(l=0.5), "held"), period) == taus
    three = pendulum_omega_rad_s(VehicleParams(l=3.0), "held")
    scaled = shaper_taus_s(taus, three, period)
    assert scaled == pytest.approx([t * 2.0 * math.pi / three / period for t in taus])
    # the airframe's peak acceleration per unit of planned acceleration: with the 1 m widths a 3 m cable asks
    # ~2.5 times what a 1 m cable does; with the scaled ones no more
    r1 = _lead_ratio(1.0, taus)
    assert _lead_ratio(3.0, taus) > 2.0 * r1
    assert _lead_ratio(3.0, scaled) <= 1.05 * r1
