"""What every ego planner is: :class:`Planner`, its input, the base of deciding planners,
and the registry of planners by name.

A planner decides, at the planner rate (10 Hz), whether the ego brakes. It sees what the
ego's sensors give (:class:`PlannerInput`: the measured system pose) and, at
:meth:`Planner.reset`, the junction's static :class:`~cdf_mj.model.layout.Layout`; it never
sees the live simulation. Braking, once decided, is held to the end of the episode at the
maximum rate (16 ft/s^2 = 4.877 m/s^2), as in the paper. ``brake`` is called at every
tick, also after the ego has started braking, so that a filter keeps filtering to the end.

Planners are made by name (:func:`make_planner`); :func:`register` adds one, by a
``"module:Class"`` string (imported on first use) or by any zero-argument callable::

    register("mine", "my_package.planners:MyPlanner")
    planner = make_planner("mine")

==========  =================================================  ==============================
constant    never brakes (the counterfactual run)              :mod:`cdf_mj.planners.simple`
reactive    brakes once the obstacle is inside the ego lane    :mod:`cdf_mj.planners.simple`
cdf         brakes when the filter's P(cutoff) reaches tau     :mod:`cdf_mj.planners.cdf`
cv          constant-velocity conflict prediction              :mod:`cdf_mj.planners.baselines`
imm         intent-only IMM conflict prediction                :mod:`cdf_mj.planners.baselines`
==========  =================================================  ==============================
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.layout import Layout

__all__ = ["PLANNERS", "DecidingPlanner", "LazyPlanner", "Planner", "PlannerInput",
           "make_planner", "predicted_label", "register"]


@dataclass(frozen=True)
class PlannerInput:
    """What the ego knows at one planner tick."""

    t: float  # [s] episode time
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, theta rad, v m/s]
    obstacle_in_lane: bool  # any corner of the obstacle's hull inside the ego lane


class Planner:
    """Base class. Subclasses set ``name`` and implement :meth:`brake`."""

    name: str = "base"

    def reset(self, layout: Layout, config: ScenarioConfig, rng: np.random.Generator) -> None:
        """Called at the start of every episode with the junction's static layout, the
        scenario's parameters and the episode's planner Generator."""

    def brake(self, obs: PlannerInput) -> bool:
        """Whether the planner wants to brake now (the episode latches the first yes)."""
        raise NotImplementedError

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable details for the episode record (posterior history, ...)."""
        return {}


class DecidingPlanner(Planner):
    """A planner that decides once to brake and holds that decision (cdf, cv, imm).

    Subclasses implement :meth:`decide`, called at every tick (so a filter keeps running
    after the decision), and may :meth:`record` per-tick values under the names in
    ``history_keys``. The first tick whose :meth:`decide` says yes is ``decision_time``
    [s]; :meth:`brake` is true from then on.
    """

    #: Per-tick values kept in ``history`` besides the time ``t``.
    history_keys: ClassVar[tuple[str, ...]] = ()

    def reset(self, layout: Layout, config: ScenarioConfig, rng: np.random.Generator) -> None:
        """Forget the last episode: no decision, an empty history."""
        self.decision_time: float | None = None
        self.history: dict[str, list[float]] = {key: [] for key in ("t", *self.history_keys)}

    def decide(self, obs: PlannerInput) -> bool:
        """Whether this tick's measurement calls for braking (the planner's own rule)."""
        raise NotImplementedError

    def brake(self, obs: PlannerInput) -> bool:
        """:meth:`decide`, latched: true from the first tick it said yes."""
        if self.decide(obs) and self.decision_time is None:
            self.decision_time = obs.t
        return self.decision_time is not None

    def record(self, t: float, **values: float) -> None:
        """Append one tick to ``history``: time ``t`` [s] and each of ``history_keys``,
        rounded to 5 decimals."""
        self.history["t"].append(t)
        for key in self.history_keys:
            self.history[key].append(round(float(values[key]), 5))

    def summary(self) -> dict[str, Any]:
        """The prediction (:func:`predicted_label` from the recorded ``p_left``), the decision
        time and the history."""
        return {"prediction": predicted_label(self.decision_time, self.history.get("p_left", [])),
                "decision_time": self.decision_time, "history": self.history}


def predicted_label(decision_time: float | None, p_left: Sequence[float]) -> str:
    """A predicting planner's label for its episode: ``Cutoff`` if it decided to brake,
    else ``Yield`` or ``Right`` by its last P(left) (``p_left`` over ticks; ``Right`` if empty)."""
    if decision_time is not None:
        return "Cutoff"
    return "Yield" if p_left and p_left[-1] >= 0.5 else "Right"


# ----------------------------------------------------------------- registry
@dataclass(frozen=True)
class LazyPlanner:
    """A planner class named ``"module:Class"``, imported when a planner is first made.

    Picklable (worker processes get the string) and free of import cycles: registering
    a planner imports nothing. Calling it returns a new planner with default parameters.
    """

    target: str  # "package.module:ClassName"

    def __post_init__(self) -> None:
        module, _, cls = self.target.partition(":")
        if not (module and cls and all(p.isidentifier() for p in (*module.split("."), cls))):
            raise ValueError(f"planner target {self.target!r} must be 'package.module:ClassName'")

    def __call__(self) -> Planner:
        module, _, cls = self.target.partition(":")
        try:
            factory = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as exc:
            raise ImportError(f"planner target {self.target!r} cannot be imported: {exc}") from exc
        planner = factory()
        if not isinstance(planner, Planner):
            raise TypeError(f"planner target {self.target!r} made a {type(planner).__name__}, "
                            "not a cdf_mj.planners.Planner")
        return planner


#: Planner factories by name: zero-argument callables returning a fresh :class:`Planner`
#: (a :class:`LazyPlanner` for those registered by ``"module:Class"``).
PLANNERS: dict[str, Callable[[], Planner]] = {}


def register(name: str, target: str | Callable[[], Planner]) -> None:
    """Make a planner available by ``name`` (to ``run_episode``, experiments and the CLI).

    ``target`` is ``"package.module:ClassName"`` (imported on first use; worker processes
    import it by name, so it works with any start method) or a zero-argument callable
    returning a fresh planner (a class, a ``functools.partial``; it must be picklable to
    run in worker processes). ValueError for an empty name or a malformed target string,
    TypeError for a target that is neither.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"a planner name must be a non-empty string, got {name!r}")
    if isinstance(target, str):
        PLANNERS[name] = LazyPlanner(target)
    elif callable(target):
        PLANNERS[name] = target
    else:
        raise TypeError(f"planner {name!r}: target must be 'module:Class' or a callable, "
                        f"got {type(target).__name__}")


def make_planner(name: str | Planner) -> Planner:
    """A fresh planner from its registered name; planner objects pass through.
    ValueError naming the registered planners for an unknown name."""
    if isinstance(name, Planner):
        return name
    try:
        factory = PLANNERS[name]
    except KeyError:
        raise ValueError(f"unknown planner {name!r}: choose one of {', '.join(sorted(PLANNERS))}") from None
    return factory()


register("constant", "cdf_mj.planners.simple:ConstantPlanner")
register("reactive", "cdf_mj.planners.simple:ReactivePlanner")
register("cdf", "cdf_mj.planners.cdf:CDFPlanner")
register("cv", "cdf_mj.planners.baselines:CVPlanner")
register("imm", "cdf_mj.planners.baselines:IMMPlanner")
