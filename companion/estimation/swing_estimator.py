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

Its settings and output types: :mod:`companion.estimation.swing_config`; the events, input histories and the
process model's propagation: :mod:`companion.estimation.swing_ekf_parts`; the measurements' timeline (reorder
wait, late insertion, replay, pruning): :mod:`companion.estimation.swing_events`.

Trust (:mod:`companion.estimation.swing_trust`): the averaged normalized innovation squared per source over the
last ``trust_window_s`` and the 1σ of the swing angle give ``fade`` in [0, 1] (scale the feed-forward by it) and
``bound_rad`` (|swing| + 3σ, for the envelope).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_config import SwingEstimate, SwingEstimatorConfig
from companion.estimation.swing_ekf_parts import Event, InputHistory, Propagation, innovation
from companion.estimation.swing_events import EventTimeline
from companion.estimation.swing_model import (
    I_DRAG,
    I_PDRAG,
    I_THRUST,
    N_STATE,
    SL_BIAS,
    payload_offset_jacobian,
    payload_offset_m,
    rotation_from_euler,
    rotation_from_quat,
)
from companion.estimation.swing_trust import NIS_CAP, fade, swing_sigma_rad, windowed_nis

_JUMP_SIGMAS2 = 9.0
_FIX_ERRORS_KEPT = 200


class SwingEstimator(Propagation, EventTimeline):
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
        self._base = Event(t=float(t0_s), seq=-1, kind="init", z=np.zeros(0), sigma=np.zeros(3), x=x, P=P)
        self._events: list[Event] = []
        self._pending: list[tuple[float, int, Event]] = []  # in-order measurements waiting ``reorder_s``
        self._seq = 0
        self._att = InputHistory()
        self._thr = InputHistory()
        self._pos = InputHistory()
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

    def _apply(self, ev: Event, x0: np.ndarray, P0: np.ndarray, t0: float) -> None:
        """Predict from (t0, x0, P0) to the event and fuse it; stores the result, the gain and the transition
        (I − K·H)·Φ in the event (for replays)."""
        x, P, acc, J, Phi = self._propagate(x0, P0, t0, ev.t)
        if not self._drag_free:
            P = self._note_kind(ev.kind, P)
        H, h = self._measurement(ev, x, acc, J)
        r2 = ev.sigma * ev.sigma
        PHt, S, Sinv = innovation(P, H, r2)
        nu = ev.z - h
        nis = float(nu @ Sinv @ nu)
        ev.nis = nis
        if ev.kind == "fix":  # how well the model predicted this fix (model selection, two_model.py)
            self.fix_sq_error.append((ev.t, float(nu @ nu)))
            if len(self.fix_sq_error) > _FIX_ERRORS_KEPT:
                del self.fix_sq_error[:_FIX_ERRORS_KEPT // 2]
        x, P, PHt, Sinv, nis_gate = self._gate(ev.kind, x, P, H, r2, nu, nis, PHt, S, Sinv)
        if ev.kind == "fix" and self.cfg.q_swing_adapt_max > 1.0:
            ratio = max(min(nis, NIS_CAP) / 3.0, 1e-6)
            self.q_swing_scale = min(max(self.q_swing_scale * ratio ** 0.25, 1.0), self.cfg.q_swing_adapt_max)
            self._Qc[2] = self._Qc[3] = self.cfg.q_swing * self.q_swing_scale
        self._fuse(ev, x, P, H, nu, PHt, Sinv, Phi, nis_gate)

    def _note_kind(self, kind: str, P: np.ndarray) -> np.ndarray:
        """Note a measurement kind; once both a velocity and an accelerometer reading came, the drag coefficients
        are learnt from then on (their prior variance added to ``P``, their process noise switched on)."""
        if kind not in self._kinds_seen:
            self._kinds_seen.add(kind)
        if {"imu", "vel"} <= self._kinds_seen:
            self._drag_free = True
            P = P.copy()
            P[I_DRAG, I_DRAG] += self._drag_sigma0 ** 2
            self._Qc[I_DRAG] = self.cfg.q_drag
            if self._pdrag_sigma0 > 0.0:  # a payload said to drag: its coefficient is refined
                P[I_PDRAG, I_PDRAG] += self._pdrag_sigma0 ** 2
                self._Qc[I_PDRAG] = self.cfg.q_payload_drag
        return P

    def _measurement(self, ev: Event, x: np.ndarray, acc, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, h): the event's measurement Jacobian (3 × N_STATE) and predicted value at the predicted state
        ``x`` (accelerations ``acc`` and their Jacobian ``J`` from the propagation); sets ``ev.Rt`` for the IMU."""
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
        return H, h

    def _gate(self, kind: str, x: np.ndarray, P: np.ndarray, H: np.ndarray, r2: np.ndarray, nu: np.ndarray,
              nis: float, PHt: np.ndarray, S: np.ndarray, Sinv: np.ndarray) -> tuple:
        """The NIS the gate judges (x, P, PHt, S⁻¹, NIS): a body-z specific force far off widens the thrust
        error's variance first; fixes rejected ``fix_reset_after`` times in a row reset the swing (NIS 0)."""
        hz = H[2, I_THRUST]
        if kind == "imu" and nu[2] * nu[2] > _JUMP_SIGMAS2 * S[2, 2] and abs(hz) > 1e-9:
            # the body-z specific force is off by more than 3σ: the thrust produced changed faster than
            # q_thrust allows (a rotor saturating while the attitude loop fights a torque); let δT take it
            P = P.copy()
            P[I_THRUST, I_THRUST] += (nu[2] / hz) ** 2
            PHt, S, Sinv = innovation(P, H, r2)
            nis_gate = float(nu @ Sinv @ nu)
        else:
            nis_gate = nis
        if kind == "fix" and nis_gate > self.cfg.gate_nis:
            self._fixes_rejected_in_row += 1
            if self._fixes_rejected_in_row > self.cfg.fix_reset_after:
                # the fixes keep disagreeing: the filter has lost the swing; forget what it believed and re-lock
                P, x = self._reset_swing(P, x)
                PHt, S, Sinv = innovation(P, H, r2)
                nis_gate = 0.0
                self._fixes_rejected_in_row = 0
                self.resets += 1
        elif kind == "fix":
            self._fixes_rejected_in_row = 0
        return x, P, PHt, Sinv, nis_gate

    def _fuse(self, ev: Event, x: np.ndarray, P: np.ndarray, H: np.ndarray, nu: np.ndarray, PHt: np.ndarray,
              Sinv: np.ndarray, Phi: np.ndarray, nis_gate: float) -> None:
        """The Kalman update when the gate passes (else the event is rejected and only predicted); stores the
        state, covariance, gain and transition in the event."""
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

    # ------------------------------------------------------------------------------------------- output
    def selection_facts(self) -> None:
        """For the report, like ``TwoModelEstimator.selection_facts`` (:mod:`companion.estimation.two_model`): one
        filter, nothing was chosen (None)."""
        return None

    def _trust(self, t: float) -> tuple[dict[str, float], tuple[str, ...], int]:
        """:func:`~companion.estimation.swing_trust.windowed_nis` over the last ``trust_window_s``, recomputed every
        50 ms, and at once after an outlier."""
        key = (round(t / 0.05), self.rejected_total)
        if self._trust_cache is not None and self._trust_cache[0] == key:
            return self._trust_cache[1], self._trust_cache[2], self._trust_cache[3]
        nis, sources, rejected = windowed_nis(self._events, t - self.cfg.trust_window_s)
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
        sigma = swing_sigma_rad(P)
        bound = math.hypot(x[0], x[1]) + 3.0 * sigma
        nis, sources, rejected = self._trust(t)
        return SwingEstimate(
            t_s=t_x, swing=x[0:4].copy(), swing_acc=np.array([a[0], a[1]]), cov=P[0:4, 0:4].copy(),
            sigma_rad=sigma, bound_rad=bound, fade=fade(sigma, nis, self.q_swing_scale, self.cfg),
            force_ned_n=x[7:10] - x[I_DRAG] * np.array([x[4], x[5], 0.0]),
            accel_bias_frd_mps2=x[10:13].copy(), nis=nis, sources=sources, rejected=rejected,
            dropped_late=self.dropped_late, drag_n_per_mps=float(x[I_DRAG]),
            payload_drag_n_per_mps2=float(x[I_PDRAG]),
        )
