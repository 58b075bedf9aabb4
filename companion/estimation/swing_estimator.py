"""Swing estimator: an extended Kalman filter over the swing, the airframe velocity, the unknown force on the
airframe and the accelerometer bias, and the thrust error, with the project's own model as its process model.

Process and measurement models: :mod:`companion.estimation.swing_model` (derivation in
``docs/swing-estimation.md``). Inputs (known, not estimated): the attitude the autopilot reports and the thrust
the companion commanded. Measurements, each optional and usable alone or together:

* ``update_imu``: accelerometer specific force (HIGHRES_IMU / SCALED_IMU, body FRD, m/s²) — the sensorless path;
* ``update_payload_offset`` / ``update_payload_position``: payload position fixes (relative to the airframe, or
  absolute NED with the airframe's position looked up at the fix's time), any rate, late and out of order;
* ``update_velocity``: the airframe velocity (LOCAL_POSITION_NED), which pins the unknown force d down and lets
  the accelerometer bias be told from it.

Time: every call carries the time of validity of its data on one clock (the vehicle's ``time_boot_ms``/
``time_usec``, s). Measurements are events kept for ``history_s``: one that arrives late (older than the newest
processed one) is inserted at its time and the events after it are replayed from a checkpoint, so a fix delayed
by 300 ms is fused exactly where it belongs. Older than ``history_s`` it is dropped and counted.
``estimate(t)`` predicts from the newest processed event to ``t`` (incrementally, cheap at the control rate).

Trust: the averaged normalized innovation squared (NIS per degree of freedom, ≈ 1 when the model and the noise
settings describe the data) over the last ``trust_window_s`` per source, and the 1σ of the swing angle from the
covariance, give ``fade`` in [0, 1] (scale the feed-forward by it) and ``bound_rad`` (|swing| + 3σ, for the
envelope).
"""

from __future__ import annotations

import bisect
import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from companion.core.model import VehicleParams
from companion.estimation.swing_model import (
    I_DRAG,
    I_PDRAG,
    I_THRUST,
    N_STATE,
    SL_BIAS,
    accel_force_jacobian_rows,
    payload_drag_unit,
    payload_force_ned_n,
    payload_offset_jacobian,
    payload_offset_m,
    rotate_by_rates,
    rotation_from_euler,
    rotation_from_quat,
    thrust_axis_by_rates,
    translation_swing_accel,
)

SOURCES = ("imu", "fix", "vel")
_IN = np.eye(N_STATE)
_I3 = np.eye(3)
_NIS_CAP = 100.0
_MAX_EXTRAPOLATE_S = 0.05
_JUMP_SIGMAS2 = 9.0
_FIX_ERRORS_KEPT = 200


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


@dataclass(slots=True)
class _Event:
    t: float
    seq: int
    kind: str
    z: np.ndarray
    sigma: np.ndarray
    nis: float = math.nan
    accepted: bool = False
    x: np.ndarray | None = None  # state and covariance after this event
    P: np.ndarray | None = None
    K: np.ndarray | None = None  # gain (None when rejected)
    Rt: np.ndarray | None = None  # Rᵀ at the event (IMU)
    T: np.ndarray | None = None  # (I − K·H)·Φ from the previous event to this one, for replays


@dataclass
class _History:
    """Time-ordered input samples with bisect lookup (zero-order hold)."""

    t: list[float] = field(default_factory=list)
    v: list[tuple] = field(default_factory=list)

    def add(self, t: float, value: tuple) -> None:
        if not self.t or t >= self.t[-1]:
            self.t.append(t)
            self.v.append(value)
        else:
            i = bisect.bisect_right(self.t, t)
            self.t.insert(i, t)
            self.v.insert(i, value)

    def at(self, t: float) -> tuple[float, tuple] | None:
        if not self.t:
            return None
        i = bisect.bisect_right(self.t, t) - 1
        i = max(i, 0)
        return self.t[i], self.v[i]

    def prune(self, t_keep: float) -> None:
        """Drop samples older than the last one at or before ``t_keep``."""
        i = bisect.bisect_right(self.t, t_keep) - 1
        if i > 0:
            del self.t[:i]
            del self.v[:i]


def _inv3(S: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite 3×3 (cofactors; ~5x faster than numpy.linalg.inv here)."""
    a, b, c = float(S[0, 0]), float(S[0, 1]), float(S[0, 2])
    d, e, f = float(S[1, 1]), float(S[1, 2]), float(S[2, 2])
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    if not (det > 0.0 and math.isfinite(det)):
        return np.linalg.pinv(S)
    k = 1.0 / det
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    return np.array([[c00 * k, c01 * k, c02 * k], [c01 * k, c11 * k, c12 * k], [c02 * k, c12 * k, c22 * k]])


def _innovation(P: np.ndarray, H: np.ndarray, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P·Hᵀ, the innovation covariance S = H·P·Hᵀ + diag(r2) and its inverse, for a 3-row measurement."""
    PHt = P @ H.T
    S = H @ PHt
    S[0, 0] += r2[0]
    S[1, 1] += r2[1]
    S[2, 2] += r2[2]
    return PHt, S, _inv3(S)


class SwingEstimator:
    """EKF over [α, β, α̇, β̇, v_NED, d_NED, b_FRD, δT] (see :mod:`companion.estimation.swing_model`).

    ``params``: the model (M, m, l, Ip, g: vehicle mass, payload mass, cable length — identified or from the
    mission). ``t0_s``: start time; ``swing0``: initial [α, β, α̇, β̇] (default hanging at rest, e.g. at lift-off);
    ``vel0_ned_mps``: initial airframe velocity. Start it at lift-off: the model is of a flying vehicle (on the
    ground the ground's reaction would be taken for a force on the airframe).
    """

    def __init__(
        self,
        params: VehicleParams,
        config: SwingEstimatorConfig | None = None,
        t0_s: float = 0.0,
        swing0=None,
        vel0_ned_mps=None,
        swing_sigma0_rad: float | None = None,
    ) -> None:
        self.params = params
        self.cfg = config or SwingEstimatorConfig()
        self.cfg.validate()
        c = self.cfg
        p = params
        self._pp = (p.M, p.m, p.g, p.Ip, p.l)
        self._hover_n = (p.M + p.m) * p.g
        x = np.zeros(N_STATE)
        if swing0 is not None:
            x[0:4] = np.asarray(swing0, dtype=np.float64)
        if vel0_ned_mps is not None:
            x[4:7] = np.asarray(vel0_ned_mps, dtype=np.float64)
        x[I_DRAG] = c.init_drag_per_s * p.M
        x[I_PDRAG] = c.init_payload_drag
        s0 = c.init_swing_sigma_rad if swing_sigma0_rad is None else float(swing_sigma0_rad)
        r0 = c.init_rate_sigma_rad_s if swing_sigma0_rad is None else 3.5 * float(swing_sigma0_rad)
        P = np.diag(np.array([s0, s0, r0, r0] + [c.init_vel_sigma_mps] * 3 + [c.init_force_sigma_n] * 3
                             + [c.init_bias_sigma_mps2] * 3 + [c.init_thrust_sigma_n, 0.0, 0.0]) ** 2)
        self._base = _Event(t=float(t0_s), seq=-1, kind="init", z=np.zeros(0), sigma=np.zeros(3), x=x, P=P)
        self._events: list[_Event] = []
        self._pending: list[tuple[float, int, _Event]] = []  # in-order measurements waiting ``reorder_s``
        self._seq = 0
        self._att = _History()
        self._thr = _History()
        self._pos = _History()
        self._version = 0
        self._shadow: tuple[int, float, np.ndarray, float, np.ndarray] | None = None
        self._Qc = np.array([0.0, 0.0, c.q_swing, c.q_swing] + [c.q_vel] * 3 + [c.q_force] * 3 + [c.q_bias] * 3
                            + [c.q_thrust, 0.0, 0.0])
        # the drag coefficients are held at their priors until both a velocity and an accelerometer reading have
        # come: with the velocity only integrated from the accelerations (the IMU alone), c·v and d cannot be told
        # apart; without the IMU (fixes and velocity) the drag shows only in the velocity, where d takes it as well
        # (c is there for the accelerometer's lateral reading, which the drag changes as fast as the velocity)
        self._drag_sigma0 = c.init_drag_sigma_per_s * p.M
        self._drag_free = False
        self._kinds_seen: set[str] = set()
        self._pdrag_sigma0 = (0.25 * c.init_payload_drag if c.init_payload_drag_sigma is None
                              else c.init_payload_drag_sigma)
        self.dropped_late = 0
        self.rejected_total = 0
        self.resets = 0  # swing covariance resets after fixes rejected in a row (see fix_reset_after)
        self._fixes_rejected_in_row = 0
        self.q_swing_scale = 1.0  # q_swing's current factor (q_swing_adapt_max)
        self.fix_sq_error: list[tuple[float, float]] = []  # (t s, |fix − its prediction|² m²) per fix
        self._trust_cache: tuple[int, float, dict, tuple, int] | None = None

    # ------------------------------------------------------------------------------------------- inputs
    def set_thrust(self, t_s: float, thrust_n: float) -> None:
        """The collective thrust the companion commanded (N, along −z body), valid from ``t_s`` on."""
        T = float(thrust_n)
        if not math.isfinite(T):
            raise ValueError(f"thrust_n: must be finite, got {thrust_n!r}")
        self._thr.add(float(t_s), (T,))

    def set_attitude_euler(self, t_s: float, euler_rad, rates_frd_rad_s=None) -> None:
        """ATTITUDE: ZYX Euler angles [φ, θ, ψ] (rad) and body rates (rad/s, FRD; used to interpolate)."""
        e = [float(v) for v in euler_rad]
        self._add_attitude(t_s, rotation_from_euler(*e), rates_frd_rad_s)

    def set_attitude_quat(self, t_s: float, q_wxyz, rates_frd_rad_s=None) -> None:
        """ATTITUDE_QUATERNION: [w, x, y, z] (body FRD → NED) and body rates (rad/s, FRD)."""
        self._add_attitude(t_s, rotation_from_quat(q_wxyz), rates_frd_rad_s)

    def _add_attitude(self, t_s: float, R: np.ndarray, rates) -> None:
        w = (0.0, 0.0, 0.0) if rates is None else tuple(float(v) for v in rates)
        if not (np.all(np.isfinite(R)) and all(math.isfinite(v) for v in w)):
            raise ValueError("attitude or rates not finite")
        self._att.add(float(t_s), (R, R.tolist(), w))

    def _dt_att(self, t: float) -> tuple[float, tuple] | None:
        a = self._att.at(t)
        if a is None:
            return None
        return min(max(t - a[0], -_MAX_EXTRAPOLATE_S), _MAX_EXTRAPOLATE_S), a[1]

    def _force(self, t: float, x: np.ndarray) -> tuple[float, float, float, float, float, float]:
        """(f, body z axis) at time t (N and unit vector, NED): f = F − c·(v_N, v_E, 0) + d, every non-gravity,
        non-cable force on the airframe, with the thrust T + δT along −z body (attitude from the sample before t
        extrapolated with its body rates; level before any sample), T held from its last command (the hover
        thrust before any)."""
        a = self._att.at(t)
        if a is None:
            b0, b1, b2 = 0.0, 0.0, 1.0
        else:
            dt = min(max(t - a[0], -_MAX_EXTRAPOLATE_S), _MAX_EXTRAPOLATE_S)
            _, Rl, w = a[1]
            b0, b1, b2 = thrust_axis_by_rates(Rl, w, dt)
        th = self._thr.at(t)
        T = (self._hover_n if th is None else th[1][0]) + float(x[I_THRUST])
        c = float(x[I_DRAG])
        return (-b0 * T - c * float(x[4]) + float(x[7]), -b1 * T - c * float(x[5]) + float(x[8]),
                -b2 * T + float(x[9]), b0, b1, b2)

    def _rotation(self, t: float) -> np.ndarray:
        a = self._dt_att(t)
        if a is None:
            return _I3
        dt, (R, _, w) = a
        return rotate_by_rates(R, w, dt)

    # ------------------------------------------------------------------------------------- measurements
    def update_imu(self, t_s: float, accel_frd_mps2, sigma_mps2=None) -> None:
        """Accelerometer specific force (HIGHRES_IMU xacc/yacc/zacc, SCALED_IMU ×9.81e-3; m/s², body FRD) at
        ``t_s`` (for an average over an integration window, pass the window's middle). ``sigma_mps2``: 1σ, one
        value or one per axis (default: the config's)."""
        self._add_event(t_s, "imu", accel_frd_mps2, self.cfg.imu_sigma_mps2 if sigma_mps2 is None else sigma_mps2)

    def update_payload_offset(self, t_s: float, offset_ned_m, sigma_m: float | None = None) -> None:
        """Payload position minus airframe position (NED, m) at ``t_s`` (e.g. :func:`~companion.estimation.
        swing_model.payload_offset_from_global` of the payload's and the vehicle's GLOBAL_POSITION_INT)."""
        self._add_event(t_s, "fix", offset_ned_m, self.cfg.fix_sigma_m if sigma_m is None else sigma_m)

    def update_payload_position(self, t_s: float, payload_pos_ned_m, sigma_m: float | None = None) -> bool:
        """Absolute payload position (NED, m) at ``t_s``; the airframe position at ``t_s`` is interpolated from
        the positions given to :meth:`update_velocity`. Returns False (fix not used) when ``t_s`` is not
        covered by that history."""
        pos = self._position_at(float(t_s))
        if pos is None:
            return False
        self.update_payload_offset(t_s, np.asarray(payload_pos_ned_m, dtype=np.float64) - pos, sigma_m)
        return True

    def update_velocity(self, t_s: float, vel_ned_mps, pos_ned_m=None, sigma_mps: float | None = None) -> None:
        """Airframe velocity (LOCAL_POSITION_NED vx, vy, vz; m/s). ``pos_ned_m`` (optional) is stored to align
        absolute payload fixes."""
        if pos_ned_m is not None:
            p = tuple(float(v) for v in pos_ned_m)
            if all(math.isfinite(v) for v in p):
                self._pos.add(float(t_s), p)
        if vel_ned_mps is not None:
            self._add_event(t_s, "vel", vel_ned_mps, self.cfg.vel_sigma_mps if sigma_mps is None else sigma_mps)

    def _position_at(self, t: float) -> np.ndarray | None:
        ts = self._pos.t
        if not ts or t < ts[0] or t > ts[-1] + 0.05:
            return None
        i = bisect.bisect_right(ts, t) - 1
        p0 = np.array(self._pos.v[i])
        if i + 1 >= len(ts):
            return p0
        w = (t - ts[i]) / (ts[i + 1] - ts[i])
        return p0 + w * (np.array(self._pos.v[i + 1]) - p0)

    def _add_event(self, t_s: float, kind: str, z, sigma) -> None:
        t = float(t_s)
        zz = np.asarray(z, dtype=np.float64).reshape(3)
        sg = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (3,)).copy()
        if not (math.isfinite(t) and np.all(np.isfinite(zz)) and np.all(np.isfinite(sg)) and np.all(sg > 0.0)):
            raise ValueError(f"{kind} measurement at t={t_s!r}: non-finite value or sigma")
        if t < self._base.t:
            self.dropped_late += 1
            return

        ev = _Event(t=t, seq=self._seq, kind=kind, z=zz, sigma=sg)
        self._seq += 1
        evs = self._events
        if not evs or t >= evs[-1].t:  # in order: wait ``reorder_s`` for others that belong before it
            heapq.heappush(self._pending, (t, ev.seq, ev))
            self._flush(t - self.cfg.reorder_s)
            return
        else:  # late: insert at its time and replay what follows
            i = bisect.bisect_right([e.t for e in evs], t)
            evs.insert(i, ev)
            prev = evs[i - 1] if i > 0 else self._base
            self._apply(ev, prev.x, prev.P, prev.t)
            nxt = evs[i + 1]  # its interval changed: process it again in full
            x_old, P_old = nxt.x, nxt.P
            self._apply(nxt, ev.x, ev.P, ev.t)
            self._replay(i + 2, nxt.x - x_old, nxt.P - P_old)
        self._version += 1
        self._prune()

    def _flush(self, t_upto: float) -> None:
        """Apply the waiting measurements up to ``t_upto``, in time order."""
        pend = self._pending
        if not pend or pend[0][0] > t_upto:
            return
        evs = self._events
        while pend and pend[0][0] <= t_upto:
            ev = heapq.heappop(pend)[2]
            prev = evs[-1] if evs else self._base
            self._apply(ev, prev.x, prev.P, prev.t)
            evs.append(ev)
        self._version += 1
        self._prune()

    def _prune(self) -> None:
        evs = self._events
        t_cut = evs[-1].t - self.cfg.history_s
        k = 0
        while k < len(evs) - 1 and evs[k].t < t_cut:
            k += 1
        if k:
            self._base = evs[k - 1]
            del evs[:k]
        keep = self._base.t - 0.1
        self._att.prune(keep)
        self._thr.prune(keep)
        self._pos.prune(keep)

    # ------------------------------------------------------------------------------------------ the filter
    def _acc(self, x: np.ndarray, f: tuple[float, float, float]) -> tuple[float, float, float, float, float]:
        M, m, g, Ip, l = self._pp
        return translation_swing_accel(x[0], x[1], x[2], x[3], f[0], f[1], f[2], M, m, g, Ip, l,
                                       *payload_force_ned_n(x, l))

    def _acc_jacobian(self, x: np.ndarray, f, base) -> np.ndarray:
        """∂(α̈, β̈, ẍ, ÿ, z̈)/∂x (5×16): swing, velocity and payload-drag columns by forward differences (the
        payload's drag depends on all of them), the others analytic through the airframe force f (``f`` as
        returned by :meth:`_force`; the accelerations are affine in it): ∂f/∂d = I, ∂f/∂δT = −z_body,
        ∂f/∂v = −c on the horizontal axes, ∂f/∂c = −(v_N, v_E, 0)."""
        M, m, g, Ip, l = self._pp
        a0, a1, a2, a3 = float(x[0]), float(x[1]), float(x[2]), float(x[3])
        c, k = float(x[I_DRAG]), float(x[I_PDRAG])
        vn, ve, vd = float(x[4]), float(x[5]), float(x[6])
        f0, f1, f2, b0, b1, b2 = f

        def acc(al, be, dal, dbe, un=vn, ue=ve, ud=vd, fa=f0, fb=f1, kk=k):
            p = payload_drag_unit(al, be, dal, dbe, un, ue, ud, l)
            return translation_swing_accel(al, be, dal, dbe, fa, fb, f2, M, m, g, Ip, l,
                                           kk * p[0], kk * p[1], kk * p[2])

        c0 = acc(a0 + 1e-6, a1, a2, a3)
        c1 = acc(a0, a1 + 1e-6, a2, a3)
        c2 = acc(a0, a1, a2 + 1e-5, a3)
        c3 = acc(a0, a1, a2, a3 + 1e-5)
        cn = acc(a0, a1, a2, a3, un=vn + 1e-5, fa=f0 - c * 1e-5)
        ce = acc(a0, a1, a2, a3, ue=ve + 1e-5, fb=f1 - c * 1e-5)
        cd = acc(a0, a1, a2, a3, ud=vd + 1e-5)
        ck = acc(a0, a1, a2, a3, kk=k + 1e-3)
        F = accel_force_jacobian_rows(a0, a1, M, m, Ip, l)
        return np.array([[(c0[i] - base[i]) * 1e6, (c1[i] - base[i]) * 1e6, (c2[i] - base[i]) * 1e5,
                          (c3[i] - base[i]) * 1e5, (cn[i] - base[i]) * 1e5, (ce[i] - base[i]) * 1e5,
                          (cd[i] - base[i]) * 1e5, F[i][0], F[i][1], F[i][2],
                          0.0, 0.0, 0.0, -(F[i][0] * b0 + F[i][1] * b1 + F[i][2] * b2),
                          -(F[i][0] * vn + F[i][1] * ve), (ck[i] - base[i]) * 1e3]
                         for i in range(5)])

    def _mean(self, x: np.ndarray, t0: float, t1: float) -> np.ndarray:
        """Mean from t0 to t1 (RK2 midpoint, steps <= ``step_s``, inputs at each step's middle); a new array."""
        x = x.copy()
        span = t1 - t0
        if span <= 0.0:
            return x
        n = max(1, math.ceil(span / self.cfg.step_s - 1e-9))
        h = span / n
        M, m, g, Ip, l = self._pp
        drags = x[I_PDRAG] != 0.0
        for k in range(n):
            f0, f1, f2, _, _, _ = self._force(t0 + (k + 0.5) * h, x)
            a0, a1, a2, a3 = float(x[0]), float(x[1]), float(x[2]), float(x[3])
            # the payload's drag, held over the step like the airframe's forces
            p0, p1, p2 = payload_force_ned_n(x, l) if drags else (0.0, 0.0, 0.0)
            k1 = translation_swing_accel(a0, a1, a2, a3, f0, f1, f2, M, m, g, Ip, l, p0, p1, p2)
            m2 = a2 + 0.5 * h * k1[0]
            m3 = a3 + 0.5 * h * k1[1]
            k2 = translation_swing_accel(a0 + 0.5 * h * a2, a1 + 0.5 * h * a3, m2, m3, f0, f1, f2, M, m, g, Ip, l,
                                         p0, p1, p2)
            x[0] = a0 + h * m2
            x[1] = a1 + h * m3
            x[2] = a2 + h * k2[0]
            x[3] = a3 + h * k2[1]
            x[4] += h * k2[2]
            x[5] += h * k2[3]
            x[6] += h * k2[4]
        return x

    def _phi(self, J: np.ndarray, h: float) -> np.ndarray:
        """Φ = I + A·h + (A·h)²/2 for the accelerations' Jacobian J (A: α̇, β̇ rows and J's five rows)."""
        A = np.zeros((N_STATE, N_STATE))
        A[0, 2] = A[1, 3] = h
        A[2:7, :] = J * h
        return _IN + A + 0.5 * (A @ A)

    def _cov(self, P: np.ndarray, J: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        """(P after h seconds with the accelerations' Jacobian J, plus Q·h; the step's transition Φ)."""
        Phi = self._phi(J, h)
        P = Phi @ P @ Phi.T
        P[np.diag_indices(N_STATE)] += self._Qc * h
        return P, Phi

    def _propagate(self, x, P, t0: float, t1: float):
        """(x, P, acc, J, Φ) at t1 from (x, P) at t0: the mean in steps of ``step_s``, the covariance in steps of at
        most ``cov_step_s`` with the Jacobian at each step's end (the last one is reused for the measurement at
        t1); Φ the transition over the whole interval."""
        span = t1 - t0
        n = max(1, math.ceil(span / self.cfg.cov_step_s - 1e-9)) if span > 0.0 else 0
        h = span / n if n else 0.0
        ta = t0
        acc = J = None
        Phi_total = _IN
        for k in range(n):
            tb = t1 if k == n - 1 else t0 + (k + 1) * h
            x = self._mean(x, ta, tb)
            f = self._force(tb, x)
            acc = self._acc(x, f)
            J = self._acc_jacobian(x, f, acc)
            P, Phi = self._cov(P, J, tb - ta)
            Phi_total = Phi @ Phi_total
            ta = tb
        if J is None:
            f = self._force(t1, x)
            acc = self._acc(x, f)
            J = self._acc_jacobian(x, f, acc)
        return x, P, acc, J, Phi_total

    def _apply(self, ev: _Event, x0: np.ndarray, P0: np.ndarray, t0: float) -> None:
        """Predict from (t0, x0, P0) to the event and fuse it; stores the result, the gain and the transition
        (I − K·H)·Φ in the event (for replays)."""
        x, P, acc, J, Phi = self._propagate(x0, P0, t0, ev.t)
        if not self._drag_free and ev.kind not in self._kinds_seen:
            self._kinds_seen.add(ev.kind)
        if not self._drag_free and {"imu", "vel"} <= self._kinds_seen:  # the drags are learnt from now on
            self._drag_free = True
            P = P.copy()
            P[I_DRAG, I_DRAG] += self._drag_sigma0 ** 2
            self._Qc[I_DRAG] = self.cfg.q_drag
            if self._pdrag_sigma0 > 0.0:  # a payload said to drag: its coefficient is refined
                P[I_PDRAG, I_PDRAG] += self._pdrag_sigma0 ** 2
                self._Qc[I_PDRAG] = self.cfg.q_payload_drag
        H = np.zeros((3, N_STATE))
        l = self._pp[4]
        if ev.kind == "imu":
            ev.Rt = self._rotation(ev.t).T
            H[:, :] = ev.Rt @ J[2:5, :]
            H[0, 10] = H[1, 11] = H[2, 12] = 1.0
            h = ev.Rt @ np.array([acc[2], acc[3], acc[4] - self._pp[2]]) + x[SL_BIAS]
        elif ev.kind == "fix":
            H[:, 0:2] = payload_offset_jacobian(x[0], x[1], l)
            h = np.array(payload_offset_m(x[0], x[1], l))
        else:  # vel
            H[0, 4] = H[1, 5] = H[2, 6] = 1.0
            h = x[4:7]
        r2 = ev.sigma * ev.sigma
        PHt, S, Sinv = _innovation(P, H, r2)
        nu = ev.z - h
        nis = float(nu @ Sinv @ nu)
        ev.nis = nis
        if ev.kind == "fix":  # how well the model predicted this fix (model selection, two_model.py)
            self.fix_sq_error.append((ev.t, float(nu @ nu)))
            if len(self.fix_sq_error) > _FIX_ERRORS_KEPT:
                del self.fix_sq_error[:_FIX_ERRORS_KEPT // 2]
        hz = H[2, I_THRUST]
        if ev.kind == "imu" and nu[2] * nu[2] > _JUMP_SIGMAS2 * S[2, 2] and abs(hz) > 1e-9:
            # the body-z specific force is off by more than 3σ: the thrust produced changed faster than
            # q_thrust allows (a rotor saturating while the attitude loop fights a torque); let δT take it
            P = P.copy()
            P[I_THRUST, I_THRUST] += (nu[2] / hz) ** 2
            PHt, S, Sinv = _innovation(P, H, r2)
            nis_gate = float(nu @ Sinv @ nu)
        else:
            nis_gate = nis
        if ev.kind == "fix" and nis_gate > self.cfg.gate_nis:
            self._fixes_rejected_in_row += 1
            if self._fixes_rejected_in_row > self.cfg.fix_reset_after:
                # the fixes keep disagreeing: the filter has lost the swing; forget what it believed and re-lock
                P, x = self._reset_swing(P, x)
                PHt, S, Sinv = _innovation(P, H, r2)
                nis_gate = 0.0
                self._fixes_rejected_in_row = 0
                self.resets += 1
        elif ev.kind == "fix":
            self._fixes_rejected_in_row = 0
        if ev.kind == "fix" and self.cfg.q_swing_adapt_max > 1.0:
            ratio = max(min(nis, _NIS_CAP) / 3.0, 1e-6)
            self.q_swing_scale = min(max(self.q_swing_scale * ratio ** 0.25, 1.0), self.cfg.q_swing_adapt_max)
            self._Qc[2] = self._Qc[3] = self.cfg.q_swing * self.q_swing_scale
        if nis_gate <= self.cfg.gate_nis:
            K = PHt @ Sinv
            x = x + K @ nu
            if x[I_DRAG] < 0.0 or x[I_PDRAG] < 0.0:  # drag only takes energy out: a negative one is the two
                x[I_DRAG] = max(x[I_DRAG], 0.0)  # trading against each other, not physics (projected back)
                x[I_PDRAG] = max(x[I_PDRAG], 0.0)
            P = P - K @ PHt.T  # optimal gain: (I − K·H)·P (symmetrized; Joseph's form costs four products more)
            P = 0.5 * (P + P.T)
            ev.accepted = True
            ev.K = K
            ev.T = Phi - K @ (H @ Phi)
        else:
            ev.accepted = False
            ev.K = None
            ev.T = Phi
            self.rejected_total += 1
        ev.x, ev.P = x, P

    def _reset_swing(self, P: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Covariance with the swing block [α, β, α̇, β̇] reset to the reset sigmas and decorrelated from the rest;
        the rates set to zero (a diverged filter's rates are its worst part)."""
        c = self.cfg
        P = P.copy()
        P[0:4, :] = 0.0
        P[:, 0:4] = 0.0
        P[0:4, 0:4] = np.diag([c.reset_swing_sigma_rad ** 2] * 2 + [c.reset_rate_sigma_rad_s ** 2] * 2)
        x = x.copy()
        x[2:4] = 0.0
        return P, x

    def _replay(self, start: int, dx: np.ndarray, dP: np.ndarray) -> None:
        """Events[start:] again after the one before them changed by (dx, dP) because of a late measurement. With
        their stored gains and transitions T = (I − K·H)·Φ the change carries through linearly: x_k += M_k·dx,
        P_k += M_k·dP·M_kᵀ with M_k = T_k···T_start — exact for the linearized filter with those gains (the
        covariance of any gain, Joseph's form), and a few µs per event instead of running the filter again."""
        M = _IN
        for e in self._events[start:]:
            M = e.T @ M
            e.x = e.x + M @ dx
            P = e.P + M @ dP @ M.T
            e.P = 0.5 * (P + P.T)

    # ------------------------------------------------------------------------------------------- output
    def selection_facts(self) -> None:
        """For the report, like ``TwoModelEstimator.selection_facts`` (:mod:`companion.estimation.two_model`): one
        filter, nothing was chosen (None)."""
        return None

    @property
    def t_processed_s(self) -> float:
        """Time of the newest processed measurement (or the start)."""
        return self._events[-1].t if self._events else self._base.t

    def _frontier(self) -> _Event:
        return self._events[-1] if self._events else self._base

    def _trust(self, t: float) -> tuple[dict[str, float], tuple[str, ...], int]:
        key = (round(t / 0.05), self.rejected_total)  # recomputed every 50 ms, and at once after an outlier
        if self._trust_cache is not None and self._trust_cache[0] == key:
            return self._trust_cache[1], self._trust_cache[2], self._trust_cache[3]
        t_lo = t - self.cfg.trust_window_s
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        rejected = 0
        for e in reversed(self._events):
            if e.t < t_lo:
                break
            sums[e.kind] = sums.get(e.kind, 0.0) + min(e.nis, _NIS_CAP) / 3.0
            counts[e.kind] = counts.get(e.kind, 0) + 1
            rejected += 0 if e.accepted else 1
        nis = {k: sums[k] / counts[k] for k in sums}
        sources = tuple(s for s in SOURCES if s in nis)
        self._trust_cache = (key, nis, sources, rejected)
        return nis, sources, rejected

    def estimate(self, t_s: float) -> SwingEstimate:
        """The estimate at ``t_s``, predicted from the newest processed measurement with the inputs given. The
        mean is predicted to ``t_s``; the covariance in steps of ``cov_step_s`` (it changes slowly)."""
        t = float(t_s)
        self._flush(t - self.cfg.reorder_s)
        fr = self._frontier()
        sh = self._shadow
        if sh is None or sh[0] != self._version or t < sh[1]:
            sh = (self._version, fr.t, fr.x, fr.t, fr.P)
        _, t_x, x, t_P, P = sh
        if t > t_x:
            x = self._mean(x, t_x, t)
            t_x = t
        f = self._force(t_x, x)
        a = self._acc(x, f)
        if t_x - t_P >= self.cfg.cov_step_s:
            P, _ = self._cov(P, self._acc_jacobian(x, f, a), t_x - t_P)
            t_P = t_x
        self._shadow = (self._version, t_x, x, t_P, P)
        Ps = P[0:2, 0:2]
        tr = 0.5 * (Ps[0, 0] + Ps[1, 1])
        det = Ps[0, 0] * Ps[1, 1] - Ps[0, 1] * Ps[1, 0]
        sigma = math.sqrt(max(tr + math.sqrt(max(tr * tr - det, 0.0)), 0.0))
        bound = math.hypot(x[0], x[1]) + 3.0 * sigma
        nis, sources, rejected = self._trust(t)
        c = self.cfg
        f_sigma = _ramp_down(3.0 * sigma, *c.fade_bound3_rad)
        f_nis = _ramp_down(max(nis.values()), *c.fade_nis) if nis else 1.0
        f_fit = _ramp_down(self.q_swing_scale, *c.fade_q_scale)
        return SwingEstimate(
            t_s=t_x, swing=x[0:4].copy(), swing_acc=np.array([a[0], a[1]]), cov=P[0:4, 0:4].copy(),
            sigma_rad=sigma, bound_rad=bound, fade=f_sigma * f_nis * f_fit,
            force_ned_n=x[7:10] - x[I_DRAG] * np.array([x[4], x[5], 0.0]),
            accel_bias_frd_mps2=x[10:13].copy(), nis=nis, sources=sources, rejected=rejected,
            dropped_late=self.dropped_late, drag_n_per_mps=float(x[I_DRAG]),
            payload_drag_n_per_mps2=float(x[I_PDRAG]),
        )


def _ramp_down(v: float, lo: float, hi: float) -> float:
    """1 below ``lo``, 0 above ``hi``, linear between."""
    if v <= lo:
        return 1.0
    if v >= hi:
        return 0.0
    return (hi - v) / (hi - lo)

