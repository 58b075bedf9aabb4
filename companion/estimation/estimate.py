"""The vehicle state estimate the flight core consumes, and swing angles from a payload position.

The swing angles (α, β) are defined by the payload offset r = ξ_p − ξ = l·[sα·cβ, −sβ, cα·cβ] (eqs. 3–4,
NED). Inverting: β = asin(−r_y / l), α = atan2(r_x, r_z). Rates follow from ṙ = J·[α̇, β̇] with
J = l·[[cα·cβ, −sα·sβ], [0, −cβ], [−sα·cβ, −cα·sβ]], whose columns are orthogonal (JᵀJ = l²·diag(cβ², 1)),
so the least-squares solution is simply [α̇, β̇] = diag(1/(l²cβ²), 1/l²)·Jᵀ·ṙ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SWING_SOURCES = ("cable_sensor", "payload_position", "estimate", "none")


@dataclass(frozen=True, slots=True)
class Estimate:
    """One sample of the vehicle state, as the companion sees it.

    t_s: time, s; pos_ned_m, vel_ned_mps: airframe position (m) and velocity (m/s) in NED;
    euler_rad: [φ, θ, ψ] rad (ZYX, body FRD to NED); rates_frd_rad_s: body rates, rad/s;
    swing: [α, β, α̇, β̇] (rad, rad/s) or None when no swing measurement is available;
    swing_source: one of :data:`SWING_SOURCES`; for ``"estimate"`` (the swing estimator,
    :mod:`companion.estimation.swing_estimator`) also swing_fade (0..1, how much feed-forward the estimate
    can carry) and swing_bound_rad (|swing| + 3σ, the swing angle the envelope should assume).
    """

    t_s: float
    pos_ned_m: np.ndarray
    vel_ned_mps: np.ndarray
    euler_rad: np.ndarray
    rates_frd_rad_s: np.ndarray
    swing: np.ndarray | None = None
    swing_source: str = "none"
    swing_fade: float = 1.0
    swing_bound_rad: float | None = None
    pos_accuracy_m: float | None = None  # 1σ horizontal position accuracy the autopilot reports (m), if it does

    def with_position(self, pos_ned_m: np.ndarray) -> Estimate:
        """The same estimate at another position (m, NED): ``dataclasses.replace`` without its per-call field
        introspection (this runs every control tick)."""
        return Estimate(self.t_s, pos_ned_m, self.vel_ned_mps, self.euler_rad, self.rates_frd_rad_s, self.swing,
                        self.swing_source, self.swing_fade, self.swing_bound_rad, self.pos_accuracy_m)


def widened_swing(alpha_rad: float, beta_rad: float, bound_rad: float) -> tuple[float, float]:
    """(α, β) (rad) stretched along their direction to the magnitude ``bound_rad`` (|swing| + 3σ of an uncertain
    estimate), the swing angles the envelope (eqs. 20–21) assumes; along α when the swing is ~0."""
    mag = math.hypot(alpha_rad, beta_rad)
    if mag > 1e-9:
        return alpha_rad * bound_rad / mag, beta_rad * bound_rad / mag
    return bound_rad, 0.0


def swing_sigma_rad(est: Estimate) -> float:
    """1σ (rad) of the swing's error, for a planner that widens its envelope by it: from the estimate's 3σ bound
    ``swing_bound_rad`` = |(α, β)| + 3σ, else 0 (no bound: an exact sensor, or no swing)."""
    bound = est.swing_bound_rad
    if bound is not None and est.swing is not None and math.isfinite(float(bound)):
        return max(0.0, (float(bound) - math.hypot(float(est.swing[0]), float(est.swing[1]))) / 3.0)
    return 0.0


def swing_from_payload(
    pos_ned_m: np.ndarray,
    payload_pos_ned_m: np.ndarray,
    vel_ned_mps: np.ndarray,
    payload_vel_ned_mps: np.ndarray,
    l_m: float,
) -> np.ndarray:
    """[α, β, α̇, β̇] (rad, rad/s) from airframe and payload positions/velocities (NED), inverting eqs. 3–4.

    The measured offset is projected onto the sphere of radius ``l_m`` (the cable is rigid in the model), so
    small position noise never produces asin arguments outside [−1, 1].
    """
    r = np.asarray(payload_pos_ned_m, dtype=np.float64) - np.asarray(pos_ned_m, dtype=np.float64)
    n = float(np.linalg.norm(r))
    if not (n > 1e-9 and math.isfinite(n)) or l_m <= 0.0:
        raise ValueError(f"payload offset {r.tolist()} or cable length {l_m} cannot give swing angles")
    u = r / n
    beta = math.asin(max(-1.0, min(1.0, -u[1])))
    alpha = math.atan2(u[0], u[2])
    rd = np.asarray(payload_vel_ned_mps, dtype=np.float64) - np.asarray(vel_ned_mps, dtype=np.float64)
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    j_a = l_m * np.array([ca * cb, 0.0, -sa * cb])
    j_b = l_m * np.array([-sa * sb, -cb, -ca * sb])
    dalpha = float(j_a @ rd) / max(l_m * l_m * cb * cb, 1e-9)
    dbeta = float(j_b @ rd) / (l_m * l_m)
    return np.array([alpha, beta, dalpha, dbeta])
