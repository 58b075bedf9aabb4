"""The bundled vehicle's own inner loop: attitude sliding-mode control (eqs. 41–47) and the rotor mixer
(eq. 13). Pure functions, no I/O.

Attitude SMC. Per axis i ∈ {φ, θ, ψ}: e = η_d − η (yaw wrapped), ė = η̇_d − η̇, S = c·e + ė (eq. 41), and
the control law of eq. 42 asks for the Euler-angle acceleration η̈* = c·ė + η̈_d + k·S. The paper writes
τ = (η̈* − f)/g per axis with f, g from eq. 17; we use the exact inverse of the (physical) rotational
dynamics instead, which is what f and g stand for without eq. 17's typos and off-diagonal coupling::

    τ = I·(R_η·η̈* + Ṙ_η·η̇) + Ω × IΩ + k_sat ⊙ sat(S)           (body-frame torque, N·m)

with sat() the boundary layer of eq. 32 (width Δ). With the disturbance d_τ the sliding variable settles
where |S| ≈ |d_τ| / (I·k + k_sat/Δ); the defaults keep the roll error under ~0.5° at eq. 49's 0.59 N·m peak.

Mixer. Rotor thrusts f_i = c_T·ω_i² map to [T, τφ, τθ, τψ] through eq. 13 (X frame, arm d, yaw moment
c_M/c_T per newton). The inverse is exact; when a rotor would leave [0, f_max], the collective may be lowered
(never below what the rotors need), and raised only as PX4's ``MC_AIRMODE`` allows: 0 (PX4's default; always
on the ground) never, 1 as far as roll/pitch need, 2 for yaw too. What still does not fit is given up yaw
first (the largest fraction of the yaw torque that fits is kept), then roll/pitch are scaled down.

The bundled vehicle flies 2: eq. 49 puts 0.59 N·m on roll, pitch and yaw at once, more than hover thrust leaves
for yaw, so at 0 or 1 the heading wanders by ~23° at the paper's scale and spins at 1.3. The price: the mixer
lifts the collective against a thrust cut, and a companion whose loop is out of margin can watch its vehicle
climb (``docs/measurements.md``, *The vehicle that climbed by itself*). ``MC_AIRMODE`` 0 flies as a stock PX4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache
from companion.core.vehicle_params import VehicleParams

_S2 = math.sqrt(2.0) / 2.0

#: PX4's ``MC_AIRMODE`` values: the collective never raised for torque, raised for roll/pitch, raised for all three
AIR_MODE_OFF, AIR_MODE_ROLL_PITCH, AIR_MODE_ALL = 0, 1, 2


@dataclass(frozen=True)
class RotorConfig:
    """Rotor and frame constants of eq. 13 (chosen for a 1.25 kg, 450-class X quadrotor).

    arm_m: d, rotor-to-centre distance; c_t: thrust coefficient N/(rad/s)²; c_m_over_c_t_m: yaw moment per
    newton of rotor thrust (c_M/c_T, m) — 0.06 m, high for real propellers (≈0.016), because eq. 49 puts up to
    0.59 N·m on yaw; thrust_to_weight: total max thrust / ((M+m)·g), sets ω_max.
    """

    arm_m: float = 0.225
    c_t: float = 1.2e-5
    c_m_over_c_t_m: float = 0.06
    thrust_to_weight: float = 2.5

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-physical values."""
        for k in ("arm_m", "c_t", "c_m_over_c_t_m"):
            if not getattr(self, k) > 0.0:
                raise ValueError(f"{k}: must be > 0")
        if not 1.05 <= self.thrust_to_weight <= 10.0:
            raise ValueError(f"thrust_to_weight: must be in [1.05, 10], got {self.thrust_to_weight}")


@dataclass(frozen=True)
class InnerLoopGains:
    """Attitude SMC gains per axis [φ, θ, ψ]: surface slope c (1/s), reaching gain k (1/s),
    switching gain k_sat (N·m, must exceed the disturbance torque bound), boundary layer Δ (rad/s)."""

    c: tuple[float, float, float] = (12.0, 12.0, 6.0)
    k: tuple[float, float, float] = (25.0, 25.0, 12.0)
    k_sat: tuple[float, float, float] = (3.0, 3.0, 2.0)
    boundary: tuple[float, float, float] = (0.3, 0.3, 0.3)
    max_tilt_rad: float = math.radians(60.0)
    rate_gain: float = 20.0  # 1/s, for body-rate-only targets

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-positive gains."""
        for k in ("c", "k", "k_sat", "boundary"):
            if any(not (v > 0.0 and math.isfinite(v)) for v in getattr(self, k)):
                raise ValueError(f"{k}: all three must be finite and > 0")
        if not 0.0 < self.max_tilt_rad < math.radians(89.0):
            raise ValueError("max_tilt_rad: must be in (0, 89°)")
        if not self.rate_gain > 0.0:
            raise ValueError("rate_gain: must be > 0")


def gains_packed(g: InnerLoopGains) -> np.ndarray:
    """Gains as the (13,) array the compiled kernel takes: c(3), k(3), k_sat(3), boundary(3), rate_gain."""
    return np.array([*g.c, *g.k, *g.k_sat, *g.boundary, g.rate_gain], dtype=np.float64)


# before the first kernel (see companion.core.kernel_cache)
use_kernel_cache(Path(__file__))


@njit(cache=True)
def _smc_torque(eta, eta_dot, tgt, tgt_rate, inertia, gp, out):  # pragma: no cover - compiled
    """Kernel of :func:`attitude_smc_torque`; writes τ (3,) into ``out``."""
    phi = eta[0]
    th = eta[1]
    sf = math.sin(phi)
    cf = math.cos(phi)
    st = math.sin(th)
    ct = math.cos(th)
    dphi = eta_dot[0]
    dth = eta_dot[1]
    dpsi = eta_dot[2]
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    sat0 = 0.0
    sat1 = 0.0
    sat2 = 0.0
    for i in range(3):
        e = tgt[i] - eta[i]
        if i == 2:
            e = (e + math.pi) % (2.0 * math.pi) - math.pi
        ed = tgt_rate[i] - eta_dot[i]
        s = gp[i] * e + ed
        acc = gp[i] * ed + gp[3 + i] * s
        sat = s / gp[9 + i]
        sat = min(1.0, max(-1.0, sat)) * gp[6 + i]
        if i == 0:
            a0 = acc
            sat0 = sat
        elif i == 1:
            a1 = acc
            sat1 = sat
        else:
            a2 = acc
            sat2 = sat
    # R_η·η̈* + Ṙ_η·η̇
    v0 = a0 - st * a2 - ct * dth * dpsi
    v1 = cf * a1 + sf * ct * a2 - sf * dphi * dth + (cf * ct * dphi - sf * st * dth) * dpsi
    v2 = -sf * a1 + cf * ct * a2 - cf * dphi * dth + (-sf * ct * dphi - cf * st * dth) * dpsi
    wx = dphi - st * dpsi
    wy = cf * dth + sf * ct * dpsi
    wz = -sf * dth + cf * ct * dpsi
    ixx = inertia[0]
    iyy = inertia[1]
    izz = inertia[2]
    out[0] = ixx * v0 + (izz - iyy) * wy * wz + sat0
    out[1] = iyy * v1 + (ixx - izz) * wz * wx + sat1
    out[2] = izz * v2 + (iyy - ixx) * wx * wy + sat2


def attitude_smc_torque(
    euler_rad: np.ndarray,
    euler_rate_rad_s: np.ndarray,
    target_euler_rad: np.ndarray,
    target_euler_rate_rad_s: np.ndarray,
    params: VehicleParams,
    gains: InnerLoopGains,
) -> np.ndarray:
    """Body-frame torque [τφ, τθ, τψ] (N·m) that drives the attitude onto the target (eqs. 41–47)."""
    out = np.empty(3)
    _smc_torque(
        np.asarray(euler_rad, dtype=np.float64), np.asarray(euler_rate_rad_s, dtype=np.float64),
        np.asarray(target_euler_rad, dtype=np.float64), np.asarray(target_euler_rate_rad_s, dtype=np.float64),
        np.array([params.Ixx, params.Iyy, params.Izz]), gains_packed(gains), out,
    )
    return out


@njit(cache=True)
def _rate_torque(w, w_tgt, inertia, gain, out):  # pragma: no cover - compiled
    """Body-rate tracking torque I·k·(ω_d − ω) + ω × Iω into ``out``."""
    ix = inertia[0]
    iy = inertia[1]
    iz = inertia[2]
    out[0] = ix * gain * (w_tgt[0] - w[0]) + (iz - iy) * w[1] * w[2]
    out[1] = iy * gain * (w_tgt[1] - w[1]) + (ix - iz) * w[2] * w[0]
    out[2] = iz * gain * (w_tgt[2] - w[2]) + (iy - ix) * w[0] * w[1]


def mixer_matrix(rotor: RotorConfig) -> np.ndarray:
    """Eq. 13 in rotor-thrust form: [T, τφ, τθ, τψ] = A·[f1, f2, f3, f4] (f_i = c_T·ω_i², N)."""
    a = _S2 * rotor.arm_m
    k = rotor.c_m_over_c_t_m
    return np.array([[1.0, 1.0, 1.0, 1.0], [a, -a, -a, a], [a, a, -a, -a], [k, -k, k, -k]])


@lru_cache(maxsize=16)
def mixer_inverse(rotor: RotorConfig) -> np.ndarray:
    """A⁻¹ of :func:`mixer_matrix` (cached per config)."""
    return np.linalg.inv(mixer_matrix(rotor))


def max_rotor_thrust_n(rotor: RotorConfig, params: VehicleParams) -> float:
    """Thrust of one rotor at ω_max, N."""
    return rotor.thrust_to_weight * params.hover_thrust_n / 4.0


@njit(cache=True)
def _fit(ft, thrust_n, f_max, air_mode, out):  # pragma: no cover - compiled
    """Add the collective closest to T/4 that keeps every rotor in [0, f_max]; False if none does.

    Without ``air_mode`` (a bool here) the collective may not rise above T/4 (torque never lifts an idling
    vehicle)."""
    lo = -1e300
    hi = 1e300
    for i in range(4):
        lo = max(lo, -ft[i])
        hi = min(hi, f_max - ft[i])
    c_req = thrust_n / 4.0
    if lo > hi or (not air_mode and lo > c_req + 1e-12):
        return False
    c = min(max(c_req, lo), hi)
    for i in range(4):
        out[i] = min(max(ft[i] + c, 0.0), f_max)
    return True


@njit(cache=True)
def _mix(thrust_n, tau, a_inv, f_max, air_mode, out):  # pragma: no cover - compiled
    """Kernel of :func:`mix`: rotor thrusts into ``out`` (4,); ``air_mode`` is ``MC_AIRMODE`` (0, 1, 2)."""
    f_rp = np.empty(4)
    ft = np.empty(4)
    for i in range(4):
        f_rp[i] = a_inv[i, 1] * tau[0] + a_inv[i, 2] * tau[1]
    if air_mode == 1:  # the collective rises as far as roll/pitch alone need it, and no further for yaw
        need = 0.0
        for i in range(4):
            need = max(need, -f_rp[i])
        thrust_n = max(thrust_n, 4.0 * need)
    raise_ok = air_mode == 2
    for i in range(4):
        ft[i] = f_rp[i] + a_inv[i, 3] * tau[2]
    if _fit(ft, thrust_n, f_max, raise_ok, out):
        return
    # Does roll/pitch fit alone? Then keep the largest fraction of the yaw torque that still fits.
    rp_scale = 1.0
    for i in range(4):
        ft[i] = f_rp[i]
    if _fit(ft, thrust_n, f_max, raise_ok, out):
        lo_s = 0.0
        hi_s = 1.0
        for _ in range(20):
            mid = 0.5 * (lo_s + hi_s)
            for i in range(4):
                ft[i] = f_rp[i] + mid * a_inv[i, 3] * tau[2]
            if _fit(ft, thrust_n, f_max, raise_ok, out):
                lo_s = mid
            else:
                hi_s = mid
        for i in range(4):
            ft[i] = f_rp[i] + lo_s * a_inv[i, 3] * tau[2]
    else:
        # Roll/pitch alone do not fit: no yaw, largest feasible fraction of roll/pitch.
        lo_s = 0.0
        hi_s = 1.0
        for _ in range(20):
            mid = 0.5 * (lo_s + hi_s)
            for i in range(4):
                ft[i] = mid * f_rp[i]
            if _fit(ft, thrust_n, f_max, raise_ok, out):
                lo_s = mid
            else:
                hi_s = mid
        rp_scale = lo_s
        for i in range(4):
            ft[i] = rp_scale * f_rp[i]
    if not _fit(ft, thrust_n, f_max, raise_ok, out):
        for i in range(4):
            out[i] = min(max(thrust_n / 4.0, 0.0), f_max)


def mix(
    thrust_n: float, torque: np.ndarray, rotor: RotorConfig, f_max: float, air_mode: int = AIR_MODE_ALL
) -> np.ndarray:
    """Rotor thrusts f (4,) in [0, f_max] realising [T, τ] as closely as the limits allow.

    Priority: roll/pitch torque, then yaw torque, then collective thrust, which is raised to make room for
    torque only as ``air_mode`` (PX4's ``MC_AIRMODE``: 0 never, 1 for roll/pitch, 2 for all three) allows.
    """
    if air_mode not in (AIR_MODE_OFF, AIR_MODE_ROLL_PITCH, AIR_MODE_ALL):
        raise ValueError(f"air_mode: must be 0, 1 or 2 (PX4's MC_AIRMODE), got {air_mode!r}")
    out = np.empty(4)
    _mix(float(thrust_n), np.asarray(torque, dtype=np.float64), mixer_inverse(rotor), float(f_max), int(air_mode),
         out)
    return out


#: the period of eq. 49's signal (s): the least common multiple of its five sines' periods (4/3, 1, 10/3, 20/3, 2/3)
EQ49_PERIOD_S = 20.0


@lru_cache(maxsize=1)
def eq49_peak() -> float:
    """The largest |w(t)| of eq. 49 at scale 1 over its whole period (N·m on each torque channel): 0.592."""
    from companion.core.wind import eq49_signal

    return max(abs(eq49_signal(k * 1e-3)) for k in range(int(EQ49_PERIOD_S * 1000)))


def yaw_authority_at_hover_nm(rotor: RotorConfig, params: VehicleParams) -> float:
    """The largest yaw torque (N·m) the rotors give while their thrust still only holds the hover: two rotors
    at twice their hover share, two at zero, i.e. (c_M/c_T)·(M + m)·g."""
    return abs(float(mixer_matrix(rotor)[3, 0])) * params.hover_thrust_n


#: how far beyond :func:`eq49_unlifted_scale` eq. 49 may go on a mixer that does not lift for yaw (MC_AIRMODE 0, 1):
#: the heading wanders and comes back. Measured hovering (``VehicleSim``, 20 s): 0.8 held within 0.6°, 1.0 wandered
#: 23°, 1.1 62°, 1.2 118°, 1.3 spun
EQ49_UNLIFTED_OVERDRIVE = 1.2


def eq49_unlifted_scale(rotor: RotorConfig, params: VehicleParams) -> float:
    """The largest eq. 49 scale whose torques (the same w(t) on roll, pitch and yaw) every rotor holds at hover
    thrust without lifting the collective: the hover share T/4 over the worst rotor's |roll| + |pitch| + |yaw|
    share of one N·m at eq. 49's peak (0.85 for the default airframe)."""
    a_inv = mixer_inverse(rotor)
    share = max(abs(a_inv[i, 1]) + abs(a_inv[i, 2]) + abs(a_inv[i, 3]) for i in range(4))
    return params.hover_thrust_n / 4.0 / (share * eq49_peak())


def eq49_torque_problem(scale: float, rotor: RotorConfig, params: VehicleParams, margin: float = 0.9,
                        air_mode: int = AIR_MODE_ALL) -> str | None:
    """Why the airframe cannot fly eq. 49 at ``scale`` (None when it can). With the collective lifted for yaw
    (``air_mode`` 2) the yaw channel's peak must stay within ``margin`` of the yaw torque the rotors give at hover.
    Beyond it the mixer can only find the yaw torque by raising the collective, and the vehicle spins up and climbs
    away (measured: scale 1.5 diverged on take-off, 1.3 flew). Eq. 49 puts the same w(t) on every channel; roll
    and pitch have ~2.7x the authority. Without (0, 1) the scale must stay within ``EQ49_UNLIFTED_OVERDRIVE`` of
    :func:`eq49_unlifted_scale`, beyond which the heading wanders ever further and then spins."""
    peak = scale * eq49_peak()
    if air_mode != AIR_MODE_ALL:
        held = eq49_unlifted_scale(rotor, params)
        largest = EQ49_UNLIFTED_OVERDRIVE * held
        why = (f" at MC_AIRMODE {air_mode}: eq. 49 puts up to {peak:.2f} N·m on roll, pitch and yaw at once; without "
               f"lifting the collective the rotors hold that only up to scale {held:.2f}, and beyond it the heading "
               f"wanders (23° at 1.0, a spin at 1.3). The largest scale flown at this air mode is {largest:.2f}; use "
               f"--airmode 2, or")
    else:
        authority = yaw_authority_at_hover_nm(rotor, params)
        largest = margin * authority / eq49_peak()
        why = (f": eq. 49 puts a yaw torque of up to {peak:.2f} N·m on the airframe, more than {margin:g} of the "
               f"{authority:.2f} N·m its rotors give at hover: no attitude loop can hold it (it spins up and climbs "
               f"away). The largest scale this airframe flies is {largest:.2f}; for stronger wind use")
    if scale <= largest:
        return None
    return f"[wind] model \"paper\" scale {scale:g}{why} model = \"turbulence\" (drag, no torques)"
