"""The decision rules: the conflict map and its compiled rollouts, the risk rule's brake and
release, the predictor x rule composition, and bad input.

Scenes: the package's T-junction, the four-way junction, and test junctions rotated,
mirrored (left-hand traffic), with other lane widths and no buildings (tests/junctions.py).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, run_cli
from junctions import junction_scene

from cdf_mj.config import CDFConfig, LayeredConfig, RiskConfig, ScenarioConfig
from cdf_mj.model.conflict import (
    BRAKE,
    DEFER,
    GO,
    Futures,
    collision_masses,
    conflict_map,
    lane_entry,
    right_turn_overlap,
    route_poses,
    widened,
)
from cdf_mj.model.geometry import boxes_overlap
from cdf_mj.model.layout import Layout
from cdf_mj.planners import CDFPlanner
from cdf_mj.planners.base import DecidingPlanner, PlannerContext, PlannerInput, ThresholdRule
from cdf_mj.planners.decision import FOLLOW_WITHIN, OPTION, SLOW_RSS, GivenFutures, LayeredRule, RiskRule
from cdf_mj.planners.registry import PLANNERS, make_planner
from cdf_mj.planners.rollout_reference import rollout_assessment
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import Scene

FOURWAY = Path(__file__).resolve().parents[1] / "models" / "xml" / "scene_fourway.xml"


@pytest.fixture(scope="module")
def layouts(scene: Scene) -> dict[str, Layout]:
    return {"default": scene.layout(), "fourway": Scene.load(FOURWAY).layout(),
            "rotated, mirrored, 3.2 m": junction_scene(rotation=2.1, mirror=True, lane_width=3.2).layout(),
            "no buildings, 4 m": junction_scene(rotation=-0.6, lane_width=4.0, buildings=False).layout()}


# ----------------------------------------------------------------- bad input
@pytest.mark.parametrize(("changes", "field"), [
    ({"brake": 1.5}, "brake"), ({"brake": 0.0}, "brake"), ({"brake": math.nan}, "brake"),
    ({"release": 0.0}, "release"), ({"brake": 0.2, "release": 0.3}, "release"),
    ({"latency": -0.1}, "latency"), ({"horizon": 0.0}, "horizon"), ({"margin": -1.0}, "margin")])
def test_risk_config_refuses_bad_values(changes: dict[str, float], field: str) -> None:
    with pytest.raises(ValueError, match=f"^{field}=") as err:
        RiskConfig(**changes)
    assert "\n" not in str(err.value)


def test_rules_and_configs_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match=r"threshold=1\.5"):
        ThresholdRule(1.5)
    with pytest.raises(ValueError, match="decision="):
        CDFConfig(decision="sometimes")
    with pytest.raises(ValueError, match="ego_brake"):
        RiskRule(ego_brake=-1.0)
    with pytest.raises(TypeError, match="RiskConfig"):
        RiskRule(config={"brake": 0.5})  # type: ignore[arg-type]
    assert CDFConfig(risk={"brake": 0.4, "release": 0.1}).risk == RiskConfig(brake=0.4, release=0.1)  # type: ignore[arg-type]


@pytest.mark.parametrize(("args", "needle"), [
    (("--brake-risk", "0.2", "--release-risk", "0.5"), "release=0.5"),
    (("--brake-risk", "1.5"), "--brake-risk"),
    (("--risk-latency", "-1"), "--risk-latency")])
def test_cli_refuses_bad_risk_arguments(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                        args: tuple[str, ...], needle: str) -> None:
    status, out, err = run_cli(capsys, "experiment", "--episodes", "1", "--out", str(tmp_path / "x"), *args)
    assert_one_line_error(status, out, err, needle)
    assert not (tmp_path / "x").exists()


# ----------------------------------------------------------------- the conflict map
def test_conflict_map_on_varied_junctions(layouts: dict[str, Layout]) -> None:
    """On every junction: overlap intervals are ordered, the conflict point lies in the
    conflict zone, an ego standing well before the zone is outside it, and the left route
    meets the ego's path only after the obstacle has left its start."""
    for name, layout in layouts.items():
        cmap = conflict_map(layout, 0.3)
        finite = np.isfinite(cmap.q_lo)
        assert finite.any() and np.all(cmap.q_lo[finite] <= cmap.q_hi[finite]), name
        q_conflict = float(layout.route_ego.project(layout.conflict)[0])
        assert cmap.inside(q_conflict) and not cmap.inside(q_conflict - 15.0), (name, cmap.zone)
        assert cmap.cleared(q_conflict + 20.0) and not cmap.cleared(q_conflict), name
        s_start = float(layout.route_left.project(layout.obstacle_start[:2])[0])
        assert np.flatnonzero(finite)[0] * cmap.ds > s_start + 1.0, name
        assert np.all(np.diff(cmap.q_lo_ahead) >= 0.0), name  # the least q_lo from j on


def _brute_force_mask(layout: Layout, margin: float, hyp: tuple[float, ...], plans: np.ndarray,
                      dt: float) -> int:
    """The plans one hypothesis collides with, from the two widened boxes at every tick."""
    s, v, a, v_max, delay = hyp
    v_max = max(v_max, v)
    ego_car, obstacle_car = widened(layout.ego, margin), widened(layout.obstacle, margin)
    v_start = v if delay <= 0.0 else 0.0
    speeds = [v_start] + [min(max(v_start + a * ((k + 1) * dt - delay), 0.0), v_max) if (k + 1) * dt > delay
                          else 0.0 for k in range(plans.shape[1])]
    arc = s + np.cumsum(0.5 * (np.array(speeds[1:]) + np.array(speeds[:-1])) * dt)
    obstacle = obstacle_car.footprint(route_poses(layout.route_left, arc))
    mask = 0
    for p, q in enumerate(plans):
        if boxes_overlap(ego_car.footprint(route_poses(layout.route_ego, q)), obstacle).any():
            mask |= 1 << p
    return mask


def test_compiled_rollouts_agree_with_the_boxes(layouts: dict[str, Layout]) -> None:
    """Random hypotheses on every junction: the compiled kernel's collisions per plan are
    those of the two boxes tested tick by tick (up to the table's 0.1 m steps: at least 95 %
    of hypotheses exactly, measured 99-100 %)."""
    rng = np.random.default_rng(7)
    config = ScenarioConfig()
    for name, layout in layouts.items():
        rule = RiskRule(RiskConfig(horizon=4.0))
        rule.reset(PlannerContext.of(layout, config))
        same = total = 0
        q_conflict = float(layout.route_ego.project(layout.conflict)[0])
        for _ in range(12):
            ego = route_poses(layout.route_ego, np.array([q_conflict - rng.uniform(8.0, 45.0)]))[0]
            ego[3] = rng.uniform(0.0, 14.0)
            plans = rule.plans(ego)
            hyps = np.column_stack([rng.uniform(0.0, 25.0, 20), rng.uniform(0.0, 8.0, 20), rng.uniform(0.0, 3.0, 20),
                                    rng.uniform(5.0, 10.0, 20), rng.choice([0.0, 0.0, 0.5, 1.5], 20)])
            for hyp in hyps:
                one = [np.array([x]) for x in hyp]
                m = collision_masses(np.ones(1), *one, plans, config.timing.dt, rule.map.ds, rule.map.q_lo,
                                     rule.map.q_hi, rule.map.q_lo_ahead)
                mask = int(np.flatnonzero(m)[0])
                same += mask == _brute_force_mask(layout, 0.3, tuple(hyp), plans, config.timing.dt)
                total += 1
        assert same >= 0.95 * total, (name, same, total)


def _plain_masses(hyps: np.ndarray, plans: np.ndarray, dt: float, cmap: Any, lazy: int, gate: int,
                  rss: tuple[int, float, int, float] = (0, 1.0, 0, 1.0)) -> np.ndarray:
    """:func:`collision_masses` as first written (every tick of every hypothesis tested
    against every open plan, in Python): the reference its faster rolls must equal exactly.
    ``rss`` = (bit mask of rows, their final brake [m/s^2], the table index from which the
    obstacle is in the lane, the obstacle's full brake [m/s^2]): those rows also collide on
    a tick on which they are behind the obstacle in the lane and stop (last arc length plus
    the braking distance from the last tick's speed) past where the ego would touch the
    obstacle had that braked to a stop from then."""
    rss_rows, rss_brake, lane_from, lead_brake = rss
    n_plans, n_steps = plans.shape
    stops = [plans[p, -1] + max((plans[p, -1] - plans[p, -2]) / dt - 0.5 * rss_brake * dt, 0.0) ** 2 / (2 * rss_brake)
             for p in range(n_plans)]
    full, out = (1 << n_plans) - 1, np.zeros(1 << n_plans)
    lazy_bit, gate_bit = (1 << lazy) if lazy >= 0 else 0, (1 << gate) if gate >= 0 else 0
    q_lo, q_hi, ahead_of = cmap.q_lo, cmap.q_hi, cmap.q_lo_ahead
    first = next((j for j in range(len(q_lo)) if q_lo[j] <= q_hi[j]), len(q_lo))
    for w, s, v, a, vm, d in hyps:
        vm, v_start = max(vm, v), (v if d <= 0.0 else 0.0)
        v_prev, mask, done = v_start, 0, 0
        for k in range(n_steps):
            t = (k + 1) * dt
            v_now = min(max(v_start + a * (t - d), 0.0), vm) if t > d else 0.0
            s += (v_prev + v_now) * (0.5 * dt)
            v_prev = v_now
            if s < (first - 0.5) * cmap.ds:
                continue
            j = int(s * (1.0 / cmap.ds) + 0.5)
            if j >= len(q_lo):
                break
            if j < first:
                continue
            for p in range(n_plans):
                if not done & (1 << p):
                    held = rss_rows >> p & 1
                    if q_lo[j] <= plans[p, k] <= q_hi[j]:
                        mask, done = mask | (1 << p), done | (1 << p)
                    elif ahead_of[j] > (max(plans[p, -1], stops[p]) if held else plans[p, -1]):
                        done |= 1 << p
                    elif held and j >= lane_from and plans[p, k] < q_lo[j]:
                        j_stop = min(int((s + v_now * v_now / (2.0 * lead_brake)) / cmap.ds + 0.5), len(q_lo) - 1)
                        if stops[p] >= q_lo[j_stop]:
                            mask, done = mask | (1 << p), done | (1 << p)
            if (done | lazy_bit if (done & gate_bit) and not (mask & gate_bit) else done) == full:
                break
        out[mask] += w
    return out


def _random_case(rng: np.random.Generator, layout: Layout, rule: LayeredRule) -> tuple[np.ndarray, np.ndarray]:
    """The rule's plans for an ego up to 45 m short of (or 2 m past) the conflict point at
    0-15 m/s, and 40 random hypotheses around it: columns weight, arc length on the left
    route [m], speed [m/s], acceleration [m/s^2], top speed [m/s], delay [s]."""
    q_conflict = float(layout.route_ego.project(layout.conflict)[0])
    s_conflict = float(layout.route_left.project(layout.conflict)[0])
    ego = route_poses(layout.route_ego, np.array([q_conflict - rng.uniform(-2.0, 45.0)]))[0]
    ego[3] = rng.uniform(0.0, 15.0)
    n = 40
    hyps = np.column_stack([rng.uniform(0.1, 1.0, n), s_conflict + rng.uniform(-20.0, 30.0, n),
                            rng.uniform(0.0, 9.0, n), rng.uniform(-2.0, 3.0, n), rng.uniform(3.0, 16.0, n),
                            rng.choice([0.0, 0.0, 0.4, 1.5, 9.0], n)])
    return rule.plans(ego), hyps


def test_the_compiled_rolls_equal_the_plain_rolls_exactly(layouts: dict[str, Layout]) -> None:
    """The kernel's shortcuts (a single plan left open rolls without the table while short of
    every overlap ahead) leave every mass as the plain tick-by-tick rolls give it, bit for
    bit, with all plans exact and with going on followed lazily (the risk rule's call)."""
    rng = np.random.default_rng(11)
    config = ScenarioConfig()
    for name, layout in layouts.items():
        rule = LayeredRule()
        rule.reset(PlannerContext.of(layout, config))
        cmap = rule.map
        for trial in range(6):
            plans, hyps = _random_case(rng, layout, rule)
            for lazy, gate in ((-1, -1), (GO, DEFER)):
                got = collision_masses(*(np.ascontiguousarray(c) for c in hyps.T), plans, config.timing.dt, cmap.ds,
                                       cmap.q_lo, cmap.q_hi, cmap.q_lo_ahead, lazy, gate)
                assert np.array_equal(got, _plain_masses(hyps, plans, config.timing.dt, cmap, lazy, gate)), (
                    name, trial, lazy)


def test_the_option_rows_rss_rolls_equal_the_plain_rolls_exactly(layouts: dict[str, Layout]) -> None:
    """With the RSS test on the option rule's plans that end in the comfortable brake (its
    call), every mass is the plain tick-by-tick roll's, bit for bit, on every junction; and
    the test changes some masks (hypotheses of a car in the lane ahead that those plans
    would end too close to), only ever adding collisions to those rows."""
    rng = np.random.default_rng(12)
    config = ScenarioConfig()
    changed = 0
    for name, layout in layouts.items():
        rule = LayeredRule(LayeredConfig(anticipation="option", option_time=0.5, anticipate=0.9,
                                         anticipate_release=0.45))
        rule.reset(PlannerContext.of(layout, config))
        cmap, lane_from = rule.map, lane_entry(layout, FOLLOW_WITHIN)
        assert 0 < lane_from < len(cmap.q_lo)
        assert lane_entry(layout, math.radians(30.0)) >= lane_from  # a stricter heading: later in the turn
        with pytest.raises(ValueError, match=r"^lane_entry: within=-1\.0 must be in \[0, pi\]"):
            lane_entry(layout, -1.0)
        for trial in range(6):
            plans, hyps = _random_case(rng, layout, rule)
            assert len(plans) == SLOW_RSS + 1
            rss = ((1 << OPTION) | (1 << SLOW_RSS), 2.5, lane_from, layout.obstacle.max_brake)
            got = collision_masses(*(np.ascontiguousarray(c) for c in hyps.T), plans, config.timing.dt, cmap.ds,
                                   cmap.q_lo, cmap.q_hi, cmap.q_lo_ahead, -1, -1, *rss)
            assert np.array_equal(got, _plain_masses(hyps, plans, config.timing.dt, cmap, -1, -1, rss)), (name, trial)
            plain = _plain_masses(hyps, plans, config.timing.dt, cmap, -1, -1)
            for row in range(len(plans)):
                more = got[_has(row, len(plans))].sum() - plain[_has(row, len(plans))].sum()
                assert (more >= -1e-12) if row in (OPTION, SLOW_RSS) else abs(more) < 1e-12, (name, trial, row)
            changed += not np.array_equal(got, plain)
    assert changed > 0


def _has(row: int, n_plans: int) -> np.ndarray:
    """The masks (indices of :func:`collision_masses`' output) with plan ``row``'s bit set."""
    return (np.arange(1 << n_plans) & (1 << row)) != 0


def test_the_option_is_lost_short_of_the_rss_distance_behind_a_merged_car(scene: Scene) -> None:
    """A car already in the ego's lane 25 m ahead at 4 m/s, which the ego at 13.4 m/s would
    hit going on: the option plan (going on 0.5 s, then 2.5 m/s^2 to a stop) and slowing
    now never touch it as it drives on, but stop past where it would stop from its full
    brake, so the option is lost and slowing is short; 60 m ahead at 12 m/s both are kept.
    Version 0.3's plans and readings are unchanged."""
    layout = scene.layout()
    config = ScenarioConfig()
    option = LayeredRule(LayeredConfig(anticipation="option", option_time=0.5, anticipate=0.9,
                                       anticipate_release=0.45))
    option.reset(PlannerContext.of(layout, config))
    lane_from = lane_entry(layout, FOLLOW_WITHIN)
    s_lane = (lane_from + 40) * option.map.ds  # [m] on its left route, well in the lane
    q_ego = float(option.map.q_lo[lane_from + 40]) - 25.0  # [m] the ego 25 m short of touching it
    ego = route_poses(layout.route_ego, np.array([q_ego]))[0]
    ego[3] = 13.4
    near = Futures(np.ones(1), np.array([s_lane]), np.array([4.0]), np.zeros(1), np.array([4.0]), np.zeros(1))
    read, _ = option._read(ego, near)
    assert read[2] == 1.0 and read[OPTION] == 1.0 and read[SLOW_RSS] == 1.0  # collides going on; both short
    assert read[3] == 0.0  # slowing's boxes never meet
    plans = option.plans(ego)
    plain = collision_masses(near.weight, near.s, near.v, near.accel, near.v_max, near.delay, plans,
                             config.timing.dt, option.map.ds, option.map.q_lo, option.map.q_hi,
                             option.map.q_lo_ahead)
    assert plain[_has(OPTION, len(plans))].sum() == 0.0  # the boxes alone keep it
    far = Futures(np.ones(1), np.array([s_lane + 35.0]), np.array([12.0]), np.zeros(1), np.array([12.0]),
                  np.zeros(1))
    assert option._read(ego, far)[0][OPTION] == 0.0 == option._read(ego, far)[0][SLOW_RSS]
    go = LayeredRule()
    go.reset(PlannerContext.of(layout, config))
    assert len(go.plans(ego)) == OPTION and len(go._read(ego, near)[0]) == OPTION


def test_the_escalation_has_its_own_threshold(scene: Scene) -> None:
    """Seed 23 of the default world, a Yield whose driver is seen late: the option rule at
    anticipate 0.5 slows from 0.5 s and, its escalation reading that threshold too, turns
    the slowing into a hard brake at 0.6 s; with the escalation at 1.0 the same slowing
    stays comfortable. An escalation threshold out of range is one clear error."""
    def brake_time(escalate: float | None) -> float | None:
        layers = LayeredConfig(anticipation="option", option_time=1.0, anticipate=0.5, anticipate_release=0.25,
                               escalate=escalate)
        return run_episode(ScenarioConfig(), 23, CDFPlanner(CDFConfig(layered=layers)), scene, label=False).brake_time

    assert brake_time(None) is not None and brake_time(0.5) == brake_time(None)
    assert brake_time(1.0) is None
    with pytest.raises(ValueError, match=r"layered\.escalate"):
        LayeredConfig(escalate=1.5)


def test_plans_brake_and_go_as_the_ego_would(scene: Scene) -> None:
    layout = scene.layout()
    rule = RiskRule()
    rule.reset(PlannerContext.of(layout, ScenarioConfig()))
    ego = route_poses(layout.route_ego, np.array([100.0]))[0]
    ego[3] = 13.4
    plans = rule.plans(ego)
    assert plans.shape == (3, 50)
    travel = plans[:, -1] - 100.0
    assert travel[GO] == pytest.approx(13.4 * 5.0, rel=1e-6)
    stop = 13.4 ** 2 / (2 * layout.ego.max_brake)
    assert travel[BRAKE] == pytest.approx(stop, abs=0.4)
    assert travel[DEFER] == pytest.approx(stop + 13.4 * 0.2, abs=0.4)  # one interval + 0.1 s latency
    assert np.all(np.diff(plans, axis=1) >= 0.0)


# ----------------------------------------------------------------- the rule
def test_a_standing_car_at_the_line_is_no_risk_and_a_car_in_the_lane_is(scene: Scene) -> None:
    layout = scene.layout()
    rule = RiskRule()
    rule.reset(PlannerContext.of(layout, ScenarioConfig()))
    q_conflict = float(layout.route_ego.project(layout.conflict)[0])
    ego = route_poses(layout.route_ego, np.array([q_conflict - 20.0]))[0]
    ego[3] = 13.4
    s_conflict = float(layout.route_left.project(layout.conflict)[0])

    def futures(s: float, v: float, delay: float = 0.0) -> Futures:
        one = np.ones(1)
        return Futures(weight=one, s=one * s, v=one * v, accel=one * 0.0, v_max=one * v, delay=one * delay)

    standing = rule.assess(ego, futures(0.0, 0.0), exact=True)
    assert standing.go == standing.deferred == standing.brake == 0.0
    crossing = rule.assess(ego, futures(s_conflict - 3.0, 4.0), exact=True)
    assert crossing.go == 1.0  # going on meets it; braking now (20 m for an 18.4 m stop) does not
    assert crossing.brake == 0.0
    assert rule.assess(ego, Futures.empty(), exact=True).go == 0.0
    assert math.isnan(rule.assess(ego, futures(s_conflict - 3.0, 4.0)).go)  # only when asked for


class _StubRule:
    """A rule that releases: brakes on the ticks at which the predictor's alarm is 1."""

    name = "stub"
    releases = True
    history_keys = ("alarm",)

    def reset(self, context: PlannerContext) -> None:
        self.alarm = 0.0

    def decide(self, predictor: Any, ego_pose: np.ndarray, braking: bool) -> bool:
        self.alarm = predictor.alarm()
        return self.alarm >= 1.0

    def values(self) -> dict[str, float]:
        return {"alarm": self.alarm}


class _Pulses(DecidingPlanner):
    """Alarms from 0.5 s to 0.7 s and from 1.5 s to 1.6 s."""

    name = "pulses"
    history_keys: ClassVar[tuple[str, ...]] = ()

    def __init__(self, rule: Any) -> None:
        self.rule = rule

    def observe(self, obs: PlannerInput) -> None:
        self.record(obs.t)
        self._on = 0.45 < obs.t < 0.75 or 1.45 < obs.t < 1.65

    def alarm(self) -> float:
        return 1.0 if self._on else 0.0


def test_the_episode_follows_a_rule_that_releases_and_holds_one_that_does_not(scene: Scene) -> None:
    config = ScenarioConfig(timing={"duration": 2.0})
    released = run_episode(config, 4, _Pulses(_StubRule()), scene, label=False, trace=True)
    flags = released.trace["brake"]
    times = [round(t, 1) for t, b in zip(released.trace["t"], flags, strict=True) if b]
    assert times == [0.5, 0.6, 0.7, 1.5, 1.6]
    info = released.planner_info
    assert released.brake_time == info["decision_time"] == 0.5
    assert info["brakes"] == [[0.5, 0.8], [1.5, 1.7]] and info["release_time"] == 1.7
    assert info["rule"] == "stub" and len(info["history"]["alarm"]) == len(info["history"]["t"])
    held = run_episode(config, 4, _Pulses(ThresholdRule(1.0)), scene, label=False, trace=True)
    assert held.brake_time == 0.5 and all(held.trace["brake"][5:]) and held.planner_info["release_time"] is None
    assert released.time_lost < held.time_lost


def test_predictors_compose_with_either_rule() -> None:
    assert {"cdf", "cdf-risk", "cdf-threshold", "imm", "imm-risk", "imm-layered", "cv", "cv-risk",
            "cv-layered"} <= set(PLANNERS)
    for name, rule in (("cdf", "layered"), ("cdf-risk", "risk"), ("cdf-threshold", "threshold"),
                       ("imm", "threshold"), ("imm-risk", "risk"), ("imm-layered", "layered"),
                       ("cv", "threshold"), ("cv-risk", "risk"), ("cv-layered", "layered")):
        planner = make_planner(name)
        assert isinstance(planner, DecidingPlanner) and planner.rule.name == rule, name
        assert planner.releases_brake == (rule != "threshold"), name
        assert planner.graded == (rule == "layered"), name
    assert not make_planner("reactive").releases_brake


def test_the_risk_rule_avoids_cutoffs_and_releases_after_false_alarms(scene: Scene) -> None:
    """Seeds 0-39: no collision with the obstacle in any episode; every Cutoff braked for;
    no brake for a right-turner; every brake in an episode that is not a Cutoff released
    by the end; no episode ends with the ego standing in the conflict zone with its brake
    on (an earlier version did in 11 of 16 braking episodes). Measured: 17 Cutoff, 0
    collisions, 0-1 false alarms. The ego without its following controller: every brake is
    the rule's own."""
    config = ScenarioConfig().with_values({"ego.follow": False})
    planner_runs = [run_episode(config, seed, "cdf-risk", scene, trace=True) for seed in range(40)]
    assert sum(r.label == "Cutoff" for r in planner_runs) >= 10
    cmap = conflict_map(scene.layout(), RiskConfig().margin)
    for r in planner_runs:
        assert r.collision_with != "obstacle", r.seed
        if r.label == "Cutoff":
            assert r.brake_time is not None, r.seed
        elif r.label == "Right":
            assert r.brake_time is None, r.seed
        elif r.brake_time is not None:
            assert r.planner_info["brakes"][-1][1] is not None, (r.seed, r.planner_info["brakes"])
        ego = np.asarray(r.trace["poses"][-1][0])
        standing_in_zone = ego[3] < 0.5 and cmap.inside(cmap.ego_arc(ego))
        assert not (r.trace["brake"][-1] and standing_in_zone), (r.seed, r.planner_info["brakes"])


def test_the_rollout_reference_reads_the_same_risk(scene: Scene) -> None:
    """The filter's own model rolled forward and the compiled closed form read the same
    deferred risk within 0.15 on the ticks around seed 1's brake (measured: 0.05-0.11 apart,
    the rollout a little higher: its process noise spreads the particles)."""
    config, cdf = ScenarioConfig(), CDFConfig(n_particles=300, decision="risk")
    world = World(scene, config)
    world.reset(1)
    planner = CDFPlanner(cdf)
    planner.reset(PlannerContext.of(world.layout, config), world.rng["planner"])
    rule = planner.rule
    assert isinstance(rule, RiskRule)
    pf = planner.filter
    compared = 0
    while not world.done and world.t < 3.0:
        m = world.measure()
        if world.t == 0.0:
            pf.reset(m.poses)
        else:
            pf.update(m.poses)
        if 2.3 <= world.t <= 2.7:
            fast = rule.assess(m.poses[0], pf.futures(rule.react_ticks), exact=True)
            slow = rollout_assessment(pf, rule, m.poses[0], np.random.default_rng(0))
            assert abs(fast.deferred - slow.deferred) <= 0.15, (world.t, fast, slow)
            assert abs(fast.go - slow.go) <= 0.15, (world.t, fast, slow)
            compared += 1
        pf.predict(m.poses)
        world.step(np.array([0.0, 0.0]))
    assert compared == 5


def _futures_reference(pf: Any, react_ticks: int) -> Futures:
    """The filter's futures in NumPy from the driver's own clear rule (road_clear) and lines
    of sight computed afresh (not the filter's caches)."""
    from cdf_mj.model.driver import DriverParams, Mode, road_clear
    from cdf_mj.model.occlusion import sight_targets

    left = np.flatnonzero((pf.intent == 0) & (pf.weights > 0.0))
    w, mode, theta = pf.weights[left].copy(), pf.mode[left], pf.theta[left]
    s = pf.model.routes[0].project(pf.pose[left, :2])[0]
    v, delay = pf.pose[left, 3].copy(), np.zeros(left.size)
    held = (mode == Mode.WAITING) | (mode == Mode.YIELDING)
    waiting = mode == Mode.WAITING
    v[held] = 0.0
    params = DriverParams(accel=0.0, turn_speed=0.0, yield_brake=0.0, critical_gap=theta[:, 3],
                          clear_distance=theta[:, 4])
    clear = road_clear(pf.model, pf.belief[left], pf.has_belief[left], pf.intent[left], params)
    b = pf.belief[left]
    ahead = (pf.model.conflict[0] - b[:, 0]) * np.cos(b[:, 2]) + (pf.model.conflict[1] - b[:, 1]) * np.sin(b[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        passes = np.where(b[:, 3] > 0.1, (ahead + pf.model.passed_margin) / b[:, 3], np.inf)
    delay[held] = np.where(clear, 0.0, np.maximum(passes, 0.0))[held]
    w *= np.where(waiting, 1.0 - (1.0 - theta[:, 6]) ** react_ticks, 1.0)
    # A look stops it only where its clear rule finds the (true) ego it sees not clear.
    ego = np.broadcast_to(pf._ego_pose(), (left.size, 4))
    seen_clear = road_clear(pf.model, ego, np.ones(left.size, dtype=bool), pf.intent[left], params)
    visible = pf.occluders.visible(pf.obstacle.eye(pf.pose[left]), sight_targets(pf.ego, pf._ego_pose()))
    u = (mode != Mode.COMMITTED) & visible & ~seen_clear
    remaining = np.maximum(pf.model.s_commit[0] - s, 0.0)
    t_commit = (np.sqrt(v * v + 2.0 * theta[:, 0] * remaining) - v) / theta[:, 0]
    w[u] *= (1.0 - theta[u, 5]) ** np.ceil(t_commit[u] / pf.dt - 1e-9)
    keep = np.isfinite(delay) & (w > 0.0)
    return Futures(w[keep], s[keep], v[keep], theta[keep, 0], theta[keep, 1], delay[keep])


def test_the_filter_futures_follow_the_drivers_clear_rule(scene: Scene) -> None:
    """On every tick of drivers who go at once and who wait 1-2 s (seeds 0-3), the compiled
    futures equal a NumPy reference built on :func:`cdf_mj.model.driver.road_clear`."""
    from cdf_mj.model.driver import ego_control

    compared = 0
    waiting = ScenarioConfig(obstacle={"stop_dwell": (1.0, 2.0)}, ego={"start_spread": (-30.0, -20.0)})
    for config in (ScenarioConfig(), waiting):
        for seed in range(4):
            world = World(scene, config)
            world.reset(seed)
            planner = CDFPlanner(CDFConfig(n_particles=200))
            planner.reset(PlannerContext.of(world.layout, config), world.rng["planner"])
            while not world.done:
                m = world.measure()
                brake = planner.brake(PlannerInput(t=m.t, poses=m.poses, obstacle_in_lane=m.obstacle_in_lane))
                got, want = planner.filter.futures(2), _futures_reference(planner.filter, 2)
                for a, b in zip((got.weight, got.s, got.v, got.accel, got.v_max, got.delay),
                                (want.weight, want.s, want.v, want.accel, want.v_max, want.delay), strict=True):
                    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
                compared += got.weight.size
                world.step(ego_control(world.driver, world.layout.ego, m.poses[0], brake))
    assert compared > 10000


# ----------------------------------------------------------------- scripts/decision.py
DECISION_SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "decision.py"


def test_the_decision_report_runs_end_to_end_and_refuses_bad_parts(tmp_path: Path) -> None:
    import importlib.util
    import json
    import subprocess
    import sys

    out, doc = tmp_path / "results", tmp_path / "D.md"
    argv = [sys.executable, str(DECISION_SCRIPT), "--parts", "held-out,stop-and-wait", "--episodes", "3",
            "--workers", "1", "--quiet", "--out", str(out), "--doc", str(doc)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = doc.read_text()
    records = [json.loads(line) for line in (out / "held-out" / "episodes.jsonl").read_text().splitlines()]
    planners = ("cdf", "cdf-option", "cdf-risk", "cdf-threshold", "imm-layered", "cv-layered", "caution-waiting",
                "caution-moving", "caution-phantom", "reactive", "constant")
    challengers = ("caution-waiting", "caution-moving", "caution-phantom", "imm-layered", "cv-layered")
    assert sorted((r["seed"], r["planner"]) for r in records) == sorted(
        (s, p) for s in range(400000, 400003) for p in planners)  # the held-out range first used by issue 35
    assert {r["planner_info"].get("rule") for r in records if r["planner"] not in ("reactive", "constant")} == {
        "layered", "risk", "threshold"}
    presets = [json.loads(line) for line in (out / "stop-and-wait" / "episodes.jsonl").read_text().splitlines()]
    assert {r["planner"] for r in presets} == {"cdf", "cdf-option", *challengers, "reactive", "constant"}
    for planner in planners:
        assert f"\n| {planner} | " in text
        assert f"- `{planner}`: " in text  # each planner described on the page
    assert "seeds 400000-400002 (a range first used here)" in text
    held_out = text.split("## Default scenario, held-out seeds", 1)[1].split("\n## Preset", 1)[0]
    for part in (held_out, text.split("## Preset `stop-and-wait`", 1)[1]):
        for first in ("cdf", "cdf-option"):  # each against every challenger: table row and verdict
            for other in challengers:
                assert f"\n| {first} / {other} | 3 | " in part and f"\n- {first} / {other}: " in part
        assert "\n| cdf-option / cdf | 3 | " in part and "\n| cdf / cdf-option |" not in part  # once, option first
        for first in ("cdf", "cdf-option"):  # issue 35's targets for both, each line judged with its figure
            targets = part.split(f"Issue 35's targets for `{first}` (point estimates):\n\n", 1)[1].split("\n\n")[0]
            lines = targets.splitlines()
            assert len(lines) == 8 and all(line.endswith(("met", "**missed**", "not measured", "met (it is "
                                                           "today's rule)")) for line in lines), targets
            assert "no worse than today's rule (`cdf`)" in targets
            assert f"dominates `{first}` (of caution-waiting, caution-moving, caution-phantom, imm-layered (" in targets
    for first in ("cdf", "cdf-option"):
        assert f"The earlier issues' targets for `{first}`" in held_out
    # The page says which rule slows on the prior and which waits for the belief.
    assert "it slows on the prior, before the belief has any evidence" in text and "waits for the belief" in text
    assert "- `cdf-option`: " in text and "Layered rule: option 0.5 s, 0.9." in text
    assert "hard-brake false alarms" in text and "| false alarms" not in text
    assert "interventions, Yield (95 % CI)" in text and "Hard subset: " in text
    assert "Safety margins over the Cutoff episodes" in text and "TTC at the first hard brake" in text
    assert "## Preset `stop-and-wait`, held-out seeds" in text and "Few seeds" in text
    if importlib.util.find_spec("matplotlib") is not None:  # the figure beside the page (seed 400002: Right)
        assert (tmp_path / "img" / "decision" / "pareto.png").stat().st_size > 10_000
        assert "](img/decision/pareto.png)" in text
    again = subprocess.run(argv, capture_output=True, text=True, timeout=300)  # resumed: nothing runs
    assert again.returncode == 0 and doc.read_text() == text
    for bad_args, needle in ((["--parts", "held-out,nope"], "unknown part(s) nope"),
                             (["--tuning", str(tmp_path / "no-tuning")], "--tuning: tuning directory")):
        bad = subprocess.run([*argv[:2], *bad_args, "--out", str(tmp_path / "r2"), "--doc", str(tmp_path / "D2.md")],
                             capture_output=True, text=True, timeout=120)
        assert bad.returncode == 2 and bad.stderr.startswith(f"decision: error: {needle}"), bad.stderr
        assert len(bad.stderr.strip().splitlines()) == 1
        assert not (tmp_path / "r2").exists() and not (tmp_path / "D2.md").exists()


def _one(s: float, v: float, accel: float = 0.0, v_max: float | None = None) -> Futures:
    one = np.ones(1)
    return Futures(weight=one, s=one * s, v=one * v, accel=one * accel, v_max=one * (v if v_max is None else v_max),
                   delay=np.zeros(1))


@pytest.mark.parametrize("name", ["default", "rotated, mirrored, 3.2 m"])
def test_decide_brakes_at_the_last_safe_moment_and_releases(layouts: dict[str, Layout], name: str) -> None:
    """One crossing hypothesis, the ego approaching at 13.4 m/s: no brake while braking
    later still avoids it, a brake at the first distance where deferring would not (and
    braking then avoids it); released once the hypothesis is gone, outside and inside the
    conflict zone; held where every plan collides (a car standing just ahead)."""
    layout = layouts[name]
    rule = RiskRule()
    rule.reset(PlannerContext.of(layout, ScenarioConfig()))
    q_conflict = float(layout.route_ego.project(layout.conflict)[0])
    s_conflict = float(layout.route_left.project(layout.conflict)[0])
    crossing = GivenFutures(_one(s_conflict - 4.0, 3.0, accel=2.0, v_max=8.0))

    def ego_at(q: float, v: float) -> np.ndarray:
        pose = route_poses(layout.route_ego, np.array([q]))[0]
        pose[3] = v
        return pose

    decisions = [(d, rule.decide(crossing, ego_at(q_conflict - d, 13.4), False)) for d in np.arange(60.0, 5.0, -0.5)]
    first = next(d for d, brake in decisions if brake)
    assert all(not brake for d, brake in decisions if d > first + 1e-9)
    a = rule.assess(ego_at(q_conflict - first, 13.4), crossing.futures(1), exact=True)
    assert a.deferred >= RiskConfig().brake and a.brake == 0.0 and a.go == 1.0, (first, a)
    nothing = GivenFutures(Futures.empty())
    assert not rule.decide(nothing, ego_at(q_conflict - first, 13.4), True)  # released outside the zone
    inside = rule.map.zone[0] + 0.5
    assert rule.map.inside(inside)
    assert not rule.decide(nothing, ego_at(inside, 0.0), True)  # released inside the zone
    s_ahead = s_conflict + 12.0  # a car standing in the lane, just ahead of the stopped ego
    standing = GivenFutures(_one(s_ahead, 0.0))
    blocked = rule.map.q_lo[int(s_ahead / rule.map.ds + 0.5)]
    a = rule.assess(ego_at(blocked - 10.0, 13.4), standing.futures(1), exact=True)
    assert a.deferred == a.brake == a.go == 1.0  # too close to stop: every plan hits it
    assert rule.decide(standing, ego_at(blocked - 10.0, 13.4), False)  # brakes all the same
    assert rule.decide(standing, ego_at(blocked - 0.5, 2.0), True)  # and holds the brake


def test_a_junction_whose_routes_never_meet_is_refused(scene: Scene) -> None:
    import dataclasses

    layout = scene.layout()
    moved = type(layout.route_left)(layout.route_left.points + np.array([0.0, 500.0]))  # 500 m north
    far = dataclasses.replace(layout, route_left=moved)
    with pytest.raises(ValueError, match="never meets the ego's route"):
        RiskRule().reset(PlannerContext.of(far, ScenarioConfig()))


def test_a_right_turner_long_enough_to_reach_the_ego_is_found(scene):
    """The drivers' model takes a right-turner for one that never meets the ego. Our car on
    the package's junction never does (no overlap anywhere on the right route); a 10 m
    obstacle does, and the arc length given is one where its box truly overlaps an ego
    box on the ego's route (``World`` warns of it)."""
    layout = scene.layout()
    assert right_turn_overlap(layout) is None
    long_car = dataclasses.replace(layout.obstacle, hull_offset=np.array([2.6, 0.0]),
                                   hull_half=np.array([5.0, 1.25]))
    long_layout = layout.with_cars(obstacle=long_car)
    s = right_turn_overlap(long_layout)
    assert s is not None
    obs = long_car.footprint(route_poses(long_layout.route_right, np.array([s])))
    q = np.arange(0.0, layout.route_ego.length, 0.1)
    ego = layout.ego.footprint(route_poses(layout.route_ego, q))
    assert boxes_overlap(np.broadcast_to(obs, ego.shape), ego).any()


def test_the_world_refuses_an_ego_start_off_its_route(scene):
    """An ego_start_spread that would place the ego past the end of its route (where the
    start heading is taken between two clamped, equal points) is one clear error."""
    with pytest.raises(ValueError, match=r"ego\.start_spread=.*off its route"):
        World(scene, ScenarioConfig(ego={"start_spread": (195.0, 195.0)}))
    World(scene, ScenarioConfig())  # the default spread is on it
