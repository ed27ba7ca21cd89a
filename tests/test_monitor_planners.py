"""The monitor with any registered planner (``CDFMonitor(..., planner=...)``): fed a real
episode's true poses, with its ego driven by ``Decision.accel``, it brakes as
``run_episode``'s ego with that planner does; a user's registered planner works; the
default (``cdf``) is unchanged; a trace without a posterior round-trips and is drawn."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from junctions import junction_scene

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.driver import ego_control
from cdf_mj.planners import register
from cdf_mj.planners.base import Planner, PlannerInput
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import CDFMonitor, TraceError, read_trace
from cdf_mj.scenario.sensing import JerkLimiter
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

#: The monitor does not follow a car ahead: neither does the episode's ego here.
CONFIG = ScenarioConfig().with_values({"ego.follow": False})


class SlowCarBrake(Planner):
    """A user's yes/no planner: brake once the other car moves faster than 3 m/s (held)."""

    name = "slow-car-brake"

    def brake(self, obs: PlannerInput) -> bool:
        return bool(obs.poses[1, 3] > 3.0)


@pytest.fixture
def user_planner():
    register("slow-car-brake", SlowCarBrake)
    yield "slow-car-brake"
    PLANNERS.pop("slow-car-brake", None)


def _monitored(scene: Scene, seed: int, planner: str | Planner,
               config: ScenarioConfig = CONFIG) -> tuple[CDFMonitor, World, list[bool]]:
    """Episode ``seed`` of the world with the monitor as the ego's planner: fed the true poses
    each tick, the ego drives its speed hold capped as ``Decision.accel`` says (through the
    actuator's jerk limit for a graded planner, as run_episode's ego). Returns the monitor,
    the world at the end and the brake decision of each tick (the true poses of each tick
    in ``monitor.trace``)."""
    world = World(scene, config)
    world.reset(seed)
    monitor = CDFMonitor(world.layout, config, rng=world.rng["planner"], planner=planner)
    actuator = JerkLimiter(config.ego.jerk_limit, config.timing.dt) if monitor.planner.graded else float
    brakes = []
    while not world.done:
        m = world.measure()
        d = monitor.observe(m.t, m.poses[0], m.poses[1])
        brakes.append(d.brake)
        controls = ego_control(world.driver, world.layout.ego, m.poses[0], False)
        controls[0] = actuator(d.accel)
        world.step(controls)
    return monitor, world, brakes


@pytest.mark.parametrize(("planner", "seed"), [
    ("imm-layered", 14),  # a cut-off: two hard brakes, each released
    ("imm-layered", 11),  # a right-turner: one hard brake, released
    ("imm-layered", 1),  # a cut-off: slowing only, no hard brake
    ("reactive", 1),  # a cut-off: the full brake, held
    ("reactive", 4),  # no brake
])
def test_the_monitor_brakes_as_run_episode_with_that_planner(scene: Scene, planner: str, seed: int):
    rec = run_episode(CONFIG, seed=seed, planner=planner, scene=scene, label=False, trace=True)
    monitor, world, brakes = _monitored(scene, seed, planner)
    assert monitor.decision is not None and monitor.decision.posterior is None and not monitor.has_posterior
    assert monitor.brake_time == rec.brake_time
    assert rec.trace is not None  # the same episode, tick by tick
    np.testing.assert_allclose([[r["ego"], r["obstacle"]] for r in monitor.trace], rec.trace["poses"], atol=1e-9)
    if planner == "imm-layered":  # every hard brake, start and end, is the episode's
        assert monitor.planner.summary()["brakes"] == rec.planner_info["brakes"]
    assert world.collision == rec.collision_with and world.t == pytest.approx(rec.end_time)
    assert world.min_gap == pytest.approx(rec.min_gap)
    if planner == "reactive" and rec.brake_time is not None:  # a yes/no brake is held: the full brake
        k = brakes.index(True)
        assert all(brakes[k:]) and monitor.decision.accel == -monitor.layout.ego.max_brake
    with pytest.raises(AttributeError, match=f"planner '{planner}' has no particle filter"):
        _ = monitor.filter


@pytest.mark.parametrize(("planner", "seed"), [
    ("imm-layered", 34),  # two hard brakes, released between
    ("cv-risk", 24),  # the risk rule switching its brake on and off for 13 s behind the merged car
])
def test_the_monitor_brakes_as_run_episode_on_a_junction_and_driver_it_was_not_written_for(planner: str,
                                                                                           seed: int):
    """A rotated, mirrored junction of 3.2 m lanes and an aggressive driver of the families
    written apart from every model: every brake and release of the monitor is the episode's."""
    scene = junction_scene(rotation=0.7, mirror=True, lane_width=3.2)
    config = CONFIG.with_values({"obstacle.family": "aggressive"})
    rec = run_episode(config, seed=seed, planner=planner, scene=scene, label=False)
    monitor, world, _ = _monitored(scene, seed, planner, config)
    assert len(rec.planner_info["brakes"]) >= 2  # the case exercises releases
    assert monitor.planner.summary()["brakes"] == rec.planner_info["brakes"]
    assert world.collision == rec.collision_with and world.min_gap == pytest.approx(rec.min_gap)


def test_a_users_registered_planner_is_monitored_as_run_episode_runs_it(scene: Scene, user_planner: str,
                                                                       tmp_path: Path):
    rec = run_episode(CONFIG, seed=1, planner=user_planner, scene=scene, label=False)
    monitor, _, brakes = _monitored(scene, 1, user_planner)
    assert rec.brake_time is not None and monitor.brake_time == rec.brake_time
    assert brakes[-1] and monitor.decision is not None and monitor.decision.posterior is None
    by_object = _monitored(scene, 1, SlowCarBrake())[0]  # a Planner object works alike
    assert by_object.brake_time == rec.brake_time
    trace = read_trace(monitor.save_trace(tmp_path / "mine.jsonl"))
    assert trace.planner == user_planner and trace.rule is None and not trace.has_posterior
    assert np.isnan(trace.threshold) and np.isnan(trace.tau) and trace.brake_time == rec.brake_time


def test_unknown_names_and_non_planners_are_one_line_errors(scene: Scene):
    layout = scene.layout()
    with pytest.raises(ValueError, match=r"unknown planner 'nosuch': choose one of .*imm-layered.*reactive") as err:
        CDFMonitor(layout, planner="nosuch")
    assert "\n" not in str(err.value)
    with pytest.raises(TypeError, match=r"planner must be a registered planner's name or a cdf_mj.planners.Planner, "
                                        r"got 3 of type int") as terr:
        CDFMonitor(layout, planner=3)  # type: ignore[arg-type]
    assert "\n" not in str(terr.value)
    with pytest.raises(TypeError, match=r"got <class '.*SlowCarBrake'> of type type"):
        CDFMonitor(layout, planner=SlowCarBrake)  # type: ignore[arg-type]  # the class, not a planner


def test_the_default_is_the_cdf_as_before(scene: Scene, tmp_path: Path):
    """``planner="cdf"`` is the default: the same decisions and the same trace file, whose
    header names no planner and whose rows hold the posterior; another cdf planner is named."""
    a, _, brakes_a = _monitored(scene, 1, "cdf")
    world = World(scene, CONFIG)
    world.reset(1)
    b = CDFMonitor(world.layout, CONFIG, rng=world.rng["planner"])
    for row in a.trace:
        b.observe(row["t"], row["ego"], row["obstacle"])
    assert [r["brake"] for r in b.trace] == brakes_a and b.has_posterior and b.filter is b.planner.filter
    pa, pb = a.save_trace(tmp_path / "a.jsonl"), b.save_trace(tmp_path / "b.jsonl")
    assert pa.read_bytes() == pb.read_bytes()
    header = json.loads(pa.read_text().splitlines()[0])
    assert "planner" not in header and "posterior" not in header and header["rule"] == "layered"
    assert read_trace(pa).planner == "cdf" and read_trace(pa).has_posterior
    risk = CDFMonitor(world.layout, CONFIG, rng=0, planner="cdf-threshold")
    risk.observe(0.0, a.trace[0]["ego"], a.trace[0]["obstacle"])
    head = risk.trace_header()
    assert head["planner"] == "cdf-threshold" and head["rule"] == "threshold" and head["threshold"] == head["tau"]
    assert read_trace(risk.save_trace(tmp_path / "c.jsonl")).has_posterior


def test_a_trace_without_a_posterior_round_trips_and_is_checked(scene: Scene, tmp_path: Path):
    monitor, _, brakes = _monitored(scene, 1, "imm-layered")
    path = monitor.save_trace(tmp_path / "imm.jsonl")
    lines = path.read_text().splitlines()
    header, row = json.loads(lines[0]), json.loads(lines[1])
    assert header["planner"] == "imm-layered" and header["posterior"] is False and "tau" not in header
    assert "posterior" not in row and {"risk", "accel", "brake"} <= set(row)
    trace = read_trace(path)
    assert not trace.has_posterior and trace.rule == "layered" and trace.threshold == monitor.cdf.risk.brake
    assert trace.brake.tolist() == brakes and trace.brake_time == monitor.brake_time
    assert set(trace.posterior) == {"t", "risk"}
    np.testing.assert_allclose(trace.posterior["risk"], monitor.planner.history["risk"], atol=1e-5)
    reactive = _monitored(scene, 1, "reactive")[0]
    rtrace = read_trace(reactive.save_trace(tmp_path / "reactive.jsonl"))
    assert rtrace.rule is None and set(rtrace.posterior) == {"t"} and rtrace.brake_time == reactive.brake_time
    bad = tmp_path / "bad.jsonl"
    for text, fragment in (
        ("\n".join([json.dumps({**header, "posterior": "no"}), lines[1]]), "the header's 'posterior' must be true"),
        ("\n".join([json.dumps({**header, "planner": 5}), lines[1]]), "the header's 'planner' must be"),
        ("\n".join([json.dumps({**header, "rule": "often"}), lines[1]]), r"'rule' must be .* \(or null\)"),
        ("\n".join([lines[0], json.dumps({k: v for k, v in row.items() if k != "risk"})]),
         "bad.jsonl:2: the observation lacks 'risk'"),
        ("\n".join([json.dumps({k: v for k, v in header.items() if k != "posterior"}), lines[1]]),
         "bad.jsonl:1: the header lacks 'tau'"),  # a CDF header: its posterior is required
    ):
        bad.write_text(text)
        with pytest.raises(TraceError, match=fragment):
            read_trace(bad)
    monitor.trace[3] = {k: v for k, v in monitor.trace[3].items() if k != "risk"}
    with pytest.raises(TraceError, match=r"not saved .* observation 4: the observation lacks 'risk'"):
        monitor.save_trace(tmp_path / "never.jsonl")  # never writes what read_trace refuses
    assert not (tmp_path / "never.jsonl").exists()


@pytest.mark.parametrize("planner", ["reactive", "imm-layered"])  # no panel of probabilities; its risk
def test_render_draws_a_trace_without_a_posterior(scene: Scene, tmp_path: Path, backend: str, planner: str):
    pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
    from cdf_mj.viz.trace import render_trace

    monitor, _, _ = _monitored(scene, 14, planner)
    path = monitor.save_trace(tmp_path / "trace.jsonl")
    result = render_trace(path, DEFAULT_SCENE, tmp_path / "frame.png", frame_time=1.0, width=320, height=240)
    assert result.n_frames == 1 and result.brake_time == monitor.brake_time
