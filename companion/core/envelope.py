"""Payload position and the swing envelope of the quadrotor–payload system (paper eqs. 3–4, 20–21).

In the horizontal plane the system is abstracted as a circle around the quadrotor's centre whose radius is
the larger of the airframe circle ``r2 = r_uav + L_uav`` and the payload's horizontal offset
``r1 = l·sqrt((cβ·sα)² + sβ²)`` (eq. 20); eq. 21's R-function ``½(r1 + r2 + |r1 − r2|)`` is that maximum.
Without a swing sensor the envelope falls back to the whole cable: ``max(l, r_uav + L_uav)``.
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.model import payload_offset_ned_m
from companion.core.vehicle_params import VehicleParams

__all__ = [
    "envelope_radii_m",
    "full_cable_r_max_m",
    "payload_offset_ned_m",
    "payload_pos_ned_m",
    "r_max_m",
]


def payload_pos_ned_m(pos_ned_m: np.ndarray, alpha_rad: float, beta_rad: float, l_m: float) -> np.ndarray:
    """Payload position ξ_p = ξ + T_p·[0, 0, l] (eq. 3), NED metres."""
    return np.asarray(pos_ned_m, dtype=np.float64) + payload_offset_ned_m(alpha_rad, beta_rad, l_m)


def envelope_radii_m(alpha_rad: float, beta_rad: float, params: VehicleParams) -> tuple[float, float]:
    """(r1, r2) of eq. 20 in metres: payload horizontal offset and airframe circle radius."""
    w1 = math.cos(beta_rad) * math.sin(alpha_rad)
    w2 = math.sin(beta_rad)
    r1 = math.sqrt(params.l**2 * (w1 * w1 + w2 * w2))
    r2 = params.r_uav + params.L_uav
    return r1, r2


def r_max_m(alpha_rad: float, beta_rad: float, params: VehicleParams) -> float:
    """Maximum envelope circle radius R_max of eq. 21 (R-function form of max(r1, r2)), metres."""
    r1, r2 = envelope_radii_m(alpha_rad, beta_rad, params)
    return 0.5 * (r1 + r2 + abs(r1 - r2))


def full_cable_r_max_m(params: VehicleParams) -> float:
    """Envelope radius when the swing is unknown: the cable may point anywhere, max(l, r_uav + L_uav)."""
    return max(params.l, params.r_uav + params.L_uav)
