"""The swing estimator's settings and its output: :class:`SwingEstimatorConfig` (noise model and behaviour) and
:class:`SwingEstimate` (what :meth:`companion.estimation.swing_estimator.SwingEstimator.estimate` returns)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SwingEstimatorConfig:
    """Noise model and behaviour of :class:`SwingEstimator` (SI units).

    Process noise (white, continuous-time spectral densities): ``q_swing`` on α̈, β̈ ((rad/s²)²/Hz: model error,
    e.g. thrust or attitude timing), ``q_vel`` on ξ̈ ((m/s²)²/Hz), ``q_force`` the random walk of the unknown
    force d (N²/s; eq. 49's wind varies by ~1 N/s), ``q_bias`` the accelerometer-bias random walk ((m/s²)²/s),
    ``q_thrust`` the random walk of the thrust error δT (N²/s; fast: saturating rotors change it by newtons),
    ``q_drag`` the random walk of the airframe's linear drag coefficient c ((N per m/s)²/s; slow: it is a property
    of the airframe). ``init_drag_per_s`` / ``init_drag_sigma_per_s``: c's prior and its 1σ per kg of airframe
    (c/M, 1/s; rotor drag of small multirotors is 0.1–0.5 /s, ArduPilot's SITL quad 0.27 /s). The payload's
    quadratic drag coefficient k (N per (m/s)²): ``init_payload_drag`` (the mission's ``[payload]
    drag_n_per_mps2``), its 1σ ``init_payload_drag_sigma`` (None: a quarter of it; 0 holds k fixed) and random
    walk ``q_payload_drag``; with no drag given (0) k stays 0: it trades against the airframe's drag and the wind,
    and left free on a payload without drag it found one (bundled vehicle's forest: RMS 0.016 → 0.033 rad).
    Measurement noise (1σ per axis): ``imu_sigma_mps2`` (sensor noise per sample plus model mismatch),
    ``fix_sigma_m`` (payload offset), ``vel_sigma_mps``. Initial 1σ: ``init_*``. ``step_s``: longest
    prediction step; ``history_s``: how late a measurement may arrive and still be fused at its time;
    ``reorder_s``: measurements wait this long to be fused, so that those a few milliseconds apart on different
    streams are taken in time order without a replay (the estimate is predicted over it); ``gate_nis``:
    innovations with NIS above it (3 dof) are rejected as outliers; ``fix_reset_after``: after that many payload
    fixes rejected in a row the filter, not the fixes, is taken to be wrong (its model does not fit the payload,
    e.g. an elastic tether): at the next rejected one the swing's covariance is reset to ``reset_swing_sigma_rad``
    / ``reset_rate_sigma_rad_s`` and the fix is fused (GNSS-aided filters reset on a persistently rejected position
    the same way; the wide σ then fades the feed-forward and widens the envelope until it has re-locked);
    ``q_swing_adapt_max``: the payload fixes also scale ``q_swing`` by up to this factor (1 = off): each fix
    multiplies the scale by (NIS/3)^¼, kept within [1, q_swing_adapt_max], so a model that does not fit the payload
    (residuals larger than its covariance explains) trusts its own prediction less and the fixes more;
    ``trust_window_s``: window of the NIS averages; ``fade_bound3_rad`` (lo, hi): the 3σ swing bound over which
    fade goes 1 → 0; ``fade_nis`` (lo, hi): the averaged NIS per dof over which fade goes 1 → 0; ``fade_q_scale``
    (lo, hi): the q_swing scale over which fade goes 1 → 0 (a payload the pendulum model does not fit: the
    feed-forward, derived from that model, would push it at the wrong frequency).
    """

    q_swing: float = 0.0005
    q_vel: float = 0.005
    q_force: float = 0.3
    q_bias: float = 1e-5
    q_thrust: float = 2.0
    q_drag: float = 0.001
    q_payload_drag: float = 1e-6
    imu_sigma_mps2: float | tuple[float, float, float] = 0.05
    fix_sigma_m: float = 0.03
    vel_sigma_mps: float = 0.03
    init_swing_sigma_rad: float = 0.01
    init_rate_sigma_rad_s: float = 0.02
    init_vel_sigma_mps: float = 0.1
    init_force_sigma_n: float = 0.5
    init_bias_sigma_mps2: float = 0.3
    init_thrust_sigma_n: float = 1.0
    init_drag_per_s: float = 0.0
    init_drag_sigma_per_s: float = 0.4
    init_payload_drag: float = 0.0
    init_payload_drag_sigma: float | None = None
    step_s: float = 0.01
    cov_step_s: float = 0.02
    history_s: float = 1.0
    reorder_s: float = 0.01
    gate_nis: float = 30.0
    fix_reset_after: int = 3
    q_swing_adapt_max: float = 100.0
    reset_swing_sigma_rad: float = 0.3
    reset_rate_sigma_rad_s: float = 1.0
    trust_window_s: float = 1.0
    fade_bound3_rad: tuple[float, float] = (0.12, 0.30)
    fade_nis: tuple[float, float] = (3.0, 10.0)
    fade_q_scale: tuple[float, float] = (2.0, 20.0)

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-positive or inconsistent values."""
        sig = self.imu_sigma_mps2 if isinstance(self.imu_sigma_mps2, tuple) else (self.imu_sigma_mps2,)
        if not (len(sig) in (1, 3) and all(math.isfinite(v) and v > 0.0 for v in sig)):
            raise ValueError(f"imu_sigma_mps2: must be > 0 (one value or three), got {self.imu_sigma_mps2}")
        for key in ("q_swing", "q_vel", "q_force", "q_bias", "q_drag", "q_payload_drag", "q_thrust", "fix_sigma_m",
                    "vel_sigma_mps", "init_swing_sigma_rad", "init_rate_sigma_rad_s", "init_vel_sigma_mps",
                    "init_force_sigma_n", "init_bias_sigma_mps2", "init_thrust_sigma_n", "init_drag_sigma_per_s",
                    "step_s", "cov_step_s", "history_s", "gate_nis", "trust_window_s", "reset_swing_sigma_rad",
                    "reset_rate_sigma_rad_s"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{key}: must be > 0, got {v}")
        for key in ("init_drag_per_s", "init_payload_drag", "init_payload_drag_sigma"):
            v = getattr(self, key)
            if v is not None and not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{key}: must be >= 0, got {v}")
        if not (math.isfinite(self.q_swing_adapt_max) and self.q_swing_adapt_max >= 1.0):
            raise ValueError(f"q_swing_adapt_max: must be >= 1 (1 = off), got {self.q_swing_adapt_max}")
        if not (isinstance(self.fix_reset_after, int) and self.fix_reset_after >= 1):
            raise ValueError(f"fix_reset_after: must be an integer >= 1, got {self.fix_reset_after!r}")
        if not (math.isfinite(self.reorder_s) and 0.0 <= self.reorder_s < self.history_s):
            raise ValueError(f"reorder_s: must be in [0, history_s), got {self.reorder_s}")
        for key in ("fade_bound3_rad", "fade_nis", "fade_q_scale"):
            lo, hi = getattr(self, key)
            if not (0.0 <= lo < hi):
                raise ValueError(f"{key}: needs 0 <= lo < hi, got {(lo, hi)}")


@dataclass(frozen=True, slots=True)
class SwingEstimate:
    """The swing estimate at ``t_s``.

    swing: [α, β, α̇, β̇] (rad, rad/s); swing_acc: [α̈, β̈] (rad/s²) from the model at the estimate; cov: 4×4
    covariance of ``swing``; sigma_rad: 1σ of the swing angle along its least certain direction;
    bound_rad: |(α, β)| + 3σ, an upper bound on the swing angle for the envelope; fade: 0..1, how much of
    the feed-forward to apply; force_ned_n: the force on the airframe besides thrust, gravity and the cable, N
    (wind and the other unknowns d plus the modelled drag −c·v); accel_bias_frd_mps2: the accelerometer bias;
    nis: averaged NIS per dof per source over the trust window (sources without data in the window absent);
    sources: those sources; rejected: outliers gated in the window; dropped_late: measurements older than the
    history, ever; drag_n_per_mps: the airframe's linear drag coefficient c (N per m/s);
    payload_drag_n_per_mps2: the payload's quadratic drag coefficient k (N per (m/s)²).
    """

    t_s: float
    swing: np.ndarray
    swing_acc: np.ndarray
    cov: np.ndarray
    sigma_rad: float
    bound_rad: float
    fade: float
    force_ned_n: np.ndarray
    accel_bias_frd_mps2: np.ndarray
    nis: dict[str, float]
    sources: tuple[str, ...]
    rejected: int = 0
    dropped_late: int = 0
    drag_n_per_mps: float = 0.0
    payload_drag_n_per_mps2: float = 0.0
