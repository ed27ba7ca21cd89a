"""Line of sight in MuJoCo: the obstacle driver's isovist and whether it can see the ego.

Rays are cast with ``mj_multiRay`` from the driver's eye against the occluders of the
scene: geoms in group 1 (buildings) and group 3 (car collision boxes); the looking
car's own body is excluded. Call :meth:`cdf_mj.sim.scene.Scene.sync` after stepping so
that geom positions match ``qpos``. ::

    iso = isovist(scene, scene.obstacle.geometry.eye(scene.pose(scene.obstacle)))
    iso.polygon            # shapely Polygon, world frame [m]
    ego_visible(scene)     # bool: the obstacle's driver sees some part of the ego
    visible_share(scene, "ego", "obstacle")   # share of the obstacle's sight points the ego's eye sees
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import mujoco
import numpy as np
import shapely

from cdf_mj.model.occlusion import sight_targets
from cdf_mj.sim.scene import Scene

__all__ = ["Isovist", "ego_visible", "isovist", "sight_lines", "visible_share"]


@dataclass(frozen=True)
class Isovist:
    """The region visible from ``origin`` in the horizontal plane of the eye.

    ``angles`` [rad, world frame] and ``distances`` [m] of each ray; ``geomid`` the geom
    each ray hit, -1 where it reached ``max_range`` unobstructed.
    """

    origin: np.ndarray  # (3,) eye position, world frame [m]
    angles: np.ndarray  # (R,)
    distances: np.ndarray  # (R,) [m]
    geomid: np.ndarray  # (R,)
    max_range: float  # [m]

    @cached_property
    def polygon(self) -> shapely.Polygon:
        """The isovist as a shapely polygon (ray end points in angular order), world frame."""
        x = self.origin[0] + self.distances * np.cos(self.angles)
        y = self.origin[1] + self.distances * np.sin(self.angles)
        return shapely.Polygon(np.column_stack([x, y]))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether ground point(s) ``(..., 2)`` [m] lie inside, by looking up each point's
        bearing in the ray table (faster than a polygon test, same answer up to the
        angular resolution)."""
        xy = np.asarray(xy, dtype=float)
        dx, dy = xy[..., 0] - self.origin[0], xy[..., 1] - self.origin[1]
        bearing = np.mod(np.arctan2(dy, dx) - self.angles[0], 2 * np.pi)
        step = 2 * np.pi / len(self.angles)
        k = np.rint(bearing / step).astype(int) % len(self.angles)
        return np.hypot(dx, dy) <= self.distances[k]


def isovist(scene: Scene, eye: np.ndarray, n_rays: int = 360, max_range: float = 200.0,
            exclude: str = "obstacle") -> Isovist:
    """Cast ``n_rays`` horizontal rays from ``eye`` (world frame, [m]) over 360 degrees.

    ``exclude`` names the car whose own body the rays ignore (the looking car).
    """
    if n_rays < 3:
        raise ValueError(f"n_rays={n_rays} is out of range: must be >= 3")
    angles = np.linspace(0.0, 2 * np.pi, n_rays, endpoint=False)
    vec = np.zeros((n_rays, 3))
    vec[:, 0], vec[:, 1] = np.cos(angles), np.sin(angles)
    geomid = np.empty(n_rays, dtype=np.int32)
    dist = np.empty(n_rays)
    mujoco.mj_multiRay(scene.model, scene.data, np.asarray(eye, dtype=float), vec.ravel(),
                       scene.ray_groups, 1, scene.car(exclude).body, geomid, dist, None,
                       n_rays, max_range)
    missed = dist < 0
    dist[missed] = max_range
    geomid[missed] = -1
    return Isovist(np.asarray(eye, dtype=float).copy(), angles, dist, geomid, max_range)


def sight_lines(scene: Scene, eye: np.ndarray, targets: np.ndarray, target_body: int,
                exclude: str = "obstacle") -> np.ndarray:
    """For each target point ``(K, 3)``: is the straight line from ``eye`` to it free of
    occluders other than ``target_body`` itself? World frame [m]."""
    eye = np.asarray(eye, dtype=float)
    d = np.asarray(targets, dtype=float) - eye
    length = np.linalg.norm(d, axis=1)
    vec = d / np.maximum(length, 1e-9)[:, None]
    k = len(vec)
    geomid = np.empty(k, dtype=np.int32)
    dist = np.empty(k)
    mujoco.mj_multiRay(scene.model, scene.data, eye, vec.ravel(), scene.ray_groups, 1,
                       scene.car(exclude).body, geomid, dist, None, k, float(length.max()) + 1.0)
    hit_body = np.where(geomid >= 0, scene.model.body_rootid[scene.model.geom_bodyid[geomid]], -1)
    return (dist < 0) | (dist >= length - 1e-6) | (hit_body == target_body)


def visible_share(scene: Scene, viewer: str, target: str, viewer_pose: np.ndarray | None = None,
                  target_pose: np.ndarray | None = None) -> float:
    """The share in [0, 1] of the ``target`` car's sight points (its four hull corners and
    centre, :func:`cdf_mj.model.occlusion.sight_targets`, at half its hull height) that the
    ``viewer`` car's eye (``CarGeometry.eye``: the driver's eye, or the ego's sensor mount)
    has a line of sight to, past the buildings and any other car; the viewer's own body
    is ignored. ``viewer`` and ``target`` are ``"ego"`` or ``"obstacle"``; poses
    ``[x, y, theta, v]`` (world frame) default to the current state. 0: hidden; 0.2: one
    corner shows; 1: in full view."""
    view_car, target_car = scene.car(viewer), scene.car(target)
    viewer_pose = scene.pose(view_car) if viewer_pose is None else viewer_pose
    target_pose = scene.pose(target_car) if target_pose is None else target_pose
    geometry = target_car.geometry
    pts = sight_targets(geometry, target_pose)  # (5, 2)
    targets = np.column_stack([pts, np.full(len(pts), 0.5 * geometry.hull_height)])
    seen = sight_lines(scene, view_car.geometry.eye(viewer_pose), targets, target_car.body, exclude=viewer)
    return float(seen.mean())


def ego_visible(scene: Scene, obstacle_pose: np.ndarray | None = None,
                ego_pose: np.ndarray | None = None) -> bool:
    """Whether the obstacle driver has a line of sight to any part of the ego: its four
    hull corners and centre (:func:`cdf_mj.model.occlusion.sight_targets`), at half the
    hull height. Poses ``[x, y, theta, v]`` (world frame) default to the current state."""
    return visible_share(scene, "obstacle", "ego", obstacle_pose, ego_pose) > 0.0
