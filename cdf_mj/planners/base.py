"""Ego planners: each decides, at the planner rate (10 Hz), whether the ego brakes.

A planner sees what the ego's sensors give: the measured system pose and the scene.
Braking, once decided, is held to the end of the episode at the maximum rate
(16 ft/s^2 = 4.877 m/s^2), as in the paper.

==========  =================================================================
constant    never brakes: the ego holds its speed (the counterfactual run)
reactive    brakes as soon as any part of the obstacle is inside the ego lane
cdf         brakes when the particle filter's P(cutoff) reaches tau
==========  =================================================================

``brake`` is called at every tick, also after the ego has started braking, so that a
filter keeps filtering to the end of the episode.

New planners subclass :class:`Planner` and register with :func:`register`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from collections.abc import Callable, Sequence

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig

__all__ = ["Planner", "PlannerInput", "ConstantPlanner", "ReactivePlanner", "CDFPlanner",
           "make_planner", "register", "predicted_label", "PLANNERS"]


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
        """Whether the planner wants to brake now (the episode latches the first yes)."""
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


class CDFPlanner(Planner):
    """The Cognitive Driving Framework: brake when P(cutoff) >= tau.

    Its prediction for the episode (README, "Planners"): ``Cutoff`` if it braked, else its most
    probable intent at the end (left -> ``Yield``, right -> ``Right``). ``summary()``
    holds the prediction, the decision time and the posterior history.
    """

    name = "cdf"

    def __init__(self, cdf: CDFConfig | None = None) -> None:
        self.cdf = cdf or CDFConfig()

    def reset(self, scene, config: ScenarioConfig, rng: np.random.Generator) -> None:
        from cdf_mj.inference.particle_filter import ParticleFilter  # the filter's import cost only when used

        self.filter = ParticleFilter.from_scene(scene, config, self.cdf, rng)
        self.decision_time: float | None = None
        self.history: dict[str, list] = {k: [] for k in ("t", "p_left", "p_seen", "p_cutoff", "ess")}
        self._started = False

    def brake(self, obs: PlannerInput) -> bool:
        pf = self.filter
        if not self._started:
            post = pf.reset(obs.poses)
            self._started = True
        else:
            post = pf.update(obs.poses)
        pf.predict(obs.poses)
        h = self.history
        h["t"].append(obs.t)
        for key in ("p_left", "p_seen", "p_cutoff", "ess"):
            h[key].append(round(getattr(post, key), 5))
        if post.p_cutoff >= self.cdf.tau and self.decision_time is None:
            self.decision_time = obs.t
        return self.decision_time is not None

    def summary(self) -> dict:
        return {"prediction": predicted_label(self.decision_time, self.history["p_left"]),
                "decision_time": self.decision_time,
                "skipped_updates": self.filter.skipped_updates, "reinits": self.filter.reinits,
                "history": self.history}


def predicted_label(decision_time: float | None, p_left: Sequence[float]) -> str:
    """A predicting planner's label for its episode: ``Cutoff`` if it decided to brake,
    else ``Yield`` or ``Right`` by its last P(left) (``p_left`` over ticks; ``Right`` if empty)."""
    if decision_time is not None:
        return "Cutoff"
    return "Yield" if p_left and p_left[-1] >= 0.5 else "Right"


PLANNERS: dict[str, Callable[[], Planner]] = {}


def register(name: str, factory: Callable[[], Planner]) -> None:
    """Make a planner available by name (to ``run_episode`` and the CLI)."""
    PLANNERS[name] = factory


register("constant", ConstantPlanner)
register("reactive", ReactivePlanner)
register("cdf", CDFPlanner)


def make_planner(name: str | Planner) -> Planner:
    """A fresh planner from its name; planner objects pass through."""
    if isinstance(name, Planner):
        return name
    try:
        return PLANNERS[name]()
    except KeyError:
        raise ValueError(f"unknown planner {name!r}: choose one of {', '.join(sorted(PLANNERS))}") from None


# Baselines (cdf_mj/baselines.py): registered here so that every process that imports the
# registry knows them; the module (and filterpy, ~1 s to import) loads on first use. The
# factories are partials of a module-level function, so worker processes can unpickle them.
def _make_baseline(class_name: str) -> Planner:
    """A fresh baseline planner (``CVPlanner``, ``IMMPlanner``) with its default parameters."""
    from cdf_mj.planners import baselines

    return getattr(baselines, class_name)()


register("cv", functools.partial(_make_baseline, "CVPlanner"))
register("imm", functools.partial(_make_baseline, "IMMPlanner"))
