"""Planner parameters (the ``[planner]`` table of ``config/controller.toml``), SI units."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class PlannerParams:
    """Gains and limits of the planners and of the reference generator.

    APF (eqs. 22–28): ``ka`` attraction gain (1/s: the force is read as a desired velocity, see
    :mod:`companion.planning.apf`), ``kr`` repulsion gain (m³/s). Reference generator: ``v_max_mps``
    horizontal speed, ``a_max_mps2`` acceleration, ``j_max_mps3`` jerk, ``k_vel`` velocity-tracking gain
    (1/s), ``vz_max_mps`` / ``az_max_mps2`` vertical limits. Safe planner: ``a_brake_mps2`` braking
    deceleration assumed for the speed-dependent influence range, ``influence_m`` base influence range,
    ``gamma`` barrier rate (1/s: approach speed <= gamma·gap), ``track_margin_m`` allowance for tracking
    error on top of the measured one, ``stuck_speed_mps`` / ``stuck_time_s`` local-minimum detector,
    ``goal_tol_m`` arrival tolerance, ``lookahead_s`` how far ahead (s, along the reference velocity) the
    safe planner also measures each gap for its barrier (the reference generator's velocity lag),
    ``steer_lookahead_s`` the same for its steering, ``a_goal_mps2`` braking deceleration towards the
    goal, ``goal_lookahead_s`` lag allowance of that braking, ``error_lookahead_s`` horizon of the predicted
    tracking error in the margin (see :mod:`companion.planning.safe`).
    """

    ka: float = 1.5
    kr: float = 3.0
    v_max_mps: float = 2.0
    a_max_mps2: float = 1.8
    j_max_mps3: float = 6.0
    k_vel: float = 3.0
    vz_max_mps: float = 1.5
    az_max_mps2: float = 2.0
    a_brake_mps2: float = 1.2
    influence_m: float = 0.6
    gamma: float = 2.0
    track_margin_m: float = 0.08
    stuck_speed_mps: float = 0.15
    stuck_time_s: float = 1.0
    goal_tol_m: float = 0.05
    lookahead_s: float = 0.4
    steer_lookahead_s: float = 0.4
    a_goal_mps2: float = 1.8
    goal_lookahead_s: float = 0.5
    error_lookahead_s: float = 0.3

    def validate(self) -> None:
        """Raise ``ValueError("<key>: must be > 0")`` for non-positive or non-finite values."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{f.name}: must be > 0, got {v}")
