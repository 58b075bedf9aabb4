"""Position controllers: sliding-mode (eqs. 30–37) with payload reaction and anti-swing feed-forward, PID.

Every controller returns the desired thrust force F (NED, N) that :mod:`companion.control.attitude`
turns into attitude and thrust. Position dynamics (eq. 29, NED, z down):

    (M+m)·ξ̈ = F + f + d + (M+m)·g·e_z,    f = −m·r̈,   r = l·[sα·cβ, −sβ, cα·cβ]  (payload offset)

so f = −m·(J·s̈ + J̇·ṡ) with s = [α, β] — the payload's reaction on the airframe (f1–f3 of eq. 29, taken
from the model's Lagrangian rather than the printed expressions). The SMC law (eqs. 32, 37) per axis:

    S = c·e + ė,   F = (M+m)·(c·ė + r̈_ref + k·S + u_ff) + k_sat·sat(S/Δ) − f − (M+m)·g·e_z.

Where and with which sign the feed-forward enters (the paper leaves it open). Linearising the swing
equations around the hanging position with airframe acceleration a (the cable offset is r ≈ l·[α, −β, 1]):

    l·α̈ = −g·α − a_x,     l·β̈ = −g·β + a_y.

An acceleration a_x = +k_rate·l·α̇ alone gives l·α̈ + k_rate·l·α̇ + g·α = 0, damped for k_rate > 0; for β
the sign flips, a_y = −k_rate·l·β̇. In words: the vehicle accelerates along the payload's motion relative
to it, and towards the side the payload hangs out to (angle term). With the position loop closed around
the same acceleration the rate term alone leaves the pendulum mode barely damped (the loop pulls the
vehicle back), so we place the closed-loop poles with an angle term too: for the default SMC gains the
linearised loop (x, ẋ, α, α̇) has every pole at Re <= −1.4 /s with k_angle = 8 /s², k_rate = 1.9 /s, a1 = 0.1
(c = 1.2, k = 2.5; tuned further in closed loop against the bundled physics).
Eq. 48's term u1 = a1·α̈ enters with the opposite sign, acc_x −= l·a1·α̈: since l·α̈ ≈ −g·α − a_x it is
an angle feedback a1·g·α plus an acceleration echo a1·a_x (loop gain a1 < 1, hence the a1 < 0.5 limit);
entered with +, it destabilises the swing. u3 (vertical) does not couple to the swing at first order; its
gain a3 defaults to 0. The feed-forward adds to the commanded acceleration before the mass multiplication
(m/s²), so it passes the same limits as the rest of the command. A test flies both signs closed-loop
(correct sign damps, flipped sign grows).

The PID baseline (cascade: position P → velocity PI) ignores the payload completely.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from companion.control.params import ControllerConfig, FeedForwardGains, PidGains, SmcGains
from companion.core.floats import floats
from companion.core.model import VehicleParams


@dataclass(frozen=True, slots=True)
class PositionOutput:
    """Desired thrust force (N, NED), commanded acceleration and feed-forward (m/s²), payload reaction (N),
    sliding variable S (m/s)."""

    force_ned_n: np.ndarray
    acc_cmd_mps2: np.ndarray
    ff_acc_mps2: np.ndarray
    f_payload_n: np.ndarray
    sliding: np.ndarray


@runtime_checkable
class PositionController(Protocol):
    """Everything the flight core uses of a position controller; every controller implements all of it.

    ``gain_scale``: horizontal stiffness factor (0..1, 1 = the configured gains) the core sets each tick from
    the loop lag where ``softens_with_lag`` (the SMC; the PID baseline keeps its gains and ignores it);
    ``swing_feedforward``: whether :meth:`update` adds the anti-swing feed-forward ff(swing) to the reference
    acceleration (``smc_ff``): the core then hands it a_ref − ff(nominal swing) of a planned reference.
    """

    gain_scale: float

    @property
    def softens_with_lag(self) -> bool: ...

    @property
    def swing_feedforward(self) -> bool: ...

    def update(self, pos, vel, ref_pos, ref_vel, ref_acc, swing: np.ndarray | None, swing_acc,
               dt_s: float) -> PositionOutput:
        """One control step: position, velocity and reference (NED (3,), SI units), swing [α, β, α̇, β̇] (rad,
        rad/s) or None, its acceleration [α̈, β̈] (rad/s²), the time step (s); the thrust force to fly."""
        ...


def _payload_reaction(
    al: float, be: float, dal: float, dbe: float, dda: float, ddb: float, m_kg: float, l_m: float
) -> tuple[float, float, float]:
    """f = −m·(J·s̈ + J̇·ṡ) as three floats (N, NED); see :func:`payload_reaction_n`."""
    ca, sa, cb, sb = math.cos(al), math.sin(al), math.cos(be), math.sin(be)
    k = -m_kg * l_m
    return (
        k * ((ca * cb * dda - sa * sb * ddb)
             + (-sa * cb * dal * dal - 2.0 * ca * sb * dal * dbe - sa * cb * dbe * dbe)),
        k * (-cb * ddb + sb * dbe * dbe),
        k * ((-sa * cb * dda - ca * sb * ddb) + (-ca * cb * (dal * dal + dbe * dbe) + 2.0 * sa * sb * dal * dbe)),
    )


def payload_reaction_n(swing: np.ndarray, swing_acc: np.ndarray, m_kg: float, l_m: float) -> np.ndarray:
    """f = −m·(J·s̈ + J̇·ṡ) (N, NED): the force the swinging payload exerts on the airframe beyond its weight.

    swing = [α, β, α̇, β̇] (rad, rad/s), swing_acc = [α̈, β̈] (rad/s²).
    """
    al, be, dal, dbe = (float(v) for v in swing)
    dda, ddb = (float(v) for v in swing_acc)
    return np.array(_payload_reaction(al, be, dal, dbe, dda, ddb, m_kg, l_m))


def feedforward_xyz(
    al: float, be: float, dal: float, dbe: float, dda: float, ddb: float, ff: FeedForwardGains, l_m: float,
    sign: float = 1.0,
) -> tuple[float, float, float]:
    """:func:`feedforward_acc` on floats (m/s², NED): the control tick's form, no arrays."""
    ux = ff.k_angle * al + ff.k_rate * dal - ff.a1 * dda
    uy = -(ff.k_angle * be + ff.k_rate * dbe - ff.a2 * ddb)
    uz = -ff.a3 * (dda + ddb)
    k = sign * l_m
    return k * ux, k * uy, k * uz


def feedforward_acc(
    swing: np.ndarray, swing_acc: np.ndarray, ff: FeedForwardGains, l_m: float, sign: float = 1.0
) -> np.ndarray:
    """Anti-swing acceleration (m/s², NED), see module docstring; ``sign`` −1 flips it (for the test)."""
    al, be, dal, dbe = (float(v) for v in swing)
    dda, ddb = (float(v) for v in swing_acc)
    return np.array(feedforward_xyz(al, be, dal, dbe, dda, ddb, ff, l_m, sign))


class SwingAccelEstimator:
    """α̈, β̈ (rad/s²) by a first-order filtered derivative of the measured rates (time constant τ)."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self._last: tuple[float, float] | None = None
        self._t = 0.0
        self._v = (0.0, 0.0)

    @property
    def value(self) -> np.ndarray:
        """The current filtered [α̈, β̈] (rad/s²), a copy."""
        return np.array(self._v)

    def update_scalar(self, t_s: float, rate_a: float, rate_b: float) -> tuple[float, float]:
        """Feed α̇, β̇ (rad/s) at time ``t_s``; returns the filtered (α̈, β̈)."""
        if self._last is not None:
            dt = t_s - self._t
            if dt > 0.0:
                k = dt / (self.tau_s + dt)
                va, vb = self._v
                va = va + k * ((rate_a - self._last[0]) / dt - va)
                vb = vb + k * ((rate_b - self._last[1]) / dt - vb)
                self._v = (va, vb)
        self._last = (rate_a, rate_b)
        self._t = t_s
        return self._v

    def update(self, t_s: float, rates: np.ndarray) -> np.ndarray:
        """Feed [α̇, β̇] at time ``t_s``; returns the filtered [α̈, β̈]."""
        return np.array(self.update_scalar(t_s, float(rates[0]), float(rates[1])))

    def reset(self) -> None:
        """Forget history (e.g. when the swing source drops out)."""
        self._last = None
        self._v = (0.0, 0.0)


def _limit_horizontal(a: np.ndarray, a_max: float) -> np.ndarray:
    h = math.hypot(a[0], a[1])
    if h > a_max:
        a = a.copy()
        a[:2] *= a_max / h
    a[2] = min(max(a[2], -a_max), a_max)
    return a


I_REF_SPEED_MPS = 0.3  # the SMC's integral action runs while the reference is slower than this (m/s)


class SmcPositionController:
    """Sliding-mode position controller (eqs. 30–37); ``feedforward`` given = ``smc_ff``, None = ``smc``.

    Scalar arithmetic per axis (this runs every control tick).
    """

    softens_with_lag = True

    def __init__(
        self, gains: SmcGains, params: VehicleParams, feedforward: FeedForwardGains | None, acc_max_mps2: float
    ) -> None:
        self.gains = gains
        self.params = params
        self.ff = feedforward
        self.ff_sign = 1.0  # −1 only to demonstrate the wrong sign in tests
        self.gain_scale = 1.0  # horizontal stiffness factor s (c and k × √s), set per tick from the loop lag
        self.acc_max = acc_max_mps2
        self._c = tuple(float(v) for v in gains.c)
        self._k = tuple(float(v) for v in gains.k)
        self._ks = tuple(float(v) for v in gains.k_sat)
        self._bl = tuple(float(v) for v in gains.boundary)
        self._ki = float(gains.ki)
        self._i_lim = float(gains.i_limit_mps2)
        self._integral = [0.0, 0.0]  # horizontal integral action (m/s²), with ki > 0
        #: (m/s², x y) the feed-forward of the swing a timed plan intends (the flight core takes it off the reference
        #: acceleration, :func:`companion.flight.legs.planned_swing_acc`): ``max_mps2`` bounds the rest only
        self.ff_center = (0.0, 0.0)
        #: (m/s², x y) the angle term's share of the swing's slow equilibrium (:mod:`companion.control.swing_bias`),
        #: taken off the feed-forward: it damps the swing about where a steady wind makes the payload hang
        self.ff_bias = (0.0, 0.0)
        #: (m/s², x y) the wind's measured push on the system beyond the ordinary
        #: (:mod:`companion.control.disturbance`), taken off the command: the loop's stiffness alone left it as a
        #: standing error along a moving reference
        self.ext_acc = (0.0, 0.0)

    @property
    def swing_feedforward(self) -> bool:
        """Whether the anti-swing feed-forward is on (``smc_ff``)."""
        return self.ff is not None

    def update(
        self, pos, vel, ref_pos, ref_vel, ref_acc, swing: np.ndarray | None, swing_acc, dt_s: float
    ) -> PositionOutput:
        """One control step; arrays NED (3,), SI units. Without swing: no payload reaction, no FF."""
        p = self.params
        mt = p.M + p.m
        pos, vel = floats(pos), floats(vel)  # element by element below: numpy scalars cost ~10x a float
        if swing is not None:
            al, be, dal, dbe = map(float, floats(swing))
            dda, ddb = float(swing_acc[0]), float(swing_acc[1])
            f_pay = _payload_reaction(al, be, dal, dbe, dda, ddb, p.m, p.l)
            if self.ff is not None:
                ff = feedforward_xyz(al, be, dal, dbe, dda, ddb, self.ff, p.l, self.ff_sign)
                bx, by = self.ff_bias
                if bx != 0.0 or by != 0.0:  # the swing's slow equilibrium (a steady wind's drag): not a swing
                    ff = (ff[0] - bx, ff[1] - by, ff[2])
                # the bound acts on what the feed-forward adds beyond the planned swing's own part
                cx, cy = self.ff_center
                dx, dy = ff[0] - cx, ff[1] - cy
                h_ff = math.hypot(dx, dy)
                if h_ff > self.ff.max_mps2:
                    k = self.ff.max_mps2 / h_ff
                    ff = (cx + dx * k, cy + dy * k, ff[2])
            else:
                ff = (0.0, 0.0, 0.0)
        else:
            f_pay = (0.0, 0.0, 0.0)
            ff = (0.0, 0.0, 0.0)
        s, acc = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        cs, ks = self._c, self._k
        if self.gain_scale != 1.0:
            r = math.sqrt(self.gain_scale)
            cs = (cs[0] * r, cs[1] * r, cs[2])
            ks = (ks[0] * r, ks[1] * r, ks[2])
        for i in range(3):
            e = float(ref_pos[i]) - float(pos[i])
            de = float(ref_vel[i]) - float(vel[i])
            s[i] = cs[i] * e + de
            acc[i] = float(ref_acc[i]) + cs[i] * de + ks[i] * s[i] + ff[i]
        if self._ki > 0.0 and math.hypot(float(ref_vel[0]), float(ref_vel[1])) < I_REF_SPEED_MPS:
            # integral action against a steady force (a mean wind's drag), only while the reference hovers: along
            # a flown path the tracking error is the plan's (and would wind up into an overshoot at its end)
            for i in range(2):
                e = float(ref_pos[i]) - float(pos[i])
                self._integral[i] = min(self._i_lim, max(-self._i_lim, self._integral[i] + self._ki * e * dt_s))
                acc[i] += self._integral[i]
        ex, ey = self.ext_acc
        if ex != 0.0 or ey != 0.0:
            acc[0] -= ex
            acc[1] -= ey
        h = math.hypot(acc[0], acc[1])
        if h > self.acc_max:
            acc[0] *= self.acc_max / h
            acc[1] *= self.acc_max / h
        acc[2] = min(max(acc[2], -self.acc_max), self.acc_max)
        force = [
            mt * acc[i] + self._ks[i] * min(1.0, max(-1.0, s[i] / self._bl[i])) - f_pay[i] for i in range(3)
        ]
        force[2] -= mt * p.g
        return PositionOutput(np.array(force), np.array(acc), np.array(ff), np.array(f_pay), np.array(s))


class PidPositionController:
    """Cascade PID baseline: position P → velocity PI with anti-windup clamp; no payload knowledge (no
    feed-forward) and no loop-lag softening (``gain_scale`` stays 1 and is not used)."""

    softens_with_lag = False
    swing_feedforward = False

    def __init__(self, gains: PidGains, params: VehicleParams, acc_max_mps2: float) -> None:
        self.gains = gains
        self.gain_scale = 1.0
        self.params = params
        self.acc_max = acc_max_mps2
        self._kp = np.array(gains.kp)
        self._kv = np.array(gains.kv)
        self._ki = np.array(gains.ki)
        self.integral = np.zeros(3)

    def update(
        self, pos, vel, ref_pos, ref_vel, ref_acc, swing: np.ndarray | None, swing_acc: np.ndarray, dt_s: float
    ) -> PositionOutput:
        """One control step (the swing arguments are ignored)."""
        p = self.params
        mt = p.M + p.m
        v_sp = np.asarray(ref_vel) + self._kp * (np.asarray(ref_pos) - np.asarray(pos))
        ev = v_sp - np.asarray(vel)
        lim = self.gains.i_limit_mps2
        self.integral = np.clip(self.integral + self._ki * ev * dt_s, -lim, lim)
        acc = np.asarray(ref_acc) + self._kv * ev + self.integral
        acc = _limit_horizontal(acc, self.acc_max)
        force = mt * acc
        force[2] -= mt * p.g
        return PositionOutput(force, acc, np.zeros(3), np.zeros(3), ev)


def make_position_controller(name: str, cfg: ControllerConfig, params: VehicleParams) -> PositionController:
    """``smc_ff`` | ``smc`` | ``pid`` from a :class:`~companion.control.params.ControllerConfig`."""
    a_max = cfg.limits.acc_max_mps2
    if name == "smc_ff":
        return SmcPositionController(cfg.smc, params, cfg.feedforward, a_max)
    if name == "smc":
        return SmcPositionController(cfg.smc, params, None, a_max)
    if name == "pid":
        return PidPositionController(cfg.pid, params, a_max)
    raise ValueError(f"controller: unknown controller {name!r} (known: smc_ff, smc, pid)")
