"""The Cognitive Driving Framework's planner: brake when the particle filter's P(cutoff)
reaches tau (:class:`CDFPlanner`, registered as ``cdf``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.model.layout import Layout
from cdf_mj.planners.base import DecidingPlanner, PlannerInput

__all__ = ["CDFPlanner"]


class CDFPlanner(DecidingPlanner):
    """The Cognitive Driving Framework: brake when P(cutoff) >= tau.

    Its prediction for the episode (README, "Planners"): ``Cutoff`` if it braked, else its
    most probable intent at the end (left -> ``Yield``, right -> ``Right``). ``summary()``
    holds the prediction, the decision time, the filter's counts of skipped measurements
    and re-initialisations, and the per-tick posterior history.

    Args:
        cdf: filter and threshold parameters (default :class:`CDFConfig`).
    """

    name = "cdf"
    history_keys = ("p_left", "p_seen", "p_cutoff", "ess")

    def __init__(self, cdf: CDFConfig | None = None) -> None:
        self.cdf = cdf or CDFConfig()

    def reset(self, layout: Layout, config: ScenarioConfig, rng: np.random.Generator) -> None:
        """A new filter for this junction, drawing from the episode's planner ``rng``."""
        super().reset(layout, config, rng)
        self.filter = ParticleFilter.from_layout(layout, config, self.cdf, rng)
        self._started = False

    def decide(self, obs: PlannerInput) -> bool:
        """One filter tick on the measured system pose: the posterior now (the prior at the
        first tick), then the particles propagated to the next tick."""
        pf = self.filter
        if not self._started:
            post = pf.reset(obs.poses)
            self._started = True
        else:
            post = pf.update(obs.poses)
        pf.predict(obs.poses)
        self.record(obs.t, p_left=post.p_left, p_seen=post.p_seen, p_cutoff=post.p_cutoff,
                    ess=post.ess)
        return post.p_cutoff >= self.cdf.tau

    def summary(self) -> dict[str, Any]:
        """Prediction, decision time [s], ``skipped_updates``, ``reinits`` and history."""
        info = super().summary()
        history = info.pop("history")
        return {**info, "skipped_updates": self.filter.skipped_updates,
                "reinits": self.filter.reinits, "history": history}
