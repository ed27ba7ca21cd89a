"""The NumPy side of a scene: :class:`CarGeometry` (a car's dimensions) and :class:`Layout`
(the junction's static geometry), checked against what MuJoCo itself computes for the
scenes under models/xml (no mocks)."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest

from cdf_mj.config import SceneNames
from cdf_mj.model.geometry import OrientedBox, Polyline
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import Occluders
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.scene import Scene

NAMES = SceneNames()
SCENES = [MODELS_DIR / "scene.xml", MODELS_DIR / "scene_fourway.xml"]
POSES = np.array([[-39.5, -1.85, 0.0, 13.4], [3.0, 7.0, 2.5, 4.0], [-1.85, 8.35, -math.pi / 2, 0.0],
                  [10.0, -20.0, -3.0, 25.0]])
GOOD = {"wheelbase": 2.7, "hull_offset": (1.35, 0.0), "hull_half": (2.3, 0.9), "hull_height": 1.5,
        "eye_offset": (1.2, 0.4, 1.2), "accel_range": (-4.877, 3.0), "steer_range": (-0.6, 0.6)}


@pytest.fixture(scope="module", params=SCENES, ids=lambda p: p.name)
def any_scene(request) -> Scene:
    return Scene.load(request.param)


# ------------------------------------------------------------------ CarGeometry
def test_car_geometry_holds_read_only_values():
    car = CarGeometry(**GOOD)
    assert (car.max_brake, car.max_accel, car.max_steer) == (4.877, 3.0, 0.6)
    assert isinstance(car.hull_half, np.ndarray) and car.hull_half.shape == (2,)
    with pytest.raises(ValueError, match="read-only"):
        car.hull_half[0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        car.wheelbase = 3.0  # type: ignore[misc]
    # An asymmetric steering range: the driver can count on the smaller side only.
    assert dataclasses.replace(car, steer_range=(-0.5, 0.7)).max_steer == 0.5


@pytest.mark.parametrize(("field", "value"), [
    ("wheelbase", 0.0), ("wheelbase", math.nan), ("wheelbase", "long"),
    ("hull_offset", (1.0,)), ("hull_offset", (1.0, math.inf)),
    ("hull_half", (2.3, 0.0)), ("hull_half", (2.3, -0.9)), ("hull_height", -1.0),
    ("eye_offset", (1.2, 0.4)), ("accel_range", (1.0, 3.0)), ("accel_range", (-4.0, 0.0)),
    ("accel_range", (-4.0,)), ("steer_range", (0.1, 0.6)), ("steer_range", (-0.6, math.nan)),
])
def test_car_geometry_refuses_bad_values_naming_the_field(field, value):
    with pytest.raises(ValueError, match=f"CarGeometry: {field}=") as err:
        CarGeometry(**{**GOOD, field: value})
    assert "\n" not in str(err.value)


def test_car_geometry_lists_every_bad_field_in_one_error():
    with pytest.raises(ValueError, match=r"^CarGeometry: ") as err:
        CarGeometry(**{**GOOD, "wheelbase": -1.0, "hull_half": (0.0, 1.0), "steer_range": (0.0, 1.0)})
    msg = str(err.value)
    assert all(f"{name}=" in msg for name in ("wheelbase", "hull_half", "steer_range"))


def test_footprint_and_eye_broadcast_over_poses():
    car = CarGeometry(**GOOD)
    assert car.footprint(POSES[0]).shape == (4, 2)
    assert car.footprint(POSES).shape == (4, 4, 2)
    assert car.footprint(POSES.reshape(2, 2, 4)).shape == (2, 2, 4, 2)
    assert car.eye(POSES).shape == (4, 3)
    np.testing.assert_allclose(car.footprint(POSES)[2], car.footprint(POSES[2]))
    # At the origin, heading east: the box spans -0.95 to 3.65 m, the eye is where it says.
    corners = car.footprint([0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(corners, [[3.65, 0.9], [-0.95, 0.9], [-0.95, -0.9], [3.65, -0.9]])
    np.testing.assert_allclose(car.eye([0.0, 0.0, math.pi / 2, 5.0]), [-0.4, 1.2, 1.2], atol=1e-12)


@pytest.mark.parametrize("which", ["ego", "obstacle"])
def test_footprint_and_eye_are_where_mujoco_puts_the_hull_and_the_eye(any_scene: Scene, which: str):
    """Each car placed at several poses: the corners of its hull geom and its eye site
    in MuJoCo's world frame (after kinematics) are the geometry's footprint and eye."""
    scene = any_scene
    car = scene.car(which)
    geom = scene.model.geom(car.prefix + NAMES.hull).id
    site = scene.model.site(car.prefix + NAMES.eye).id
    layout = scene.layout()
    for pose in POSES:
        scene.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)
        scene.set_pose(car, pose)
        scene.sync()
        d = scene.data
        rot = d.geom_xmat[geom].reshape(3, 3)
        half = scene.model.geom_size[geom]
        signs = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
        corners = d.geom_xpos[geom, :2] + (signs * half[:2]) @ rot[:2, :2].T
        np.testing.assert_allclose(car.geometry.footprint(pose), corners, atol=1e-9)
        np.testing.assert_allclose(car.geometry.eye(pose), d.site_xpos[site], atol=1e-9)
        assert car.geometry.hull_height == pytest.approx(d.geom_xpos[geom, 2] + half[2], abs=1e-9)


# ------------------------------------------------------------------ Layout
def test_layout_is_read_once_and_holds_no_state(scene: Scene):
    layout = scene.layout()
    assert scene.layout() is layout
    assert layout.ego is scene.ego.geometry and layout.obstacle is scene.obstacle.geometry
    scene.reset(ego=np.array([10.0, -1.85, 0.0, 13.4]), obstacle=np.array([-1.85, 20.0, 0.0, 0.0]))
    scene.step(20)
    assert scene.layout() is layout
    with pytest.raises(ValueError, match="read-only"):
        layout.conflict[0] = 0.0


def _route(scene: Scene, body: str) -> np.ndarray:
    m, d = scene.model, scene.data
    return d.site_xpos[np.flatnonzero(m.site_bodyid == m.body(body).id), :2]


def test_layout_equals_what_mujoco_has(any_scene: Scene):
    """Every field of the layout against MuJoCo's own numbers: site and geom positions
    and orientations after kinematics, sizes, joint frames and actuator ranges."""
    scene = any_scene
    layout = scene.layout()
    m = scene.model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    scene_at_ref = Scene.from_model(m, d, source="reference")
    for field in ("route_ego", "route_left", "route_right"):
        np.testing.assert_array_equal(getattr(layout, field).points,
                                      _route(scene_at_ref, getattr(NAMES, field)))
    for field in ("conflict", "commit"):
        np.testing.assert_array_equal(getattr(layout, field), d.site(getattr(NAMES, field)).xpos[:2])
    for field in ("ego_start", "obstacle_start"):
        site = d.site(getattr(NAMES, field))
        expected = [*site.xpos[:2], math.atan2(site.xmat[3], site.xmat[0]), 0.0]
        np.testing.assert_allclose(getattr(layout, field), expected, atol=1e-12)
    for field in ("stop_line", "ego_lane"):
        box, site = getattr(layout, field), d.site(getattr(NAMES, field))
        np.testing.assert_array_equal(box.center, site.xpos[:2])
        np.testing.assert_array_equal(box.half, m.site(getattr(NAMES, field)).size[:2])
        assert box.heading == pytest.approx(math.atan2(site.xmat[3], site.xmat[0]), abs=1e-12)
    buildings = [g for g in range(m.ngeom) if m.geom(g).name.startswith(NAMES.building_prefix)]
    occ = layout.occluders
    assert occ.names == tuple(m.geom(g).name for g in buildings) and len(occ) >= 4
    np.testing.assert_array_equal(occ.center, d.geom_xpos[buildings, :2])
    np.testing.assert_array_equal(occ.half, m.geom_size[buildings, :2])
    np.testing.assert_allclose(occ.top - occ.bottom, 2 * m.geom_size[buildings, 2])
    for car, prefix in ((layout.ego, NAMES.ego_prefix), (layout.obstacle, NAMES.obstacle_prefix)):
        assert car.wheelbase == m.body(prefix + NAMES.front_axle).pos[0]
        np.testing.assert_array_equal(car.hull_half, m.geom(prefix + NAMES.hull).size[:2])
        np.testing.assert_array_equal(car.eye_offset, m.site(prefix + NAMES.eye).pos)
        assert car.accel_range == tuple(m.actuator(prefix + NAMES.accel).ctrlrange)
        assert car.steer_range == tuple(m.actuator(prefix + NAMES.steer).ctrlrange)


def test_a_layout_from_a_live_simulation_is_the_reference_one(scene: Scene):
    """A scene built over someone's data in mid-episode reads the same layout: static
    geometry comes from the model, not from the data's state."""
    d = mujoco.MjData(scene.model)
    mujoco.mj_resetData(scene.model, d)
    d.qpos[:] = np.random.default_rng(0).uniform(-5, 5, scene.model.nq)
    mujoco.mj_forward(scene.model, d)
    live = Scene.from_model(scene.model, d).layout()
    ref = scene.layout()
    for field in dataclasses.fields(Layout):
        a, b = getattr(live, field.name), getattr(ref, field.name)
        if isinstance(a, Polyline):
            np.testing.assert_array_equal(a.points, b.points)
        elif isinstance(a, OrientedBox):
            np.testing.assert_array_equal([*a.center, a.heading, *a.half], [*b.center, b.heading, *b.half])
        elif isinstance(a, Occluders):
            np.testing.assert_array_equal(a.center, b.center)
            np.testing.assert_array_equal(a.heading, b.heading)
        elif isinstance(a, CarGeometry):
            flat = [np.hstack([np.ravel(v) for v in dataclasses.astuple(c)]) for c in (a, b)]
            np.testing.assert_array_equal(*flat)
        else:
            np.testing.assert_array_equal(a, b)


def test_layout_refuses_bad_fields_in_one_error(scene: Scene):
    fields = {f.name: getattr(scene.layout(), f.name) for f in dataclasses.fields(Layout)}
    Layout(**fields)  # a copy of a good one is fine
    with pytest.raises(ValueError, match=r"^Layout: ") as err:
        Layout(**{**fields, "conflict": [0.0, math.nan], "ego_start": np.zeros(3),
                  "route_left": np.zeros((3, 2)), "ego": None})
    msg = str(err.value)
    for fragment in ("conflict must be 2 finite numbers", "ego_start must be 4 finite numbers",
                     "route_left must be a Polyline", "ego must be a CarGeometry"):
        assert fragment in msg, fragment
