"""The ego's sensing of the obstacle and its brake's actuation, as the world gives them
to the planner (:class:`cdf_mj.config.Sensing`); records keep the truth.

:class:`Sensor` turns each tick's true :class:`~cdf_mj.scenario.world.Measurement` into the
planner's: the obstacle's pose ``latency`` ticks old, plus Gaussian noise, or none at all
(a dropout: the obstacle's row is NaN and it is not in the lane); the ego's own pose is
exact. With ``occluded`` sensing there is none either while the obstacle was out of the
ego's line of sight (``Measurement.visible``, the share of its sight points that the ego's
sensor mount sees past the buildings, 0 on that tick, ``latency`` ticks back; MuJoCo rays,
docs/OCCLUSION.md). :class:`CommandDelay` delays the ego's commands (a yes/no planner's full brake and
release too) by ``brake_latency`` ticks; :class:`JerkLimiter` is the actuator a graded
planner's commands go through, whose acceleration changes by at most ``ego.jerk_limit`` per
second. With perfect sensing (the default) the sensor and the delay pass everything
through and draw nothing.

Randomness: the sensor draws from its own stream (the world's ``sensing`` stream), so the
obstacle, the ego's start and every other draw of a seed are the same whatever the
sensing (common random numbers). The ego agent (:class:`cdf_mj.scenario.ego_agent.EgoAgent`)
holds all three; by hand::

    sensor = Sensor(config.sensing, layout, world.rng["sensing"])
    m = world.measure()
    poses, in_lane = sensor.sense(m.poses, m.obstacle_in_lane, m.visible)
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from cdf_mj.config import Sensing
from cdf_mj.model import road
from cdf_mj.model.layout import Layout

__all__ = ["CommandDelay", "JerkLimiter", "Sensor"]


class Sensor:
    """The ego's measurement of the obstacle (see the module docstring).

    Args:
        sensing: noise std [m, rad, m/s], dropout probability, latency [ticks], whether
            the ego's sensor is occluded.
        layout: the junction (the obstacle's box and the ego's lane, for the lane test of a
            measured pose).
        rng: the Generator of the sensing draws (one normal per pose component and one
            uniform per tick, drawn only where the sensing is imperfect, every such tick
            whatever is seen: the same draws per seed with and without occlusion).

    Counts per episode: ``occluded``, the ticks whose measurement the obstacle's being out of
    sight took (0 without ``occluded`` sensing), and ``dropped``, those a dropout took while
    it was in sight; together the ticks without a measurement of the obstacle.
    """

    def __init__(self, sensing: Sensing, layout: Layout, rng: np.random.Generator) -> None:
        self.sensing, self.layout, self.rng = sensing, layout, rng
        self._std = np.array([sensing.pos, sensing.pos, sensing.heading, sensing.speed])
        self._noisy = bool(self._std.any())
        self._past: deque[tuple[np.ndarray, bool, bool]] = deque(maxlen=sensing.latency + 1)
        self.dropped = 0  # ticks without a measurement of the obstacle by a dropout (it was in sight)
        self.occluded = 0  # ticks without a measurement of the obstacle because it was out of sight

    def sense(self, poses: np.ndarray, in_lane: bool, visible: float = math.nan) -> tuple[np.ndarray, bool]:
        """The planner's system pose ``(2, 4)`` and whether the measured obstacle is in the
        ego's lane, from the true ones of this tick, and, read only with ``occluded``
        sensing, the share [0, 1] of the obstacle's sight points the ego's sensor sees on it
        (``Measurement.visible``; 0: out of sight). Returns the inputs themselves with perfect
        sensing. ValueError with ``occluded`` sensing and a ``visible`` that is not in [0, 1]
        (NaN included: a caller that does not know must not blind the ego silently)."""
        s = self.sensing
        if s.perfect:
            return poses, in_lane
        if s.occluded and not 0.0 <= visible <= 1.0:
            raise ValueError(f"Sensor.sense: visible={visible!r} must be the share in [0, 1] of the obstacle's "
                             "sight points the ego sees (sensing.occluded: World.measure() gives it)")
        self._past.append((np.array(poses[1], dtype=float), in_lane, bool(visible > 0.0)))
        obstacle, seen_in_lane, in_sight = self._past[0]  # latency ticks old (the oldest kept)
        u = self.rng.random()
        noise = self.rng.standard_normal(4) * self._std
        out = np.array(poses, dtype=float)
        if s.occluded and not in_sight:
            self.occluded += 1
            out[1] = np.nan
            return out, False
        if u < s.dropout:
            self.dropped += 1
            out[1] = np.nan
            return out, False
        if not self._noisy:
            out[1] = obstacle
            return out, seen_in_lane
        out[1] = obstacle + noise
        x, y, th = out[1, :3].tolist()
        return out, road.in_lane(self.layout, self.layout.obstacle.footprint_one(x, y, th))


class CommandDelay:
    """The ego's commands [m/s^2] ``latency`` ticks behind its planner; ``initial`` acts
    before the first one arrives (default ``inf``: no command, the ego's own controller)."""

    def __init__(self, latency: int, initial: float = math.inf) -> None:
        self._queue: deque[float] = deque([initial] * latency, maxlen=latency + 1)

    def __call__(self, command: float) -> float:
        """The command that acts on this tick, given this tick's."""
        self._queue.append(command)
        return self._queue[0]


class JerkLimiter:
    """The ego's actuator: the applied acceleration [m/s^2] changes by at most
    ``jerk_limit * dt`` from one tick to the next (``jerk_limit`` [m/s^3], ``dt`` [s])."""

    def __init__(self, jerk_limit: float, dt: float) -> None:
        self.step = jerk_limit * dt
        self.last: float | None = None

    def __call__(self, accel: float) -> float:
        """The acceleration applied over this tick for the one asked for."""
        if self.last is not None:
            accel = min(max(accel, self.last - self.step), self.last + self.step)
        self.last = accel
        return accel
