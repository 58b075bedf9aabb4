"""The wind disturbance of the paper's eq. 49, as a model the simulator and the planner can name.

Eq. 49 applies one scalar signal to all six channels of D (eq. 14)::

    w(t) = 0.14·sin(1.5πt − 3.0) − 0.05·sin(2.0πt + 7.0) + 0.08·sin(0.6πt − 4.0)
         + 0.09·sin(0.3πt + 5.0) − 0.10·sin(3.0πt + 3.5) + 0.23

``d = scale·w(t)·[1, 1, 1, 1, 1, 1]``: dx, dy, dz in N (NED), dφ, dθ, dψ in N·m (body frame).
Over t ∈ [0, 40] s, w ranges over −0.095 … +0.592 with mean 0.23.

How large that is: as forces, 0.23 N on a 1.5 kg system is a 0.15 m/s² push (a light breeze). As torques
it is large: 0.23 N·m on Ixx = 0.0087 kg·m² is 26 rad/s² of angular acceleration, and the peak 0.59 N·m is
68 rad/s². Left alone it would flip the vehicle in well under a second. Rejecting it needs torque
authority above the peak on every axis: on roll/pitch that is ordinary (the bundled vehicle has ~2 N·m at
hover with 0.225 m arms), but on yaw a typical propeller drag/thrust ratio of 0.016 m gives only ~0.24 N·m,
so the bundled vehicle uses 0.06 m (0.88 N·m at hover) and an inner loop with integral-free sliding-mode
robust gain above the peak. ``model = "none"`` turns it off; ``scale`` multiplies it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache

WIND_MODELS = ("paper", "none")


@dataclass(frozen=True)
class WindConfig:
    """Which wind model and how strong: ``model`` in :data:`WIND_MODELS`, ``scale`` >= 0 (1 = the paper)."""

    model: str = "paper"
    scale: float = 1.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for an unknown model or a bad scale."""
        if self.model not in WIND_MODELS:
            raise ValueError(f"model: must be one of {', '.join(WIND_MODELS)}, got {self.model!r}")
        if not (math.isfinite(self.scale) and 0.0 <= self.scale <= 10.0):
            raise ValueError(f"scale: must be in [0, 10], got {self.scale}")


# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache()


@njit(cache=True)
def eq49_signal(t_s: float) -> float:
    """The scalar w(t) of eq. 49 (N or N·m) at time ``t_s`` seconds (compiled; callable from kernels)."""
    return (
        0.23
        + 0.14 * math.sin(1.5 * math.pi * t_s - 3.0)
        - 0.05 * math.sin(2.0 * math.pi * t_s + 7.0)
        + 0.08 * math.sin(0.6 * math.pi * t_s - 4.0)
        + 0.09 * math.sin(0.3 * math.pi * t_s + 5.0)
        - 0.10 * math.sin(3.0 * math.pi * t_s + 3.5)
    )


def wind_scale_factor(cfg: WindConfig) -> float:
    """The factor multiplying w(t) on every channel: ``cfg.scale``, or 0 for model "none"."""
    return 0.0 if cfg.model == "none" else float(cfg.scale)


def wind_disturbance(t_s: float, cfg: WindConfig) -> np.ndarray:
    """Disturbance vector d = [dx, dy, dz, dφ, dθ, dψ] (N, N·m) at time ``t_s`` for ``cfg``."""
    if cfg.model == "none" or cfg.scale == 0.0:
        return np.zeros(6)
    return np.full(6, cfg.scale * eq49_signal(t_s))
