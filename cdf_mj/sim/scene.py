"""Load an MJCF scene and answer "where is it?" by name.

A :class:`Scene` owns one ``MjModel``/``MjData`` pair, checks once that every element
the code needs exists (:func:`cdf_mj.sim.checks.validate`: one error listing all that
are missing or wrong), reads the junction's static :class:`~cdf_mj.model.layout.Layout`
(routes, lanes, start poses, buildings, car dimensions) and steps the physics. Poses
are ``[x, y, theta, v]``: rear-axle position [m] and heading [rad] in the world frame
(x east, y north), speed [m/s] along the heading. ::

    from cdf_mj.sim.scene import Scene
    scene = Scene.load()                       # models/xml/scene.xml
    layout = scene.layout()                    # static geometry, NumPy only
    scene.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)
    scene.set_controls("ego", accel=0.0, steer=0.0)
    collision = scene.step(20)                 # 20 physics steps = 0.1 s
    poses = scene.poses()                      # (2, 4): ego, obstacle
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.geometry import OrientedBox, Polyline
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import Occluders
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.sim.assets import DEFAULT_SCENE
from cdf_mj.sim.checks import SceneError, check_drive, check_regular_files, substeps, validate

__all__ = ["DEFAULT_SCENE", "Car", "Scene", "SceneError", "SimulationDivergedError", "car_geometry",
           "read_layout"]

# Where data.warning counts MuJoCo's "unstable simulation" warnings (plain ints: read every tick).
_BADQPOS, _BADQVEL, _BADQACC = (int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                                 mujoco.mjtWarning.mjWARN_BADQACC))
_TWO_PI = 2 * math.pi


class SimulationDivergedError(FloatingPointError):
    """MuJoCo found a NaN, Inf or huge value in the state (and reset it)."""


def _yaw(mat9: np.ndarray) -> float:
    """Heading [rad] of a frame's x axis projected on the ground, from a row-major 3x3."""
    return math.atan2(mat9[3], mat9[0])


def _exists(m: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> bool:
    return mujoco.mj_name2id(m, kind, name) >= 0


def car_geometry(model: mujoco.MjModel, names: SceneNames, prefix: str,
                 source: str = "<model>") -> CarGeometry:
    """A car's dimensions read from the model: wheelbase = x offset of body ``front_axle``
    in the chassis frame, the collision box = geom ``hull``, the eye = site ``eye``, the
    ranges = ctrlranges of actuators ``accel`` and ``steer`` (all with ``prefix``).

    These are our car's conventions (origin on the rear axle); for any other car give a
    :class:`CarGeometry` instead. SceneError naming every missing element, or a bad value.
    """
    m, n = model, names
    wanted = ((mujoco.mjtObj.mjOBJ_BODY, "body", n.front_axle), (mujoco.mjtObj.mjOBJ_GEOM, "geom", n.hull),
              (mujoco.mjtObj.mjOBJ_SITE, "site", n.eye), (mujoco.mjtObj.mjOBJ_ACTUATOR, "actuator", n.accel),
              (mujoco.mjtObj.mjOBJ_ACTUATOR, "actuator", n.steer))
    missing = [f"{word} '{prefix}{name}'" for kind, word, name in wanted
               if not _exists(m, kind, prefix + name)]
    if missing:
        raise SceneError(f"scene {source}: car '{prefix}' lacks {', '.join(missing)}, from which "
                         "its dimensions are read; name them (SceneNames) or give the car's "
                         "CarGeometry")
    hull = m.geom(prefix + n.hull)
    accel, steer = m.actuator(prefix + n.accel), m.actuator(prefix + n.steer)
    try:
        return CarGeometry(
            wheelbase=float(m.body(prefix + n.front_axle).pos[0]),
            hull_offset=np.array(hull.pos[:2], dtype=float),
            hull_half=np.array(hull.size[:2], dtype=float),
            hull_height=float(hull.pos[2] + hull.size[2]),
            eye_offset=np.array(m.site(prefix + n.eye).pos, dtype=float),
            accel_range=(float(accel.ctrlrange[0]), float(accel.ctrlrange[1])),
            steer_range=(float(steer.ctrlrange[0]), float(steer.ctrlrange[1])))
    except ValueError as exc:
        raise SceneError(f"scene {source}: car '{prefix}': {exc}") from None


def _junction(m: mujoco.MjModel, d: mujoco.MjData, n: SceneNames, buildings: np.ndarray,
              ego: CarGeometry, obstacle: CarGeometry) -> Layout:
    """The layout from ``d``, the model at its reference configuration (names checked)."""

    def site_pose(name: str) -> np.ndarray:
        s = d.site(name)
        return np.array([s.xpos[0], s.xpos[1], _yaw(s.xmat), 0.0])

    def site_box(name: str) -> OrientedBox:
        s = d.site(name)
        return OrientedBox(np.array(s.xpos[:2]), _yaw(s.xmat), np.array(m.site(name).size[:2]))

    def route(body: str) -> Polyline:
        ids = np.flatnonzero(m.site_bodyid == m.body(body).id)
        return Polyline(d.site_xpos[ids, :2].copy())

    ids = buildings
    xmat = d.geom_xmat[ids].reshape(-1, 3, 3)
    size = m.geom_size[ids]
    z = d.geom_xpos[ids, 2]
    occluders = Occluders(names=tuple(m.geom(int(i)).name for i in ids),
                          center=d.geom_xpos[ids, :2].copy(),
                          heading=np.arctan2(xmat[:, 1, 0], xmat[:, 0, 0]),
                          half=size[:, :2].copy(), bottom=z - size[:, 2], top=z + size[:, 2])
    return Layout(route_ego=route(n.route_ego), route_left=route(n.route_left),
                  route_right=route(n.route_right),
                  conflict=np.array(d.site(n.conflict).xpos[:2], dtype=float),
                  commit=np.array(d.site(n.commit).xpos[:2], dtype=float),
                  stop_line=site_box(n.stop_line), ego_lane=site_box(n.ego_lane),
                  ego_start=site_pose(n.ego_start), obstacle_start=site_pose(n.obstacle_start),
                  occluders=occluders, ego=ego, obstacle=obstacle)


def read_layout(model: mujoco.MjModel, names: SceneNames | None = None, *,
                ego: CarGeometry | None = None, obstacle: CarGeometry | None = None,
                source: str = "<model>") -> Layout:
    """The junction's :class:`Layout` from any model, whatever its cars: routes, sites and
    buildings by ``names`` at the model's reference configuration (``qpos0``), and the two
    cars' dimensions, ``ego`` and ``obstacle``, as given (default: read from the model's
    elements by :func:`car_geometry`, i.e. our car's conventions).

    Nothing of a car is read when its geometry is given, so a user's own cars (free joint,
    mocap, other structure) are fine. SceneError listing every problem of the junction
    (:func:`cdf_mj.sim.checks.validate` with ``cars=False``), then a car's missing elements.
    """
    m, n = model, names or SceneNames()
    reference = mujoco.MjData(m)
    mujoco.mj_kinematics(m, reference)
    validate(m, reference, n, source, cars=False)
    if ego is None:
        ego = car_geometry(m, n, n.ego_prefix, source)
    if obstacle is None:
        obstacle = car_geometry(m, n, n.obstacle_prefix, source)
    buildings = np.array([i for i in range(m.ngeom)
                          if (m.geom(i).name or "").startswith(n.building_prefix)], dtype=int)
    try:
        return _junction(m, reference, n, buildings, ego, obstacle)
    except ValueError as exc:
        raise SceneError(f"scene {source}: {' '.join(str(exc).split())}") from None


@dataclass(frozen=True, eq=False)
class Car:
    """Where one placed car lives in the model (ids and addresses), and its dimensions."""

    prefix: str
    body: int  # chassis body id (origin on the rear axle)
    accel: int  # actuator id, ctrl [m/s^2]
    steer: int  # actuator id, ctrl [rad]
    accel_act: int  # index in data.act of the speed state [m/s]
    qpos: np.ndarray  # qpos addresses of the planar joints x, y, yaw
    qvel: np.ndarray  # dof addresses of the planar joints x, y, yaw
    steer_qpos: int  # qpos address of the steering hinge
    steer_dof: int  # dof address of the steering hinge
    frame_pos: np.ndarray  # (2,) origin of the joints' frame in the world [m]
    frame_yaw: float  # heading of the joints' frame [rad]
    geometry: CarGeometry  # dimensions and actuator ranges, chassis frame


class Scene:
    """An MJCF scene with two cars, read by name.

    Args:
        model: compiled model; use :meth:`load` to read a file.
        names: the element names to read (defaults match ``models/xml``).
        source: where the model came from, for error messages.
        data: the ``MjData`` to read poses from and step (default: a new one). Pass your
            own to watch a simulation that you step yourself (:meth:`from_model`).
        drive: test-drive both cars once on a scratch ``MjData`` (about 2 ms): SceneError
            if one does not move or steer when commanded (:func:`cdf_mj.sim.checks.check_drive`).
            False for cars that are only observed.
        compiler_degree: the source file's compiler reads angles in degrees, which is
            refused (:meth:`load` reads it from the file; an ``MjModel`` does not keep it).

    The static geometry (:meth:`layout`) is read once, from the model at its reference
    configuration; poses are read from ``data`` on demand. SceneError lists every missing
    or wrong element at once.
    """

    def __init__(self, model: mujoco.MjModel, names: SceneNames | None = None,
                 source: str = "<model>", data: mujoco.MjData | None = None, *,
                 drive: bool = True, compiler_degree: bool = False) -> None:
        self.model = model
        self.names = n = names or SceneNames()
        self.source = source
        reference = mujoco.MjData(model)  # static geometry at qpos0
        mujoco.mj_kinematics(model, reference)
        validate(model, reference, n, source, compiler_degree=compiler_degree)
        if drive:  # the code will drive these cars: each must move when commanded
            check_drive(model, n, source)
        self.ego = self._car(n.ego_prefix)
        self.obstacle = self._car(n.obstacle_prefix)
        self.cars = {"ego": self.ego, "obstacle": self.obstacle}
        self.buildings = np.array([i for i in range(model.ngeom)
                                   if (model.geom(i).name or "").startswith(n.building_prefix)],
                                  dtype=int)
        self._root = model.body_rootid[model.geom_bodyid]  # geom -> root body
        self._is_building = np.zeros(model.ngeom, dtype=bool)
        self._is_building[self.buildings] = True
        # Ray filter for sight lines: the geom groups of the buildings and of the two cars'
        # collision boxes (groups 1 and 3 in models/xml).
        self.ray_groups = np.zeros(mujoco.mjNGROUP, dtype=np.uint8)
        hulls = [model.geom(p + n.hull).id for p in (n.ego_prefix, n.obstacle_prefix)]
        self.ray_groups[model.geom_group[np.r_[self.buildings, hulls].astype(int)]] = 1
        self._layout = self._read_layout(reference)
        self.data = reference
        if data is not None:
            have = (data.qpos.size, data.act.size, data.xpos.shape[0], data.geom_xpos.shape[0],
                    data.site_xpos.shape[0])
            want = (model.nq, model.na, model.nbody, model.ngeom, model.nsite)
            if have != want:
                raise SceneError(f"scene {source}: the MjData given does not belong to this "
                                 f"model (nq, na, nbody, ngeom, nsite: {have} vs {want})")
            self.data = data
        # Both cars' joint addresses and frames as Python numbers, for the per-tick pose read.
        self._frames = tuple((float(c.frame_pos[0]), float(c.frame_pos[1]), math.cos(c.frame_yaw),
                              math.sin(c.frame_yaw), c.frame_yaw) for c in (self.ego, self.obstacle))
        self._bound: mujoco.MjData | None = None  # the data whose array views are kept (see _bind)

    # ----------------------------------------------------------------- loading
    @classmethod
    def load(cls, path: str | Path = DEFAULT_SCENE, names: SceneNames | None = None) -> Scene:
        """Compile an MJCF file into a scene; errors name the file. The file and every file
        it names must be regular files (:func:`cdf_mj.sim.checks.check_regular_files`:
        checked before MuJoCo opens any, so a FIFO cannot block)."""
        path = Path(path)
        check_regular_files(path)
        try:  # through MjSpec: the model does not keep the compiler's angle unit, the spec does
            spec = mujoco.MjSpec.from_file(str(path))
            model = spec.compile()
        except ValueError as exc:  # MuJoCo reports parse and compile errors as ValueError
            msg = " ".join(str(exc).split())
            raise SceneError(f"cannot load scene {path}: {msg}") from None
        return cls(model, names, source=str(path), compiler_degree=bool(spec.compiler.degree))

    @classmethod
    def from_model(cls, model: mujoco.MjModel, data: mujoco.MjData | None = None,
                   names: SceneNames | None = None, source: str = "<model>", *,
                   drive: bool = True) -> Scene:
        """A scene over a model you compiled yourself (for example from an ``MjSpec`` with
        cars placed by :func:`cdf_mj.sim.spec.add_car`), reading poses from your ``data``.

        ``names`` says which elements are the cars, routes, lanes and sites
        (:class:`cdf_mj.config.SceneNames`; docs/SCENES.md lists them). SceneError lists
        every missing or wrong element at once. ``drive=False`` skips the test drive of
        the cars (:func:`cdf_mj.sim.checks.check_drive`) for a scene whose cars you only
        observe, never drive through this scene.
        """
        return cls(model, names, source=source, data=data, drive=drive)

    def substeps(self, dt: float) -> int:
        """Physics steps per scenario tick of ``dt`` [s]: SceneError naming both numbers if
        ``dt`` is not a whole multiple of the model's timestep."""
        return substeps(float(self.model.opt.timestep), dt, self.source)

    def layout(self) -> Layout:
        """The junction's static geometry (routes, points, lanes, start poses, buildings,
        both cars' dimensions), read once when the scene was built: what drivers, the
        filter and planners may know. The same object on every call."""
        return self._layout

    def _read_layout(self, d: mujoco.MjData) -> Layout:
        """The layout from ``d``, the model at its reference configuration."""
        return _junction(self.model, d, self.names, self.buildings, self.ego.geometry,
                         self.obstacle.geometry)

    def _car(self, prefix: str) -> Car:
        m, n = self.model, self.names
        body = m.body(prefix + n.chassis)
        joints = [m.joint(prefix + j) for j in n.planar_joints]
        steer_joint = m.joint(prefix + n.steer_joint)
        accel = m.actuator(prefix + n.accel)
        steer = m.actuator(prefix + n.steer)
        quat = body.quat
        frame_yaw = 2.0 * math.atan2(quat[3], quat[0])  # the chassis frame is level
        geometry = car_geometry(m, n, prefix, self.source)
        return Car(
            prefix=prefix,
            body=body.id,
            accel=accel.id,
            steer=steer.id,
            accel_act=int(m.actuator_actadr[accel.id]),
            qpos=np.array([j.qposadr[0] for j in joints]),
            qvel=np.array([j.dofadr[0] for j in joints]),
            steer_qpos=int(steer_joint.qposadr[0]),
            steer_dof=int(steer_joint.dofadr[0]),
            frame_pos=np.array(body.pos[:2], dtype=float),
            frame_yaw=frame_yaw,
            geometry=geometry,
        )

    # ----------------------------------------------------------------- state
    def car(self, which: str) -> Car:
        """The car called ``"ego"`` or ``"obstacle"``."""
        try:
            return self.cars[which]
        except KeyError:
            raise KeyError(f"unknown car {which!r}: expected 'ego' or 'obstacle'") from None

    def reset(self, ego: np.ndarray, obstacle: np.ndarray) -> None:
        """Clear the simulation and place both cars at poses ``[x, y, theta, v]``."""
        mujoco.mj_resetData(self.model, self.data)
        for car, pose in ((self.ego, ego), (self.obstacle, obstacle)):
            self.set_pose(car, pose)
        mujoco.mj_forward(self.model, self.data)

    def set_pose(self, car: Car, pose: np.ndarray) -> None:
        """Put a car at pose ``[x, y, theta, v]`` (world frame) with straight wheels and its
        controls at zero; refuses a non-finite pose without touching the state."""
        x, y, th, v = (float(p) for p in pose)
        if not all(math.isfinite(p) for p in (x, y, th, v)):
            raise ValueError(f"pose of {car.prefix.rstrip('_')} is not finite: {list(pose)}")
        d = self.data
        c, s = math.cos(car.frame_yaw), math.sin(car.frame_yaw)
        dx, dy = x - car.frame_pos[0], y - car.frame_pos[1]
        rel = th - car.frame_yaw
        d.qpos[car.qpos] = (c * dx + s * dy, -s * dx + c * dy, rel)
        d.qvel[car.qvel] = (v * math.cos(rel), v * math.sin(rel), 0.0)
        d.qpos[car.steer_qpos] = 0.0
        d.qvel[car.steer_dof] = 0.0
        d.act[car.accel_act] = v
        d.ctrl[car.accel] = 0.0
        d.ctrl[car.steer] = 0.0

    def pose(self, car: Car) -> np.ndarray:
        """Current pose ``[x, y, theta, v]`` of one car, from its joints (exact after a step)."""
        return np.array(self._pose(car))

    def poses(self) -> np.ndarray:
        """System pose ``S_t`` as ``(2, 4)``: row 0 the ego, row 1 the obstacle."""
        return np.array(self.pose_values())

    def _pose(self, car: Car) -> list[float]:
        """:meth:`pose` as Python floats (read every tick: NumPy scalars would cost more)."""
        if car is self.ego or car is self.obstacle:
            return self.pose_values()[car is self.obstacle]
        d = self.data
        qx, qy, qyaw = d.qpos[car.qpos].tolist()
        vx, vy, _ = d.qvel[car.qvel].tolist()
        fx, fy = car.frame_pos.tolist()
        c, s = math.cos(car.frame_yaw), math.sin(car.frame_yaw)
        v = vx * math.cos(qyaw) + vy * math.sin(qyaw)
        return [fx + c * qx - s * qy, fy + s * qx + c * qy, math.remainder(car.frame_yaw + qyaw, _TWO_PI), v]

    def __getstate__(self) -> dict[str, Any]:
        """Copies and pickles leave out the kept array views (:meth:`_bind`): a copy binds
        to its own ``data`` at its first read."""
        state = {k: v for k, v in self.__dict__.items() if k not in ("_qpos", "_qvel", "_ctrl", "_warnings")}
        state["_bound"] = None
        return state

    def _bind(self) -> None:
        """Keep views of ``self.data``'s arrays that the per-tick calls read and write (an
        MjData never moves its buffers): the joint positions and velocities, the controls
        and the warning counters; and the addresses of both cars' planar joints (x, y, yaw
        and the two planar velocities of each, ego first). Called again whenever
        ``self.data`` is another object."""
        d = self.data
        self._qpos, self._qvel = d.qpos, d.qvel
        self._qaddr = np.array([int(a) for c in (self.ego, self.obstacle) for a in c.qpos])
        self._vaddr = np.array([int(a) for c in (self.ego, self.obstacle) for a in c.qvel[:2]])
        self._ctrl = d.ctrl
        self._warnings = d.warning.number  # a view: (mjNWARNING,) counts
        self._bound = d

    def pose_values(self) -> list[list[float]]:
        """Both poses ``[[x, y, theta, v] ego, [...] obstacle]`` (world frame [m], heading
        [rad] in (-pi, pi], speed along the heading [m/s]) as Python floats: :meth:`poses`
        without its array, from one read of both cars' joints (the per-tick read)."""
        if self._bound is not self.data:
            self._bind()
        q = self._qpos[self._qaddr].tolist()
        w = self._qvel[self._vaddr].tolist()
        out = []
        for i, (fx, fy, c, s, yaw) in enumerate(self._frames):
            qx, qy, qyaw = q[3 * i], q[3 * i + 1], q[3 * i + 2]
            vx, vy = w[2 * i], w[2 * i + 1]
            v = vx * math.cos(qyaw) + vy * math.sin(qyaw)
            out.append([fx + c * qx - s * qy, fy + s * qx + c * qy, math.remainder(yaw + qyaw, _TWO_PI), v])
        return out

    def set_controls(self, which: str, accel: float, steer: float) -> None:
        """Command a car: acceleration [m/s^2] and steering angle [rad], clipped to the
        actuator ranges as MuJoCo does."""
        car = self.car(which)
        if self._bound is not self.data:
            self._bind()
        ctrl = self._ctrl
        ctrl[car.accel] = accel
        ctrl[car.steer] = steer

    def drive(self, ego_accel: float, ego_steer: float, obstacle_accel: float, obstacle_steer: float) -> None:
        """:meth:`set_controls` of both cars at once (the per-tick call): accelerations
        [m/s^2] and steering angles [rad], clipped to the actuator ranges by MuJoCo."""
        if self._bound is not self.data:
            self._bind()
        ctrl, ego, obstacle = self._ctrl, self.ego, self.obstacle
        ctrl[obstacle.accel] = obstacle_accel
        ctrl[obstacle.steer] = obstacle_steer
        ctrl[ego.accel] = ego_accel
        ctrl[ego.steer] = ego_steer

    def step(self, nstep: int) -> str | None:
        """Advance ``nstep`` physics steps; stop at the first contact of the ego.

        Returns ``"obstacle"`` or ``"building"`` (a geom named ``building*``) for the ego's
        first such contact, else ``None``.
        Contacts of the obstacle with a building are ignored here (they do not end the
        ego's episode) but stay in ``data.contact``.
        """
        m, d = self.model, self.data
        bad_before = self._instability_count()
        mj_step = mujoco.mj_step
        for _ in range(nstep):
            mj_step(m, d)
            if d.ncon:  # after a reset the cars overlap: rule that out before reporting
                self._check_stable(bad_before)
                hit = self._ego_contact()
                if hit is not None:
                    return hit
        self._check_stable(bad_before)
        return None

    def _check_stable(self, bad_before: int) -> None:
        if self._instability_count() != bad_before:
            raise SimulationDivergedError(
                f"MuJoCo reported an unstable simulation (NaN, Inf or huge value in qpos, "
                f"qvel or qacc) in {self.source}; it reset the state, so the run is void")

    def _instability_count(self) -> int:
        if self._bound is not self.data:
            self._bind()
        n = self._warnings.tolist()  # (mjNWARNING,) counts, one array read
        return n[_BADQPOS] + n[_BADQVEL] + n[_BADQACC]

    def _ego_contact(self) -> str | None:
        d = self.data
        geoms = d.contact.geom[: d.ncon]  # (ncon, 2)
        roots = self._root[geoms]
        ego, obs = self.ego.body, self.obstacle.body
        with_ego = roots == ego
        if np.any((with_ego[:, 0] & (roots[:, 1] == obs)) | (with_ego[:, 1] & (roots[:, 0] == obs))):
            return "obstacle"
        building = self._is_building[geoms]
        if np.any((with_ego[:, 0] & building[:, 1]) | (with_ego[:, 1] & building[:, 0])):
            return "building"
        return None

    def sync(self) -> None:
        """Recompute positions of all geoms and sites from ``qpos`` (for rays and drawing)."""
        mujoco.mj_kinematics(self.model, self.data)
