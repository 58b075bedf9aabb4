"""What the wind alone does to the payload: the simulator's truth about a physical wind, for ``evaluate`` and for
the report of a flight against a simulated vehicle (computed after the flight from the wind the vehicle flew; the
flight itself is never told the wind, :mod:`companion.core.turbulence`).

A payload of mass m held still in the wind w hangs where its drag F = k·|w|·w (k = ½·ρ·C_d·A) and its weight
balance: at the *drag angle* atan(|F_h| / (m·g + F_z)) off the vertical (NED, F_z > 0 down). No controller that
keeps the airframe where it is can hold the swing below that angle; it is where the swing bound of a grid cell
stops being the controller's to meet. A gust shorter than the pendulum's swing does not hang the payload out to
its angle, so the force is averaged over the half period π·√(l/g) before each instant: the time a pendulum takes to
swing to a new equilibrium.

That angle is quasi-static: a gust that builds within the half period swings the payload *past* its new
equilibrium, and one that falls off in it leaves the payload swinging. :func:`held_swing_rad` is the dynamic
truth of the same question: the largest swing of the payload hung on a rigid cable from a pivot held still in the
wind, its own drag (at its own airspeed) the only force besides gravity and the cable's. A controller that keeps
the airframe still gets exactly that swing; one that moves it can do better or worse. A flight over its swing
bound where this held payload stays inside it is one the controller lost; one where it is beyond the bound too is
the wind's.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.mission import Mission
from companion.core.turbulence import TABLE_DT_S, WindField
from companion.core.wind import WindConfig

use_kernel_cache(Path(__file__))

HELD_DT_S = 0.004  # (s) the held pendulum's RK4 step: a tenth of the shortest cable's (0.1 m) period


def drag_angle_rad(cfg: WindConfig, payload_kg: float, cable_m: float, t_s: np.ndarray, g: float = 9.81,
                   table: np.ndarray | None = None) -> np.ndarray:
    """The drag angle (rad, see module docstring) of a still payload of ``payload_kg`` on ``cable_m`` in the
    physical wind ``cfg`` at the simulation times ``t_s`` (s, >= 0), its drag averaged over the half period.
    ``table``: ``cfg``'s wind table (:meth:`WindField.cover`) reaching past ``t_s``, if already drawn."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0)
    half_period = math.pi * math.sqrt(cable_m / g)
    tab = WindField(cfg).cover(float(t.max())) if table is None else table
    k_payload = float(cfg.drag_coefficients()[1])
    force = k_payload * np.linalg.norm(tab, axis=1)[:, None] * tab  # (n, 3) N, one sample every TABLE_DT_S
    n = max(1, round(half_period / TABLE_DT_S))
    csum = np.vstack([np.zeros((1, 3)), np.cumsum(force, axis=0)])
    idx = np.arange(len(force))
    lo = np.maximum(idx + 1 - n, 0)
    mean = (csum[idx + 1] - csum[lo]) / (idx + 1 - lo)[:, None]  # the trailing half-period mean at each sample
    k = np.clip(np.rint(np.maximum(t, 0.0) / TABLE_DT_S).astype(np.int64), 0, len(force) - 1)
    f = mean[k]
    return np.arctan2(np.hypot(f[:, 0], f[:, 1]), payload_kg * g + f[:, 2])


@njit(cache=True)
def _held_accel(tab, dt_tab, k_m, l, g, t, p, v):  # pragma: no cover - compiled
    """The payload's acceleration (m/s², NED) at offset ``p`` (m, |p| = l) and velocity ``v`` (m/s) from the still
    pivot at ``t`` (s): gravity, its drag k/m·|w − v|·(w − v) in the wind table ``tab`` (one row per ``dt_tab``),
    and the cable's pull that keeps it on the sphere."""
    x = max(t, 0.0) / dt_tab
    i = min(int(x), tab.shape[0] - 2)
    f = x - i
    a = np.empty(3)
    for j in range(3):
        a[j] = (1.0 - f) * tab[i, j] + f * tab[i + 1, j] - v[j]
    s = k_m * math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    acc = s * a
    acc[2] += g
    pull = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + acc[0] * p[0] + acc[1] * p[1] + acc[2] * p[2]) / (l * l)
    return acc - pull * p


@njit(cache=True)
def _held_swing(tab, dt_tab, k_m, l, g, t0, t1, dt, t_from):  # pragma: no cover - compiled
    """The largest max(|α|, |β|) (rad) over [t_from, t1] of the payload hung from rest at its static equilibrium at
    ``t0`` (s); RK4 steps of ``dt`` (s), projected back onto the sphere after each."""
    p = np.empty(3)
    w = tab[min(int(max(t0, 0.0) / dt_tab), tab.shape[0] - 1)]
    s = k_m * math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    for j in range(3):
        p[j] = s * w[j]
    p[2] += g
    p *= l / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    v = np.zeros(3)
    worst = 0.0
    t = t0
    while t < t1:
        a1 = _held_accel(tab, dt_tab, k_m, l, g, t, p, v)
        v1 = v + 0.5 * dt * a1
        a2 = _held_accel(tab, dt_tab, k_m, l, g, t + 0.5 * dt, p + 0.5 * dt * v, v1)
        v2 = v + 0.5 * dt * a2
        a3 = _held_accel(tab, dt_tab, k_m, l, g, t + 0.5 * dt, p + 0.5 * dt * v1, v2)
        v3 = v + dt * a3
        a4 = _held_accel(tab, dt_tab, k_m, l, g, t + dt, p + dt * v2, v3)
        p = p + dt / 6.0 * (v + 2.0 * v1 + 2.0 * v2 + v3)
        v = v + dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        p *= l / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        v -= (v[0] * p[0] + v[1] * p[1] + v[2] * p[2]) / (l * l) * p
        t += dt
        if t >= t_from:
            beta = math.asin(min(1.0, max(-1.0, -p[1] / l)))
            worst = max(worst, abs(math.atan2(p[0], p[2])), abs(beta))
    return worst


def held_swing_rad(cfg: WindConfig, payload_kg: float, cable_m: float, t_from_s: float, t_to_s: float,
                   g: float = 9.81, t_start_s: float = 0.0, table: np.ndarray | None = None) -> float:
    """The largest swing max(|α|, |β|) (rad; α, β as :func:`~companion.core.model.payload_offset_ned_m`) over
    [``t_from_s``, ``t_to_s``] (s) of a payload of ``payload_kg`` on a rigid ``cable_m`` hung from a pivot held still
    in the physical wind ``cfg`` (module docstring), released from rest at its static equilibrium at ``t_start_s``.
    ``table`` as :func:`drag_angle_rad` (reaching past ``t_to_s``)."""
    if t_to_s <= t_from_s:
        return 0.0
    tab = WindField(cfg).cover(t_to_s + HELD_DT_S) if table is None else table
    k_m = float(cfg.drag_coefficients()[1]) / payload_kg
    return float(_held_swing(tab, TABLE_DT_S, k_m, cable_m, g, t_start_s, t_to_s, HELD_DT_S, t_from_s))


class FlightWindTruth(NamedTuple):
    """What the wind alone did over one logged flight (rad): the largest drag angle (:func:`drag_angle_rad`, over
    the log's times) and the largest swing of the payload held still (:func:`held_swing_rad`, over the part in which
    the flown payload hung: from the first nonzero swing reading to the log's end; None without one)."""

    drag_angle_max_rad: float
    held_swing_max_rad: float | None


def wind_truth(wind: WindConfig, payload_kg: float, cable_m: float, g: float, t_s: np.ndarray, swing: np.ndarray
               ) -> FlightWindTruth | None:
    """:class:`FlightWindTruth` of a flight logged at the vehicle's times ``t_s`` (s, (n,)) with the swing readings
    ``swing`` (rad, (n, ≥ 2): α, β; 0 or NaN while the payload lay on the ground), for a payload of ``payload_kg`` on
    ``cable_m`` in the physical wind ``wind``; None without a physical wind or a logged tick."""
    t = np.asarray(t_s, dtype=np.float64)
    if not wind.is_physical or t.size == 0:
        return None
    t_end = float(t.max())
    table = WindField(wind).cover(t_end + HELD_DT_S)
    drag = float(drag_angle_rad(wind, payload_kg, cable_m, t, g, table).max())
    hung = np.flatnonzero(np.nan_to_num(np.abs(np.asarray(swing)[:, :2])).max(axis=1) > 0.0)
    held = None if hung.size == 0 else held_swing_rad(wind, payload_kg, cable_m, float(t[hung[0]]), t_end, g,
                                                       table=table)
    return FlightWindTruth(drag, held)


def report_wind_truth(mission: Mission, facts: dict, t_s: np.ndarray, swing: np.ndarray
                      ) -> dict[str, float | None] | None:
    """The report's ``wind_truth`` of a flight whose vehicle was simulated for it in the mission's world and wind (its
    run ``facts`` say ``simulated``: ``fly --sitl``, ``lab``'s in-process flights): :func:`wind_truth` (rad) of the
    payload it carried (``payload_true``: the bundled vehicle's mass and cable flags, else the mission's), with that
    payload; None otherwise or without a physical wind."""
    if not facts.get("simulated") or not mission.wind.is_physical:
        return None
    v, true = mission.vehicle, facts.get("payload_true") or {}
    m, l_m = true.get("mass_kg", v.m), true.get("cable_length_m", v.l)
    truth = wind_truth(mission.wind, m, l_m, v.g, t_s, swing)
    if truth is None:
        return None
    return {"drag_angle_max_rad": truth.drag_angle_max_rad, "held_swing_max_rad": truth.held_swing_max_rad,
            "payload_kg": m, "cable_m": l_m}
