"""Load an MJCF scene and answer "where is it?" by name.

A :class:`Scene` owns one ``MjModel``/``MjData`` pair, checks once that every element
the code needs exists (one error listing all that are missing), and reads the routes,
lanes and start poses from the model. Poses are ``[x, y, theta, v]``: rear-axle position
[m] and heading [rad] in the world frame (x east, y north), speed [m/s] along the
heading. ::

    from cdf_mj.sim.scene import Scene
    scene = Scene.load()                       # models/xml/scene.xml
    scene.reset(ego=scene.ego_start, obstacle=scene.obstacle_start)
    scene.set_controls("ego", accel=0.0, steer=0.0)
    collision = scene.step(20)                 # 20 physics steps = 0.1 s
    poses = scene.poses()                      # (2, 4): ego, obstacle
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.geometry import OrientedBox, Polyline, rotated_corners
from cdf_mj.sim.assets import CAR_XML, DEFAULT_SCENE, MODELS_DIR

__all__ = [
    "CAR_XML",
    "DEFAULT_SCENE",
    "MODELS_DIR",
    "Car",
    "Scene",
    "SceneError",
    "SimulationDivergedError",
    "add_car",
]


_OBJ = {
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
}


class SceneError(ValueError):
    """A scene file that cannot be loaded or lacks an element the code needs."""


class SimulationDivergedError(FloatingPointError):
    """MuJoCo found a NaN, Inf or huge value in the state (and reset it)."""


def _id(model: mujoco.MjModel, kind: str, name: str) -> int:
    return mujoco.mj_name2id(model, _OBJ[kind], name)


def _yaw(mat9: np.ndarray) -> float:
    """Heading [rad] of a frame's x axis projected on the ground, from a row-major 3x3."""
    return math.atan2(mat9[3], mat9[0])


@dataclass(frozen=True)
class Car:
    """Indices and dimensions of one placed car, read from the model."""

    prefix: str
    body: int  # chassis body id (origin on the rear axle)
    accel: int  # actuator id, ctrl [m/s^2]
    steer: int  # actuator id, ctrl [rad]
    accel_act: int  # index in data.act of the speed state [m/s]
    qpos: np.ndarray  # qpos addresses of the planar joints x, y, yaw
    qvel: np.ndarray  # dof addresses of the planar joints x, y, yaw
    steer_qpos: int  # qpos address of the steering hinge
    steer_dof: int
    frame_pos: np.ndarray  # (2,) origin of the joints' frame in the world [m]
    frame_yaw: float  # heading of the joints' frame [rad]
    wheelbase: float  # [m] rear axle to front axle
    hull_offset: np.ndarray  # (2,) centre of the collision box in the chassis frame [m]
    hull_half: np.ndarray  # (2,) half length and half width of the collision box [m]
    hull_height: float  # [m] top of the collision box above the ground
    eye_offset: np.ndarray  # (3,) driver's eye in the chassis frame [m]
    accel_range: tuple[float, float]  # [m/s^2] (maximum braking as negative, maximum accel)
    steer_range: tuple[float, float]  # [rad]

    @property
    def max_brake(self) -> float:
        """Maximum braking deceleration [m/s^2], positive."""
        return -self.accel_range[0]

    def footprint(self, pose: np.ndarray) -> np.ndarray:
        """Corners ``(..., 4, 2)`` [m] of the collision box for pose(s) ``(..., 4)``."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        ox, oy = self.hull_offset
        return rotated_corners(pose[..., 0] + c * ox - s * oy, pose[..., 1] + s * ox + c * oy, c, s,
                               self.hull_half)

    def eye(self, pose: np.ndarray) -> np.ndarray:
        """World position(s) ``(..., 3)`` [m] of the driver's eye for pose(s) ``(..., 4)``."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        ex, ey, ez = self.eye_offset
        out = np.empty(pose.shape[:-1] + (3,))
        out[..., 0] = pose[..., 0] + c * ex - s * ey
        out[..., 1] = pose[..., 1] + s * ex + c * ey
        out[..., 2] = ez
        return out


class Scene:
    """An MJCF scene with two cars, its routes and lanes, read by name.

    Args:
        model: compiled model; use :meth:`load` to read a file.
        names: the element names to read (defaults match ``models/xml``).
        source: where the model came from, for error messages.
        data: the ``MjData`` to read poses from and step (default: a new one). Pass your
            own to watch a simulation that you step yourself (:meth:`from_model`).

    The static geometry (routes, lanes, start sites, car dimensions) is read once, from
    the model at its reference configuration; poses are read from ``data`` on demand.
    """

    def __init__(self, model: mujoco.MjModel, names: SceneNames | None = None,
                 source: str = "<model>", data: mujoco.MjData | None = None) -> None:
        self.model = model
        self.names = names or SceneNames()
        self.source = source
        self.data = mujoco.MjData(model)  # scratch: static geometry at qpos0
        mujoco.mj_kinematics(model, self.data)
        self._validate()
        n = self.names
        self.ego = self._car(n.ego_prefix)
        self.obstacle = self._car(n.obstacle_prefix)
        self.cars = {"ego": self.ego, "obstacle": self.obstacle}
        self.ego_start = self._site_pose(n.ego_start)
        self.obstacle_start = self._site_pose(n.obstacle_start)
        self.ego_lane = self._site_box(n.ego_lane)
        self.stop_line = self._site_box(n.stop_line)
        self.conflict = self._site_xy(n.conflict)
        self.commit = self._site_xy(n.commit)
        self.route_ego = self._route(n.route_ego)
        self.route_left = self._route(n.route_left)
        self.route_right = self._route(n.route_right)
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
        if data is not None:
            have = (data.qpos.size, data.act.size, data.xpos.shape[0], data.geom_xpos.shape[0],
                    data.site_xpos.shape[0])
            want = (model.nq, model.na, model.nbody, model.ngeom, model.nsite)
            if have != want:
                raise SceneError(f"scene {source}: the MjData given does not belong to this "
                                 f"model (nq, na, nbody, ngeom, nsite: {have} vs {want})")
            self.data = data

    # ----------------------------------------------------------------- loading
    @classmethod
    def load(cls, path: str | Path = DEFAULT_SCENE, names: SceneNames | None = None) -> Scene:
        """Compile an MJCF file into a scene; errors name the file."""
        path = Path(path)
        if not path.is_file():
            raise SceneError(f"scene file not found: {path}")
        try:
            model = mujoco.MjModel.from_xml_path(str(path))
        except ValueError as exc:  # MuJoCo reports parse and compile errors as ValueError
            msg = " ".join(str(exc).split())
            raise SceneError(f"cannot load scene {path}: {msg}") from None
        return cls(model, names, source=str(path))

    @classmethod
    def from_model(cls, model: mujoco.MjModel, data: mujoco.MjData | None = None,
                   names: SceneNames | None = None, source: str = "<model>") -> Scene:
        """A scene over a model you compiled yourself (for example from an ``MjSpec`` with
        cars placed by :func:`add_car`), reading poses from your ``data``.

        ``names`` says which elements are the cars, routes, lanes and sites
        (:class:`cdf_mj.config.SceneNames`; docs/SCENES.md lists them). SceneError lists
        every missing or wrong element at once.
        """
        return cls(model, names, source=source, data=data)

    def _required(self) -> list[tuple[str, str]]:
        n = self.names
        req = [("site", s) for s in (n.ego_start, n.obstacle_start, n.stop_line, n.ego_lane,
                                     n.conflict, n.commit)]
        req += [("body", b) for b in (n.route_ego, n.route_left, n.route_right)]
        for p in (n.ego_prefix, n.obstacle_prefix):
            req += [("body", p + n.chassis), ("body", p + n.front_axle), ("geom", p + n.hull),
                    ("site", p + n.eye), ("actuator", p + n.accel), ("actuator", p + n.steer)]
            req += [("joint", p + j) for j in (*n.planar_joints, n.steer)]
        return req

    def _validate(self) -> None:
        """One SceneError listing every missing element, then every element of the wrong
        kind, shape or place (each checked only where it exists)."""
        m, n = self.model, self.names
        exists = {(kind, name): mujoco.mj_name2id(m, _OBJ[kind], name) >= 0
                  for kind, name in self._required()}
        missing = [f"{kind} '{name}'" for (kind, name), ok in exists.items() if not ok]
        wrong: list[str] = []

        def has(kind: str, name: str) -> bool:
            return exists[(kind, name)]

        d = self.data
        not_finite = [f"{kind} '{name}'" for kind, name in self._required()
                      if kind in ("site", "body") and has(kind, name)
                      and not np.all(np.isfinite((d.site if kind == "site" else d.body)(name).xpos))]
        if not_finite:
            wrong.append(f"positions that are not finite numbers: {', '.join(not_finite)}")
        for route in (n.route_ego, n.route_left, n.route_right):
            if not has("body", route):
                continue
            ids = np.flatnonzero(m.site_bodyid == m.body(route).id)
            if len(ids) < 2:
                wrong.append(f"body '{route}' has fewer than 2 waypoint sites")
                continue
            try:  # the route as the drivers will use it: Polyline's own rules
                Polyline(d.site_xpos[ids, :2])
            except ValueError as exc:
                wrong.append(f"body '{route}': {str(exc).replace('a polyline', 'the route')}")
        for site in (n.stop_line, n.ego_lane):
            if has("site", site) and m.site(site).type[0] != mujoco.mjtGeom.mjGEOM_BOX:
                wrong.append(f"site '{site}' must be a box (its half sizes give the area)")
        for p in (n.ego_prefix, n.obstacle_prefix):
            chassis = p + n.chassis
            if has("body", chassis):
                cid = m.body(chassis).id
                if m.body_parentid[cid] != 0:
                    wrong.append(f"body '{chassis}' must be a child of the worldbody")
                for kind, name, owner in (("body", p + n.front_axle, m.body_parentid),
                                          ("geom", p + n.hull, m.geom_bodyid),
                                          ("site", p + n.eye, m.site_bodyid)):
                    if has(kind, name) and owner[_id(m, kind, name)] != cid:
                        wrong.append(f"{kind} '{name}' must belong to body '{chassis}'")
            joints = [p + j for j in n.planar_joints]
            if all(has("joint", j) for j in joints):
                types = [int(m.joint(j).type[0]) for j in joints]
                if types != [mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_SLIDE,
                             mujoco.mjtJoint.mjJNT_HINGE]:
                    wrong.append(f"joints {', '.join(joints)} must be slide, slide, hinge")
            if has("joint", p + n.steer) and m.joint(p + n.steer).type[0] != mujoco.mjtJoint.mjJNT_HINGE:
                wrong.append(f"joint '{p}{n.steer}' must be a hinge")
            if has("geom", p + n.hull) and m.geom(p + n.hull).type[0] != mujoco.mjtGeom.mjGEOM_BOX:
                wrong.append(f"geom '{p}{n.hull}' must be a box")
            if has("actuator", p + n.accel):
                acc = m.actuator(p + n.accel)
                if acc.dyntype[0] != mujoco.mjtDyn.mjDYN_INTEGRATOR or not acc.ctrllimited[0]:
                    wrong.append(f"actuator '{p}{n.accel}' must be a ctrl-limited integrator "
                                 "(ctrl = acceleration, act = speed)")
                elif not acc.ctrlrange[0] < 0.0 < acc.ctrlrange[1]:
                    wrong.append(f"actuator '{p}{n.accel}' needs a ctrlrange from braking (< 0) "
                                 f"to accelerating (> 0) [m/s^2], has {acc.ctrlrange.tolist()}")
            if has("actuator", p + n.steer) and not m.actuator(p + n.steer).ctrllimited[0]:
                wrong.append(f"actuator '{p}{n.steer}' must be ctrl-limited (steering range)")
        not_box, tilted = [], []
        for g in range(m.ngeom):
            name = m.geom(g).name or ""
            if not name.startswith(n.building_prefix):
                continue
            if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
                kind = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
                not_box.append(f"'{name}' is a {kind}")
            elif abs(abs(self.data.geom_xmat[g, 8]) - 1.0) > 1e-9:
                tilted.append(f"'{name}'")
        if not_box:
            wrong.append(f"building geoms must be boxes: {', '.join(not_box)}")
        if tilted:
            wrong.append(f"building boxes must be upright (rotated about z only): {', '.join(tilted)}")
        problems = ([f"lacks {', '.join(missing)}"] if missing else []) + wrong
        if problems:
            raise SceneError(f"scene {self.source}: {'; '.join(problems)} "
                             "(docs/SCENES.md lists the names a scene must have)")

    def _car(self, prefix: str) -> Car:
        m, n = self.model, self.names
        body = m.body(prefix + n.chassis)
        joints = [m.joint(prefix + j) for j in n.planar_joints]
        steer_joint = m.joint(prefix + n.steer)
        accel = m.actuator(prefix + n.accel)
        steer = m.actuator(prefix + n.steer)
        hull = m.geom(prefix + n.hull)
        quat = body.quat
        frame_yaw = 2.0 * math.atan2(quat[3], quat[0])  # the chassis frame is level
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
            wheelbase=float(m.body(prefix + n.front_axle).pos[0]),
            hull_offset=np.array(hull.pos[:2], dtype=float),
            hull_half=np.array(hull.size[:2], dtype=float),
            hull_height=float(hull.pos[2] + hull.size[2]),
            eye_offset=np.array(m.site(prefix + n.eye).pos, dtype=float),
            accel_range=(float(accel.ctrlrange[0]), float(accel.ctrlrange[1])),
            steer_range=(float(steer.ctrlrange[0]), float(steer.ctrlrange[1])),
        )

    def _site_pose(self, name: str) -> np.ndarray:
        s = self.data.site(name)
        return np.array([s.xpos[0], s.xpos[1], _yaw(s.xmat), 0.0])

    def _site_xy(self, name: str) -> np.ndarray:
        return np.array(self.data.site(name).xpos[:2], dtype=float)

    def _site_box(self, name: str) -> OrientedBox:
        s = self.data.site(name)
        return OrientedBox(np.array(s.xpos[:2]), _yaw(s.xmat), np.array(self.model.site(name).size[:2]))

    def _route(self, body: str) -> Polyline:
        m = self.model
        ids = np.flatnonzero(m.site_bodyid == m.body(body).id)
        return Polyline(self.data.site_xpos[ids, :2].copy())

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
        d = self.data
        qx, qy, qyaw = d.qpos[car.qpos]
        vx, vy, _ = d.qvel[car.qvel]
        c, s = math.cos(car.frame_yaw), math.sin(car.frame_yaw)
        v = vx * math.cos(qyaw) + vy * math.sin(qyaw)
        return np.array([car.frame_pos[0] + c * qx - s * qy, car.frame_pos[1] + s * qx + c * qy,
                         math.remainder(car.frame_yaw + qyaw, 2 * math.pi), v])

    def poses(self) -> np.ndarray:
        """System pose ``S_t`` as ``(2, 4)``: row 0 the ego, row 1 the obstacle."""
        return np.stack([self.pose(self.ego), self.pose(self.obstacle)])

    def set_controls(self, which: str, accel: float, steer: float) -> None:
        """Command a car: acceleration [m/s^2] and steering angle [rad], clipped to the
        actuator ranges as MuJoCo does."""
        car = self.car(which)
        self.data.ctrl[car.accel] = accel
        self.data.ctrl[car.steer] = steer

    def step(self, nstep: int) -> str | None:
        """Advance ``nstep`` physics steps; stop at the first contact of the ego.

        Returns ``"obstacle"`` or ``"building"`` (a geom named ``building*``) for the ego's
        first such contact, else ``None``.
        Contacts of the obstacle with a building are ignored here (they do not end the
        ego's episode) but stay in ``data.contact``.
        """
        m, d = self.model, self.data
        bad_before = self._instability_count()
        for _ in range(nstep):
            mujoco.mj_step(m, d)
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
        w = self.data.warning
        return (w[mujoco.mjtWarning.mjWARN_BADQPOS].number + w[mujoco.mjtWarning.mjWARN_BADQVEL].number
                + w[mujoco.mjtWarning.mjWARN_BADQACC].number)

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


#: Named elements a car file can bring into a spec (MjSpec finder, list), for name clashes.
_CAR_ELEMENT_KINDS = (("body", "bodies"), ("geom", "geoms"), ("site", "sites"), ("joint", "joints"),
                      ("actuator", "actuators"), ("sensor", "sensors"), ("tendon", "tendons"),
                      ("camera", "cameras"), ("light", "lights"), ("material", "materials"),
                      ("mesh", "meshes"), ("texture", "textures"))


def add_car(spec: mujoco.MjSpec, prefix: str, pos: tuple[float, float] = (0.0, 0.0),
            yaw: float = 0.0, paint: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0),
            car_file: str | Path = CAR_XML, set_options: bool = True) -> mujoco.MjsBody:
    """Place our car (``models/xml/car.xml``) in your ``MjSpec`` and return its chassis.

    The car is attached to the worldbody at rear-axle position ``pos`` [m] (world x, y;
    z = 0 is the ground) with heading ``yaw`` [rad] from the world x axis, and every name
    in it gets ``prefix`` (``chassis`` becomes ``<prefix>chassis``, and so on; see
    :class:`cdf_mj.config.SceneNames`). A material ``<prefix>paint`` of colour ``paint``
    (RGBA) is added unless the spec has one. With ``set_options`` the spec's integrator
    becomes ``implicitfast`` and its timestep at most 0.005 s, which the car's stiff speed
    servo and tyre dampers need to stay stable.

    SceneError, before anything is added to ``spec``, if the car file cannot be read or has
    no ``chassis`` body, or if any prefixed name of the car is already in the spec;
    ValueError for a pose that is not two finite numbers and a finite yaw.
    """
    if not prefix:
        raise SceneError("add_car: prefix must be a non-empty string (e.g. 'ego_')")
    chassis = SceneNames().chassis
    try:
        x, y = (float(v) for v in pos)
    except (TypeError, ValueError):
        raise ValueError(f"add_car: pos must be (x, y) in metres, got {pos!r}") from None
    if not all(math.isfinite(v) for v in (x, y, float(yaw))):
        raise ValueError(f"add_car: pose must be finite, got pos={pos}, yaw={yaw}")
    try:
        car = mujoco.MjSpec.from_file(str(car_file))
    except ValueError as exc:
        raise SceneError(f"add_car: cannot read car file {car_file}: "
                         f"{' '.join(str(exc).split())}") from None
    if car.body(chassis) is None:
        raise SceneError(f"add_car: car file {car_file} has no body '{chassis}'")
    clashes = [f"{kind} '{prefix}{element.name}'" for kind, plural in _CAR_ELEMENT_KINDS
               for element in getattr(car, plural)
               if element.name and element.name != "world"
               and getattr(spec, kind)(prefix + element.name) is not None]
    if clashes:
        more = f" and {len(clashes) - 6} more" if len(clashes) > 6 else ""
        raise SceneError(f"add_car: the spec already has {', '.join(clashes[:6])}{more}; "
                         "choose another prefix")
    if spec.material(prefix + "paint") is None:
        spec.add_material(name=prefix + "paint", rgba=list(paint))
    frame = spec.worldbody.add_frame(pos=[x, y, 0.0],
                                     quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    body = frame.attach_body(car.body(chassis), prefix, "")
    if set_options:
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.timestep = min(spec.option.timestep, 0.005)
    return body
