"""Naive caution: three baselines that slow the ego by a stated rule, with no model of the
other driver's intent or belief (issue 35). They are the bar the belief model must clear.

Each is ``cdf`` with its anticipation layer replaced (:class:`~cdf_mj.planners.cdf.CDFPlanner`
with a subclass of :class:`~cdf_mj.planners.decision.LayeredRule` on ``CDFConfig.layered`` and
``CDFConfig.risk``): the same emergency layer (the full brake at the last safe moment for the
filter's hypotheses), the same follow layer and the same guard (the ego slows only while
slowing is not riskier than going on). Only the decision to slow differs: it reads a rule
about where the other car is, never the belief of its intent or of what its driver has seen.
So a comparison with ``cdf`` measures what the belief buys in the decision to intervene,
with the safety net held equal (the same referee's bar as issue 35's; a baseline on the
constant-velocity path instead hard-brakes for every right-turner through its emergency
layer, which would say nothing of the decision to slow).

===============  ==========================================================================
caution-waiting  slow at ``comfort_brake`` while the other car is on the side road and the
                 ego is short of the conflict zone: "always slow for a waiting car"
caution-moving   the same, only while the other car moves (faster than ``stand_speed`` plus
                 twice the told speed noise, as the standoff reads it): "assume the worst
                 while it moves"
caution-phantom  hold a speed from which the ego can stop at ``comfort_brake`` before the
                 conflict zone while a car could reach the ego's path before the ego has
                 cleared the zone: one hidden on the side road's approach (the *phantom
                 vehicle* of occlusion-aware planning) or the other car on the side road
===============  ==========================================================================

*On the side road* (:meth:`CautionRule.cleared` is false): the other car is not in the ego's
lane (its box does not meet ``Layout.ego_lane``), has not gone right (it is not nearer to
``route_right`` than to ``route_left`` by more than half its width) and is not past the
conflict zone (its rear axle is not past the conflict point along ``route_left``). A missed
measurement (a NaN row) keeps the last one. *Short of the conflict zone*: the ego's arc
length on its route is below the zone's start (:class:`~cdf_mj.model.conflict.ConflictMap`,
boxes widened by ``RiskConfig.margin``); none of the three slows inside it or past it.

``caution-waiting`` stops slowing once both cars have stood for ``layers.standoff`` (the
other is then taken to wait for the ego, as the emergency layer takes it): without that, an
ego stopped for a driver who waits for it would wait for ever. ``caution-phantom`` leaves a
waiting car out the same way; its phantom stays (a hidden approach is never taken to wait).

The phantom rule follows the hypothetical vehicles that occlusion-aware planners assume to
approach at a constant speed from the occluded areas (e.g. Narksri et al., *Deadlock-free
planner for occluded intersections*, Electronics 10(4) 411, 2021; McGill et al., RA-L 4(4),
2019). A car may wait unseen anywhere on the side road's approach, the stretch of
``RiskConfig.horizon`` times the ego's nominal speed upstream of the other car's waiting
place along ``route_left``'s first segment, and drive at the ego's nominal speed (the only
road speed the ego knows) to the point where its box first meets the ego's route. A point
of the approach is hidden when the ego's eye sees none of a car's sight points there
(:func:`~cdf_mj.model.occlusion.sight_targets`) past the layout's buildings
(:class:`~cdf_mj.model.occlusion.Occluders`: buildings only, cars do not occlude). The seen
other car, while on the side road, may pull out at once at its car's full acceleration from
its measured speed. Either threatens the ego while it could reach the ego's route before the
ego, at its present speed, has cleared the conflict zone. While one does, the ego holds the
speed ``v`` with ``v T + v^2 / (2 b) <= d`` (``d`` [m] to the zone, ``b`` =
``comfort_brake``): its reaction time ``T`` is one tick, the told latency and
``b / (2 comfort_jerk)``, the distance lost while the brake builds up at the comfortable
jerk (0.35 s in the default world). The command is a proportional speed hold, at the ego's
own gain (``PlannerContext.speed_gain``), to the cap one tick ahead, plus the rate at which
the cap falls as the ego nears the zone, braking at most ``b``, ramped at ``comfort_jerk``.
From above its cap it brakes at ``b`` and may enter the zone slowed: the default world's
ego starts 27-43 m before the zone at 13.4 m/s, where its cap is 10.8-13.8 m/s. Where even
the zone's edge sees too little of the approach, the phantom keeps the ego there (the
deadlock Narksri et al. describe).

What all three ignore: the other driver's intent, its belief, its gap acceptance, how long
it has waited; where it waits, they slow whatever it will do. What they assume: one other
car, on the junction's side road (``route_left``/``route_right``), measured each tick.
Every distance and speed comes from the Layout, the cars and the
:class:`~cdf_mj.planners.base.PlannerContext` (any scale, :func:`cdf_mj.config.scaled`).

Frames and units: world frame, metres, seconds, radians; poses ``[x, y, theta, v]`` of the
rear axle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from cdf_mj.config import CDFConfig
from cdf_mj.model import road
from cdf_mj.model.occlusion import sight_targets
from cdf_mj.planners.base import PlannerContext, PlannerInput, Predictor, as_config
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.decision import LayeredRule

__all__ = ["CautionMovingPlanner", "CautionRule", "CautionWaitingPlanner", "MovingRule", "PhantomPlanner",
           "PhantomRule", "WaitingRule"]


class CautionRule(LayeredRule):
    """The layered rule with a naive anticipation layer (module docstring): it slows at the
    comfortable brake while :meth:`cautious` holds and slowing is not riskier than going on
    (``slow <= go``), and stops slowing, after the dwell, once it no longer holds or slowing
    is riskier (``slow > go``). ``caution`` (kept per tick in the history) is whether the
    rule's condition held this tick."""

    history_keys: tuple[str, ...] = (*LayeredRule.history_keys, "caution")

    def reset(self, context: PlannerContext) -> None:
        """The layered rule's reset; where the other car meets the ego's route and passes
        the conflict point along ``route_left`` [m]; no reading of the other car yet."""
        super().reset(context)
        lay = context.layout
        self._junction = lay
        meets = np.flatnonzero(np.isfinite(self.map.q_lo))  # non-empty: conflict_map refuses a layout without
        self._s_meet = float(meets[0] * self.map.ds)  # [m] its box first meets the ego's route (widened)
        self._s_past = lay.route_left.project_point(float(lay.conflict[0]), float(lay.conflict[1]))[0]
        self._moving_speed = self.layers.stand_speed + 2.0 * context.measurement_std[3]  # [m/s]
        self._other: np.ndarray | None = None
        self.caution = False

    def other(self, obs: PlannerInput) -> np.ndarray | None:
        """The other car's pose ``(4,)``: this tick's measurement, or the last one where it
        is missing (NaN); None before the first."""
        pose = obs.poses[1]
        if np.isfinite(pose).all():
            self._other = np.array(pose, dtype=float)
        return self._other

    def cleared(self, pose: np.ndarray) -> bool:
        """Whether the other car at ``pose`` is off the side road: in the ego's lane, gone
        right, or past the conflict point along ``route_left``."""
        lay, car = self._junction, self._junction.obstacle
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        if road.in_lane(lay, car.footprint_one(x, y, th)):
            return True
        s_left = lay.route_left.project_point(x, y)[0]
        if s_left > self._s_past:
            return True
        off = [math.dist((x, y), route.point_at(route.project_point(x, y)[0]))
               for route in (lay.route_left, lay.route_right)]
        return off[1] + 0.5 * car.width < off[0]

    def short_of_zone(self, ego_pose: np.ndarray) -> bool:
        """Whether the ego has not reached the conflict zone."""
        return self.map.ego_arc(ego_pose) < self.map.zone[0]

    def cautious(self, obs: PlannerInput) -> bool:
        """Whether the rule's naive condition holds on this tick (its subclasses')."""
        raise NotImplementedError

    def anticipation(self, obs: PlannerInput, go: float, slow: float) -> tuple[bool, bool]:
        """``(start, stop)``: start slowing while :meth:`cautious` and ``slow <= go``; stop
        once not, or once ``slow > go``."""
        self.caution = self.cautious(obs)
        return self.caution and slow <= go, not self.caution or slow > go

    def values(self) -> dict[str, float]:
        """The layered rule's, and ``caution``: 1 where the naive condition held this tick."""
        return {**super().values(), "caution": float(self.caution)}


class WaitingRule(CautionRule):
    """``caution-waiting``: slow while the other car is on the side road (waiting at it or
    coming along it), the ego short of the conflict zone, until both cars have stood for
    ``layers.standoff``."""

    def cautious(self, obs: PlannerInput) -> bool:
        """The other car is on the side road, the ego short of the zone, no standoff."""
        other = self.other(obs)
        return (other is not None and not self._standoff and self.short_of_zone(obs.poses[0])
                and not self.cleared(other))


class MovingRule(CautionRule):
    """``caution-moving``: slow while the other car moves on the side road (its measured
    speed at least ``layers.stand_speed`` plus twice the told speed std), the ego short of
    the conflict zone."""

    def cautious(self, obs: PlannerInput) -> bool:
        """The other car moves and is on the side road, the ego short of the zone."""
        other = self.other(obs)
        return (other is not None and abs(float(other[3])) >= self._moving_speed
                and self.short_of_zone(obs.poses[0]) and not self.cleared(other))


class PhantomRule(CautionRule):
    """``caution-phantom``: the worst-case occlusion-aware speed cap (module docstring). Its
    anticipation layer never slows at the fixed comfortable brake; :meth:`command` takes the
    least of the layered rule's command and the cap's."""

    def reset(self, context: PlannerContext) -> None:
        """The caution rule's reset; the approach's sample poses and sight points, the
        phantom's speed, the response time and the ego's speed hold; no cap."""
        super().reset(context)
        lay, layers = context.layout, self.layers
        left = lay.route_left.points
        way = (left[1] - left[0]) / float(np.hypot(*(left[1] - left[0])))  # towards the junction
        self._v_phantom = context.nominal_speed  # [m/s]
        self._reach = self._v_phantom * self.config.horizon  # [m] of approach looked at, at most
        upstream = np.arange(0.0, self._reach + 1e-9, 0.25 * lay.obstacle.length)  # [m] from the waiting place
        poses = np.zeros((len(upstream), 4))
        poses[:, :2] = lay.obstacle_start[:2] - upstream[:, None] * way
        poses[:, 2] = math.atan2(way[1], way[0])
        self._upstream = upstream
        self._sight = sight_targets(lay.obstacle, poses)  # (N, 5, 2)
        b = layers.comfort_brake
        self.response = context.dt + context.latency + b / (2.0 * layers.comfort_jerk)  # [s] T
        self._gain = context.speed_gain  # [1/s] the ego's own speed hold's
        self._ego_accel = lay.ego.max_accel
        self._cap_accel = math.inf  # [m/s^2] the cap's command now
        self._v_prev: float | None = None

    def anticipation(self, obs: PlannerInput, go: float, slow: float) -> tuple[bool, bool]:
        """Never the fixed comfortable brake (the cap is :meth:`command`'s); keeps the reading."""
        self.other(obs)
        return False, True

    def speed_cap(self, distance: float) -> float:
        """[m/s] The highest speed from which the ego stops within ``distance`` [m] at the
        comfortable brake after the response time ``T``: ``v T + v^2 / (2 b) = distance``."""
        b, t = self.layers.comfort_brake, self.response
        return b * (math.sqrt(t * t + 2.0 * max(distance, 0.0) / b) - t)

    def arrival(self, pose: np.ndarray) -> float:
        """[s] The earliest the other car at ``pose`` reaches the ego's route: along
        ``route_left`` at its car's full acceleration from its measured speed."""
        lay = self._junction
        rest = self._s_meet - lay.route_left.project_point(float(pose[0]), float(pose[1]))[0]
        if rest <= 0.0:
            return 0.0
        v, a = max(float(pose[3]), 0.0), lay.obstacle.max_accel
        return (math.sqrt(v * v + 2.0 * a * rest) - v) / a

    def phantom(self, ego_pose: np.ndarray, within: float) -> bool:
        """Whether a car hidden on the approach could reach the ego's route within ``within``
        [s] at the phantom's speed: some point of it near enough is hidden from the ego's eye."""
        reach = min(self._reach, self._v_phantom * within - self._s_meet)  # [m] upstream that could
        n = int(np.searchsorted(self._upstream, reach, side="right"))
        if n == 0:
            return False
        eye = self._junction.ego.eye(ego_pose)
        seen = self._junction.occluders.visible(np.broadcast_to(eye, (n, 3)), self._sight[:n])
        return not bool(seen.all())

    def threatened(self, ego_pose: np.ndarray) -> bool:
        """Whether the phantom or the other car on the side road (not standing off) could
        reach the ego's route before the ego, at its present speed, has cleared the zone."""
        v = max(float(ego_pose[3]), 0.0)
        rest = self.map.zone[1] - self.map.ego_arc(ego_pose)  # [m] until the ego has cleared the zone
        clear = rest / v if v > 0.0 else math.inf  # [s]
        other = self._other
        if other is not None and not self._standoff and not self.cleared(other) and self.arrival(other) < clear:
            return True
        return self.phantom(ego_pose, clear)

    def command(self, predictor: Predictor, obs: PlannerInput) -> float:
        """The layered rule's command, capped while threatened (the ego short of the zone
        and slowing not riskier than going on) by a speed hold to :meth:`speed_cap` of the
        distance to the zone [m/s^2]; ``-inf`` is the full brake, ``inf`` none."""
        command = super().command(predictor, obs)
        ego, layers, dt = obs.poses[0], self.layers, self._dt
        v = max(float(ego[3]), 0.0)
        a_now = (v - self._v_prev) / dt if self._v_prev is not None else 0.0  # [m/s^2] last tick's
        self._v_prev = v
        ly = self.last_layers
        distance = self.map.zone[0] - self.map.ego_arc(ego)
        self.caution = (distance > 0.0 and ly is not None and ly.slow <= ly.go and self.threatened(ego))
        if not (self.caution or self._cap_accel < math.inf):
            return command
        b, step = layers.comfort_brake, layers.comfort_jerk * dt
        target = math.inf
        if self.caution:  # how fast the cap falls as the ego nears the zone, and a speed hold to it
            cap = self.speed_cap(distance - v * dt)  # at the next tick, when this command has acted
            target = max(-b * v / (cap + b * self.response) + self._gain * (cap - v), -b)
        start = min(self._cap_accel, max(a_now, -b) + step)  # a cap above the ego's use does not bind
        accel = max(start - step, min(target, start + step))
        self._cap_accel = math.inf if accel >= self._ego_accel * (1.0 - 1e-9) else accel  # none at the car's most
        self.last_command = min(command, self._cap_accel)
        return self.last_command


class _CautionPlanner(CDFPlanner):
    """The CDF's filter with a caution rule (``rule_type``) on ``cdf.layered`` and
    ``cdf.risk``: ``cdf``'s emergency and follow layers and guard, a naive anticipation."""

    rule_type: ClassVar[type[CautionRule]] = CautionRule

    def __init__(self, cdf: CDFConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(as_config(cdf, CDFConfig, "cdf").replace(decision="layered"))
        self.rule = self.rule_type(self.cdf.layered, self.cdf.risk, self.cdf.ego_brake)


class CautionWaitingPlanner(_CautionPlanner):
    """``caution-waiting``: slow at the comfortable brake while the other car is on the side
    road (:class:`WaitingRule`)."""

    name = "caution-waiting"
    rule_type = WaitingRule


class CautionMovingPlanner(_CautionPlanner):
    """``caution-moving``: slow at the comfortable brake while the other car moves on the
    side road (:class:`MovingRule`)."""

    name = "caution-moving"
    rule_type = MovingRule


class PhantomPlanner(_CautionPlanner):
    """``caution-phantom``: the worst-case occlusion-aware speed cap (:class:`PhantomRule`)."""

    name = "caution-phantom"
    rule_type = PhantomRule
