"""The reference for the risk rule's compiled rolls: :func:`rollout_assessment` rolls every
particle of a CDF filter forward through the filter's own model, in NumPy.

Slow (about 0.3 s a tick at N = 1000), for tests and for measuring how closely the
compiled rule (:meth:`cdf_mj.planners.decision.RiskRule.assess`) agrees
(``scripts/risk_agreement.py``, docs/DECISION.md). Kept apart from the rules so that
importing them loads no filter. ::

    from cdf_mj.planners.rollout_reference import rollout_assessment
    slow = rollout_assessment(pf, rule, ego_pose, np.random.default_rng(0))

Frames and units: world frame, metres, seconds; probabilities in [0, 1].
"""

from __future__ import annotations

import copy

import numpy as np

from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.model.conflict import BRAKE, DEFER, GO, route_poses, widened
from cdf_mj.model.geometry import boxes_overlap
from cdf_mj.planners.decision import Assessment, RiskRule

__all__ = ["rollout_assessment"]


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
