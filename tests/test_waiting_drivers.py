"""Drivers who stop and wait at the line, and the CDF filter's own driver model.

Real MuJoCo episodes on the default scene, the four-way scene and (from
``tests/junctions.py``) a rotated and a mirrored junction. The world's driver waits
0-2 s at the stop line and then cuts across the ego's lane or turns away; the filter
keeps its default prior (its driver model is its own, not the world's). The scene
tests run the default N = 1000: with 300 particles the prior's own sampling noise moves
P(left) by a few hundredths, and on the four-way scene (no building between the cars)
a right-turner's P(cutoff), 0.81 at N = 1000 (seeds 0-3), then touches tau = 0.85.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from junctions import junction_scene

from cdf_mj.analysis.metrics import decision_time
from cdf_mj.config import CDFConfig, DriverPrior, ScenarioConfig
from cdf_mj.inference.particle_filter import THETA, ParticleFilter
from cdf_mj.model.driver import DriverModel, Intent, Mode, road_clear
from cdf_mj.planners import CDFPlanner
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import Scene

N = 300
TAU = CDFConfig().tau
FOURWAY = Path(__file__).resolve().parents[1] / "models" / "xml" / "scene_fourway.xml"
_MOVING = (int(Mode.GOING), int(Mode.COMMITTED))


@pytest.fixture(scope="module")
def scenes(scene) -> dict[str, Scene]:
    return {"default": scene, "fourway": Scene.load(FOURWAY),
            "rotated": junction_scene(rotation=2.1, center=(30.0, -12.0)),
            "mirrored": junction_scene(mirror=True, lane_width=3.3)}


def _waiting(dwell: float, p_left: float) -> ScenarioConfig:
    """A driver who never sees the ego (beta = 0) and waits ``dwell`` [s] at the line; the
    ego starts ``13.4 * dwell`` m further back, so a left turn still cuts it off."""
    back = -13.4 * dwell
    return ScenarioConfig(obstacle={"beta": 0.0, "p_left": p_left, "stop_dwell": (dwell, dwell)},
                          ego={"start_spread": (back - 4.0, back + 4.0)})


def _departure(rec) -> float:
    """[s] the first tick on which the obstacle was going."""
    modes = rec.trace["mode"]
    k = next(i for i, m in enumerate(modes) if m in _MOVING)
    return float(rec.trace["t"][k])


@pytest.mark.parametrize("name", ["default", "fourway", "rotated", "mirrored"])
def test_cutoff_after_a_wait_is_warned_before_the_lane_and_a_turn_away_is_not(scenes, name):
    """For waits of 0, 1 and 2 s and two seeds each: a left-turner that waited is warned
    of (the filter's P(cutoff) >= tau) before it enters the ego's lane and not while it
    still stands, and the CDF (layered rule) acts on it (brakes hard, or slows the ego as
    it enters the lane) and the ego does not touch it; for a right-turner that waited the
    CDF never brakes hard."""
    scene = scenes[name]
    tau = CDFConfig().tau
    for dwell in (0.0, 1.0, 2.0):
        for seed in (0, 1):
            rec = run_episode(_waiting(dwell, 1.0), seed, CDFPlanner(CDFConfig()),
                              scene, label=False, trace=True)
            warned = decision_time(rec, tau)
            assert rec.entered_lane_time is not None, (name, dwell, seed)
            assert warned is not None and warned < rec.entered_lane_time, \
                (name, dwell, seed, warned, rec.entered_lane_time)
            assert warned >= _departure(rec), (name, dwell, seed, warned)
            assert rec.planner_info["prediction"] == "Cutoff" and rec.collision_with != "obstacle", \
                (name, dwell, seed, rec.brake_time, rec.collision_time)
            rec = run_episode(_waiting(dwell, 0.0), seed, CDFPlanner(CDFConfig()),
                              scene, label=False)
            p_cutoff = rec.planner_info["history"]["p_cutoff"]
            assert rec.brake_time is None, (name, dwell, seed, max(p_cutoff))


def test_a_standing_car_keeps_the_going_and_right_turn_hypotheses(scene):
    """A car standing 3 s at the line (it never sees the ego) is "still waiting": P(right)
    stays above 0.05 (0.24 at first; it drifts down as hypotheses that saw the ego and
    wait gain on those that leak away at the departure hazard, 0.10 at 3 s), P(cutoff) stays below tau, and once
    it turns right the filter finds it (P(right) > 0.9 at the end) without a warning."""
    cfg = ScenarioConfig(obstacle={"beta": 0.0, "p_left": 0.0, "stop_dwell": (3.0, 3.0)},
                         ego={"start_spread": (-45.0, -45.0)})
    rec = run_episode(cfg, 3, CDFPlanner(CDFConfig(n_particles=N)), scene, label=False, trace=True)
    h = rec.planner_info["history"]
    standing = np.array(h["t"]) < _departure(rec)
    p_right = 1.0 - np.array(h["p_left"])
    assert standing.sum() >= 29
    assert p_right[standing].min() > 0.05, p_right[standing].min()
    assert max(h["p_cutoff"]) < TAU and rec.brake_time is None
    assert p_right[-1] > 0.9


def test_the_old_filter_loses_the_standing_car(scene):
    """The same standing car with the old model (no departure hazard: the driver leaves
    the line as soon as it believes the road clear; no rejuvenation): every hypothesis
    that goes dies, only "has seen the ego and waits" explains it. The test above fails
    for that filter: it shows what the departure hazard is for."""
    old = CDFConfig(n_particles=N, prior=DriverPrior(departure_hazard=(1000.0, 1000.0)), mode_jump=0.0,
                    intent_floor=0.0)
    cfg = ScenarioConfig(obstacle={"beta": 0.0, "p_left": 0.0, "stop_dwell": (3.0, 3.0)},
                         ego={"start_spread": (-45.0, -45.0)})
    rec = run_episode(cfg, 3, CDFPlanner(old), scene, label=False, trace=True)
    h = rec.planner_info["history"]
    standing = np.array(h["t"]) < _departure(rec)
    assert (1.0 - np.array(h["p_left"]))[standing].min() < 0.05
    assert np.array(h["p_seen"])[standing].max() > 0.9


def test_world_waits_its_dwell_with_the_same_intent_and_start(scene):
    """stop_dwell = (1.2, 1.2): the obstacle stands until t = 1.2 s and then goes; the intent
    and the ego's start are those of the same seed without a dwell (common random numbers);
    waiting out the dwell is not yielding."""
    world = World(scene, ScenarioConfig(obstacle={"beta": 0.0, "p_left": 1.0}))
    world.reset(5)
    intent, offset = world.intent, world.ego_start_offset
    world = World(scene, ScenarioConfig(obstacle={"beta": 0.0, "p_left": 1.0, "stop_dwell": (1.2, 1.2)}))
    world.reset(5)
    assert (world.intent, world.ego_start_offset, world.dwell) == (intent, offset, 1.2)
    while world.t < 1.15:
        tick = world.step(np.zeros(2))
        assert tick.mode == Mode.WAITING and abs(tick.poses[1, 3]) < 0.05
    tick = world.step(np.zeros(2))
    assert tick.mode == Mode.GOING and world.departed == pytest.approx(1.2)
    assert not world.yielded


def test_a_hesitating_driver_noses_out_stops_and_goes_on(scene):
    """hesitation = 1: the driver leaves after its dwell, stops again once 0.7 m out (before
    the commit point), stands its pause without counting as yielding, then goes on; the
    intent, ego start and dwell are those of the same seed without hesitation (CRN)."""
    base = ScenarioConfig(obstacle={"beta": 0.0, "p_left": 1.0, "stop_dwell": (0.5, 0.5)})
    world = World(scene, base)
    world.reset(3)
    draws = (world.intent, world.ego_start_offset, world.dwell)
    world = World(scene, base.replace(obstacle={"hesitation": 1.0, "hesitation_pause": (1.0, 1.0)}))
    world.reset(3)
    assert (world.intent, world.ego_start_offset, world.dwell) == draws
    speeds, modes, where = [], [], []
    while not world.done and world.t < 5.0:
        tick = world.step(np.zeros(2))
        speeds.append(tick.poses[1, 3])
        modes.append(tick.mode)
        where.append(tick.poses[1, :2])
    assert world.departed == pytest.approx(0.5)
    assert world.hesitated is not None and world.hesitated > world.departed
    k_stop, k_go = round(world.hesitated / 0.1), round((world.hesitated + 1.0) / 0.1)
    assert all(m == Mode.WAITING for m in modes[k_stop:k_go])
    assert min(speeds[k_stop:k_go]) < 0.05  # it came to a stop
    assert modes[k_go] in _MOVING and not world.yielded
    s = world.driver.routes[int(Intent.LEFT)].project(np.array(where))[0]
    assert s[k_stop] - s[0] == pytest.approx(0.7, abs=0.25)  # nosed out 0.7 m
    assert s[k_go] < world.driver.s_commit[int(Intent.LEFT)]  # and stood before the commit point
    assert s[-1] > s[k_go] + 5.0  # then went on


def test_a_creep_past_the_commit_point_is_refused(scene):
    """On models/xml the commit point is 1.44-1.45 m from the start: a 1.5 m creep could never
    end in a stop (the driver is committed by then), so it is one clear error, not a
    driver who silently never hesitates."""
    with pytest.raises(ValueError, match=r"hesitation_creep=1.5 m reaches the commit point, 1\.4\d m"):
        World(scene, ScenarioConfig(obstacle={"hesitation": 0.5, "hesitation_creep": 1.5}))
    World(scene, ScenarioConfig(obstacle={"hesitation": 0.0, "hesitation_creep": 1.5}))  # no hesitation: no matter


def test_departure_look_sees_the_ego_when_it_would_leave(scene):
    """beta = 0 but departure_look = 1: the driver's only look is on the tick its dwell ends
    with the ego in sight; it sees the ego (first_seen = the dwell) and does not go."""
    cfg = ScenarioConfig(obstacle={"beta": 0.0, "p_left": 1.0, "stop_dwell": (1.5, 1.5), "departure_look": 1.0},
                         ego={"start_spread": (-20.0, -20.0)})
    rec = run_episode(cfg, 2, "constant", scene, trace=True)
    assert rec.first_seen_time == pytest.approx(1.5)
    assert rec.trace["mode"][15] == Mode.WAITING and rec.yielded
    assert rec.label == "Yield" and not rec.collision
    no_look = run_episode(cfg.replace(obstacle={"departure_look": 0.0}), 2, "constant", scene, trace=True)
    assert no_look.first_seen_time is None and no_look.label == "Cutoff"


def test_a_slow_or_stopped_ego_near_the_conflict_point_is_not_clear(scene):
    """The time-to-arrival bug: an ego stopped 5 m before the conflict point has a time
    to arrive of 50 s at the 0.1 m/s floor and looked clear. Nearer than clear_distance it
    never is, whatever its speed; far and stopped it is; passed it is."""
    layout = scene.layout()
    model = DriverModel.of_world(layout, ScenarioConfig())
    cx, cy = layout.conflict
    seen, left = np.array([True] * 5), np.array([Intent.LEFT] * 5)
    belief = np.array([[cx - 5.0, cy, 0.0, 0.0],  # stopped 5 m before
                       [cx - 8.0, cy, 0.0, 1.0],  # creeping at 1 m/s, 8 m before
                       [cx - 30.0, cy, 0.0, 0.0],  # stopped 30 m before
                       [cx - 30.0, cy, 0.0, 13.4],  # 2.2 s away at speed
                       [cx + 5.0, cy, 0.0, 0.0]])  # 5 m past
    assert road_clear(model, belief, seen, left).tolist() == [False, False, True, False, True]
    # Without the clearance in space, both near ones look clear (the bug).
    far = ScenarioConfig(obstacle={"clear_distance": 0.0})
    assert road_clear(DriverModel.of_world(layout, far), belief, seen, left)[:2].tolist() == [True, True]


def test_particles_draw_their_parameters_from_the_prior_and_reinit_restores_diversity(scene):
    """Each particle's parameters lie in the prior's ranges and differ between particles;
    a measurement far from every particle redraws intents, modes, sightings and parameters
    from the prior (both intents, both seen and unseen, parameters spread again)."""
    prior = DriverPrior()
    pf = ParticleFilter.from_layout(scene.layout(), CDFConfig(n_particles=N), np.random.default_rng(0), 0.1)
    poses = scene.poses()
    pf.reset(poses)
    for j, name in enumerate(THETA[:-1]):
        lo, hi = getattr(prior, name)
        assert lo <= pf.theta[:, j].min() < pf.theta[:, j].max() <= hi, name
    # Collapse the hypotheses: one intent, one set of parameters, never seen.
    pf.intent[:] = Intent.LEFT
    pf.theta[:] = pf.theta[0]
    far = poses.copy()
    far[1, :2] += 80.0
    far[1, 3] = 6.0
    pf.update(far)
    assert pf.reinits == 1
    assert 0.1 < np.mean(pf.intent == Intent.RIGHT) < 0.45
    assert 0.3 < pf.has_belief.mean() < 0.7 and np.all(pf.mode == Mode.GOING)
    assert np.all(pf.theta.std(axis=0) > 0)
    np.testing.assert_array_equal(pf.pose, np.broadcast_to(far[1], (N, 4)))


@pytest.mark.parametrize(("changes", "field"), [
    ({"beta": (0.1, 0.05)}, "DriverPrior.beta"),
    ({"accel": (0.0, 2.0)}, "DriverPrior.accel"),
    ({"departure_hazard": (1.0, float("inf"))}, "DriverPrior.departure_hazard"),
    ({"clear_distance": (-1.0, 5.0)}, "DriverPrior.clear_distance"),
    ({"p_left": 1.5}, "DriverPrior.p_left"),
])
def test_bad_prior_is_one_clear_error(changes, field):
    with pytest.raises(ValueError, match=field):
        DriverPrior(**changes)


def test_cdf_config_reads_its_prior_back_from_json():
    cfg = CDFConfig(prior=DriverPrior(beta=(0.04, 0.06)), ego_brake=4.0)
    back = CDFConfig(**{**cfg.to_dict(), "prior": {k: list(v) if isinstance(v, tuple) else v
                                                    for k, v in cfg.to_dict()["prior"].items()}})
    assert back == cfg
    for bad, field in (({"ego_brake": 0.0}, "ego_brake"), ({"mode_jump": 0.9}, "mode_jump"),
                       ({"intent_floor": -0.1}, "intent_floor"), ({"ego_latency": -1.0}, "ego_latency")):
        with pytest.raises(ValueError, match=field):
            CDFConfig(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="stop_dwell"):
        ScenarioConfig(obstacle={"stop_dwell": (2.0, 1.0)})
    with pytest.raises(ValueError, match="departure_look"):
        ScenarioConfig(obstacle={"departure_look": 1.5})


def test_ego_braking_and_latency_set_the_last_tick_to_stop(scene):
    """The filter counts a going left-turner's looks only until the ego's last chance to
    stop short of its path: ``(ahead - nose - half width - v^2 / 2b) / v - latency``,
    in ticks. A weaker brake or a longer latency leaves fewer ticks, a stopped ego all."""
    layout = scene.layout()
    ego = np.array([layout.conflict[0] - 40.0, layout.conflict[1], 0.0, 13.4])
    obstacle = layout.obstacle_start
    margin = layout.ego.hull_offset[0] + layout.ego.hull_half[0] + layout.obstacle.hull_half[1]

    def ticks(**changes) -> float:
        pf = ParticleFilter.from_layout(layout, CDFConfig(n_particles=8, **changes), np.random.default_rng(0), 0.1)
        pf.reset(np.stack([ego, obstacle]))
        return pf.ego_ticks_to_stop()

    for brake, latency in ((layout.ego.max_brake, 0.0), (4.0, 0.0), (4.0, 0.3)):
        t = (40.0 - margin - 13.4 ** 2 / (2 * brake)) / 13.4 - latency
        assert ticks(ego_brake=brake, ego_latency=latency) == int(np.ceil(t / 0.1 - 1e-9))
    assert ticks() > ticks(ego_brake=4.0) > ticks(ego_brake=4.0, ego_latency=0.3) > 0
    ego[0], ego[3] = layout.conflict[0] - 6.0, 0.0
    assert ticks() == np.inf


def test_a_left_turner_that_pulls_out_behind_the_ego_is_no_cutoff(scene):
    """A going left-turner whose nose reaches the conflict point only after the ego (at
    its speed) has cleared it does not count towards P(cutoff); the same one with the ego
    further back does, fully when nobody can see anybody."""
    layout = scene.layout()
    obstacle = layout.obstacle_start.copy()
    obstacle[3] = 2.0

    def p_cutoff(ego_back: float) -> float:
        ego = np.array([layout.conflict[0] - ego_back, layout.conflict[1], 0.0, 13.4])
        pf = ParticleFilter.from_layout(layout, CDFConfig(n_particles=50), np.random.default_rng(0), 0.1)
        pf.reset(np.stack([ego, obstacle]))
        pf.intent[:] = Intent.LEFT
        pf.mode[:] = Mode.GOING
        pf.theta[:, 5] = 0.0  # the driver never looks: a sure cut-off if it is in time
        return float(pf.posterior().p_cutoff)

    assert p_cutoff(5.0) == 0.0  # the ego is past before the obstacle's nose gets there
    assert p_cutoff(40.0) == pytest.approx(1.0)
