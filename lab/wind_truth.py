"""What the wind alone does to the payload: the evaluator's truth about a physical wind (the companion is never told
the wind, :mod:`companion.core.turbulence`).

A payload of mass m held still in the wind w hangs where its drag F = k·|w|·w (k = ½·ρ·C_d·A) and its weight
balance: at the *drag angle* atan(|F_h| / (m·g + F_z)) off the vertical (NED, F_z > 0 down). No controller that
keeps the airframe where it is can hold the swing below that angle; it is where the swing bound of a grid cell
stops being the controller's to meet. A gust shorter than the pendulum's swing does not hang the payload out to
its angle, so the force is averaged over the half period π·√(l/g) before each instant: the time a pendulum takes to
swing to a new equilibrium.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.core.mission import Mission
from companion.core.turbulence import TABLE_DT_S, WindField
from companion.core.wind import WindConfig


def drag_angle_rad(cfg: WindConfig, payload_kg: float, cable_m: float, t_s: np.ndarray, g: float = 9.81
                   ) -> np.ndarray:
    """The drag angle (rad, see module docstring) of a still payload of ``payload_kg`` on ``cable_m`` in the
    physical wind ``cfg`` at the simulation times ``t_s`` (s, >= 0), its drag averaged over the half period."""
    t = np.asarray(t_s, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0)
    half_period = math.pi * math.sqrt(cable_m / g)
    tab = WindField(cfg).cover(float(t.max()))
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


def flight_drag_angle_max_rad(mission: Mission, run_dir: Path | str | None) -> float | None:
    """The largest drag angle (rad) over the flight logged in ``run_dir``'s ``flight_log.npz`` (its vehicle times),
    for ``mission``'s payload in its wind; None without a physical wind or a log."""
    if not mission.wind.is_physical or run_dir is None:
        return None
    path = Path(run_dir) / "flight_log.npz"
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as z:
        t = z["t_s"]
    if t.size == 0:
        return None
    v = mission.vehicle
    return float(drag_angle_rad(mission.wind, v.m, v.l, t, v.g).max())
