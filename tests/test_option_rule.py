"""The layered rule's option anticipation (``LayeredConfig.anticipation = "option"``,
``cdf-option``) against version 0.3's (``"go"``, the default ``cdf``), on real episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdf_mj.config import CDFConfig, LayeredConfig, ScenarioConfig
from cdf_mj.planners import make_planner
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.cdf import OPTION_ANTICIPATION, CDFPlanner, OptionCDFPlanner
from cdf_mj.planners.decision import OPTION, SLOW, SLOW_RSS, LayeredRule
from cdf_mj.presets import load_preset
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

SEEDS = range(8)


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene.load()


def test_the_anticipation_is_one_of_its_names_and_option_time_is_a_duration():
    with pytest.raises(ValueError, match=r"layered\.anticipation"):
        LayeredConfig(anticipation="maybe")
    with pytest.raises(ValueError, match="option_time"):
        LayeredConfig(option_time=-1.0)
    assert LayeredConfig().anticipation == "go"  # the declared objective kept version 0.3's for cdf


def test_cdf_option_is_registered_with_the_option_rule_and_keeps_the_rest_of_a_given_config():
    planner = make_planner("cdf-option")
    assert isinstance(planner, OptionCDFPlanner) and planner.name == "cdf-option"
    lay = planner.cdf.layered
    assert (lay.anticipation, lay.option_time, lay.anticipate) == ("option", 1.0, 0.9)
    given = CDFConfig(n_particles=300, layered=LayeredConfig(comfort_brake=2.0, anticipate=0.2,
                                                             anticipate_release=0.1))
    built = OptionCDFPlanner(given)
    assert built.cdf.n_particles == 300 and built.cdf.layered.comfort_brake == 2.0
    assert {k: getattr(built.cdf.layered, k) for k in OPTION_ANTICIPATION} == OPTION_ANTICIPATION


def test_the_option_rule_does_not_slow_on_the_prior_where_version_0_3_does(scene):
    """Version 0.3's rule intervenes on its first ticks, before any evidence; the option rule
    waits: its first intervention, where there is one, comes after the other car has moved."""
    config = ScenarioConfig()
    for seed in SEEDS:
        go = run_episode(config, seed, "cdf", scene)
        option = run_episode(config, seed, "cdf-option", scene, trace=True)
        assert go.intervention["first"] is not None and go.intervention["first"] <= 0.2
        first = option.intervention["first"]
        if first is not None:
            speeds = np.array([p[1][3] for p in option.trace["poses"]])
            moved = float(np.asarray(option.trace["t"])[np.argmax(speeds > 0.3)])
            assert first > moved


def test_the_option_is_lost_only_where_going_on_collides(scene):
    """P(losing the option) counts hypotheses that collide going on and that going on a
    little longer before the comfortable brake would hit or leave short of the RSS distance
    behind the merged car: never more than P(collision going on), and on the prior alone
    (the first tick) far below the rule's threshold (at most 0.25 where it reads up to 0.21
    on these seeds, nearly all of P(collision going on): the ego starts 27-43 m out at
    13.4 m/s, about the comfortable brake's RSS distance behind a car merging at the
    conflict point, so nearly all the prior's cut-off mass is at stake from the start)."""
    config = ScenarioConfig()
    planner = OptionCDFPlanner()
    readings: list[tuple[float, float, float]] = []

    def observe(step):
        layers = step.planner.rule.last_layers
        readings.append((step.measurement.t, layers.option, layers.go))

    for seed in SEEDS:
        readings.clear()
        run_episode(config, seed, planner, scene, label=False, observers=[observe])
        assert readings[0][1] <= 0.25 < OPTION_ANTICIPATION["anticipate"]
        assert all(option <= go + 1e-12 for _, option, go in readings)
        assert planner.history["anticipate"] == [round(o, 5) for _, o, _ in readings]


def test_version_0_3s_rule_reads_no_option_and_plans_four_ways(scene):
    ego = np.array([-30.0, -1.9, 0.0, 13.4])
    context = PlannerContext.of(scene.layout(), ScenarioConfig())
    rule = LayeredRule(LayeredConfig())
    rule.reset(context)
    assert rule.plans(ego).shape[0] == OPTION
    option = LayeredRule(LayeredConfig(**OPTION_ANTICIPATION))
    option.reset(context)
    plans = option.plans(ego)
    assert plans.shape[0] == SLOW_RSS + 1
    # The option plan goes on as GO does up to its deferral, then falls behind it; the
    # sixth row is the comfortable brake now, as SLOW (read against the RSS distance).
    np.testing.assert_array_equal(plans[OPTION, :5], plans[0, :5])
    assert plans[OPTION, -1] < plans[0, -1]
    np.testing.assert_array_equal(plans[SLOW_RSS], plans[SLOW])
    planner = CDFPlanner()
    run_episode(ScenarioConfig(), 3, planner, scene, label=False)
    assert math.isnan(planner.rule.last_layers.option)


def test_the_option_rule_brakes_fully_before_a_car_that_merges_too_close_and_stops():
    """``stress-merge-stops`` development seed 29 (the merged car brakes to a stop in the
    ego's lane): the option rule slows once the option is lost (P >= 0.9), and, the
    comfortable brake still likely to leave the ego short of the RSS distance behind the
    merging car a tick later, brakes fully before that car is in the lane and before the
    emergency layer would; the ego stops short of it (the option rule before the RSS test,
    tested by boxes alone, hit it)."""
    config = load_preset("stress-merge-stops")
    planner = OptionCDFPlanner()
    ticks: list[tuple[float, float, float, float, float]] = []

    def observe(step):
        ly = step.planner.rule.last_layers
        ticks.append((step.measurement.t, step.planner.rule.last_command, ly.slow_rss, ly.gap, ly.emergency))

    record = run_episode(config, 29, planner, Scene.load(), observers=[observe])
    assert record.label == "Cutoff" and not record.collision
    first_full = next(i for i, (_, command, *_rest) in enumerate(ticks) if command == -math.inf)
    _, _, slow_rss, gap, emergency = ticks[first_full]
    assert slow_rss >= OPTION_ANTICIPATION["anticipate"] and gap == math.inf and emergency < 0.5
    assert ticks[first_full - 1][1] < 0.0  # it was slowing on the tick before

