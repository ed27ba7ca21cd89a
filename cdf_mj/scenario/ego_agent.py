"""The ego's half of a tick: :class:`EgoAgent` senses, asks its planner, holds or releases
its brake, delays the command by its brake's latency, and drives by its nominal controller
(speed hold, car following) under that command through its jerk-limited actuator.

The episode loop is three lines: the world measures, the ego acts, the world steps::

    ego = EgoAgent(world.layout, config, world.driver, make_planner("cdf"))
    m = world.reset(seed)
    ego.reset(world.rng)                   # the planner's and the sensor's streams
    while not world.done:
        m = world.measure()
        tick = world.step(ego.act(m))      # [accel m/s^2, steer rad]

A controller outside the package (the Gymnasium env's agent) uses the same sensor and
brake latency without a planner: :meth:`EgoAgent.sense` gives what the ego measures,
:meth:`EgoAgent.drive` puts its own acceleration through the brake's latency::

    obs = ego.sense(world.measure())       # PlannerInput: t, the sensed (2, 4) poses, in_lane
    tick = world.step(ego.drive(accel, steer))

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import DriverModel, ego_control
from cdf_mj.model.layout import Layout
from cdf_mj.model.road import follow_accel
from cdf_mj.planners.base import (
    INTERVENTION_SHARE,
    Planner,
    PlannerContext,
    PlannerInput,
    hard_brake_of,
    intervenes,
    intervention_tolerance_of,
)
from cdf_mj.scenario.sensing import CommandDelay, JerkLimiter, Sensor

if TYPE_CHECKING:  # annotations only: the monitor imports PlannerCommand without MuJoCo
    from cdf_mj.scenario.world import Measurement

#: Re-exported from :mod:`cdf_mj.planners.base`, where the rule lives beside ``hard_brake_of``.
__all__ = ["INTERVENTION_SHARE", "EgoAgent", "PlannerCommand", "intervention_tolerance_of"]

def _answer(planner: Planner, wants: object) -> bool:
    """A planner's answer to "brake now?": a ``bool`` or NumPy bool, else TypeError naming the
    planner and what it returned (NaN, ``"yes"`` or ``None`` would otherwise read as a
    decision)."""
    if not isinstance(wants, (bool, np.bool_)):
        name = getattr(planner, "name", None) or type(planner).__name__
        raise TypeError(f"planner {name!r} ({type(planner).__name__}.brake) returned {wants!r} of type "
                        f"{type(wants).__name__}: it must return a bool (True: brake now)")
    return bool(wants)


def _command(planner: Planner, command: object) -> float:
    """A graded planner's command: a real number or +-inf (not NaN), else TypeError naming
    the planner and what it returned."""
    if isinstance(command, bool) or not isinstance(command, (int, float, np.floating, np.integer)) \
            or math.isnan(command):
        name = getattr(planner, "name", None) or type(planner).__name__
        raise TypeError(f"planner {name!r} ({type(planner).__name__}.command) returned {command!r}: it must "
                        "return an acceleration cap [m/s^2] (-inf: the full brake, inf: none)")
    return float(command)


class PlannerCommand:
    """A planner's answer on each tick as a command [m/s^2], what the ego (:class:`EgoAgent`)
    and the monitor (:class:`~cdf_mj.scenario.monitor.CDFMonitor`) act on: a graded
    planner's own command, or a yes/no planner's full brake (``-inf``; its first yes held
    unless it ``releases_brake``) or none (``inf``).

    After each call ``braking`` is whether it brakes on this tick (a graded command at or
    beyond the planner's ``hard_brake``, else :func:`~cdf_mj.planners.base.hard_brake_of`
    the car's ``max_brake`` [m/s^2]) and ``brake_time`` [s] the first tick it did. Call
    :meth:`reset` after the planner's own reset (a rule may be chosen there).
    """

    def __init__(self, planner: Planner | None, max_brake: float) -> None:
        self.planner, self.max_brake = planner, max_brake
        self.reset()

    def reset(self) -> None:
        """Start an episode: no brake yet; read the planner's kind: ``graded`` (a command
        [m/s^2]) or yes/no, whether it ``releases`` its brake, and the command ``hard``
        [m/s^2] from which a graded command is a brake."""
        planner = self.planner
        self.graded = bool(getattr(planner, "graded", False))
        self.releases = bool(getattr(planner, "releases_brake", False))
        hard = getattr(planner, "hard_brake", None) if self.graded else None
        self.hard = hard_brake_of(self.max_brake) if hard is None else hard
        self.braking = False  # a yes/no planner's brake, held
        self.brake_time: float | None = None

    def __call__(self, seen: PlannerInput) -> float:
        """The planner's command [m/s^2] on this tick's measurement ``seen``."""
        planner = self.planner
        if planner is None:
            raise RuntimeError("PlannerCommand: no planner to ask")
        if self.graded:
            command = _command(planner, planner.command(seen))
            wants = command <= -self.hard
        else:
            wants = _answer(planner, planner.brake(seen))
            wants = wants if self.releases else (self.braking or wants)
            command = -math.inf if wants else math.inf
        self.braking = wants
        if wants and self.brake_time is None:
            self.brake_time = seen.t
        return command


class EgoAgent:
    """The ego car's sensing, decision and control (see the module docstring).

    One :meth:`act`, in order: its sensor turns the true measurement into the planner's
    (``config.sensing``: noise, dropouts, latency, occlusion; the truth by default); the planner
    answers: a graded command [m/s^2], or yes/no to the full brake (its first yes is held
    unless the planner ``releases_brake``); the command acts ``sensing.brake_latency`` ticks
    later; the nominal controller (speed hold and pure pursuit) is capped by it and, where
    the ego ``follows``, by the IDM behind the measured obstacle ahead in its lane (at most
    ``ego.follow_brake``); the car's brake bounds it, and a graded planner's commands pass
    the jerk-limited actuator (``ego.jerk_limit``; a yes/no planner's act at once, as the
    paper's did).

    Args:
        layout: the junction (routes, lane, both cars' geometry).
        config: scenario parameters (``sensing``, ``ego``, ``timing``).
        driver: the world's :class:`~cdf_mj.model.driver.DriverModel` (its ego controller).
        planner: what decides the brake; None for a controller outside the package, which
            uses :meth:`sense` and :meth:`drive` (:meth:`act` needs a planner).
        follows: whether it follows a car ahead (default ``config.ego.follow``; the label's
            counterfactual ego holds its speed whatever is ahead).

    Attributes after :meth:`reset` (updated by :meth:`act`): ``sensor``
    (:class:`~cdf_mj.scenario.sensing.Sensor`), ``brake_time`` [s] (the first tick its
    planner wanted the brake, else None), ``deviated`` [s] (the first tick it did not hold
    its nominal controller's acceleration, else None), ``acting`` (the full brake acts on
    this tick: the decision ``brake_latency`` late) and ``accel`` [m/s^2] (the acceleration
    it commanded on this tick).

    Interventions (every one counted, not only hard brakes): ``own`` [m/s^2] is what its
    own controller would apply on this tick without the planner (speed hold and, where it
    ``follows``, the IDM behind the measured car ahead), within the car's brake;
    ``command`` [m/s^2] the planner's command as it acts (``brake_latency`` late; +-inf as
    given); the tick is ``intervening`` when that command, read within the car's brake, is
    below ``own`` by more than ``tolerance`` (:func:`intervention_tolerance_of` the car's
    ``max_brake``). Per episode: ``first_intervention`` [s] (None if none),
    ``intervention_ticks`` and ``intervention_peak`` [m/s^2, >= 0] (the most deceleration
    applied on an intervening tick; 0 without one).
    """

    def __init__(self, layout: Layout, config: ScenarioConfig, driver: DriverModel,
                 planner: Planner | None = None, *, follows: bool | None = None) -> None:
        self.layout, self.config, self.driver, self.planner = layout, config, driver, planner
        self.follows = config.ego.follow if follows is None else bool(follows)
        self._car = layout.ego
        self._max_brake = layout.ego.max_brake
        self.tolerance = intervention_tolerance_of(self._max_brake)  # [m/s^2]
        self._command = PlannerCommand(planner, self._max_brake)
        self.sensor: Sensor | None = None
        self._m: Measurement | None = None

    def reset(self, rng: Mapping[str, np.random.Generator]) -> None:
        """Start an episode with the world's streams (:attr:`World.rng
        <cdf_mj.scenario.world.World>`): the planner's is ``rng["planner"]``, the sensor's
        ``rng["sensing"]``. The planner is told only what the ego knows: the map, the tick,
        its own controller."""
        config = self.config
        if self.planner is not None:
            self.planner.reset(PlannerContext.of(self.layout, config), rng["planner"])
        self._command.reset()  # the planner's kind as it is after its reset (a rule may be chosen there)
        self.sensor = Sensor(config.sensing, self.layout, rng["sensing"])
        self._m = None  # the last measurement sensed
        self._delay = CommandDelay(config.sensing.brake_latency)
        # A graded planner's commands go through the ego's jerk-limited actuator; a yes/no
        # planner's full brake and release act at once, as the paper's did (its records are
        # what they were before graded commands existed).
        self._actuator: Callable[[float], float] = \
            JerkLimiter(config.ego.jerk_limit, config.timing.dt) if self.graded else float
        self.deviated: float | None = None
        self.acting = False
        self.accel = math.nan
        self.own = self.command = math.nan
        self.intervening = False
        self.first_intervention: float | None = None
        self.intervention_ticks = 0
        self.intervention_peak = 0.0

    def sense(self, m: Measurement) -> PlannerInput:
        """What the ego measures of the tick's true measurement ``m`` (``config.sensing``; the
        truth itself with perfect sensing): time [s], the (2, 4) system pose whose obstacle
        row is late, noisy or NaN (a dropout, or with ``sensing.occluded`` an obstacle out of
        the ego's sight: ``m.visible`` 0), and whether that obstacle is in its lane."""
        if self.sensor is None:
            raise RuntimeError("EgoAgent: call reset(world.rng) before sensing")
        self._m = m
        poses, in_lane = self.sensor.sense(m.poses, m.obstacle_in_lane, m.visible)
        return PlannerInput(t=m.t, poses=poses, obstacle_in_lane=in_lane)

    def act(self, m: Measurement) -> np.ndarray:
        """The ego's controls ``[accel m/s^2, steer rad]`` for the tick of the true
        measurement ``m``: sense, decide, delay, control (see the class docstring)."""
        planner = self.planner
        if planner is None:
            raise RuntimeError("EgoAgent.act needs a planner; a controller of its own uses sense() and drive()")
        seen = self.sense(m)
        command = self._delay(self._command(seen))  # as it acts, sensing.brake_latency ticks on
        self.acting = command <= -self._command.hard
        # The ego's own controller: its speed hold and its car following, within its brake.
        controls = ego_control(self.driver, self._car, m.poses[0], False)
        nominal = own = float(controls[0])
        if self.follows:
            layout = self.layout
            behind = follow_accel(layout, layout.ego, m.poses[0], layout.obstacle, seen.poses[1], self.config.ego,
                                  max_brake=self.config.ego.follow_brake)
            if behind is not None:
                own = min(own, behind)
        own = max(own, -self._max_brake)
        # Capped by the command, within the car's brake, through the actuator's jerk limit.
        controls[0] = self._actuator(max(min(own, command), -self._max_brake))
        if controls[0] < nominal - 1e-9 and self.deviated is None:
            self.deviated = m.t
        self.accel = float(controls[0])
        self._count(m.t, own, command)
        return controls

    def _count(self, t: float, own: float, command: float) -> None:
        """Keep tick ``t`` [s]'s own acceleration and planner's command [m/s^2] and whether
        it intervened (the command, read within the car's brake, below ``own`` by more than
        the tolerance); count it in the episode's interventions."""
        self.own, self.command = own, command
        self.intervening = intervenes(command, own, self._max_brake)
        if self.intervening:
            if self.first_intervention is None:
                self.first_intervention = t
            self.intervention_ticks += 1
            self.intervention_peak = max(self.intervention_peak, -self.accel)

    def drive(self, accel: float, steer: float) -> np.ndarray:
        """Controls ``[accel m/s^2, steer rad]`` for a controller outside the package (the
        Gymnasium env's agent) on the tick it last sensed (:meth:`sense`): its acceleration
        acts ``sensing.brake_latency`` ticks late (before the first arrives, the nominal
        controller's, from the true pose of that tick), its steering at once."""
        if self.sensor is None:
            raise RuntimeError("EgoAgent: call reset(world.rng) before drive()")
        if self.config.sensing.brake_latency:
            accel = self._delay(accel)
            if accel == math.inf:  # nothing commanded yet: the ego's own controller
                if self._m is None:
                    raise RuntimeError("EgoAgent: call sense(m) before drive(): its speed hold needs the pose")
                accel = float(ego_control(self.driver, self._car, self._m.poses[0], False)[0])
        self.accel = accel
        return np.array([accel, steer])

    @property
    def graded(self) -> bool:
        """Whether the planner gives a graded command [m/s^2] (else yes/no to the full brake)."""
        return self._command.graded

    @property
    def releases(self) -> bool:
        """Whether a yes/no planner may release its brake (else its first yes is held)."""
        return self._command.releases

    @property
    def brake_time(self) -> float | None:
        """[s] The first tick its planner wanted the brake, None if it has not."""
        return self._command.brake_time
