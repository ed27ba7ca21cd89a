"""The two planners without a model of the obstacle: ``constant`` and ``reactive``."""

from __future__ import annotations

from cdf_mj.planners.base import Planner, PlannerInput

__all__ = ["ConstantPlanner", "ReactivePlanner"]


class ConstantPlanner(Planner):
    """Never brakes: the ego holds its speed (the counterfactual run that labels a seed)."""

    name = "constant"

    def brake(self, obs: PlannerInput) -> bool:
        """Never."""
        return False


class ReactivePlanner(Planner):
    """Brakes once any part of the obstacle's collision box is inside the ego lane
    (checked at the planner rate, 10 Hz)."""

    name = "reactive"

    def brake(self, obs: PlannerInput) -> bool:
        """Whether the obstacle is in the ego lane now."""
        return obs.obstacle_in_lane
