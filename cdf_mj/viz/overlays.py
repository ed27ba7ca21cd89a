"""What the CDF sees and believes, drawn into a MuJoCo ``MjvScene`` as user geoms.

All positions are in the world frame [m] (x east, y north, z up from the ground); each
function adds geoms after the model's (call it after ``mjv_updateScene``) and stops
quietly when the scene is full (``maxgeom``).

* :func:`draw_isovist`: the obstacle driver's isovist, a translucent yellow fan on the road;
* :func:`draw_particles`: the filter's particles above the roof line, coloured by intent
  and belief (:data:`PARTICLE_COLORS`);
* :func:`draw_belief`: where the obstacle believes the ego is, a yellow wire box;
* :func:`draw_braking`: a red stripe across the ego's lane where the ego decided to
  brake, and a red beacon over the ego while it brakes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.sim.visibility import Isovist

if TYPE_CHECKING:
    from cdf_mj.viz.replay import Particles

__all__ = ["OVERLAY_COLORS", "PARTICLE_COLORS", "draw_belief", "draw_braking", "draw_isovist",
           "draw_particles"]

#: RGBA of the particles by (intent, has seen the ego).
PARTICLE_COLORS = {
    ("left", False): (1.0, 0.1, 1.0, 1.0),   # magenta: a left-turner that has not seen the ego
    ("left", True): (0.55, 0.3, 1.0, 1.0),   # violet: a left-turner that has seen it
    ("right", False): (0.1, 0.9, 0.1, 1.0),  # green: a right-turner that has not seen the ego
    ("right", True): (0.6, 1.0, 0.6, 1.0),   # pale green: a right-turner that has seen it
}
#: RGBA of the other overlays (3D geoms and the panel's curves).
OVERLAY_COLORS = {
    "isovist": (1.0, 0.9, 0.15, 0.25),
    "belief": (1.0, 0.9, 0.15, 1.0),
    "brake": (1.0, 0.05, 0.05, 1.0),
    "p_left": (1.0, 0.1, 1.0, 1.0),
    "p_seen": (1.0, 0.9, 0.15, 1.0),
    "p_cutoff": (1.0, 0.35, 0.1, 1.0),
    "p_conflict": (1.0, 0.35, 0.1, 1.0),  # the imm baseline's braking quantity, as P(cutoff)
}
_INTENT_NAMES = ("left", "right")  # cdf_mj.model.driver.Intent order
_EYE3 = np.eye(3)
_TRI = mujoco.mjtGeom.mjGEOM_TRIANGLE.value
_BOX = mujoco.mjtGeom.mjGEOM_BOX.value
_LINEBOX = mujoco.mjtGeom.mjGEOM_LINEBOX.value
_CYL = mujoco.mjtGeom.mjGEOM_CYLINDER.value


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


def draw_isovist(scn: mujoco.MjvScene, iso: Isovist, z: float = 0.05) -> None:
    """The isovist as a fan of triangles from the eye (it is star-shaped from there) at
    height ``z`` [m], its boundary simplified to 10 cm (straight building faces need few
    corners: 360 rays become about 40 triangles)."""
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


def draw_particles(scn: mujoco.MjvScene, particles: Particles, z: float, limit: int,
                   half: float = 0.3) -> None:
    """The first ``limit`` of one tick's distinct particles (heaviest first, as
    :data:`cdf_mj.viz.replay.Particles`) as flat squares of half side ``half`` [m] at
    height ``z`` [m]."""
    xy, code, _ = particles
    colors = [np.asarray(PARTICLE_COLORS[(_INTENT_NAMES[c // 2], bool(c % 2))], dtype=np.float32)
              for c in range(4)]
    size = np.array([half, half, 0.05])
    for i in range(min(limit, len(xy))):
        _add_geom(scn, _BOX, size, (xy[i, 0], xy[i, 1], z), _EYE3, colors[code[i]], emission=0.8)


def draw_belief(scn: mujoco.MjvScene, car: CarGeometry, pose: np.ndarray) -> None:
    """The collision box of ``car`` at the believed ``pose`` ``[x m, y m, theta rad, v]``
    as a wire box."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    ox, oy = car.hull_offset
    centre = (pose[0] + c * ox - s * oy, pose[1] + s * ox + c * oy, car.hull_height / 2)
    _add_geom(scn, _LINEBOX, (*car.hull_half, car.hull_height / 2), centre, _yaw_mat(pose[2]),
              OVERLAY_COLORS["belief"], emission=1.0)


def draw_braking(scn: mujoco.MjvScene, car: CarGeometry, lane_half_width: float,
                 brake_pose: np.ndarray, pose: np.ndarray, z: float) -> None:
    """A stripe across the lane (half width ``lane_half_width`` [m]) at the front of
    ``car`` where it decided to brake (``brake_pose``), and a beacon at height ``z`` [m]
    over its hull at ``pose`` (poses ``[x m, y m, theta rad, v]``)."""
    c, s = math.cos(brake_pose[2]), math.sin(brake_pose[2])
    front = car.hull_offset[0] + car.hull_half[0]
    _add_geom(scn, _BOX, (0.35, lane_half_width, 0.02),
              (brake_pose[0] + c * front, brake_pose[1] + s * front, 0.04), _yaw_mat(brake_pose[2]),
              OVERLAY_COLORS["brake"], emission=1.0)
    ce, se = math.cos(pose[2]), math.sin(pose[2])
    cx, cy = pose[0] + ce * car.hull_offset[0], pose[1] + se * car.hull_offset[0]
    _add_geom(scn, _CYL, (0.45, 0.6, 0.0), (cx, cy, z), _EYE3, OVERLAY_COLORS["brake"],
              emission=1.0)
