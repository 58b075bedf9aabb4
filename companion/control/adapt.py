"""Gains and limits that follow the payload: the swing-bounded accelerations scale with the pendulum frequency.

The controller and the planners were tuned on Table 1's configuration (0.25 kg on a 1 m cable). Most of what
depends on the payload already follows it through the model: the position SMC works on the total mass M + m,
the anti-swing feed-forward is proportional to the cable length (:class:`~companion.control.params.FeedForwardGains`),
the shaped planner's notch sits at the payload's own pendulum frequency and the envelope radius is l·sin θ.
What does not is the acceleration the planners allow. A replan changes the reference's acceleration within a
few control ticks; the payload answers a change Δj of jerk with a residual swing of about Δj/(g·ω), so a longer
cable (smaller ω) swings more for the same plan. Scaling the swing-bounded accelerations by ω/ω_ref keeps that
residual at Table 1's level; the nominal swing atan(a/g) shrinks with it. It is never raised above the tuned
value (a short cable keeps Table 1's limits). Measured on the payload grid (docs/measurements.md, 2026-12-03):
with a 3 m cable the worst swing over five forests went from 0.26–0.29 rad to 0.12–0.14 rad, for 10–15 % more time.

Nor do the anti-swing gains. With the position SMC's c, k the linearised loop of one axis (airframe, pendulum,
feed-forward: :func:`swing_loop_matrices`) has its slowest pole at −1.44 /s on Table 1's 1 m cable, but at −0.60 /s
on 2 m and −0.37 /s on 3 m: the airframe wanders off its plan for seconds after each gust on the payload
(0.4 m past a trunk, docs/measurements.md, 2026-12-05). For a cable longer than Table 1's the angle and rate gains
are placed again (:func:`placed_swing_gains`): the pair up to the configured values whose slowest pole is the
fastest, among those whose swing answers a force on the payload no more than the configured gains' do. On 2 m
that is k_angle 4.7 /s², k_rate 0.33 /s: the slowest pole at −1.12 /s, the airframe's answer to a force on the
payload halved, the swing's the same.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from companion.control.params import ControllerConfig, FeedForwardGains
from companion.core.model import VehicleParams
from companion.planning.shaping import pendulum_omega_rad_s

#: the configuration the gains were tuned on (Table 1)
REFERENCE = VehicleParams()


def accel_scale(vp: VehicleParams) -> float:
    """ω/ω_ref of the payload's pendulum (held airframe), at most 1."""
    return min(1.0, pendulum_omega_rad_s(vp, "held") / pendulum_omega_rad_s(REFERENCE, "held"))


def swing_loop_matrices(l_m: float, g: float, c: float, k: float, a1: float, k_angle, k_rate) -> np.ndarray:
    """The linearised loop of one horizontal axis, state (x, ẋ, α, α̇), as (..., 4, 4) matrices for arrays of
    ``k_angle`` (1/s²) and ``k_rate`` (1/s): the SMC (c, k in 1/s, the payload's reaction cancelled, so the airframe
    flies the commanded acceleration a), the feed-forward a += l·(k_angle·α + k_rate·α̇ − a1·α̈) and the pendulum
    l·α̈ = −g·α − a (:mod:`companion.control.position`)."""
    ka, kr = np.broadcast_arrays(np.asarray(k_angle, dtype=np.float64), np.asarray(k_rate, dtype=np.float64))
    a = np.zeros((*ka.shape, 4, 4))
    row = np.stack([np.full(ka.shape, -c * k), np.full(ka.shape, -(c + k)), l_m * ka + a1 * g, l_m * kr], -1)
    row = row / (1.0 - a1)
    a[..., 0, 1] = 1.0
    a[..., 1, :] = row
    a[..., 2, 3] = 1.0
    a[..., 3, :] = -row / l_m
    a[..., 3, 2] -= g / l_m
    return a


#: (rad/s) where the payload's swing answers a force on it: the turbulence's band around every cable's pendulum
FREQS_RAD_S = np.logspace(-1.0, 1.3, 120)


def loop_response(l_m: float, g: float, c: float, k: float, a1: float, k_angle, k_rate
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per gain pair (:func:`swing_loop_matrices`): the peak over :data:`FREQS_RAD_S` of the swing's answer to a
    force on the payload (rad per m/s² of the force over the payload's mass), of the airframe's (m per m/s²), and
    the largest real part of the loop's poles (1/s)."""
    a = swing_loop_matrices(l_m, g, c, k, a1, k_angle, k_rate)
    b = np.zeros(4)
    b[3] = 1.0 / l_m  # l·α̈ = −g·α − a + f
    m = 1j * FREQS_RAD_S[:, None, None] * np.eye(4) - a[..., None, :, :]
    x = np.linalg.solve(m, np.broadcast_to(b, m.shape[:-1])[..., None])[..., 0]
    return np.abs(x[..., 2]).max(-1), np.abs(x[..., 0]).max(-1), np.linalg.eigvals(a).real.max(-1)


def _best(l_m, g, c, k, a1, ka, kr, swing_peak_max: float) -> tuple[float, float]:
    swing, _, pole = loop_response(l_m, g, c, k, a1, ka, kr)
    i = np.unravel_index(np.argmin(np.where(swing <= swing_peak_max, pole, np.inf)), pole.shape)
    return float(ka[i]), float(kr[i])


@lru_cache(maxsize=64)
def placed_swing_gains(l_m: float, g: float, c: float, k: float, a1: float, k_angle_max: float,
                       k_rate_max: float) -> tuple[float, float]:
    """(k_angle 1/s², k_rate 1/s) in [0, max] whose loop's slowest pole is the fastest among those whose swing
    answers a force on the payload no more than the configured gains' do (:func:`loop_response`): a grid of
    0.2 /s² by 0.05 /s, then ten times finer around its best."""
    (cap,), _, _ = loop_response(l_m, g, c, k, a1, np.array([k_angle_max]), np.array([k_rate_max]))
    ka, kr = np.meshgrid(np.arange(0.0, k_angle_max + 1e-9, 0.2), np.arange(0.0, k_rate_max + 1e-9, 0.05))
    a0, r0 = _best(l_m, g, c, k, a1, ka, kr, cap)
    ka, kr = np.meshgrid(np.clip(a0 + np.arange(-0.2, 0.2001, 0.02), 0.0, k_angle_max),
                         np.clip(r0 + np.arange(-0.05, 0.05001, 0.005), 0.0, k_rate_max))
    return _best(l_m, g, c, k, a1, ka, kr, cap)


def adapt_feedforward(cfg: ControllerConfig, vp: VehicleParams) -> FeedForwardGains:
    """The anti-swing gains for a cable longer than Table 1's: the pair of :func:`placed_swing_gains`, up to the
    configured values, for the SMC's horizontal c, k (the configured gains for a cable up to Table 1's)."""
    ff = cfg.feedforward
    if vp.l <= REFERENCE.l:
        return ff
    ka, kr = placed_swing_gains(vp.l, vp.g, float(cfg.smc.c[0]), float(cfg.smc.k[0]), ff.a1, ff.k_angle, ff.k_rate)
    return replace(ff, k_angle=ka, k_rate=kr)


def adapt_to_payload(cfg: ControllerConfig, vp: VehicleParams) -> ControllerConfig:
    """``cfg`` with its swing-bounded planner accelerations scaled by :func:`accel_scale` (the reference's, the goal
    approach's, the shaped plan's, and the braking the ``safe`` barrier counts on: a 3 m cable's reference brakes at
    0.58 of the 1 m one's, and a barrier that assumed more let its payload into the trunks) and its anti-swing gains
    placed for the cable (:func:`adapt_feedforward`); ``cfg`` itself for Table 1's payload and shorter cables."""
    k = accel_scale(vp)
    ff = adapt_feedforward(cfg, vp)
    if k >= 1.0 and ff is cfg.feedforward:
        return cfg
    p = cfg.planner
    return replace(cfg, feedforward=ff, planner=replace(p, a_max_mps2=p.a_max_mps2 * k, a_goal_mps2=p.a_goal_mps2 * k,
                                                        a_brake_mps2=p.a_brake_mps2 * k,
                                                        shaped_a_max_mps2=p.shaped_a_max_mps2 * k))
