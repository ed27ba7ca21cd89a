"""The SUMO co-simulated obstacle (cdf_mj/scenario/sumo_driver.py), with real SUMO.

Each run puts :class:`SumoDriver` in the default MuJoCo scene against a scripted ego that
holds 13.4 m/s east along its route (the label's counterfactual ego), at dt = 0.1 s: the
driver is handed the ego's true pose every tick (its ``sight`` is ``"all"``), MuJoCo steps
both cars. Skipped, with the reason, where the ``sumo`` extra is not installed.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import multiprocessing
import os
import shutil
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.extras import install_hint
from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING, YIELDING
from cdf_mj.model.road import in_lane
from cdf_mj.scenario import sumo_driver
from cdf_mj.scenario.drivers import GapAcceptanceParams
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.sumo_driver import FEATURE, SumoDriver, SumoError, SumoParams, build_network
from tests.junctions import junction_scene

if importlib.util.find_spec("libsumo") is None:
    pytest.skip(f"libsumo is not installed ({install_hint('sumo')})", allow_module_level=True)
sumolib = pytest.importorskip("sumolib", reason=f"sumolib is not installed ({install_hint('sumo')})")

DT = 0.1  # [s]
EGO_SPEED = 13.4  # [m/s]
EGO_X = -40.8  # [m] the ego's nominal start (rear axle), models/xml/scene.xml
# Parameters with SUMO's randomness in the decision taken out: the stop made (no wait left),
# no impatience; overlooking the ego on every step, or never.
SURE = {"jmStopSignWait": (0.0, 0.0), "impatience": (0.0, 0.0)}


@pytest.fixture(scope="module")
def layout(scene):
    return scene.layout()


@dataclasses.dataclass
class Run:
    poses: np.ndarray  # (K, 4) the obstacle's pose at the start of each tick
    modes: list[int]  # (K,) after each tick's decision
    fronts: list[float]  # (K,) [m] SUMO's front bumper to MuJoCo's, after the tick
    in_lane: list[bool]  # (K,) the obstacle's box meets the ego's lane
    hit: str | None  # what the ego touched
    driver: SumoDriver


def run(scene, intent: int, seed: int, params: SumoParams | None = None, ticks: int = 100,
        ego_x: float = EGO_X) -> Run:
    """One closed-loop run (see the module docstring); stops when the ego touches something.
    ``ego_x`` [m]: the ego's start in the default scene; in another, its start site."""
    layout = scene.layout()
    driver = SumoDriver(params)
    driver.reset(layout, intent, np.random.default_rng(seed))
    ego = np.array([ego_x, float(layout.ego_start[1]), 0.0, EGO_SPEED])
    if not np.allclose(layout.ego_start[1:3], [-1.85, 0.0]):  # a junction of its own
        ego = np.array([*layout.ego_start[:3], EGO_SPEED])
    scene.reset(ego=ego, obstacle=driver.start)
    n_sub = scene.substeps(DT)
    front = float(layout.obstacle.hull_offset[0] + layout.obstacle.hull_half[0])
    poses, modes, fronts, lane = [], [], [], []
    hit = None
    for k in range(ticks):
        ego, obs = scene.pose_values()
        accel, steer = driver.control(k * DT, np.array(obs), np.array(ego), DT)
        scene.drive(0.0, 0.0, accel, steer)
        hit = scene.step(n_sub)
        x, y, th, _ = scene.pose_values()[1]
        if driver.sumo_state is not None:
            fronts.append(math.dist((x + front * math.cos(th), y + front * math.sin(th)), driver.sumo_state[1:3]))
        poses.append(obs)
        modes.append(driver.mode)
        lane.append(in_lane(layout, layout.obstacle.footprint_one(*obs[:3])))
        if hit is not None:
            break
    return Run(np.array(poses), modes, fronts, lane, hit, driver)


def test_the_network_has_the_layouts_lanes_and_stop_line(layout):
    net = build_network(layout)
    sumo = sumolib.net.readNet(str(net.net_file), withInternal=True)
    junction = sumo.getNode("J")
    assert junction.getType() == "priority_stop"
    # Every movement from the side road stops at the sign; the left turn yields to the ego's road.
    side = {c.getTo().getID(): c for cs in sumo.getEdge("side_in").getOutgoing().values() for c in cs}
    assert {to: c.getDirection() for to, c in side.items()} == {"ego_out": "l", "right_out": "r"}
    assert all(c.getState() == "s" for c in side.values())
    # The side road's lane ends at the front bumper of the obstacle at its start (on the stop line).
    x, y, th, _ = layout.obstacle_start
    front = float(layout.obstacle.hull_offset[0] + layout.obstacle.hull_half[0])
    stop = sumo.getLane("side_in_0").getShape()[-1]
    assert math.dist(stop, (x + front * math.cos(th), y + front * math.sin(th))) < 0.01
    # The ego's lanes lie on its route; the conflict point is inside the junction, on them.
    for lane in ("ego_in_0", ":J_3_0", "ego_out_0"):
        _, lateral = layout.route_ego.project(np.array(sumo.getLane(lane).getShape()))
        assert np.max(np.abs(lateral)) < 0.01, lane
    ego_mid = np.array(sumo.getLane(":J_3_0").getShape())
    assert ego_mid[0, 0] < layout.conflict[0] < ego_mid[-1, 0]
    # Lane lengths are their shapes' (SUMO's odometer is arc length along them).
    for edge in sumo.getEdges(withInternal=True):
        for lane in edge.getLanes():
            shape = np.array(lane.getShape())
            assert lane.getLength() == pytest.approx(np.hypot(*np.diff(shape, axis=0).T).sum(), abs=0.02)
    # The turns: the left one ends on the ego's lane, the right one never reaches it.
    left = np.array(sumo.getLane(":J_1_0").getShape())
    right = np.array(sumo.getLane(":J_0_0").getShape())
    assert abs(layout.route_ego.project(left[-1])[1]) < 0.02
    assert np.min(layout.route_ego.project(right)[1]) > float(layout.ego_lane.half[1])  # left of it, out of it
    # They are the routes' front-bumper paths: within about a metre outside the rear-axle routes.
    for shape, route in ((left, layout.route_left), (right, layout.route_right)):
        assert 0.5 < np.max(np.abs(route.project(shape)[1])) < 1.1


def test_the_network_is_cached_per_layout(layout):
    first = build_network(layout)
    stamp = first.net_file.stat().st_mtime_ns
    assert build_network(layout) is first
    sumo_driver._NETWORKS.clear()  # a fresh process: the file on disk is reused, not rebuilt
    again = build_network(layout)
    assert again.net_file == first.net_file and again.net_file.stat().st_mtime_ns == stamp
    other = build_network(layout.with_cars(obstacle=layout.obstacle.padded(0.2)))  # a longer car
    assert other.net_file != first.net_file


def test_the_same_seed_gives_the_same_poses(scene):
    a, b = run(scene, LEFT, seed=3, ticks=60), run(scene, LEFT, seed=3, ticks=60)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert a.modes == b.modes and dict(a.driver.params) == dict(b.driver.params)
    c = run(scene, LEFT, seed=4, ticks=60)
    assert dict(c.driver.params) != dict(a.driver.params)


@pytest.mark.parametrize("intent", [LEFT, RIGHT])
def test_the_mujoco_car_follows_the_sumo_car(scene, intent):
    attentive = SumoParams(jmIgnoreFoeProb=(0.0, 0.0))
    r = run(scene, intent, seed=1, params=attentive, ticks=120)
    assert r.hit is None
    assert r.modes[-1] == COMMITTED and r.poses[-1, 3] > 5.0  # it went, and drives on
    # [m] its rear axle against where SUMO's car puts it: about 0.1 m, up to 0.26 m in 40 runs
    # where a turn's exit asks the rear axle for more than the car's 3 m/s^2 (docs/SUMO.md)
    assert r.driver.tracking < 0.3
    assert max(r.fronts) < 0.35  # [m] its front bumper against SUMO's


@pytest.mark.parametrize("intent", [LEFT, RIGHT])
def test_a_users_junction_gets_its_own_network(layout, intent):
    """Rotated and mirrored (left-hand traffic): the network follows the scene."""
    scene = junction_scene(rotation=-2.0, mirror=True)
    r = run(scene, intent, seed=0, params=SumoParams(jmIgnoreFoeProb=(0.0, 0.0)), ticks=120)
    assert r.hit is None and r.modes[-1] == COMMITTED
    assert r.driver.tracking < 0.3 and max(r.fronts) < 0.35
    assert not any(r.in_lane) if intent == RIGHT else any(r.in_lane)
    assert r.driver._net.net_file != build_network(layout).net_file


def test_right_turners_never_enter_the_egos_lane(scene):
    for seed in range(8):
        r = run(scene, RIGHT, seed=seed, ticks=80)
        assert not any(r.in_lane), seed


def _changes(modes: list[int]) -> list[int]:
    return [m for i, m in enumerate(modes) if i == 0 or m != modes[i - 1]]


@pytest.mark.parametrize("seed", [0, 1])
def test_modes_follow_sumos_state(scene, seed):
    # An attentive left-turner at the default start: held at its line by the ego, then goes.
    held = run(scene, LEFT, seed, params=SumoParams(jmIgnoreFoeProb=(0.0, 0.0), **SURE), ticks=90)
    assert _changes(held.modes) == [WAITING, YIELDING, GOING, COMMITTED]
    # A right-turner has no foe: it stands its wait, goes, commits.
    right = run(scene, RIGHT, seed, params=SumoParams(jmStopSignWait=(1.0, 1.0)), ticks=60)
    assert _changes(right.modes) == [WAITING, GOING, COMMITTED]
    assert right.modes.index(GOING) == pytest.approx(10, abs=1)  # [ticks] after its 1 s wait


def test_overlooking_the_ego_cuts_it_off_and_attentive_drivers_do_not(scene):
    """20 seeds each, the ego's start spread as the world's (+-8 m): drivers that overlook
    the ego on every step pull out in front of it; drivers that never do wait for it."""
    spread = np.random.default_rng(0).uniform(-8.0, 8.0, size=20)
    blind = [run(scene, LEFT, seed, SumoParams(jmIgnoreFoeProb=(1.0, 1.0), **SURE), 60, EGO_X + off).hit
             for seed, off in enumerate(spread)]
    attentive = [run(scene, LEFT, seed, SumoParams(jmIgnoreFoeProb=(0.0, 0.0), **SURE), 60, EGO_X + off).hit
                 for seed, off in enumerate(spread)]
    assert blind.count("obstacle") >= 8, blind
    assert attentive.count("obstacle") == 0, attentive


def test_bad_parameters_are_one_line():
    with pytest.raises(ValueError, match=r"SumoParams: jmIgnoreFoeProb=\(0.5, 2.0\) must be"):
        SumoParams(jmIgnoreFoeProb=(0.5, 2.0))
    with pytest.raises(ValueError, match="driver family 'sumo' takes SumoParams, got GapAcceptanceParams"):
        SumoDriver(GapAcceptanceParams())  # type: ignore[arg-type]


def test_a_missing_sumo_is_one_line_naming_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "libsumo", None)  # import libsumo now fails
    with pytest.raises(ImportError) as info:
        SumoDriver()
    assert str(info.value) == f"{FEATURE} needs libsumo: {install_hint('sumo')}"


def test_a_netconvert_failure_is_one_line(tmp_path):
    files = {"net.nod.xml": "<nodes><node id='a' x='0' y='0'/></nodes>\n",
             "net.edg.xml": "<edges><edge id='e' from='a' to='nowhere'/></edges>\n",
             "net.con.xml": "<connections/>\n"}
    with pytest.raises(SumoError) as info:
        sumo_driver._netconvert(files, tmp_path)
    message = str(info.value)
    assert "\n" not in message and message.startswith("netconvert failed") and "nowhere" in message
    assert not (tmp_path / "net.net.xml").exists()


def test_a_sumo_load_failure_is_one_line(scene, layout, monkeypatch):
    driver = SumoDriver()
    driver.reset(layout, LEFT, np.random.default_rng(0))
    monkeypatch.setattr(sumo_driver, "_SUMO_OPTIONS", (*sumo_driver._SUMO_OPTIONS, "--no-such-option", "1"))
    with pytest.raises(SumoError) as info:
        driver.control(0.0, np.array(layout.obstacle_start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED]), DT)
    message = str(info.value)
    assert message == ("SUMO could not load the episode: Error: On processing option '--no-such-option': "
                       "No option with the name 'no-such-option' exists."), message
    monkeypatch.undo()  # the process's SUMO loads the next episode as before
    assert run(scene, RIGHT, seed=0, ticks=5).driver.sumo_state is not None


def test_a_cleared_cache_is_built_again(layout):
    own = layout.with_cars(obstacle=layout.obstacle.padded(0.1))  # a network of its own to remove
    driver = SumoDriver()
    driver.reset(own, RIGHT, np.random.default_rng(0))
    shutil.rmtree(driver._net.directory)  # a temp cleaner between episodes
    driver.control(0.0, np.array(layout.obstacle_start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED]), DT)
    assert driver._net.net_file.is_file()


def test_two_sumo_episodes_at_once_are_refused(scene, layout):
    first, second = SumoDriver(), SumoDriver()
    pose, ego = np.array(layout.obstacle_start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED])
    for driver in (first, second):
        driver.reset(layout, LEFT, np.random.default_rng(0))
        driver.control(0.0, pose, ego, DT)
    with pytest.raises(RuntimeError, match="one SUMO world at a time per process"):
        first.control(DT, pose, ego, DT)
    with pytest.raises(ValueError, match=r"dt=0.2 s: this episode's SUMO steps 0.1 s"):
        second.control(DT, pose, ego, 0.2)


def test_make_driver_gives_the_sumo_family():
    from cdf_mj.scenario.drivers import make_driver

    driver = make_driver("sumo")
    assert isinstance(driver, SumoDriver) and driver.family == "sumo" and driver.sight == "all"


def test_an_episode_in_the_world_is_deterministic(scene):
    config = ScenarioConfig().with_values({"obstacle.family": "sumo"})
    a = run_episode(config, seed=5, planner="constant", scene=scene, trace=True)
    b = run_episode(config, seed=5, planner="constant", scene=scene, trace=True)
    assert a.to_dict() == b.to_dict()


# ------------------------------------------------------------------- processes
SUMO_WORLD = ScenarioConfig().with_values({"obstacle.family": "sumo"})
_SCENE = None  # a worker's scene: inherited from the test process when forked, loaded when spawned


def _record(seed: int) -> tuple[dict, int, str]:
    """A worker's SUMO episode of ``seed`` with its trace; its process id and SUMO folder."""
    global _SCENE
    if _SCENE is None:
        from cdf_mj.sim.scene import Scene

        _SCENE = Scene.load()
    rec = run_episode(SUMO_WORLD, seed=seed, planner="constant", scene=_SCENE, trace=True).to_dict()
    return rec, os.getpid(), str(sumo_driver._Simulation.folder)


def test_forked_workers_give_a_fresh_process_s_records(scene):
    """A process that ran a SUMO episode (its simulation open, its folder made) forks two
    workers: each starts its own SUMO and folder (no worker loads another's route file),
    gives each seed the record of a fresh process, and removes its folder as it leaves."""
    global _SCENE
    seeds = [3, 4, 5, 6, 7, 8]
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as fresh:
        reference = [r for r, _, _ in fresh.map(_record, seeds)]
    _SCENE = scene
    run_episode(SUMO_WORLD, seed=0, planner="constant", scene=scene)  # SUMO open in this process
    parent = sumo_driver._Simulation.folder
    assert parent is not None and parent.is_dir()
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork")) as pool:
        results = list(pool.map(_record, seeds))
    assert [r for r, _, _ in results] == reference
    folders = {(pid, folder) for _, pid, folder in results}
    assert len({pid for pid, _ in folders}) == len({folder for _, folder in folders}) > 1  # one folder a worker
    assert str(parent) not in {folder for _, folder in folders}
    assert not any(Path(folder).exists() for _, folder in folders)  # removed as each worker left
    assert parent.is_dir() and len(list(parent.glob("*.rou.xml"))) == 1  # this process's: its last episode's
    assert run_episode(SUMO_WORLD, seed=3, planner="constant", scene=scene, trace=True).to_dict() == reference[0]


_LOADED: SumoDriver | None = None  # an episode loaded in the test process, seen by a forked worker


def _step_inherited(_: int) -> str:
    assert _LOADED is not None
    try:
        _LOADED.control(DT, np.array(_LOADED.start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED]), DT)
    except RuntimeError as exc:
        return str(exc)
    return "stepped"


def test_a_forked_process_refuses_an_episode_loaded_before_the_fork(layout):
    global _LOADED
    _LOADED = driver = SumoDriver()
    driver.reset(layout, LEFT, np.random.default_rng(0))
    driver.control(0.0, np.array(driver.start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED]), DT)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
        message = pool.submit(_step_inherited, 0).result()
    assert message.startswith(f"this SUMO episode was loaded in process {os.getpid()}, not this one"), message
    driver.control(DT, np.array(driver.start), np.array([EGO_X, -1.85, 0.0, EGO_SPEED]), DT)  # here it goes on


# -------------------------------------------------------------- SUMO's errors
@pytest.mark.parametrize("first", [True, False])
def test_an_ego_faster_than_the_road_joins_sumo(layout, first):
    """An ego above SUMO's 13.89 m/s road limit (the falsification space's egos reach 18 m/s)
    enters SUMO at the limit, on the first tick or later, and has its own speed after."""
    import libsumo

    driver = SumoDriver()
    driver.reset(layout, LEFT, np.random.default_rng(0))
    fast = np.array([EGO_X, -1.85, 0.0, 18.0])
    pose = np.array(driver.start)
    for k in range(3):
        driver.control(k * DT, pose, fast if first or k else None, DT)
    assert libsumo.vehicle.getSpeed(sumo_driver.EGO) == pytest.approx(18.0)


@pytest.mark.parametrize("first", [True, False])
def test_a_car_sumo_refuses_is_a_sumo_error(layout, scene, monkeypatch, first):
    """SUMO refusing the ego (here: no limit on its entry speed, so that SUMO's own check
    refuses it), at the load's first step or when it joins later, is one SumoError line."""
    driver = SumoDriver()
    driver.reset(layout, LEFT, np.random.default_rng(0))
    monkeypatch.setattr(sumo_driver, "ROAD_SPEED", 100.0)  # after reset: the network is as before
    fast, pose = np.array([EGO_X, -1.85, 0.0, 18.0]), np.array(driver.start)
    if not first:
        driver.control(0.0, pose, None, DT)  # SUMO's ego joins on the next tick
    with pytest.raises(SumoError) as info:
        driver.control(0.0 if first else DT, pose, fast, DT)
    message = str(info.value)
    what = "SUMO failed to insert the cars at t=0.0 s" if first else "SUMO cannot add the ego at x=-40.8 m"
    assert message.startswith(what) and "too high for the departure edge 'ego_in'" in message, message
    assert "\n" not in message
    monkeypatch.undo()  # the process's SUMO loads the next episode as before
    assert run(scene, RIGHT, seed=0, ticks=5).driver.sumo_state is not None


# ------------------------------------------------------------ the network cache
def test_networks_are_cached_in_the_users_cache_folder(layout, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    own = layout.with_cars(obstacle=layout.obstacle.padded(0.3))  # a Layout object not yet seen
    net = build_network(own)
    assert net.net_file.is_file() and net.directory.parent == tmp_path / "cdf_mj" / "sumo"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")  # not absolute: ignored, as the XDG spec says
    assert sumo_driver._cache_root() == Path.home() / ".cache" / "cdf_mj" / "sumo"
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))
    with pytest.raises(SumoError) as info:
        build_network(layout.with_cars(obstacle=layout.obstacle.padded(0.3)))
    assert str(info.value).startswith(f"cannot make SUMO's network cache {tmp_path / 'file'}/cdf_mj/sumo/")
    assert str(info.value).endswith("set XDG_CACHE_HOME to a folder of yours")
