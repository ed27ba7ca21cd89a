"""Ego planners and their registry: ``make_planner("cdf", **kwargs)``,
``register(name, target, **defaults)``; a planner is told a :class:`PlannerContext` at
reset (what the ego knows) and a :class:`PlannerInput` each tick.

Planners decide from measurements and the junction's static layout; they never see the
live simulation. The baselines (``CVPlanner``, ``IMMPlanner`` and their configs) are
imported on first access, as they import filterpy (about 1 s).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cdf_mj.planners.base import DecidingPlanner, Planner, PlannerContext, PlannerInput, predicted_label
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.registry import PLANNERS, LazyPlanner, PlannerSpec, make_planner, register
from cdf_mj.planners.simple import ConstantPlanner, ReactivePlanner

if TYPE_CHECKING:
    from cdf_mj.planners.baselines import CVConfig, CVPlanner, IMMConfig, IMMPlanner

__all__ = ["PLANNERS", "CDFPlanner", "CVConfig", "CVPlanner", "ConstantPlanner", "DecidingPlanner",
           "IMMConfig", "IMMPlanner", "LazyPlanner", "Planner", "PlannerContext", "PlannerInput", "PlannerSpec",
           "ReactivePlanner", "make_planner", "predicted_label", "register"]

_BASELINES = frozenset(("CVConfig", "CVPlanner", "IMMConfig", "IMMPlanner"))


def __getattr__(name: str) -> Any:
    """The baselines' names on first access (PEP 562)."""
    if name in _BASELINES:
        from cdf_mj.planners import baselines

        return getattr(baselines, name)
    raise AttributeError(f"module 'cdf_mj.planners' has no attribute {name!r}")
