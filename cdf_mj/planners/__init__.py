"""Ego planners and their registry: ``make_planner("cdf")``, ``register(name, factory)``.

Planners decide from measurements and the scene's static geometry; they never see the
live simulation.
"""

from cdf_mj.planners.base import (PLANNERS, CDFPlanner, ConstantPlanner, Planner, PlannerInput,
                                  ReactivePlanner, make_planner, predicted_label, register)

__all__ = ["PLANNERS", "CDFPlanner", "ConstantPlanner", "Planner", "PlannerInput", "ReactivePlanner",
           "make_planner", "predicted_label", "register"]
