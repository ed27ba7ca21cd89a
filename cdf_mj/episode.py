"""One episode of the T-intersection scenario in MuJoCo: ``run_episode(config, seed)``.

Each 0.1 s tick (``config.dt``), in this order:

1. read the system pose ``S_t`` from MuJoCo (error on a non-finite pose);
2. the obstacle looks: line of sight from its eye to the ego (MuJoCo rays); if visible,
   with probability ``beta`` it observes the ego's pose with Gaussian noise; its belief
   is updated (``g``);
3. the obstacle driver's state machine gives its controls (``h``), plus process noise;
4. the ego's planner is asked whether to brake (the first yes is latched: the ego then
   brakes at the maximum rate to the end), the ego's controller gives its
   controls, plus process noise;
5. MuJoCo steps ``dt / timestep`` physics steps; the episode ends at the ego's first contact.

Randomness: the seed makes a ``numpy.random.SeedSequence`` that is split into
independent streams for the scenario draw (intent, ego start), the obstacle (observation
draws, observation noise, process noise), the ego (process noise) and the planner. Every
stream is drawn the same way whatever the planner does, so two planners on one seed
see the same obstacle (common random numbers), and the counterfactual run that labels
the episode (the ego holding its speed) is the same world with a different ego.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import shapely

from cdf_mj.config import ScenarioConfig
from cdf_mj.driver import DriverModel, Intent, Mode, ego_control, obstacle_control, update_belief
from cdf_mj.planners import Planner, PlannerInput, make_planner
from cdf_mj.scene import Scene, SimulationDivergedError
from cdf_mj.visibility import ego_visible

__all__ = ["run_episode", "EpisodeRecord", "Labels", "NonFiniteStateError"]


class NonFiniteStateError(FloatingPointError):
    """The simulation produced a NaN or infinite pose, or MuJoCo found its state unstable."""


class Labels:
    """Scenario labels (DESIGN.md, Ground truth)."""

    CUTOFF = "Cutoff"
    YIELD = "Yield"
    RIGHT = "Right"


@dataclass
class EpisodeRecord:
    """What happened in one episode. Times are seconds from the start, ``None`` if never.

    ``label`` is the scenario label from the counterfactual run of the same seed with the
    ego holding its speed: ``Right`` (intent right), ``Cutoff`` (intent left and that run
    collides with the obstacle) or ``Yield`` (intent left, no such collision).
    """

    seed: int
    planner: str
    intent: str  # "left" | "right"
    label: str | None  # Cutoff | Yield | Right (None if labelling was not asked for)
    ego_start_offset: float  # [m] along the ego route from site ego_start
    first_seen_time: float | None  # obstacle's first observation of the ego
    yielded: bool  # the obstacle held back for the ego (waited at the stop line or braked)
    entered_lane_time: float | None  # first tick with any part of the obstacle in the ego lane
    collision: bool  # the ego touched the obstacle or a building
    collision_with: str | None  # "obstacle" | "building"
    collision_time: float | None
    min_gap: float  # [m] smallest distance between the two hulls (0 at contact)
    brake_time: float | None  # the planner's decision to brake
    time_lost: float  # [s] the ego's progress deficit at the end, over its nominal speed
    end_time: float  # [s]
    counterfactual_collision: bool | None  # the constant-speed run hit the obstacle
    planner_info: dict = field(default_factory=dict)
    trace: dict | None = None  # per-tick arrays when asked for

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict."""
        return asdict(self)


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
    trace: dict | None = None


def _streams(seed: int) -> dict[str, np.random.Generator]:
    ss = np.random.SeedSequence(seed)
    names = ("scenario", "obstacle", "ego", "planner")
    return {n: np.random.Generator(np.random.PCG64(s)) for n, s in zip(names, ss.spawn(len(names)))}


def _substeps(scene: Scene, config: ScenarioConfig) -> int:
    ratio = config.dt / scene.model.opt.timestep
    n = int(round(ratio))
    if n < 1 or abs(ratio - n) > 1e-6:
        raise ValueError(f"dt={config.dt} s must be a whole multiple of the scene's timestep "
                         f"{scene.model.opt.timestep} s")
    return n


def _simulate(scene: Scene, config: ScenarioConfig, seed: int, planner: Planner,
              record_trace: bool) -> _Run:
    rng = _streams(seed)
    model = DriverModel.from_scene(scene, config)
    n_sub = _substeps(scene, config)
    dt = config.dt

    # Scenario draw: intent, then the ego's start along its route.
    intent = int(Intent.LEFT if rng["scenario"].random() < config.p_left else Intent.RIGHT)
    offset = float(rng["scenario"].uniform(*config.ego_start_spread))
    s0, _ = scene.route_ego.project(scene.ego_start[:2])
    xy0 = scene.route_ego.point_at(s0 + offset)
    ahead = scene.route_ego.point_at(s0 + offset + 1.0)
    heading0 = math.atan2(ahead[1] - xy0[1], ahead[0] - xy0[0])
    scene.reset(ego=np.array([xy0[0], xy0[1], heading0, config.ego_speed]),
                obstacle=scene.obstacle_start)
    planner.reset(scene, config, rng["planner"])

    run = _Run(intent=intent, offset=offset)
    mode = np.array([Mode.WAITING])
    belief = np.zeros((1, 4))
    has_belief = np.zeros(1, dtype=bool)
    intents = np.array([intent])
    obs_std = np.array([config.obs_noise_pos, config.obs_noise_pos, config.obs_noise_heading,
                        config.obs_noise_speed])
    nu_std = np.array([config.noise_accel, config.noise_steer])
    s_conflict, _ = scene.route_ego.project(scene.conflict)
    s_start = s0 + offset
    braking = False
    tr: dict[str, list] = {k: [] for k in ("t", "poses", "mode", "seen", "belief", "brake")}

    t = 0.0
    for k in range(config.n_ticks):
        t = round(k * dt, 6)
        poses = scene.poses()
        if not np.all(np.isfinite(poses)):
            raise NonFiniteStateError(f"non-finite system pose at t={t:.1f} s (seed {seed}): "
                                      f"{poses.tolist()}")
        ego, obs = poses[0], poses[1]

        # The obstacle looks (draws are made every tick, whatever is visible: CRN).
        scene.sync()
        u_look = rng["obstacle"].random()
        noise = rng["obstacle"].standard_normal(4) * obs_std
        nu1 = rng["obstacle"].standard_normal(2) * nu_std
        nu2 = rng["ego"].standard_normal(2) * nu_std
        observed = bool(u_look < config.beta) and ego_visible(scene, obs, ego)
        belief, has_belief = update_belief(belief, has_belief, np.array([observed]),
                                           (ego + noise)[None], dt, scene.obstacle.wheelbase)
        if observed and run.first_seen is None:
            run.first_seen = t

        # The obstacle decides.
        u1, mode = obstacle_control(model, obs[None], mode, belief, has_belief, intents)
        # Held back by what it believes: braking to yield, or still waiting after its first look.
        run.yielded |= bool(mode[0] in (Mode.YIELDING, Mode.WAITING))

        # The ego decides.
        obstacle_hull = scene.obstacle.footprint(obs)
        in_lane = bool(scene.ego_lane.contains(obstacle_hull).any())
        if in_lane and run.entered is None:
            run.entered = t
        wants_brake = planner.brake(PlannerInput(t=t, poses=poses, obstacle_in_lane=in_lane))
        if wants_brake and not braking:
            braking = True
            run.brake_time = t
        u2 = ego_control(model, scene.ego, ego, braking)

        gap = shapely.distance(shapely.Polygon(scene.ego.footprint(ego)), shapely.Polygon(obstacle_hull))
        run.min_gap = min(run.min_gap, float(gap))
        if record_trace:
            for key, val in (("t", t), ("poses", poses.tolist()), ("mode", int(mode[0])),
                             ("seen", bool(has_belief[0])), ("belief", belief[0].tolist()),
                             ("brake", braking)):
                tr[key].append(val)

        scene.set_controls("obstacle", *(u1[0] + nu1))
        scene.set_controls("ego", *(u2 + nu2))
        try:
            hit = scene.step(n_sub)
        except SimulationDivergedError as exc:
            raise NonFiniteStateError(f"non-finite system pose between t={t:.1f} s and "
                                      f"t={t + dt:.1f} s (seed {seed}): {exc}") from None
        if hit is not None:
            run.collision = hit
            run.collision_time = round(float(scene.data.time), 6)
            run.min_gap = 0.0
            break
        # The ego's rear axle is 20 m past the conflict point: nothing more can happen to it.
        if scene.route_ego.project(scene.pose(scene.ego)[:2])[0] > s_conflict + 20.0:
            break

    final = scene.pose(scene.ego)
    run.end_time = round(float(scene.data.time), 6)
    s_end, _ = scene.route_ego.project(final[:2])
    run.time_lost = float((s_start + config.ego_speed * run.end_time - s_end) / config.ego_speed)
    if record_trace:
        run.trace = tr
    return run


def run_episode(config: ScenarioConfig | None = None, seed: int = 0,
                planner: str | Planner = "reactive", scene: Scene | None = None,
                label: bool = True, trace: bool = False) -> EpisodeRecord:
    """Run one episode and return its record.

    Args:
        config: scenario parameters (default :class:`ScenarioConfig`).
        seed: episode seed; the same seed gives the same record.
        planner: planner name (``constant``, ``reactive``, ...) or object.
        scene: a loaded scene (reused between episodes for speed); default scene.xml.
        label: also run the counterfactual (ego holding its speed) to label the episode.
        trace: include per-tick poses, modes and beliefs in the record.
    """
    config = config or ScenarioConfig()
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} is out of range: must be a non-negative integer")
    seed = int(seed)
    scene = scene or Scene.load(names=config.names)
    plan = make_planner(planner)
    run = _simulate(scene, config, seed, plan, trace)
    info = plan.summary()

    cf_collision: bool | None = None
    lab: str | None = None
    if label:
        cf = run if plan.name == "constant" else _simulate(scene, config, seed, make_planner("constant"), False)
        cf_collision = cf.collision == "obstacle"
        if run.intent == Intent.RIGHT:
            lab = Labels.RIGHT
        else:
            lab = Labels.CUTOFF if cf_collision else Labels.YIELD

    return EpisodeRecord(
        seed=seed, planner=plan.name, intent=Intent(run.intent).name.lower(), label=lab,
        ego_start_offset=run.offset, first_seen_time=run.first_seen, yielded=run.yielded,
        entered_lane_time=run.entered, collision=run.collision is not None,
        collision_with=run.collision, collision_time=run.collision_time,
        min_gap=float(run.min_gap), brake_time=run.brake_time, time_lost=run.time_lost,
        end_time=run.end_time, counterfactual_collision=cf_collision, planner_info=info,
        trace=run.trace,
    )
