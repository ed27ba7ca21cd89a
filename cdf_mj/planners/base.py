"""What every ego planner is: :class:`Planner`, its input, the base of deciding planners,
and the registry of planners by name.

A planner decides, at the planner rate (10 Hz), whether the ego brakes. It sees what the
ego's sensors give (:class:`PlannerInput`: the measured system pose) and, at
:meth:`Planner.reset`, the junction's static :class:`~cdf_mj.model.layout.Layout`; it never
sees the live simulation. Braking is at the maximum rate (16 ft/s^2 = 4.877 m/s^2); once
decided it is held to the end of the episode, as in the paper, unless the planner
``releases_brake`` (the risk rule of :mod:`cdf_mj.planners.decision`), which returns the
ego to its nominal speed. ``brake`` is called at every tick, also while the ego brakes,
so that a filter keeps filtering to the end.

Planners are made by name (:func:`make_planner`); :func:`register` adds one, by a
``"module:Class"`` string (imported on first use) or by any zero-argument callable::

    register("mine", "my_package.planners:MyPlanner")
    planner = make_planner("mine")

=============  ==============================================  ==============================
constant       never brakes (the counterfactual run)           :mod:`cdf_mj.planners.simple`
reactive       brakes once the obstacle is inside the ego lane :mod:`cdf_mj.planners.simple`
cdf            the CDF filter with the risk rule               :mod:`cdf_mj.planners.cdf`
cdf-threshold  the CDF filter, brakes once P(cutoff) >= tau    :mod:`cdf_mj.planners.cdf`
               (the paper's rule)
cv             constant-velocity conflict prediction           :mod:`cdf_mj.planners.baselines`
cv-risk        constant velocity with the risk rule            :mod:`cdf_mj.planners.baselines`
imm            intent-only IMM conflict prediction             :mod:`cdf_mj.planners.baselines`
imm-risk       intent-only IMM with the risk rule              :mod:`cdf_mj.planners.baselines`
=============  ==============================================  ==============================
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.layout import Layout

if TYPE_CHECKING:  # annotations only: registering a planner imports no compiled kernel
    from cdf_mj.model.conflict import Futures

__all__ = ["PLANNERS", "DecidingPlanner", "DecisionRule", "LazyPlanner", "Planner", "PlannerInput",
           "Predictor", "ThresholdRule", "make_planner", "predicted_label", "register"]


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

    @property
    def releases_brake(self) -> bool:
        """Whether :meth:`brake` may say no again after a yes (the episode then follows every
        tick's answer); otherwise the episode holds the first yes to the end, as in the paper."""
        return False

    def brake(self, obs: PlannerInput) -> bool:
        """Whether the planner wants to brake now (the first yes is held to the end unless
        ``releases_brake``)."""
        raise NotImplementedError

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable details for the episode record (posterior history, ...)."""
        return {}


# ----------------------------------------------------------------- predictor x decision rule
class Predictor(Protocol):
    """What a decision rule reads from a predicting planner after its tick."""

    def alarm(self) -> float:
        """The predictor's own probability that the obstacle cuts the ego off (threshold rule)."""

    def futures(self, react_ticks: int) -> Futures | np.ndarray:
        """Its hypotheses for the risk rule: :class:`Futures`, or one predicted obstacle path
        ``(K, 4)`` at ticks ``1..K`` (weight 1)."""


class DecisionRule(Protocol):
    """A rule that decides each tick whether the ego brakes."""

    @property
    def name(self) -> str:
        """The rule's name, kept in the planner's summary."""

    @property
    def releases(self) -> bool:
        """Whether it may release a brake it started (else the brake is held)."""

    @property
    def history_keys(self) -> tuple[str, ...]:
        """The per-tick values it keeps in the planner's history."""

    def reset(self, layout: Layout, config: ScenarioConfig) -> None:
        """Start an episode on ``layout`` with the ego's nominal controller of ``config``."""

    def decide(self, predictor: Predictor, ego_pose: np.ndarray, braking: bool) -> bool:
        """Whether to brake on this tick (``braking``: whether the ego brakes now)."""

    def values(self) -> dict[str, float]:
        """This tick's values of ``history_keys``."""


@dataclass(frozen=True)
class ThresholdRule:
    """The paper's rule: brake once the predictor's alarm probability reaches ``threshold``
    (in (0, 1]), and hold it. ValueError for a threshold outside (0, 1]."""

    threshold: float
    name: ClassVar[str] = "threshold"
    releases: ClassVar[bool] = False
    history_keys: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        t = self.threshold
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or not 0 < t <= 1:
            raise ValueError(f"threshold={t!r} is out of range: must be in (0, 1]")

    def reset(self, layout: Layout, config: ScenarioConfig) -> None:
        """Nothing to prepare."""

    def decide(self, predictor: Predictor, ego_pose: np.ndarray, braking: bool) -> bool:
        """``alarm() >= threshold``."""
        return predictor.alarm() >= self.threshold

    def values(self) -> dict[str, float]:
        """None."""
        return {}


class DecidingPlanner(Planner):
    """A predicting planner built from a predictor and a decision rule (``cdf``, ``cv``, ``imm``).

    Subclasses are the predictor: :meth:`observe` runs one prediction tick on the
    measurement (and may :meth:`record` per-tick values under the names in
    ``history_keys``), :meth:`alarm` gives its own probability of a cut-off (read by the
    paper's :class:`~cdf_mj.planners.decision.ThresholdRule`) and :meth:`futures` its
    hypotheses of the obstacle's motion (read by the
    :class:`~cdf_mj.planners.decision.RiskRule`). ``rule`` decides from them each tick
    (:mod:`cdf_mj.planners.decision`). A rule that releases (``rule.releases``) may end a
    brake it started; otherwise the first brake is held to the end. ``decision_time`` [s]
    is the first tick that braked; ``brakes`` lists each brake as ``[start, end]`` [s]
    (``end`` None while it lasts), ``release_time`` is the last end.
    """

    #: Per-tick values kept in ``history`` besides the time ``t`` (and the rule's own).
    history_keys: ClassVar[tuple[str, ...]] = ()
    #: The decision rule (an instance may set its own): by default brake once ``alarm()``
    #: reaches 1/2, and hold it.
    rule: DecisionRule = ThresholdRule(0.5)

    @property
    def releases_brake(self) -> bool:
        """Whether this planner may release a brake it started (the episode holds it otherwise)."""
        return bool(self.rule.releases)

    def reset(self, layout: Layout, config: ScenarioConfig, rng: np.random.Generator) -> None:
        """Forget the last episode: no decision, an empty history; the rule reset on ``layout``."""
        self.decision_time: float | None = None
        self.brakes: list[list[float | None]] = []  # [start, end] [s] of each brake; end None while braking
        self.braking = False
        self.rule.reset(layout, config)
        self.history: dict[str, list[float]] = {
            key: [] for key in ("t", *self.history_keys, *self.rule.history_keys)}

    def observe(self, obs: PlannerInput) -> None:
        """One prediction tick on this tick's measurement."""
        raise NotImplementedError(f"{type(self).__name__} must implement observe(obs) and alarm() (a "
                                  "DecidingPlanner is a predictor; its rule decides: the decide(obs) hook "
                                  "of version 0.1 became observe(obs) + alarm() >= the rule's threshold)")

    def alarm(self) -> float:
        """The predictor's own probability [0, 1] that the obstacle cuts the ego off, now."""
        raise NotImplementedError

    def futures(self, react_ticks: int) -> Futures | np.ndarray:
        """The obstacle's futures for the risk rule: :class:`~cdf_mj.model.conflict.Futures`
        along its left route, or one predicted path ``(K, 4)`` at ticks ``1..K``;
        ``react_ticks`` ticks pass before a deferred brake could act."""
        raise NotImplementedError(f"planner {self.name!r} gives no futures: it runs with the "
                                  "threshold rule only")

    def brake(self, obs: PlannerInput) -> bool:
        """:meth:`observe`, then the rule's decision (held from the first yes, unless the rule
        releases)."""
        self.observe(obs)
        wants = self.rule.decide(self, obs.poses[0], self.braking)
        for key, value in self.rule.values().items():
            self.history[key].append(round(float(value), 5))
        if not self.rule.releases:
            wants = wants or self.braking
        if wants and self.decision_time is None:
            self.decision_time = obs.t
        if wants and not self.braking:
            self.brakes.append([obs.t, None])
        elif self.braking and not wants:
            self.brakes[-1][1] = obs.t
        self.braking = wants
        return wants

    @property
    def release_time(self) -> float | None:
        """[s] when the last brake was released; None if the ego never braked or brakes now."""
        return self.brakes[-1][1] if self.brakes else None

    def record(self, t: float, **values: float) -> None:
        """Append one tick to ``history``: time ``t`` [s] and each of ``history_keys``,
        rounded to 5 decimals."""
        self.history["t"].append(t)
        for key in self.history_keys:
            self.history[key].append(round(float(values[key]), 5))

    def summary(self) -> dict[str, Any]:
        """The prediction (:func:`predicted_label` from the recorded ``p_left``), the decision
        rule, the decision and (last) release times, the brakes and the history."""
        return {"prediction": predicted_label(self.decision_time, self.history.get("p_left", [])),
                "rule": self.rule.name, "decision_time": self.decision_time,
                "release_time": self.release_time, "brakes": self.brakes, "history": self.history}


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
register("cdf-threshold", "cdf_mj.planners.cdf:ThresholdCDFPlanner")
register("cv", "cdf_mj.planners.baselines:CVPlanner")
register("cv-risk", "cdf_mj.planners.baselines:CVRiskPlanner")
register("imm", "cdf_mj.planners.baselines:IMMPlanner")
register("imm-risk", "cdf_mj.planners.baselines:IMMRiskPlanner")
