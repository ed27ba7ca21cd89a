"""Ego-side occlusion (``sensing.occluded``): the ego measures the other car only while its
sensor mount sees it past the buildings (MuJoCo rays), and every planner copes with not
seeing it.

Real episodes on the package's scene, no mocks. In the default world the corner buildings
let the ego see a car waiting at the stop line from its start (60-80 % of its sight
points), so occlusion changes nothing there but the count; a ``rolling-stop`` driver starts
10-20 m up the side road, out of the ego's sight for its first 1-2 s. The filter's
negative information (a hypothesis in the ego's sight that is not measured loses weight)
is tested on hypotheses placed by hand, and on episodes.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cdf_mj.config import CDFConfig, ScenarioConfig, Sensing
from cdf_mj.inference.particle_filter import MISS_PROBABILITY, ParticleFilter
from cdf_mj.model.modes import GOING, WAITING
from cdf_mj.planners.base import PlannerContext, PlannerInput
from cdf_mj.planners.cv import COAST_TIME
from cdf_mj.planners.registry import PLANNERS, make_planner
from cdf_mj.scenario.ego_agent import EgoAgent
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.sensing import Sensor
from cdf_mj.scenario.world import World
from cdf_mj.sim.visibility import visible_share

OCCLUDED = {"sensing.occluded": True}
ROLLING = {"obstacle.family": "rolling-stop"}  # starts up the side road, out of the ego's sight
N = 300  # particles: enough for the weights' sums below, fast
NAN = np.full(4, np.nan)
EGO = np.array([-40.8, -1.85, 0.0, 13.4])  # the ego at its start site [x m, y m, theta rad, v m/s]
SOUTH = -math.pi / 2
IN_SIGHT = np.array([-1.85, 8.35, SOUTH, 0.0])  # waiting at the stop line: the ego sees its front
HIDDEN = np.array([-1.85, 25.0, SOUTH, 0.0])  # up the side road, behind the corner buildings


def _run(scene, values, seed=3, planner="cdf", **kwargs):
    return run_episode(ScenarioConfig().with_values(values), seed, planner, scene, **kwargs)


def _filter(scene, occluded: bool, seed: int = 0) -> ParticleFilter:
    return ParticleFilter.from_layout(scene.layout(), CDFConfig(n_particles=N), np.random.default_rng(seed), 0.1,
                                      occluded=occluded)


# ---------------------------------------------------------------------------- the option
def test_occluded_is_off_by_default_a_bool_and_never_perfect():
    assert ScenarioConfig().sensing.occluded is False and ScenarioConfig().sensing.perfect
    assert not Sensing(occluded=True).perfect
    assert ScenarioConfig().with_values(OCCLUDED).sensing.occluded is True
    with pytest.raises(ValueError, match=r"sensing\.occluded"):
        Sensing(occluded=1)


def test_the_world_casts_the_egos_sight_only_when_occluded(scene):
    """``Measurement.visible`` is MuJoCo's share of the obstacle's sight points that the ego's
    eye sees, cast only where the sensing is occluded."""
    assert math.isnan(World(scene, ScenarioConfig()).reset(0).visible)
    m = World(scene, ScenarioConfig().with_values(OCCLUDED)).reset(0)
    assert m.visible == visible_share(scene, "ego", "obstacle", m.poses[0], m.poses[1])
    assert 0.4 <= m.visible <= 1.0  # the corner buildings show most of a car at the stop line
    assert World(scene, ScenarioConfig().with_values(OCCLUDED | ROLLING)).reset(0).visible == 0.0


# ---------------------------------------------------------------------------- the sensor
def test_the_sensor_drops_a_car_out_of_sight_latency_ticks_back(scene):
    sensor = Sensor(Sensing(occluded=True, latency=1), scene.layout(), np.random.default_rng(0))
    poses = [np.array([EGO + np.array([k, 0, 0, 0]), IN_SIGHT - np.array([0, k, 0, 0])]) for k in range(3)]
    out0, lane0 = sensor.sense(poses[0], True, 0.0)  # out of sight now
    out1, _ = sensor.sense(poses[1], False, 0.6)  # in sight now, but the measurement is tick 0's
    out2, _ = sensor.sense(poses[2], False, 0.6)  # tick 1's: in sight
    assert np.isnan(out0[1]).all() and np.isnan(out1[1]).all() and not lane0
    assert out2[1].tolist() == poses[1][1].tolist() and out2[0].tolist() == poses[2][0].tolist()
    assert (sensor.occluded, sensor.dropped) == (2, 0)
    fresh = Sensor(Sensing(occluded=True), scene.layout(), np.random.default_rng(0))
    for bad in (math.nan, -0.1, 1.5):  # not cast, or not a share: refused, never a silently blind ego
        with pytest.raises(ValueError, match="visible="):
            fresh.sense(poses[0], False, bad)


def test_occlusion_draws_what_the_sensor_always_draws(scene):
    """With noise and dropouts, the occluded sensor gives exactly the plain sensor's
    measurement on every tick the car is in sight (the same draws per seed); a hidden tick
    is counted as occluded, a dropout of a car in sight as dropped."""
    kw = {"pos": 0.3, "speed": 0.2, "dropout": 0.3}
    plain = Sensor(Sensing(**kw), scene.layout(), np.random.default_rng(5))
    occluded = Sensor(Sensing(**kw, occluded=True), scene.layout(), np.random.default_rng(5))
    sight = [0.0, 0.2, 1.0, 0.0, 0.0, 0.6, 0.4, 0.0, 1.0, 0.8] * 3
    poses = np.array([EGO, IN_SIGHT])
    dropped = 0
    for share in sight:
        a, _ = plain.sense(poses, False, share)
        b, _ = occluded.sense(poses, False, share)
        if share > 0.0:
            np.testing.assert_array_equal(a, b)  # NaN where both dropped it
            dropped += int(np.isnan(a[1]).all())
        else:
            assert np.isnan(b[1]).all() and np.isfinite(b[0]).all()
    assert occluded.occluded == sight.count(0.0) and occluded.dropped == dropped > 0


# ---------------------------------------------------------------------------- episodes
def test_an_occluded_episode_counts_the_hidden_ticks_and_keeps_the_truth(scene):
    """The world's truth (poses, modes, label) is the same with the ego's sensor occluded;
    the record counts the ticks the car was out of the ego's sight (``world["occluded"]``)."""
    still = {"ego.follow": False}
    base = _run(scene, ROLLING | still, planner="constant", trace=True)
    hidden = _run(scene, ROLLING | still | OCCLUDED, planner="constant", trace=True)
    assert hidden.trace == base.trace and hidden.label == base.label and "occluded" not in base.world
    # The count is the ticks at whose start the ego's eye saw none of the car.
    cfg = ScenarioConfig().with_values(ROLLING | still | OCCLUDED)
    world = World(scene, cfg)
    world.reset(3)
    ego = EgoAgent(world.layout, cfg, world.driver, make_planner("constant"))
    ego.reset(world.rng)
    out_of_sight = 0
    while not world.done:
        m = world.measure()
        out_of_sight += m.visible == 0.0
        world.step(ego.act(m))
    assert hidden.world["occluded"] == out_of_sight >= 5 and hidden.world["dropped"] == 0


@pytest.mark.parametrize("planner", ["cdf", "imm-layered", "cv-layered", "caution-phantom", "reactive"])
def test_where_the_ego_always_sees_the_car_occlusion_changes_nothing(scene, planner):
    """In the default world the car is in the ego's sight on every tick: an occluded ego's
    records are the full observation's, but for the count (0) and the filter's."""
    for seed in (0, 1):
        full = _run(scene, {}, seed, planner, trace=True).to_dict()
        occluded = _run(scene, OCCLUDED, seed, planner, trace=True).to_dict()
        assert occluded["world"].pop("occluded") == 0 and occluded["world"].pop("dropped") == 0
        assert occluded["planner_info"].pop("unseen_updates", 0) == 0
        assert json.dumps(occluded, sort_keys=True) == json.dumps(full, sort_keys=True)


@pytest.mark.parametrize("planner", sorted(PLANNERS))
def test_every_planner_copes_with_a_car_out_of_sight(scene, planner):
    rec = _run(scene, ROLLING | OCCLUDED, seed=140, planner=planner, label=False)
    assert rec.world["occluded"] > 0 and rec.end_time > 0.0


def test_the_cdf_reads_not_seeing_as_information(scene):
    """Its filter starts before the first sight, on hypotheses of a car coming unseen down
    the side road (P(cutoff) > 0 at once, where a filter that waits for the first
    measurement has none), and weighs every later tick out of sight."""
    rec = _run(scene, ROLLING | OCCLUDED)
    info, hidden = rec.planner_info, rec.world["occluded"]
    assert info["unseen_updates"] == info["skipped_updates"] == hidden - 1  # the first tick starts the filter
    assert info["history"]["p_cutoff"][0] > 0.5
    dropout = _run(scene, ROLLING | {"sensing.dropout": 1e-9})  # imperfect, never dropped: the same sensor draws
    assert dropout.planner_info["history"]["p_cutoff"][0] < 0.5


# ---------------------------------------------------------------------------- the filter
def test_not_seeing_the_car_weighs_down_the_hypotheses_the_ego_would_see(scene):
    """Half the particles in the ego's sight, half hidden: a tick without a measurement
    leaves the hidden ones ``1 / (1 + miss)`` of the weight; without an occluded sensor
    it leaves the weights alone. The 2D sight model agrees with MuJoCo's rays here."""
    for pose, seen in ((HIDDEN, False), (IN_SIGHT, True)):
        scene.reset(ego=EGO, obstacle=pose)
        assert (visible_share(scene, "ego", "obstacle") > 0.0) == seen
    half = N // 2
    weights = {}
    for occluded in (True, False):
        pf = _filter(scene, occluded)
        pf.reset(np.stack([EGO, IN_SIGHT]))
        pose = pf.pose.copy()
        pose[:half] = HIDDEN
        pf.pose = pose
        assert pf.in_sight().tolist() == [False] * half + [True] * (N - half)
        post = pf.weigh(np.stack([EGO, NAN]))
        weights[occluded] = pf.weights.copy()
        assert pf.skipped_updates == 1 and pf.unseen_updates == int(occluded)
        assert 1.0 <= post.ess <= N
    assert weights[True][:half].sum() == pytest.approx(1.0 / (1.0 + MISS_PROBABILITY))
    np.testing.assert_allclose(weights[False], 1.0 / N)


def test_an_occluded_filter_starts_where_the_ego_cannot_see(scene):
    """Unseen at the start: the hypotheses come down the side road's hidden approach (the
    stop line is in sight from the ego's start); with the whole approach in sight they all
    wait at the stop line. A filter whose sensor sees through buildings refuses a NaN start."""
    pf = _filter(scene, True)
    post = pf.reset(np.stack([EGO, NAN]))
    assert not pf.in_sight().any() and (pf.mode == GOING).all()
    assert np.allclose(pf.pose[:, 0], IN_SIGHT[0]) and (pf.pose[:, 1] > IN_SIGHT[1]).all()
    assert (pf.pose[:, 3] >= 0.0).all() and 0.0 < post.p_cutoff <= 1.0
    near = np.array([-3.0, -1.85, 0.0, 5.0])  # at the junction: the ego sees up the side road
    pf.reset(np.stack([near, NAN]))
    assert (pf.mode == WAITING).all() and np.allclose(pf.pose, pf.waiting_pose())
    with pytest.raises(ValueError, match="finite"):
        _filter(scene, False).reset(np.stack([EGO, NAN]))


# ---------------------------------------------------------------------------- the others
def test_the_monitor_reads_nan_as_not_seeing_when_its_ego_is_occluded(scene):
    layout = scene.layout()
    scenario = ScenarioConfig().with_values(OCCLUDED)
    occluded = CDFMonitor(layout, scenario, CDFConfig(n_particles=N), rng=0, record_trace=False)
    plain = CDFMonitor(layout, ScenarioConfig(), CDFConfig(n_particles=N), rng=0, record_trace=False)
    assert occluded.filter.occluded and not plain.filter.occluded
    ego = EGO.copy()
    for k in range(10):
        d_occluded, d_plain = occluded.observe(0.1 * k, ego, NAN), plain.observe(0.1 * k, ego, NAN)
        ego[0] += 0.1 * ego[3]
    assert d_plain.posterior is not None and d_plain.posterior.p_cutoff == 0.0  # waits for a measurement
    assert d_occluded.posterior is not None and d_occluded.posterior.p_cutoff > 0.0
    assert occluded.filter.unseen_updates == 9 and plain.filter.unseen_updates == 0


def test_cv_coasts_its_track_out_of_sight_then_drops_it(scene):
    layout = scene.layout()
    moving = np.array([-1.85, 12.0, SOUTH, 5.0])
    first = {}
    for occluded in (True, False):
        cv = make_planner("cv-layered")
        cv.reset(PlannerContext.of(layout, ScenarioConfig().with_values({"sensing.occluded": occluded})),
                 np.random.default_rng(0))
        cv.command(PlannerInput(t=0.0, poses=np.stack([EGO, moving]), obstacle_in_lane=False))
        cv.command(PlannerInput(t=0.5, poses=np.stack([EGO, NAN]), obstacle_in_lane=False))
        first[occluded] = cv.futures(1)[0]
        cv.command(PlannerInput(t=0.6 + COAST_TIME, poses=np.stack([EGO, NAN]), obstacle_in_lane=False))
        if occluded:
            assert cv.futures(1).shape == (0, 4)  # the track is dropped
    dt = 0.1
    assert first[True][1] == pytest.approx(12.0 - 5.0 * (0.5 + dt))  # coasted to t = 0.5 s, then one tick
    assert first[False][1] == pytest.approx(12.0 - 5.0 * dt)  # a dropout: the last pose stands


def test_the_imm_coasts_and_starts_at_its_first_measurement(scene):
    context = PlannerContext.of(scene.layout(), ScenarioConfig().with_values(OCCLUDED))
    imm = make_planner("imm-layered")
    imm.reset(context, np.random.default_rng(0))
    imm.command(PlannerInput(t=0.0, poses=np.stack([EGO, NAN]), obstacle_in_lane=False))
    assert imm.imm is None  # no track before the car is seen
    imm.command(PlannerInput(t=0.1, poses=np.stack([EGO, np.array([-1.85, 12.0, SOUTH, 5.0])]),
                             obstacle_in_lane=False))
    s0 = imm.estimates()[0][:, 0].copy()
    for k in range(2, 7):
        imm.command(PlannerInput(t=0.1 * k, poses=np.stack([EGO, NAN]), obstacle_in_lane=False))
    assert (imm.estimates()[0][:, 0] > s0 + 1.5).all()  # each intent's track coasted on at about 5 m/s
