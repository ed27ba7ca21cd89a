"""What every ego planner is: :class:`Planner`, what it is told (:class:`PlannerContext`
at reset, :class:`PlannerInput` each tick), the base of deciding planners and their
threshold rule.

A planner decides, at the planner rate (10 Hz), how the ego may accelerate: a yes/no
planner whether it brakes fully (:meth:`Planner.brake`), a graded one the most the ego may
accelerate (:meth:`Planner.command`, [m/s^2]). It is told only what an ego can know: at
:meth:`Planner.reset` a :class:`PlannerContext` (the junction's static
:class:`~cdf_mj.model.layout.Layout` with the cars' dimensions, the planner tick, the ego's
own nominal controller and what it knows of its sensing) and a random stream, and each tick the measured
system pose (:class:`PlannerInput`). It never sees the live simulation nor any field that
describes the other driver (its intent prior, its acceleration, its turn speed, ...):
a predicting planner brings its own model of that driver in its own configuration.
A yes/no planner's brake is the maximum rate (16 ft/s^2 = 4.877 m/s^2); once decided it
is held to the end of the episode, as in the paper, unless the planner ``releases_brake``
(the risk rule of :mod:`cdf_mj.planners.decision`), which returns the ego to its nominal
speed. A graded planner (the layered rule) commands slowing, following and the full brake
itself; a command at or beyond its ``hard_brake`` counts as a brake. ``brake`` or
``command`` is called at every tick, also while the ego brakes, so that a filter keeps
filtering to the end.

Planners are made by name: :mod:`cdf_mj.planners.registry` (``make_planner``,
``register``; re-exported by :mod:`cdf_mj.planners` and :mod:`cdf_mj`). This module
imports no planner and not the registry (the registry imports it).

===============  ===============================================  ==============================
constant         never brakes (the counterfactual run)            :mod:`cdf_mj.planners.simple`
reactive         brakes once the obstacle is inside the ego lane  :mod:`cdf_mj.planners.simple`
cdf              the CDF filter with the layered rule (graded)    :mod:`cdf_mj.planners.cdf`
cdf-option       the CDF filter with the layered rule's option    :mod:`cdf_mj.planners.cdf`
                 anticipation (slows only as the option runs out)
cdf-risk         the CDF filter with version 0.2's risk rule      :mod:`cdf_mj.planners.cdf`
cdf-threshold    the CDF filter, brakes once P(cutoff) >= tau     :mod:`cdf_mj.planners.cdf`
                 (the paper's rule)
cv               constant-velocity conflict prediction            :mod:`cdf_mj.planners.cv`
cv-risk          constant velocity with the risk rule             :mod:`cdf_mj.planners.cv`
cv-layered       constant velocity with the layered rule          :mod:`cdf_mj.planners.cv`
caution-waiting  slows at the comfortable brake while the other   :mod:`cdf_mj.planners.caution`
                 car is on the side road (naive caution)
caution-moving   the same, only while the other car moves         :mod:`cdf_mj.planners.caution`
caution-phantom  holds a speed that stops before the conflict     :mod:`cdf_mj.planners.caution`
                 zone while a car could come unseen (phantom)
imm              intent-only IMM conflict prediction              :mod:`cdf_mj.planners.imm`
imm-risk         intent-only IMM with the risk rule               :mod:`cdf_mj.planners.imm`
imm-layered      intent-only IMM with the layered rule            :mod:`cdf_mj.planners.imm`
===============  ===============================================  ==============================
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeVar

import numpy as np

from cdf_mj.config import MAX_SPEED, MAX_TOLD_LATENCY, MAX_TOLD_STD, ScenarioConfig
from cdf_mj.model.layout import Layout

if TYPE_CHECKING:  # annotations only: registering a planner imports no compiled kernel
    from cdf_mj.model.conflict import Futures

__all__ = ["HARD_BRAKE_SHARE", "INTERVENTION_SHARE", "DecidingPlanner", "DecisionRule", "Planner", "PlannerContext",
           "PlannerInput", "Predictor", "ThresholdRule", "as_config", "hard_brake_of", "intervenes",
           "intervention_tolerance_of", "predicted_label"]

@dataclass(frozen=True)
class PlannerContext:
    """What the ego knows when an episode starts, and all a planner is told at reset.

    Never a field of the other driver: a planner that predicts it brings its own model.
    Built from a world's configuration by :meth:`of`, or by hand (the monitor, a user's
    simulation). ValueError naming the field for a tick outside (0, 1] s, a speed outside
    (0, :data:`~cdf_mj.config.MAX_SPEED`] m/s or a gain that is not > 0.
    """

    layout: Layout  # the junction's map (routes, lanes, buildings) and both cars' dimensions
    dt: float  # [s] the planner tick: command() is called every dt of simulated time
    nominal_speed: float  # [m/s] the speed the ego's own controller holds when not braking
    speed_gain: float = 1.0  # [1/s] that controller's proportional speed hold
    # What the ego knows of its own hardware (0: nothing known; a rule then keeps only its
    # own margins): the latency [s] of its measurement of the other car plus that of its
    # brake, and the std of its measured pose of the other car [x m, y m, theta rad, v m/s].
    latency: float = 0.0
    measurement_std: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    # Whether its sensor sees the other car only in its own line of sight (from the ego's eye,
    # CarGeometry.eye, past the layout's buildings), so that a tick without a measurement may
    # mean a car out of sight (ScenarioConfig.sensing.occluded; docs/OCCLUSION.md). False: the
    # paper's full observation, where a missing measurement is a dropout.
    occluded: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.layout, Layout):
            raise TypeError(f"PlannerContext.layout must be a Layout, got {type(self.layout).__name__}")
        if not isinstance(self.occluded, bool):
            raise ValueError(f"PlannerContext.occluded={self.occluded!r} must be true or false")
        std = self.measurement_std
        if not (isinstance(std, tuple) and len(std) == 4 and all(
                not isinstance(v, bool) and isinstance(v, (int, float, np.floating)) and 0 <= v <= MAX_TOLD_STD
                for v in std)):
            raise ValueError(f"PlannerContext.measurement_std={std!r} is out of range: must be 4 stds in "
                             f"[0, {MAX_TOLD_STD:g}] [m, m, rad, m/s]")
        for name, low, high, unit in (("dt", 0, 1.0, "s"), ("nominal_speed", 0, MAX_SPEED, "m/s"),
                                      ("speed_gain", 0, 1000.0, "1/s"), ("latency", None, MAX_TOLD_LATENCY, "s")):
            v = getattr(self, name)
            ok = not isinstance(v, bool) and isinstance(v, (int, float, np.floating)) and v <= high and (
                v > low if low is not None else v >= 0)
            if not ok:
                span = f"(0, {high:g}]" if low is not None else f"[0, {high:g}]"
                raise ValueError(f"PlannerContext.{name}={v!r} is out of range: must be in {span} [{unit}]")

    @classmethod
    def of(cls, layout: Layout, config: ScenarioConfig) -> PlannerContext:
        """The ego's knowledge in a world of ``config``: its tick, its own nominal controller
        (speed and gain), whether its sensor is occluded (``sensing.occluded``: an ego knows
        that its sensors need a line of sight) and, where ``config.sensing.told``, its
        sensing's latency and noise and its brake's latency; nothing of the obstacle driver is read."""
        sensing, dt = config.sensing, config.timing.dt
        context = cls(layout=layout, dt=dt, nominal_speed=config.ego.speed, speed_gain=config.ego.speed_gain,
                      occluded=sensing.occluded)
        if not sensing.told:
            return context
        return dataclasses.replace(context, latency=(sensing.latency + sensing.brake_latency) * dt,
                                   measurement_std=(sensing.pos, sensing.pos, sensing.heading, sensing.speed))


@dataclass(frozen=True)
class PlannerInput:
    """What the ego knows at one planner tick."""

    t: float  # [s] episode time
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, theta rad, v m/s]
    obstacle_in_lane: bool  # the obstacle's collision box meets the ego lane's (road.in_lane)


#: Share of the ego car's maximum braking beyond which a graded command counts as a brake
#: where a planner states no threshold of its own (0.6 of 4.877 m/s^2 = 2.9 m/s^2, 0.3 g).
HARD_BRAKE_SHARE = 0.6


def hard_brake_of(car_max_brake: float) -> float:
    """[m/s^2] The deceleration from which a command is a brake, for an ego car braking at
    most ``car_max_brake`` [m/s^2] (:data:`HARD_BRAKE_SHARE` of it)."""
    return HARD_BRAKE_SHARE * car_max_brake


#: The share of the ego car's full brake (``max_brake``) by which a planner's command must be
#: below the ego's own acceleration (its speed hold and car following) for a tick to count
#: as an intervention (docs/DECISION.md, "Every intervention counted").
INTERVENTION_SHARE = 0.1


def intervention_tolerance_of(car_max_brake: float) -> float:
    """[m/s^2] How far below the ego's own acceleration the planner's command must be for a
    tick to be intervening, for an ego car braking at most ``car_max_brake`` [m/s^2]
    (:data:`INTERVENTION_SHARE` of it: 0.4877 m/s^2 for the default car's 4.877 m/s^2)."""
    return INTERVENTION_SHARE * car_max_brake


def intervenes(command: float, own: float, car_max_brake: float) -> bool:
    """Whether a planner's ``command`` [m/s^2] (``-inf``: the full brake), read within the
    car's brake, holds the ego below its ``own`` acceleration [m/s^2] by more than
    :func:`intervention_tolerance_of` the car's ``car_max_brake``: the one rule of the
    episodes (:class:`~cdf_mj.scenario.ego_agent.EgoAgent`) and of the monitor."""
    return max(command, -car_max_brake) < own - intervention_tolerance_of(car_max_brake)


class Planner:
    """Base class. Subclasses set ``name`` and implement :meth:`brake` (a yes/no planner)
    or :meth:`command` (a graded one; then ``graded`` is True and :meth:`brake` reads it).

    The command is the most the ego may accelerate over the next tick [m/s^2]: ``inf``
    leaves the ego's own controller (its speed hold, its car following) alone, a finite
    value caps it (negative: decelerate at least that much), ``-inf`` is the car's full
    brake. The world applies the least of the command and its own controller, within the
    car's limits and the actuator's jerk limit (``ego.jerk_limit``).
    """

    name: str = "base"

    @property
    def graded(self) -> bool:
        """Whether :meth:`command` is the planner's own (graded); else it is :meth:`brake`'s yes/no."""
        return False

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Called at the start of every episode with what the ego knows (the junction's
        static layout, the tick, its own nominal controller) and the episode's planner
        Generator."""

    @property
    def releases_brake(self) -> bool:
        """Whether :meth:`brake` may say no again after a yes (the episode then follows every
        tick's answer); otherwise the episode holds the first yes to the end, as in the paper."""
        return False

    def brake(self, obs: PlannerInput) -> bool:
        """Whether the planner wants to brake now (the first yes is held to the end unless
        ``releases_brake``)."""
        raise NotImplementedError

    def command(self, obs: PlannerInput) -> float:
        """The most the ego may accelerate over this tick [m/s^2] (see the class): for a
        yes/no planner ``-inf`` (the full brake) on :meth:`brake`'s yes, else ``inf``."""
        return -math.inf if self.brake(obs) else math.inf

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

    def reset(self, context: PlannerContext) -> None:
        """Start an episode on ``context.layout`` with the ego's nominal controller of ``context``."""

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

    def reset(self, context: PlannerContext) -> None:
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

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Forget the last episode: no decision, an empty history; the rule reset on ``context``."""
        self.decision_time: float | None = None
        self.brakes: list[list[float | None]] = []  # [start, end] [s] of each brake; end None while braking
        self.braking = False
        # A graded rule's reading of the cut-off: it was slowing the ego (a negative command)
        # on the first tick the obstacle was measured in the ego's lane.
        self.anticipated = False
        self._lane_seen = False
        self.rule.reset(context)
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

    @property
    def graded(self) -> bool:
        """Whether the rule gives a graded command (:class:`~cdf_mj.planners.decision.LayeredRule`)."""
        return bool(getattr(self.rule, "graded", False))

    @property
    def hard_brake(self) -> float | None:
        """[m/s^2] A graded rule's threshold of a brake; None for a yes/no rule."""
        return float(self.rule.hard_brake) if self.graded else None  # type: ignore[attr-defined]

    def brake(self, obs: PlannerInput) -> bool:
        """:meth:`command`, read as yes/no: whether it brakes (hard, for a graded rule)."""
        self.command(obs)
        return self.braking

    def command(self, obs: PlannerInput) -> float:
        """:meth:`observe`, then the rule's command [m/s^2]: a graded rule's own, or the full
        brake (``-inf``) on a yes/no rule's yes (held from the first yes, unless the rule
        releases) and ``inf`` otherwise. ``brakes`` and ``decision_time`` count the hard
        brakes (a graded command at or beyond ``hard_brake``)."""
        self.observe(obs)
        if self.graded:
            accel = float(self.rule.command(self, obs))  # type: ignore[attr-defined]
            wants = accel <= -self.rule.hard_brake  # type: ignore[attr-defined]
        else:
            wants = self.rule.decide(self, obs.poses[0], self.braking)
            if not self.rule.releases:
                wants = wants or self.braking
            accel = -math.inf if wants else math.inf
        for key, value in self.rule.values().items():
            self.history[key].append(round(float(value), 5))
        if obs.obstacle_in_lane and not self._lane_seen:
            self._lane_seen = True
            self.anticipated = self.graded and accel < 0.0
        self._track(obs.t, wants)
        return accel

    def _track(self, t: float, wants: bool) -> None:
        """Keep the decision time and the brakes' starts and ends."""
        if wants and self.decision_time is None:
            self.decision_time = t
        if wants and not self.braking:
            self.brakes.append([t, None])
        elif self.braking and not wants:
            self.brakes[-1][1] = t
        self.braking = bool(wants)

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
        """The prediction (:func:`predicted_label` from the recorded ``p_left``), whether a graded
        rule ``anticipated`` the obstacle's entry into the lane, the decision
        rule, the decision and (last) release times, the brakes and the history."""
        return {"prediction": predicted_label(self.decision_time, self.history.get("p_left", []), self.anticipated),
                "anticipated": self.anticipated,
                "rule": self.rule.name, "decision_time": self.decision_time,
                "release_time": self.release_time, "brakes": self.brakes, "history": self.history}


def predicted_label(decision_time: float | None, p_left: Sequence[float], anticipated: bool = False) -> str:
    """A predicting planner's label for its episode: ``Cutoff`` if it decided to brake (hard),
    or if its graded rule was slowing the ego when the obstacle entered the ego's lane
    (``anticipated``); else ``Yield`` or ``Right`` by its last P(left) (``p_left`` over
    ticks; ``Right`` if empty)."""
    if decision_time is not None or anticipated:
        return "Cutoff"
    return "Yield" if p_left and p_left[-1] >= 0.5 else "Right"


# ----------------------------------------------------------------- registry
_Config = TypeVar("_Config")


def _tuples(value: Any) -> Any:
    """JSON lists back to the tuples the configs hold (nested)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def as_config(value: Any, cls: type[_Config], name: str) -> _Config:
    """``value`` as a ``cls`` (a frozen configuration dataclass): ``value`` itself, ``cls()``
    for None, or ``cls(**value)`` for a mapping (a stored run's arguments, read back from
    JSON: lists become tuples). TypeError naming the argument ``name`` for anything else
    or for unknown keys; the configuration's own ValueError for values out of range."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        try:
            return cls(**{k: _tuples(v) for k, v in value.items()})
        except TypeError as exc:
            raise TypeError(f"{name}: {exc}; the keys are {cls.__name__} fields") from None
    raise TypeError(f"{name} must be a {cls.__name__} (or a mapping of its fields), got {type(value).__name__}")
