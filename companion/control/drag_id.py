"""The payload's drag, identified in flight from the swing's wind equilibrium (issue 28).

A payload of mass m and drag coefficient k (N per (m/s)²) in air moving at a = w − v relative to it (w the wind,
v the vehicle's ground velocity, both m/s) hangs off the vertical by the drag angle (small angles)

    e = k·|a|·a/(m·g) = c·|a|·a,      c = k/(m·g)  (rad per (m/s)²),

which :class:`~companion.control.swing_bias.SwingBias` measures from forces (its low-passed equilibrium
(α_eq, β_eq) is e = (α_eq, −β_eq)). Neither c nor w is told to the companion. Their square roots separate them:
u = e/√|e| = √c·(w − v) is linear in the known v, so over any interval in which the wind changes less than the
vehicle's speed, Δu = −√c·Δv, and

    √c = −Σ Δu·Δv / Σ |Δv|²

over the flight (Δ over :data:`LAG_S`, sampled every :data:`SAMPLE_S`; v low-passed like e so their lags match).
The wind's own change over the lag is noise uncorrelated with the vehicle's speed changes, which average it out.
The estimate is given once Σ|Δv|² reaches :data:`SXX_MIN` (about a second of the planned acceleration) and is kept
for the flight (c is the payload's, not the weather's); the wind then follows as w = v + u/√c. In calm air and
eq. 49 (no payload drag) the regression's slope is noise about zero: a c below :data:`C_MIN` is taken as none, so
those flights are planned exactly as before.

With the airframe's drag coefficient k_a declared (``[payload] airframe_drag_n_per_mps2``), the wind's push on the
whole system, d = (k_a + k)·|a|·a/(M + m) (:class:`~companion.control.disturbance.ForceObserver`), measures the same
relative wind at the same moment, so the ratio of the two needs no speed change: with r = e·d/|d|² (a regression
through the origin over the flight's samples, a push of at least :data:`RATIO_PUSH_MIN_MPS2` and a drag angle of
at least :data:`TRACK_MIN_RAD`, the payload lifted), c = r·k_a/((M + m) − r·m·g), given after
:data:`RATIO_SAMPLES_MIN` samples. It is the report's estimate of the payload's drag, the one to declare for the
next flight (median 0.99 of the world's in light turbulence, 0.88 in moderate; the regression's often none); the
flight itself does not use it: flown with it, the grid swung and hit more (docs/measurements.md, twenty-first
sitting).

A payload whose drag the mission declares (``[payload] drag_n_per_mps2`` = k, as it declares mass and cable) has
c = k/(m·g) from take-off (``c_declared``): no speed-up is waited for, and the wind follows from the equilibrium at
once, the hover before the cruise included. In turbulence one speed-up cannot separate c from the wind's own change
(light turbulence, forest 8: the wind along the path changed by 3.5 m/s while the vehicle sped up by 5, and c came
out at 0.35x the truth, after the speed-up it should have shaped; docs/measurements.md, 2026-12-04). In moderate
turbulence it mostly cannot at all: the wind's changes swamp the vehicle's, and the regression's slope stays at or
below zero for whole flights. Until c is known, the gust the planner budgets the payload's drift for is taken from
the spread of u itself (:attr:`DragIdentifier.gust_drag_tan`): u = √c·(w − v) needs no c to be measured.
"""

from __future__ import annotations

import math
from collections import deque

from companion.control.swing_bias import TAU_S as SWING_BIAS_TAU_S

LAG_S = 1.0  # (s) the interval of each difference: the wind's correlation time in light turbulence is ~8 s
SAMPLE_S = 0.1  # (s) one difference per this
SXX_MIN = 10.0  # ((m/s)²) Σ|Δv|² before the estimate is given: ~0.4 s of 1.85 m/s² acceleration
TAU_S = SWING_BIAS_TAU_S  # (s) the low-pass on v: the one on e, so their lags match
GUST_TAU_S = 10.0  # (s) the wind's mean and spread are averaged over this: light turbulence's correlation time
#: a gust budgeted this many standard deviations above the wind now (2 let a gust from 4 to 14 m/s in 3 s outrun the
#: plan: forest 84 in moderate turbulence, docs/measurements.md, 2026-12-05)
GUST_SIGMAS = 3.0
TRACK_MIN_RAD = 0.01  # (rad) a smaller drag angle is no wind to learn the turbulence from (a payload on the ground)
#: (rad per (m/s)²) a smaller c is none: 0.03 rad of trailing at 5 m/s (the swing observer's error is <= 0.017 rad)
C_MIN = 0.0012
RATIO_PUSH_MIN_MPS2 = 0.3  # (m/s²) a smaller push is too near the observer's own error (0.06) to divide by
RATIO_SAMPLES_MIN = 20  # samples (every SAMPLE_S) before the ratio's c is given: 2 s of wind


def declared_drag_c(drag_n_per_mps2: float, payload_kg: float, g_mps2: float) -> float:
    """c = k/(m·g) (rad per (m/s)²) of a payload of ``payload_kg`` whose drag coefficient k the mission declares
    (N per (m/s)²; 0: not declared)."""
    return drag_n_per_mps2 / (payload_kg * g_mps2) if drag_n_per_mps2 > 0.0 else 0.0


class RunningSpread:
    """A 2-vector's running mean and variance per axis, averaged over ~``tau_s`` (s) of the times it is folded in
    (an exponential moving average; the first value starts the mean)."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.mean = (0.0, 0.0)
        self.var = (0.0, 0.0)
        self.t_s: float | None = None

    def fold(self, t_s: float, x: tuple[float, float]) -> None:
        """Fold ``x`` in at ``t_s`` (s)."""
        if self.t_s is None:
            self.mean = x
        elif t_s > self.t_s:
            k = (t_s - self.t_s) / (self.tau_s + t_s - self.t_s)
            mx, my = self.mean
            dx, dy = x[0] - mx, x[1] - my
            self.mean = (mx + k * dx, my + k * dy)
            vx, vy = self.var
            self.var = (vx + k * (dx * dx - vx), vy + k * (dy * dy - vy))
        self.t_s = t_s

    @property
    def sigma(self) -> float:
        """The standard deviation per axis, √(mean of the two variances)."""
        return math.sqrt(0.5 * (self.var[0] + self.var[1]))


class DragIdentifier:
    """c (rad per (m/s)²) and the wind (m/s, NED x y) from the swing's wind equilibrium; see module docstring.
    ``c_declared`` (> 0): the payload's declared c (:func:`declared_drag_c`), used instead of the regression's."""

    def __init__(self, tau_s: float = TAU_S, c_declared: float = 0.0, k_airframe: float = 0.0,
                 m_total_kg: float = 1.0, payload_weight_n: float = 1.0) -> None:
        self.tau_s = tau_s
        self.c_declared = c_declared
        #: the airframe's drag coefficient (N per (m/s)², 0: unknown), the system's mass (kg), the payload's weight (N)
        self.k_airframe, self.m_total_kg, self.payload_weight_n = k_airframe, m_total_kg, payload_weight_n
        self.sed = self.sdd = 0.0  # Σ e·d (rad·m/s²) and Σ |d|² ((m/s²)²) of the ratio's samples
        self.n_ratio = 0
        self._vf: tuple[float, float] | None = None
        self._t: float | None = None
        self._hist: deque[tuple[float, float, float, float, float]] = deque()  # (t, ux, uy, vx, vy)
        self._next_s = -math.inf
        self.sxy = self.sxx = 0.0
        self._u = (0.0, 0.0)
        self._w = RunningSpread(GUST_TAU_S)  # the wind estimate's (m/s), while c is known
        self._u_spread = RunningSpread(GUST_TAU_S)  # u's (rad^½): the gust without c

    @property
    def c(self) -> float:
        """The drag angle per (m/s)² of airspeed (rad): the declared one, else the identified one (0 while unknown or
        below :data:`C_MIN`)."""
        return self.c_declared if self.c_declared > 0.0 else self._fitted()

    def _from_push(self) -> float:
        """c (rad per (m/s)²) from the ratio of the drag angle to the push (module docstring; the report's, not the
        flight's); 0 while it gives none (too few samples, a ratio at or below zero or past the system's own)."""
        if self.n_ratio < RATIO_SAMPLES_MIN or self.sed <= 0.0:
            return 0.0
        r = self.sed / self.sdd
        den = self.m_total_kg - r * self.payload_weight_n
        return r * self.k_airframe / den if den > 0.0 else 0.0

    def _fitted(self) -> float:
        """The regression's own c (rad per (m/s)²; 0 while it gives none), declared or not."""
        if self.sxx < SXX_MIN or self.sxy <= 0.0:
            return 0.0
        c = (self.sxy / self.sxx) ** 2
        return c if c >= C_MIN else 0.0

    def facts(self, payload_kg: float, g_mps2: float) -> dict[str, float | str | None]:
        """The report's ``payload_drag`` for a payload of ``payload_kg`` (kg): k = c·m·g (N per (m/s)²) declared,
        identified in flight by the regression (which runs whether or not k is declared) or why it gave none, and
        from the push's ratio (None without the airframe's drag or enough wind)."""
        mg = payload_kg * g_mps2
        fit = self._fitted()
        ratio = self._from_push()
        why = None
        if fit <= 0.0:
            if self.sxx < SXX_MIN:
                why = f"too little speed change to fit it (Σ|Δv|² {self.sxx:.1f} of {SXX_MIN:g} (m/s)²)"
            elif self.sxy <= 0.0:
                why = "the wind's own changes swamped the vehicle's (the fit's slope is not positive)"
            else:
                why = (f"the fit's c, {(self.sxy / self.sxx) ** 2:.5f} rad per (m/s)², is below the {C_MIN:g} it takes "
                       "for a drag")
        return {"declared_n_per_mps2": round(self.c_declared * mg, 5) if self.c_declared > 0.0 else None,
                "identified_n_per_mps2": round(fit * mg, 5) if fit > 0.0 else None,
                "identified_detail": why,
                "from_push_n_per_mps2": round(ratio * mg, 5) if ratio > 0.0 else None}

    @property
    def wind_estimate(self) -> tuple[float, float]:
        """The wind (m/s, NED x y) now, w = v + u/√c; (0, 0) while c is unknown."""
        c = self.c
        if c <= 0.0 or self._vf is None:
            return 0.0, 0.0
        s = math.sqrt(c)
        return self._vf[0] + self._u[0] / s, self._vf[1] + self._u[1] / s

    @property
    def gust_mps(self) -> float:
        """(m/s) the gust to budget: the wind's speed now plus GUST_SIGMAS standard deviations of its turbulence (per
        axis) over the last ~GUST_TAU_S; 0 while c is unknown or before the payload hangs in any wind."""
        if self.c <= 0.0 or self._w.t_s is None:
            return 0.0
        return math.hypot(*self.wind_estimate) + GUST_SIGMAS * self._w.sigma

    @property
    def gust_drag_tan(self) -> float:
        """The tangent of the payload's drag angle in the gust to budget: c·gust² once c is known
        (:attr:`gust_mps`); before, (|u| + GUST_SIGMAS·σ_u)², u = √c·(w − v) the root of the drag angle now and σ_u
        its spread per axis over the last ~GUST_TAU_S (the vehicle's own speed changes count in it too: the careful
        side); 0 before the payload hangs in any wind."""
        c = self.c
        if c > 0.0:
            g = self.gust_mps
            return c * g * g
        if self._u_spread.t_s is None:
            return 0.0
        r = math.hypot(*self._u) + GUST_SIGMAS * self._u_spread.sigma
        return r * r

    def _track(self, t_s: float, eq_rad: float) -> None:
        """Fold u (unless c is declared: then its spread is never asked for), and the wind estimate while c is
        known, into their spreads at ``t_s`` (s), once the payload hangs in a wind (``eq_rad``, its drag angle,
        beyond TRACK_MIN_RAD: a payload on the ground has none)."""
        if eq_rad < TRACK_MIN_RAD:
            return
        if self.c_declared <= 0.0:
            self._u_spread.fold(t_s, self._u)
        if self.c > 0.0:
            self._w.fold(t_s, self.wind_estimate)

    def update(self, t_s: float, eq_rad: tuple[float, float] | None, vel_ned_mps,
               push_mps2: tuple[float, float] = (0.0, 0.0)) -> None:
        """Feed the equilibrium (α_eq, β_eq) (rad, :attr:`SwingBias.mean`; None: no swing input, the differences'
        history is forgotten), the airframe's velocity (m/s, NED) and the wind's push on the system (m/s², NED x y,
        :attr:`ForceObserver.mean`; read only with the airframe's drag known) at ``t_s`` (s)."""
        if eq_rad is None:
            self.reset()
            return
        vx, vy = float(vel_ned_mps[0]), float(vel_ned_mps[1])
        if self._vf is None or self._t is None:
            self._vf = (vx, vy)
        elif t_s > self._t:
            k = (t_s - self._t) / (self.tau_s + t_s - self._t)
            self._vf = (self._vf[0] + k * (vx - self._vf[0]), self._vf[1] + k * (vy - self._vf[1]))
        self._t = t_s
        ex, ey = float(eq_rad[0]), -float(eq_rad[1])
        r = math.sqrt(math.hypot(ex, ey))
        self._u = (ex / r, ey / r) if r > 0.0 else (0.0, 0.0)
        self._track(t_s, r * r)
        if t_s < self._next_s:
            return
        self._next_s = t_s + SAMPLE_S
        if self.k_airframe > 0.0:
            self._ratio_sample(ex, ey, push_mps2)
        h = self._hist
        h.append((t_s, self._u[0], self._u[1], self._vf[0], self._vf[1]))
        while len(h) > 1 and h[1][0] <= t_s - LAG_S + 1e-9:
            h.popleft()
        t0, ux0, uy0, vx0, vy0 = h[0]
        if t_s - t0 < LAG_S - 1e-9:
            return
        dvx, dvy = self._vf[0] - vx0, self._vf[1] - vy0
        self.sxy -= (self._u[0] - ux0) * dvx + (self._u[1] - uy0) * dvy
        self.sxx += dvx * dvx + dvy * dvy

    def _ratio_sample(self, ex: float, ey: float, push_mps2: tuple[float, float]) -> None:
        """Fold one sample of the drag angle e (rad, NED x y) against the push d (m/s²) into the ratio's sums, when
        both are large enough to mean a wind on a lifted payload."""
        dx, dy = float(push_mps2[0]), float(push_mps2[1])
        dd = dx * dx + dy * dy
        if dd < RATIO_PUSH_MIN_MPS2 * RATIO_PUSH_MIN_MPS2 or math.hypot(ex, ey) < TRACK_MIN_RAD:
            return
        self.sed += ex * dx + ey * dy
        self.sdd += dd
        self.n_ratio += 1

    def reset(self) -> None:
        """Forget the differences' history (the swing input dropped out); the sums are kept."""
        self._hist.clear()
        self._vf = self._t = None
        self._next_s = -math.inf
