"""One episode of the T-intersection scenario in MuJoCo: ``run_episode(config, seed)``.

The world itself is :class:`cdf_mj.scenario.world.World` (``reset(seed)``, ``measure()``,
``step(ego_controls)``), shared with the Gymnasium environment; the ego is an
:class:`~cdf_mj.scenario.ego_agent.EgoAgent`, the obstacle the world's
:class:`~cdf_mj.scenario.obstacle_agent.ObstacleAgent`. Each 0.1 s tick
(``config.timing.dt``) of an episode reads: the world measures, the ego acts, the world
steps. In this order:

1. read the system pose ``S_t`` from MuJoCo (error on a non-finite pose);
2. the ego senses it (``config.sensing``), its planner is asked whether to brake (the
   first yes is held to the end, unless the planner ``releases_brake``: then every tick's
   answer counts, and a released ego returns to its nominal speed), the ego's controller
   gives its controls;
3. the obstacle looks: line of sight from its eye to the ego (MuJoCo rays); if visible,
   with probability ``beta`` it observes the ego's pose with Gaussian noise; its belief
   is updated (``g``);
4. the obstacle driver's state machine gives its controls (``h``); both cars' controls
   get process noise;
5. MuJoCo steps ``dt / timestep`` physics steps; the episode ends at the ego's first contact.

Observers (``run_episode(..., observers=[...])``, in the style of filterpy's ``Saver``)
are called after every tick with an :class:`EpisodeTick` (the measurement, the decision,
the world's tick and the planner after its tick): they read what they need (a video's
particles, a trace) and never run the simulation again with choices of their own. The
per-tick trace of a record is one such observer (:class:`TraceRecorder`).

The scenario label of a seed comes from one rule (:func:`seed_label`): a run whose ego
never braked is the constant-speed counterfactual itself; only when every run of the
seed braked is the counterfactual simulated.

Randomness: the seed makes a ``numpy.random.SeedSequence`` that is split into
independent streams for the scenario draw (intent, ego start), the obstacle (observation
draws, observation noise, process noise), the ego (process noise) and the planner. Every
stream is drawn the same way whatever the planner does, so two planners on one seed
see the same obstacle (common random numbers), and the counterfactual run that labels
the episode (the ego holding its speed) is the same world with a different ego.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from cdf_mj.analysis.safety import SafetyRecorder
from cdf_mj.config import ScenarioConfig, check_seed
from cdf_mj.model.driver import Intent
from cdf_mj.planners.base import Planner
from cdf_mj.planners.registry import make_planner
from cdf_mj.records import EpisodeRecord, Label
from cdf_mj.scenario.ego_agent import EgoAgent
from cdf_mj.scenario.world import Measurement, Tick, World
from cdf_mj.sim.scene import Scene

__all__ = ["EpisodeTick", "Observer", "TraceRecorder", "counterfactual", "episode_label", "label_of",
           "run_episode", "seed_label"]


@dataclass(frozen=True)
class EpisodeTick:
    """One tick of an episode as an observer sees it, after the world has stepped."""

    measurement: Measurement  # what the planner was given (time t [s], system pose, lane flag)
    braking: bool  # whether the ego braked hard over this tick (its decision, sensing.brake_latency late)
    tick: Tick  # the world's tick: the poses after it, the obstacle's mode, look and belief
    planner: Planner  # the planner after its tick (a filter's particles of time t, ...)
    world: World  # the world after the tick (read only)
    command: float = math.nan  # [m/s^2] the acceleration the ego's actuator applied over the tick
    own: float = math.nan  # [m/s^2] what the ego's own controller (speed hold, following) would apply
    # [m/s^2] the planner's command as it acts (sensing.brake_latency late), clipped to the
    # car's [-max_brake, max_accel] so that it is finite
    planner_command: float = math.nan
    intervening: bool = False  # that command is below own by more than the tolerance (EgoAgent)


#: Called after every tick of an episode with its :class:`EpisodeTick`.
Observer = Callable[[EpisodeTick], None]


@dataclass
class TraceRecorder:
    """The observer behind a record's ``trace``: per tick the time [s], the system pose,
    the obstacle's mode, whether it saw the ego, its belief, the ego's brake flag, the
    planner's ``command`` as it acts and the ego's ``own`` acceleration [m/s^2]
    (:class:`EpisodeTick`'s ``planner_command`` and ``own``) and whether the tick was
    ``intervening``."""

    trace: dict[str, list[Any]] = field(
        default_factory=lambda: {k: [] for k in ("t", "poses", "mode", "seen", "belief", "brake", "command", "own",
                                                 "intervening")})

    def __call__(self, step: EpisodeTick) -> None:
        tick, tr = step.tick, self.trace
        tr["t"].append(tick.t)
        tr["poses"].append(tick.poses.tolist())
        tr["mode"].append(tick.mode)
        tr["seen"].append(tick.seen)
        tr["belief"].append(tick.belief.tolist())
        tr["brake"].append(step.braking)
        tr["command"].append(step.planner_command)
        tr["own"].append(step.own)
        tr["intervening"].append(step.intervening)


@dataclass
class _Run:
    """The raw outcome of one simulated run."""

    intent: int
    offset: float
    first_seen: float | None = None
    yielded: bool = False
    entered: float | None = None
    collision: str | None = None
    collision_time: float | None = None
    min_gap: float = math.inf
    brake_time: float | None = None
    time_lost: float = 0.0
    end_time: float = 0.0
    label_hit: bool | None = None  # the label's outcome, where this run is the counterfactual up to it
    world: dict[str, Any] = field(default_factory=dict)
    intervention: dict[str, Any] = field(default_factory=dict)  # EpisodeRecord.intervention


def _simulate(scene: Scene, config: ScenarioConfig, seed: int, planner: Planner,
              observers: Sequence[Observer] = (), *, holds_speed: bool = False) -> _Run:
    """One run. ``holds_speed``: the label's counterfactual, whose ego never follows."""
    world = World(scene, config)
    world.reset(seed)
    ego = EgoAgent(world.layout, config, world.driver, planner, follows=config.ego.follow and not holds_speed)
    ego.reset(world.rng)
    car = world.layout.ego
    while not world.done:
        m = world.measure()  # the truth at the start of the tick
        controls = ego.act(m)  # what the ego senses, decides and commands
        tick = world.step(controls)  # the obstacle acts, the physics steps
        if observers:
            step = EpisodeTick(measurement=m, braking=ego.acting, tick=tick, planner=planner, world=world,
                               command=ego.accel, own=ego.own, intervening=ego.intervening,
                               planner_command=min(max(ego.command, -car.max_brake), car.max_accel))
            for observe in observers:
                observe(step)
    # Up to the label's outcome this run was the constant-speed run if its ego held its speed.
    same = world.label_time is not None and (ego.deviated is None or ego.deviated >= world.label_time - 1e-9)
    info: dict[str, Any] = {"family": config.obstacle.family,
                            "after_merge": {**world.after_merge.params, "since": world.after_merge.active_since}}
    if world.family is not None:
        info["driver"] = dict(world.family.params)
    if not config.sensing.perfect:
        assert ego.sensor is not None
        info["dropped"] = ego.sensor.dropped
        if config.sensing.occluded:  # ticks the obstacle was out of the ego's sight (not in earlier records)
            info["occluded"] = ego.sensor.occluded
    return _Run(intent=int(world.intent), offset=world.ego_start_offset,
                first_seen=world.first_seen, yielded=world.yielded, entered=world.entered_lane,
                collision=world.collision, collision_time=world.collision_time,
                min_gap=world.min_gap, brake_time=ego.brake_time, time_lost=world.time_lost,
                end_time=world.end_time, label_hit=world.label_outcome if same else None, world=info,
                intervention=_intervention(world, ego))


def _intervention(world: World, ego: EgoAgent) -> dict[str, Any]:
    """A run's ``EpisodeRecord.intervention``: the ego's interventions and when it passed the
    fixed point ``timing.label_distance`` past the conflict point. Where it never got there
    ``pass_time`` is extrapolated from the end at its nominal speed: end_time + remaining /
    ego.speed, a lower bound of when it would have."""
    pass_time = world.pass_time
    passed = pass_time is not None
    if pass_time is None:
        pass_time = world.end_time + world.pass_remaining / world.config.ego.speed
    return {"tolerance": ego.tolerance, "first": ego.first_intervention, "ticks": ego.intervention_ticks,
            "time": round(ego.intervention_ticks * world.config.timing.dt, 6), "peak_decel": ego.intervention_peak,
            "pass_time": round(float(pass_time), 6), "passed": passed}


def _label(intent: int, counterfactual_collision: bool) -> str:
    if intent == Intent.RIGHT:
        return Label.RIGHT.value
    return (Label.CUTOFF if counterfactual_collision else Label.YIELD).value


def label_of(intent: str, counterfactual_collision: bool) -> str:
    """The scenario label from a record's ``intent`` (``"left"``/``"right"``) and whether
    the constant-speed run of its seed hit the obstacle (see :class:`EpisodeRecord`)."""
    return _label(Intent[intent.upper()], counterfactual_collision)


def counterfactual(config: ScenarioConfig, seed: int, scene: Scene) -> tuple[str, bool]:
    """``(label, counterfactual_collision)`` of a seed, from its run with the ego holding
    its speed up to the label's horizon (``timing.label_distance`` past the conflict point;
    resets ``scene``)."""
    horizon = config.with_values({"timing.end_distance": config.timing.label_distance, "timing.until_clear": False})
    cf = _simulate(scene, horizon, seed, make_planner("constant"), holds_speed=True)
    hit = cf.collision == "obstacle"
    return _label(cf.intent, hit), hit


def episode_label(config: ScenarioConfig, seed: int, scene: Scene) -> str:
    """The scenario label of a seed (``Cutoff``, ``Yield`` or ``Right``), from its
    counterfactual run with the ego holding its speed (resets ``scene``)."""
    return counterfactual(config, seed, scene)[0]


def seed_label(config: ScenarioConfig, seed: int, scene: Scene,
               runs: Iterable[tuple[str, bool | None]] = ()) -> tuple[str, bool]:
    """``(label, counterfactual_collision)`` of a seed: the one labelling rule.

    ``runs`` are the seed's finished runs as ``(intent, label_hit)`` (``"left"``/``"right"``
    and, from an unlabelled record, its ``counterfactual_collision``: whether it touched
    the obstacle before the label's horizon, where its ego held its speed until then, else
    None). A run whose ego held its speed up to the label's outcome *is* the constant-speed
    counterfactual up to there (the same random streams, the same controls: a planner's
    own stream does not touch the world), so it labels the seed; only when no run did (or
    none is given) is the counterfactual simulated, once (it resets ``scene``).
    """
    for intent, hit in runs:
        if hit is not None:
            return label_of(intent, hit), hit
    return counterfactual(config, seed, scene)


def run_episode(config: ScenarioConfig | None = None, seed: int = 0,
                planner: str | Planner = "reactive", scene: Scene | None = None,
                label: bool = True, trace: bool = False,
                observers: Sequence[Observer] = ()) -> EpisodeRecord:
    """Run one episode and return its record.

    Args:
        config: scenario parameters (default :class:`ScenarioConfig`).
        seed: episode seed; the same seed gives the same record.
        planner: planner name (``constant``, ``reactive``, ...; built by
            :func:`~cdf_mj.planners.make_planner` with its registered arguments) or object.
        scene: a loaded scene (reused between episodes for speed); default scene.xml.
        label: also label the episode (:func:`seed_label`).
        trace: include per-tick poses, modes and beliefs in the record.
        observers: called after every tick with an :class:`EpisodeTick`, in order.
    """
    config = config or ScenarioConfig()
    seed = check_seed(seed)  # before any work: a bool, 1.5 or 2^64 is refused, not truncated
    scene = scene or Scene.load(names=config.names)
    plan = make_planner(planner)
    recorder = TraceRecorder() if trace else None
    safety = SafetyRecorder()
    run = _simulate(scene, config, seed, plan, (*observers, safety, *([recorder] if recorder else [])))
    info = plan.summary()
    intent = Intent(run.intent).name.lower()

    # Unlabelled, what this run tells of the label (None: only the counterfactual can tell).
    cf_collision: bool | None = run.label_hit
    lab: str | None = None
    if label:
        lab, cf_collision = seed_label(config, seed, scene, [(intent, run.label_hit)])

    return EpisodeRecord(
        seed=seed, planner=plan.name, intent=intent, label=lab,
        ego_start_offset=run.offset, first_seen_time=run.first_seen, yielded=run.yielded,
        entered_lane_time=run.entered, collision=run.collision is not None,
        collision_with=run.collision, collision_time=run.collision_time,
        min_gap=float(run.min_gap), brake_time=run.brake_time, time_lost=run.time_lost,
        end_time=run.end_time, counterfactual_collision=cf_collision, planner_info=info,
        safety=safety.result().to_dict(), world=run.world, intervention=run.intervention,
        trace=recorder.trace if recorder else None,
    )
