"""Timing along a path: the fastest motion under an acceleration bound, sampled; stops along it.

Along the path (a C² cubic spline in arc length, clamped to the current heading) the speed is limited by the
lateral acceleration, v <= sqrt(a_max/κ), by ``v_max``, and the tangential acceleration by what the friction
circle leaves, sqrt(a_max² − (v²κ)²): a backward pass from rest at the goal and a forward pass from the current
speed — the time-optimal profile of a point mass with bounded acceleration along a fixed path. The
acceleration of the resulting motion stays within ``a_max`` in norm (up to the 0.1 m discretisation), which is
what bounds the swing (see :mod:`companion.planning.shaping`). :func:`sample_motion` gives position, velocity
and acceleration at uniform times, :func:`stop_along` a stop along the path.

Compiled kernels (numba, cached); the Python wrappers only shape arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache

use_kernel_cache(Path(__file__))

#: (m/s) below this speed a drag budget never stops the speed-up (:func:`_drag_accel`): the flight makes progress
DRAG_V_PROGRESS_MPS = 1.0
#: (m/s) the speed-up budgets the trailing in a headwind this much stronger than the measured wind: ~1.3 σ of light
#: turbulence along the path (Dryden, low altitude: σ_u ≈ 1.5 m/s at 3 m)
DRAG_GUST_MPS = 2.0
#: the speed-up kept below DRAG_V_PROGRESS_MPS, as a fraction of the acceleration bound
DRAG_A_FLOOR = 0.25


@dataclass(frozen=True, slots=True)
class DragBudget:
    """The payload's drag as the timing budgets it (issue 28): ``c`` its drag angle per (m/s)² of airspeed (rad),
    ``wind_estimate`` the wind (m/s, NED x y) as the companion measured it, ``budget_rad`` the swing the planned
    acceleration and the trailing share, ``g`` (m/s²)."""

    c: float
    wind_estimate: tuple[float, float]
    budget_rad: float
    g: float = 9.81

    def array(self, tangents: np.ndarray, a_max: float, turn: np.ndarray) -> np.ndarray:
        """The ``drag`` argument of :func:`_profile` for a path of unit ``tangents`` (n, 2) that turns to the side
        ``turn`` (n,: the sign of its curvature); the wind across it is signed toward the outside of the turn."""
        wx, wy = self.wind_estimate
        wt = tangents[:, 0] * wx + tangents[:, 1] * wy
        wn = (tangents[:, 1] * wx - tangents[:, 0] * wy) * turn
        return np.r_[self.c, self.budget_rad, self.g, DRAG_A_FLOOR * a_max, wt, wn]


@njit(cache=True)
def _spline(s, y, d0x, d0y, clamped):  # pragma: no cover - compiled
    """Second derivatives M (n, 2) of the C² cubic spline through y (n, 2) at knots s; start slope (d0x, d0y)
    when ``clamped``, natural otherwise; natural at the end."""
    n = len(s)
    mm = np.zeros((n, 2))
    if n < 3 and not clamped:
        return mm
    sub = np.zeros(n)
    dia = np.zeros(n)
    sup = np.zeros(n)
    rhs = np.zeros((n, 2))
    h0 = s[1] - s[0]
    if clamped:
        dia[0] = 2.0 * h0
        sup[0] = h0
        rhs[0, 0] = 6.0 * ((y[1, 0] - y[0, 0]) / h0 - d0x)
        rhs[0, 1] = 6.0 * ((y[1, 1] - y[0, 1]) / h0 - d0y)
    else:
        dia[0] = 1.0
    for k in range(1, n - 1):
        hp, hn = s[k] - s[k - 1], s[k + 1] - s[k]
        sub[k] = hp
        dia[k] = 2.0 * (hp + hn)
        sup[k] = hn
        for c in range(2):
            rhs[k, c] = 6.0 * ((y[k + 1, c] - y[k, c]) / hn - (y[k, c] - y[k - 1, c]) / hp)
    dia[n - 1] = 1.0
    # Thomas algorithm
    for k in range(1, n):
        f = sub[k] / dia[k - 1]
        dia[k] -= f * sup[k - 1]
        rhs[k, 0] -= f * rhs[k - 1, 0]
        rhs[k, 1] -= f * rhs[k - 1, 1]
    mm[n - 1, 0] = rhs[n - 1, 0] / dia[n - 1]
    mm[n - 1, 1] = rhs[n - 1, 1] / dia[n - 1]
    for k in range(n - 2, -1, -1):
        mm[k, 0] = (rhs[k, 0] - sup[k] * mm[k + 1, 0]) / dia[k]
        mm[k, 1] = (rhs[k, 1] - sup[k] * mm[k + 1, 1]) / dia[k]
    return mm


@njit(cache=True)
def _spline_eval(s, y, mm, q, out):  # pragma: no cover - compiled
    """Position, first and second derivative at each q: out (len(q), 6) = [x, y, x', y', x'', y'']."""
    n = len(s)
    k = 0
    for i in range(len(q)):
        sq = min(max(q[i], s[0]), s[n - 1])
        if sq < s[k]:
            k = 0
        while k < n - 2 and s[k + 1] < sq:
            k += 1
        h = s[k + 1] - s[k]
        a = s[k + 1] - sq
        b = sq - s[k]
        for c in range(2):
            m0, m1 = mm[k, c], mm[k + 1, c]
            c0 = y[k, c] / h - m0 * h / 6.0
            c1 = y[k + 1, c] / h - m1 * h / 6.0
            out[i, c] = m0 * a * a * a / (6.0 * h) + m1 * b * b * b / (6.0 * h) + c0 * a + c1 * b
            out[i, 2 + c] = -m0 * a * a / (2.0 * h) + m1 * b * b / (2.0 * h) - c0 + c1
            out[i, 4 + c] = m0 * a / h + m1 * b / h


@njit(cache=True)
def _drag_accel(v, c, wt, wn, budget, g, a_floor):  # pragma: no cover - compiled
    """The speed-up (m/s²) at speed ``v`` (m/s) that keeps the planned swing atan(a/g) plus what flying adds to the
    payload's drag trailing along the path within ``budget`` (rad). The trailing is c·|w − v|·(v − w_t) (none with
    a tailwind faster than v; wind ``wt`` along the path and ``wn`` across it, m/s; c the drag angle per (m/s)² of
    airspeed), budgeted in a headwind :data:`DRAG_GUST_MPS` stronger than measured (the plan is timed with the wind
    of its moment; light turbulence moves it by ~1.5 m/s rms), less what the measured wind alone trails it at a
    standstill (that part no timing changes: budgeting it made moderate-wind flights crawl). At least ``a_floor``
    below :data:`DRAG_V_PROGRESS_MPS`; 0 once the trailing fills the budget."""
    rel = v - wt + DRAG_GUST_MPS
    hover = max(-c * math.sqrt(wt * wt + wn * wn) * wt, 0.0)  # what the wind alone trails it at a standstill
    room = budget - max(c * math.sqrt(rel * rel + wn * wn) * rel - hover, 0.0)
    acc = g * math.tan(min(room, 1.0)) if room > 0.0 else 0.0
    if v < DRAG_V_PROGRESS_MPS:
        acc = max(acc, a_floor)
    return acc


@njit(cache=True)
def _lat_accel(v, c, wt, wn_out, a, budget, g, a_floor):  # pragma: no cover - compiled
    """The lateral acceleration (m/s²) a bend may ask at speed ``v``: the payload's drag toward the outside of the
    bend (crosswind ``wn_out`` > 0 blows it there, the wind ``wt`` along the path) and the bend's own swing share
    ``budget`` (rad); a crosswind toward the inside leaves ``a``. At least ``a_floor``."""
    rel = v - wt
    wo = wn_out + DRAG_GUST_MPS  # budgeted in a crosswind this much stronger, as the speed-up in a headwind
    out = c * math.sqrt(rel * rel + wo * wo) * wo
    room = budget - max(out, 0.0)
    lat = g * math.tan(min(room, 1.0)) if room > 0.0 else 0.0
    return max(min(lat, a), a_floor)


@njit(cache=True)
def _profile(kappa, h, v0, a, v_max, a_brake, vcap, drag):  # pragma: no cover - compiled
    """Speeds at stations h apart with curvature kappa: time-optimal under |a| <= a and v <= vcap (per station;
    see module docstring). ``drag`` (c, budget, g, a_floor, wt[0..n), wn[0..n)) as one array (only four values:
    none): the speed-up is also bounded by :func:`_drag_accel`."""
    n = len(kappa)
    v = np.empty(n)
    for i in range(n):
        v[i] = min(v_max, vcap[i], math.sqrt(a / max(kappa[i], 1e-9)))
        if len(drag) > 4:  # held only where the current speed comes down to it at half the bound (a bend's
            # braking shares the bound with its lateral acceleration): never braking harder than the bound for it
            a_lat = _lat_accel(v[i], drag[0], drag[4 + i], drag[4 + n + i], a, drag[1], drag[2], drag[3])
            reach = math.sqrt(max(v0 * v0 - a * h * i, 0.0))
            v[i] = min(v[i], max(math.sqrt(a_lat / max(kappa[i], 1e-9)), reach))
    v[n - 1] = 0.0
    for i in range(n - 2, -1, -1):
        lat = v[i + 1] * v[i + 1] * kappa[i + 1]
        at = math.sqrt(max(a * a - lat * lat, 0.0))
        v[i] = min(v[i], math.sqrt(v[i + 1] * v[i + 1] + 2.0 * at * h))
    vb = v.copy()
    v[0] = v0
    for i in range(n - 1):
        vi = v[i]
        if vi > vb[i] + 1e-9:
            v[i + 1] = max(min(vb[i + 1], vi), math.sqrt(max(vi * vi - 2.0 * a_brake * h, 0.0)))
        else:
            lat = vi * vi * kappa[i]
            at = math.sqrt(max(a * a - lat * lat, 0.0))
            if len(drag) > 4:
                at = min(at, _drag_accel(vi, drag[0], drag[4 + i], drag[4 + n + i], drag[1], drag[2], drag[3]))
            v[i + 1] = min(vb[i + 1], math.sqrt(vi * vi + 2.0 * at * h))
    return v


_NO_DRAG = np.zeros(4)


def drag_budget(c: float, wind: tuple[float, float], budget_rad: float, g: float) -> DragBudget | None:
    """The timing's drag budget for drag angle ``c`` (rad per (m/s)², 0: None) in ``wind`` (m/s): ``budget_rad``
    is what the acceleration's swing and the trailing share."""
    return DragBudget(c, wind, budget_rad, g) if c > 0.0 else None


@dataclass(frozen=True, slots=True)
class Profile:
    """A timed path: spline knots ``knots_s`` (m) and points ``knots_xy`` (n, 2) with second derivatives
    ``knots_m``; stations ``s`` (m), speeds ``v`` (m/s) there, times ``t`` (s) and constant tangential
    accelerations ``a_t`` (m/s²) per interval; ``duration_s``; ``length_m``."""

    knots_s: np.ndarray
    knots_xy: np.ndarray
    knots_m: np.ndarray
    s: np.ndarray
    v: np.ndarray
    t: np.ndarray
    a_t: np.ndarray
    duration_s: float
    length_m: float
    a_peak_mps2: float = 0.0

    def curve(self, s: np.ndarray) -> np.ndarray:
        """[x, y, x', y', x'', y''] (k, 6) of the path at arc lengths ``s`` (m)."""
        q = np.ascontiguousarray(np.atleast_1d(s), dtype=np.float64)
        out = np.empty((len(q), 6))
        _spline_eval(self.knots_s, self.knots_xy, self.knots_m, q, out)
        return out


def speed_profile(points: np.ndarray, v0_mps: float, *, a_max_mps2: float, v_max_mps: float,
                  heading: np.ndarray | None = None, ds_m: float = 0.1, a_brake_mps2: float | None = None,
                  caps: tuple[np.ndarray, np.ndarray] | None = None, drag: DragBudget | None = None) -> Profile:
    """Fastest motion along ``points`` (n, 2) from speed ``v0_mps`` to rest at the end (see module docstring).

    ``heading`` clamps the spline's initial direction. If the current speed is too high for the bend ahead,
    the forward pass brakes with up to ``a_brake_mps2`` (default ``a_max_mps2``) until back under the limit.
    ``caps`` (arc lengths (m) where legs end, their speed limits (m/s)): each station's speed stays under the
    limit of the leg it is on (the last leg's beyond the last end). ``drag``: the speed-up also keeps the planned
    swing plus the payload's drag trailing within its budget (:func:`_drag_accel`; braking is not limited by it:
    a braking swing leans against the trailing).
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    seg = np.hypot(*np.diff(p, axis=0).T)
    keep = np.r_[True, seg > 1e-9]
    p = np.ascontiguousarray(p[keep])
    sk = np.r_[0.0, np.cumsum(np.hypot(*np.diff(p, axis=0).T))]
    length = float(sk[-1])
    if len(p) < 2 or length < 1e-6:
        z = np.zeros(1)
        pk = np.repeat(p[:1], 2, axis=0)
        return Profile(np.array([0.0, 1.0]), pk, np.zeros((2, 2)), z, z, z, np.zeros(0), 0.0, 0.0)
    hd = (0.0, 0.0) if heading is None else (float(heading[0]), float(heading[1]))
    mm = _spline(sk, p, hd[0], hd[1], heading is not None)
    n = max(3, math.ceil(length / ds_m) + 1)
    s = np.linspace(0.0, length, n)
    ev = np.empty((n, 6))
    _spline_eval(sk, p, mm, s, ev)
    sp = np.maximum(np.hypot(ev[:, 2], ev[:, 3]), 1e-9)
    kappa_signed = (ev[:, 2] * ev[:, 5] - ev[:, 3] * ev[:, 4]) / sp**3
    kappa = np.abs(kappa_signed)
    kappa = np.maximum(kappa, np.maximum(np.r_[kappa[1:], kappa[-1]], np.r_[kappa[0], kappa[:-1]]))
    vcap = np.full(n, np.inf)
    if caps is not None:
        ends, lim = np.asarray(caps[0], dtype=np.float64), np.asarray(caps[1], dtype=np.float64)
        vcap = lim[np.minimum(np.searchsorted(ends, s, side="left"), len(lim) - 1)]
    dr = _NO_DRAG if drag is None else drag.array(ev[:, 2:4] / sp[:, None], float(a_max_mps2), np.sign(kappa_signed))
    v = _profile(kappa, s[1] - s[0], float(v0_mps), float(a_max_mps2), float(v_max_mps),
                 float(a_brake_mps2 if a_brake_mps2 is not None else a_max_mps2), np.ascontiguousarray(vcap), dr)
    vm = v[:-1] + v[1:]
    dt = np.where(vm > 1e-9, 2.0 * (s[1] - s[0]) / np.maximum(vm, 1e-9), 0.0)
    t = np.r_[0.0, np.cumsum(dt)]
    a_t = np.where(dt > 0.0, (v[1:] - v[:-1]) / np.maximum(dt, 1e-12), 0.0)
    # the peak of the acceleration sampled (:func:`sample_motion`): the spline is in chord length, not arc length,
    # and a route that turns back on the heading it is clamped to hooks where the two part (|x'| << 1)
    acc = ev[:-1, 4:6] * (v[:-1] ** 2)[:, None] + ev[:-1, 2:4] * a_t[:, None]
    a_peak = float(np.max(np.hypot(acc[:, 0], acc[:, 1]))) if len(a_t) else 0.0
    return Profile(sk, p, mm, s, v, t, a_t, float(t[-1]), length, a_peak)


@njit(cache=True)
def _sample(t_knots, s_knots, v_knots, a_knots, duration, times, out_s):  # pragma: no cover - compiled
    """Arc length, speed and tangential acceleration at ``times``: out_s (k, 3)."""
    j = 0
    nk = len(t_knots)
    for i in range(len(times)):
        t = times[i]
        if t >= duration or nk < 2:
            out_s[i, 0], out_s[i, 1], out_s[i, 2] = s_knots[nk - 1], 0.0, 0.0
            continue
        t = max(t, 0.0)
        while j < nk - 2 and t_knots[j + 1] <= t:
            j += 1
        tau = t - t_knots[j]
        at = a_knots[j]
        out_s[i, 0] = min(s_knots[j] + v_knots[j] * tau + 0.5 * at * tau * tau, s_knots[nk - 1])
        out_s[i, 1] = max(v_knots[j] + at * tau, 0.0)
        out_s[i, 2] = at


def sample_motion(prof: Profile, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position (m), velocity (m/s), acceleration (m/s²), each (k, 2), of the profile at ``times_s``
    (increasing; clamped to [0, duration]; at rest at the end)."""
    times = np.ascontiguousarray(times_s, dtype=np.float64)
    sv = np.empty((len(times), 3))
    _sample(prof.t, prof.s, prof.v, prof.a_t, prof.duration_s, times, sv)
    ev = prof.curve(sv[:, 0])
    p = ev[:, 0:2]
    v = ev[:, 2:4] * sv[:, 1:2]
    a = ev[:, 4:6] * (sv[:, 1:2] ** 2) + ev[:, 2:4] * sv[:, 2:3]
    return p, v, a


def state_at(prof: Profile, t_s: float) -> tuple[float, float]:
    """Arc length (m) and speed (m/s) of the profile ``t_s`` seconds after its start."""
    sv = np.empty((1, 3))
    _sample(prof.t, prof.s, prof.v, prof.a_t, prof.duration_s, np.array([float(t_s)]), sv)
    return float(sv[0, 0]), float(sv[0, 1])


def stop_along(prof: Profile, s0_m: float, v0_mps: float, a_dec_mps2: float, h_s: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration ((k, 2) each, every ``h_s``) of a stop along the profile's path from arc
    length ``s0_m`` at ``v0_mps``, decelerating at ``a_dec_mps2`` (never beyond the path's end)."""
    t_stop = v0_mps / a_dec_mps2 if a_dec_mps2 > 0.0 else 0.0
    t = np.arange(0.0, t_stop + h_s, h_s)
    t = np.minimum(t, t_stop)
    sd = np.maximum(v0_mps - a_dec_mps2 * t, 0.0)
    s = np.minimum(s0_m + v0_mps * t - 0.5 * a_dec_mps2 * t * t, prof.length_m)
    ev = prof.curve(s)
    at = np.where(sd > 0.0, -a_dec_mps2, 0.0)
    return ev[:, 0:2], ev[:, 2:4] * sd[:, None], ev[:, 4:6] * (sd * sd)[:, None] + ev[:, 2:4] * at[:, None]


def brake_rows(p0: np.ndarray, v0: np.ndarray, b_mps2: float, h_s: float) -> np.ndarray:
    """Unshaped rows [p, v, a] ((k, 6), every ``h_s``) of a straight stop from (p0 m, v0 m/s) at ``b_mps2``
    (or just rest when not moving)."""
    speed = math.hypot(float(v0[0]), float(v0[1]))
    if speed < 1e-6:
        row = np.zeros((1, 6))
        row[0, 0:2] = p0
        return row
    u = v0 / speed
    tt = np.arange(0.0, speed / b_mps2 + h_s, h_s)
    tt = np.minimum(tt, speed / b_mps2)
    s = speed * tt - 0.5 * b_mps2 * tt * tt
    sp = np.maximum(speed - b_mps2 * tt, 0.0)
    rows = np.zeros((len(tt), 6))
    rows[:, 0:2] = p0[None, :] + s[:, None] * u[None, :]
    rows[:, 2:4] = sp[:, None] * u[None, :]
    rows[:, 4:6] = np.where(sp[:, None] > 0.0, -b_mps2 * u[None, :], 0.0)
    return rows
