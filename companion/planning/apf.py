"""The paper's potential-field planners, as printed: traditional (eqs. 22–26) and improved (eqs. 27–28).

Both evaluate the field at the measured airframe position ξ* (the paper's "real flight trajectory").
ρ_oi is the distance between centres (vehicle to obstacle axis). Repulsion acts while ρ_oi <= ρ0 with

* traditional: ρ0 = l + r_oi + Δd_min (cable length as the fixed avoidance distance),
* improved:    ρ* = R_max + r_oi + Δd_min (the live envelope radius of eq. 21).

From force to reference (not in the paper; our choice): the resultant force is read as a desired velocity,
``v_des = sat(F_all, v_max)`` (gradient flow on the potential, units: ka in 1/s, kr in m³/s), and the
reference generator integrates it with acceleration and jerk limits. Far from the goal F_att saturates to
v_max, near it the approach is exponential with rate ka; the speed is also capped by the braking profile
sqrt(2·a_brake·ρ_goal) so that the reference never needs more deceleration than it may use (without it
the acceleration-limited reference overshoots the goal). The cap changes no direction, only speed.
For ``none`` (no obstacles; the paper's group 1) ρ_goal in the cap is measured from where the reference
will be in ``goal_lookahead_s`` (its velocity lags the desired one), as in the safe planner: the
vehicle no longer overshoots the goal by ~0.3 m and sets the payload swinging there (group 1, smc_ff:
swing below 0.05 rad 2.2 s after arrival instead of 4.0 s). ``traditional`` and ``improved`` keep the
cap as it was.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.core.obstacles import Obstacle
from companion.planning.base import PlanInput, PlanOutput, saturate
from companion.planning.params import PlannerParams


def attractive_force(pos_m: np.ndarray, goal_m: np.ndarray, ka: float) -> np.ndarray:
    """F_att = ka·ρ(ξ_T, ξ*)·∇ρ (eq. 23): ka times the vector to the goal (2,)."""
    return ka * (np.asarray(goal_m, dtype=np.float64) - np.asarray(pos_m, dtype=np.float64))


def repulsive_force(pos_m: np.ndarray, obstacle_m: np.ndarray, kr: float, rho0_m: float) -> np.ndarray:
    """F_rep = kr·(1/ρ − 1/ρ0)·(1/ρ²)·∇ρ for ρ <= ρ0, else 0 (eqs. 25 and 27); ∇ρ points away from it."""
    d = np.asarray(pos_m, dtype=np.float64) - np.asarray(obstacle_m, dtype=np.float64)
    rho = float(np.linalg.norm(d))
    if rho > rho0_m or rho <= 1e-9:
        return np.zeros(2)
    return kr * (1.0 / rho - 1.0 / rho0_m) / (rho * rho) * (d / rho)


def rho0_traditional_m(o: Obstacle, cable_l_m: float) -> float:
    """ρ0 = l + r_oi + Δd_min."""
    return cable_l_m + o.radius_m + o.safe_distance_m


def rho_star_improved_m(o: Obstacle, r_max_m: float) -> float:
    """ρ* = R_max + r_oi + Δd_min (eq. 27)."""
    return r_max_m + o.radius_m + o.safe_distance_m


class ApfPlanner:
    """``traditional`` or ``improved`` APF (see module docstring); ``none`` is attraction only."""

    time_parameterised = False

    def __init__(self, kind: str, params: PlannerParams) -> None:
        if kind not in ("traditional", "improved", "none"):
            raise ValueError(f"planner: unknown APF kind {kind!r}")
        self.name = kind
        self.params = params

    def stop(self) -> None:
        """Nothing to stop: the flight core holds the reference itself (:class:`~companion.planning.base.Planner`)."""

    def resume(self) -> None:
        """Nothing to resume: the flight core flies on itself (:class:`~companion.planning.base.Planner`)."""

    def facts(self) -> dict[str, int]:
        """Nothing of its own to report: the paper's APFs keep no state between ticks."""
        return {}

    def plan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> PlanOutput:
        """Resultant force (eq. 26 / 28) at the measured position, read as desired velocity."""
        p = self.params
        f_att = attractive_force(inp.pos_m, inp.goal_m, p.ka)
        f_rep = np.zeros(2)
        if self.name != "none":
            for o in obstacles:
                if self.name == "traditional":
                    rho0 = rho0_traditional_m(o, inp.cable_l_m)
                else:
                    rho0 = rho_star_improved_m(o, inp.r_max_m)
                f_rep = f_rep + repulsive_force(inp.pos_m, np.array([o.x_m, o.y_m]), p.kr, rho0)
        rho_goal = float(np.linalg.norm(inp.goal_m - inp.pos_m))
        if self.name == "none":
            # no obstacles to answer to (group 1): brake from where the lagging reference will be, as the safe
            # planner does, so the vehicle does not overshoot the goal and set the payload swinging there
            ex, ey = float(inp.goal_m[0] - inp.ref_pos_m[0]), float(inp.goal_m[1] - inp.ref_pos_m[1])
            d = math.hypot(ex, ey)
            v_along = (float(inp.ref_vel_mps[0]) * ex + float(inp.ref_vel_mps[1]) * ey) / d if d > 1e-9 else 0.0
            rho_goal = max(0.0, rho_goal - p.goal_lookahead_s * max(0.0, v_along))
        v = saturate(f_att + f_rep, min(p.v_max_mps, math.sqrt(2.0 * p.a_brake_mps2 * rho_goal)))
        return PlanOutput(v_des_mps=v, force_att=f_att, force_rep=f_rep)
