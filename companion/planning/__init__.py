"""Planners by name: ``traditional``, ``improved`` (the paper, as printed), ``safe`` and ``shaped`` (ours), ``none``."""

from __future__ import annotations

from companion.core.model import VehicleParams
from companion.planning.apf import ApfPlanner
from companion.planning.base import PlanInput, Planner, PlanOutput, ReferenceSample
from companion.planning.params import PlannerParams
from companion.planning.reference import ReferenceGenerator
from companion.planning.safe import SafePlanner
from companion.planning.shaped import ShapedPlanner

PLANNER_NAMES = ("traditional", "improved", "safe", "shaped", "none")

__all__ = [
    "PLANNER_NAMES",
    "ApfPlanner",
    "PlanInput",
    "PlanOutput",
    "Planner",
    "PlannerParams",
    "ReferenceGenerator",
    "ReferenceSample",
    "SafePlanner",
    "ShapedPlanner",
    "make_planner",
]


def make_planner(name: str, params: PlannerParams | None = None, vehicle: VehicleParams | None = None) -> Planner:
    """A fresh planner (planners keep state: the safe planner's turning side, the shaped planner's plan) by
    name; ``vehicle`` gives the shaped planner the model's pendulum frequency (else it takes l and g from
    its inputs)."""
    params = params or PlannerParams()
    if name == "safe":
        return SafePlanner(params)
    if name == "shaped":
        return ShapedPlanner(params, vehicle)
    if name in ("traditional", "improved", "none"):
        return ApfPlanner(name, params)
    raise ValueError(f"planner: unknown planner {name!r} (known: {', '.join(PLANNER_NAMES)})")
