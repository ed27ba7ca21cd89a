"""The compiled baselines (cdf_mj/planners/baseline_kernels.py) against the code they replace.

- The compiled IMM against filterpy's ``IMMEstimator`` over ``RouteKalmanFilter`` (an
  :class:`IMMPlanner` with ``reference = True``): whole episodes of ``imm``, ``imm-risk`` and
  ``imm-layered`` on the default scene and a rotated, mirrored user junction, with
  perfect and with noisy sensing that drops measurements; every tick the per-intent states,
  covariances and mode probabilities agree within 1e-9 and the records are the same.
- The compiled paths (route, straight line), the first overlap and the risk rule's path
  test (``RiskRule._path_masses``) against the NumPy code, on random states and paths:
  the same points and speeds, headings within 1e-14 rad (libm's atan2 against NumPy's
  arctan2), the same conflicts and masks.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.conflict import route_poses, widened
from cdf_mj.model.driver import Intent
from cdf_mj.model.geometry import boxes_overlap
from cdf_mj.planners import make_planner
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.baseline_common import first_conflict, straight_path
from cdf_mj.planners.cv import CVPlanner
from cdf_mj.planners.decision import LayeredRule, RiskRule
from cdf_mj.planners.imm import IMMConfig, IMMPlanner, _imm_model
from cdf_mj.scenario.episode import run_episode
from tests.junctions import junction_scene

TOL = 1e-9
NOISY = ScenarioConfig(sensing={"pos": 0.3, "heading": 0.05, "speed": 0.3, "dropout": 0.2})


@pytest.fixture(scope="module")
def junction():
    """A user junction: rotated, mirrored (left-hand traffic), 3.2 m lanes."""
    return junction_scene(rotation=2.1, mirror=True, lane_width=3.2)


def _probed(name: str, reference: bool) -> tuple[IMMPlanner, list]:
    """Planner ``name`` running the compiled IMM or filterpy's, keeping its estimates each tick."""
    planner = make_planner(name)
    assert isinstance(planner, IMMPlanner)
    planner.reference = reference
    ticks: list = []
    observe = planner.observe

    def probe(obs):
        observe(obs)
        ticks.append(planner.estimates() if planner.imm is not None else None)

    planner.observe = probe  # type: ignore[method-assign]
    return planner, ticks


@pytest.mark.parametrize("where", ["default", "junction"])
def test_compiled_imm_matches_filterpy(where, scene, junction):
    world = scene if where == "default" else junction
    runs = 0
    for name in ("imm", "imm-risk", "imm-layered"):
        for config, seed in ((None, 1), (None, 3), (NOISY, 4)):
            compiled, ours = _probed(name, reference=False)
            reference, theirs = _probed(name, reference=True)
            a = run_episode(config, seed, compiled, world, label=False).to_dict()
            b = run_episode(config, seed, reference, world, label=False).to_dict()
            assert a == b, (name, seed)
            assert len(ours) == len(theirs) > 0
            for mine, ref in zip(ours, theirs, strict=True):
                assert (mine is None) == (ref is None)
                if mine is not None:
                    for got, want in zip(mine, ref, strict=True):  # x (2, 3), P (2, 3, 3), mu (2,)
                        np.testing.assert_allclose(got, want, rtol=TOL, atol=TOL)
            runs += sum(m is not None for m in ours)
            assert type(reference.imm).__name__ == "IMMEstimator"
    assert runs > 300


def test_compiled_paths_match_numpy(scene):
    layout = scene.layout()
    planner = IMMPlanner()
    planner.reset(PlannerContext.of(layout, ScenarioConfig()), np.random.default_rng(0))
    reference = IMMPlanner()
    reference.reference = True
    reference.reset(PlannerContext.of(layout, ScenarioConfig()), np.random.default_rng(0))
    rng = np.random.default_rng(5)
    for _ in range(200):
        pose = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-math.pi, math.pi), rng.uniform(0, 10)])
        reference.imm = reference._start(pose)
        planner.imm = planner._start(pose)
        # A state anywhere along the routes, past their ends too.
        state = np.array([rng.uniform(-5, 170), rng.uniform(-1, 12), rng.uniform(-6, 4)])
        for i, f in enumerate(reference.imm.filters):
            f.x = state[:, None] + i
            planner.imm.x[i] = state + i
        for intent in (Intent.LEFT, Intent.RIGHT):
            got, want = planner.predicted_path(intent), reference.predicted_path(intent)
            np.testing.assert_array_equal(got[:, [0, 1, 3]], want[:, [0, 1, 3]])  # the same operations
            # The headings: libm's atan2 against NumPy's arctan2 (SIMD), which may differ in the last bit.
            np.testing.assert_allclose(got[:, 2], want[:, 2], rtol=0, atol=1e-14)
        ego = np.array([*rng.uniform(-30, 10, 2), rng.uniform(-0.3, 0.3), rng.uniform(0, 14)])
        assert planner.conflict_probability(ego) == reference.conflict_probability(ego)
    F, Q, R = _imm_model(0.1, IMMConfig())
    kf = reference.imm.filters[0]
    assert (F == kf.F).all() and (Q == kf.Q).all() and (R == kf.R).all()


def test_straight_conflict_matches_numpy(scene):
    layout = scene.layout()
    planner = CVPlanner()
    planner.reset(PlannerContext.of(layout, ScenarioConfig()), np.random.default_rng(0))
    rng = np.random.default_rng(6)
    hits = 0
    for _ in range(500):
        poses = np.array([[*rng.uniform(-25, 5, 2), rng.uniform(-0.5, 0.5), rng.uniform(0, 14)],
                          [*rng.uniform(-10, 10, 2), rng.uniform(-math.pi, math.pi), rng.uniform(0, 10)]])
        want = first_conflict(layout.ego, layout.obstacle, straight_path(poses[0], planner._times),
                              straight_path(poses[1], planner._times), planner.params.margin, planner._dt)
        assert planner.time_to_conflict(poses) == want
        hits += want is not None
    assert 20 < hits < 480  # both answers, many times


def _numpy_path_masses(rule: RiskRule, plans: np.ndarray, path: np.ndarray) -> np.ndarray:
    """``RiskRule._path_masses`` as it was before the compiled kernel (NumPy)."""
    k = min(len(path), plans.shape[1])
    out = np.zeros(1 << len(plans))
    if k == 0:
        return out
    lay, margin = rule._layout, rule.config.margin
    obstacle = widened(lay.obstacle, margin).footprint(path[:k])
    ego_car = widened(lay.ego, margin)
    mask = 0
    for p, q in enumerate(plans[:, :k]):
        if boxes_overlap(ego_car.footprint(route_poses(lay.route_ego, q, rule.map.window)), obstacle).any():
            mask |= 1 << p
    out[mask] = 1.0
    return out


@pytest.mark.parametrize("where", ["default", "junction"])
def test_path_masses_match_numpy(where, scene, junction):
    layout = (scene if where == "default" else junction).layout()
    context = PlannerContext.of(layout, ScenarioConfig())
    rules = [RiskRule(), LayeredRule()]
    for rule in rules:
        rule.reset(context)
    left, ego_route = layout.route_left, layout.route_ego
    rng = np.random.default_rng(7)
    seen = set()
    for trial in range(1000):
        rule = rules[trial % 2]
        # The ego somewhere on its route (past its end too), its plans from its speed.
        q0 = rng.uniform(0.0, ego_route.length + 20.0) if trial % 10 else rng.uniform(0, 1) * ego_route.length
        pose = np.array([*ego_route.point_at(min(q0, ego_route.length)), 0.0, rng.uniform(0, 14)])
        plans = rule.plans(pose, q0)
        # The obstacle on a straight line through a point of its left route, or along that route.
        s = rng.uniform(0.0, 40.0)
        x, y = left.point_at(s)
        th = rng.uniform(-math.pi, math.pi)
        steps = int(rng.integers(0, plans.shape[1] + 5))
        path = straight_path(np.array([x, y, th, rng.uniform(0, 10)]), (np.arange(steps) + 1) * 0.1)
        if trial % 3 == 0:  # along the route
            arc = s + np.arange(steps) * rng.uniform(0, 1)
            path = route_poses(left, arc)
        mask = np.flatnonzero(rule._path_masses(plans, path))
        want = np.flatnonzero(_numpy_path_masses(rule, plans, path))
        assert mask.tolist() == want.tolist(), trial
        seen.update(mask.tolist())  # empty for an empty path
    assert len(seen) >= 4  # several different masks, not only "no collision"


def test_poses_and_paths_of_the_wrong_shape_are_one_clear_error(scene):
    """The compiled calls read their arrays unchecked: a pose or a path of another shape is
    refused before them, in one line (not broadcast, not read out of bounds)."""
    context = PlannerContext.of(scene.layout(), ScenarioConfig())
    cv = make_planner("cv")
    cv.reset(context, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"must be \(2, 4\) rows.*got shape \(4,\)"):
        cv.time_to_conflict(np.zeros(4))
    rule = RiskRule()
    rule.reset(context)
    ego = scene.layout().ego_start.copy()
    with pytest.raises(ValueError, match=r"must be \(K, 4\) rows.*got shape \(10, 2\)"):
        rule.assess(ego, np.zeros((10, 2)))
