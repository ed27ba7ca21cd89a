"""Cars that are not ours: a third-party-style wheeled car (tests/cars.py) on the ground of
models/xml, observed by attach with its own names and geometry; a mocap car; add_car that
leaves the user's options alone; and the ground that holds up a wheeled car but never
touches our planar cars (episode records unchanged)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
from cars import (
    CHASSIS_Z,
    REAR_AXLE,
    WHEELED_GEOMETRY,
    add_mocap_car,
    add_wheeled_car,
    rear_axle_point,
    set_mocap_pose,
)

from cdf_mj.config import SceneNames
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import TrackedCar, attach
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.checks import SceneError
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.spec import add_car

START = (-1.85, 8.35)  # the obstacle's rear-axle start in intersection.xml [m]


def _junction(timestep: float = 0.005) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(str(MODELS_DIR / "intersection.xml"))
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return spec


def _collide(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    """MuJoCo's contype/conaffinity rule for a pair of geoms."""
    return bool((m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1]))


def test_our_car_constant_is_car_xml(scene: Scene):
    ours, read = CarGeometry.ours(), scene.layout().ego
    for field in ("wheelbase", "hull_height", "accel_range", "steer_range"):
        assert getattr(ours, field) == pytest.approx(getattr(read, field)), field
    for field in ("hull_offset", "hull_half", "eye_offset"):
        np.testing.assert_allclose(getattr(ours, field), getattr(read, field), atol=1e-12)


def test_ground_holds_a_wheeled_car_and_never_touches_our_hulls(scene: Scene):
    spec = _junction()
    add_wheeled_car(spec, "rival", pos=START, yaw=-math.pi / 2, drop=0.05)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data, nstep=400)  # 2 s: it drops 5 cm and settles
    assert data.body("rival").xpos[2] == pytest.approx(CHASSIS_Z, abs=0.02)
    assert data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0
    ground = model.geom("ground").id
    wheels = [g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name.startswith("rival_wheel")]
    assert len(wheels) == 4 and all(_collide(model, ground, g) for g in wheels)
    m = scene.model  # our cars: no geom of theirs collides with the ground or the roads
    statics = [m.geom("ground").id, m.geom("road_main").id, m.geom("road_side").id]
    car_geoms = [g for g in range(m.ngeom) if m.body_rootid[m.geom_bodyid[g]] in (scene.ego.body, scene.obstacle.body)]
    assert car_geoms and not any(_collide(m, s, g) for s in statics for g in car_geoms)


def test_ground_leaves_episode_records_unchanged(tmp_path: Path, scene: Scene):
    """The same seeds on a copy of the scene whose ground does not collide (as before)."""
    for name in ("car.xml", "intersection.xml", "scene.xml"):
        shutil.copy(MODELS_DIR / name, tmp_path / name)
    path = tmp_path / "intersection.xml"
    text = path.read_text()
    new = text.replace('material="grass" contype="0" conaffinity="1"', 'material="grass" contype="0" conaffinity="0"')
    assert new != text
    path.write_text(new)
    before = Scene.load(tmp_path / "scene.xml")
    for seed in (1, 2):
        a = run_episode(seed=seed, planner="cdf", scene=scene, label=False).to_dict()
        b = run_episode(seed=seed, planner="cdf", scene=before, label=False).to_dict()
        assert a == b, seed


def test_add_car_leaves_the_options_alone():
    spec = mujoco.MjSpec.from_file(str(MODELS_DIR / "intersection.xml"))
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    add_car(spec, "ego_", pos=(-40.0, -1.85))
    assert spec.option.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert spec.option.timestep == 0.002


def _wheeled_world(front_axle: str = "front_axle") -> tuple[mujoco.MjModel, mujoco.MjData, SceneNames]:
    """Our ego and the wheeled car as the obstacle, with the user's own names."""
    spec = _junction()
    add_car(spec, "me/", pos=(-40.0, -1.85))
    add_wheeled_car(spec, "rival", pos=START, yaw=-math.pi / 2)
    model = spec.compile()
    names = SceneNames(ego_prefix="me/", obstacle_prefix="rival", front_axle=front_axle)
    return model, mujoco.MjData(model), names


def test_attach_reads_a_wheeled_cars_rear_axle_pose_and_speed():
    # front_axle mapped to a wheel body: with a geometry it is not read, so no wrong wheelbase.
    model, data, names = _wheeled_world(front_axle="_wheel_fl")
    monitor = attach(model, data, names, rng=0, ego=CarGeometry.ours(),
                     obstacle=TrackedCar(body="rival", rear_axle=REAR_AXLE, geometry=WHEELED_GEOMETRY))
    assert monitor.layout.obstacle.wheelbase == 2.7 and monitor.layout.obstacle.max_brake == 4.0
    mujoco.mj_step(model, data, nstep=100)  # settle on the ground
    engine, left, right = (model.actuator(f"rival_{a}").id for a in ("engine", "steer_left", "steer_right"))
    data.ctrl[engine] = 0.5
    data.ctrl[left] = data.ctrl[right] = 0.15  # positive = right: the car turns west
    monitor.reset()
    measured, truth = [], []
    for _ in range(25):
        decision = monitor.step()
        mujoco.mj_forward(model, data)  # the user's data, recomputed, as MuJoCo has it now
        rear = rear_axle_point(model, data, "rival")
        front = 0.5 * (data.body("rival_wheel_fl").xpos[:2] + data.body("rival_wheel_fr").xpos[:2])
        truth.append((*rear, math.atan2(*(front - rear)[::-1])))
        measured.append(decision.poses[1])
        mujoco.mj_step(model, data, nstep=20)
    measured, truth = np.array(measured), np.array(truth)
    np.testing.assert_allclose(measured[:, :2], truth[:, :2], atol=1e-3)  # wheel centres vs body frame
    np.testing.assert_allclose(measured[:, 2], truth[:, 2], atol=2e-3)
    assert truth[-1, 2] < -math.pi / 2 - 0.1  # it turned right: from south towards west
    # speed: central differences of MuJoCo's rear-axle points along the heading, 0.1 s apart
    step = np.diff(truth[:, :2], axis=0)
    heading = np.column_stack([np.cos(truth[1:-1, 2]), np.sin(truth[1:-1, 2])])
    central = ((step[1:] + step[:-1]) * heading).sum(axis=1) / 0.2
    np.testing.assert_allclose(measured[1:-1, 3], central, atol=0.05)
    assert measured[-1, 3] > 3.0  # it accelerated at about 2 m/s^2


def test_attach_without_a_geometry_names_what_it_would_read():
    model, data, names = _wheeled_world()
    with pytest.raises(SceneError, match=r"car 'rival' lacks body 'rivalfront_axle'.*CarGeometry"):
        attach(model, data, names, obstacle=TrackedCar(body="rival"))
    with pytest.raises(SceneError, match=r"body 'nobody' is not in the model"):
        attach(model, data, names, obstacle=TrackedCar(body="nobody", geometry=WHEELED_GEOMETRY))


def test_a_mocap_car_is_observed_with_its_speed():
    spec = _junction()
    add_car(spec, "ego_", pos=(-40.0, -1.85))
    add_mocap_car(spec, "ghost", pos=START, yaw=-math.pi / 2)
    model = spec.compile()
    data = mujoco.MjData(model)
    monitor = attach(model, data, rng=0, obstacle=TrackedCar(body="ghost", geometry=CarGeometry.ours()))
    speeds = []
    for k in range(8):  # straight south at 3 m/s after the first tick
        set_mocap_pose(model, data, "ghost", START[0], START[1] - 0.3 * k, -math.pi / 2)
        d = monitor.step()
        np.testing.assert_allclose(d.poses[1, :3], [START[0], START[1] - 0.3 * k, -math.pi / 2], atol=1e-9)
        speeds.append(d.poses[1, 3])
        mujoco.mj_step(model, data, nstep=20)
    assert speeds[0] == 0.0  # no earlier read to difference against
    np.testing.assert_allclose(speeds[1:], 3.0, atol=1e-6)


@pytest.mark.parametrize(("ipos", "qvel"), [
    ((0.0, 1.0, 0.0), (5.0, 0.0, 0.0, 0.0, 0.0, 1.0)),   # centre of mass to the side, turning
    ((0.0, 0.0, 0.5), (5.0, 0.0, 0.0, 0.0, 1.0, 0.0)),   # centre of mass high, pitching
])
def test_speed_is_the_rear_axles_whatever_the_centre_of_mass(ipos, qvel):
    """The rear axle's velocity is taken at the body's origin, not at its centre of mass:
    a free body whose origin moves at 5 m/s along its heading reads 5 m/s however its
    mass is placed and however it turns or pitches (the rear axle on the body's x axis)."""
    from cdf_mj.scenario.monitor import _BodySource

    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="chassis", pos=[0.0, 0.0, 0.5])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[2.0, 0.9, 0.5])
    body.explicitinertial = True
    body.mass, body.ipos, body.inertia = 1000.0, list(ipos), [500.0, 1500.0, 1800.0]
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qvel[:] = qvel
    source = _BodySource(model, data, [model.body("chassis").id] * 2, [TrackedCar(body="chassis",
                                                                                   rear_axle=(-1.35, 0.0))] * 2)
    _, poses = source.read()
    assert poses[0, 3] == pytest.approx(5.0, abs=1e-9)
