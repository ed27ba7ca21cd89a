"""The scenario world: both cars ticked at ``config.timing.dt`` (:class:`World`), used by
:func:`cdf_mj.scenario.episode.run_episode` and by the Gymnasium environment
(:mod:`cdf_mj.envs.t_intersection`). The world keeps the scene, the random streams, the
physics, the bookkeeping and the episode's end; the obstacle driver is its
:class:`~cdf_mj.scenario.obstacle_agent.ObstacleAgent`, and the ego takes the controls it
is given (the episode's come from an :class:`~cdf_mj.scenario.ego_agent.EgoAgent`). ::

    world = World(scene, config)
    m = world.reset(seed=7)                    # draws intent and ego start; places cars
    while not world.done:
        m = world.measure()                    # S_t and whether the obstacle is in the lane
        tick = world.step(np.array([0.0, 0.0]))    # ego [accel m/s^2, steer rad]

Frames and units: world frame (x east, y north), metres, seconds, radians; poses are
rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cdf_mj.config import ScenarioConfig, check_seed
from cdf_mj.model.conflict import right_turn_overlap
from cdf_mj.model.driver import DriverModel, Intent
from cdf_mj.model.geometry import box_gap
from cdf_mj.model.road import in_lane, in_lane_ahead
from cdf_mj.scenario.after_merge import AfterMergeOverride
from cdf_mj.scenario.drivers import WorldDriver
from cdf_mj.scenario.obstacle_agent import ObstacleAgent
from cdf_mj.sim.checks import SceneWarning
from cdf_mj.sim.scene import Scene, SimulationDivergedError

__all__ = ["Measurement", "NonFiniteStateError", "Tick", "World"]


class NonFiniteStateError(FloatingPointError):
    """The simulation produced a NaN or infinite pose, or MuJoCo found its state unstable."""


@dataclass(slots=True)
class Measurement:
    """What the ego measures at the start of a tick, before it chooses its controls
    (read-only by convention; not frozen, which would cost microseconds every tick)."""

    t: float  # [s] episode time
    poses: np.ndarray  # (2, 4) system pose S_t: ego, obstacle [x m, y m, theta rad, v m/s], world frame
    obstacle_in_lane: bool  # the obstacle's collision box meets the ego lane's (road.in_lane)
    # The share [0, 1] of the obstacle's sight points (hull corners and centre) that the ego's
    # sensor mount sees past the buildings (cdf_mj.sim.visibility.visible_share, MuJoCo rays):
    # what occluded sensing reads. Computed only with config.sensing.occluded; NaN otherwise.
    visible: float = math.nan


@dataclass(slots=True)
class Tick:
    """What one :meth:`World.step` did (read-only by convention). Times in seconds from the
    start of the episode."""

    t: float  # [s] time at the start of the tick
    poses: np.ndarray  # (2, 4) the system pose S_t the tick started from (world frame)
    obstacle_in_lane: bool  # at the start of the tick
    observed: bool  # the obstacle observed the ego on this tick
    mode: int  # the obstacle driver's Mode after its decision
    seen: bool  # the obstacle has observed the ego at least once
    belief: np.ndarray  # (4,) its believed ego pose [x m, y m, theta rad, v m/s] (zeros if not seen)
    gap: float  # [m] distance between the two cars' collision boxes at the start of the tick
    collision: str | None  # "obstacle" | "building" if the ego touched one during the tick
    done: bool  # the episode is over (contact, the ego past the end, or the duration reached)


def _streams(seed: int) -> dict[str, np.random.Generator]:
    ss = np.random.SeedSequence(seed)
    # Children of a SeedSequence depend on their index only: the streams added later
    # ("departure", then the world options') leave the earlier ones, and so every earlier
    # seed's draws, as they were.
    names = ("scenario", "obstacle", "ego", "planner", "departure", "sensing", "after_merge", "driver")
    return {n: np.random.Generator(np.random.PCG64(s)) for n, s in zip(names, ss.spawn(len(names)), strict=True)}


class World:
    """The scenario world, ticked at ``config.timing.dt``: the obstacle looks, believes and drives
    (:attr:`obstacle_agent`); the ego takes the controls it is given (see the module docstring
    for an example).

    One tick, in order: the world draws the tick's random numbers; the obstacle looks
    (MuJoCo rays; with probability ``beta`` it observes the ego's pose with Gaussian noise),
    updates its belief and its driver state machine gives its controls
    (:meth:`ObstacleAgent.act <cdf_mj.scenario.obstacle_agent.ObstacleAgent.act>`); both
    cars' controls get the scenario's process noise; MuJoCo steps ``dt / timestep`` physics
    steps, stopping at the ego's first contact; the world keeps its books and decides
    whether the episode is over.

    Stop line: the obstacle starts at rest at its stop line and waits ``dwell`` [s]
    (drawn per episode from ``config.obstacle.stop_dwell``) before it may go; on the tick it
    would leave, it looks once more with probability ``config.obstacle.departure_look`` (and
    sees the ego if it is in its line of sight), on top of the beta draw. A hesitating driver
    (probability ``config.obstacle.hesitation``) stops again once it has moved
    ``hesitation_creep`` [m] from the line, stands ``hesitation_pause`` [s], and goes on
    as its belief says (with another departure look).

    Randomness: ``reset(seed)`` splits the seed into independent streams (``rng``:
    ``scenario``, ``obstacle``, ``ego``, ``planner``, ``departure``, ``sensing``,
    ``after_merge``, ``driver``), each drawn the same way whatever the ego does (common
    random numbers). The world draws every tick's numbers itself, in one place of
    :meth:`step`, and hands the obstacle agent those of its look. The ``planner`` and
    ``sensing`` streams are not used here; they are the ego's
    (:meth:`EgoAgent.reset <cdf_mj.scenario.ego_agent.EgoAgent.reset>`). The dwell is drawn
    from ``scenario`` after the intent and the ego's start, so these stay the same per seed
    whatever the dwell.

    Args:
        scene: the loaded scene (its model is not changed; its data is).
        config: scenario parameters; ``config.timing.dt`` must be a whole multiple of the
            scene's timestep.

    Attributes: ``scene``, ``config``, ``layout`` (``scene.layout()``), ``driver`` (the
    obstacle's :class:`~cdf_mj.model.driver.DriverModel`, whose ego controller the ego
    agent uses too), ``obstacle_agent`` (the obstacle's
    :class:`~cdf_mj.scenario.obstacle_agent.ObstacleAgent`: ``hesitated``, ``first_seen``,
    ``departed``, ``yielded``, ``family`` and ``after_merge`` below are read from it, read
    only). After :meth:`reset` (updated by :meth:`step`): ``seed``, ``intent`` (:class:`cdf_mj.model.driver.Intent`),
    ``ego_start_offset`` [m], ``dwell`` [s], ``departed`` [s] (when it left the line,
    else ``None``), ``hesitates``, ``hesitation_pause`` [s], ``hesitated`` [s] (when it
    stopped again, else ``None``), ``first_seen`` [s], ``yielded``, ``entered_lane`` [s],
    ``min_gap`` [m] (between the two cars' collision boxes at the starts of ticks; 0 once they touched),
    ``collision`` (``"obstacle"``/``"building"``/``None``), ``collision_time`` [s], ``done`` and
    ``end_reason`` (``None`` while running, then ``"collision"``, ``"passed"``: the ego's
    rear axle ``timing.end_distance`` past the conflict point, with no car ahead of it in its
    lane where ``timing.until_clear``, or ``"duration"``), ``label_outcome`` and
    ``label_time`` (whether the ego touched the obstacle before it got
    ``timing.label_distance`` past the conflict point, and when that was decided; None
    until then), ``pass_time`` [s] (when its rear axle got
    ``timing.label_distance`` past the conflict point, whatever it touched before,
    interpolated within the tick it crossed: the fixed point at which time lost is
    measured; None until then) and ``pass_remaining``
    [m] (how far its rear axle still is from that point; 0 once it got there).

    World options (off by default): ``config.obstacle.family`` drives the obstacle with a
    driver of :mod:`cdf_mj.scenario.drivers` (placed at its own start) instead of the
    traits' state machine; ``config.after_merge`` overrides its acceleration once it is in
    the ego's lane (:mod:`cdf_mj.scenario.after_merge`); ``config.sensing.occluded`` has
    :meth:`measure` cast the ego's line of sight to the obstacle (``Measurement.visible``,
    five MuJoCo rays a tick, for the ego's sensor).
    """

    def __init__(self, scene: Scene, config: ScenarioConfig | None = None) -> None:
        self.scene = scene
        self.config = config = config or ScenarioConfig()
        self.layout = layout = scene.layout()
        self.driver = DriverModel.of_world(layout, config)
        self.n_sub = scene.substeps(config.timing.dt)  # SceneError (a ValueError) unless whole, <= 1000
        # The process noise's std as Python floats (the per-tick products on floats).
        self._nu_std_py: list[float] = np.array([config.noise.accel, config.noise.steer]).tolist()
        self._dt = config.timing.dt
        self._s0 = layout.route_ego.project(layout.ego_start[:2])[0]
        self._s_conflict = layout.route_ego.project(layout.conflict)[0]
        lo, hi = config.ego.start_spread
        # A start off the route is refused: before its first waypoint the ego would start at
        # that waypoint while the record kept the offset drawn; past its end there is no heading.
        if self._s0 + lo < 0.0 or self._s0 + hi + 1.0 > layout.route_ego.length:
            raise ValueError(f"ego.start_spread=({lo:g}, {hi:g}) m puts the ego's start off its route in "
                             f"{scene.source}: its start site is {self._s0:.1f} m along a route of "
                             f"{layout.route_ego.length:.1f} m (and the start needs 1 m of route ahead)")
        s_right = right_turn_overlap(layout)
        if s_right is not None:
            warnings.warn(f"in {scene.source}, the obstacle's collision box meets the ego's on the obstacle's "
                          f"right route ({s_right:.1f} m along it): a right-turner can hit the ego, which the "
                          "drivers' model and every planner built on it take for impossible; give the right "
                          "route a wider turn or the obstacle a smaller box", SceneWarning, stacklevel=2)
        # The obstacle driver (ValueError for world options its routes cannot take).
        self.obstacle_agent = ObstacleAgent(scene, config, self.driver)
        # The ego's line of sight to the obstacle, cast only where its sensing is occluded.
        self._sight: Callable[[Scene, str, str, np.ndarray, np.ndarray], float] | None = None
        if config.sensing.occluded:
            from cdf_mj.sim.visibility import visible_share  # shapely: imported only when needed

            self._sight = visible_share
        self.done = True  # until reset

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int) -> Measurement:
        """Start the episode of ``seed`` (a non-negative integer): draw the intent and the
        ego's start offset, place both cars (the ego at its nominal speed, the obstacle at
        rest at its start site), and return the first measurement."""
        scene, config, layout = self.scene, self.config, self.layout
        behaviour = config.obstacle
        self.seed = seed = check_seed(seed)
        self.rng = rng = _streams(seed)
        # Scenario draw: intent, then the ego's start along its route.
        self.intent = Intent.LEFT if rng["scenario"].random() < behaviour.p_left else Intent.RIGHT
        self.ego_start_offset = offset = float(rng["scenario"].uniform(*config.ego.start_spread))
        route = layout.route_ego
        xy0 = route.point_at(self._s0 + offset)
        # Drawn after the draws above, so that intent and ego start stay the same per seed.
        self.dwell = float(rng["scenario"].uniform(*behaviour.stop_dwell))
        # Drawn whatever the hesitation is, after the dwell: the same per seed (CRN).
        u_hesitate = rng["scenario"].random()
        pause = float(rng["scenario"].uniform(*behaviour.hesitation_pause))
        self.hesitates = bool(u_hesitate < behaviour.hesitation)
        self.hesitation_pause = pause if self.hesitates else 0.0
        ahead = route.point_at(self._s0 + offset + 1.0)
        heading0 = math.atan2(ahead[1] - xy0[1], ahead[0] - xy0[0])
        # The world options draw from streams of their own (the same per seed whatever they are).
        obstacle_start = self.obstacle_agent.reset(self.intent, self.dwell, self.hesitates,
                                                   self.hesitation_pause, rng)
        scene.reset(ego=np.array([xy0[0], xy0[1], heading0, config.ego.speed]), obstacle=obstacle_start)
        # The per-tick draws' streams, looked up once (the same Generators as in rng).
        self._draws = (rng["obstacle"], rng["ego"], rng["departure"])
        self.entered_lane: float | None = None
        self.min_gap = math.inf
        self.collision: str | None = None
        self.collision_time: float | None = None
        self.done = False
        self.end_reason: str | None = None
        # The label's outcome on this run: True once the ego touched the obstacle before its
        # rear axle was timing.label_distance past the conflict point, False once it got there.
        self.label_outcome: bool | None = None
        self.label_time: float | None = None  # [s] when that outcome was decided
        self.pass_time: float | None = None  # [s] when the rear axle got label_distance past the conflict point
        self._k = 0
        self._measured: Measurement | None = None
        self._ego_arc: float | None = None  # [m] kept by step()
        return self.measure()

    # The obstacle's own record, kept by its agent (read-only here).
    @property
    def hesitated(self) -> float | None:
        """[s] when the obstacle stopped again after creeping out (a hesitating driver), else None."""
        return self.obstacle_agent.hesitated

    @property
    def first_seen(self) -> float | None:
        """[s] when the obstacle first observed the ego, else None."""
        return self.obstacle_agent.first_seen

    @property
    def departed(self) -> float | None:
        """[s] when the obstacle left its line (its mode first going or committed), else None."""
        return self.obstacle_agent.departed

    @property
    def yielded(self) -> bool:
        """Whether the obstacle has been held back by what it believes (braking to yield, or
        waiting once its dwell was over)."""
        return self.obstacle_agent.yielded

    @property
    def family(self) -> WorldDriver | None:
        """The obstacle's driver family (``config.obstacle.family``), None for the traits' state machine."""
        return self.obstacle_agent.family

    @property
    def after_merge(self) -> AfterMergeOverride:
        """The obstacle's override once it is in the ego's lane (``config.after_merge``)."""
        return self.obstacle_agent.after_merge

    @property
    def t(self) -> float:
        """[s] episode time at the start of the current tick."""
        return round(self._k * self.config.timing.dt, 6)

    @property
    def ego_arc(self) -> float:
        """[m] the ego's arc length along its route now (its rear axle projected on it): kept
        by :meth:`step`, which needs it for the episode's end."""
        if self._ego_arc is None:
            x, y = self.scene.pose_values()[0][:2]
            self._ego_arc = self.layout.route_ego.project_point(x, y)[0]
        return self._ego_arc

    @property
    def pass_remaining(self) -> float:
        """[m] how far the ego's rear axle is, along its route, from the fixed point
        ``timing.label_distance`` past the conflict point (0 once it got there: ``pass_time``)."""
        if self.pass_time is not None:
            return 0.0
        return max(0.0, float(self.config.timing.label_distance - (self.ego_arc - self._s_conflict)))

    @property
    def end_time(self) -> float:
        """[s] simulated time so far (the episode's end time once ``done``)."""
        return round(float(self.scene.data.time), 6)

    @property
    def time_lost(self) -> float:
        """[s] the ego's progress deficit along its route over its nominal speed, so far."""
        speed = self.config.ego.speed
        s_end = self.layout.route_ego.project(self.scene.pose(self.scene.ego)[:2])[0]
        s_start = self._s0 + self.ego_start_offset
        return float((s_start + speed * self.end_time - s_end) / speed)

    def measure(self) -> Measurement:
        """The system pose ``S_t`` (2, 4) read from MuJoCo at the start of the current tick,
        whether the obstacle is in the ego lane and, with ``sensing.occluded``, how much of it
        the ego's sensor sees (``Measurement.visible``: rays from the ego's eye). NonFiniteStateError
        on a NaN pose."""
        if self._measured is not None:
            return self._measured
        values = self.scene.pose_values()
        (ex, ey, eth, ev), (ox, oy, oth, ov) = values
        if not all(map(math.isfinite, (ex, ey, eth, ev, ox, oy, oth, ov))):
            raise NonFiniteStateError(f"non-finite system pose at t={self.t:.1f} s "
                                      f"(seed {self.seed}): {values}")
        # Both collision boxes: the obstacle's for the lane test, both for the gap in step().
        self._hull = self.layout.obstacle.footprint_one(ox, oy, oth)
        self._ego_hull = self.layout.ego.footprint_one(ex, ey, eth)
        self._values = values
        poses = np.array(values)
        visible = math.nan if self._sight is None else self._sight(self.scene, "ego", "obstacle", poses[0], poses[1])
        self._measured = Measurement(t=self.t, poses=poses, obstacle_in_lane=in_lane(self.layout, self._hull),
                                     visible=visible)
        return self._measured

    def step(self, ego_controls: np.ndarray) -> Tick:
        """One tick of ``config.timing.dt`` with the ego's controls ``[accel m/s^2, steer rad]``
        (process noise is added; MuJoCo clips them to the actuator ranges).

        RuntimeError after the episode is over (call :meth:`reset`); ValueError for controls
        that are not two numbers (nothing of the tick happens then).
        """
        if self.done:
            raise RuntimeError("the episode is over: call reset(seed) before step()")
        m = self.measure()
        t = m.t
        # The ego's controls as two floats, checked before anything of the tick is drawn or moved.
        u = np.asarray(ego_controls, dtype=float)
        if u.shape != (2,):
            raise ValueError(f"World.step: ego_controls must be [acceleration m/s^2, steering rad], got shape "
                             f"{u.shape}")
        ego_a, ego_steer = u.tolist()
        # The tick's draws, made every tick whatever is visible (CRN): a uniform (the beta
        # look), 4 observation normals and 2 control normals from "obstacle" (one call of 6
        # normals gives the same numbers as calls of 4 and 2), 2 from "ego", a uniform (the
        # departure look) from "departure".
        g_obstacle, g_ego, g_departure = self._draws
        u_look = g_obstacle.random()
        z = g_obstacle.standard_normal(6).tolist()
        z_ego = g_ego.standard_normal(2).tolist()
        u_depart = g_departure.random()
        agent = self.obstacle_agent
        a1, steer1 = agent.act(t, m.poses, self._values, m.obstacle_in_lane, u_look, z, u_depart)
        if m.obstacle_in_lane and self.entered_lane is None:
            self.entered_lane = t
        gap = box_gap(self._ego_hull, self._hull)
        self.min_gap = min(self.min_gap, gap)
        sa, ss = self._nu_std_py  # both cars' controls with the process noise
        self.scene.drive(ego_a + z_ego[0] * sa, ego_steer + z_ego[1] * ss, a1 + z[4] * sa, steer1 + z[5] * ss)
        hit = self._physics(t)
        return Tick(t=t, poses=m.poses, obstacle_in_lane=m.obstacle_in_lane, observed=agent.observed,
                    mode=agent.mode, seen=agent.seen, belief=agent.belief.copy(), gap=gap, collision=hit,
                    done=self.done)

    def _physics(self, t: float) -> str | None:
        """MuJoCo's steps of one tick from ``t`` [s], then the books and the episode's end;
        returns what the ego touched (``"obstacle"``, ``"building"``) or None."""
        scene, layout, config = self.scene, self.layout, self.config
        self._measured = None
        t0, past0 = self.end_time, float(self.ego_arc - self._s_conflict)  # before the tick, for pass_time
        try:
            hit = scene.step(self.n_sub)
        except SimulationDivergedError as exc:
            self.done = True
            raise NonFiniteStateError(f"non-finite system pose between t={t:.1f} s and "
                                      f"t={t + self._dt:.1f} s (seed {self.seed}): {exc}") from None
        self._k += 1
        timing = config.timing
        ex, ey = scene.pose_values()[0][:2]
        self._ego_arc = s_ego = layout.route_ego.project_point(ex, ey)[0]
        past = s_ego - self._s_conflict
        if hit is not None:
            self.collision = hit
            self.collision_time = self.end_time
            if hit == "obstacle":  # the two cars touch; a building contact leaves their distance
                self.min_gap = 0.0
            self.end_reason = "collision"
        # The ego's rear axle is end_distance past the conflict point (and, until_clear, no car
        # is ahead of it in its lane): nothing more can happen to it.
        elif past > timing.end_distance and not (timing.until_clear and self.car_ahead()):
            self.end_reason = "passed"
        elif self._k >= config.n_ticks:
            self.end_reason = "duration"
        if self.label_outcome is None and (hit == "obstacle" or past > timing.label_distance):
            self.label_outcome, self.label_time = hit == "obstacle", self.end_time
        if self.pass_time is None and past > timing.label_distance:  # crossed within this tick: interpolated
            share = (timing.label_distance - past0) / (past - past0) if past > past0 else 1.0
            self.pass_time = round(float(t0 + min(max(share, 0.0), 1.0) * (self.end_time - t0)), 6)
        self.done = self.end_reason is not None
        return hit

    def car_ahead(self) -> bool:
        """Whether the obstacle is ahead of the ego in the ego's lane now (its collision box
        meets the lane, its box centre is further along the ego's route: road.in_lane_ahead)."""
        ego, obstacle = self.scene.poses()
        return in_lane_ahead(self.layout, obstacle, self.layout.obstacle, ego, self.layout.ego)
