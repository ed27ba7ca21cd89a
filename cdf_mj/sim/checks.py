"""Validation of an MJCF scene against the names the code reads: one :class:`SceneError`
that lists every problem at once.

:class:`cdf_mj.sim.scene.Scene` runs :func:`validate` when it is built, before it reads
anything, so that a scene with several mistakes is fixed in one round. ::

    from cdf_mj.sim.checks import SceneError, validate
    validate(model, data, SceneNames(), source="my_scene.xml")   # SceneError or nothing
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.geometry import Polyline

__all__ = ["SceneError", "validate"]

# MuJoCo object types by the word the error messages use.
_OBJ = {
    "body": mujoco.mjtObj.mjOBJ_BODY,
    "site": mujoco.mjtObj.mjOBJ_SITE,
    "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
    "joint": mujoco.mjtObj.mjOBJ_JOINT,
    "geom": mujoco.mjtObj.mjOBJ_GEOM,
}


class SceneError(ValueError):
    """A scene file that cannot be loaded or lacks an element the code needs."""


def _required_elements(names: SceneNames) -> list[tuple[str, str]]:
    """Every ``(kind, name)`` the code reads: the world's sites and route bodies, and each
    car's bodies, hull, eye, actuators and joints (with its prefix)."""
    n = names
    req = [("site", s) for s in (n.ego_start, n.obstacle_start, n.stop_line, n.ego_lane,
                                 n.conflict, n.commit)]
    req += [("body", b) for b in (n.route_ego, n.route_left, n.route_right)]
    for p in (n.ego_prefix, n.obstacle_prefix):
        req += [("body", p + n.chassis), ("body", p + n.front_axle), ("geom", p + n.hull),
                ("site", p + n.eye), ("actuator", p + n.accel), ("actuator", p + n.steer)]
        req += [("joint", p + j) for j in (*n.planar_joints, n.steer)]
    return req


def validate(model: mujoco.MjModel, data: mujoco.MjData, names: SceneNames, source: str) -> None:
    """Raise one SceneError listing every missing element, then every element of the wrong
    kind, shape or place (each checked only where it exists); return if there are none.

    ``data`` must hold the model's reference configuration after ``mj_kinematics`` (world
    positions of sites, bodies and geoms); ``source`` names the scene in the message.
    """
    m, n, d = model, names, data
    required = _required_elements(n)
    exists = {(kind, name): mujoco.mj_name2id(m, _OBJ[kind], name) >= 0 for kind, name in required}
    missing = [f"{kind} '{name}'" for (kind, name), ok in exists.items() if not ok]
    wrong: list[str] = []

    def has(kind: str, name: str) -> bool:
        return exists[(kind, name)]

    not_finite = [f"{kind} '{name}'" for kind, name in required
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
        wrong += _car_problems(m, n, p, has)
    wrong += _building_problems(m, d, n)
    problems = ([f"lacks {', '.join(missing)}"] if missing else []) + wrong
    if problems:
        raise SceneError(f"scene {source}: {'; '.join(problems)} "
                         "(docs/SCENES.md lists the names a scene must have)")


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
    if has("actuator", p + n.steer):
        steer = m.actuator(p + n.steer)
        if not steer.ctrllimited[0]:
            wrong.append(f"actuator '{p}{n.steer}' must be ctrl-limited (steering range)")
        elif not steer.ctrlrange[0] < 0.0 < steer.ctrlrange[1]:
            wrong.append(f"actuator '{p}{n.steer}' needs a ctrlrange from right (< 0) to "
                         f"left (> 0) [rad], has {steer.ctrlrange.tolist()}")
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
