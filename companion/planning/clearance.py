"""Time-aware clearance of a planned reference against obstacles whose positions are predicted.

An obstacle j is a vertical cylinder at c_j + v_j·(t − t_now) (constant-velocity prediction; v = 0 for
trunks) whose required clearance grows with the look-ahead, ring_j + growth·(t − t_now), because the
prediction grows uncertain. The reference rows carry the airframe position and the nominal swing, so
both the airframe circle and the payload point are checked at the time the vehicle will be there.

One compiled kernel (numba, cached), O(rows × obstacles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache


@dataclass(frozen=True, slots=True)
class Predicted:
    """Obstacles as arrays (N,): centre now (m), velocity (m/s), required airframe-centre and payload-point
    distances now (m), growth (m per s of look-ahead); ``moving`` (N,) bool; ``payload_shift`` (m, x y): where the
    wind holds the payload off the nominal swing the reference rows carry (the plan check adds it to each payload
    point)."""

    cx: np.ndarray
    cy: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    ring_airframe: np.ndarray
    ring_payload: np.ndarray
    growth: np.ndarray
    moving: np.ndarray
    payload_shift: tuple[float, float] = (0.0, 0.0)

    def __len__(self) -> int:
        return len(self.cx)


use_kernel_cache(Path(__file__))


@njit(cache=True)
def _clearance(ref, t_first, h, t_now, l, cx, cy, vx, vy, ring_a, ring_p, growth, sx, sy, first_hit, worst):
    # pragma: no cover - compiled
    n = ref.shape[0]
    for j in range(len(cx)):
        first_hit[j] = np.inf
        worst[j] = np.inf
    for i in range(n):
        t = t_first + i * h
        dt = max(t - t_now, 0.0)
        ax, ay = ref[i, 0], ref[i, 1]
        al, be = ref[i, 8], ref[i, 9]
        px = ax + l * math.sin(al) * math.cos(be) + sx
        py = ay - l * math.sin(be) + sy
        for j in range(len(cx)):
            ox = cx[j] + vx[j] * dt
            oy = cy[j] + vy[j] * dt
            gr = growth[j] * dt
            da = math.hypot(ax - ox, ay - oy) - ring_a[j] - gr
            dp = math.hypot(px - ox, py - oy) - ring_p[j] - gr
            d = min(da, dp)
            if d < worst[j]:
                worst[j] = d
            if d < 0.0 and first_hit[j] == np.inf:
                first_hit[j] = t


def clearance(ref_rows: np.ndarray, t_first_s: float, h_s: float, t_now_s: float, cable_l_m: float,
              obs: Predicted) -> tuple[np.ndarray, np.ndarray]:
    """Per obstacle: the first time (s) the reference violates its ring (inf if never) and the smallest
    margin (m) over the rows. ``ref_rows`` (n, REF_COLS) start at time ``t_first_s``, one every ``h_s``."""
    first = np.empty(len(obs))
    worst = np.empty(len(obs))
    if len(obs) and len(ref_rows):
        _clearance(np.ascontiguousarray(ref_rows), float(t_first_s), float(h_s), float(t_now_s), float(cable_l_m),
                   obs.cx, obs.cy, obs.vx, obs.vy, obs.ring_airframe, obs.ring_payload, obs.growth,
                   float(obs.payload_shift[0]), float(obs.payload_shift[1]), first, worst)
    else:
        first[:] = np.inf
        worst[:] = np.inf
    return first, worst
