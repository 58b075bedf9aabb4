"""What every planner consumes and produces.

A planner maps the situation (vehicle and reference positions, envelope radius, swing, obstacles, goal) to
a desired horizontal velocity ``v_des_mps`` in NED (2,). The potential-field planners read their virtual
force as that velocity (gradient flow: ``v_des = sat(F_all, v_max)``; see :mod:`companion.planning.apf`),
the safe planner builds it directly. The :class:`~companion.planning.reference.ReferenceGenerator` turns
the desired velocity into a flyable reference (position, velocity, acceleration) with acceleration and jerk
limits; the position controller tracks that reference.

A *time-parameterised* planner (``time_parameterised`` True: the ``shaped`` planner)
produces the horizontal reference itself, :class:`ReferenceSample` in ``PlanOutput.reference``, including the
payload's nominal swing along it; the flight core then flies that reference instead of integrating
``v_des_mps``. Such a planner may also find that no route to the goal exists (``PlanOutput.no_route``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple, Protocol, runtime_checkable

import numpy as np

from companion.core.obstacles import Obstacle


class PlanInput(NamedTuple):
    """Inputs for one planning step. Horizontal NED vectors (2,), metres and m/s.

    pos_m / vel_mps: measured airframe; ref_pos_m / ref_vel_mps: current reference; goal_m: goal;
    r_max_m: envelope radius now (eq. 21, or the full cable without swing sensing); swing: [α, β, α̇, β̇]
    or None; cable_l_m, airframe_r_m (r_uav + L_uav); z_ned_m: airframe altitude (NED z, m) for "below the trunk's top"
    tests; t_s: time; swing_sigma_rad: standard deviation (rad) of the swing estimate's error (0: exact, the
    cable-angle sensor; the swing estimator will supply it), used by planners that widen their envelope by it.

    Multi-leg missions (:mod:`companion.flight.legs`): ``goal_m`` is the next point to stop at or pass;
    ``goal_pass_mps`` the speed (m/s) the goal may be passed at (0: stop there; the safe planner brakes to it
    instead of to rest); ``via_m`` the pass-through points (2,) before the goal, for a time-parameterised planner
    that plans through them as one path; ``leg_caps_mps`` the speed limit (m/s, inf: none) of each leg of that
    path (len(via_m) + 1; empty: none).

    ``v_cap_mps``: the speed (m/s) the flight may keep inside the space its range sensor has seen free
    (:mod:`companion.planning.stop_cap`; inf without perception): the planners fly no faster.

    ``drift_ned_m``: where (m, NED x y, downwind) the wind's drag holds the payload off the path planned for it,
    the horizontal cable offset at the swing's slow equilibrium θ_eq (:mod:`companion.control.swing_bias`: measured
    from forces, so a re-plan's swing is not in it); 0 without a swing input. :attr:`drift_m` is its length.

    ``drag_c``: the payload's drag angle per (m/s)² of airspeed (rad), as declared or identified in flight
    (:mod:`companion.control.drag_id`; 0: none or not yet known); ``wind_mps``: the wind (m/s, NED x y) measured
    with it. The shaped planner's timing budgets the trailing they give
    (:class:`~companion.planning.timing.DragBudget`). ``gust_drag_tan``: the tangent of the payload's drag angle
    in a gust to budget its drift for (:attr:`~companion.control.drag_id.DragIdentifier.gust_drag_tan`, 0: none).

    This and the outputs below are named tuples: immutable, and built every control tick at a fifth of a frozen
    dataclass's cost.
    """

    t_s: float
    pos_m: np.ndarray
    vel_mps: np.ndarray
    ref_pos_m: np.ndarray
    ref_vel_mps: np.ndarray
    goal_m: np.ndarray
    r_max_m: float
    swing: np.ndarray | None
    cable_l_m: float
    airframe_r_m: float
    g_mps2: float = 9.81
    z_ned_m: float = 0.0
    swing_sigma_rad: float = 0.0
    goal_pass_mps: float = 0.0
    via_m: tuple[np.ndarray, ...] = ()
    leg_caps_mps: tuple[float, ...] = ()
    v_cap_mps: float = math.inf
    drift_ned_m: tuple[float, float] = (0.0, 0.0)
    drag_c: float = 0.0
    wind_mps: tuple[float, float] = (0.0, 0.0)
    gust_drag_tan: float = 0.0

    @property
    def drift_m(self) -> float:
        """How far (m) the wind's drag holds the payload off its path: the length of ``drift_ned_m``."""
        return math.hypot(*self.drift_ned_m)


class ReferenceSample(NamedTuple):
    """A time-parameterised planner's horizontal reference at one instant (NED, SI; tuples of floats).

    pos_m, vel_mps, acc_mps2, jerk_mps3: the airframe's reference (2 each); swing_nom: the nominal swing the
    payload has when the airframe flies it, [α, β, α̇, β̇, α̈, β̈] (rad, rad/s, rad/s²).
    """

    pos_m: tuple[float, float]
    vel_mps: tuple[float, float]
    acc_mps2: tuple[float, float]
    jerk_mps3: tuple[float, float]
    swing_nom: tuple[float, float, float, float, float, float]


class PlanOutput(NamedTuple):
    """Desired horizontal velocity (2,) m/s, and the attractive / repulsive parts for plots and telemetry.

    ``reference``: the horizontal reference itself (time-parameterised planners only, else None);
    ``no_route``: the planner has established that no route to the goal exists (it holds at a safe point).
    """

    v_des_mps: np.ndarray
    force_att: np.ndarray
    force_rep: np.ndarray
    mode: str = "track"
    reference: ReferenceSample | None = None
    no_route: bool = False


@runtime_checkable
class Planner(Protocol):
    """Everything the flight core uses of a planner; every planner implements all of it.

    ``name``: its registry name; ``time_parameterised``: whether :meth:`plan` gives the horizontal reference
    itself (``PlanOutput.reference``) rather than a desired velocity.
    """

    @property
    def name(self) -> str: ...

    @property
    def time_parameterised(self) -> bool: ...

    def plan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> PlanOutput:
        """The plan at ``inp.t_s`` around ``obstacles`` (see :class:`PlanOutput`)."""
        ...

    def stop(self) -> None:
        """Stop the mission where the plan allows and hold there (a hold the flight sequence asked for); takes
        effect at the next :meth:`plan`. A no-op for planners that give a desired velocity: the flight core
        then holds the reference itself."""
        ...

    def resume(self) -> None:
        """Fly on after :meth:`stop` (a ground station's pause ended): the next :meth:`plan` plans from where the
        stop left the plan. A no-op for planners that give a desired velocity."""
        ...

    def facts(self) -> dict[str, Any]:
        """What the report says of the planner's flight (its own counters; JSON-ready)."""
        ...


def saturate(v: np.ndarray, limit: float) -> np.ndarray:
    """``v`` scaled down to norm ``limit`` if longer."""
    n = float(np.linalg.norm(v))
    return v * (limit / n) if n > limit else v
