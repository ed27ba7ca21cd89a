"""Tests of the MJCF scenes and of :mod:`cdf_mj.sim.scene`, on real MuJoCo (no mocks).

In the style of dm_control / MuJoCo Menagerie model tests: every full scene under
``models/xml`` compiles, steps under random controls without a MuJoCo warning, and has
every element the code reads; broken scenes give one clear :class:`SceneError`.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from cdf_mj.config import SceneNames
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene, SceneError, SimulationDivergedError

NAMES = SceneNames()


def _full_scenes() -> list[Path]:
    """Every MJCF file under models/xml that places cars with an <attach> element.

    Parsed rather than grepped: car.xml mentions ``<attach`` in a comment only.
    """
    found = []
    for path in sorted(MODELS_DIR.glob("**/*.xml")):
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError:
            continue
        if root.find(".//attach") is not None:
            found.append(path)
    return found


SCENES = _full_scenes()

# The fixture `scene` (tests/conftest.py) is the default scene, shared by the session:
# tests reset it before use and never change its model; those that do load their own.


def _at_start(scene: Scene) -> None:
    """Reset with both cars on their start sites, at rest."""
    layout = scene.layout()
    scene.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)


def _warnings(data: mujoco.MjData) -> dict[str, int]:
    n = int(mujoco.mjtWarning.mjNWARNING)
    return {mujoco.mjtWarning(i).name: int(data.warning[i].number)
            for i in range(n) if data.warning[i].number != 0}


def test_default_scene_is_discovered():
    assert DEFAULT_SCENE in SCENES


# ------------------------------------------------------------------ compile and step
@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.name)
@pytest.mark.parametrize("start_speed", [0.0, 13.4])
def test_scene_steps_under_random_controls_without_warnings(path: Path, start_speed: float):
    scene = Scene.load(path)
    m, d = scene.model, scene.data
    layout = scene.layout()
    ego = layout.ego_start.copy()
    ego[3] = start_speed
    scene.reset(ego=ego, obstacle=layout.obstacle_start)
    lo, hi = m.actuator_ctrlrange[:, 0].copy(), m.actuator_ctrlrange[:, 1].copy()
    limited = m.actuator_ctrllimited.astype(bool)
    lo[~limited] = hi[~limited] = 0.0  # unlimited inputs (tyre dampers, gain 0): leave at 0
    rng = np.random.default_rng(12345)
    nstep = round(2.0 / m.opt.timestep)
    for _ in range(nstep):
        d.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(m, d)
    assert d.time == pytest.approx(2.0)
    assert _warnings(d) == {}
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    assert np.all(np.isfinite(d.act))
    # Speeds stay within the actuator's activation range (no reverse, at most actrange).
    for car in scene.cars.values():
        v = scene.pose(car)[3]
        assert -1e-3 <= v <= m.actuator_actrange[car.accel, 1] + 1e-3


# ------------------------------------------------------------------ names
# How each field of SceneNames is looked up: per car (with its prefix) or in the world.
_CAR_FIELDS = {"chassis": ["body"], "front_axle": ["body"], "hull": ["geom"], "eye": ["site"],
               "accel": ["actuator"], "steer": ["actuator"], "steer_joint": ["joint"],
               "joint_x": ["joint"],
               "joint_y": ["joint"], "joint_yaw": ["joint"]}
_WORLD_FIELDS = {"ego_start": ["site"], "obstacle_start": ["site"], "stop_line": ["site"],
                 "ego_lane": ["site"], "conflict": ["site"], "commit": ["site"],
                 "route_ego": ["body"], "route_left": ["body"], "route_right": ["body"]}
_OTHER_FIELDS = {"ego_prefix", "obstacle_prefix", "building_prefix"}
_OBJ = {"body": mujoco.mjtObj.mjOBJ_BODY, "site": mujoco.mjtObj.mjOBJ_SITE,
        "geom": mujoco.mjtObj.mjOBJ_GEOM, "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
        "joint": mujoco.mjtObj.mjOBJ_JOINT}


def test_every_scenenames_field_is_covered_by_this_test():
    fields = {f.name for f in dataclasses.fields(SceneNames)}
    assert fields == set(_CAR_FIELDS) | set(_WORLD_FIELDS) | _OTHER_FIELDS, (
        "a field was added to SceneNames: add it to the name tables of this test")


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.name)
def test_every_name_the_code_reads_exists(path: Path):
    scene = Scene.load(path)  # validates once; check independently as well
    m = scene.model
    missing = []
    for field, kinds in _WORLD_FIELDS.items():
        for kind in kinds:
            name = getattr(NAMES, field)
            if mujoco.mj_name2id(m, _OBJ[kind], name) < 0:
                missing.append(f"{kind} {name}")
    for prefix in (NAMES.ego_prefix, NAMES.obstacle_prefix):
        for field, kinds in _CAR_FIELDS.items():
            for kind in kinds:
                name = prefix + getattr(NAMES, field)
                if mujoco.mj_name2id(m, _OBJ[kind], name) < 0:
                    missing.append(f"{kind} {name}")
    assert missing == []
    # Buildings: the occluders, found by name prefix; all collide with cars.
    assert len(scene.buildings) >= 1
    for g in scene.buildings:
        assert m.geom(g).name.startswith(NAMES.building_prefix)
        assert m.geom_group[g] == 1
    # The cars read as two distinct bodies with the model's indices.
    assert scene.ego.body == m.body(NAMES.ego_prefix + NAMES.chassis).id
    assert scene.obstacle.body == m.body(NAMES.obstacle_prefix + NAMES.chassis).id
    assert scene.ego.accel != scene.obstacle.accel
    assert scene.ego.accel_act != scene.obstacle.accel_act


@pytest.mark.parametrize("route", ["route_ego", "route_left", "route_right"])
def test_route_bodies_have_at_least_two_waypoints(scene: Scene, route: str):
    m = scene.model
    body = m.body(getattr(NAMES, route)).id
    assert np.count_nonzero(m.site_bodyid == body) >= 2
    assert len(getattr(scene.layout(), route).points) >= 2


def _end_heading(points: np.ndarray) -> float:
    d = points[-1] - points[-2]
    return math.atan2(d[1], d[0])


def test_routes_are_read_in_order(scene: Scene):
    layout = scene.layout()
    start = layout.obstacle_start[:2]
    left, right, ego = layout.route_left.points, layout.route_right.points, layout.route_ego.points
    # Both obstacle routes start at the obstacle's start pose, heading south.
    for pts in (left, right):
        np.testing.assert_allclose(pts[0], start, atol=0.05)
        assert math.atan2(*(pts[1] - pts[0])[::-1]) == pytest.approx(-math.pi / 2, abs=0.05)
    # Left turn ends going east in the ego's (eastbound) lane.
    assert left[-1, 1] == pytest.approx(-1.85, abs=0.05)
    assert left[-1, 0] > 20.0
    assert _end_heading(left) == pytest.approx(0.0, abs=0.05)
    assert layout.ego_lane.contains(left[-1])
    # Right turn ends going west in the westbound lane.
    assert right[-1, 1] == pytest.approx(1.85, abs=0.05)
    assert right[-1, 0] < -20.0
    assert abs(math.remainder(_end_heading(right) - math.pi, 2 * math.pi)) < 0.05
    assert not layout.ego_lane.contains(right[-1])
    # The ego's route runs east along its lane.
    assert ego[0, 0] < ego[-1, 0]
    np.testing.assert_allclose(ego[:, 1], -1.85, atol=0.05)
    # Arc length increases monotonically along the left route from the start to the conflict.
    s_start = layout.route_left.project(start)[0]
    s_conflict = layout.route_left.project(layout.conflict)[0]
    assert s_start == pytest.approx(0.0, abs=1e-6) and s_conflict > s_start


def test_start_poses(scene: Scene):
    layout = scene.layout()
    ex, ey, eth, ev = layout.ego_start
    assert ey == pytest.approx(-1.85, abs=0.05) and ex < 0
    assert eth == pytest.approx(0.0, abs=1e-6) and ev == 0.0
    oth, ov = layout.obstacle_start[2:]
    assert oth == pytest.approx(-math.pi / 2, abs=1e-6) and ov == 0.0
    assert not layout.ego_lane.contains(layout.obstacle_start[:2])


# ------------------------------------------------------------------ broken scenes
def _copy_scene(tmp_path: Path) -> Path:
    for name in ("scene.xml", "intersection.xml", "car.xml"):
        shutil.copy(MODELS_DIR / name, tmp_path / name)
    return tmp_path / "scene.xml"


def _remove_sites(xml_file: Path, names: list[str]) -> None:
    tree = ET.parse(xml_file)
    removed = []
    for parent in tree.getroot().iter():
        for child in list(parent):
            if child.tag == "site" and child.get("name") in names:
                parent.remove(child)
                removed.append(child.get("name"))
    assert sorted(removed) == sorted(names), "the test's fixture no longer matches the XML"
    tree.write(xml_file)


def test_copied_scene_loads(tmp_path: Path):
    path = _copy_scene(tmp_path)
    assert Scene.load(path).source == str(path)


def test_missing_elements_give_one_error_naming_them_and_the_file(tmp_path: Path):
    path = _copy_scene(tmp_path)
    _remove_sites(tmp_path / "intersection.xml", [NAMES.conflict, NAMES.commit])
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    msg = str(info.value)
    assert f"'{NAMES.conflict}'" in msg
    assert f"'{NAMES.commit}'" in msg
    assert str(path) in msg


def test_missing_car_element_is_named_with_its_prefix(tmp_path: Path):
    path = _copy_scene(tmp_path)
    _remove_sites(tmp_path / "car.xml", [NAMES.eye])
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    msg = str(info.value)
    assert NAMES.ego_prefix + NAMES.eye in msg and NAMES.obstacle_prefix + NAMES.eye in msg
    assert str(path) in msg


def test_malformed_xml_names_the_file(tmp_path: Path):
    path = _copy_scene(tmp_path)
    text = path.read_text()
    path.write_text(text[: len(text) // 2])  # truncated mid-element
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    assert str(path) in str(info.value)


def test_malformed_included_file_names_the_scene(tmp_path: Path):
    # MuJoCo reports a broken <include> against the including file (scene.xml).
    path = _copy_scene(tmp_path)
    inc = tmp_path / "intersection.xml"
    text = inc.read_text()
    inc.write_text(text[: len(text) // 2])
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    assert str(path) in str(info.value)


def test_missing_car_file_is_named(tmp_path: Path):
    path = _copy_scene(tmp_path)
    (tmp_path / "car.xml").unlink()
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    assert str(path) in str(info.value) and "car.xml" in str(info.value)


def test_missing_file_gives_scene_error(tmp_path: Path):
    path = tmp_path / "no_such_scene.xml"
    with pytest.raises(SceneError) as info:
        Scene.load(path)
    assert str(path) in str(info.value)


def test_scene_error_is_a_value_error():
    assert issubclass(SceneError, ValueError)


# ------------------------------------------------------------------ contacts
def _drive_until_contact(scene: Scene, which: str, seconds: float) -> str | None:
    scene.set_controls(which, accel=0.0, steer=0.0)
    nstep = round(seconds / scene.model.opt.timestep)
    return scene.step(nstep)


def test_ego_into_stationary_obstacle_reports_obstacle():
    scene = Scene.load()
    # Obstacle parked in the ego's lane well east of the junction; ego 12 m behind at 10 m/s.
    scene.reset(ego=np.array([48.0, -1.85, 0.0, 10.0]), obstacle=np.array([60.0, -1.85, 0.0, 0.0]))
    assert _drive_until_contact(scene, "ego", 3.0) == "obstacle"
    # It stopped at the first contact: the ego's nose (rear axle + 3.65 m) reaches the
    # obstacle's tail (rear axle - 0.95 m) after about (12 - 4.6) / 10 s.
    assert scene.data.time == pytest.approx(0.74, abs=0.05)
    assert _warnings(scene.data) == {}


def test_ego_into_building_reports_building():
    scene = Scene.load()
    # Ego heading south, from the main road into building_sw (face at y = -7.5).
    scene.reset(ego=np.array([-20.0, 2.0, -math.pi / 2, 10.0]), obstacle=scene.layout().obstacle_start)
    assert _drive_until_contact(scene, "ego", 3.0) == "building"
    assert _warnings(scene.data) == {}


def test_obstacle_into_building_is_not_an_ego_contact():
    scene = Scene.load()
    # Obstacle heading north on the side road, turned into building_ne; ego far away.
    scene.reset(ego=np.array([-100.0, -1.85, 0.0, 0.0]),
                obstacle=np.array([2.0, 10.0, 0.0, 8.0]))
    assert _drive_until_contact(scene, "obstacle", 2.0) is None
    assert scene.data.ncon > 0  # the contact is there, just not the ego's


def test_diverged_simulation_is_an_error():
    scene = Scene.load()
    _at_start(scene)
    scene.data.qvel[scene.ego.qvel[2]] = 1e12  # beyond MuJoCo's limit: it warns and resets
    with pytest.raises(SimulationDivergedError) as info:
        scene.step(5)
    assert scene.source in str(info.value)


def test_free_road_gives_no_contact(scene: Scene):
    _at_start(scene)
    assert scene.step(round(1.0 / scene.model.opt.timestep)) is None
    assert scene.data.ncon == 0


# ------------------------------------------------------------------ poses
@pytest.mark.parametrize("pose", [
    [-39.5, -1.85, 0.0, 13.4],
    [3.0, 7.0, 2.5, 4.0],
    [-1.85, 8.35, -math.pi / 2, 0.0],
    [10.0, -20.0, -3.0, 25.0],
])
@pytest.mark.parametrize("which", ["ego", "obstacle"])
def test_set_pose_round_trip(scene: Scene, which: str, pose: list[float]):
    _at_start(scene)
    car = scene.car(which)
    scene.set_pose(car, np.array(pose))
    got = scene.pose(car)
    np.testing.assert_allclose(got[[0, 1, 3]], np.array(pose)[[0, 1, 3]], atol=1e-9)
    assert math.remainder(got[2] - pose[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    # The speed state of the actuator is the pose's speed as well.
    assert scene.data.act[car.accel_act] == pytest.approx(pose[3])
    # The world frame of the model agrees after a kinematics pass (rear-axle origin, heading).
    scene.sync()
    xpos = scene.data.xpos[car.body]
    xmat = scene.data.xmat[car.body]
    assert xpos[:2] == pytest.approx(pose[:2], abs=1e-9)
    assert math.remainder(math.atan2(xmat[3], xmat[0]) - pose[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_reset_places_both_cars_and_poses_shape(scene: Scene):
    ego = np.array([-30.0, -1.85, 0.0, 13.4])
    obs = np.array([-1.85, 8.35, -math.pi / 2, 0.0])
    scene.reset(ego=ego, obstacle=obs)
    poses = scene.poses()
    assert poses.shape == (2, 4)
    np.testing.assert_allclose(poses, np.stack([ego, obs]), atol=1e-9)
    assert scene.data.time == 0.0


def test_pose_is_consistent_after_stepping(scene: Scene):
    scene.reset(ego=np.array([-30.0, -1.85, 0.0, 10.0]), obstacle=scene.layout().obstacle_start)
    scene.step(20)
    x, y, th, v = scene.pose(scene.ego)
    assert x == pytest.approx(-29.0, abs=1e-3) and y == pytest.approx(-1.85, abs=1e-6)
    assert th == pytest.approx(0.0, abs=1e-6) and v == pytest.approx(10.0, abs=1e-3)


@pytest.mark.parametrize("bad", [
    [math.nan, 0.0, 0.0, 0.0],
    [0.0, 0.0, math.nan, 0.0],
    [0.0, 0.0, 0.0, math.nan],
    [math.inf, 0.0, 0.0, 0.0],
])
def test_set_pose_rejects_non_finite(scene: Scene, bad: list[float]):
    _at_start(scene)
    before = scene.data.qpos.copy()
    with pytest.raises(ValueError, match="pose of ego is not finite"):
        scene.set_pose(scene.ego, np.array(bad))
    np.testing.assert_array_equal(scene.data.qpos, before)  # nothing written


def test_unknown_car_name(scene: Scene):
    with pytest.raises(KeyError):
        scene.car("bicycle")


# ------------------------------------------------------------------ lanes
def test_ego_lane_box(scene: Scene):
    lane = scene.layout().ego_lane
    inside = np.array([[0.0, -0.01], [0.0, -1.85], [0.0, -3.69], [-100.0, -1.0], [100.0, -3.0]])
    outside = np.array([[0.0, 0.01], [0.0, 1.85], [0.0, 3.0], [0.0, -3.8], [0.0, 10.0]])
    assert lane.contains(inside).all()
    assert not lane.contains(outside).any()
    assert lane.contains(inside).shape == (5,)


def test_stop_line_is_north_of_the_main_road(scene: Scene):
    layout = scene.layout()
    assert layout.stop_line.contains(np.array([-1.85, 4.85]))
    assert not layout.stop_line.contains(np.array([1.85, 4.85]))  # not in the northbound lane
    # The obstacle starts north of the stop line; its commit point lies ahead of it on its way.
    assert layout.obstacle_start[1] > layout.stop_line.center[1]
    assert layout.commit[1] < layout.obstacle_start[1]


def test_car_dimensions(scene: Scene):
    for car in (c.geometry for c in scene.cars.values()):
        assert car.wheelbase == pytest.approx(2.7, abs=1e-9)
        np.testing.assert_allclose(car.hull_half, [2.3, 0.9])
        corners = car.footprint(np.array([0.0, 0.0, 0.0, 0.0]))
        assert corners.shape == (4, 2)
        np.testing.assert_allclose(corners[:, 0].min(), -0.95, atol=1e-9)
        np.testing.assert_allclose(corners[:, 0].max(), 3.65, atol=1e-9)
        assert car.eye(np.zeros((3, 4))).shape == (3, 3)


def _pose_of(scene: Scene, car) -> list[float]:
    """A car's pose by the formula of Scene.pose, from its own joints (a copy of the Car:
    not the scene's own object, so none of its kept views)."""
    return scene._pose(dataclasses.replace(car))


def test_both_poses_of_one_read_are_each_cars_own(scene: Scene):
    try:
        scene.reset(ego=np.array([-30.0, -1.85, 0.3, 10.0]), obstacle=scene.layout().obstacle_start)
        scene.set_controls("ego", 1.0, 0.2)
        scene.set_controls("obstacle", 2.0, -0.3)
        scene.step(37)
        want = [_pose_of(scene, scene.ego), _pose_of(scene, scene.obstacle)]
        assert scene.poses().tolist() == want  # the same operations: the same floats
        assert scene.pose(scene.ego).tolist() == want[0] and scene.pose(scene.obstacle).tolist() == want[1]
    finally:
        scene._bound = None


def test_a_scene_reads_and_drives_the_data_it_holds_now(scene: Scene):
    """Scene keeps views of its MjData's arrays; given another MjData it reads and commands that one."""
    first = scene.data
    scene.reset(ego=np.array([-30.0, -1.85, 0.0, 10.0]), obstacle=scene.layout().obstacle_start)
    moved = scene.poses()
    other = mujoco.MjData(scene.model)  # every car at qpos0
    try:
        scene.data = other
        assert scene.poses().tolist() != moved.tolist()
        assert scene.poses().tolist() == [_pose_of(scene, scene.ego), _pose_of(scene, scene.obstacle)]
        scene.set_controls("ego", 1.5, 0.1)
        assert other.ctrl[scene.ego.accel] == 1.5 and first.ctrl[scene.ego.accel] == 0.0
    finally:
        scene.data = first
    np.testing.assert_array_equal(scene.poses(), moved)


def test_a_copied_scene_reads_and_drives_its_own_data():
    """A deep copy (or a pickle) of a scene that has read and driven its cars reads and drives
    its own MjData, not views of the original's."""
    import copy
    import pickle

    original = Scene.load()
    original.pose_values()  # binds the original's views
    for other in (copy.deepcopy(original), pickle.loads(pickle.dumps(original))):
        other.drive(1.0, 0.1, 0.5, 0.0)
        for _ in range(20):
            mujoco.mj_step(other.model, other.data)
        assert other.data.ctrl.tolist() != original.data.ctrl.tolist()
        assert other.pose_values() == np.array(other.poses()).tolist() != original.pose_values()
