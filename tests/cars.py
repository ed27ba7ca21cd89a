"""Cars that are not ours, built with MjSpec, for the tests that observe any car.

:func:`add_wheeled_car` builds a car the way a third-party MuJoCo driving project does:
a free joint, four wheels on hinge joints (contacts with the ground do the rest), an
engine that drives both rear wheels through a fixed tendon, two steering position servos
with positive steer = RIGHT, about 4.0 m/s^2 of braking, an unnamed chassis geom, no eye
site, and the body origin at the chassis centre (not on the rear axle).
:func:`add_mocap_car` is a box moved by its mocap pose. ::

    spec = mujoco.MjSpec.from_file(str(MODELS_DIR / "intersection.xml"))
    add_wheeled_car(spec, "rival", pos=(-1.85, 9.7), yaw=-math.pi / 2)
    model = spec.compile()
    attach(model, data, names, obstacle=TrackedCar(body="rival", rear_axle=REAR_AXLE,
                                                  geometry=WHEELED_GEOMETRY))
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from cdf_mj.model.vehicle import CarGeometry

WHEELBASE = 2.7  # [m]
TRACK = 1.6  # [m] between the wheel centres of one axle
WHEEL_RADIUS = 0.35  # [m]
MASS = 1500.0  # [kg] chassis (the wheels add 4 x 20 kg)
CHASSIS_Z = 1.0  # [m] height of the body origin (the chassis box's centre) at rest
#: The rear axle's centre in the car body's frame (x, y) [m]: the origin is the chassis centre.
REAR_AXLE = (-WHEELBASE / 2, 0.0)
#: [N m] engine torque per unit of ctrl at each rear wheel: 4.0 m/s^2 at ctrl -1 for the whole car.
WHEEL_TORQUE = 4.0 * (MASS + 80.0) * WHEEL_RADIUS / 2
#: The wheeled car's dimensions in its rear-axle frame, as its owner would write them down.
WHEELED_GEOMETRY = CarGeometry(wheelbase=WHEELBASE, hull_offset=np.array([1.35, 0.0]),
                               hull_half=np.array([2.3, 0.9]), hull_height=1.45,
                               eye_offset=np.array([1.2, 0.4, 1.2]), accel_range=(-4.0, 3.0),
                               steer_range=(-0.5, 0.5))


def _quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def _inertial(body: mujoco.MjsBody, mass: float, inertia: list[float]) -> None:
    """An explicit inertial at the body's origin: ``mass`` [kg], diagonal ``inertia`` [kg m^2]."""
    body.mass, body.inertia, body.explicitinertial = mass, inertia, True
    body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]


def add_wheeled_car(spec: mujoco.MjSpec, name: str, pos: tuple[float, float] = (0.0, 0.0),
                    yaw: float = 0.0, drop: float = 0.02) -> mujoco.MjsBody:
    """Add the wheeled car: body ``name`` (free joint, origin at the chassis centre), its
    rear axle at ``pos`` [m] facing ``yaw`` [rad], the wheels ``drop`` [m] above the ground.

    Actuators ``<name>_engine`` (ctrl in [-1, 1]: -1 brakes at about 4.0 m/s^2, drives
    backwards once stopped) and ``<name>_steer_left`` / ``<name>_steer_right`` (position
    servos [rad], positive = right). Joints ``<name>_wheel_{fl,fr,rl,rr}`` and
    ``<name>_steer_{left,right}``. Needs a ground that collides with contype 1 geoms.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    cx, cy = pos[0] + c * WHEELBASE / 2, pos[1] + s * WHEELBASE / 2  # the chassis centre
    body = spec.worldbody.add_body(name=name, pos=[cx, cy, CHASSIS_Z + drop], quat=_quat(yaw))
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[2.3, 0.9, 0.3], pos=[0, 0, 0.1],  # no name
                  rgba=[0.2, 0.6, 0.3, 1], density=0)
    body.add_geom(name=f"{name}_cabin", type=mujoco.mjtGeom.mjGEOM_BOX, size=[1.2, 0.8, 0.25],
                  pos=[-0.2, 0, 0.65], rgba=[0.1, 0.1, 0.15, 1], density=0, contype=0, conaffinity=0)
    body.add_site(name=f"{name}_centre", pos=[0, 0, 0])
    _inertial(body, MASS, [700.0, 2800.0, 3000.0])
    axle_z = WHEEL_RADIUS - CHASSIS_Z
    wheels = {}
    for tag, x, y in (("fl", WHEELBASE / 2, TRACK / 2), ("fr", WHEELBASE / 2, -TRACK / 2),
                      ("rl", -WHEELBASE / 2, TRACK / 2), ("rr", -WHEELBASE / 2, -TRACK / 2)):
        parent = body
        if tag[0] == "f":  # a steering knuckle: positive angle turns the wheel to the right
            side = "left" if tag[1] == "l" else "right"
            parent = body.add_body(name=f"{name}_knuckle_{side}", pos=[x, y, axle_z])
            parent.add_joint(name=f"{name}_steer_{side}", type=mujoco.mjtJoint.mjJNT_HINGE,
                             axis=[0, 0, -1], range=[-0.5, 0.5], damping=50.0)
            _inertial(parent, 5.0, [0.2, 0.2, 0.2])
            wheel = parent.add_body(name=f"{name}_wheel_{tag}")
        else:
            wheel = parent.add_body(name=f"{name}_wheel_{tag}", pos=[x, y, axle_z])
        wheel.add_joint(name=f"{name}_wheel_{tag}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0],
                        damping=0.5)
        wheel.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[WHEEL_RADIUS, 0, 0],
                       rgba=[0.05, 0.05, 0.05, 1], friction=[1.5, 0.01, 0.001], density=0)
        _inertial(wheel, 20.0, [1.2, 1.2, 1.2])
        wheels[tag] = wheel
    engine = spec.add_tendon(name=f"{name}_drive")
    for tag in ("rl", "rr"):
        engine.wrap_joint(f"{name}_wheel_{tag}", 1.0)
    spec.add_actuator(name=f"{name}_engine", trntype=mujoco.mjtTrn.mjTRN_TENDON, target=f"{name}_drive",
                      gear=[WHEEL_TORQUE, 0, 0, 0, 0, 0], ctrllimited=True, ctrlrange=[-1.0, 1.0])
    for side in ("left", "right"):
        act = spec.add_actuator(name=f"{name}_steer_{side}", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                                target=f"{name}_steer_{side}", ctrllimited=True, ctrlrange=[-0.5, 0.5])
        act.set_to_position(kp=3000.0, kv=300.0)
    return body


def rear_axle_point(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> np.ndarray:
    """The rear axle's centre (x, y) [m] as MuJoCo has it: the midpoint of the two rear
    wheels' centres (after ``mj_forward``)."""
    return 0.5 * (data.body(f"{name}_wheel_rl").xpos[:2] + data.body(f"{name}_wheel_rr").xpos[:2])


def add_mocap_car(spec: mujoco.MjSpec, name: str, pos: tuple[float, float] = (0.0, 0.0),
                  yaw: float = 0.0, scale: float = 1.0) -> mujoco.MjsBody:
    """A mocap body ``name`` whose origin is the rear axle (no joint: move it with
    ``data.mocap_pos`` / ``data.mocap_quat``); a visual box 4.6 m x 1.8 m (times ``scale``:
    0.46 m x 0.18 m at 1:10) that collides with nothing."""
    body = spec.worldbody.add_body(name=name, mocap=True, pos=[pos[0], pos[1], 0.0], quat=_quat(yaw))
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[2.3 * scale, 0.9 * scale, 0.7 * scale],
                  pos=[1.35 * scale, 0, 0.7 * scale], rgba=[0.7, 0.5, 0.1, 1], contype=0, conaffinity=0,
                  group=2)
    return body


def set_mocap_pose(model: mujoco.MjModel, data: mujoco.MjData, name: str, x: float, y: float,
                   yaw: float) -> None:
    """Put the mocap car ``name`` with its rear axle at (x, y) [m], heading ``yaw`` [rad]."""
    i = int(model.body_mocapid[model.body(name).id])
    data.mocap_pos[i] = (x, y, 0.0)
    data.mocap_quat[i] = _quat(yaw)
