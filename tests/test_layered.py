"""The graded command and the layered rule (docs/DECISION.md): each layer on hypotheses of
our own (GivenFutures) on the package's junction, the ego's actuator, what the ego is
told, and closed loop: a user's ego on junctions of its own obeying the monitor's
``Decision.accel`` every tick while the other car cuts in and then brakes, slows or
stops, or the user's brakes act 0.2 s late."""

from __future__ import annotations

import math

import numpy as np
import pytest
from junctions import junction_scene

from cdf_mj.config import CDFConfig, LayeredConfig, RiskConfig, ScenarioConfig, SceneNames
from cdf_mj.model.conflict import Futures, conflict_map
from cdf_mj.model.driver import ego_control
from cdf_mj.planners.base import PlannerContext, PlannerInput
from cdf_mj.planners.decision import GivenFutures, LayeredRule
from cdf_mj.planners.registry import make_planner
from cdf_mj.scenario.episode import episode_label, run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.sensing import CommandDelay, JerkLimiter
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import Scene

DT = 0.1
LAYERS = LayeredConfig()
NO_FUTURE = GivenFutures(Futures.empty())


def _rule(scene: Scene, **context: object) -> LayeredRule:
    rule = LayeredRule()
    rule.reset(PlannerContext(layout=scene.layout(), dt=DT, nominal_speed=13.4, **context))  # type: ignore[arg-type]
    return rule


def _ego_at(scene: Scene, q: float, v: float) -> np.ndarray:
    """The ego's pose on its route at arc length ``q`` [m] with speed ``v`` [m/s]."""
    route = scene.layout().route_ego
    a, b = route.point_at(q), route.point_at(q + 1.0)
    return np.array([a[0], a[1], math.atan2(b[1] - a[1], b[0] - a[0]), v])


def _far_obstacle() -> np.ndarray:
    return np.array([-1.85, 8.35, -math.pi / 2, 0.0])  # at its stop line, facing south


def _going(s: float, v: float, weight: float = 1.0, delay: float = 0.0) -> Futures:
    """One left-turner at arc length ``s`` [m] of its route, speed ``v``, pulling away at 2 m/s^2."""
    one = np.ones(1)
    return Futures(weight=one * weight, s=one * s, v=one * v, accel=one * 2.0, v_max=one * 8.0, delay=one * delay)


def _ask(rule: LayeredRule, futures: GivenFutures, t: float, ego: np.ndarray,
         obstacle: np.ndarray | None = None, in_lane: bool = False) -> float:
    poses = np.stack([ego, _far_obstacle() if obstacle is None else obstacle])
    return rule.command(futures, PlannerInput(t=t, poses=poses, obstacle_in_lane=in_lane))


# ------------------------------------------------------------------ the layers
def test_the_anticipation_layer_slows_gently_and_never_brakes_hard(scene: Scene) -> None:
    """A likely cut-off still far ahead: the command ramps down at the comfort jerk to the
    comfortable brake and stays there; it never reaches a hard brake."""
    rule = _rule(scene)
    cmap = conflict_map(scene.layout(), RiskConfig().margin)
    ego = _ego_at(scene, cmap.zone[0] - 45.0, 13.4)  # [m] 3.4 s before the zone at 13.4 m/s
    soon = GivenFutures(_going(0.0, 0.0, delay=0.5))  # pulls out in 0.5 s: in the way going on
    commands = [_ask(rule, soon, k * DT, ego) for k in range(10)]
    layers = rule.last_layers
    assert layers is not None and layers.go >= LAYERS.anticipate and layers.slow < layers.go
    assert layers.emergency < RiskConfig().brake
    finite = [c for c in commands if math.isfinite(c)]
    assert finite and min(finite) == pytest.approx(-LAYERS.comfort_brake)
    steps = np.diff([0.0, *finite[: finite.index(min(finite)) + 1]])
    assert np.all(steps >= -LAYERS.comfort_jerk * DT - 1e-9)  # the ramp's jerk
    assert all(c > -LAYERS.hard_brake for c in commands)


def test_the_emergency_layer_brakes_at_once_and_holds_for_the_dwell(scene: Scene) -> None:
    """A car already pulling out in front of a near ego: the full brake on the first tick;
    with the danger gone on the next tick it is held for ``dwell`` and then eased off at the
    comfort jerk, not dropped."""
    rule = _rule(scene)
    cmap = conflict_map(scene.layout(), RiskConfig().margin)
    ego = _ego_at(scene, cmap.zone[0] - 18.0, 13.4)
    assert _ask(rule, GivenFutures(_going(2.0, 2.0)), 0.0, ego) == -math.inf
    held: list[float] = []
    for k in range(1, 9):  # the ego's speed follows the command (its place is left where it was)
        ego = ego.copy()
        ego[3] -= DT * (scene.layout().ego.max_brake if not held or held[-1] == -math.inf else -held[-1])
        held.append(_ask(rule, NO_FUTURE, k * DT, ego))
    n_hold = round(LAYERS.dwell / DT)
    assert held[: n_hold - 1] == [-math.inf] * (n_hold - 1)
    eased = held[n_hold - 1:]
    assert eased[0] == pytest.approx(-LAYERS.comfort_brake + LAYERS.comfort_jerk * DT)  # down from the hard brake
    assert np.allclose(np.diff(eased), LAYERS.comfort_jerk * DT)


def test_the_follow_layer_keeps_the_rss_distance_behind_a_merged_car(scene: Scene) -> None:
    """Behind a car ahead in the ego's lane: the full brake while the gap is under the RSS
    distance; at two time gaps behind a car of its own speed no braking at all."""
    lay = scene.layout()
    ego = _ego_at(scene, 60.0, 13.4)
    ahead = _ego_at(scene, 60.0 + lay.ego.hull_half[0] * 2 + 6.0, 6.0)  # 6 m gap, much slower
    rule = _rule(scene)
    assert _ask(rule, NO_FUTURE, 0.0, ego, ahead, in_lane=True) == -math.inf
    assert rule.last_layers is not None and rule.last_layers.gap < rule.last_layers.rss
    lost = np.full(4, np.nan)  # a dropped measurement: the car ahead is kept, moved on at its speed
    assert _ask(rule, NO_FUTURE, DT, ego, lost, in_lane=False) == -math.inf
    assert rule.last_layers.gap < rule.last_layers.rss
    far = _ego_at(scene, 60.0 + lay.ego.hull_half[0] * 2 + 2 * 13.4 * LAYERS.time_gap, 13.4)
    rule = _rule(scene)
    assert all(_ask(rule, NO_FUTURE, k * DT, ego, far, in_lane=True) >= 0.0 for k in range(5))


def test_a_driver_waiting_for_a_standing_ego_does_not_hold_it_stopped(scene: Scene) -> None:
    """No deadlock: the ego stands before the conflict zone and the other driver stands at
    its line (a hypothesis that it may pull out at any moment); the ego is held at first,
    and once both have stood for ``standoff`` the waiting driver is taken to wait for it and
    the ego goes; once the other moves, its hypotheses count again."""
    rule = _rule(scene)
    cmap = conflict_map(scene.layout(), RiskConfig().margin)
    ego = _ego_at(scene, cmap.zone[0] - 4.0, 0.0)
    waiting = GivenFutures(_going(0.0, 0.0, delay=0.2))
    commands, q, v = [], cmap.zone[0] - 4.0, 0.0
    for k in range(50):  # the ego drives as commanded (its speed hold capped by the command)
        c = _ask(rule, waiting, k * DT, _ego_at(scene, q, v))
        commands.append(c)
        a = max(min(1.0 * (13.4 - v), 3.0, c), -4.877)
        q, v = q + max(v + 0.5 * a * DT, 0.0) * DT, max(v + a * DT, 0.0)
    standoff = round(LAYERS.standoff / DT)
    assert max(commands[:standoff]) <= 0.0 and min(commands[:standoff]) < 0.0  # held: no acceleration
    assert commands[standoff + 1] >= 0.0  # no dead time once it may go
    assert rule.last_layers is not None and rule.last_layers.standoff  # latched while the ego moves
    assert v > 2.0  # it went
    moving = _far_obstacle()
    moving[3] = 2.0
    _ask(rule, GivenFutures(_going(1.0, 2.0)), 5.0, ego, moving)
    assert not rule.last_layers.standoff and rule.last_layers.go >= LAYERS.anticipate


def test_the_latency_the_ego_is_told_lengthens_the_deferral_and_widens_the_filter(scene: Scene) -> None:
    """``sensing.told`` tells the planner its own sensing: the layered rule defers the full
    brake by that much less, and the CDF's likelihood is wider by the told noise."""
    base, told = ScenarioConfig(), ScenarioConfig(sensing={"latency": 2, "brake_latency": 1, "pos": 0.3,
                                                           "told": True})
    assert PlannerContext.of(scene.layout(), base).latency == 0.0
    context = PlannerContext.of(scene.layout(), told)
    assert context.latency == pytest.approx(0.3) and context.measurement_std == (0.3, 0.3, 0.0, 0.0)
    untold_rule, told_rule = _rule(scene), LayeredRule()
    told_rule.reset(context)
    assert told_rule.react_ticks >= untold_rule.react_ticks + 3
    planner = make_planner("cdf")
    planner.reset(context, np.random.default_rng(0))
    inverse = planner.filter._cov_inv  # type: ignore[attr-defined]
    assert inverse[0, 0] == pytest.approx(1.0 / (0.3 ** 2 + 0.3 ** 2))


def test_bad_layer_settings_are_refused_naming_the_field(scene: Scene) -> None:
    with pytest.raises(ValueError, match=r"layered\.anticipate"):
        LayeredConfig(anticipate=1.5)
    with pytest.raises(ValueError, match=r"layered\.anticipate_release"):
        LayeredConfig(anticipate=0.2, anticipate_release=0.3)
    with pytest.raises(ValueError, match=r"layered\.comfort_brake"):
        LayeredConfig(comfort_brake=3.5)
    with pytest.raises(ValueError, match="horizon"):
        LayeredRule(LayeredConfig(emergency_margin=5.0)).reset(
            PlannerContext(layout=scene.layout(), dt=DT, nominal_speed=13.4))


# ------------------------------------------------------------------ the actuator
def test_the_actuator_limits_jerk_and_the_delay_holds_commands() -> None:
    limit = JerkLimiter(jerk_limit=20.0, dt=DT)
    assert [limit(a) for a in (0.0, -4.877, -4.877, 3.0)] == pytest.approx([0.0, -2.0, -4.0, -2.0])
    delay = CommandDelay(2)
    assert [delay(a) for a in (-1.0, -2.0, -3.0)] == [math.inf, math.inf, -1.0]


def test_a_graded_episode_records_hard_brakes_only_and_its_commands(scene: Scene) -> None:
    """Seed 5 (a cut-off from an ego close to the junction): the layered CDF predicts it and
    avoids it; its history keeps the command of every tick within the car's limits;
    ``brake_time`` is its first command at or beyond ``hard_brake``, and each brake the
    planner lists is a run of such commands (measured: one brake, 1.9-2.9 s)."""
    rec = run_episode(ScenarioConfig(), 5, "cdf", scene)
    info = rec.planner_info
    accel = np.array(info["history"]["accel"])
    assert rec.label == "Cutoff" and not rec.collision and info["prediction"] == "Cutoff"
    assert accel.min() >= -scene.layout().ego.max_brake - 1e-9 and accel.max() <= scene.layout().ego.max_accel
    hard = accel <= -LAYERS.hard_brake
    assert hard.any()
    times = np.array(info["history"]["t"])
    assert rec.brake_time == times[hard][0]
    runs = [[float(times[i]), float(times[j]) if j < len(times) else None]
            for i, j in zip(np.flatnonzero(np.diff(np.r_[0, hard.astype(int)]) == 1),
                            np.flatnonzero(np.diff(np.r_[hard.astype(int), 0]) == -1) + 1, strict=True)]
    assert info["brakes"] == runs


def test_yes_no_planners_act_at_once_whatever_the_jerk_limit(scene: Scene) -> None:
    """A yes/no planner's full brake and release do not go through the graded actuator: a
    releasing one (``cdf-risk``) gives the same record with any ``ego.jerk_limit``."""
    for seed in (5, 14):
        a = run_episode(ScenarioConfig(), seed, "cdf-risk", scene, label=False)
        b = run_episode(ScenarioConfig(ego={"jerk_limit": 1.0}), seed, "cdf-risk", scene, label=False)
        assert a.planner_info["brakes"] and a.to_dict() == b.to_dict()


# ------------------------------------------------------------------ closed loop, a user's junctions
def _cutoff_seeds(scene: Scene, config: ScenarioConfig, n: int) -> list[int]:
    seeds = [s for s in range(40) if episode_label(config, s, scene) == "Cutoff"]
    assert len(seeds) >= n
    return seeds[:n]


def _user_loop(scene: Scene, config: ScenarioConfig, seed: int, late: int) -> tuple[bool, int]:
    """The user's simulation loop: their ego's speed is set by ``Decision.accel`` every
    0.1 s (their own actuator, ``late`` ticks behind, jerk-limited as ours), its steering by
    their own route following; the other car is the scenario's world. Returns whether the
    ego touched the other car and how many times the monitor's hard brake switched."""
    world = World(scene, config)
    world.reset(seed)
    monitor = CDFMonitor(scene.layout(), config, rng=seed, record_trace=False)
    delay, actuator = CommandDelay(late, initial=0.0), JerkLimiter(config.ego.jerk_limit, config.timing.dt)
    switches, braking = 0, False
    while not world.done:
        m = world.measure()
        decision = monitor.observe(m.t, m.poses[0], m.poses[1])
        switches += decision.brake != braking
        braking = decision.brake
        steer = float(ego_control(world.driver, world.layout.ego, m.poses[0], False)[1])
        world.step(np.array([actuator(delay(decision.accel)), steer]))
    return world.collision == "obstacle", switches


JUNCTIONS = {
    "rotated, narrow, named": {"rotation": 0.7, "lane_width": 3.2, "center": (25.0, -40.0),
                                   "names": SceneNames(ego_prefix="av_", obstacle_prefix="rival_")},
    "mirrored": {"mirror": True, "rotation": -1.9},
    "wide": {"lane_width": 4.2},
}
AFTER = {"brakes": {"after_merge.behaviour": "brake", "after_merge.brake": (4.0, 4.0), "after_merge.at": (5.0, 15.0)},
         "slows": {"after_merge.behaviour": "slow", "after_merge.decel": (2.0, 2.0)},
         "stops": {"after_merge.behaviour": "stop"}}


@pytest.mark.parametrize("junction", list(JUNCTIONS))
def test_an_ego_obeying_the_monitor_never_touches_a_car_that_brakes_slows_or_stops_after_cutting_in(
        junction: str) -> None:
    """On junctions of the user's own (other names, widths, rotated, mirrored), an ego that
    applies ``Decision.accel`` every tick and nothing else (no car following of ours), on two
    cut-offs each, with the other car braking at 4 m/s^2, slowing at 2 m/s^2 or stopping
    after it merges, and with the user's brakes 0.2 s late behind a car that brakes: no
    touch, and few brake switches (measured: none touched; 0-2 switches)."""
    kwargs = JUNCTIONS[junction]
    names = kwargs.get("names", SceneNames())
    scene = junction_scene(**kwargs)
    base = ScenarioConfig(names=names)  # type: ignore[arg-type]
    seeds = _cutoff_seeds(scene, base, 2)
    runs = [(what, late) for what in AFTER for late in (0,)] + [("brakes", 2)]
    for seed in seeds:
        for what, late in runs:
            touched, switches = _user_loop(scene, base.with_values(AFTER[what]), seed, late)
            assert not touched, (junction, seed, what, late)
            assert switches <= 4, (junction, seed, what, late, switches)


def test_the_monitor_accel_is_the_speed_hold_capped_by_the_rule(scene: Scene) -> None:
    """``Decision.accel`` is the ego's speed hold towards its nominal speed until the rule
    commands less, and the car's full brake when it brakes hard with a yes/no rule."""
    world = World(scene, ScenarioConfig())
    world.reset(1)
    graded = CDFMonitor(scene.layout(), rng=1, record_trace=False)
    paper = CDFMonitor(scene.layout(), cdf=CDFConfig(decision="threshold"), rng=1, record_trace=False)
    seen_slowing = False
    while not world.done and world.t < 4.0:
        m = world.measure()
        d, p = graded.observe(m.t, *m.poses), paper.observe(m.t, *m.poses)
        hold = 1.0 * (13.4 - m.poses[0, 3])
        assert d.accel <= min(max(hold, -4.877), 3.0) + 1e-9
        seen_slowing |= d.accel < -0.5 and not d.brake
        assert (p.accel == pytest.approx(-4.877)) == p.brake
        world.step(np.array([d.accel, float(ego_control(world.driver, world.layout.ego, m.poses[0], False)[1])]))
    assert seen_slowing


# ------------------------------------------------------------------ the pictures of docs/DECISION.md
def test_the_decision_figures_script_draws_a_layer_and_refuses_an_unknown_one(tmp_path) -> None:
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "decision_figures.py"
    pytest.importorskip("matplotlib")
    ok = subprocess.run([sys.executable, str(script), "--only", "anticipate", "--out", str(tmp_path)],
                        capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert (tmp_path / "anticipate.png").stat().st_size > 10_000 and "anticipate: seed" in ok.stderr
    bad = subprocess.run([sys.executable, str(script), "--only", "brake", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("decision_figures: error: unknown picture(s) brake")
    assert len(bad.stderr.strip().splitlines()) == 1 and not (tmp_path / "x").exists()
