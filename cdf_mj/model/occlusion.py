"""Line of sight for many particles at once: sight segments against building boxes.

The particle filter asks, for every particle's obstacle pose, whether that driver's eye
sees the ego. One MuJoCo ray per particle (or one isovist) costs far too much at
N = 1000, so this module tests 2D sight segments against the buildings' footprints
(oriented rectangles) with NumPy, for all particles, target points and buildings in one
broadcast, particles on the innermost (contiguous) axis. The filter itself runs the same
test compiled, particle by particle and only for those whose answer it needs
(:func:`cdf_mj.inference.kernels.eye_sees`); this module is its reference in the tests
and the form for other callers. ::

    from cdf_mj.model.occlusion import ego_visible

    layout = scene.layout()                    # occluders and car geometries, read once
    seen = ego_visible(layout.occluders, layout.ego, layout.obstacle, particle_poses, ego_pose)
    seen = layout.occluders.visible(eyes, targets)     # general form, see below

The model, and how it differs from :func:`cdf_mj.sim.visibility.ego_visible` (MuJoCo rays):

* Only buildings occlude: every geom whose name starts with ``building`` (read by
  :meth:`cdf_mj.sim.scene.Scene.layout`), each a box standing upright (rotated about z
  only). Cars do not occlude here. In the scenario the looking car is the obstacle and
  the target is the ego, and the MuJoCo version ignores the looking car's body and
  counts a ray that stops on the ego as "seen", so with two cars the answers agree; a
  third car would occlude only there.
* Sight lines are segments in the ground plane: a box occludes iff its footprint meets
  the segment from the eye to the target point. This is exact in 3D when the box spans
  every height on the sight line, i.e. from the ground to above the eye, as the
  scenario's buildings do (0 to 10-12 m; eye 1.2 m, targets at half the hull height).
  A box whose top is below the eye (or whose bottom is above it) cannot block a
  horizontal sight line at eye height and is left out for that eye; a low box that
  would clip a line sloping down to a lower target is therefore ignored (not in this
  scene). With eyes given as ``(N, 2)`` (no height) every box occludes.
* A target counts as seen if ANY of its points is (for the ego: four hull corners and
  the hull centre, :func:`sight_targets`, as in the MuJoCo version).
* Touching counts as blocked (a sight line grazing a corner is occluded); MuJoCo may
  decide such measure-zero cases either way.

The segment-rectangle test is the separating-axis test: segment ``p0 -> p1`` misses a
rectangle of half sizes ``(hx, hy)`` (in its own frame, centre at the origin) iff both
end points lie beyond the same side, or the segment's line separates it,
``|p0 x p1| > hx |dy| + hy |dx|`` with ``(dx, dy) = p1 - p0``. Boxes that all eyes and
all targets lie beyond on one side are dropped before the ``(boxes, K, N)`` stage.

Cost (2-core dev machine, N = 1000 eyes, the scene's 4 buildings, 5 ego points):
``visible`` ~55 us when the culling leaves one building (the usual case), ~85 us with
none culled; :func:`ego_visible` adds ~50 us for ``CarGeometry.eye`` and ``footprint``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cdf_mj.model.vehicle import CarGeometry

__all__ = ["Occluders", "ego_visible", "segments_hit_rectangle", "sight_targets"]


def segments_hit_rectangle(p0: np.ndarray, p1: np.ndarray, center: np.ndarray,
                           heading: float, half: np.ndarray) -> np.ndarray:
    """Whether segments ``p0 -> p1`` (points ``(..., 2)``, broadcast together) meet the
    closed rectangle with ``center`` (2,) [m], ``heading`` of its x axis [rad] and half
    sizes ``half`` (2,) [m]. Touching counts as meeting. Returns a bool array."""
    c, s = math.cos(heading), math.sin(heading)
    hx, hy = (float(h) for h in half)
    a = np.asarray(p0, dtype=float) - np.asarray(center, dtype=float)
    b = np.asarray(p1, dtype=float) - np.asarray(center, dtype=float)
    ax, ay = c * a[..., 0] + s * a[..., 1], -s * a[..., 0] + c * a[..., 1]
    bx, by = c * b[..., 0] + s * b[..., 1], -s * b[..., 0] + c * b[..., 1]
    beyond = (((ax > hx) & (bx > hx)) | ((ax < -hx) & (bx < -hx))
              | ((ay > hy) & (by > hy)) | ((ay < -hy) & (by < -hy)))
    line = np.abs(ax * by - ay * bx) > hx * np.abs(by - ay) + hy * np.abs(bx - ax)
    hit: np.ndarray = ~(beyond | line)
    return hit


# Rotates (x, y) rows by -90 degrees: T @ _PERP turns rows (tx, ty) into (ty, -tx).
_PERP = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass(frozen=True, eq=False)
class Occluders:
    """Upright boxes that block sight lines: footprints (oriented rectangles) and heights.

    All arrays have one row per box, world frame [m], [rad]. A scene's buildings are
    ``Scene.layout().occluders`` (:meth:`cdf_mj.sim.scene.Scene.layout`); any other set
    is built from arrays (e.g. in tests). ValueError if the arrays disagree in length or
    are not finite (half sizes >= 0).
    """

    names: tuple[str, ...]
    center: np.ndarray  # (B, 2) footprint centre
    heading: np.ndarray  # (B,) heading of the box's x axis
    half: np.ndarray  # (B, 2) half length (local x) and half width (local y)
    bottom: np.ndarray  # (B,) lowest z of the box
    top: np.ndarray  # (B,) highest z of the box
    # Derived. World -> box frames as one (2B, 2) matrix, rows (x axis, y axis) of box 0,
    # then of box 1, ..., and the centres in those frames (2B, 1): one matmul places P
    # points in every box frame as (2B, P), viewed as (B, 2, P). Half sizes as (2B, 1)
    # in the same row order, and as (B, 1, 2) weights (hy, hx) for the line test.
    _rot: np.ndarray = field(init=False, repr=False)
    _rc: np.ndarray = field(init=False, repr=False)
    _h2: np.ndarray = field(init=False, repr=False)
    _neg_h2: np.ndarray = field(init=False, repr=False)
    _w: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        center = np.asarray(self.center, dtype=float).reshape(-1, 2)
        b = len(center)
        heading = np.asarray(self.heading, dtype=float).reshape(b)
        half = np.asarray(self.half, dtype=float).reshape(b, 2)
        bottom = np.asarray(self.bottom, dtype=float).reshape(b)
        top = np.asarray(self.top, dtype=float).reshape(b)
        if len(self.names) != b:
            raise ValueError(f"{len(self.names)} names for {b} boxes")
        if not (np.all(np.isfinite(center)) and np.all(np.isfinite(heading))
                and np.all(np.isfinite(half)) and np.all(half >= 0)):
            raise ValueError("box centres, headings and half sizes must be finite, half sizes >= 0")
        c, s = np.cos(heading), np.sin(heading)
        rot = np.stack([np.column_stack([c, s]), np.column_stack([-s, c])], axis=1)  # (B, 2, 2)
        rc = (rot @ center[:, :, None]).reshape(2 * b, 1)
        for name, value in (("center", center), ("heading", heading), ("half", half),
                            ("bottom", bottom), ("top", top), ("_rot", rot.reshape(2 * b, 2)),
                            ("_rc", rc), ("_h2", half.reshape(2 * b, 1)),
                            ("_neg_h2", -half.reshape(2 * b, 1)),
                            ("_w", half[:, ::-1].reshape(b, 1, 2))):
            value = np.ascontiguousarray(value)
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        object.__setattr__(self, "names", tuple(self.names))

    def __len__(self) -> int:
        return len(self.names)

    def visible(self, eyes: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """For each eye, whether ANY of its target points has a sight segment that meets
        no box.

        Args:
            eyes: ``(N, 3)`` eye positions [m] (boxes not spanning an eye's height are
                ignored for it) or ``(N, 2)`` (all boxes count).
            targets: ``(K, 2)`` points shared by all eyes, or ``(N, K, 2)`` one set per
                eye; a third coordinate (height) is accepted and ignored.

        Returns:
            ``(N,)`` bool. With ``K = 0`` nothing is visible; with no boxes, everything.
        """
        eyes = np.asarray(eyes, dtype=float)
        if eyes.ndim != 2 or eyes.shape[1] not in (2, 3):
            raise ValueError(f"eyes must have shape (N, 2) or (N, 3), got {eyes.shape}")
        n = len(eyes)
        targets = np.asarray(targets, dtype=float)
        shared = targets.ndim == 2
        if not (shared or targets.ndim == 3) or targets.shape[-1] not in (2, 3) or (
                not shared and targets.shape[0] != n):
            raise ValueError(f"targets must have shape (K, 2) or (N={n}, K, 2), "
                             f"got {targets.shape}")
        k = targets.shape[-2]
        nb = len(self)
        if n == 0 or k == 0:
            return np.zeros(n, dtype=bool)
        if nb == 0:
            return np.ones(n, dtype=bool)

        # Boxes that can block a sight line at each eye's height.
        active = None  # (B,) bool, None: all
        inactive = None  # (B, N) bool, only when eye heights differ
        if eyes.shape[1] == 3:
            z = eyes[:, 2]
            z0 = z[0]
            if np.all(z == z0):
                active = (self.bottom <= z0) & (self.top >= z0)
            else:
                spans = (self.bottom[:, None] <= z) & (self.top[:, None] >= z)  # (B, N)
                active = spans.any(axis=1)
                inactive = ~spans

        # All points in all box frames, (B, 2, P): the N eyes, then the targets (K, or
        # K x N ordered so that the particle axis stays innermost).
        tgt = targets[:, :2] if shared else targets[:, :, :2].transpose(1, 0, 2).reshape(k * n, 2)
        loc = self._rot @ np.concatenate([eyes[:, :2], tgt]).T
        loc -= self._rc
        beyond_hi = loc > self._h2  # right of / above the box, per axis
        beyond_lo = loc < self._neg_h2  # left of / below
        # A box that ALL points lie beyond on one side blocks nothing: leave it out (in
        # the scenario most buildings, most of the time).
        cull = (beyond_hi.all(axis=1) | beyond_lo.all(axis=1)).reshape(nb, 2).any(axis=1)
        keep = ~cull if active is None else active & ~cull
        b = int(np.count_nonzero(keep))
        if b == 0:
            return np.ones(n, dtype=bool)
        loc, beyond_hi, beyond_lo = (a.reshape(nb, 2, -1) for a in (loc, beyond_hi, beyond_lo))
        w = self._w
        if b < nb:
            loc, beyond_hi, beyond_lo, w = (a[keep] for a in (loc, beyond_hi, beyond_lo, w))
        e = loc[:, :, :n]  # (b, 2, N)
        if shared:
            t = loc[:, :, n:]  # (b, 2, K)
            t4 = t[..., None]  # (b, 2, K, 1)
            hi_t, lo_t = beyond_hi[:, :, n:, None], beyond_lo[:, :, n:, None]
        else:
            t4 = loc[:, :, n:].reshape(b, 2, k, n)
            hi_t = beyond_hi[:, :, n:].reshape(b, 2, k, n)
            lo_t = beyond_lo[:, :, n:].reshape(b, 2, k, n)

        # Separated on a box axis: eye and target beyond the same side.
        sep = beyond_hi[:, :, None, :n] & hi_t
        sep |= beyond_lo[:, :, None, :n] & lo_t
        sep = sep.any(axis=1)  # (b, K, N)
        # Separated by the segment's own line: |e x t| > hx |ty - ey| + hy |tx - ex|
        # (box frame, centre at the origin).
        if shared:
            cross = (t.transpose(0, 2, 1) @ _PERP) @ e  # rows (ty, -tx) . (ex, ey)
        else:
            cross = e[:, None, 0] * t4[:, 1]
            cross -= e[:, None, 1] * t4[:, 0]
        np.abs(cross, out=cross)
        d = t4 - e[:, :, None, :]  # (b, 2, K, N)
        np.abs(d, out=d)
        reach = (w @ d.reshape(b, 2, k * n)).reshape(b, k, n)  # hy |dx| + hx |dy|
        sep |= cross > reach
        if inactive is not None:
            sep |= inactive[keep][:, None, :]
        # A point is seen if its segment is separated from every box; an eye sees the
        # target if any of its points is seen.
        seen: np.ndarray = np.logical_and.reduce(sep, axis=0).any(axis=0)
        return seen


def sight_targets(ego: CarGeometry, ego_pose: np.ndarray) -> np.ndarray:
    """The points of the ego a driver may see, ``(..., 5, 2)`` [m, world frame]: the four
    corners of its collision box and the box's centre, for pose(s) ``(..., 4)`` (one pose,
    the particle filter's per-tick call, on Python floats: the same operations)."""
    pose = np.asarray(ego_pose, dtype=float)
    if pose.shape == (4,):
        points = ego.footprint_one(float(pose[0]), float(pose[1]), float(pose[2]))
        (x0, y0), (x1, y1), (x2, y2), (x3, y3) = points
        points.append(((((x0 + x1) + x2) + x3) / 4.0, (((y0 + y1) + y2) + y3) / 4.0))
        return np.array(points)
    corners = ego.footprint(pose)
    return np.concatenate([corners, corners.mean(axis=-2, keepdims=True)], axis=-2)


def ego_visible(occluders: Occluders, ego: CarGeometry, obstacle: CarGeometry,
                obstacle_poses: np.ndarray, ego_pose: np.ndarray) -> np.ndarray:
    """Whether the obstacle driver at each pose sees any part of the ego
    (:func:`sight_targets`), the ``occluders`` blocking.

    Args:
        occluders: the buildings (``Layout.occluders``).
        ego: the ego's dimensions (hull), ``Layout.ego``.
        obstacle: the obstacle's dimensions (eye), ``Layout.obstacle``.
        obstacle_poses: ``(N, 4)`` ``[x, y, theta, v]`` (a single ``(4,)`` pose gives N = 1).
        ego_pose: ``(4,)`` shared by all, or ``(N, 4)`` one per obstacle pose.

    Returns:
        ``(N,)`` bool. Unlike :func:`cdf_mj.sim.visibility.ego_visible`, neither car
        occludes (see the module notes).
    """
    poses = np.atleast_2d(np.asarray(obstacle_poses, dtype=float))
    targets = sight_targets(ego, np.asarray(ego_pose, dtype=float))
    return occluders.visible(obstacle.eye(poses), targets)
