"""Episodes: reproducible records, planners, labels, bad input, metrics."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from cdf_mj.analysis.metrics import scenario_summary, wilson_interval
from cdf_mj.config import ScenarioConfig
from cdf_mj.planners import Planner, make_planner
from cdf_mj.records import Label
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.world import NonFiniteStateError


def test_same_seed_same_record(scene):
    a = run_episode(seed=11, planner="reactive", scene=scene, trace=True).to_dict()
    b = run_episode(seed=11, planner="reactive", scene=scene, trace=True).to_dict()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    c = run_episode(seed=12, planner="reactive", scene=scene, trace=True).to_dict()
    assert c["trace"]["poses"] != a["trace"]["poses"]


def test_record_is_json_serialisable_and_consistent(scene):
    rec = run_episode(seed=5, planner="reactive", scene=scene).to_dict()
    back = json.loads(json.dumps(rec))
    assert back["seed"] == 5 and back["planner"] == "reactive"
    assert back["label"] in (Label.CUTOFF, Label.YIELD, Label.RIGHT)
    assert back["min_gap"] >= 0.0 and back["end_time"] > 0.0


def _first_cutoff(scene, planner):
    for seed in range(40):
        rec = run_episode(seed=seed, planner=planner, scene=scene)
        if rec.label == Label.CUTOFF:
            return rec
    raise AssertionError("no Cutoff episode in seeds 0-39")


def test_reactive_planner_brakes_on_entry(scene):
    rec = _first_cutoff(scene, "reactive")
    assert rec.brake_time is not None
    assert rec.brake_time == rec.entered_lane_time


def test_constant_planner_never_brakes_and_labels_itself(scene):
    rec = _first_cutoff(scene, "constant")
    assert rec.brake_time is None
    assert rec.collision_with == "obstacle" and rec.counterfactual_collision


def test_planners_share_the_obstacle_world(scene):
    """Common random numbers: the obstacle's intent and the label do not depend on the planner."""
    for seed in range(6):
        a = run_episode(seed=seed, planner="constant", scene=scene)
        b = run_episode(seed=seed, planner="reactive", scene=scene)
        assert (a.intent, a.label, a.ego_start_offset) == (b.intent, b.label, b.ego_start_offset)


def test_braking_reduces_progress(scene):
    rec = _first_cutoff(scene, "reactive")
    assert rec.time_lost > 0.5
    free = run_episode(ScenarioConfig(obstacle={"p_left": 0.0}), seed=0, planner="constant", scene=scene)
    assert abs(free.time_lost) < 0.1


class _Corrupting(Planner):
    """Stands for a diverging user model: writes NaN into the ego's state at t = 1 s. It
    holds the scene itself: planners get only the static layout."""

    name = "corrupting"

    def __init__(self, scene):
        self.scene = scene

    def brake(self, obs):
        if obs.t >= 1.0:
            self.scene.data.qvel[self.scene.ego.qvel[0]] = math.nan
        return False


def test_nan_pose_raises_a_clear_error(scene):
    with pytest.raises(NonFiniteStateError, match="non-finite system pose"):
        run_episode(seed=0, planner=_Corrupting(scene), scene=scene, label=False)


@pytest.mark.parametrize("car", ["ego", "obstacle"])
@pytest.mark.parametrize(("kind", "i", "bad"), [("qpos", 0, math.nan), ("qpos", 1, math.inf), ("qpos", 2, math.nan),
                                               ("qvel", 0, -math.inf), ("qvel", 1, math.nan)])
def test_a_non_finite_pose_entry_is_refused_and_huge_finite_ones_are_not(scene, car, kind, i, bad):
    from cdf_mj.scenario.world import World

    world = World(scene)
    world.reset(3)
    world.step(np.zeros(2))
    getattr(scene.data, kind)[getattr(scene.car(car), kind)[i]] = bad
    with pytest.raises(NonFiniteStateError, match=r"non-finite system pose at t=0\.1 s"):
        world.measure()
    world.reset(3)
    world.step(np.zeros(2))
    scene.data.qpos[scene.ego.qpos[0]] = scene.data.qpos[scene.obstacle.qpos[0]] = 1e308  # their sum overflows
    assert world.measure().poses[:, 0].tolist() == [1e308, 1e308]


def test_world_ticks_the_same_whatever_holds_the_ego_controls(scene):
    from cdf_mj.scenario.world import World

    runs = []
    for form in (np.array, lambda v: np.array(v, dtype=np.float32), lambda v: np.c_[v, v][:, 0], list, tuple):
        world = World(scene)
        world.reset(9)
        ticks = [world.step(form([0.75, 0.03125])) for _ in range(12)]
        runs.append(([(t.poses.tolist(), t.mode, t.gap, t.belief.tolist()) for t in ticks], scene.data.qpos.tolist()))
    assert all(r == runs[0] for r in runs[1:])
    # Controls of another shape are one ValueError, before the tick draws or moves anything.
    world = World(scene)
    world.reset(9)
    before = (world.rng["obstacle"].bit_generator.state, scene.data.qpos.tolist())
    for bad in ([0.5], [[0.5, 0.0]], [0.5, 0.0, 0.0]):
        with pytest.raises(ValueError, match=r"^World.step: ego_controls must be \[acceleration"):
            world.step(bad)
    assert (world.rng["obstacle"].bit_generator.state, scene.data.qpos.tolist()) == before


@pytest.mark.parametrize(("field", "value", "fragment"), [
    ("obstacle.beta", 1.5, "in [0, 1]"),
    ("obstacle.beta", float("nan"), "in [0, 1]"),
    ("ego.speed", -1.0, "> 0"),
    ("timing.dt", 0.0, "> 0"),
    ("obstacle.p_left", -0.1, "in [0, 1]"),
    ("ego.start_spread", (5.0, -5.0), "low <= high"),
])
def test_out_of_range_config_is_refused(field, value, fragment):
    with pytest.raises(ValueError, match=re.escape(field)) as err:
        ScenarioConfig().with_values({field: value})
    assert fragment in str(err.value)


def test_unknown_planner_and_bad_seed_are_refused(scene):
    with pytest.raises(ValueError, match="reactive"):
        make_planner("psychic")
    with pytest.raises(ValueError, match="seed"):
        run_episode(seed=-1, scene=scene)


def test_dt_must_be_a_multiple_of_the_timestep(scene):
    with pytest.raises(ValueError, match="multiple"):
        run_episode(ScenarioConfig(timing={"dt": 0.0123}), seed=0, scene=scene)


def test_wilson_interval_is_the_score_interval():
    z = 1.959963984540054
    for k, n in ((0, 10), (3, 10), (10, 10), (417, 1000)):
        lo, hi = wilson_interval(k, n)
        assert 0.0 <= lo <= k / n <= hi <= 1.0
        for p in (lo, hi):  # the end points solve |k/n - p| = z sqrt(p (1 - p) / n)
            if 0.0 < p < 1.0:
                assert abs(k / n - p) == pytest.approx(z * math.sqrt(p * (1 - p) / n), rel=1e-9)
    with pytest.raises(ValueError, match="need 0 <= k <= n"):
        wilson_interval(5, 3)


def test_scenario_summary_counts(scene):
    recs = [run_episode(seed=s, planner="reactive", scene=scene) for s in range(12)]
    summary = scenario_summary(recs)
    assert sum(summary[lab].k for lab in (Label.CUTOFF, Label.YIELD, Label.RIGHT)) == 12
    cut = [r for r in recs if r.label == Label.CUTOFF]
    assert summary["avoided"].n == len(cut)
    assert summary["avoided"].k == sum(r.collision_with != "obstacle" for r in cut)
    assert np.isclose(summary[Label.RIGHT].value, np.mean([r.intent == "right" for r in recs]))


def test_a_run_that_never_brakes_is_the_counterfactual(scene):
    """The premise that lets a non-braking run stand in for the constant-speed run that
    labels its seed (run_episode and the experiment runner skip simulating it)."""
    from cdf_mj.scenario.episode import counterfactual

    cfg = ScenarioConfig()
    compared = braked = 0
    for seed in range(12):
        constant = run_episode(cfg, seed, "constant", scene, label=False).to_dict()
        run = run_episode(cfg, seed, "reactive", scene).to_dict()
        label, hit = counterfactual(cfg, seed, scene)
        assert (run["label"], run["counterfactual_collision"]) == (label, hit)
        assert hit == (constant["collision_with"] == "obstacle")
        if run["brake_time"] is None:
            compared += 1
            for key in constant.keys() - {"planner", "planner_info", "label", "counterfactual_collision"}:
                assert run[key] == constant[key], (seed, key)
        else:
            braked += 1
    assert compared and braked  # both paths exercised
