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
    (1/s), ``vz_max_mps`` / ``az_max_mps2`` vertical limits, ``start_jerk_frac`` / ``start_ramp_mps`` a gentler
    onset when speeding up from rest: the horizontal jerk limit is ``j_max_mps3`` × start_jerk_frac at rest,
    rising linearly to the full limit at ``start_ramp_mps`` (braking always has the full limit; 1 = off). The
    default 0.5 takes the Table 2 forest's peak swing from 0.265 to 0.248 rad for 0.12 s more (0.4: 0.239 rad,
    +0.19 s). Safe planner:
    ``a_brake_mps2`` braking deceleration assumed for the speed-dependent influence range, ``influence_m`` base
    influence range, ``gamma`` barrier rate (1/s: approach speed <= gamma·gap), ``track_margin_m`` allowance for
    tracking error on top of the measured one, ``stuck_speed_mps`` / ``stuck_time_s`` local-minimum detector,
    ``goal_tol_m`` arrival tolerance, ``lookahead_s`` how far ahead (s, along the reference velocity) the
    safe planner also measures each gap for its barrier (the reference generator's velocity lag),
    ``steer_lookahead_s`` the same for its steering, ``a_goal_mps2`` braking deceleration towards the
    goal, ``goal_lookahead_s`` lag allowance of that braking, ``error_lookahead_s`` horizon of the predicted
    tracking error in the margin, ``vehicle_lookahead_s`` how far ahead (s, along the vehicle's own velocity) the
    barrier also measures each gap from where the vehicle will be, ``safe_no_progress_s`` how long (s) the reference
    may come no closer to the goal before the planner declares no route (see
    :mod:`companion.planning.safe`).

    Shaped planner (:mod:`companion.planning.shaped`): ``shaped_a_max_mps2`` bound on the planned payload
    acceleration (the nominal swing is atan(a/g): 1.85 m/s² is 0.187 rad), ``shaped_v_max_mps`` speed cap,
    ``shaper_tau_s`` the three moving-average widths (s) of the smoothing cascade for pendulum periods up to
    ``shaper_period_s`` (a longer period scales them by its ratio to it), ``shaped_step_s`` the time
    step of the planned reference, ``replan_rate_hz`` how often the plan is checked against the latest obstacles
    (and the route search rerun whenever an obstacle appeared, vanished, changed or left its predicted
    track, the envelope grew, or the plan failed the check), ``route_refresh_s`` how often the search reruns
    anyway,
    ``route_ds_m`` spacing of the points of the minimum-curvature path, ``route_extra_m`` /
    ``route_candidates`` the extra inflations (k·extra, k = 0 .. candidates−1) whose routes are timed and
    compared, ``replan_hysteresis_s`` how much
    faster (s) a new plan must be to replace a valid current one, ``no_route_confirm_s`` how long the route
    search must fail before the planner declares that there is none, ``goal_wind_wait_s`` how long it waits in all,
    with the goal within the wind's reach of a trunk, before it declares the same (:mod:`~.wind_wait`),
    ``swing_sigma_k`` how many standard deviations of the swing estimate's uncertainty widen the envelope,
    ``predict_growth_mps`` how fast the
    predicted position of a moving obstacle grows uncertain (m per s of look-ahead), ``error_hold_s`` how
    long a tracking-error peak is remembered in the margin, ``shaped_brake_mps2`` the deceleration allowed
    when the current speed is too high for what lies ahead (also the no-route stop), ``drag_swing_budget_rad``
    the swing (rad) the planned speed-up and the payload's drag trailing share once the drag is measured
    (:class:`~companion.planning.timing.DragBudget`; Table 1's atan(1.85/9.81), not scaled with the payload: a long
    cable's lower acceleration leaves the trailing more of it).
    """

    ka: float = 1.5
    kr: float = 3.0
    v_max_mps: float = 2.0
    a_max_mps2: float = 1.8
    j_max_mps3: float = 6.0
    start_jerk_frac: float = 0.5
    start_ramp_mps: float = 1.0
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
    vehicle_lookahead_s: float = 0.8
    safe_no_progress_s: float = 20.0
    shaped_a_max_mps2: float = 1.85
    shaped_v_max_mps: float = 6.0
    shaper_tau_s: tuple[float, float, float] = (0.3, 0.35, 0.4)
    shaper_period_s: float = 2.01
    shaped_step_s: float = 0.01
    replan_rate_hz: float = 20.0
    route_refresh_s: float = 0.5
    route_ds_m: float = 0.4
    route_extra_m: float = 0.2
    route_candidates: int = 6
    replan_hysteresis_s: float = 0.15
    no_route_confirm_s: float = 0.5
    goal_wind_wait_s: float = 30.0
    swing_sigma_k: float = 2.0
    predict_growth_mps: float = 0.1
    error_hold_s: float = 2.0
    shaped_brake_mps2: float = 3.0
    drag_swing_budget_rad: float = 0.186

    def validate(self) -> None:
        """Raise ``ValueError("<key>: must be > 0")`` for non-positive or non-finite values."""
        for f in fields(self):
            v = getattr(self, f.name)
            for x in v if isinstance(v, tuple) else (v,):
                if not (math.isfinite(x) and x > 0.0):
                    raise ValueError(f"{f.name}: must be > 0, got {v}")
        if not 1 <= self.route_candidates <= 8:
            raise ValueError(f"route_candidates: must be in 1..8, got {self.route_candidates}")
        if self.start_jerk_frac > 1.0:
            raise ValueError(f"start_jerk_frac: must be in (0, 1] (1 = off), got {self.start_jerk_frac}")
        if self.replan_rate_hz < 1.0:
            raise ValueError(f"replan_rate_hz: must be >= 1, got {self.replan_rate_hz}")
