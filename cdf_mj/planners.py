"""Ego planners: each decides, at the planner rate (10 Hz), whether the ego brakes.

A planner sees what the ego's sensors give: the measured system pose and the scene.
Braking, once decided, is held to the end of the episode at the maximum rate
(16 ft/s^2 = 4.877 m/s^2), as in the paper.

==========  =================================================================
constant    never brakes: the ego holds its speed (the counterfactual run)
reactive    brakes as soon as any part of the obstacle is inside the ego lane
==========  =================================================================

New planners subclass :class:`Planner` and register with :func:`register`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cdf_mj.config import ScenarioConfig

__all__ = ["Planner", "PlannerInput", "ConstantPlanner", "ReactivePlanner", "make_planner",
           "register", "PLANNERS"]


@dataclass(frozen=True)
class PlannerInput:
    """What the ego knows at one planner tick."""

    t: float  # [s] episode time
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, theta rad, v m/s]
    obstacle_in_lane: bool  # any corner of the obstacle's hull inside the ego lane


class Planner:
    """Base class. Subclasses set ``name`` and implement :meth:`brake`."""

    name: str = "base"

    def reset(self, scene, config: ScenarioConfig, rng: np.random.Generator) -> None:
        """Called at the start of every episode with the episode's planner Generator."""

    def brake(self, obs: PlannerInput) -> bool:
        """Whether to start braking now."""
        raise NotImplementedError

    def summary(self) -> dict:
        """JSON-serialisable details for the episode record (posterior history, ...)."""
        return {}


class ConstantPlanner(Planner):
    """Never brakes."""

    name = "constant"

    def brake(self, obs: PlannerInput) -> bool:
        return False


class ReactivePlanner(Planner):
    """Brakes once any part of the obstacle enters the ego lane (checked at 10 Hz)."""

    name = "reactive"

    def brake(self, obs: PlannerInput) -> bool:
        return obs.obstacle_in_lane


PLANNERS: dict[str, Callable[[], Planner]] = {}


def register(name: str, factory: Callable[[], Planner]) -> None:
    """Make a planner available by name (to ``run_episode`` and the CLI)."""
    PLANNERS[name] = factory


register("constant", ConstantPlanner)
register("reactive", ReactivePlanner)


def make_planner(name: str | Planner) -> Planner:
    """A fresh planner from its name; planner objects pass through."""
    if isinstance(name, Planner):
        return name
    try:
        return PLANNERS[name]()
    except KeyError:
        raise ValueError(f"unknown planner {name!r}: choose one of {', '.join(sorted(PLANNERS))}") from None
