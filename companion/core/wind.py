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

``model = "turbulence"`` is physical wind instead (:mod:`companion.core.turbulence`): a mean wind, Dryden
turbulence and a 1-cosine gust, acting as quadratic drag F = ½·ρ·C_d·A·|v_rel|·v_rel (v_rel = wind − the
point's velocity) on the airframe and on the payload, each with its own drag area C_d·A. These are world
settings (the companion never reads ``[wind]``; its own belief about the payload's drag is
``[payload] drag_n_per_mps2``). Defaults: airframe C_d·A = 0.04 m² (a 450-class 1.25 kg quadrotor seen
edge-on: ~0.04 m² of body, arms, battery and motors at C_d ≈ 1; measured quadrotor drag areas of this class
are 0.02–0.06 m²), payload C_d·A = 0.01 m² (a 0.25 kg parcel, a ~10 cm cube at C_d ≈ 1.05). No torques: a
uniform flow's drag on a body whose centre of pressure is its centre of mass has no moment about it, and the
cable is attached at the centre of mass, so neither force depends on (φ, θ, ψ) (their Jacobians w.r.t. the
attitude are zero). The generalised forces (see :func:`generalized_drag`): with the payload at
ξ_p = ξ + r(α, β), Q = Σ (∂p_i/∂q)ᵀ·F_i gives Q_ξ = F_a + F_p, Q_η = 0, Q_(α,β) = Jᵀ·F_p, J = ∂r/∂(α, β).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache

WIND_MODELS = ("paper", "none", "turbulence")
INTENSITIES = ("none", "light", "moderate", "severe")


@dataclass(frozen=True)
class WindConfig:
    """Which wind model and how strong: ``model`` in :data:`WIND_MODELS`, ``scale`` >= 0 (1 = the paper;
    eq. 49 only). For ``model = "turbulence"`` (see the module docstring): mean wind ``mean_speed_mps`` (m/s)
    blowing FROM ``direction_deg`` (clockwise from north); Dryden ``intensity`` in :data:`INTENSITIES` (or
    ``w20_mps`` > 0: the 20 ft wind speed setting σ, m/s) at ``altitude_m`` (m), ``seed``; a 1-cosine gust of
    ``gust_amplitude_mps`` (m/s, along the mean wind) over ``gust_length_m`` (m) from ``gust_start_s`` (s,
    simulation time); drag areas C_d·A (m²) of the airframe and the payload; air density (kg/m³)."""

    model: str = "paper"
    scale: float = 1.0
    mean_speed_mps: float = 0.0
    direction_deg: float = 0.0
    intensity: str = "none"
    w20_mps: float = 0.0
    altitude_m: float = 3.0
    seed: int = 0
    gust_amplitude_mps: float = 0.0
    gust_length_m: float = 10.0
    gust_start_s: float = 10.0
    airframe_drag_area_m2: float = 0.04
    payload_drag_area_m2: float = 0.01
    air_density_kgpm3: float = 1.225

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for an unknown model or a bad scale."""
        if self.model not in WIND_MODELS:
            raise ValueError(f"model: must be one of {', '.join(WIND_MODELS)}, got {self.model!r}")
        if not (math.isfinite(self.scale) and 0.0 <= self.scale <= 10.0):
            raise ValueError(f"scale: must be in [0, 10], got {self.scale}")
        if self.intensity not in INTENSITIES:
            raise ValueError(f"intensity: must be one of {', '.join(INTENSITIES)}, got {self.intensity!r}")
        limits = {"mean_speed_mps": 30.0, "w20_mps": 40.0, "altitude_m": 300.0, "gust_amplitude_mps": 20.0,
                  "airframe_drag_area_m2": 1.0, "payload_drag_area_m2": 1.0, "air_density_kgpm3": 2.0}
        for key, hi in limits.items():
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= hi):
                raise ValueError(f"{key}: must be in [0, {hi:g}], got {v}")
        if not (math.isfinite(self.gust_length_m) and 0.1 <= self.gust_length_m <= 1000.0):
            raise ValueError(f"gust_length_m: must be in [0.1, 1000], got {self.gust_length_m}")
        if not (math.isfinite(self.direction_deg) and math.isfinite(self.gust_start_s)):
            raise ValueError("direction_deg: must be finite")
        if not 0 <= self.seed < 2**63:
            raise ValueError(f"seed: must be in [0, 2^63), got {self.seed}")

    @property
    def is_physical(self) -> bool:
        """True for the drag model (``turbulence``), False for eq. 49 and none."""
        return self.model == "turbulence"

    def drag_coefficients(self) -> np.ndarray:
        """[k_airframe, k_payload] = ½·ρ·C_d·A (N per (m/s)²) for :func:`drag_force`."""
        half_rho = 0.5 * self.air_density_kgpm3
        return np.array([half_rho * self.airframe_drag_area_m2, half_rho * self.payload_drag_area_m2])

    def toml_lines(self) -> list[str]:
        """The ``[wind]`` table's body (keys that differ from the defaults, model and scale always)."""
        out = [f'model = "{self.model}"', f"scale = {float(self.scale)!r}"]
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("model", "scale") or v == f.default:
                continue
            out.append(f'{f.name} = "{v}"' if isinstance(v, str) else f"{f.name} = {v!r}")
        return out


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
    """The factor multiplying w(t) on every channel: ``cfg.scale`` for model "paper", else 0."""
    return float(cfg.scale) if cfg.model == "paper" else 0.0


def wind_disturbance(t_s: float, cfg: WindConfig) -> np.ndarray:
    """Eq. 49's disturbance vector d = [dx, dy, dz, dφ, dθ, dψ] (N, N·m) at time ``t_s`` for ``cfg`` (zero
    unless model "paper": the physical wind depends on the state, see :func:`generalized_drag`)."""
    if cfg.model != "paper" or cfg.scale == 0.0:
        return np.zeros(6)
    return np.full(6, cfg.scale * eq49_signal(t_s))


def drag_force(k: float, v_air, v_point) -> np.ndarray:
    """Quadratic drag (N, NED) on a point moving at ``v_point`` in air moving at ``v_air`` (m/s):
    F = k·|v_rel|·v_rel, v_rel = v_air − v_point, k = ½·ρ·C_d·A (N per (m/s)²)."""
    rel = np.asarray(v_air, dtype=np.float64) - np.asarray(v_point, dtype=np.float64)
    return k * float(np.linalg.norm(rel)) * rel


def generalized_drag(alpha: float, beta: float, l: float, f_air, f_pay) -> np.ndarray:
    """The generalised disturbance (8,) of a force ``f_air`` (N, NED) at the airframe's centre of mass and
    ``f_pay`` (N, NED) on the payload: [Q_ξ (N), Q_η = 0 (N·m), Q_α, Q_β (N·m)] with Q_ξ = f_air + f_pay and
    Q_(α,β) = Jᵀ·f_pay, J = ∂r/∂(α, β) of the payload offset r = l·[sα·cβ, −sβ, cα·cβ] (eqs. 3–4).
    This is the ``d`` (8,) that :func:`companion.core.model.accelerations` takes."""
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    jac = l * np.array([[ca * cb, -sa * sb], [0.0, -cb], [-sa * cb, -ca * sb]])
    fp = np.asarray(f_pay, dtype=np.float64)
    out = np.zeros(8)
    out[0:3] = np.asarray(f_air, dtype=np.float64) + fp
    out[6:8] = jac.T @ fp
    return out
