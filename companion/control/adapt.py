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
"""

from __future__ import annotations

from dataclasses import replace

from companion.control.params import ControllerConfig
from companion.core.model import VehicleParams
from companion.planning.shaping import pendulum_omega_rad_s

#: the configuration the gains were tuned on (Table 1)
REFERENCE = VehicleParams()


def accel_scale(vp: VehicleParams) -> float:
    """ω/ω_ref of the payload's pendulum (held airframe), at most 1."""
    return min(1.0, pendulum_omega_rad_s(vp, "held") / pendulum_omega_rad_s(REFERENCE, "held"))


def adapt_to_payload(cfg: ControllerConfig, vp: VehicleParams) -> ControllerConfig:
    """``cfg`` with its swing-bounded planner accelerations scaled by :func:`accel_scale` (``cfg`` itself when
    the scale is 1: Table 1's payload flies with exactly the tuned values)."""
    k = accel_scale(vp)
    if k >= 1.0:
        return cfg
    p = cfg.planner
    return replace(cfg, planner=replace(p, a_max_mps2=p.a_max_mps2 * k, a_goal_mps2=p.a_goal_mps2 * k,
                                        shaped_a_max_mps2=p.shaped_a_max_mps2 * k))
