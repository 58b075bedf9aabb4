"""The swing's slow equilibrium: where the payload hangs in a steady wind, so the anti-swing feed-forward damps
the swing about it instead of chasing it (issue 28).

The feed-forward's angle term (:mod:`companion.control.position`) places the pendulum's poles about the hanging
position θ = 0 (or the swing the plan intends). A steady drag on the payload moves that equilibrium: in a mean wind
w the payload hangs at θ_eq ≈ k_p·|w|·w/(m·g) off the plan. Left in, the angle term reads θ_eq as a swing to
remove and asks for a steady l·k_angle·θ_eq of acceleration towards the side the payload hangs to: downwind. The
position loop can only balance that with a standing error e ≈ l·k_angle·θ_eq/(c·k): with a 2 m cable, 0.12 rad of
drag deflection and the default gains (k_angle 8 /s², c·k 3 /s²) that is 0.6 m downwind of the reference, and it is
what put the airframe into the trunks in moderate turbulence (docs/measurements.md, issue 28, 2026-12-03).

The companion is never told the wind; it sees what the wind does to the payload. The swing equations of a
held pendulum (:mod:`companion.control.position`, l_e = g/ω² its equivalent length) with an external force F on
the payload read l_e·α̈ = −g·α − a_x + F_x/m and l_e·β̈ = −g·β + a_y − F_y/m, so

    α_eq = F_x/(m·g) = (l_e·α̈ + g·α + a_x)/g,     β_eq = −F_y/(m·g) = (l_e·β̈ + g·β − a_y)/g

is where the payload would hang, measured each tick from the swing, its filtered α̈, β̈ (the feed-forward's own)
and the airframe's acceleration (the same filtered derivative of its velocity), then low-passed over
:data:`TAU_S`. The pendulum's own motion cancels in it (that is what the model says), so no filter at the
pendulum frequency is needed and a gust's drag is followed within half a second. What the low-pass trails a
building gust by, rate·τ, the angle term takes for a swing and pulls the airframe downwind with, l·k_angle·rate·τ
(1.35 m/s² for 3 m of cable in a 0.25 rad/s gust at τ = 0.5 s), so τ is short: 0.25 s (docs/measurements.md,
2026-12-05). In calm air and in eq. 49 (whose forces act on the airframe only) the residual is the model's error:
at most 0.017 rad over the lockstep Table 2 forest, computed from its flight logs (0.010-0.014 rad low-passed at
0.25 s, in-process); an equilibrium inside :data:`DEADBAND_RAD` is taken as none (and fully from twice
that on, linearly between), so those flights are flown exactly as before (bit-identical logs).

A building gust moves the equilibrium itself, and the payload rides it: its rate then reads as a swing to the
feed-forward's rate term, which pushed the airframe downwind (1.9 /s × 2 m × 0.35 rad/s ≈ 1.3 m/s² in a moderate
gust: 0.57 m off the plan past a trunk, 0.35 m with the rate taken off; docs/measurements.md). The equilibrium's
rate (:attr:`SwingBias.rate`, of the part beyond the dead band) is taken off with it, so the feed-forward damps the
swing about the moving equilibrium.
"""

from __future__ import annotations

import math

from companion.control.params import FeedForwardGains
from companion.control.position import SwingAccelEstimator, feedforward_xyz

TAU_S = 0.25  # (s) the observer's low-pass: short, for what it trails a gust by (module docstring)
DEADBAND_RAD = 0.03  # (rad) an equilibrium inside this is the model's own error, not a wind (see module docstring)


def _beyond(v: float, band: float) -> float:
    """``v`` outside 2·``band``, 0 inside ``band``, rising linearly between (continuous: no step in the command)."""
    a = abs(v)
    if a <= band:
        return 0.0
    return v if a >= 2.0 * band else v * (a - band) / band


class SwingBias:
    """Where the payload's own drag makes it hang (rad, α and β), from the swing and the airframe's acceleration;
    see module docstring. ``l_eff_m``: the pendulum's equivalent length g/ω² (m, held airframe), ``g`` (m/s²),
    ``rate_filter_s``: the time constant of the airframe acceleration's filtered derivative (the one of α̈, β̈)."""

    def __init__(self, l_eff_m: float, g: float, rate_filter_s: float, tau_s: float = TAU_S,
                 deadband_rad: float = DEADBAND_RAD) -> None:
        self.l_eff_m, self.g, self.tau_s, self.deadband_rad = l_eff_m, g, tau_s, deadband_rad
        self._acc = SwingAccelEstimator(rate_filter_s)  # the same filtered derivative, of the airframe's velocity
        self.mean = (0.0, 0.0)  # the low-passed equilibrium (rad)
        self.rate = (0.0, 0.0)  # how fast the equilibrium beyond the dead band moves (rad/s)
        self._gated = (0.0, 0.0)
        self._t: float | None = None

    def update(self, t_s: float, swing, swing_acc, vel_ned_mps) -> tuple[float, float]:
        """Feed the swing [α, β, ...] (rad), its accelerations [α̈, β̈] (rad/s²) and the airframe's velocity (m/s,
        NED) at ``t_s`` (s); returns the equilibrium (rad), 0 inside the dead band."""
        ax, ay = self._acc.update_scalar(t_s, float(vel_ned_mps[0]), float(vel_ned_mps[1]))
        le, g = self.l_eff_m, self.g
        ea = (le * float(swing_acc[0]) + g * float(swing[0]) + ax) / g
        eb = (le * float(swing_acc[1]) + g * float(swing[1]) - ay) / g
        if self._t is not None and t_s > self._t:
            dt = t_s - self._t
            k = dt / (self.tau_s + dt)
            ma, mb = self.mean
            self.mean = (ma + k * (ea - ma), mb + k * (eb - mb))
            ga, gb = _beyond(self.mean[0], self.deadband_rad), _beyond(self.mean[1], self.deadband_rad)
            self.rate = ((ga - self._gated[0]) / dt, (gb - self._gated[1]) / dt)
            self._gated = (ga, gb)
        self._t = t_s
        return self._gated

    def drift_ned_m(self, l_m: float) -> tuple[float, float]:
        """Where (m, NED x y) the equilibrium holds a payload on ``l_m`` (m) of cable off the vertical below the
        airframe: l·(sin α·cos β, −sin β) of the low-passed equilibrium (dead band not applied)."""
        a, b = self.mean
        return l_m * math.sin(a) * math.cos(b), -l_m * math.sin(b)

    def reset(self) -> None:
        """Forget the history (the swing input dropped out)."""
        self._acc.reset()
        self._t = None
        self.mean = (0.0, 0.0)
        self.rate = self._gated = (0.0, 0.0)


def feedforward_offsets(ctl, bias: SwingBias, t_s: float, swing, swing_acc, vel_ned_mps, swing_nom: tuple | None,
                        trust: float, ff_cfg: FeedForwardGains, l_m: float) -> None:
    """Set ``ctl.ff_center`` and ``ctl.ff_bias`` (m/s², x y) of a feed-forward controller for this tick.

    ``swing`` [α, β, ...] (rad) as measured, None without one (both offsets 0, the observer reset); ``swing_acc``
    its [α̈, β̈] (rad/s²); ``vel_ned_mps`` the airframe's velocity (m/s); ``swing_nom`` a timed plan's nominal swing
    (α, β, α̇, β̇, α̈, β̈), None without one; ``trust`` (0..1) the share of the swing the controller acts on (its
    swing is scaled by it); ``l_m`` the cable length (m)."""
    if swing is None:
        bias.reset()
        ctl.ff_center = ctl.ff_bias = (0.0, 0.0)
        return
    if swing_nom is None:
        ctl.ff_center = (0.0, 0.0)
    else:
        fx, fy, _ = feedforward_xyz(*swing_nom, ff_cfg, l_m, 1.0)
        ctl.ff_center = (trust * fx, trust * fy)
    ba, bb = bias.update(t_s, swing, swing_acc, vel_ned_mps)
    if ba == 0.0 and bb == 0.0:
        ctl.ff_bias = (0.0, 0.0)
        return
    k = trust * ctl.ff_sign * l_m
    ra, rb = bias.rate
    ctl.ff_bias = (k * (ff_cfg.k_angle * ba + ff_cfg.k_rate * ra), -k * (ff_cfg.k_angle * bb + ff_cfg.k_rate * rb))
