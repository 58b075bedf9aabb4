"""Planners by name: ``traditional``, ``improved`` (the paper, as printed), ``safe`` (ours), ``none``."""

from __future__ import annotations

from companion.planning.apf import ApfPlanner
from companion.planning.base import PlanInput, Planner, PlanOutput
from companion.planning.params import PlannerParams
from companion.planning.reference import ReferenceGenerator
from companion.planning.safe import SafePlanner

PLANNER_NAMES = ("traditional", "improved", "safe", "none")

__all__ = [
    "PLANNER_NAMES",
    "ApfPlanner",
    "PlanInput",
    "PlanOutput",
    "Planner",
    "PlannerParams",
    "ReferenceGenerator",
    "SafePlanner",
    "make_planner",
]


def make_planner(name: str, params: PlannerParams | None = None) -> Planner:
    """A fresh planner (planners keep a little state: the safe planner's turning side) by name."""
    params = params or PlannerParams()
    if name == "safe":
        return SafePlanner(params)
    if name in ("traditional", "improved", "none"):
        return ApfPlanner(name, params)
    raise ValueError(f"planner: unknown planner {name!r} (known: {', '.join(PLANNER_NAMES)})")
