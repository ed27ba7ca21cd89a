"""The obstacle's half of a tick: :class:`ObstacleAgent` looks, believes, decides, hesitates,
is overridden once it has merged, and keeps its distance behind the ego.

The world (:class:`cdf_mj.scenario.world.World`) owns the random streams and draws every
tick's numbers in one place; it hands the agent the ones of its look and asks for its
controls once a tick, before the physics::

    agent = ObstacleAgent(scene, config, DriverModel.of_world(layout, config))
    start = agent.reset(Intent.LEFT, dwell=1.5, hesitates=False, hesitation_pause=0.0, rng=streams)
    accel, steer = agent.act(t, poses, values, in_lane, u_look, z, u_depart)
    agent.mode, agent.observed, agent.seen, agent.belief     # what it did and believes

Its driver is the traits' state machine (:mod:`cdf_mj.model.driver`, the filter's own
model) or, with ``config.obstacle.family``, a family of :mod:`cdf_mj.scenario.drivers`
written apart from it, shown the ego as its ``sight`` says (``"line"``: its pose while in the
driver's line of sight; ``"share"``: that and the visible share, set as the driver's
``ego_share``; ``"all"``: its pose every tick, see :class:`~cdf_mj.scenario.drivers.WorldDriver`);
``config.after_merge`` overrides its acceleration once it is in the
ego's lane (:mod:`cdf_mj.scenario.after_merge`). World frame (x east, y north), metres,
seconds, radians; poses are rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import DriverModel, Intent, Mode, obstacle_control_one, road_clear, update_belief_one
from cdf_mj.model.road import follow_accel, heading_within
from cdf_mj.scenario.after_merge import AfterMergeOverride
from cdf_mj.scenario.drivers import SIGHTS, WorldDriver, make_driver
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.visibility import visible_share

__all__ = ["ObstacleAgent"]

_HELD_BACK = frozenset((int(Mode.YIELDING), int(Mode.WAITING)))  # plain ints: a cheap test per tick
_MOVING = frozenset((int(Mode.GOING), int(Mode.COMMITTED)))
_GOING, _WAITING, _YIELDING = int(Mode.GOING), int(Mode.WAITING), int(Mode.YIELDING)


class ObstacleAgent:
    """The obstacle driver of one world (see the module docstring).

    One :meth:`act`, in order: it looks (MuJoCo rays, cast at most once a tick; with
    probability ``obstacle.beta`` it observes the ego's pose with Gaussian noise) and
    updates its belief; a hesitating driver stops again once it has crept
    ``hesitation_creep`` [m] from its line; on the tick it would leave the line it looks once
    more with probability ``departure_look``; its state machine (or family) gives its
    controls; ``after_merge`` may override its acceleration, and behind the ego in the lane
    it keeps its distance (``after_merge.follows``).

    Args:
        scene: the world's scene (its rays answer the line of sight; it is not stepped here).
        config: scenario parameters (``obstacle``, ``observation``, ``after_merge``, ``ego``).
        driver: the obstacle's :class:`~cdf_mj.model.driver.DriverModel` (the world's).

    ValueError, naming the scene, for an ``after_merge.at`` beyond its left route or a
    ``hesitation_creep`` that reaches its commit point; ValueError for a family whose
    ``sight`` is not one of :data:`~cdf_mj.scenario.drivers.SIGHTS`.

    A family is shown the ego by its ``sight`` (``"line"`` where it has none): ``"line"``
    its true pose on a tick it is ``looking`` and its eye sees any of the ego's sight points
    (else None); ``"share"`` the same, with the driver's ``ego_share`` set before its
    ``control`` to the share of those points its eye sees (0 on a tick it does not look);
    ``"all"`` its true pose every tick. ``observed`` is whether it was shown the pose.

    Attributes after :meth:`reset` (updated by :meth:`act`): ``intent``, ``dwell`` [s],
    ``hesitates``, ``hesitation_pause`` [s], ``hesitated`` [s] (when it stopped again, else
    None), ``first_seen`` [s], ``departed`` [s], ``yielded``, ``mode`` (its
    :class:`~cdf_mj.model.driver.Mode` as an int after its last decision), ``observed``
    (it observed the ego on its last tick), ``belief`` (4,) its believed ego pose (zeros
    until it has one; updated in place), :attr:`seen`. Always: ``family`` (the
    :class:`~cdf_mj.scenario.drivers.WorldDriver` or None) and ``after_merge``.
    """

    def __init__(self, scene: Scene, config: ScenarioConfig, driver: DriverModel) -> None:
        self.scene, self.config, self.driver = scene, config, driver
        self.layout = layout = scene.layout()
        behaviour = self._behaviour = config.obstacle
        seen = config.observation
        # The observation noise as Python floats (the per-tick products on floats).
        self._obs_std_py = [float(v) for v in (seen.pos, seen.pos, seen.heading, seen.speed)]
        self._dt = config.timing.dt
        self._follows = config.after_merge.follows
        # Its driver: the traits' state machine, or a family written apart from it.
        self.family: WorldDriver | None = None if behaviour.family == "model" else make_driver(behaviour.family)
        sight = getattr(self.family, "sight", "line")
        if sight not in SIGHTS:
            raise ValueError(f"driver family {behaviour.family!r} has sight={sight!r}: it must be one of "
                             f"{', '.join(SIGHTS)}")
        self.after_merge = AfterMergeOverride(config.after_merge)
        room = layout.route_left.length - float(layout.route_left.project(layout.conflict)[0])
        if config.after_merge.behaviour in ("slow", "brake") and config.after_merge.at[1] >= room:
            raise ValueError(f"after_merge.at={config.after_merge.at} m: the obstacle's left route goes on for "
                             f"{room:.1f} m past the conflict point in {scene.source}; give distances below it")
        if behaviour.hesitation > 0.0:  # a stop past the commit point would never happen
            start = layout.obstacle_start[:2]
            room = min(float(s - r.project(start)[0]) for r, s in zip(layout.obstacle_routes,
                                                                        driver.s_commit, strict=True))
            if behaviour.hesitation_creep >= room:
                raise ValueError(f"obstacle.hesitation_creep={behaviour.hesitation_creep} m reaches the commit point, "
                                 f"{room + 1e-9:.2f} m from the obstacle's start in {scene.source}: a driver "
                                 "past it never stops again; give a shorter creep")

    def reset(self, intent: Intent, dwell: float, hesitates: bool, hesitation_pause: float,
              rng: Mapping[str, np.random.Generator]) -> np.ndarray:
        """Start an episode with the world's draws (``intent``, ``dwell`` [s] at the line,
        whether it ``hesitates`` and its ``hesitation_pause`` [s]); its world options draw
        from ``rng["after_merge"]`` and (a family) ``rng["driver"]``. Returns where the world
        places it: ``[x m, y m, theta rad, v m/s]``."""
        self.intent, self.dwell = intent, dwell
        self.hesitates, self.hesitation_pause = hesitates, hesitation_pause
        self.hesitated: float | None = None
        self._go_after = dwell  # [s] a WAITING driver may leave from then on
        self._line = self.layout.obstacle_start[:2].copy()  # where it stood
        self.after_merge.reset(rng["after_merge"])
        start = self.layout.obstacle_start
        if self.family is not None:
            self.family.reset(self.layout, int(intent), rng["driver"])
            start = self.family.start
        self._mode = np.array([Mode.WAITING])
        self._belief = np.zeros((1, 4))
        self.belief = self._belief[0]  # a view: the belief update writes row 0 in place
        self._has_belief = np.zeros(1, dtype=bool)
        self._intents = np.array([int(intent)])
        self.mode, self.observed = int(Mode.WAITING), False
        self.first_seen: float | None = None
        self.departed: float | None = None
        self.yielded = False
        return start

    @property
    def seen(self) -> bool:
        """Whether it has observed the ego at least once (holds a belief; a family: looked and saw)."""
        return bool(self._has_belief[0]) if self.family is None else self.first_seen is not None

    def act(self, t: float, poses: np.ndarray, values: list[list[float]], in_lane: bool,
            u_look: float, z: list[float], u_depart: float) -> tuple[float, float]:
        """Its controls ``(accel m/s^2, steer rad)`` for the tick starting at ``t`` [s], before
        process noise: ``poses`` (2, 4) the true system pose (ego, obstacle) and ``values`` the
        same as Python floats; ``in_lane``: it is in the ego's lane; the world's draws of this
        tick: ``u_look`` uniform (the beta look), ``z[:4]`` standard normals (its observation
        noise on the ego's x, y, theta, v), ``u_depart`` uniform (the departure look)."""
        ego, obs = poses[0], poses[1]
        ego_v, obs_v = values
        self._share: float | None = None  # the share of the ego in sight, cast at most once a tick
        if self.family is None:  # the traits' state machine, the filter's own model
            a, steer, mode, may_go, observed = self._decide(t, ego_v, obs_v, poses, u_look, z, u_depart)
        else:  # a driver written apart from it: it looks whenever it looks, and acts on what it sees
            observed = self._shown(poses)
            if observed and self.first_seen is None:
                self.first_seen = t
            a, steer = self.family.control(t, obs, ego if observed else None, self._dt)
            a = float(np.float64(a))  # what it was as an entry of the (1, 2) controls array
            steer = float(np.float64(steer))
            mode, may_go = int(self.family.mode), True
        # Once in the ego's lane, what it does next is the world's option (keep by default),
        # and behind the ego it keeps its distance (after_merge.follows).
        a = float(self.after_merge.accel(t, obs, in_lane, a))
        # follow_accel is None unless the ego is ahead in the lane heading the obstacle's way
        # (in_lane_ahead(..., within=FOLLOW_HEADING)): its heading test first, on the floats,
        # spares the call on most ticks.
        if self._follows and heading_within(ego_v[2], obs_v[2]):
            layout = self.layout
            behind = follow_accel(layout, layout.obstacle, obs, layout.ego, ego, self.config.ego)
            if behind is not None:
                a = float(min(a, behind))
        if mode in _MOVING and self.departed is None:
            self.departed = t
        # Held back by what it believes: braking to yield, or still waiting once its dwell
        # is over (waiting out the dwell itself is not yielding).
        self.yielded |= mode in _HELD_BACK and (may_go or mode != _WAITING) if self.family is None \
            else mode == _YIELDING
        self.mode, self.observed = mode, observed
        return a, steer

    def _visible_share(self, poses: np.ndarray) -> float:
        """The share of the ego's sight points its eye sees (MuJoCo rays), cast once a tick."""
        if self._share is None:
            self.scene.sync()  # geoms where qpos puts them, for the rays
            self._share = visible_share(self.scene, "obstacle", "ego", poses[1], poses[0])
        return self._share

    def _sees_ego(self, poses: np.ndarray) -> bool:
        """The line of sight from its eye to any part of the ego (MuJoCo rays), cast once a tick."""
        return self._visible_share(poses) > 0.0

    def _shown(self, poses: np.ndarray) -> bool:
        """Whether its family is shown the ego's pose this tick, as its ``sight`` says (for
        ``"share"``, the driver's ``ego_share`` is set here)."""
        family = self.family
        assert family is not None
        sight = getattr(family, "sight", "line")  # the family's, read each tick (a class attribute)
        if sight == "all":
            return True
        looking = family.looking
        if sight == "share":
            share = self._visible_share(poses) if looking else 0.0
            family.ego_share = share  # type: ignore[attr-defined]
            return share > 0.0
        return looking and self._sees_ego(poses)

    def _decide(self, t: float, ego_v: list[float], obs_v: list[float], poses: np.ndarray, u_look: float,
                z: list[float], u_depart: float) -> tuple[float, float, int, bool, bool]:
        """The traits' state machine: look, believe, hesitate, the departure look, decide.
        Returns ``(accel, steer, mode, may_go, observed)``."""
        behaviour, dt = self._behaviour, self._dt
        observed = bool(u_look < behaviour.beta) and self._sees_ego(poses)
        std = self._obs_std_py
        seen_as = [ego_v[i] + z[i] * std[i] for i in range(4)]  # the ego's pose with the observation noise
        # The belief update g(B, O), in place: self._belief is this agent's own.
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
                and self._sees_ego(poses)):
            # It would leave now: it looks once more, and sees the ego.
            observed = True
            update_belief_one(self._belief, self._has_belief, seen_as, dt)
        if observed and self.first_seen is None:
            self.first_seen = t
        # It decides (obstacle_control of one car: its kernel, from the full route search,
        # with this tick's pose, mode and belief).
        a, steer, mode, _ = obstacle_control_one(self.driver, obs_v, mode, self._belief[0].tolist(),
                                                 bool(self._has_belief[0]), int(self._intents[0]), may_go)
        self._mode[0] = mode  # this agent's own array (obstacle_control returned a new one)
        return a, steer, mode, may_go, observed
