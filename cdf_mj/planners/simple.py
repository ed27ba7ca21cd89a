"""The two planners without a model of the obstacle: ``constant`` and ``reactive``."""

from __future__ import annotations

import numpy as np

from cdf_mj.model.road import ahead
from cdf_mj.planners.base import Planner, PlannerContext, PlannerInput

__all__ = ["ConstantPlanner", "ReactivePlanner"]


class ConstantPlanner(Planner):
    """Never brakes: the ego's nominal controller drives (holding its speed, and following a
    car that has merged ahead of it where ``ego.follow``). The label's counterfactual is
    this planner with the ego holding its speed whatever is ahead."""

    name = "constant"

    def brake(self, obs: PlannerInput) -> bool:
        """Never."""
        return False


class ReactivePlanner(Planner):
    """Brakes once any part of the obstacle's collision box is inside the ego lane and not
    wholly behind the ego (checked at the planner rate, 10 Hz). A car that turns into the
    lane behind an ego that has passed is no reason to brake (episodes that end 20 m past
    the junction never showed one)."""

    name = "reactive"

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Keep the layout: the ego's route and both cars' boxes."""
        self._layout = context.layout

    def brake(self, obs: PlannerInput) -> bool:
        """Whether the obstacle is in the ego lane now, ahead of the ego's tail."""
        if not obs.obstacle_in_lane:
            return False
        layout = self._layout
        ego, obstacle = obs.poses.tolist()
        return ahead(layout, obstacle, layout.obstacle, ego, layout.ego, by="extent")
