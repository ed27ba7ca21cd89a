"""A default camera that keeps both cars and the conflict zone in view, for any junction.

:class:`FollowCamera` looks straight down on the junction with the ego's direction of
travel (the tangent of its route at the conflict point) pointing right in the image, so a
rotated or mirrored scene looks like the paper's: the ego drives left to right, the main
road is horizontal and the wider image side runs along it. At every 0.1 s tick it frames
both cars' footprints and the conflict zone with a margin, then smooths the look-at point
and the camera's height over time (a Gaussian over about half a second, after a running
maximum of the needed height so the smoothed view still holds everything): it zooms in as
the cars converge, without jumps between frames. The height never exceeds the one at which
a car is ``min_car_px`` long on the ground, so both cars stay readable; when both cars and
the conflict zone cannot all be framed at that scale, the cars are framed and the conflict
zone may leave the view (and then the margin). ::

    from cdf_mj.viz.camera import FollowCamera

    follow = FollowCamera(layout, replay.times, replay.poses, 640, 480)
    gl.use_view(follow.at(t))          # cdf_mj.sim.gl.Offscreen, before update()

World frame throughout: x east, y north, z up, metres; :class:`CameraView` holds MuJoCo's
free-camera settings (``mjvCamera``: look-at point [m], distance [m], azimuth and
elevation [deg]). The projection is perspective with the model's ``visual/global/fovy``
(MuJoCo's free camera), so ground distances scale by ``height / (2 distance tan(fovy/2))``
pixels per metre.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from cdf_mj.model.layout import Layout

__all__ = ["CameraView", "FollowCamera", "follow_camera", "lane_direction"]

#: Smallest length [px] of a car in the default view at 480 px of image height (the
#: target is 40 px at 640x480); scaled with the height at other sizes.
MIN_CAR_PX = 42.0
_MARGIN = 3.0  # [m] kept around the cars' footprints and the conflict zone
_SMOOTH = 0.5  # [s] standard deviation of the Gaussian over the view's path
_MIN_HALF_HEIGHT = 11.0  # [m] the closest view still shows the junction's mouth (22 m tall)


@dataclass(frozen=True)
class CameraView:
    """One free-camera setting (MuJoCo ``mjvCamera``), world frame.

    Attributes:
        lookat: ``(3,)`` the point looked at [m].
        distance: from the camera to ``lookat`` [m].
        azimuth: [deg] about z, MuJoCo's convention (image up is this direction when
            looking straight down).
        elevation: [deg]; -90 looks straight down.
    """

    lookat: np.ndarray
    distance: float
    azimuth: float
    elevation: float = -90.0

    def apply(self, camera: mujoco.MjvCamera) -> None:
        """Set ``camera`` (a free camera) to this view."""
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = self.lookat
        camera.distance = self.distance
        camera.azimuth = self.azimuth
        camera.elevation = self.elevation

    def pixels_per_metre(self, height: int, fovy: float = 45.0) -> float:
        """Image scale [px/m] on the ground at :attr:`lookat` for a view ``height`` [px]
        tall and the vertical field of view ``fovy`` [deg]."""
        return height / (2.0 * self.distance * math.tan(math.radians(fovy) / 2.0))


def lane_direction(layout: Layout) -> np.ndarray:
    """Unit vector ``(2,)`` of the ego's direction of travel at the conflict point (the
    tangent of ``route_ego`` there), world frame."""
    route = layout.route_ego
    s, _ = route.project(np.asarray(layout.conflict, dtype=float)[None])
    s0 = float(np.clip(s[0], 0.0, route.length))
    a = route.point_at(max(s0 - 0.5, 0.0))
    b = route.point_at(min(s0 + 0.5, route.length))
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    return d / float(np.hypot(d[0], d[1]))


def _gaussian_smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """``x`` ``(K, ...)`` smoothed along axis 0 by a Gaussian of ``sigma`` samples, the ends
    padded with the end values (so a constant stays constant)."""
    if sigma <= 0 or len(x) < 2:
        return x.copy()
    r = math.ceil(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    pad = np.concatenate([np.repeat(x[:1], r, axis=0), x, np.repeat(x[-1:], r, axis=0)])
    out = np.zeros_like(x, dtype=float)
    for j, w in enumerate(k):
        out += w * pad[j:j + len(x)]
    return out


def _running_max(x: np.ndarray, r: int) -> np.ndarray:
    """The maximum of ``x`` ``(K,)`` over each window ``[i - r, i + r]``."""
    if r <= 0 or len(x) < 2:
        return x.copy()
    pad = np.concatenate([np.full(r, x[0]), x, np.full(r, x[-1])])
    windows = np.lib.stride_tricks.sliding_window_view(pad, 2 * r + 1)
    out: np.ndarray = windows.max(axis=1)
    return out


class FollowCamera:
    """The default view of an episode (see the module docstring).

    Args:
        layout: the junction (routes, conflict point, both cars' dimensions).
        times: ``(K,)`` sample times [s], increasing (a replay's tick times).
        poses: ``(K, 2, 4)`` both cars' poses ``[x, y, theta, v]`` at ``times`` (ego first).
        width, height: image size [px].
        fovy: the vertical field of view [deg] of MuJoCo's free camera: the model's
            ``vis.global_.fovy`` (45 by default).
        min_car_px: the smallest length [px] of a car on the ground (caps the height);
            default :data:`MIN_CAR_PX` at 480 px of image height, in proportion at other
            heights (a 320x240 GIF keeps the same framing as 640x480, at half the pixels).
        margin: [m] kept around the footprints and the conflict zone.
        smooth: [s] standard deviation of the Gaussian smoothing the view over time.

    Raises:
        ValueError: poses and times of different lengths, no sample, or a size <= 0.
    """

    def __init__(self, layout: Layout, times: Sequence[float] | np.ndarray, poses: np.ndarray,
                 width: int, height: int, *, fovy: float = 45.0, min_car_px: float | None = None,
                 margin: float = _MARGIN, smooth: float = _SMOOTH) -> None:
        t = np.asarray(times, dtype=float)
        p = np.asarray(poses, dtype=float)
        if p.ndim != 3 or p.shape[1:] != (2, 4) or len(p) != len(t) or len(t) == 0:
            raise ValueError(f"FollowCamera: poses must be (K, 2, 4) with K = len(times) > 0, got "
                             f"{p.shape} for {len(t)} times")
        if width <= 0 or height <= 0 or not 0.0 < fovy < 180.0:
            raise ValueError(f"FollowCamera: width {width}, height {height} [px] must be > 0 and "
                             f"fovy {fovy} in (0, 180) degrees")
        self.times = t
        self.width, self.height, self.fovy = int(width), int(height), float(fovy)
        u = lane_direction(layout)
        v = np.array([-u[1], u[0]])  # image up: the left of the ego's direction
        self.axes = np.stack([u, v])  # world -> view: rows (right, up)
        self.azimuth = math.degrees(math.atan2(v[1], v[0]))
        tan = math.tan(math.radians(self.fovy) / 2.0)
        aspect = self.width / self.height
        shortest = min(2 * float(layout.ego.hull_half[0]), 2 * float(layout.obstacle.hull_half[0]))
        #: The highest camera [m] at which the shorter car is ``min_car_px`` long.
        if min_car_px is None:
            min_car_px = MIN_CAR_PX * self.height / 480.0
        self.max_distance = shortest * self.height / (2.0 * tan * min_car_px)
        min_distance = min(_MIN_HALF_HEIGHT / tan, self.max_distance)

        # The points to keep, in the view frame: both footprints (K, 8, 2), the conflict zone.
        feet = np.concatenate([layout.ego.footprint(p[:, 0]), layout.obstacle.footprint(p[:, 1])],
                              axis=1) @ self.axes.T
        lane = 2.0 * float(min(layout.ego_lane.half))  # the lane's width [m]
        zone = (np.asarray(layout.conflict, dtype=float) @ self.axes.T
                + np.array([[-lane, -lane], [lane, lane]]))  # a lane width around it
        # Per sample, the first framing that fits under max_distance: cars and zone with the
        # margin, the cars with the margin, the cars alone (else the cars alone, too small).
        lo_bare, hi_bare = feet.min(axis=1), feet.max(axis=1)
        lo_cars, hi_cars = lo_bare - margin, hi_bare + margin
        lo_all = np.minimum(lo_cars, zone.min(axis=0) - margin)
        hi_all = np.maximum(hi_cars, zone.max(axis=0) + margin)

        def needed(lo: np.ndarray, hi: np.ndarray, centre: np.ndarray) -> np.ndarray:
            half = np.maximum(hi - centre, centre - lo)  # (K, 2) half extents about centre
            return np.maximum(half[:, 0] / (aspect * tan), half[:, 1] / tan)

        fit_all = needed(lo_all, hi_all, 0.5 * (lo_all + hi_all)) <= self.max_distance
        fit_cars = needed(lo_cars, hi_cars, 0.5 * (lo_cars + hi_cars)) <= self.max_distance
        lo = np.where(fit_all[:, None], lo_all, np.where(fit_cars[:, None], lo_cars, lo_bare))
        hi = np.where(fit_all[:, None], hi_all, np.where(fit_cars[:, None], hi_cars, hi_bare))
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.1
        sigma = smooth / max(dt, 1e-9)
        centre = _gaussian_smooth(0.5 * (lo + hi), sigma)
        dist = needed(lo, hi, centre)
        r = math.ceil(3 * sigma)
        # A running max over the Gaussian's support, then the Gaussian: the smoothed height
        # is a weighted mean of values each >= the height needed at that sample.
        dist = _gaussian_smooth(_running_max(dist, r), sigma)
        self.centres = centre  # (K, 2) view frame [m]
        self.distances = np.clip(dist, min_distance, self.max_distance)  # (K,) [m]

    def at(self, t: float) -> CameraView:
        """The view at time ``t`` [s], interpolated linearly between samples (clamped at
        the ends)."""
        c = np.array([np.interp(t, self.times, self.centres[:, 0]),
                      np.interp(t, self.times, self.centres[:, 1])])
        d = float(np.interp(t, self.times, self.distances))
        xy = c @ self.axes  # view frame -> world
        return CameraView(np.array([xy[0], xy[1], 0.0]), d, self.azimuth)

    def pixels_per_metre(self, t: float) -> float:
        """Image scale [px/m] on the ground at time ``t`` [s]."""
        return self.at(t).pixels_per_metre(self.height, self.fovy)


def follow_camera(layout: Layout, poses_over_time: np.ndarray, width: int, height: int, *,
                  times: Sequence[float] | np.ndarray | None = None,
                  fovy: float = 45.0) -> list[CameraView]:
    """The default view at each of ``poses_over_time`` ``(K, 2, 4)`` (ego, obstacle; one
    sample per 0.1 s tick unless ``times`` [s] are given): :class:`FollowCamera` sampled
    at its own samples."""
    p = np.asarray(poses_over_time, dtype=float)
    t = np.arange(len(p)) * 0.1 if times is None else np.asarray(times, dtype=float)
    follow = FollowCamera(layout, t, p, width, height, fovy=fovy)
    return [follow.at(float(ti)) for ti in t]
