"""When to brake: the decision rules a predicting planner is built from (predictor x rule).

A predicting planner (:class:`cdf_mj.planners.base.DecidingPlanner`: ``cdf``, ``imm``,
``cv``) estimates the obstacle's future each tick; its rule turns that estimate into
braking or not:

================  ==========================================================================
ThresholdRule     the paper's rule: brake once the predictor's own alarm probability
                  (the CDF's P(cutoff), the IMM's P(conflict), the CV's predicted conflict)
                  reaches a threshold, and hold the brake to the end
RiskRule          brake at the last safe moment: when the probability of a collision that
                  deferring the brake by one more decision interval (plus a latency
                  margin) would make unavoidable reaches ``RiskConfig.brake`` and braking
                  now is no riskier; release the
                  brake, back to the nominal speed, once that risk of going on is below
                  ``RiskConfig.release``, or, inside the conflict zone, once it is below
                  the risk of staying there
================  ==========================================================================

The risk rule rolls the predictor's hypotheses forward
(:class:`cdf_mj.model.conflict.Futures` along the obstacle's left route, or one
predicted path of poses) against three plans of the ego on its route: going on
(``GO``), going on for ``n_defer`` ticks then braking (``DEFER``), braking now
(``BRAKE``). A hypothesis is *unavoidable if deferred* when it collides under both GO
and DEFER: the ego could neither pass first nor stop in time after waiting. The ego
brakes when the weight of those reaches ``brake`` and braking now collides with no more
weight. Any predictor that gives futures runs with it, so a comparison
of ``cdf`` with ``imm-risk`` isolates the prediction.

Frames and units: world frame, metres, seconds; probabilities in [0, 1].
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from cdf_mj.config import RiskConfig
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.model.conflict import (
    BRAKE,
    DEFER,
    GO,
    ConflictMap,
    Futures,
    collision_masses,
    conflict_map,
    ego_plans,
    route_poses,
    widened,
)
from cdf_mj.model.geometry import boxes_overlap
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners.base import DecisionRule, PlannerContext, Predictor, ThresholdRule

#: Bit masks of :func:`collision_masses`' index: the masses that collide going on and when
#: deferring (unavoidable if deferred), when braking now, and going on.
_INDEX = np.arange(1 << 3)
_DEFERRED = (_INDEX & ((1 << GO) | (1 << DEFER))) == ((1 << GO) | (1 << DEFER))
_BRAKES = (_INDEX & (1 << BRAKE)) != 0
_GOES = (_INDEX & (1 << GO)) != 0

def _unit(total: float) -> float:
    """A probability summed from weights, clipped into [0, 1] against rounding."""
    return min(max(float(total), 0.0), 1.0)


__all__ = ["Assessment", "DecisionRule", "GivenFutures", "Predictor", "RiskRule", "ThresholdRule", "rollout_assessment"]


@dataclass(frozen=True)
class Assessment:
    """The risk rule's reading of one tick: probabilities (total weight of the hypotheses)
    of a collision under the ego's plans, and where the ego is."""

    deferred: float  # collides both going on and braking after the deferral: unavoidable if deferred
    brake: float  # collides when the ego brakes now
    inside: bool  # the ego is inside the conflict zone
    go: float = math.nan  # collides when the ego goes on (NaN unless assessed with exact=True)


class GivenFutures:
    """A predictor whose futures are given: to ask a rule what it decides for hypotheses
    of your own (tests, scripts, another estimator). ``alarm()`` is 0 (it predicts no
    cut-off of its own for the threshold rule)."""

    def __init__(self, futures: Futures | np.ndarray) -> None:
        self._futures = futures

    def alarm(self) -> float:
        """No alarm of its own."""
        return 0.0

    def futures(self, react_ticks: int) -> Futures | np.ndarray:
        """The futures it was given."""
        return self._futures


class RiskRule:
    """Brake at the last safe moment, release when the risk is gone (module docstring).

    Args:
        config: thresholds, latency margin, horizon and box margin (default :class:`RiskConfig`).
        ego_brake: [m/s^2] the ego's braking in the plans (default: its car's maximum).
    """

    name = "risk"
    releases = True
    history_keys = ("risk",)

    def __init__(self, config: RiskConfig | None = None, ego_brake: float | None = None) -> None:
        self.config = config or RiskConfig()
        if not isinstance(self.config, RiskConfig):
            raise TypeError(f"config must be a RiskConfig, got {type(self.config).__name__}")
        if ego_brake is not None and not (isinstance(ego_brake, (int, float)) and math.isfinite(ego_brake)
                                          and ego_brake > 0):
            raise ValueError(f"ego_brake={ego_brake!r} is out of range: must be > 0 [m/s^2]")
        self.ego_brake = ego_brake
        self.last: Assessment | None = None

    @property
    def react_ticks(self) -> int:
        """Ticks before a decision deferred now could act: the next decision, plus the latency."""
        return self._defer

    def reset(self, context: PlannerContext) -> None:
        """The junction's conflict map, the ego's limits and its nominal controller."""
        cfg = self.config
        layout, dt = context.layout, context.dt
        half = min(float(layout.ego.hull_half[1]), float(layout.obstacle.hull_half[1]))  # [m]
        if cfg.margin > half:  # 0.3 m is a full-size car's (a third of our car's half width)
            raise ValueError(f"RiskConfig.margin={cfg.margin:g} m is more than half the narrower car's width "
                             f"({half:.3g} m): boxes widened by it collide where the cars pass well apart; for "
                             "a testbed at another scale, scale the configs with the cars (cdf_mj.scaled("
                             f"config, {2 * half / CarGeometry.ours().width:.2g}): its width / our car's)")
        self.map: ConflictMap = conflict_map(layout, cfg.margin)
        self._layout = layout
        self._dt = dt
        self._steps = max(1, math.ceil(cfg.horizon / dt - 1e-9))
        self._defer = 1 + math.ceil(cfg.latency / dt - 1e-9)
        brake = self.ego_brake if self.ego_brake is not None else layout.ego.max_brake
        speed = context.nominal_speed
        self._nominal = (speed, context.speed_gain, layout.ego.max_accel, brake)
        need = self._defer * dt + speed / brake  # [s] to defer, then stop from v_nominal
        if cfg.horizon < need:
            raise ValueError(f"RiskConfig.horizon={cfg.horizon:g} s is shorter than the {need:.2f} s the ego "
                             f"needs to defer and then stop from {speed:g} m/s at {brake:g} m/s^2: collisions "
                             "after the horizon would go unseen; give a longer horizon, or, for a testbed at "
                             "another scale, its own nominal speed (cdf_mj.scaled scales the configs)")
        self.last = None

    def plans(self, ego_pose: np.ndarray, q: float | None = None) -> np.ndarray:
        """The ego's arc lengths [m] ``(3, K)`` at ticks ``1..K`` under GO, DEFER and BRAKE,
        from its pose (and its arc length ``q`` [m] on its route, if known)."""
        v_nom, gain, a_max, b = self._nominal
        q0 = self.map.ego_arc(ego_pose) if q is None else q
        return ego_plans(q0, max(float(ego_pose[3]), 0.0), v_nom, gain, a_max, b, self._defer, self._steps,
                         self._dt)

    def assess(self, ego_pose: np.ndarray, futures: Futures | np.ndarray, exact: bool = False) -> Assessment:
        """Collision probabilities of the plans for the predictor's hypotheses. Going on
        alone (``go``) is assessed with ``exact`` only: the rule needs it only together
        with the deferral, and it is the longest roll."""
        q = self.map.ego_arc(ego_pose)
        plans = self.plans(ego_pose, q)
        if isinstance(futures, Futures):
            lazy, gate = (-1, -1) if exact else (GO, DEFER)
            m = collision_masses(futures.weight, futures.s, futures.v, futures.accel, futures.v_max,
                                 futures.delay, plans, self._dt, self.map.ds, self.map.q_lo, self.map.q_hi,
                                 self.map.q_lo_ahead, lazy, gate)
        else:
            m = self._path_masses(plans, np.asarray(futures, dtype=float))
        return Assessment(deferred=_unit(m[_DEFERRED].sum()), brake=_unit(m[_BRAKES].sum()),
                          inside=self.map.inside(q), go=_unit(m[_GOES].sum()) if exact else math.nan)

    def _path_masses(self, plans: np.ndarray, path: np.ndarray) -> np.ndarray:
        """:func:`collision_masses` for one predicted obstacle path ``(K', 4)`` at ticks 1..K'."""
        k = min(len(path), plans.shape[1])
        out = np.zeros(1 << len(plans))
        if k == 0:
            return out
        lay, margin = self._layout, self.config.margin
        obstacle = widened(lay.obstacle, margin).footprint(path[:k])
        ego_car = widened(lay.ego, margin)
        mask = 0
        for p, q in enumerate(plans[:, :k]):
            if boxes_overlap(ego_car.footprint(route_poses(lay.route_ego, q, self.map.window)), obstacle).any():
                mask |= 1 << p
        out[mask] = 1.0
        return out

    def decide(self, predictor: Predictor, ego_pose: np.ndarray, braking: bool) -> bool:
        """Brake when the deferred risk reaches ``brake`` and braking now is no riskier (where
        every hypothesis collides whatever the ego does, braking at least lowers the speed).
        Once braking, release when that risk is below ``release``, or, inside the conflict
        zone, as soon as it is below the risk of staying (braking on): an ego stopped in
        the zone waits for whoever crosses it next. Where both are certain it brakes on."""
        a = self.last = self.assess(ego_pose, predictor.futures(self._defer))
        if braking:
            release = a.deferred < self.config.release or (a.inside and a.deferred < a.brake)
            return not release
        return a.deferred >= self.config.brake and a.brake <= a.deferred

    def values(self) -> dict[str, float]:
        """``risk``: this tick's probability of a collision made unavoidable by deferring."""
        return {"risk": self.last.deferred if self.last is not None else 0.0}



def rollout_assessment(pf: ParticleFilter, rule: RiskRule, ego_pose: np.ndarray,
                       rng: np.random.Generator) -> Assessment:
    """The reference for :meth:`RiskRule.assess` on a CDF filter: every particle rolled
    forward through the filter's own model (its observation draws with beta and line of
    sight, belief update, driver state machine with its departure hazard and mode jumps,
    process noise and bicycle) for the rule's horizon, once with the ego going on and once
    with it going on for the deferral and then braking (the same draws for both: ``rng``
    is copied), each tick tested for an overlap of the two widened collision boxes.

    Slow (a whole filter predict per rolled tick and plan, and a box test of every
    particle in NumPy; about 0.3 s a tick at N = 1000): for tests and for measuring
    how closely the compiled rule agrees (docs/DECISION.md). The filter is not changed;
    call it after the update of a tick, before the particles move on (where the rule
    reads them).
    """
    plans = rule.plans(ego_pose)
    layout = rule._layout
    ego_car = widened(layout.ego, rule.config.margin)
    state = rng.bit_generator.state
    hits = []
    for p in (GO, DEFER, BRAKE):
        sim = copy.copy(pf)
        sim.pose, sim.mode, sim.belief = pf.pose.copy(), pf.mode.copy(), pf.belief.copy()
        sim.has_belief, sim.intent, sim.theta = pf.has_belief.copy(), pf.intent.copy(), pf.theta.copy()
        sim.rng = np.random.Generator(type(rng.bit_generator)())
        sim.rng.bit_generator.state = state
        obstacle_car = widened(sim.obstacle, rule.config.margin)
        ego = route_poses(layout.route_ego, plans[p], rule.map.window)
        speed = np.diff(np.concatenate([[rule.map.ego_arc(ego_pose)], plans[p]])) / rule._dt
        ego[:, 3] = speed
        hit = np.zeros(sim.n, dtype=bool)
        current = np.asarray(ego_pose, dtype=float)
        for k in range(plans.shape[1]):
            sim.predict(np.stack([current, current]))  # the obstacle row is not read by predict
            current = ego[k]
            hit |= boxes_overlap(obstacle_car.footprint(sim.pose),
                                 np.broadcast_to(ego_car.footprint(current), (sim.n, 4, 2)))
        hits.append(hit)
    w = pf.weights
    go, deferred, brake = hits[0], hits[0] & hits[1], hits[2]
    return Assessment(go=float(w[go].sum()), deferred=float(w[deferred].sum()), brake=float(w[brake].sum()),
                      inside=rule.map.inside(rule.map.ego_arc(ego_pose)))
