"""Scenes beyond the default: the four-way junction, a scene built from scratch with
MjSpec (cars added with add_car, the filter attached with attach), and bad scenes that
must give one error listing every problem."""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest

from cdf_mj.analysis.metrics import decision_time
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames
from cdf_mj.model.driver import ego_control
from cdf_mj.records import Label
from cdf_mj.scenario.episode import World, run_episode
from cdf_mj.scenario.monitor import CDFMonitor, attach
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.scene import Scene, SceneError
from cdf_mj.sim.spec import add_car

FOURWAY = MODELS_DIR / "scene_fourway.xml"


@pytest.fixture(scope="module")
def fourway() -> Scene:
    return Scene.load(FOURWAY)


# ------------------------------------------------------------------ the four-way junction
def test_fourway_differs_in_geometry(fourway: Scene, scene: Scene):
    assert fourway.layout().ego_lane.half[1] == pytest.approx(1.6)  # 3.2 m lanes, not 3.7 m
    assert scene.layout().ego_lane.half[1] == pytest.approx(1.85)
    assert len(fourway.buildings) == 5 and len(scene.buildings) == 4
    names = [fourway.model.geom(int(g)).name for g in fourway.buildings]
    assert "building_kiosk" in names


def test_cdf_acts_on_a_cutoff_on_the_fourway(fourway: Scene):
    """Seeds 0-11 hold cut-offs on this scene (measured: 97 of seeds 0-199); on each one the
    CDF's filter warns (P(cutoff) >= tau) before the obstacle enters the ego lane, its rule
    brakes hard or was slowing the ego as the obstacle entered, and the ego avoids it."""
    cfg = ScenarioConfig()
    cutoffs = 0
    for seed in range(12):
        world = World(fourway, cfg)
        world.reset(seed)
        if int(world.intent) != 0:  # right-turners cannot cut off
            continue
        rec = run_episode(cfg, seed=seed, planner="cdf", scene=fourway)
        if rec.label != Label.CUTOFF:
            continue
        cutoffs += 1
        assert rec.planner_info["prediction"] == "Cutoff"
        assert (rec.brake_time is not None or rec.planner_info["anticipated"]) and rec.entered_lane_time is not None
        warned = decision_time(rec, CDFConfig().tau)
        assert warned is not None and warned < rec.entered_lane_time
        assert rec.collision_with != "obstacle"
        if cutoffs == 2:
            break
    assert cutoffs == 2


@pytest.mark.parametrize("argv", [
    ["episode", "--seed", "3", "--planner", "reactive"],
    ["experiment", "--episodes", "2", "--planner", "reactive", "--quiet", "--workers", "1"],
    ["reproduce", "--episodes", "2", "--planner", "constant", "--quiet", "--workers", "1"],
    ["bench", "--only-reproduce", "--reproduce-episodes", "2", "--workers", "1", "--quiet"],
])
def test_cli_runs_on_the_fourway(argv, tmp_path, capsys):
    extra = ["--out", str(tmp_path / "out")] if argv[0] in ("experiment", "reproduce") else []
    assert main([*argv, "--scene", str(FOURWAY), *extra]) == 0
    out = capsys.readouterr().out
    if argv[0] == "episode":
        rec = json.loads(out)
        assert rec["label"] in (Label.CUTOFF, Label.YIELD, Label.RIGHT)
        assert rec["ego_start_offset"] == run_episode(seed=3, scene=Scene.load(FOURWAY)).ego_start_offset


# ------------------------------------------------------------------ a scene from scratch
# Our own names for everything, to show that nothing is tied to models/xml's spelling.
MY_NAMES = SceneNames(ego_prefix="av/", obstacle_prefix="other/", ego_start="av_home",
                      obstacle_start="other_home", stop_line="stop", ego_lane="av_lane",
                      conflict="crossing", commit="point_of_no_return", route_ego="av_path",
                      route_left="other_path_left", route_right="other_path_right",
                      building_prefix="house")


def _arc(cx: float, cy: float, r: float, a0: float, a1: float, n: int) -> list[tuple[float, float]]:
    return [(cx + r * math.cos(a0 + (a1 - a0) * k / n), cy + r * math.sin(a0 + (a1 - a0) * k / n))
            for k in range(n + 1)]


def _spec_from_scratch(names: SceneNames = MY_NAMES, cars: bool = True) -> mujoco.MjSpec:
    """A T-junction written with the MjSpec API only: 3.5 m lanes, one house, no XML."""
    spec = mujoco.MjSpec()
    spec.modelname = "from_scratch"
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # what our cars need
    spec.option.timestep = 0.005
    world = spec.worldbody
    world.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[100, 100, 0.1],
                   contype=0, conaffinity=0)
    world.add_geom(name=names.building_prefix + "_corner", type=mujoco.mjtGeom.mjGEOM_BOX,
                   pos=[-20, 18, 5], size=[14, 10, 5], group=1, contype=1, conaffinity=2)
    c = 1.75  # lane centre [m]
    start_y = 3.5 + 1.0 + 3.65
    world.add_site(name=names.ego_start, pos=[-40, -c, 0])
    world.add_site(name=names.obstacle_start, pos=[-c, start_y, 0],
                   quat=[math.cos(-math.pi / 4), 0, 0, math.sin(-math.pi / 4)])
    world.add_site(name=names.stop_line, type=mujoco.mjtGeom.mjGEOM_BOX, pos=[-c, 4.65, 0],
                   size=[c, 0.15, 0.02])
    world.add_site(name=names.ego_lane, type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0, -c, 0],
                   size=[100, c, 0.02])
    world.add_site(name=names.conflict, pos=[2.5, -c, 0])
    world.add_site(name=names.commit, pos=[-c, start_y - 1.45, 0])
    routes = {
        names.route_ego: [(-100, -c), (100, -c)],
        names.route_left: [(-c, start_y), *_arc(-c + 7, 7 - c, 7, math.pi, 1.5 * math.pi, 8), (100, -c)],
        names.route_right: [(-c, start_y), *_arc(-c - 6, c + 6, 6, 0.0, -0.5 * math.pi, 6), (-100, c)],
    }
    for body_name, pts in routes.items():
        body = world.add_body(name=body_name)
        for x, y in pts:
            body.add_site(pos=[x, y, 0])
    if cars:
        add_car(spec, names.ego_prefix, pos=(-40, -c), yaw=0.0, paint=(0.8, 0.1, 0.1, 1))
        add_car(spec, names.obstacle_prefix, pos=(-c, start_y), yaw=-math.pi / 2)
    return spec


def test_scene_from_scratch_gets_two_cars_and_the_filter():
    spec = _spec_from_scratch()
    model = spec.compile()
    data = mujoco.MjData(model)
    monitor = attach(model, data, MY_NAMES, rng=0)
    # At rest where add_car put them: the poses the monitor reads are the placement poses.
    np.testing.assert_allclose(monitor.step().poses,
                               [[-40, -1.75, 0, 0], [-1.75, 8.15, -math.pi / 2, 0]], atol=1e-9)

    # Our scenario drives both cars in the user's data (a cut-off seed found by search);
    # the monitor, attached separately, only reads the data.
    cfg = ScenarioConfig()
    world = World(Scene.from_model(model, data, MY_NAMES), cfg)
    for seed in range(40):
        world.reset(seed)
        if int(world.intent) == 0 and world.first_seen is None:
            label = run_episode(cfg, seed=seed, planner="constant", scene=world.scene).label
            if label == Label.CUTOFF:
                break
    else:
        pytest.fail("no cut-off in seeds 0-39 on the scratch scene")
    world.reset(seed)
    monitor.reset()
    decisions = []
    while not world.done:
        d = monitor.step()
        decisions.append(d)
        world.step(ego_control(world.driver, world.layout.ego, d.poses[0], d.brake))
    assert all(0.0 <= d.posterior.p_cutoff <= 1.0 for d in decisions)
    assert monitor.brake_time is not None, "the monitor never asked to brake in a cut-off"
    warned = next(d.t for d in decisions if d.posterior.p_cutoff >= monitor.cdf.tau)
    assert world.entered_lane is None or warned < world.entered_lane
    assert world.collision != "obstacle"
    assert decisions[-1].posterior.p_left > 0.9


def test_monitor_refuses_an_irregular_call_rate():
    spec = _spec_from_scratch()
    model = spec.compile()
    data = mujoco.MjData(model)
    monitor = CDFMonitor(Scene.from_model(model, data, MY_NAMES), rng=1)
    monitor.step()
    mujoco.mj_step(model, data, nstep=5)  # 0.025 s, not dt = 0.1 s
    with pytest.raises(ValueError, match=r"every dt=0\.1 s"):
        monitor.step()


def test_add_car_refuses_a_taken_prefix():
    spec = _spec_from_scratch()
    with pytest.raises(SceneError, match="av/chassis"):
        add_car(spec, MY_NAMES.ego_prefix)


def test_add_car_refuses_any_name_clash_before_touching_the_spec():
    spec = _spec_from_scratch(cars=False)
    spec.worldbody.add_body(name="marker").add_site(name="av/eye")
    spec.add_material(name="av/glass")
    before = spec.to_xml()
    with pytest.raises(SceneError) as err:
        add_car(spec, "av/")
    assert "site 'av/eye'" in str(err.value) and "material 'av/glass'" in str(err.value)
    assert spec.to_xml() == before  # no frame, no paint material left behind
    with pytest.raises(ValueError, match=r"pos must be \(x, y\)"):
        add_car(spec, "b/", pos=(0.0, 0.0, 0.0))


def test_monitor_example_steps_with_the_models_own_timestep():
    spec = _spec_from_scratch()
    spec.option.timestep = 0.002  # a user's finer timestep: 50 steps per 0.1 s tick
    model = spec.compile()
    data = mujoco.MjData(model)
    monitor = CDFMonitor(Scene.from_model(model, data, MY_NAMES), rng=1)
    nstep = round(monitor.scenario.timing.dt / model.opt.timestep)  # as the module docstring does
    for _ in range(3):
        decision = monitor.step()
        mujoco.mj_step(model, data, nstep=nstep)
    assert nstep == 50 and decision.t == pytest.approx(0.2)


# ------------------------------------------------------------------ bad scenes, bad names
def test_bad_scene_gives_one_error_listing_everything():
    spec = _spec_from_scratch()
    spec.delete(spec.site(MY_NAMES.conflict))
    spec.delete(spec.site(MY_NAMES.commit))
    spec.site(MY_NAMES.ego_lane).type = mujoco.mjtGeom.mjGEOM_SPHERE
    route = spec.body(MY_NAMES.route_ego)
    spec.delete(route.sites[0])
    spec.geom(MY_NAMES.building_prefix + "_corner").type = mujoco.mjtGeom.mjGEOM_CYLINDER
    model = spec.compile()
    with pytest.raises(SceneError) as err:
        attach(model, mujoco.MjData(model), MY_NAMES)
    msg = str(err.value)
    assert "\n" not in msg
    for fragment in ("site 'crossing'", "site 'point_of_no_return'", "site 'av_lane' must be a box",
                     "body 'av_path' has fewer than 2 waypoint sites",
                     "'house_corner' is a cylinder"):
        assert fragment in msg, fragment


def test_bad_numbers_in_a_scene_are_listed_too():
    spec = _spec_from_scratch()
    spec.site(MY_NAMES.ego_start).pos = [float("nan"), -1.75, 0.0]
    left = spec.body(MY_NAMES.route_left).sites
    left[2].pos = left[1].pos  # two waypoints at one place
    spec.actuator("av/accel").ctrlrange = [1.0, 3.0]  # cannot brake
    model = spec.compile()
    with pytest.raises(SceneError) as err:
        Scene.from_model(model, names=MY_NAMES)
    msg = str(err.value)
    for fragment in ("not finite numbers: site 'av_home'",
                     "body 'other_path_left': the route has two consecutive waypoints at the same place",
                     "actuator 'av/accel' needs a ctrlrange from braking"):
        assert fragment in msg, fragment


def test_wrong_names_give_one_error_listing_every_missing_name(scene: Scene):
    names = SceneNames(ego_prefix="car1_", route_left="left_path", conflict="conflict_point")
    with pytest.raises(SceneError) as err:
        Scene.from_model(scene.model, names=names)
    msg = str(err.value)
    for fragment in ("body 'car1_chassis'", "actuator 'car1_accel'", "joint 'car1_yaw'",
                     "site 'car1_eye'", "body 'left_path'", "site 'conflict_point'"):
        assert fragment in msg, fragment


def test_data_of_another_model_is_refused(scene: Scene):
    other = _spec_from_scratch().compile()
    with pytest.raises(SceneError, match="does not belong"):
        Scene.from_model(scene.model, mujoco.MjData(other))


@pytest.mark.parametrize(("kwargs", "fragment"), [
    ({"ego_prefix": ""}, "ego_prefix must be non-empty"),
    ({"ego_prefix": "car_", "obstacle_prefix": "car_"}, "different prefixes"),
])
def test_bad_scenenames_are_refused(kwargs, fragment):
    with pytest.raises(ValueError, match=fragment):
        SceneNames(**kwargs)
