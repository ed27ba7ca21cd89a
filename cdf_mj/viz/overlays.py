"""What the CDF sees and believes, drawn into a MuJoCo ``MjvScene`` as user geoms.

All positions are in the world frame [m] (x east, y north, z up from the ground); each
function adds geoms after the model's (call it after ``mjv_updateScene``) and stops
quietly when the scene is full (``maxgeom``).

* :func:`draw_isovist`: what the obstacle's driver can see (its isovist): a light,
  translucent yellow fill that leaves the grey road readable, and a yellow outline;
* :func:`draw_particles`: the filter's particles above the roof line as heading ticks (a
  needle from each particle's rear axle along its heading, sized as a fraction of the
  view), coloured by intent and belief (:data:`PARTICLE_COLORS`);
* :func:`draw_belief`: the obstacle driver's belief of where the ego is (its last
  observation, dead-reckoned; not the ego's true pose), a yellow wire box;
* :func:`draw_braking`: a red stripe across the ego's lane where the ego decided to
  brake (for a lane in any direction), and a red beacon over the ego while it brakes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from cdf_mj.model.geometry import OrientedBox
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.sim.visibility import Isovist

if TYPE_CHECKING:
    from cdf_mj.viz.replay import Particles

__all__ = ["OVERLAY_COLORS", "PARTICLE_COLORS", "draw_belief", "draw_braking", "draw_isovist",
           "draw_particles", "lane_half_width", "view_height_at"]

#: RGBA of the particles by (intent, has seen the ego).
PARTICLE_COLORS = {
    ("left", False): (1.0, 0.1, 1.0, 1.0),   # magenta: a left-turner that has not seen the ego
    ("left", True): (0.55, 0.3, 1.0, 1.0),   # violet: a left-turner that has seen it
    ("right", False): (0.1, 0.9, 0.1, 1.0),  # green: a right-turner that has not seen the ego
    ("right", True): (0.6, 1.0, 0.6, 1.0),   # pale green: a right-turner that has seen it
}
#: RGBA of the other overlays (3D geoms and the panel's curves).
OVERLAY_COLORS = {
    "isovist": (1.0, 0.95, 0.45, 0.10),       # fill: light enough to keep the road grey
    "isovist_edge": (1.0, 0.85, 0.1, 0.85),  # outline
    "belief": (1.0, 0.9, 0.15, 1.0),
    "brake": (1.0, 0.05, 0.05, 1.0),
    "p_left": (1.0, 0.1, 1.0, 1.0),
    "p_seen": (1.0, 0.9, 0.15, 1.0),
    "p_cutoff": (1.0, 0.35, 0.1, 1.0),
    "p_conflict": (1.0, 0.35, 0.1, 1.0),  # the imm baseline's braking quantity, as P(cutoff)
    "risk": (1.0, 0.15, 0.15, 1.0),  # the risk rule's braking quantity
}
_INTENT_NAMES = ("left", "right")  # cdf_mj.model.driver.Intent order
_EYE3 = np.eye(3)
_TRI = mujoco.mjtGeom.mjGEOM_TRIANGLE.value
_BOX = mujoco.mjtGeom.mjGEOM_BOX.value
_LINEBOX = mujoco.mjtGeom.mjGEOM_LINEBOX.value
_CYL = mujoco.mjtGeom.mjGEOM_CYLINDER.value
_LINE = mujoco.mjtGeom.mjGEOM_LINE.value
#: Length of a particle's heading tick as a fraction of the view's height (about 17 px at
#: 480 px), when not given in metres.
TICK_FRACTION = 0.035


def _add_geom(scn: mujoco.MjvScene, gtype: int, size: Sequence[float] | np.ndarray,
              pos: Sequence[float] | np.ndarray, mat: np.ndarray, rgba: Sequence[float] | np.ndarray,
              emission: float = 0.0) -> None:
    """One decor geom of type ``gtype`` (MuJoCo sizes [m]) at ``pos`` with orientation
    ``mat`` (3x3); nothing when the scene is full."""
    if scn.ngeom >= scn.maxgeom:
        return
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(g, gtype, np.asarray(size, dtype=float), np.asarray(pos, dtype=float),
                        mat.ravel(), np.asarray(rgba, dtype=np.float32))
    g.emission = emission
    g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
    scn.ngeom += 1


def _yaw_mat(theta: float) -> np.ndarray:
    """Rotation by ``theta`` [rad] about z."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def draw_isovist(scn: mujoco.MjvScene, iso: Isovist, z: float = 0.05, *, outline: bool = True,
                 line_width: float = 2.0) -> None:
    """The isovist as a fan of light translucent triangles from the eye (it is star-shaped
    from there) at height ``z`` [m], its boundary simplified to 10 cm (straight building
    faces need few corners: 360 rays become about 40 triangles), and, with ``outline``,
    its boundary as lines ``line_width`` [px] wide just above the fill."""
    boundary = np.asarray(iso.polygon.simplify(0.1).exterior.coords)[:-1]
    rgba = np.asarray(OVERLAY_COLORS["isovist"], dtype=np.float32)
    size = np.zeros(3)
    pos = np.array([iso.origin[0], iso.origin[1], z])
    mat = np.zeros((3, 3))
    mat[2, 2] = 1.0
    d = boundary - np.asarray(iso.origin[:2])
    dist = np.hypot(d[:, 0], d[:, 1])
    keep = dist > 1e-6
    d, dist = d[keep], dist[keep]
    u = d / dist[:, None]
    n = len(d)
    for i in range(n):
        j = (i + 1) % n
        if scn.ngeom >= scn.maxgeom:
            return
        # Triangle (0,0,0)-(size0,0,0)-(0,size1,0) in the geom frame: x towards corner i,
        # y towards corner j (a sheared frame: MuJoCo draws it as given).
        mat[0, 0], mat[1, 0], mat[0, 1], mat[1, 1] = u[i, 0], u[i, 1], u[j, 0], u[j, 1]
        size[0], size[1] = dist[i], dist[j]
        g = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(g, _TRI, size, pos, mat.ravel(), rgba)
        g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
        scn.ngeom += 1
    if not outline:
        return
    edge = np.asarray(OVERLAY_COLORS["isovist_edge"], dtype=np.float32)
    ring = np.column_stack([boundary, np.full(len(boundary), z + 0.02)])
    for i in range(len(ring)):
        if scn.ngeom >= scn.maxgeom:
            return
        g = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(g, _LINE, np.zeros(3), np.zeros(3), _EYE3.ravel(), edge)
        mujoco.mjv_connector(g, _LINE, line_width, ring[i], ring[(i + 1) % len(ring)])
        g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
        scn.ngeom += 1


def view_height_at(scn: mujoco.MjvScene, point: Sequence[float] | np.ndarray) -> float:
    """The height [m] of the view of ``scn``'s camera (set by ``mjv_updateScene``) at the
    depth of world ``point`` ``(3,)`` [m]: how many metres the image's height spans there.
    ValueError if the scene has no camera yet."""
    cam = mujoco.mjv_averageCamera(scn.camera[0], scn.camera[1])
    span = float(cam.frustum_top - cam.frustum_bottom)
    if not cam.frustum_near > 0 or not span > 0:
        raise ValueError("the MjvScene has no camera yet: call mujoco.mjv_updateScene before drawing "
                         "particles, or give their tick length in metres (length=...)")
    if cam.orthographic:
        return span
    depth = float(np.dot(np.asarray(point, dtype=float) - np.asarray(cam.pos), np.asarray(cam.forward)))
    return max(depth, float(cam.frustum_near)) * span / float(cam.frustum_near)


def draw_particles(scn: mujoco.MjvScene, particles: Particles, z: float, limit: int,
                   half: float | None = None, *, length: float | None = None,
                   line_width: float = 3.0) -> None:
    """The first ``limit`` of one tick's distinct particles (heaviest first, as
    :class:`cdf_mj.viz.replay.Particles`) at height ``z`` [m] as heading ticks: a line
    ``line_width`` [px] wide from each particle's rear axle along its heading, ``length``
    [m] long (default :data:`TICK_FRACTION` of the view's height at the particles, so the
    ticks read the same at any zoom). A snapshot without headings (three arrays) draws
    flat squares of half side ``half`` [m] (default 0.3)."""
    xy, code = particles[0], particles[1]
    heading = particles[3] if len(particles) > 3 else None
    n = min(limit, len(xy))
    if n == 0:
        return
    colors = [np.asarray(PARTICLE_COLORS[(_INTENT_NAMES[c // 2], bool(c % 2))], dtype=np.float32)
              for c in range(4)]
    if heading is None:
        side = 0.3 if half is None else half
        size = np.array([side, side, 0.05])
        for i in range(n):
            _add_geom(scn, _BOX, size, (xy[i, 0], xy[i, 1], z), _EYE3, colors[code[i]], emission=0.8)
        return
    if length is None:
        centre = np.array([float(np.mean(xy[:n, 0])), float(np.mean(xy[:n, 1])), z])
        length = TICK_FRACTION * view_height_at(scn, centre)
    th = heading[:n].astype(float)
    start = np.column_stack([xy[:n].astype(float), np.full(n, z)])
    end = start + length * np.column_stack([np.cos(th), np.sin(th), np.zeros(n)])
    zero = np.zeros(3)
    for i in range(n):
        if scn.ngeom >= scn.maxgeom:
            return
        g = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(g, _LINE, zero, zero, _EYE3.ravel(), colors[code[i]])
        mujoco.mjv_connector(g, _LINE, line_width, start[i], end[i])
        g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
        scn.ngeom += 1


def draw_belief(scn: mujoco.MjvScene, car: CarGeometry, pose: np.ndarray) -> None:
    """The obstacle driver's belief of the ego: the collision box of ``car`` at the
    believed ``pose`` ``[x m, y m, theta rad, v]`` (the driver's last observation of the
    ego, dead-reckoned; not where the ego is) as a wire box."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    ox, oy = car.hull_offset
    centre = (pose[0] + c * ox - s * oy, pose[1] + s * ox + c * oy, car.hull_height / 2)
    _add_geom(scn, _LINEBOX, (*car.hull_half, car.hull_height / 2), centre, _yaw_mat(pose[2]),
              OVERLAY_COLORS["belief"], emission=1.0)


def lane_half_width(lane: OrientedBox, heading: float) -> float:
    """Half the width [m] of the lane box ``lane`` across a car heading ``heading`` [rad]
    along it: the box's half size on the axis further from the heading (a box may run
    along its local x or y)."""
    return float(lane.half[1] if _lane_axis(lane, heading) == lane.heading else lane.half[0])


def _lane_axis(lane: OrientedBox, heading: float) -> float:
    """The heading [rad] of the axis of box ``lane`` nearer ``heading`` [rad]: its local x
    or y axis."""
    along_x = abs(math.cos(heading - lane.heading)) >= abs(math.sin(heading - lane.heading))
    return float(lane.heading) if along_x else float(lane.heading) + math.pi / 2


_lane_half = lane_half_width  # draw_braking's argument of that name hides the function


def draw_braking(scn: mujoco.MjvScene, car: CarGeometry, lane_half_width: float | OrientedBox,
                 brake_pose: np.ndarray, pose: np.ndarray, z: float) -> None:
    """A stripe across the ego's lane at the front of ``car`` where it decided to brake
    (``brake_pose``), and a beacon at height ``z`` [m] over its hull at ``pose`` (poses
    ``[x m, y m, theta rad, v]``).

    ``lane_half_width`` is the lane's box (:attr:`cdf_mj.model.layout.Layout.ego_lane`,
    best: the stripe then runs across the lane's own direction, centred on the lane, for a
    box along its local x or y) or the lane's half width [m] (the stripe then runs across
    the car's heading, centred on the car)."""
    c, s = math.cos(brake_pose[2]), math.sin(brake_pose[2])
    front = car.hull_offset[0] + car.hull_half[0]
    fx, fy = brake_pose[0] + c * front, brake_pose[1] + s * front
    yaw = float(brake_pose[2])
    if isinstance(lane_half_width, OrientedBox):
        lane = lane_half_width
        half = _lane_half(lane, yaw)
        ax = _lane_axis(lane, yaw)
        if math.cos(yaw - ax) < 0:  # pointing the car's way
            ax += math.pi
        ux, uy = math.cos(ax), math.sin(ax)
        along = (fx - lane.center[0]) * ux + (fy - lane.center[1]) * uy
        fx, fy, yaw = lane.center[0] + along * ux, lane.center[1] + along * uy, ax
    else:
        half = float(lane_half_width)
    _add_geom(scn, _BOX, (0.35, half, 0.02), (fx, fy, 0.04), _yaw_mat(yaw), OVERLAY_COLORS["brake"],
              emission=1.0)
    ce, se = math.cos(pose[2]), math.sin(pose[2])
    cx, cy = pose[0] + ce * car.hull_offset[0], pose[1] + se * car.hull_offset[0]
    _add_geom(scn, _CYL, (0.45, 0.6, 0.0), (cx, cy, z), _EYE3, OVERLAY_COLORS["brake"],
              emission=1.0)
