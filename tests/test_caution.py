"""The naive-caution baselines (``caution-waiting``, ``caution-moving``, ``caution-phantom``,
:mod:`cdf_mj.planners.caution`) in real episodes of the default world: each slows for a car
at the side road where ``constant`` holds its speed, ``caution-moving`` leaves a standing car
alone, ``caution-phantom`` holds a speed that stops before the conflict zone and slows for a
hidden approach only where buildings hide it, each avoids a cut-off that ``constant`` hits; a
missed measurement keeps the last reading; they are registered as ``cdf`` is (they take the
run's whole CDF configuration: its filter, emergency layer and guard) and rebuilt from their
stored arguments; at 1:10, given the run's scaled CDF configuration as ``cdf`` is, they
command the full-size scenario shrunk."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from junctions import build_junction, junction_scene

from cdf_mj.config import CDFConfig, LayeredConfig, RiskConfig, ScenarioConfig, scaled
from cdf_mj.model.conflict import conflict_map
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners import base
from cdf_mj.planners.base import Planner, PlannerContext, PlannerInput
from cdf_mj.planners.caution import CautionRule
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.decision import GivenFutures
from cdf_mj.planners.registry import bind_planner, make_planner, planner_arguments, planner_spec
from cdf_mj.records.schema import EpisodeRecord, check_record
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.sim.scene import Scene, read_layout

PLANNERS = ("caution-waiting", "caution-moving", "caution-phantom")
#: The layers every baseline reads by default: the default run's (``CDFConfig().layered``).
LAYERS = CDFConfig().layered
#: Seeds of the default world, as run_episode labels them (checked where used): a Yield whose
#: driver creeps out and stops again; a Yield whose driver stands until the ego has passed;
#: a Right; two cut-offs that the constant-speed ego runs into.
CREEPS, STANDS, RIGHT, CUTOFFS = 3, 9, 0, (1, 5)


def _poses(record: EpisodeRecord) -> list[Any]:
    """The poses ``[ego, other]`` per tick of a traced record."""
    assert record.trace is not None
    return list(record.trace["poses"])


def _ego_speed(record: EpisodeRecord) -> np.ndarray:
    """[m/s] The ego's speed per tick of a traced record."""
    return np.array([pose[0][3] for pose in _poses(record)])


def _rule(planner: Planner) -> CautionRule:
    """A baseline's caution rule (it is a ``cdf`` planner under one)."""
    assert isinstance(planner, CDFPlanner) and isinstance(planner.rule, CautionRule)
    return planner.rule


def _caution(record: EpisodeRecord) -> np.ndarray:
    """Per tick, whether the baseline's naive condition held."""
    assert record.planner_info is not None
    history = record.planner_info["history"]
    assert len(history["caution"]) == len(history["t"])
    return np.array(history["caution"]) == 1.0


def test_each_slows_for_a_car_at_the_side_road_where_constant_holds_its_speed(scene: Scene):
    """A Yield whose driver creeps out, then waits: each baseline's ego falls more than 0.5
    m/s below the constant-speed ego's, gently (no hard brake), after its condition held;
    the constant ego stays within 0.5 m/s of its nominal speed. The records pass the checks."""
    constant = run_episode(None, CREEPS, "constant", scene, trace=True)
    assert constant.label == "Yield" and not constant.collision
    held = _ego_speed(constant)
    assert held.min() > ScenarioConfig().ego.speed - 0.5
    for name in PLANNERS:
        record = run_episode(None, CREEPS, name, scene, trace=True)
        speed, caution = _ego_speed(record), _caution(record)
        n = min(len(speed), len(held))
        below = np.flatnonzero(held[:n] - speed[:n] > 0.5)
        assert below.size and caution.any(), (name, "never slowed")
        assert np.flatnonzero(caution)[0] < below[0], name
        assert record.brake_time is None and not record.collision, (name, record.brake_time)
        data = json.loads(json.dumps(record.to_dict()))
        check_record(data)
        assert set(data["planner_info"]["history"]["caution"]) == {0.0, 1.0}


def test_caution_moving_leaves_a_standing_car_alone(scene: Scene):
    """Where the driver stands until the ego has passed, caution-moving never slows (its ego
    is the constant one's) while caution-waiting does; over a few episodes of every label,
    caution-moving's condition holds only while the other car moves."""
    constant = run_episode(None, STANDS, "constant", scene, trace=True)
    moving = run_episode(None, STANDS, "caution-moving", scene, trace=True)
    waiting = run_episode(None, STANDS, "caution-waiting", scene, trace=True)
    assert constant.label == "Yield" and not _caution(moving).any() and _caution(waiting).any()
    np.testing.assert_allclose(_ego_speed(moving), _ego_speed(constant), atol=0.05)
    assert waiting.time_lost > constant.time_lost + 0.1
    stand = LAYERS.stand_speed
    for seed in range(8):
        record = run_episode(None, seed, "caution-moving", scene, trace=True)
        other = np.array([pose[1][3] for pose in _poses(record)])
        caution = _caution(record)
        assert np.all(np.abs(other[caution]) >= stand), (seed, other[caution].min())


def _stopping_cap(distance: np.ndarray, context: PlannerContext) -> np.ndarray:
    """[m/s] The speeds from which the ego stops within ``distance`` [m] at the comfortable
    brake after one tick, the latency and half the jerk ramp (the rule's stated response)."""
    b, jerk = LAYERS.comfort_brake, LAYERS.comfort_jerk
    response = context.dt + context.latency + b / (2.0 * jerk)
    return b * (np.sqrt(response ** 2 + 2.0 * np.maximum(distance, 0.0) / b) - response)


def test_caution_phantom_holds_a_speed_that_stops_before_the_conflict_zone(scene: Scene):
    """An ego cruising at 10 m/s (below its cap where it starts): while the rule holds the
    cap, its speed stays within the ego's process noise (0.1 m/s) of the speed from which
    the comfortable brake stops it before the conflict zone, and comes within 0.5 m/s of
    it (the cap binds); it enters the zone only once the cap is off."""
    config = ScenarioConfig().with_values({"ego.speed": 10.0})
    layout = scene.layout()
    zone = conflict_map(layout, RiskConfig().margin).zone
    context = PlannerContext.of(layout, config)
    for seed in (1, CREEPS):
        record = run_episode(config, seed, "caution-phantom", scene, trace=True)
        assert record.label == "Yield" and not record.collision
        caution = _caution(record)
        ego = np.array([pose[0] for pose in _poses(record)])[: len(caution)]
        distance = zone[0] - layout.route_ego.project(ego[:, :2])[0]
        cap = _stopping_cap(distance, context)
        excess = ego[caution, 3] - cap[caution]
        assert excess.max() <= 0.1 and excess.max() >= -0.5, (seed, excess.max())
        assert np.all(distance[caution] > 0.0)


def _gone_west(record: EpisodeRecord) -> np.ndarray:
    """Per tick, whether the other car heads west (it has turned right, away from the ego)."""
    return np.array([math.cos(pose[1][2]) < -0.9 for pose in _poses(record)])


def test_caution_phantom_slows_for_the_hidden_approach_only_where_buildings_hide_it(scene: Scene):
    """After a right-turner has gone, the phantom rule still holds the cap on the default
    junction, whose buildings hide the side road's approach from an ego short of the zone;
    on the same junction without buildings it lets go once the car has gone."""
    open_junction = junction_scene(buildings=False)
    assert len(open_junction.layout().occluders) == 0
    for world, hidden in ((scene, True), (open_junction, False)):
        record = run_episode(None, RIGHT, "caution-phantom", world, trace=True)
        assert record.label == "Right"
        caution = _caution(record)
        after = caution[_gone_west(record)[: len(caution)]]
        assert caution.any() and after.any() == hidden, (hidden, int(after.sum()))


@pytest.mark.parametrize("seed", CUTOFFS)
def test_each_avoids_a_cut_off_that_constant_runs_into(scene: Scene, seed: int):
    constant = run_episode(None, seed, "constant", scene)
    assert constant.label == "Cutoff" and constant.collision
    for name in PLANNERS:
        record = run_episode(None, seed, name, scene)
        assert not record.collision, (name, record.collision_time)


@pytest.mark.parametrize("name", PLANNERS)
def test_a_missed_measurement_keeps_the_last_reading(name: str):
    """Fed NaN rows after one measurement of the other car (waiting; for caution-moving,
    creeping out at 2 m/s), a baseline's rule slows as when fed that measurement every tick,
    on the junction without buildings (no hidden approach: caution-phantom's cap reads only
    the other car). The rule is given the same hypotheses in both runs (the other car
    standing at its line, :class:`GivenFutures`): the planner's filter predicts on without
    an update where a measurement is missed, which changes its futures, and so the guard, as
    it does ``cdf``'s."""
    layout = junction_scene(buildings=False).layout()
    context = PlannerContext.of(layout, ScenarioConfig())
    other = np.array(layout.obstacle_start, dtype=float)
    other[3] = 2.0 if name == "caution-moving" else 0.0
    standing = GivenFutures(np.tile(np.array(layout.obstacle_start, dtype=float), (50, 1)))
    runs = []
    for missed in (False, True):
        rule = _rule(make_planner(name))
        rule.reset(context)
        ego = np.array(layout.ego_start, dtype=float)
        ego[3] = context.nominal_speed
        commands, caution = [], []
        for k in range(15):
            seen = other if k == 0 or not missed else np.full(4, np.nan)
            commands.append(rule.command(standing, PlannerInput(t=0.1 * k, poses=np.stack([ego, seen]),
                                                                 obstacle_in_lane=False)))
            caution.append(rule.caution)
            ego[0] += 0.1 * ego[3]
        runs.append((commands, caution))
    assert runs[0] == runs[1]
    assert all(runs[1][1]) and min(runs[1][0]) < 0.0


@pytest.mark.parametrize("name", ["caution-waiting", "caution-phantom"])
def test_a_standoff_ends_the_wait_for_a_car_that_waits_for_the_ego(scene: Scene, name: str):
    """An ego standing just short of the conflict zone and the other car standing at its
    line: the baseline holds the ego there for layers.standoff, then lets it go (no
    deadlock with a driver who waits for the ego)."""
    layout = scene.layout()
    context = PlannerContext.of(layout, ScenarioConfig())
    planner = make_planner(name)
    planner.reset(context, np.random.default_rng(0))
    zone = _rule(planner).map.zone
    ego = np.array([*layout.route_ego.point_at(zone[0] - 0.5), 0.0, 0.0])
    other = np.array(layout.obstacle_start, dtype=float)
    caution = []
    for k in range(40):
        planner.command(PlannerInput(t=0.1 * k, poses=np.stack([ego, other]), obstacle_in_lane=False))
        caution.append(_rule(planner).caution)
    waited = 0.1 * caution.index(False)
    assert all(caution[:5]) and not any(caution[caution.index(False):])
    assert waited == pytest.approx(LAYERS.standoff, abs=0.15)


def test_registered_as_cdf_is_and_rebuilt_from_their_stored_arguments():
    """Each takes the run's whole CDF configuration (``shared=("cdf",)``, as ``cdf`` does):
    a ``cdf`` filter under a caution rule on its layers, risk rule and full brake, rebuilt
    the same from its stored (JSON) arguments."""
    assert planner_spec("cdf").shared == ("cdf",)
    changed = CDFConfig(layered=LayeredConfig(comfort_brake=2.0), risk=RiskConfig(brake=0.4), ego_brake=5.0)
    for name in PLANNERS:
        spec = planner_spec(name)
        assert spec.shared == ("cdf",) and f"\n{name} " in (base.__doc__ or "")
        planner = make_planner(name)
        assert planner.name == name and planner.graded and isinstance(planner, CDFPlanner)
        assert isinstance(planner.rule, CautionRule) and planner.rule.name == "layered"
        assert planner.cdf == CDFConfig() and planner.rule.layers == LAYERS
        stored = json.loads(json.dumps(planner_arguments(name, cdf=changed)))
        rebuilt = make_planner(name, **stored)
        assert rebuilt.cdf == changed and rebuilt.rule.layers.comfort_brake == 2.0
        assert rebuilt.rule.config.brake == 0.4 and rebuilt.rule.ego_brake == 5.0
        bound = bind_planner(name, changed)()
        assert type(bound) is type(planner) and bound.cdf == changed and bound.rule.config.brake == 0.4


# ------------------------------------------------------------------ at another scale
def _commands(scale: float, name: str) -> tuple[list[float], list[float]]:
    """The rule's commands [m/s^2] and the ego's speeds [m/s] for 6 s on the paper's junction at ``scale``
    with our car at that scale and every config scaled (cdf_mj.scaled): the ego driven by
    the monitor's acceleration, the other car creeping out for 0.6 s and then waiting. The
    monitor builds the planner by name with the run's scaled CDF configuration, as it builds
    ``cdf``."""
    ours = CarGeometry.ours().to_dict()
    shrunk: dict[str, Any] = {k: np.asarray(v) * scale if k != "steer_range" else v for k, v in ours.items()}
    car = CarGeometry(**shrunk)
    layout = read_layout(build_junction(cars=False, scale=scale).compile(), ego=car, obstacle=car)
    cdf = scaled(CDFConfig(), scale)
    monitor = CDFMonitor(layout, scaled(ScenarioConfig(), scale), cdf, rng=0, planner=name)
    planner = monitor.planner
    assert isinstance(planner, CDFPlanner) and planner.name == name and planner.cdf == cdf
    dt, left = monitor.scenario.timing.dt, layout.route_left
    ego = np.array(layout.ego_start, dtype=float)
    ego[3] = monitor.context.nominal_speed
    s = v = 0.0
    commands, speeds = [], []
    for k in range(60):
        p, q = left.point_at(s), left.point_at(s + 0.5 * scale)
        other = np.array([p[0], p[1], math.atan2(q[1] - p[1], q[0] - p[0]), v])
        decision = monitor.observe(k * dt, ego, other)
        commands.append(_rule(planner).last_command)
        speeds.append(float(ego[3]))
        ego[3] = max(ego[3] + decision.accel * dt, 0.0)
        ego[0] += ego[3] * dt
        v = max(v + (2.5 if k < 6 else -2.5) * scale * dt, 0.0)
        s += v * dt
    return commands, speeds


@pytest.mark.parametrize("name", PLANNERS)
def test_at_a_tenth_of_full_size_each_commands_the_full_size_scenario_shrunk(name: str):
    full, full_speeds = _commands(1.0, name)
    small, small_speeds = _commands(0.1, name)
    assert min(full) < 0.0, "it never slowed"
    np.testing.assert_allclose(small_speeds, np.array(full_speeds) * 0.1, rtol=1e-6, atol=1e-6)
    most = CarGeometry.ours().max_accel  # [m/s^2] a cap at the car's most acceleration is none
    np.testing.assert_allclose(np.minimum(small, 0.1 * most), 0.1 * np.minimum(full, most), rtol=1e-6, atol=1e-6)
