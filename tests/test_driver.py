"""The obstacle driver and the ego controller: routes followed, yield vs cut-off, belief."""

from __future__ import annotations

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import (
    DriverModel,
    Intent,
    Mode,
    obstacle_control,
    obstacle_control_one,
    road_clear,
    update_belief,
    update_belief_one,
)
from cdf_mj.records import Label
from cdf_mj.scenario.episode import run_episode


def test_routes_are_followed_into_their_lanes(scene):
    """Obstacle that never sees the ego (beta = 0): the left-turner ends in the ego's lane
    heading east, the right-turner in the far lane heading west; the ego keeps its lane."""
    far_ego = ScenarioConfig(obstacle={"beta": 0.0}, ego={"start_spread": (-105.0, -105.0)}, timing={"duration": 8.0})
    for p_left, lane_y, heading in ((1.0, -1.85, 0.0), (0.0, 1.85, np.pi)):
        rec = run_episode(far_ego.replace(obstacle={"p_left": p_left}), seed=1, planner="constant",
                          scene=scene, label=False, trace=True)
        assert not rec.collision
        poses = np.array(rec.trace["poses"])
        obs_end, ego_all = poses[-1, 1], poses[:, 0]
        assert obs_end[1] == pytest.approx(lane_y, abs=0.3)
        assert np.cos(obs_end[2] - heading) > np.cos(0.05)
        assert np.abs(ego_all[:, 1] + 1.85).max() < 0.2  # ego lane centre y = -1.85
        # The right-turner never puts any part of itself into the ego lane.
        assert (rec.entered_lane_time is None) == (p_left == 0.0)


def test_obstacle_yields_when_it_sees_the_ego_in_time(scene):
    """beta = 1: the ego is visible from the start, so a left-turner sees it at once,
    never enters the ego lane before the ego has passed, and the episode is a Yield."""
    cfg = ScenarioConfig(obstacle={"beta": 1.0, "p_left": 1.0})
    rec = run_episode(cfg, seed=3, planner="constant", scene=scene, trace=True)
    assert rec.first_seen_time == 0.0
    assert rec.yielded
    assert rec.label == Label.YIELD and not rec.collision
    modes = rec.trace["mode"]
    assert Mode.COMMITTED not in modes[:20]  # still waiting while the ego approaches


def test_obstacle_cuts_off_when_it_never_sees_the_ego(scene):
    cfg = ScenarioConfig(obstacle={"beta": 0.0, "p_left": 1.0})
    for seed in range(5):
        rec = run_episode(cfg, seed=seed, planner="constant", scene=scene)
        assert rec.first_seen_time is None and not rec.yielded
        assert rec.entered_lane_time is not None
        assert rec.label == Label.CUTOFF and rec.collision_with == "obstacle"


def test_vectorised_controller_equals_one_at_a_time(scene):
    """The same function drives one obstacle and N particles: rows are independent."""
    model = DriverModel.of_world(scene.layout(), ScenarioConfig())
    rng = np.random.default_rng(0)
    n = 64
    pose = np.column_stack([rng.uniform(-4, 2, n), rng.uniform(-2, 8.5, n),
                            rng.uniform(-np.pi, np.pi, n), rng.uniform(0, 8, n)])
    mode = rng.integers(0, 4, n)
    belief = np.column_stack([rng.uniform(-60, 10, n), np.full(n, -1.85), np.zeros(n),
                              rng.uniform(5, 15, n)])
    has = rng.random(n) < 0.5
    intent = rng.integers(0, 2, n)
    u, new = obstacle_control(model, pose, mode, belief, has, intent)
    assert u.shape == (n, 2) and new.shape == (n,)
    for i in range(n):
        ui, ni = obstacle_control(model, pose[i:i + 1], mode[i:i + 1], belief[i:i + 1],
                                  has[i:i + 1], intent[i:i + 1])
        np.testing.assert_allclose(ui[0], u[i])
        assert ni[0] == new[i]
        # The world car's per-tick call, on Python numbers: the same numbers exactly.
        a, steer, m, _ = obstacle_control_one(model, pose[i].tolist(), int(mode[i]), belief[i].tolist(),
                                              bool(has[i]), int(intent[i]), True)
        assert [a, steer, m] == [*u[i].tolist(), int(new[i])]


def test_mode_transitions(scene):
    model = DriverModel.of_world(scene.layout(), ScenarioConfig())
    start = scene.layout().obstacle_start[None]
    near_ego = np.array([[-30.0, -1.85, 0.0, 13.4]])  # ~2.4 s from the conflict point
    left, right = np.array([Intent.LEFT]), np.array([Intent.RIGHT])
    waiting = np.array([Mode.WAITING])
    # Never seen: go. Seen close: wait. Right-turners do not cross the ego's lane: go.
    assert obstacle_control(model, start, waiting, near_ego, np.array([False]), left)[1][0] == Mode.GOING
    u, m = obstacle_control(model, start, waiting, near_ego, np.array([True]), left)
    assert m[0] == Mode.WAITING and u[0, 0] < 0
    assert obstacle_control(model, start, waiting, near_ego, np.array([True]), right)[1][0] == Mode.GOING
    # Going and then seeing the ego: yield, unless past the commit point.
    going = np.array([Mode.GOING])
    assert obstacle_control(model, start, going, near_ego, np.array([True]), left)[1][0] == Mode.YIELDING
    s_commit = model.s_commit[Intent.LEFT]
    past = model.routes[Intent.LEFT].point_at(s_commit + 0.5)
    pose_past = np.array([[past[0], past[1], -np.pi / 2, 3.0]])
    assert obstacle_control(model, pose_past, going, near_ego, np.array([True]), left)[1][0] == Mode.COMMITTED
    # A believed ego that has passed the conflict point clears the road.
    gone = np.array([[20.0, -1.85, 0.0, 13.4]])
    assert road_clear(model, gone, np.array([True]), left)[0]


def test_mode_and_intent_are_the_shared_vocabulary():
    """Mode and Intent live in cdf_mj.model.modes (which the world's driver families read
    without loading the filter); this module re-exports them and the kernels read their ints."""
    from cdf_mj.model import modes

    assert Mode is modes.Mode and Intent is modes.Intent
    assert (modes.WAITING, modes.GOING, modes.YIELDING, modes.COMMITTED) == tuple(Mode) == (0, 1, 2, 3)
    assert (modes.LEFT, modes.RIGHT) == tuple(Intent) == (0, 1)


def test_belief_update_takes_observation_or_dead_reckons():
    dt, wheelbase = 0.1, 2.7
    belief = np.array([[0.0, 0.0, 0.0, 10.0], [5.0, 1.0, np.pi / 2, 2.0], [0.0, 0.0, 0.0, 0.0]])
    has = np.array([True, True, False])
    observed = np.array([False, True, False])
    obs = np.array([[9.0, 9.0, 9.0, 9.0]] * 3)
    new, new_has = update_belief(belief, has, observed, obs, dt, wheelbase)
    np.testing.assert_allclose(new[0], [1.0, 0.0, 0.0, 10.0])  # carried forward v * dt
    np.testing.assert_allclose(new[1], obs[1])  # replaced
    np.testing.assert_allclose(new[2], belief[2])  # still nothing
    assert new_has.tolist() == [True, True, False]
    for i in range(3):  # one driver in place: the same rows
        one, one_has = belief[i:i + 1].copy(), has[i:i + 1].copy()
        update_belief_one(one, one_has, obs[i] if observed[i] else None, dt)
        assert one[0].tolist() == new[i].tolist() and bool(one_has[0]) == bool(new_has[i])
