"""When the vehicle counts as at the goal: within a horizontal tolerance (widened to the autopilot's reported
position accuracy) and a vertical one, for a dwell time on end. Pure; times are the estimates' (s)."""

from __future__ import annotations

import math

import numpy as np

from companion.estimation.estimate import Estimate

ARRIVE_HORIZ_M = 0.1  # arrival tolerance (m) where the autopilot reports no position accuracy, and the least
ARRIVE_ACCURACY_K = 1.0  # ... otherwise ARRIVE_ACCURACY_K × its 1σ horizontal accuracy (PX4's ESTIMATOR_STATUS)
ARRIVE_DWELL_S = 0.3  # the vehicle must stay within the tolerance this long for the arrival to count
ARRIVE_VERT_M = 0.25


def arrival_tolerance_m(est: Estimate) -> float:
    """How close (m, horizontally) counts as at the goal: ARRIVE_HORIZ_M, widened to ARRIVE_ACCURACY_K times
    the autopilot's reported 1σ position accuracy: the estimated position wanders by about that much, so a
    tighter tolerance is met only by chance (PX4 SIH reports 0.29 m; at 0.1 m its arrival took seconds)."""
    acc = est.pos_accuracy_m
    return ARRIVE_HORIZ_M if acc is None else max(ARRIVE_HORIZ_M, ARRIVE_ACCURACY_K * acc)


class ArrivalRule:
    """Watches the vehicle near ``goal_ned_m``; :attr:`facts` is the arrival rule of this flight for the report:
    tolerance (m), dwell (s), the accuracy it came from, and when the vehicle arrived (``t_s``)."""

    def __init__(self, goal_ned_m: np.ndarray) -> None:
        self.goal_ned_m = goal_ned_m
        self._t_within_s: float | None = None  # since when the vehicle is within the tolerance
        self.facts: dict[str, float | None] = {"tolerance_m": ARRIVE_HORIZ_M, "dwell_s": ARRIVE_DWELL_S,
                                               "accuracy_m": None, "t_s": None}

    def arrived(self, est: Estimate) -> float | None:
        """The time (s) the vehicle first got within the tolerance, once it has stayed there for the dwell
        time; None until then."""
        g, pos, t = self.goal_ned_m, est.pos_ned_m, est.t_s
        dh = math.hypot(pos[0] - g[0], pos[1] - g[1])
        tol = arrival_tolerance_m(est)
        if not (dh < tol and abs(float(pos[2]) - g[2]) < ARRIVE_VERT_M):
            self._t_within_s = None
            return None
        if self._t_within_s is None:
            self._t_within_s = t
        if t - self._t_within_s < ARRIVE_DWELL_S:
            return None
        self.facts.update(tolerance_m=tol, accuracy_m=est.pos_accuracy_m, t_s=self._t_within_s)
        return self._t_within_s
