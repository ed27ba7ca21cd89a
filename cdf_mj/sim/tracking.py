"""Where a car is in a MuJoCo simulation that someone else steps: the rear-axle pose
``[x m, y m, yaw rad, speed m/s]`` (world frame) of a named body of any kind, for the
CDF monitor (:func:`cdf_mj.scenario.monitor.attach`).

:class:`TrackedCar` says how one car is read (its body, the rear axle's place and the
forward direction in that body's frame, its dimensions); :func:`find_bodies` looks both
cars' bodies up by name; :class:`BodyPoseSource` reads their poses from the user's
``MjData`` without writing to it; :class:`ScenePoseSource` reads those of our own
:class:`~cdf_mj.sim.scene.Scene`. The sources have the monitor's ``read() -> (t, poses)``
(:class:`cdf_mj.scenario.monitor.PoseSource`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.vehicle import CAR_SIZE, CarGeometry, unit_hint
from cdf_mj.sim.checks import SceneError
from cdf_mj.sim.scene import Scene

__all__ = ["BodyPoseSource", "ScenePoseSource", "TrackedCar", "find_bodies"]


@dataclass(frozen=True)
class TrackedCar:
    """How :func:`attach` reads one car.

    Attributes:
        body: the body whose pose is the car's (default: the car's prefix + ``chassis``
            of the :class:`SceneNames`). Any body: planar or free joints, a mocap body, a
            child of other moving bodies.
        rear_axle: ``(x, y)`` [m] the rear axle's centre in that body's frame (a chassis
            origin at the car's centre: ``(-wheelbase / 2, 0)`` or so), within
            :data:`~cdf_mj.model.vehicle.CAR_SIZE` of the body's origin as every part of a
            :class:`~cdf_mj.model.vehicle.CarGeometry` is (beyond it, a ValueError says which
            smaller unit it looks like: ``(-1350.0, 0.0)``, millimetres?). The pose given to
            the filter is this point's.
        heading: [rad] the car's forward direction in the body frame, from the body's x
            axis about its z axis (0: x forward; ``pi / 2``: y forward).
        geometry: the car's dimensions in its rear-axle frame; default: read from the
            model's elements of our car (``front_axle``, ``hull``, ``eye``, ``accel``,
            ``steer``: :func:`cdf_mj.sim.scene.car_geometry`), which only our car has.
    """

    body: str | None = None
    rear_axle: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0
    geometry: CarGeometry | None = None

    def __post_init__(self) -> None:
        try:
            x, y = (float(v) for v in self.rear_axle)
            heading = float(self.heading)
        except (TypeError, ValueError):
            x = y = heading = math.nan
        if not all(math.isfinite(v) for v in (x, y, heading)):
            raise ValueError(f"TrackedCar: rear_axle must be (x, y) [m] and heading [rad] finite, got "
                             f"rear_axle={self.rear_axle!r}, heading={self.heading!r}")
        if (far := math.hypot(x, y)) > CAR_SIZE:
            raise ValueError(f"TrackedCar: rear_axle=({x:g}, {y:g}) is {far:g} m from the body's origin: a car's "
                             f"rear axle is within {CAR_SIZE:g} m of its body{unit_hint(far, CAR_SIZE)}")
        object.__setattr__(self, "rear_axle", (x, y))
        object.__setattr__(self, "heading", heading)
        if self.geometry is not None and not isinstance(self.geometry, CarGeometry):
            raise TypeError(f"TrackedCar: geometry must be a CarGeometry, got {type(self.geometry).__name__}")


def find_bodies(model: mujoco.MjModel, names: SceneNames, ego: TrackedCar, obstacle: TrackedCar) -> list[int]:
    """The ids of the ego's and the obstacle's bodies: each :attr:`TrackedCar.body`, or else
    the car's prefix + ``chassis`` of ``names``. SceneError naming the body and the fix for
    one that is not in the model (or is the world body), or for both cars on one body."""
    bodies = []
    for which, car, prefix in (("ego", ego, names.ego_prefix), ("obstacle", obstacle, names.obstacle_prefix)):
        body = car.body or prefix + names.chassis
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if bid <= 0:
            raise SceneError(f"attach: the {which} car's body '{body}' is not in the model (the world "
                             f"body cannot be a car); name it with TrackedCar(body=...) or the "
                             f"{which}_prefix and chassis of SceneNames")
        bodies.append(bid)
    if bodies[0] == bodies[1]:
        raise SceneError(f"attach: ego and obstacle are both body '{model.body(bodies[0]).name}'")
    return bodies


class BodyPoseSource:
    """Rear-axle poses of two named bodies of any kind, read from the user's ``MjData``.

    The user's data is only read: its ``qpos``, ``qvel`` and mocap poses are copied into a
    private ``MjData`` whose kinematics and velocities are computed there (exact after
    ``mj_step``, whose own derived quantities are those of the step's start). Speed is the
    rear axle's velocity along the heading; a body that no degree of freedom moves (a
    mocap body) has none in MuJoCo, so its speed is the rear axle's displacement since the
    last read along the heading over the elapsed time (0 at the first read). SceneError if
    ``data`` is not an ``MjData`` of ``model``.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, bodies: Sequence[int],
                 cars: Sequence[TrackedCar]) -> None:
        if (data.qpos.size != model.nq or data.xpos.shape[0] != model.nbody
                or data.mocap_pos.shape[0] != model.nmocap):
            raise SceneError("attach: the MjData given does not belong to this model (its sizes differ)")
        self.model, self.data = model, data
        self.timestep = float(model.opt.timestep)
        self.scratch = mujoco.MjData(model)
        self.bodies = list(bodies)
        self.offsets = [np.array([c.rear_axle[0], c.rear_axle[1], 0.0]) for c in cars]
        self.forward = [np.array([math.cos(c.heading), math.sin(c.heading), 0.0]) for c in cars]
        self.moved = [self._has_dofs(b) for b in self.bodies]
        self._last: tuple[float, np.ndarray] | None = None

    def _has_dofs(self, body: int) -> bool:
        """Whether any joint moves ``body`` (on it or on one of its ancestors)."""
        m = self.model
        while body > 0:
            if m.body_dofnum[body] > 0:
                return True
            body = int(m.body_parentid[body])
        return False

    def forget(self) -> None:
        """Drop the last read (after a reset: no finite difference across it)."""
        self._last = None

    def read(self) -> tuple[float, np.ndarray]:
        mj, m, d, s = mujoco, self.model, self.data, self.scratch
        s.qpos[:], s.qvel[:] = d.qpos, d.qvel
        s.mocap_pos[:], s.mocap_quat[:] = d.mocap_pos, d.mocap_quat
        mj.mj_kinematics(m, s)
        mj.mj_comPos(m, s)
        mj.mj_comVel(m, s)
        t = float(d.time)
        poses = np.zeros((2, 4))
        points = np.zeros((2, 3))
        vel = np.zeros(6)
        for i, body in enumerate(self.bodies):
            rot = s.xmat[body].reshape(3, 3)
            arm = rot @ self.offsets[i]
            points[i] = s.xpos[body] + arm
            fwd = rot @ self.forward[i]
            yaw = math.atan2(fwd[1], fwd[0])
            heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
            if self.moved[i]:
                mj.mj_objectVelocity(m, s, mj.mjtObj.mjOBJ_XBODY, body, vel, 0)  # [rot, lin] at xpos, world axes
                speed = float((vel[3:] + np.cross(vel[:3], arm)) @ heading)
            elif self._last is not None and t > self._last[0]:
                speed = float((points[i] - self._last[1][i]) @ heading / (t - self._last[0]))
            else:
                speed = 0.0
            poses[i] = (points[i, 0], points[i, 1], yaw, speed)
        self._last = (t, points)
        return t, poses


class ScenePoseSource:
    """Time and poses of a :class:`~cdf_mj.sim.scene.Scene` (our cars, by their joints)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.timestep = float(scene.model.opt.timestep)

    def read(self) -> tuple[float, np.ndarray]:
        return float(self.scene.data.time), self.scene.poses()
