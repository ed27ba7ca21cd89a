"""The two agents of a tick as units, on the package's scene (real MuJoCo, no mocks).

The ego agent (:class:`cdf_mj.scenario.ego_agent.EgoAgent`): a yes/no brake is held unless
the planner releases it, a command acts ``brake_latency`` ticks late, a graded command goes
through the jerk limiter, the sensor changes what the planner sees and never the truth, an
outside controller's acceleration is delayed too. The obstacle agent
(:class:`cdf_mj.scenario.obstacle_agent.ObstacleAgent`): its look and belief, a family
driver, the after-merge override. And the loop they make with the world is run_episode's.
"""

from __future__ import annotations

import inspect
import itertools
import math

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import DriverModel, Intent, Mode, ego_control
from cdf_mj.planners import Planner, make_planner
from cdf_mj.scenario.ego_agent import EgoAgent
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.obstacle_agent import ObstacleAgent
from cdf_mj.scenario.world import World
from cdf_mj.sim.visibility import ego_visible


class _BrakeOnce(Planner):
    """Says "brake" on one tick only (t = ``at`` [s]); ``releases`` whether it lets go."""

    name = "brake-once"

    def __init__(self, at: float, releases: bool) -> None:
        self.at, self._releases = at, releases

    @property
    def releases_brake(self) -> bool:
        return self._releases

    def brake(self, obs):
        return bool(abs(obs.t - self.at) < 1e-9)


class _FullBrakeAt(Planner):
    """A graded planner: no cap until ``at`` [s], the full brake from then on."""

    name = "full-brake-at"

    def __init__(self, at: float) -> None:
        self.at = at

    @property
    def graded(self) -> bool:
        return True

    def command(self, obs):
        return -math.inf if obs.t >= self.at - 1e-9 else math.inf


def _drive(scene, config, planner, seed=0, ticks=20):
    """Ticks of a world driven by an EgoAgent: (agent, [(t, acting, accel)])."""
    world = World(scene, config)
    world.reset(seed)
    ego = EgoAgent(world.layout, config, world.driver, planner)
    ego.reset(world.rng)
    out = []
    for _ in range(ticks):
        m = world.measure()
        controls = ego.act(m)
        out.append((m.t, ego.acting, float(controls[0])))
        world.step(controls)
    return ego, out


@pytest.mark.parametrize("releases", [False, True])
def test_a_yes_no_brake_is_held_unless_the_planner_releases_it(scene, releases):
    config = ScenarioConfig().with_values({"ego.follow": False})
    ego, ticks = _drive(scene, config, _BrakeOnce(at=0.5, releases=releases), seed=0, ticks=12)
    max_brake = scene.layout().ego.max_brake
    assert ego.brake_time == 0.5 and ego.deviated == 0.5
    acting = [a for _, a, _ in ticks]
    assert acting[:5] == [False] * 5 and acting[5]
    assert ticks[5][2] == -max_brake
    if releases:  # the next tick's "no" counts: back to the speed hold
        assert not any(acting[6:]) and ticks[6][2] > -max_brake
    else:  # its first yes holds to the end
        assert all(acting[5:]) and all(a == -max_brake for _, _, a in ticks[5:])


def test_a_command_acts_brake_latency_ticks_late(scene):
    config = ScenarioConfig().with_values({"ego.follow": False, "sensing.brake_latency": 3})
    ego, ticks = _drive(scene, config, _BrakeOnce(at=0.5, releases=False), seed=0, ticks=12)
    acting = [a for _, a, _ in ticks]
    assert ego.brake_time == 0.5  # the decision is on its own tick
    assert acting.index(True) == 5 + 3 and ego.deviated == pytest.approx(0.8)


def test_a_graded_command_goes_through_the_jerk_limiter(scene):
    config = ScenarioConfig().with_values({"ego.follow": False, "ego.jerk_limit": 10.0})
    ego, ticks = _drive(scene, config, _FullBrakeAt(at=0.3), seed=0, ticks=15)
    accel = [a for _, _, a in ticks]
    step = 10.0 * config.timing.dt  # [m/s^2] a tick at most
    assert all(abs(b - a) <= step + 1e-12 for a, b in itertools.pairwise(accel))
    max_brake = scene.layout().ego.max_brake
    assert accel[3] == pytest.approx(accel[2] - step) and accel[-1] == -max_brake
    assert ego.brake_time == pytest.approx(0.3)


def test_the_sensor_changes_what_the_ego_sees_not_the_truth(scene):
    config = ScenarioConfig().with_values({"sensing.pos": 0.5, "sensing.heading": 0.05, "sensing.speed": 0.5})
    world = World(scene, config)
    m = world.reset(2)
    truth = m.poses.copy()
    ego = EgoAgent(world.layout, config, world.driver)
    ego.reset(world.rng)
    seen = ego.sense(m)
    assert seen.t == m.t and np.array_equal(seen.poses[0], truth[0])  # its own pose is exact
    assert not np.array_equal(seen.poses[1], truth[1]) and np.all(np.isfinite(seen.poses[1]))
    assert np.array_equal(m.poses, truth)  # the world's measurement is untouched
    perfect = EgoAgent(world.layout, ScenarioConfig(), world.driver)
    perfect.reset(world.rng)
    assert perfect.sense(m).poses is m.poses  # perfect sensing passes the truth through


def test_an_outside_controllers_acceleration_is_delayed_its_steering_not(scene):
    config = ScenarioConfig().with_values({"sensing.brake_latency": 2})
    world = World(scene, config)
    m = world.reset(0)
    ego = EgoAgent(world.layout, config, world.driver)
    with pytest.raises(RuntimeError, match="reset"):
        ego.drive(1.0, 0.0)
    ego.reset(world.rng)
    applied = []
    for k in range(5):
        ego.sense(m)
        nominal = float(ego_control(world.driver, world.layout.ego, m.poses[0], False)[0])
        controls = ego.drive(-1.0 - k, 0.01 * k)
        applied.append((controls.tolist(), nominal))
        world.step(controls)
        m = world.measure()
    assert [c[0] for c, _ in applied[:2]] == [n for _, n in applied[:2]]  # the speed hold until it arrives
    assert [c[0] for c, _ in applied[2:]] == [-1.0, -2.0, -3.0]
    assert [c[1] for c, _ in applied] == [0.01 * k for k in range(5)]
    with pytest.raises(RuntimeError, match="planner"):
        ego.act(m)


def test_a_planners_answer_that_is_not_a_bool_is_refused(scene):
    class Yes(Planner):
        name = "yes"

        def brake(self, obs):
            return "yes"

    world = World(scene)
    m = world.reset(0)
    ego = EgoAgent(world.layout, world.config, world.driver, Yes())
    ego.reset(world.rng)
    with pytest.raises(TypeError, match=r"planner 'yes' \(Yes.brake\) returned 'yes'"):
        ego.act(m)


def _obstacle(scene, values=None, intent=Intent.LEFT, seed=0):
    """An ObstacleAgent on a reset scene (the ego at its start), and the tick's poses."""
    config = ScenarioConfig().with_values(values or {})
    layout = scene.layout()
    agent = ObstacleAgent(scene, config, DriverModel.of_world(layout, config))
    rng = {"after_merge": np.random.default_rng(seed), "driver": np.random.default_rng(seed + 1)}
    start = agent.reset(intent, dwell=1.0, hesitates=False, hesitation_pause=0.0, rng=rng)
    scene.reset(ego=np.array([*layout.ego_start[:3], config.ego.speed]), obstacle=start)
    return agent, scene.poses(), scene.pose_values(), start


def test_the_obstacle_looks_with_probability_beta_and_believes_what_it_saw(scene):
    z = [1.0, -1.0, 0.5, 2.0, 0.0, 0.0]
    agent, poses, values, _ = _obstacle(scene, {"obstacle.beta": 0.3})
    scene.sync()
    assert ego_visible(scene)  # in its line of sight at the start
    agent.act(0.0, poses, values, False, u_look=0.5, z=z, u_depart=1.0)  # 0.5 > beta: no look
    assert not agent.observed and not agent.seen and agent.first_seen is None
    assert agent.belief.tolist() == [0.0] * 4 and agent.mode == Mode.WAITING
    agent.act(0.1, poses, values, False, u_look=0.1, z=z, u_depart=1.0)  # it looks and sees
    seen = agent.config.observation
    std = [seen.pos, seen.pos, seen.heading, seen.speed]
    assert agent.observed and agent.seen and agent.first_seen == 0.1
    np.testing.assert_allclose(agent.belief, [v + zi * s for v, zi, s in zip(values[0], z, std, strict=False)])


def test_a_family_driver_starts_where_it_draws_and_acts_from_its_own_stream(scene):
    controls, starts = [], []
    for _ in range(2):
        agent, poses, values, start = _obstacle(scene, {"obstacle.family": "rolling-stop"}, seed=5)
        starts.append(start.tolist())
        controls.append(agent.act(0.0, poses, values, False, u_look=0.9, z=[0.0] * 6, u_depart=0.9))
    assert starts[0] == starts[1] and controls[0] == controls[1]
    assert starts[0] != scene.layout().obstacle_start.tolist()  # it comes down the side road, moving
    assert starts[0][3] > 0.0 and all(isinstance(c, float) for c in controls[0])
    assert agent.family is not None and agent.mode == int(agent.family.mode)
    assert agent.seen == (agent.first_seen is not None)


def test_after_merge_stop_overrides_the_acceleration_in_the_lane_only(scene):
    agent, poses, values, _ = _obstacle(scene, {"after_merge.behaviour": "stop", "after_merge.follows": False})
    free, _ = agent.act(0.0, poses, values, False, u_look=0.9, z=[0.0] * 6, u_depart=0.9)
    assert agent.after_merge.active_since is None
    merged, _ = agent.act(0.1, poses, values, True, u_look=0.9, z=[0.0] * 6, u_depart=0.9)
    assert merged == -agent.after_merge.params["brake"] and agent.after_merge.active_since == 0.1
    assert free != merged


@pytest.mark.parametrize("planner", ["cdf", "reactive"])
def test_measure_act_step_is_run_episodes_loop(scene, planner):
    """The episode loop, written out: the world measures, the ego acts, the world steps."""
    config = ScenarioConfig()
    rec = run_episode(config, seed=1, planner=planner, scene=scene, label=False)
    world = World(scene, config)
    world.reset(1)
    ego = EgoAgent(world.layout, config, world.driver, make_planner(planner))
    ego.reset(world.rng)
    while not world.done:
        world.step(ego.act(world.measure()))
    assert (ego.brake_time, world.min_gap, world.end_time) == (rec.brake_time, rec.min_gap, rec.end_time)
    assert (world.collision, world.first_seen, world.yielded) == (rec.collision_with, rec.first_seen_time, rec.yielded)


@pytest.mark.parametrize("method", [World.step, EgoAgent.act, ObstacleAgent.act])
def test_each_half_of_a_tick_reads_on_one_screen(method):
    assert len(inspect.getsource(method).splitlines()) <= 45
