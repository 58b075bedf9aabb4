"""The swing estimator's parts below its filter logic: the measurement events and input histories it keeps, the
3×3 innovation algebra, and the process model's propagation — mean (RK2), the accelerations' Jacobian and the
covariance step — as :class:`Propagation`, mixed into :class:`~companion.estimation.swing_estimator.SwingEstimator`
(whose inputs, model constants and noise it reads). Models: :mod:`companion.estimation.swing_model`."""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from companion.estimation.swing_model import (
    I_DRAG,
    I_PDRAG,
    I_THRUST,
    N_STATE,
    accel_force_jacobian_rows,
    payload_drag_unit,
    payload_force_ned_n,
    rotate_by_rates,
    thrust_axis_by_rates,
    translation_swing_accel,
)

IDENTITY = np.eye(N_STATE)
_I3 = np.eye(3)
MAX_EXTRAPOLATE_S = 0.05  # the attitude is extrapolated with its body rates at most this far (s)


@dataclass(slots=True)
class Event:
    """One measurement in the filter's history (time s, arrival order, kind, value, 1σ) and what fusing it gave."""

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
class InputHistory:
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


def inv3(S: np.ndarray) -> np.ndarray:
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


def innovation(P: np.ndarray, H: np.ndarray, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P·Hᵀ, the innovation covariance S = H·P·Hᵀ + diag(r2) and its inverse, for a 3-row measurement."""
    PHt = P @ H.T
    S = H @ PHt
    S[0, 0] += r2[0]
    S[1, 1] += r2[1]
    S[2, 2] += r2[2]
    return PHt, S, inv3(S)


class Propagation:
    """The process model's propagation for :class:`~companion.estimation.swing_estimator.SwingEstimator` (a mixin:
    it uses the estimator's ``cfg``, ``_pp`` (M, m, g, Ip, l), ``_hover_n``, ``_Qc`` and its input histories
    ``_att`` and ``_thr``)."""

    def _dt_att(self, t: float) -> tuple[float, tuple] | None:
        a = self._att.at(t)
        if a is None:
            return None
        return min(max(t - a[0], -MAX_EXTRAPOLATE_S), MAX_EXTRAPOLATE_S), a[1]

    def _force(self, t: float, x: np.ndarray) -> tuple[float, float, float, float, float, float]:
        """(f, body z axis) at time t (N and unit vector, NED): f = F − c·(v_N, v_E, 0) + d, every non-gravity,
        non-cable force on the airframe, with the thrust T + δT along −z body (attitude from the sample before t
        extrapolated with its body rates; level before any sample), T held from its last command (the hover
        thrust before any)."""
        a = self._att.at(t)
        if a is None:
            b0, b1, b2 = 0.0, 0.0, 1.0
        else:
            dt = min(max(t - a[0], -MAX_EXTRAPOLATE_S), MAX_EXTRAPOLATE_S)
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
        return IDENTITY + A + 0.5 * (A @ A)

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
        Phi_total = IDENTITY
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
