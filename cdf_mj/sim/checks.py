"""Validation of an MJCF scene: one :class:`SceneError` that lists every problem at once.

:class:`cdf_mj.sim.scene.Scene` runs :func:`validate` when it is built, before it reads
anything, so that a scene with several mistakes is fixed in one round. The checks go past
the names to what the elements mean:

- every element the code reads exists, with the right kind, shape and place;
- the left route crosses into the ego's lane and the right one does not ("swapped?"),
  the conflict point lies on the ego's route within its lane and ahead of the ego's
  start, the obstacle's start site faces along its routes;
- angles are radians: a file whose compiler reads degrees is refused (``Scene.load``
  reads that from the file; a compiled model does not keep it), and what degrees give away
  in a compiled model is refused too (a steering range beyond 90 degrees, a steering joint
  range 57 times smaller than its actuator's);
- an explicit integrator (Euler, RK4) gives a :class:`SceneWarning`: our car's tyre
  dampers and speed servo diverge with it.

Two more checks need more than the model: :func:`substeps` (the scenario tick must be a
whole multiple of the timestep) and :func:`check_drive` (a test drive on a scratch
``MjData``: each car must move when commanded), in :mod:`cdf_mj.sim.drive_check`. A names
file (``cdf-mj ... --names FILE``) is read by :func:`read_names`, and the files a scene
names are checked by :func:`check_regular_files`, in :mod:`cdf_mj.sim.files`;
:class:`SceneError` and :class:`SceneWarning` are defined in :mod:`cdf_mj.sim.errors`.
All of them can be imported from here. ::

    from cdf_mj.sim.checks import SceneError, validate
    validate(model, data, SceneNames(), source="my_scene.xml")   # SceneError or nothing
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.geometry import OrientedBox, Polyline, box_corners, boxes_overlap
from cdf_mj.sim.drive_check import MAX_SUBSTEPS, MIN_TIMESTEP, check_drive, substeps
from cdf_mj.sim.errors import MUJOCO_LOGGER as MUJOCO_LOGGER
from cdf_mj.sim.errors import SceneError, SceneWarning, route_mujoco_warnings
from cdf_mj.sim.files import check_regular_files, read_names

__all__ = ["MAX_SUBSTEPS", "MIN_TIMESTEP", "SceneError", "SceneWarning", "check_drive", "check_regular_files",
           "read_names", "route_mujoco_warnings", "substeps", "validate"]

# MuJoCo object types by the word the error messages use.
_OBJ = {
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
}

#: Integrators that integrate our car's velocity-dependent actuator forces (tyre dampers of
#: 1e7 N s/m, the speed servo) implicitly; Euler and RK4 treat them explicitly and diverge.
STABLE_INTEGRATORS = (mujoco.mjtIntegrator.mjINT_IMPLICIT, mujoco.mjtIntegrator.mjINT_IMPLICITFAST)

# The lengths below are a full-size junction's; a narrower one (a testbed at another scale)
# is checked at these lengths x its lane width / FULL_LANE (:func:`_junction_scale`).
_ROUTE_STEP = 0.2  # [m] spacing of the points at which routes are tested against the ego lane
_START_SPAN = 1.0  # [m] a route's start direction is measured over its first this much
_LANE_SPAN = 1.0  # [m] the left route's direction in the ego's lane: over its last this much there
_HEADING_TOL = math.radians(20.0)  # [rad] obstacle start site vs its routes' first direction
#: [m] lanes at least this wide (a narrow full-size lane) are checked at the lengths above.
FULL_LANE = 3.0
#: [m] the width of the ego's lane (site ``ego_lane``, its shorter side): a lane of a 1:40
#: testbed to a wide road; a width outside it is a unit mistake.
LANE_WIDTH = (0.05, 20.0)
#: Largest coordinate or size of any body, geom or site in a scene, and largest control
#: range: 100 km, far beyond a junction; larger values are a unit mistake or garbage [m].
MAX_EXTENT = 1e5


def _required_junction(n: SceneNames) -> list[tuple[str, str]]:
    """Every ``(kind, name)`` of the junction: the world's sites and route bodies."""
    req = [("site", s) for s in (n.ego_start, n.obstacle_start, n.stop_line, n.ego_lane,
                                 n.conflict, n.commit)]
    return req + [("body", b) for b in (n.route_ego, n.route_left, n.route_right)]


def _required_cars(n: SceneNames) -> list[tuple[str, str]]:
    """Every ``(kind, name)`` of the two cars: bodies, hull, eye, actuators, joints."""
    req: list[tuple[str, str]] = []
    for p in (n.ego_prefix, n.obstacle_prefix):
        req += [("body", p + n.chassis), ("body", p + n.front_axle), ("geom", p + n.hull),
                ("site", p + n.eye), ("actuator", p + n.accel), ("actuator", p + n.steer)]
        req += [("joint", p + j) for j in (*n.planar_joints, n.steer_joint)]
    return req


def validate(model: mujoco.MjModel, data: mujoco.MjData, names: SceneNames, source: str, *,
             cars: bool = True, compiler_degree: bool = False) -> None:
    """Raise one SceneError listing every missing element, then every element of the wrong
    kind, shape, place or meaning (each checked only where it exists); return if there are
    none. Among them: a timestep that is not a finite number > 0, and any body, geom or
    site whose position, orientation or size (or actuator whose control range) is not a
    finite number within :data:`MAX_EXTENT` (the meaning of the junction is then not read). With
    ``cars``, warn (:class:`SceneWarning`) for an integrator other than implicit/implicitfast.

    ``data`` must hold the model's reference configuration after ``mj_kinematics`` (world
    positions of sites, bodies and geoms); ``source`` names the scene in the message.
    ``cars=False`` checks the junction only (for cars that are not ours: only observed).
    ``compiler_degree``: the file's ``<compiler>`` reads angles in degrees (an ``MjModel``
    does not keep this; :meth:`Scene.load` reads it from the file's ``MjSpec``).
    """
    m, n, d = model, names, data
    required = _required_junction(n) + (_required_cars(n) if cars else [])
    exists = {(kind, name): mujoco.mj_name2id(m, _OBJ[kind], name) >= 0 for kind, name in required}
    missing = [f"{kind} '{name}'" for (kind, name), ok in exists.items() if not ok]
    wrong: list[str] = []
    if compiler_degree:
        wrong.append("the compiler reads angles in degrees (MuJoCo's default when <compiler "
                     "angle=...> is not given); put <compiler angle=\"radian\"/> in the file and "
                     "write every angle in radians")

    def has(kind: str, name: str) -> bool:
        return exists[(kind, name)]

    not_finite = [f"{kind} '{name}'" for kind, name in required
                  if kind in ("site", "body") and has(kind, name)
                  and not np.all(np.isfinite((d.site if kind == "site" else d.body)(name).xpos))]
    if not_finite:
        wrong.append(f"positions that are not finite numbers: {', '.join(not_finite)}")
    numbers = _number_problems(m, d, skip={name.split("'")[1] for name in not_finite})
    wrong += numbers
    routes: dict[str, Polyline] = {}
    for route in (n.route_ego, n.route_left, n.route_right):
        if not has("body", route):
            continue
        ids = np.flatnonzero(m.site_bodyid == m.body(route).id)
        if len(ids) < 2:
            wrong.append(f"body '{route}' has fewer than 2 waypoint sites")
            continue
        try:  # the route as the drivers will use it: Polyline's own rules
            routes[route] = Polyline(d.site_xpos[ids, :2].copy())
        except ValueError as exc:
            wrong.append(f"body '{route}': {str(exc).replace('a polyline', 'the route')}")
    for site in (n.stop_line, n.ego_lane):
        if has("site", site) and m.site(site).type[0] != mujoco.mjtGeom.mjGEOM_BOX:
            wrong.append(f"site '{site}' must be a box (its half sizes give the area)")
    if not not_finite and not numbers:  # the meaning of non-finite places cannot be read
        wrong += _meaning_problems(m, d, n, routes, has)
    if cars:
        for p in (n.ego_prefix, n.obstacle_prefix):
            wrong += _car_problems(m, n, p, has)
    wrong += _building_problems(m, d, n)
    if not not_finite and not numbers:
        wrong += _buildings_in_the_way(m, d, n, routes, has, cars)
    problems = ([f"lacks {', '.join(missing)}"] if missing else []) + wrong
    if problems:
        raise SceneError(f"scene {source}: {'; '.join(problems)} "
                         "(docs/SCENES.md lists the names a scene must have and what they mean)")
    if cars:  # only our cars care; the integrator of a scene whose cars are watched is the user's
        _warn_integrator(m, source)


def _number_problems(m: mujoco.MjModel, d: mujoco.MjData, skip: set[str]) -> list[str]:
    """A timestep that is not a finite number > 0; every body, geom and site whose world
    position, orientation or size is not a finite number within :data:`MAX_EXTENT` of the
    origin; every actuator whose control range is not (five named per kind, those named in
    ``skip`` left out: already listed)."""
    wrong: list[str] = []
    timestep = float(m.opt.timestep)
    if not (math.isfinite(timestep) and timestep > 0):
        wrong.append(f"<option timestep=\"{timestep:g}\"> must be a finite number of seconds > 0, "
                     "e.g. 0.005")
    elif timestep < MIN_TIMESTEP:
        wrong.append(f"<option timestep=\"{timestep:g}\"> is shorter than {MIN_TIMESTEP:g} s: "
                     f"{1.0 / timestep:.3g} physics steps per simulated second would make an episode "
                     "take minutes or hours; use 0.005 (the package's scenes) or at least "
                     f"{MIN_TIMESTEP:g}")
    views = (("body", m.nbody, (d.xpos, d.xmat), m.body),
             ("geom", m.ngeom, (d.geom_xpos, d.geom_xmat, m.geom_size), m.geom),
             ("site", m.nsite, (d.site_xpos, d.site_xmat, m.site_size), m.site),
             ("actuator", m.nu, (m.actuator_ctrlrange,), m.actuator))
    for kind, count, arrays, view in views:
        if not count:
            continue
        values = np.hstack([np.asarray(a).reshape(count, -1) for a in arrays])
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1)
                                 | (np.max(np.abs(values), axis=1) > MAX_EXTENT))
        bad = np.array([i for i in bad if view(int(i)).name not in skip], dtype=int)
        if len(bad):
            shown = ", ".join(f"'{view(int(i)).name}'" if view(int(i)).name else f"#{int(i)} (unnamed)"
                              for i in bad[:5])
            more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
            what = "control range" if kind == "actuator" else "position, orientation or size"
            wrong.append(f"{kind}s whose {what} is not a finite number within {MAX_EXTENT:.0e} "
                         f"(m or rad): {shown}{more}")
    return wrong


def _warn_integrator(m: mujoco.MjModel, source: str) -> None:
    integrator = int(m.opt.integrator)
    if integrator not in STABLE_INTEGRATORS:
        name = mujoco.mjtIntegrator(integrator).name.removeprefix("mjINT_")
        warnings.warn(f"scene {source}: integrator {name} treats velocity-dependent actuator forces "
                      "explicitly, and our car's tyre dampers (1e7 N s/m) and speed servo diverge "
                      "with it (NaN within 0.03 s at timesteps of 5 ms and 1 ms); use "
                      "<option integrator=\"implicitfast\"/> unless the cars are not ours",
                      SceneWarning, stacklevel=3)


def _site_box(m: mujoco.MjModel, d: mujoco.MjData, name: str) -> OrientedBox:
    s = d.site(name)
    return OrientedBox(np.array(s.xpos[:2]), math.atan2(s.xmat[3], s.xmat[0]),
                       np.array(m.site(name).size[:2]))


def _junction_scale(lane: OrientedBox | None) -> float:
    """The junction's scale for the checks' lengths: its lane width (the ego lane box's
    shorter side) / :data:`FULL_LANE`, at most 1 (1 without a lane box)."""
    return 1.0 if lane is None else min(1.0, 2.0 * float(np.min(lane.half)) / FULL_LANE)


def _meaning_problems(m: mujoco.MjModel, d: mujoco.MjData, n: SceneNames, routes: dict[str, Polyline],
                      has: Callable[[str, str], bool]) -> list[str]:
    """What the junction's elements mean: how wide the ego's lane is, which route crosses
    it, where the conflict point lies, where the obstacle's start site faces (elements that
    exist and are well formed only). Lengths are measured at the junction's scale
    (:func:`_junction_scale`) and said in its own metres."""
    wrong: list[str] = []
    ego, left, right = (routes.get(r) for r in (n.route_ego, n.route_left, n.route_right))
    lane = _site_box(m, d, n.ego_lane) if has("site", n.ego_lane) and \
        m.site(n.ego_lane).type[0] == mujoco.mjtGeom.mjGEOM_BOX else None
    if lane is not None and not LANE_WIDTH[0] <= 2.0 * float(np.min(lane.half)) <= LANE_WIDTH[1]:
        width = 2.0 * float(np.min(lane.half))
        hint = "; millimetres?" if LANE_WIDTH[0] <= width / 1000.0 <= LANE_WIDTH[1] and width > LANE_WIDTH[1] \
            else ""
        wrong.append(f"site '{n.ego_lane}' makes the ego's lane {width:.4g} m wide (its box's shorter "
                     f"side): a lane is {LANE_WIDTH[0]:g}-{LANE_WIDTH[1]:g} m wide{hint}")
        lane = None  # nothing else is read at a scale that is not a junction's
    scale = _junction_scale(lane)
    if lane is not None and left is not None and right is not None:
        def inside(route: Polyline) -> np.ndarray:
            s = np.append(np.arange(0.0, route.length, _ROUTE_STEP * scale), route.length)
            pts = route.point_at(s)
            return pts[lane.contains(pts)]

        left_in, right_in = inside(left), inside(right)
        if not len(left_in) and len(right_in):
            wrong.append(f"body '{n.route_left}' never enters the ego's lane (site '{n.ego_lane}') "
                         f"but body '{n.route_right}' does: routes swapped? The left route is the "
                         "turn that crosses into the ego's lane (SceneNames.route_left), the right "
                         "one turns away")
        else:
            if not len(left_in):
                wrong.append(f"body '{n.route_left}' never enters the ego's lane (site "
                             f"'{n.ego_lane}'): the left route must cross into it")
            if len(right_in):
                x, y = right_in[0]
                wrong.append(f"body '{n.route_right}' enters the ego's lane (site '{n.ego_lane}') "
                             f"at ({x:.4g}, {y:.4g}) m: the right route must turn away from it")
        if len(left_in) and ego is not None:
            # in the lane, the left-turner drives the ego's way (the end of its path there)
            s_end = left.project(left_in[-1])[0]
            s_ego = ego.project(left_in[-1])[0]
            span = _LANE_SPAN * scale
            t_left = left.point_at(min(float(s_end), left.length)) - left.point_at(max(float(s_end) - span, 0.0))
            t_ego = ego.point_at(float(s_ego) + span / 2) - ego.point_at(float(s_ego) - span / 2)
            if float(t_left @ t_ego) < 0.0:
                wrong.append(f"body '{n.route_left}' runs against the ego's direction (body "
                             f"'{n.route_ego}') in the ego's lane: is one of the routes reversed?")
    if ego is not None and has("site", n.conflict):
        conflict = np.array(d.site(n.conflict).xpos[:2])
        s_c, lat = (float(v) for v in ego.project(conflict))
        half = float(lane.half[1]) if lane is not None else math.inf
        if abs(lat) > half:
            wrong.append(f"site '{n.conflict}' is {abs(lat):.3g} m from the ego's route (body "
                         f"'{n.route_ego}'); it must lie on that route within the ego's lane "
                         f"(half width {half:.3g} m): on the wrong carriageway?")
        elif lane is not None and not lane.contains(conflict):
            wrong.append(f"site '{n.conflict}' lies outside the ego's lane (site '{n.ego_lane}'); "
                         "it marks where a left-turner enters that lane")
        if has("site", n.ego_start):
            s_start = float(ego.project(np.array(d.site(n.ego_start).xpos[:2]))[0])
            if s_c <= s_start:
                wrong.append(f"site '{n.conflict}' is not ahead of site '{n.ego_start}' along body "
                             f"'{n.route_ego}' ({s_c - s_start:.3g} m): is the ego's route reversed? "
                             "Its waypoints go in the ego's direction of travel")
    if has("site", n.obstacle_start):
        heading = math.atan2(d.site(n.obstacle_start).xmat[3], d.site(n.obstacle_start).xmat[0])
        for name, route in ((n.route_left, left), (n.route_right, right)):
            if route is None:
                continue
            span = min(_START_SPAN * scale, route.length)
            u = route.point_at(span) - route.point_at(0.0)
            off = abs(math.remainder(math.atan2(u[1], u[0]) - heading, 2 * math.pi))
            if off > _HEADING_TOL:
                wrong.append(f"site '{n.obstacle_start}' heads {math.degrees(heading):.1f} deg but "
                             f"body '{name}' starts towards {math.degrees(math.atan2(u[1], u[0])):.1f} "
                             f"deg over its first {span:.3g} m: turn the site's x axis along the route "
                             "(euler=\"0 0 yaw\", yaw in radians)")
    return wrong


def _car_problems(m: mujoco.MjModel, n: SceneNames, p: str,
                  has: Callable[[str, str], bool]) -> list[str]:
    """What is wrong with the car of prefix ``p`` (elements that exist only)."""
    wrong: list[str] = []
    chassis = p + n.chassis
    if has("body", chassis):
        cid = m.body(chassis).id
        if m.body_parentid[cid] != 0:
            wrong.append(f"body '{chassis}' must be a child of the worldbody")
        for kind, name, owner in (("body", p + n.front_axle, m.body_parentid),
                                  ("geom", p + n.hull, m.geom_bodyid),
                                  ("site", p + n.eye, m.site_bodyid)):
            if has(kind, name) and owner[mujoco.mj_name2id(m, _OBJ[kind], name)] != cid:
                wrong.append(f"{kind} '{name}' must belong to body '{chassis}'")
    joints = [p + j for j in n.planar_joints]
    if all(has("joint", j) for j in joints):
        types = [int(m.joint(j).type[0]) for j in joints]
        if types != [mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_SLIDE,
                     mujoco.mjtJoint.mjJNT_HINGE]:
            wrong.append(f"joints {', '.join(joints)} must be slide, slide, hinge")
    if has("joint", p + n.steer_joint) and \
            m.joint(p + n.steer_joint).type[0] != mujoco.mjtJoint.mjJNT_HINGE:
        wrong.append(f"joint '{p}{n.steer_joint}' must be a hinge")
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
    if has("actuator", p + n.steer):
        steer = m.actuator(p + n.steer)
        lo, hi = (float(v) for v in steer.ctrlrange)
        if not steer.ctrllimited[0]:
            wrong.append(f"actuator '{p}{n.steer}' must be ctrl-limited (steering range)")
        elif not lo < 0.0 < hi:
            wrong.append(f"actuator '{p}{n.steer}' needs a ctrlrange from right (< 0) to "
                         f"left (> 0) [rad], has {[lo, hi]}")
        elif max(-lo, hi) > math.pi / 2:
            wrong.append(f"actuator '{p}{n.steer}' has a ctrlrange of {[lo, hi]}, beyond 90 deg: "
                         "angles in degrees? Steering angles are radians (0.6 rad = 34 deg)")
        elif has("joint", p + n.steer_joint):
            joint = m.joint(p + n.steer_joint)
            jmax = float(np.max(np.abs(joint.range)))
            if joint.limited[0] and jmax < min(-lo, hi) / 10.0:
                wrong.append(f"joint '{p}{n.steer_joint}' has a range of +-{jmax:.4g} rad, less than a "
                             f"tenth of its actuator's ctrlrange {[lo, hi]}: read from degrees? "
                             "Use <compiler angle=\"radian\"/>")
    return wrong


def _building_problems(m: mujoco.MjModel, d: mujoco.MjData, n: SceneNames) -> list[str]:
    """Building geoms (``building_prefix``) that are not boxes standing upright."""
    not_box, tilted = [], []
    for g in range(m.ngeom):
        name = m.geom(g).name or ""
        if not name.startswith(n.building_prefix):
            continue
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
            kind = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
            not_box.append(f"'{name}' is a {kind}")
        elif abs(abs(d.geom_xmat[g, 8]) - 1.0) > 1e-9:
            tilted.append(f"'{name}'")
    wrong = []
    if not_box:
        wrong.append(f"building geoms must be boxes: {', '.join(not_box)}")
    if tilted:
        wrong.append(f"building boxes must be upright (rotated about z only): {', '.join(tilted)}")
    return wrong


def _buildings_in_the_way(m: mujoco.MjModel, d: mujoco.MjData, n: SceneNames, routes: dict[str, Polyline],
                          has: Callable[[str, str], bool], cars: bool) -> list[str]:
    """Building boxes (upright, named ``building_prefix``) that a car would meet where the
    scene puts it: its collision box (geom ``hull``) at its start site, and swept along each
    of its routes (the rear axle on the route, heading along it, every :data:`_ROUTE_STEP`
    at the junction's scale). Touching counts. Without ``cars`` (cars that are not ours),
    the routes' lines and the start sites themselves."""
    ids = [g for g in range(m.ngeom) if (m.geom(g).name or "").startswith(n.building_prefix)
           and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX and abs(abs(d.geom_xmat[g, 8]) - 1.0) <= 1e-9]
    if not ids:
        return []
    blocks = [(m.geom(g).name, OrientedBox(np.array(d.geom_xpos[g, :2]), math.atan2(d.geom_xmat[g, 3],
                                                                                  d.geom_xmat[g, 0]),
                                           np.array(m.geom_size[g, :2])).corners()) for g in ids]
    lane = _site_box(m, d, n.ego_lane) if has("site", n.ego_lane) and \
        m.site(n.ego_lane).type[0] == mujoco.mjtGeom.mjGEOM_BOX else None
    step = _ROUTE_STEP * max(_junction_scale(lane), 1e-3)

    def hull(prefix: str) -> tuple[np.ndarray, np.ndarray]:  # offset from the rear axle, half sizes
        name = prefix + n.hull
        if cars and has("geom", name) and m.geom(name).type[0] == mujoco.mjtGeom.mjGEOM_BOX:
            return np.array(m.geom(name).pos[:2]), np.array(m.geom(name).size[:2])
        return np.zeros(2), np.zeros(2)

    def hits(prefix: str, poses: np.ndarray) -> list[tuple[str, int]]:  # (building, first pose) met
        offset, half = hull(prefix)
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        centre = poses[:, :2] + np.stack([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]], axis=1)
        car = box_corners(centre, poses[:, 2], half)
        met = [(name, np.flatnonzero(boxes_overlap(car, np.broadcast_to(corners, car.shape))))
               for name, corners in blocks]
        return [(name, int(k[0])) for name, k in met if len(k)]

    wrong: list[str] = []
    what = "the collision box (geom '{p}" + n.hull + "') of car '{p}'" if cars else "the site of car '{p}'"
    for site, prefix in ((n.ego_start, n.ego_prefix), (n.obstacle_start, n.obstacle_prefix)):
        if has("site", site):
            pose = np.array([[*d.site(site).xpos[:2], math.atan2(d.site(site).xmat[3], d.site(site).xmat[0])]])
            for name, _ in hits(prefix, pose):
                wrong.append(f"{what.format(p=prefix)} at its start (site '{site}') meets building '{name}': "
                             "a car cannot start inside a building; move the building or the start")
    for route_name, prefix in ((n.route_ego, n.ego_prefix), (n.route_left, n.obstacle_prefix),
                               (n.route_right, n.obstacle_prefix)):
        route = routes.get(route_name)
        if route is None:
            continue
        s = np.linspace(0.0, route.length, 1 + min(math.ceil(route.length / step), 100_000))
        ds = min(step, route.length) / 2
        along = route.point_at(np.minimum(s + ds, route.length)) - route.point_at(np.maximum(s - ds, 0.0))
        poses = np.column_stack([route.point_at(s), np.arctan2(along[:, 1], along[:, 0])])
        for name, k in hits(prefix, poses):
            x, y = poses[k, :2]
            wrong.append(f"body '{route_name}' is not drivable: {what.format(p=prefix)} driving it meets building "
                         f"'{name}' at ({x:.4g}, {y:.4g}) m, {s[k]:.4g} m along it; move the building or the route")
    return wrong
