"""Ego planners and their registry: ``make_planner("cdf", **kwargs)``,
``register(name, target, **defaults)``; a planner is told a :class:`PlannerContext` at
reset (what the ego knows) and a :class:`PlannerInput` each tick.

Planners decide from measurements and the junction's static layout; they never see the
live simulation. The planners with a model of the obstacle are imported on first access,
so that importing this package (or one of its modules, such as the decision rules) loads
neither the particle filter's kernels nor filterpy: ``CDFPlanner`` from
:mod:`cdf_mj.planners.cdf`, ``CVPlanner`` and ``CVConfig`` from :mod:`cdf_mj.planners.cv`,
``IMMPlanner`` and ``IMMConfig`` from :mod:`cdf_mj.planners.imm` (filterpy, about 1 s).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from cdf_mj.planners.base import DecidingPlanner, Planner, PlannerContext, PlannerInput, predicted_label
from cdf_mj.planners.registry import PLANNERS, LazyPlanner, PlannerSpec, make_planner, register
from cdf_mj.planners.simple import ConstantPlanner, ReactivePlanner

if TYPE_CHECKING:
    from cdf_mj.planners.cdf import CDFPlanner
    from cdf_mj.planners.cv import CVConfig, CVPlanner
    from cdf_mj.planners.imm import IMMConfig, IMMPlanner

__all__ = ["PLANNERS", "CDFPlanner", "CVConfig", "CVPlanner", "ConstantPlanner", "DecidingPlanner",
           "IMMConfig", "IMMPlanner", "LazyPlanner", "Planner", "PlannerContext", "PlannerInput", "PlannerSpec",
           "ReactivePlanner", "make_planner", "predicted_label", "register"]

#: The names imported on first access -> the module that defines each.
_LAZY = {"CDFPlanner": "cdf_mj.planners.cdf", "CVConfig": "cdf_mj.planners.cv", "CVPlanner": "cdf_mj.planners.cv",
         "IMMConfig": "cdf_mj.planners.imm", "IMMPlanner": "cdf_mj.planners.imm"}


def __getattr__(name: str) -> Any:
    """The planners with a model of the obstacle, on first access (PEP 562)."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'cdf_mj.planners' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
