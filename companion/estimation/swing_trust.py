"""How far to trust the swing estimator's estimate: the averaged normalized innovation squared (NIS per degree of
freedom, ≈ 1 when the model and the noise settings describe the data) per measurement source over a window, the
1σ of the swing angle from the covariance, and the ``fade`` in [0, 1] they give (the feed-forward is scaled by
it). Pure: numbers in, numbers out; angles in rad.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.estimation.swing_config import SwingEstimatorConfig
from companion.estimation.swing_ekf_parts import Event

SOURCES = ("imu", "fix", "vel")
NIS_CAP = 100.0  # one outlier's NIS counts at most this much (in the trust average and the q_swing adaptation)


def windowed_nis(events: Sequence[Event], t_lo: float) -> tuple[dict[str, float], tuple[str, ...], int]:
    """(mean NIS per degree of freedom per source, the sources present in :data:`SOURCES` order, events rejected)
    over the events at or after ``t_lo`` (s); ``events``: the filter's events in time order."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    rejected = 0
    for e in reversed(events):
        if e.t < t_lo:
            break
        sums[e.kind] = sums.get(e.kind, 0.0) + min(e.nis, NIS_CAP) / 3.0
        counts[e.kind] = counts.get(e.kind, 0) + 1
        rejected += 0 if e.accepted else 1
    nis = {k: sums[k] / counts[k] for k in sums}
    sources = tuple(s for s in SOURCES if s in nis)
    return nis, sources, rejected


def swing_sigma_rad(P: np.ndarray) -> float:
    """The 1σ (rad) of the swing angle along its most uncertain direction: √ of the larger eigenvalue of the
    covariance's [α, β] block."""
    Ps = P[0:2, 0:2]
    tr = 0.5 * (Ps[0, 0] + Ps[1, 1])
    det = Ps[0, 0] * Ps[1, 1] - Ps[0, 1] * Ps[1, 0]
    return math.sqrt(max(tr + math.sqrt(max(tr * tr - det, 0.0)), 0.0))


def fade(sigma_rad: float, nis: dict[str, float], q_swing_scale: float, cfg: SwingEstimatorConfig) -> float:
    """The feed-forward's factor in [0, 1]: the product of three ramps, on 3σ of the swing angle
    (``fade_bound3_rad``), on the worst source's mean NIS (``fade_nis``) and on q_swing's adapted factor
    (``fade_q_scale``: the model keeps failing to predict the fixes)."""
    f_sigma = _ramp_down(3.0 * sigma_rad, *cfg.fade_bound3_rad)
    f_nis = _ramp_down(max(nis.values()), *cfg.fade_nis) if nis else 1.0
    f_fit = _ramp_down(q_swing_scale, *cfg.fade_q_scale)
    return f_sigma * f_nis * f_fit


def _ramp_down(v: float, lo: float, hi: float) -> float:
    """1 below ``lo``, 0 above ``hi``, linear between."""
    if v <= lo:
        return 1.0
    if v >= hi:
        return 0.0
    return (hi - v) / (hi - lo)
