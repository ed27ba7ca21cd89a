"""The crash families (cdf_mj/scenario/crash_drivers.py): drivers that cut off.

Two harnesses: the real world (MuJoCo, the ``constant`` ego holding its speed, the label's
horizon) for what the families do to the ego, and, for their inner workings, each driver
against its own kinematic bicycle at dt = 0.1 s with a scripted ego driving east along its
route at 13.4 m/s from its nominal start (handed over always, never, or from a time on).
The obstacle agent's sight modes are checked on the real scene's rays.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import itertools
import math
import subprocess
import sys
from types import MappingProxyType

import driver_loop
import numpy as np
import pytest
from driver_loop import EGO_SPEED, always, progress

from cdf_mj.config import DRIVER_FAMILIES, ScenarioConfig
from cdf_mj.model.driver import DriverModel, Intent
from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING
from cdf_mj.planners import make_planner
from cdf_mj.scenario import crash_drivers, drivers
from cdf_mj.scenario.crash_drivers import (
    CreeperDriver,
    CreeperParams,
    DistractedParams,
    LookedButFailedDriver,
    LookedButFailedParams,
    MisjudgedSpeedParams,
    angular_width,
    look_failure,
)
from cdf_mj.scenario.drivers import (
    FAMILIES,
    OPTIONAL_FAMILIES,
    SIGHTS,
    GapAcceptanceDriver,
    GapAcceptanceParams,
    WorldDriver,
    make_driver,
)
from cdf_mj.scenario.ego_agent import EgoAgent
from cdf_mj.scenario.episode import counterfactual
from cdf_mj.scenario.obstacle_agent import ObstacleAgent
from cdf_mj.scenario.world import World
from cdf_mj.sim.visibility import visible_share

CRASH = ("looked-but-failed", "misjudged-speed", "distracted", "creeper")

SEEDS = range(40)  # the real world's seeds for the shares


def run(layout, driver: WorldDriver, intent: int = LEFT, **kwargs) -> driver_loop.Run:
    """:func:`driver_loop.run` as the world shows a crash family the ego: only on the ticks
    it looks (8 s by default)."""
    return driver_loop.run(layout, driver, intent, **{"seconds": 8.0, **kwargs}, only_looking=True)


@pytest.fixture(scope="module")
def layout(scene):
    return scene.layout()


# ---------------------------------------------------------------------------- harnesses
def world_run(scene, family: str, seed: int, params=None, p_left: float = 1.0) -> World:
    """The seed's run of the real world up to the label's horizon, the ego holding its speed
    (the labelling counterfactual), the obstacle driven by ``family`` (with ``params``)."""
    config = ScenarioConfig().with_values({"obstacle.family": family, "obstacle.p_left": p_left,
                                           "timing.end_distance": 20.0, "timing.until_clear": False})
    world = World(scene, config)
    if params is not None:
        world.obstacle_agent.family = make_driver(family, params)
    world.reset(seed)
    ego = EgoAgent(world.layout, config, world.driver, make_planner("constant"), follows=False)
    ego.reset(world.rng)
    world.track = []  # the obstacle's pose at the start of each tick
    while not world.done:
        m = world.measure()
        world.track.append(m.poses[1].copy())
        world.step(ego.act(m))
    return world


def cutoffs(scene, family: str, seeds=SEEDS, params=None) -> list[bool]:
    """Per seed: the ego holding its speed touched the left-turning obstacle (a Cutoff)."""
    return [world_run(scene, family, seed, params).collision == "obstacle" for seed in seeds]





# ---------------------------------------------------------------------------- registry
def test_the_crash_families_are_families_and_the_config_knows_them_all(layout):
    assert set(CRASH) <= set(FAMILIES)
    assert set(DRIVER_FAMILIES) == {"model", *FAMILIES, *OPTIONAL_FAMILIES}
    for name in CRASH:
        driver = make_driver(name)
        assert isinstance(driver, WorldDriver) and driver.family == name
        assert type(driver).__module__ == crash_drivers.__name__
        assert getattr(driver, "sight", "line") in SIGHTS
        driver.reset(layout, LEFT, np.random.default_rng(1))
        assert driver.mode == WAITING and np.allclose(driver.start, layout.obstacle_start)
    assert make_driver("looked-but-failed").sight == "share"


def test_optional_families_are_imported_only_when_asked_for(monkeypatch):
    code = ("import sys, cdf_mj.scenario.drivers as d\n"
            "print(sorted(m for m in sys.modules if m.endswith(('crash_drivers', 'sumo_driver'))))\n"
            "d.FAMILIES['creeper']\n"
            "print(sorted(m for m in sys.modules if m.endswith(('crash_drivers', 'sumo_driver'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[:2] == ["[]", "['cdf_mj.scenario.crash_drivers']"]
    # One whose module is not there is one line.
    monkeypatch.setattr(drivers, "OPTIONAL_FAMILIES",
                        MappingProxyType({**OPTIONAL_FAMILIES, "elsewhere": "cdf_mj.scenario.no_such_driver:Driver"}))
    with pytest.raises(ValueError, match=r"^driver family 'elsewhere' is not available here: "
                                         r"cdf_mj.scenario.no_such_driver is missing$"):
        drivers.make_driver("elsewhere")
    with pytest.raises(ValueError, match=r"unknown driver family 'sumu': known families are .*creeper, sumo"):
        make_driver("sumu")
    if importlib.util.find_spec("cdf_mj.scenario.sumo_driver") is None:
        with pytest.raises(ValueError, match=r"'sumo' is not available here: cdf_mj.scenario.sumo_driver is missing"):
            make_driver("sumo")
    else:  # its own tests cover what it does; here: make_driver finds it, and it is shown the ego always
        try:
            driver = make_driver("sumo")
        except (ImportError, ValueError) as exc:  # SUMO itself not installed: its own error
            pytest.skip(f"SUMO is not installed here: {exc}")
        assert driver.family == "sumo" and getattr(driver, "sight", None) == "all"


# ---------------------------------------------------------------------------- parameters
@pytest.mark.parametrize("family", CRASH)
def test_draws_stay_in_their_ranges_and_repeat_per_seed(layout, family):
    driver = make_driver(family)
    draws = []
    for seed in range(20):
        driver.reset(layout, seed % 2, np.random.default_rng(seed))
        draws.append(dict(driver.params))
        for name, value in driver.params.items():
            if name in type(driver).extra_draws:  # the creeper's restops: does it stop again (1) or not (0)
                assert value in (0.0, 1.0)
                continue
            low, high = getattr(driver.ranges, name)
            assert low <= value <= high, (name, value)
    again = make_driver(family)
    again.reset(layout, LEFT, np.random.default_rng(7))
    assert dict(again.params) == draws[7] and draws[7] != draws[8]


@pytest.mark.parametrize(("kind", "name", "value"), [
    (LookedButFailedParams, "lapse", (0.5, 1.5)),
    (LookedButFailedParams, "conspicuity", (0.0, 2.0)),
    (LookedButFailedParams, "look_interval", (0.0, 1.0)),
    (MisjudgedSpeedParams, "speed_factor", (0.5, 1.2)),
    (MisjudgedSpeedParams, "dwell", (1.0, math.nan)),
    (DistractedParams, "glance_away", (3.0, 2.0)),
    (DistractedParams, "approach_distance", (5.0, 5.0)),  # it starts at rest on its line
    (CreeperParams, "restop_chance", (0.5, 1.5)),
    (CreeperParams, "creep_distance", (0.5, 3.0)),  # beyond the commit distance
])
def test_bad_parameters_are_one_value_error_by_name(kind, name, value):
    with pytest.raises(ValueError, match=rf"^{kind.__name__}: {name}=") as info:
        kind(**{name: value})
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="takes CreeperParams, got GapAcceptanceParams"):
        make_driver("creeper", GapAcceptanceParams())


# ---------------------------------------------------------------------------- looked but failed
def test_a_look_fails_more_often_the_further_and_the_more_hidden_the_car():
    th = math.radians(3.0)
    far = [look_failure(d, 1.8, 1.0, 0.1, th) for d in (5.0, 10.0, 20.0, 40.0, 80.0, 160.0)]
    assert all(a < b for a, b in itertools.pairwise(far))
    hidden = [look_failure(30.0, 1.8, s, 0.1, th) for s in (1.0, 0.8, 0.6, 0.4, 0.2, 0.0)]
    assert all(a < b for a, b in itertools.pairwise(hidden))
    assert look_failure(30.0, 1.8, 0.0, 0.1, th) == 1.0  # a hidden car is never registered
    assert look_failure(0.5, 1.8, 1.0, 0.1, th) == pytest.approx(0.1)  # one filling the view: the lapses only
    # A narrower car (a motorcycle, 0.8 m) is missed at the distance where a car is missed less.
    assert look_failure(30.0, 0.8, 1.0, 0.1, th) > look_failure(30.0, 1.8, 1.0, 0.1, th)
    assert angular_width(10.0, 2.0) == pytest.approx(2.0 * math.atan(0.1))
    for bad in ((30.0, 1.8, 1.2, 0.1, th), (30.0, 1.8, 1.0, -0.1, th), (30.0, 1.8, 1.0, 0.1, 0.0),
                (30.0, 0.0, 1.0, 0.1, th), (-1.0, 1.8, 1.0, 0.1, th)):
        with pytest.raises(ValueError, match=r"must be"):
            look_failure(*bad)


def test_it_looks_at_its_interval_and_goes_on_a_look_that_failed(layout):
    blind = LookedButFailedParams(lapse=(1.0, 1.0), look_interval=(0.5, 0.5), dwell=(0.0, 0.0),
                                  reaction_time=(0.6, 0.6))
    r = run(layout, LookedButFailedDriver(blind), sight=always)
    assert r.first(r.mode >= GOING) == pytest.approx(0.6)  # its first look (t = 0), a reaction later
    looks = r.t[r.looking]  # it looks at 0, 0.5, 1.0, ... until it has committed
    assert looks[0] == 0.0 and len(looks) >= 3 and np.allclose(np.diff(looks), 0.5)
    assert looks[-1] < r.first(r.mode == COMMITTED) <= looks[-1] + 0.5
    # Every look registers the ego: it waits until the ego has passed.
    keen = dataclasses.replace(blind, lapse=(0.0, 0.0), conspicuity=(0.01, 0.01))
    r = run(layout, LookedButFailedDriver(keen), sight=always)
    ego_front = layout.ego.hull_offset[0] + layout.ego.hull_half[0]
    passed = (float(layout.route_ego.project(layout.conflict)[0] - layout.route_ego.project(layout.ego_start[:2])[0])
              + layout.ego.hull_half[0] - layout.ego.hull_offset[0]) / EGO_SPEED
    assert r.first(r.mode >= GOING) > passed > ego_front / EGO_SPEED


def test_its_failure_is_of_its_own_eye_and_the_share_the_world_gives(layout):
    driver = make_driver("looked-but-failed")
    driver.reset(layout, LEFT, np.random.default_rng(3))
    obstacle = np.asarray(layout.obstacle_start, dtype=float)
    near, far = np.array([-10.0, -1.85, 0.0, 13.4]), np.array([-60.0, -1.85, 0.0, 13.4])
    assert driver.failure(obstacle, near, 1.0) < driver.failure(obstacle, far, 1.0) < driver.failure(obstacle, far, 0.4)
    eye = layout.obstacle.eye(obstacle)[:2]
    centre = far[:2] + layout.ego.hull_offset
    p = driver.params
    assert driver.failure(obstacle, far, 0.6) == pytest.approx(
        look_failure(float(np.hypot(*(eye - centre))), 2 * layout.ego.hull_half[1], 0.6, p["lapse"],
                     math.radians(p["conspicuity"])))


# ---------------------------------------------------------------------------- the others, inside
def test_misjudged_speed_takes_the_gap_a_true_judge_refuses(layout):
    shift = 10.0  # the ego's front ~35 m (2.6 s) from the conflict point at t = 0
    params = MisjudgedSpeedParams(dwell=(0.0, 0.0), reaction_time=(0.5, 0.5), critical_gap=(6.0, 6.0),
                                  min_distance=(8.0, 8.0))
    true = run(layout, make_driver("misjudged-speed", dataclasses.replace(params, speed_factor=(1.0, 1.0))),
               sight=always, ego_shift=-shift)
    bias = run(layout, make_driver("misjudged-speed", dataclasses.replace(params, speed_factor=(0.3, 0.3))),
               sight=always, ego_shift=-shift)
    assert bias.first(bias.mode >= GOING) == pytest.approx(0.5)  # at once on its first picture
    assert true.first(true.mode >= GOING) > 3.0  # only once the ego has passed


def test_distracted_goes_at_its_dwell_on_a_stale_look(layout):
    params = DistractedParams(dwell=(0.5, 0.5), glance_away=(5.0, 5.0), critical_gap=(6.0, 6.0))
    driver = make_driver("distracted", params)
    r = run(layout, driver, sight=always)
    assert r.first(r.mode >= GOING) == pytest.approx(0.5)  # its look, 4.5 s before the start, saw a long gap
    assert r.looking[0] and not r.looking[1:5].any() and r.looking[6:].any()  # eyes off the road until it goes
    # A shorter glance: its last look saw the ego near, so it looks again and waits for it to pass.
    r = run(layout, make_driver("distracted", dataclasses.replace(params, glance_away=(2.0, 2.0))), sight=always)
    assert r.first(r.mode >= GOING) > 3.0
    # No ego in sight at the start: its look saw none, and it goes at its dwell.
    r = run(layout, make_driver("distracted", dataclasses.replace(params, glance_away=(2.0, 2.0))))
    assert r.first(r.mode >= GOING) == pytest.approx(0.5)


def test_the_creeper_edges_out_and_may_stop_again(layout):
    params = CreeperParams(creep_distance=(1.5, 1.5), creep_speed=(1.0, 1.0), critical_gap=(5.0, 5.0),
                           restop_chance=(0.0, 0.0), restop_pause=(1.0, 1.0), reaction_time=(0.6, 0.6))
    r = run(layout, make_driver("creeper", params), sight=always)  # the ego near: it creeps and waits
    depart = r.first(r.mode >= GOING)
    x = progress(layout, r.pose)
    assert depart > 3.0 and 1.3 < x[r.t < depart].max() <= 1.55 and r.pose[r.t < depart, 3].max() <= 1.05
    r = run(layout, make_driver("creeper", params))  # no ego: it goes once its first look has reached it
    assert r.first(r.mode >= GOING) == pytest.approx(0.6)
    assert 0.0 < progress(layout, r.pose[r.mode == WAITING]).max() < 0.5  # from within its creep
    stops = CreeperDriver(dataclasses.replace(params, restop_chance=(1.0, 1.0)))
    r = run(layout, stops)  # no ego, but it stops again at the end of its creep
    assert stops.restops
    rest = (r.pose[:, 3] < 0.2) & (progress(layout, r.pose) > 1.3)
    assert r.first(rest) < r.first(r.mode >= GOING) and rest.sum() >= 8


@pytest.mark.parametrize("family", CRASH)
def test_a_right_turner_goes_its_own_way(layout, family):
    for seed in range(3):
        r = run(layout, make_driver(family), RIGHT, seed=seed, sight=always)
        assert not r.looking.any() and r.mode[-1] == COMMITTED
        assert not layout.ego_lane.contains(layout.obstacle.footprint(r.pose)).any()


# ---------------------------------------------------------------------------- the real world
@pytest.mark.parametrize("family", ["looked-but-failed", "distracted", "creeper"])
def test_it_cuts_off_a_share_of_left_turners(scene, family):
    cut = cutoffs(scene, family)
    assert 0.10 <= np.mean(cut) <= 0.60, np.mean(cut)
    # What the harness counts is the label's Cutoff.
    for seed in (int(np.argmax(cut)), cut.index(False)):
        config = ScenarioConfig().with_values({"obstacle.family": family, "obstacle.p_left": 1.0})
        assert counterfactual(config, seed, scene)[0] == ("Cutoff" if cut[seed] else "Yield")


def test_misjudged_speed_cuts_off_as_much_as_it_misjudges(scene):
    """At the default ranges it seldom pulls out in front of an ego 2.6-3.8 s away (the
    HCM's critical gaps need speed_factor < ~0.5 for that); misjudging more, it does."""
    strong = MisjudgedSpeedParams(speed_factor=(0.3, 0.5))
    assert np.mean(cutoffs(scene, "misjudged-speed", params=strong)) >= 0.15
    assert not any(cutoffs(scene, "misjudged-speed", params=MisjudgedSpeedParams(speed_factor=(1.0, 1.0))))


@pytest.mark.parametrize("family", CRASH)
def test_the_same_seed_drives_the_same_obstacle(scene, family):
    a, b = (world_run(scene, family, seed=11) for _ in range(2))
    np.testing.assert_array_equal(np.array(a.track), np.array(b.track))
    assert dict(a.family.params) == dict(b.family.params)
    c = world_run(scene, family, seed=12)
    assert dict(c.family.params) != dict(a.family.params)


@pytest.mark.parametrize("family", CRASH)
def test_a_right_turner_never_cuts_off(scene, family):
    for seed in range(8):
        world = world_run(scene, family, seed, p_left=0.0)
        assert world.intent == Intent.RIGHT and world.entered_lane is None and world.collision is None


# ---------------------------------------------------------------------------- the world's sight
class _Kept(GapAcceptanceDriver):
    """A gap-acceptance driver of a given sight that keeps what it is handed (a real driver)."""

    def __init__(self, sight: str) -> None:
        super().__init__()
        self.sight = sight
        self.handed: list[tuple[np.ndarray | None, float | None]] = []

    def control(self, t, pose, ego, dt):
        self.handed.append((None if ego is None else np.array(ego), getattr(self, "ego_share", None)))
        return super().control(t, pose, ego, dt)


def _agent(scene, family, intent=Intent.LEFT, back=0.0, ego_x=-45.0):
    """An ObstacleAgent driven by ``family`` (a driver object), the obstacle ``back`` [m] up
    the side road from its line and the ego at ``ego_x`` [m] in its lane; the tick's poses."""
    config = ScenarioConfig().with_values({"obstacle.family": "gap-acceptance"})
    layout = scene.layout()
    agent = ObstacleAgent(scene, config, DriverModel.of_world(layout, config))
    agent.family = family
    rng = {"after_merge": np.random.default_rng(0), "driver": np.random.default_rng(1)}
    agent.reset(intent, dwell=1.0, hesitates=False, hesitation_pause=0.0, rng=rng)
    obstacle = np.array(layout.obstacle_start, dtype=float)
    obstacle[1] += back
    scene.reset(ego=np.array([ego_x, -1.85, 0.0, 13.4]), obstacle=obstacle)
    return agent, scene.poses(), scene.pose_values()


def _act(agent, poses, values, t=0.0):
    return agent.act(t, poses, values, False, u_look=0.9, z=[0.0] * 6, u_depart=0.9)


@pytest.mark.parametrize(("back", "ego_x", "seen"), [(0.0, -45.0, 1.0), (1.5, -45.0, None), (3.0, -45.0, 0.0)])
def test_sight_line_and_share_hand_over_what_the_rays_see(scene, back, ego_x, seen):
    share = None
    for sight in ("line", "share"):
        kept = _Kept(sight)
        agent, poses, values = _agent(scene, kept, back=back, ego_x=ego_x)
        share = visible_share(scene, "obstacle", "ego", poses[1], poses[0])
        if seen is not None:
            assert share == seen
        else:
            assert 0.0 < share < 1.0  # the building's corner hides part of it
        _act(agent, poses, values)
        ego, kept_share = kept.handed[-1]
        assert agent.observed == (share > 0.0) == (ego is not None)
        if ego is not None:
            np.testing.assert_array_equal(ego, poses[0])
        assert kept_share == (share if sight == "share" else None)


def test_sight_share_gives_zero_on_a_tick_it_does_not_look(scene):
    kept = _Kept("share")
    agent, poses, values = _agent(scene, kept, intent=Intent.RIGHT)  # a right-turner never looks
    _act(agent, poses, values)
    assert kept.handed[-1] == (None, 0.0) and not agent.observed


def test_sight_all_hands_over_the_ego_whatever_the_rays(scene):
    kept = _Kept("all")
    agent, poses, values = _agent(scene, kept, intent=Intent.RIGHT, back=3.0)  # hidden, and not looking
    assert visible_share(scene, "obstacle", "ego", poses[1], poses[0]) == 0.0 and not kept.looking
    _act(agent, poses, values)
    np.testing.assert_array_equal(kept.handed[-1][0], poses[0])
    assert agent.observed and agent.first_seen == 0.0


def test_a_family_of_unknown_sight_is_refused(scene, monkeypatch):
    monkeypatch.setattr(LookedButFailedDriver, "sight", "telepathy")
    config = ScenarioConfig().with_values({"obstacle.family": "looked-but-failed"})
    with pytest.raises(ValueError, match=r"driver family 'looked-but-failed' has sight='telepathy': it must be "
                                         r"one of line, share, all"):
        ObstacleAgent(scene, config, DriverModel.of_world(scene.layout(), config))
