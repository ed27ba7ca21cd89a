"""The scenario world: both cars ticked at ``config.timing.dt``, the obstacle's side of the
scenario in one place (:class:`World`), used by :func:`cdf_mj.scenario.episode.run_episode`
and by the Gymnasium environment (:mod:`cdf_mj.envs.t_intersection`). ::

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
from dataclasses import dataclass

import numpy as np

from cdf_mj.config import ScenarioConfig, check_seed
from cdf_mj.model.conflict import right_turn_overlap
from cdf_mj.model.driver import DriverModel, Intent, Mode, obstacle_control_one, road_clear, update_belief_one
from cdf_mj.model.following import FOLLOW_HEADING, follow_accel, in_lane_ahead
from cdf_mj.model.geometry import box_gap
from cdf_mj.scenario.after_merge import AfterMergeOverride
from cdf_mj.scenario.drivers import WorldDriver, make_driver
from cdf_mj.sim.checks import SceneWarning
from cdf_mj.sim.scene import Scene, SimulationDivergedError
from cdf_mj.sim.visibility import ego_visible

__all__ = ["Measurement", "NonFiniteStateError", "Tick", "World"]


_HELD_BACK = frozenset((int(Mode.YIELDING), int(Mode.WAITING)))  # plain ints: a cheap test per tick
_MOVING = frozenset((int(Mode.GOING), int(Mode.COMMITTED)))
_GOING, _WAITING, _YIELDING = int(Mode.GOING), int(Mode.WAITING), int(Mode.YIELDING)
#: Below this cosine of the two cars' heading difference the obstacle follows no ego
#: (:func:`cdf_mj.model.following.ahead_in_lane`'s first test, the same expression).
_FOLLOW_COS = math.cos(FOLLOW_HEADING) - 1e-12


class NonFiniteStateError(FloatingPointError):
    """The simulation produced a NaN or infinite pose, or MuJoCo found its state unstable."""


@dataclass(slots=True)
class Measurement:
    """What the ego measures at the start of a tick, before it chooses its controls
    (read-only by convention; not frozen, which would cost microseconds every tick)."""

    t: float  # [s] episode time
    poses: np.ndarray  # (2, 4) system pose S_t: ego, obstacle [x m, y m, theta rad, v m/s], world frame
    obstacle_in_lane: bool  # any corner of the obstacle's collision box inside the ego lane


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
    """The scenario world, ticked at ``config.timing.dt``: the obstacle looks, believes and drives;
    the ego takes the controls it is given (see the module docstring for an example).

    One tick, in order: the obstacle looks (MuJoCo rays; with probability ``beta`` it
    observes the ego's pose with Gaussian noise) and updates its belief; its driver state
    machine gives its controls; both cars' controls get the scenario's process noise;
    MuJoCo steps ``dt / timestep`` physics steps, stopping at the ego's first contact.

    Stop line: the obstacle starts at rest at its stop line and waits ``dwell`` [s]
    (drawn per episode from ``config.obstacle.stop_dwell``) before it may go; on the tick it
    would leave, it looks once more with probability ``config.obstacle.departure_look`` (and
    sees the ego if it is in its line of sight), on top of the beta draw. A hesitating driver
    (probability ``config.obstacle.hesitation``) stops again once it has moved
    ``hesitation_creep`` [m] from the line, stands ``hesitation_pause`` [s], and goes on
    as its belief says (with another departure look).

    Randomness: ``reset(seed)`` splits the seed into independent streams (``rng``:
    ``scenario``, ``obstacle``, ``ego``, ``planner``, ``departure``), each drawn the same
    way whatever the ego does (common random numbers). The ``planner`` stream is not used
    here; it is for the ego's decision maker. The dwell is drawn from ``scenario`` after
    the intent and the ego's start, so these stay the same per seed whatever the dwell.

    Args:
        scene: the loaded scene (its model is not changed; its data is).
        config: scenario parameters; ``config.timing.dt`` must be a whole multiple of the
            scene's timestep.

    Attributes: ``scene``, ``config``, ``layout`` (``scene.layout()``), ``driver`` (the
    obstacle's :class:`~cdf_mj.model.driver.DriverModel`). After :meth:`reset` (updated by
    :meth:`step`): ``seed``, ``intent`` (:class:`cdf_mj.model.driver.Intent`),
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
    until then).

    World options (off by default): ``config.obstacle.family`` drives the obstacle with a
    driver of :mod:`cdf_mj.scenario.drivers` (placed at its own start) instead of the
    traits' state machine; ``config.after_merge`` overrides its acceleration once it is in
    the ego's lane (:mod:`cdf_mj.scenario.after_merge`).
    """

    def __init__(self, scene: Scene, config: ScenarioConfig | None = None) -> None:
        self.scene = scene
        self.config = config = config or ScenarioConfig()
        self.layout = layout = scene.layout()
        self.driver = DriverModel.of_world(layout, config)
        self.n_sub = scene.substeps(config.timing.dt)  # SceneError (a ValueError) unless whole, <= 1000
        seen = config.observation
        self._obs_std = np.array([seen.pos, seen.pos, seen.heading, seen.speed])
        self._nu_std = np.array([config.noise.accel, config.noise.steer])
        # The same as Python floats (the per-tick products on floats: the same values).
        self._obs_std_py: list[float] = self._obs_std.tolist()
        self._nu_std_py: list[float] = self._nu_std.tolist()
        self._dt = config.timing.dt
        self._s0 = layout.route_ego.project(layout.ego_start[:2])[0]
        self._s_conflict = layout.route_ego.project(layout.conflict)[0]
        lo, hi = config.ego.start_spread
        # A start before the route's first waypoint starts at it (heading along the route);
        # past its end there is no heading to take.
        if self._s0 + hi + 1.0 > layout.route_ego.length:
            raise ValueError(f"ego.start_spread=({lo:g}, {hi:g}) m puts the ego's start off its route in "
                             f"{scene.source}: its start site is {self._s0:.1f} m along a route of "
                             f"{layout.route_ego.length:.1f} m (and the start needs 1 m of route ahead)")
        s_right = right_turn_overlap(layout)
        if s_right is not None:
            warnings.warn(f"in {scene.source}, the obstacle's collision box meets the ego's on the obstacle's "
                          f"right route ({s_right:.1f} m along it): a right-turner can hit the ego, which the "
                          "drivers' model and every planner built on it take for impossible; give the right "
                          "route a wider turn or the obstacle a smaller box", SceneWarning, stacklevel=2)
        behaviour = config.obstacle
        # The obstacle's driver: the traits' state machine, or a family written apart from it.
        self.family: WorldDriver | None = None if behaviour.family == "model" else make_driver(behaviour.family)
        self.after_merge = AfterMergeOverride(config.after_merge)
        room = layout.route_left.length - float(layout.route_left.project(layout.conflict)[0])
        if config.after_merge.behaviour in ("slow", "brake") and config.after_merge.at[1] >= room:
            raise ValueError(f"after_merge.at={config.after_merge.at} m: the obstacle's left route goes on for "
                             f"{room:.1f} m past the conflict point in {scene.source}; give distances below it")
        if behaviour.hesitation > 0.0:  # a stop past the commit point would never happen
            start = layout.obstacle_start[:2]
            room = min(float(s - r.project(start)[0]) for r, s in zip(layout.obstacle_routes,
                                                                        self.driver.s_commit, strict=True))
            if behaviour.hesitation_creep >= room:
                raise ValueError(f"obstacle.hesitation_creep={behaviour.hesitation_creep} m reaches the commit point, "
                                 f"{room + 1e-9:.2f} m from the obstacle's start in {scene.source}: a driver "
                                 "past it never stops again; give a shorter creep")
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
        self.hesitated: float | None = None
        self._go_after = self.dwell  # [s] a WAITING driver may leave from then on
        self._line = layout.obstacle_start[:2].copy()  # where it stood
        ahead = route.point_at(self._s0 + offset + 1.0)
        heading0 = math.atan2(ahead[1] - xy0[1], ahead[0] - xy0[0])
        # The world options draw from streams of their own (the same per seed whatever they are).
        self.after_merge.reset(rng["after_merge"])
        obstacle_start = layout.obstacle_start
        if self.family is not None:
            self.family.reset(layout, int(self.intent), rng["driver"])
            obstacle_start = self.family.start
        scene.reset(ego=np.array([xy0[0], xy0[1], heading0, config.ego.speed]), obstacle=obstacle_start)
        self._mode = np.array([Mode.WAITING])
        self._belief = np.zeros((1, 4))
        self._has_belief = np.zeros(1, dtype=bool)
        self._intents = np.array([int(self.intent)])
        # The per-tick draws' streams, looked up once (the same Generators as in rng).
        self._draws = (rng["obstacle"], rng["ego"], rng["departure"])
        self.first_seen: float | None = None
        self.departed: float | None = None
        self.yielded = False
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
        self._k = 0
        self._measured: Measurement | None = None
        self._ego_arc: float | None = None  # [m] kept by step()
        return self.measure()

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
        and whether the obstacle is in the ego lane. NonFiniteStateError on a NaN pose."""
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
        in_lane = self.layout.ego_lane.contains_any(self._hull)
        self._measured = Measurement(t=self.t, poses=np.array(values), obstacle_in_lane=in_lane)
        return self._measured

    def step(self, ego_controls: np.ndarray) -> Tick:
        """One tick of ``config.timing.dt`` with the ego's controls ``[accel m/s^2, steer rad]``
        (process noise is added; MuJoCo clips them to the actuator ranges).

        RuntimeError after the episode is over (call :meth:`reset`); ValueError for controls
        that are not two numbers (nothing of the tick happens then).
        """
        if self.done:
            raise RuntimeError("the episode is over: call reset(seed) before step()")
        scene, layout = self.scene, self.layout
        config = self.config
        behaviour = config.obstacle
        m = self.measure()
        t, poses = m.t, m.poses
        ego, obs = poses[0], poses[1]
        ego_v, obs_v = self._values  # the same poses as Python floats
        dt = self._dt
        # The ego's controls as two floats, checked before anything of the tick is drawn or moved.
        u = np.asarray(ego_controls, dtype=float)
        if u.shape != (2,):
            raise ValueError(f"World.step: ego_controls must be [acceleration m/s^2, steering rad], got shape "
                             f"{u.shape}")
        ego_a, ego_steer = u.tolist()

        # The obstacle looks (draws are made every tick, whatever is visible: CRN). Drawn as
        # before: uniform, 4 observation normals, 2 control normals from "obstacle" (one call
        # of 6 normals gives the same numbers as calls of 4 and 2), 2 from "ego", a uniform
        # from "departure".
        g_obstacle, g_ego, g_departure = self._draws
        u_look = g_obstacle.random()
        z = g_obstacle.standard_normal(6).tolist()
        z_ego = g_ego.standard_normal(2).tolist()
        u_depart = g_departure.random()
        sa, ss = self._nu_std_py
        nu1 = (z[4] * sa, z[5] * ss)
        nu2 = (z_ego[0] * sa, z_ego[1] * ss)
        visible: bool | None = None  # the line of sight, cast at most once a tick

        def sees_ego() -> bool:
            nonlocal visible
            if visible is None:
                scene.sync()  # geoms where qpos puts them, for the rays
                visible = ego_visible(scene, obs, ego)
            return visible

        std = self._obs_std_py
        seen_as = [ego_v[i] + z[i] * std[i] for i in range(4)]  # the ego's pose with the observation noise

        if self.family is None:  # the traits' state machine, the filter's own model
            observed = bool(u_look < behaviour.beta) and sees_ego()
            # The belief update g(B, O), in place: self._belief is this world's own.
            update_belief_one(self._belief, self._has_belief, seen_as if observed else None, dt)
            mode = int(self._mode[0])
            if (self.hesitates and self.hesitated is None and mode == _GOING
                    and math.dist(obs_v[:2], self._line.tolist()) >= behaviour.hesitation_creep):
                # It has nosed out and stops again: it stands its pause, then may go on.
                self.hesitated = t
                self._mode[0] = mode = _WAITING
                self._go_after = t + self.hesitation_pause
            may_go = t >= self._go_after - 1e-9
            if (not observed and may_go and u_depart < behaviour.departure_look
                    and mode == _WAITING
                    and road_clear(self.driver, self._belief, self._has_belief, self._intents)[0]
                    and sees_ego()):
                # It would leave now: it looks once more, and sees the ego.
                observed = True
                update_belief_one(self._belief, self._has_belief, seen_as, dt)
            if observed and self.first_seen is None:
                self.first_seen = t

            # The obstacle decides (obstacle_control of one car: its kernel, from the full
            # route search, with this tick's pose, mode and belief).
            a1, steer1, mode, _ = obstacle_control_one(self.driver, obs_v, mode, self._belief[0].tolist(),
                                                       bool(self._has_belief[0]), int(self._intents[0]), may_go)
            self._mode[0] = mode  # this world's own array (obstacle_control returned a new one)
        else:  # a driver written apart from it: it looks whenever it looks, and acts on what it sees
            observed = self.family.looking and sees_ego()
            if observed and self.first_seen is None:
                self.first_seen = t
            a1, steer1 = self.family.control(t, obs, ego if observed else None, dt)
            a1 = float(np.float64(a1))  # what it was as an entry of the (1, 2) controls array
            steer1 = float(np.float64(steer1))
            mode, may_go = int(self.family.mode), True
        # Once in the ego's lane, what it does next is the world's option (keep by default),
        # and behind the ego it keeps its distance (after_merge.follows).
        a1 = float(self.after_merge.accel(t, obs, m.obstacle_in_lane, a1))
        # follow_accel is None unless the ego is ahead in the lane heading the obstacle's way
        # (ahead_in_lane): its first test here, on the floats, spares the call on most ticks.
        if config.after_merge.follows and math.cos(ego_v[2] - obs_v[2]) >= _FOLLOW_COS:
            behind = follow_accel(layout, layout.obstacle, obs, layout.ego, ego, config.ego)
            if behind is not None:
                a1 = float(min(a1, behind))
        if mode in _MOVING and self.departed is None:
            self.departed = t
        # Held back by what it believes: braking to yield, or still waiting once its dwell
        # is over (waiting out the dwell itself is not yielding).
        self.yielded |= mode in _HELD_BACK and (may_go or mode != _WAITING) if self.family is None \
            else mode == _YIELDING
        if m.obstacle_in_lane and self.entered_lane is None:
            self.entered_lane = t
        gap = box_gap(self._ego_hull, self._hull)
        self.min_gap = min(self.min_gap, gap)

        scene.drive(ego_a + nu2[0], ego_steer + nu2[1], a1 + nu1[0], steer1 + nu1[1])
        self._measured = None
        try:
            hit = scene.step(self.n_sub)
        except SimulationDivergedError as exc:
            self.done = True
            raise NonFiniteStateError(f"non-finite system pose between t={t:.1f} s and "
                                      f"t={t + dt:.1f} s (seed {self.seed}): {exc}") from None
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
        self.done = self.end_reason is not None
        seen = bool(self._has_belief[0]) if self.family is None else self.first_seen is not None
        return Tick(t=t, poses=poses, obstacle_in_lane=m.obstacle_in_lane, observed=observed,
                    mode=mode, seen=seen, belief=self._belief[0].copy(), gap=gap, collision=hit, done=self.done)

    def car_ahead(self) -> bool:
        """Whether the obstacle is ahead of the ego in the ego's lane now (any corner of its
        collision box in the lane, its rear axle further along the ego's route)."""
        ego, obstacle = self.scene.poses()
        return in_lane_ahead(self.layout, obstacle, self.layout.obstacle, ego)
