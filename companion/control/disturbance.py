"""The wind's push on the whole vehicle, measured, and taken off the position command (issue 28).

The position loop of :mod:`companion.control.position` holds the reference by stiffness alone while it moves
(its integral action runs only while the reference hovers): a steady horizontal acceleration d the wind puts on
the system leaves a standing error e ≈ d/(c·k) (c·k = 3 /s² with the default gains). In moderate turbulence (6 m/s
mean across the path, gusts to 12 m/s) the airframe's and the payload's drag are 1–2 m/s² on the grid's payloads:
the airframe flew 0.4–0.7 m downwind of a plan that cleared the trunks, and every collision of the moderate grid
came from it (docs/measurements.md, issue 28). A margin in the planner from the observed tracking error could not
tell that error from the one a late re-plan makes (a trunk seen late: the reference jumps, the airframe follows a
moment later), and stopped blind flights in the forest.

The disturbance itself is observable, and it does not depend on the reference. The system's horizontal equation
(eq. 29, the payload's reaction f = −m·r̈ written out, :func:`companion.control.position._payload_reaction`) is

    (M + m)·a = F_h + f_h + d·(M + m),

so d = a − (F_h + f_h)/(M + m) with a the airframe's measured acceleration (the filtered derivative of its
velocity), F_h the horizontal part of the thrust the rotors give (the thrust the last tick commanded, along the
body's −z axis as *measured*, so the attitude loop's lag is not taken for a force) and f_h the payload's reaction
from the swing. A late re-plan changes the command, not d: the estimate sees wind, not plans. The thrust term goes
through the same first-order filter as the velocity's derivative (their lags match), and d is low-passed over
:data:`TAU_S`.

Eq. 49 (the paper's experiment) pushes the airframe by up to 0.59 N per axis (0.56 m/s² on the 1.5 kg system);
the estimate over the lockstep Table 2 forest peaks at 0.50 m/s² (its flight logs, ``shaped``; ``safe`` 0.39). A
push inside :data:`DEADBAND_MPS2` is left to the position loop as before, so those flights are flown exactly as
before (bit-identical logs); beyond it the push is taken off the command, in full from twice the band on
(:func:`companion.control.swing_bias._beyond`, continuous). A mission that declares the airframe's drag says the
wind drags it: the band is then :data:`DEADBAND_DRAG_MPS2`, above the observer's own residual in calm air (at most
0.06 m/s² on the envelope grid's payloads), and the airframe no longer trails its reference, nor the goal, by
push/(c·k) in a light wind (docs/measurements.md, 2026-12-05). A payload drag declared or identified in flight
says so too: the band then comes down to it at :data:`BAND_RAMP_MPS3` (:meth:`ForceObserver.lower_band`; at once,
the command stepped by the push mid speed-up and swung light payloads over the bound).
"""

from __future__ import annotations

import math

from companion.control.position import SwingAccelEstimator, _payload_reaction
from companion.control.swing_bias import _beyond
from companion.core.floats import floats

TAU_S = 0.3  # (s) the low-pass on d: a gust's push builds over a second and more (Dryden, 6 m/s mean)
#: (m/s²) a push up to this is left to the position loop: above eq. 49's 0.56 m/s² peak on Table 1's vehicle
DEADBAND_MPS2 = 0.7
#: (m/s²) the band with the airframe's drag declared: above the observer's calm-air residual (see module docstring)
DEADBAND_DRAG_MPS2 = 0.1
BAND_RAMP_MPS3 = 0.2  # (m/s² per s) how fast the band comes down once the payload's drag is known


def thrust_horizontal(thrust_n: float, phi: float, theta: float, psi: float) -> tuple[float, float]:
    """(N, NED x y) of the rotor thrust ``thrust_n`` (N) along the body's −z axis at Euler angles (rad, ZYX)."""
    cph, sph, sth = math.cos(phi), math.sin(phi), math.sin(theta)
    cps, sps = math.cos(psi), math.sin(psi)
    return -thrust_n * (cps * sth * cph + sps * sph), -thrust_n * (sps * sth * cph - cps * sph)


class ForceObserver:
    """The horizontal acceleration (m/s², NED x y) the wind gives the airframe and payload together; see module
    docstring. ``m_total_kg`` M + m, ``m_payload_kg``, ``l_m`` the cable (m), ``rate_filter_s`` the time constant of
    the filtered derivatives (the feed-forward's). The band a push is left to the position loop within is the
    observer's to decide: :data:`DEADBAND_DRAG_MPS2` from the start when the mission declares the airframe's drag
    (``airframe_drag_declared``), else :data:`DEADBAND_MPS2` until :meth:`lower_band` brings it down."""

    def __init__(self, m_total_kg: float, m_payload_kg: float, l_m: float, rate_filter_s: float,
                 tau_s: float = TAU_S, airframe_drag_declared: bool = False) -> None:
        self.mt, self.m, self.l_m = m_total_kg, m_payload_kg, l_m
        self.rate_filter_s, self.tau_s = rate_filter_s, tau_s
        self.deadband = DEADBAND_DRAG_MPS2 if airframe_drag_declared else DEADBAND_MPS2  # (m/s²)
        self._acc = SwingAccelEstimator(rate_filter_s)
        self._force = (0.0, 0.0)  # (m/s²) (F_h + f_h)/(M + m) through the derivative's filter
        self.mean = (0.0, 0.0)  # (m/s²) the low-passed d
        self._t: float | None = None

    def update(self, t_s: float, vel_ned_mps, euler_rad, thrust_n: float, swing, swing_acc) -> tuple[float, float]:
        """Feed the airframe's velocity (m/s, NED), attitude (rad), the thrust commanded last tick (N), the swing
        [α, β, α̇, β̇] (rad, rad/s) and its [α̈, β̈] (rad/s²) at ``t_s`` (s); returns d (m/s², x y), 0 inside the
        dead band (its magnitude, the direction kept)."""
        ax, ay = self._acc.update_scalar(t_s, float(vel_ned_mps[0]), float(vel_ned_mps[1]))
        fx, fy = thrust_horizontal(thrust_n, float(euler_rad[0]), float(euler_rad[1]), float(euler_rad[2]))
        al, be, dal, dbe = map(float, floats(swing[:4]))
        px, py, _ = _payload_reaction(al, be, dal, dbe, float(swing_acc[0]), float(swing_acc[1]), self.m, self.l_m)
        gx, gy = (fx + px) / self.mt, (fy + py) / self.mt
        if self._t is None:
            self._force = (gx, gy)
        elif t_s > self._t:
            dt = t_s - self._t
            k = dt / (self.rate_filter_s + dt)
            self._force = (self._force[0] + k * (gx - self._force[0]), self._force[1] + k * (gy - self._force[1]))
            k = dt / (self.tau_s + dt)
            mx, my = self.mean
            self.mean = (mx + k * (ax - self._force[0] - mx), my + k * (ay - self._force[1] - my))
        self._t = t_s
        return self.beyond()

    def beyond(self) -> tuple[float, float]:
        """The low-passed d (m/s², x y) outside the dead band (see :func:`companion.control.swing_bias._beyond`,
        applied to its magnitude), else (0, 0)."""
        mx, my = self.mean
        h = math.hypot(mx, my)
        b = _beyond(h, self.deadband)
        if b == 0.0:
            return 0.0, 0.0
        return mx * b / h, my * b / h

    def lower_band(self, dt_s: float) -> None:
        """The payload's drag is known (the wind drags): bring the band ``dt_s`` (s) of :data:`BAND_RAMP_MPS3` closer
        to :data:`DEADBAND_DRAG_MPS2`."""
        if self.deadband > DEADBAND_DRAG_MPS2:
            self.deadband = max(DEADBAND_DRAG_MPS2, self.deadband - BAND_RAMP_MPS3 * max(dt_s, 0.0))

    def reset(self) -> None:
        """Forget the history (the swing input dropped out, or the flight is not under way)."""
        self._acc.reset()
        self._t = None
        self.mean = (0.0, 0.0)


def push_offset(ctl, obs: ForceObserver, t_s: float, vel_ned_mps, euler_rad, thrust_n: float | None, swing,
                swing_acc, trust: float = 1.0) -> None:
    """Set ``ctl.ext_acc`` (m/s², x y) of an SMC for this tick from ``obs``: the thrust commanded last tick (N, None
    on the first), the swing [α, β, α̇, β̇] (rad, rad/s; None without one: no estimate, the observer reset) and its
    [α̈, β̈] (rad/s²). ``trust`` (0..1, the feed-forward's: the swing estimate's fade times the loop-lag trust)
    scales what is taken off: over a late link the thrust commanded last tick is not the thrust flown, and the
    difference reads as a push (65 ± 25 ms each way: the hold cycled on it, tests/test_loop_lag.py)."""
    if swing is None or thrust_n is None:
        obs.reset()
        ctl.ext_acc = (0.0, 0.0)
        return
    dx, dy = obs.update(t_s, vel_ned_mps, euler_rad, thrust_n, swing, swing_acc)
    ctl.ext_acc = (dx * trust, dy * trust) if trust < 1.0 else (dx, dy)
