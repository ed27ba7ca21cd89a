"""Planar geometry, vectorised over leading axes: polylines (routes), oriented boxes.

All coordinates are world-frame metres in the ground plane (x east, y north).
Functions take arrays of shape ``(..., 2)`` for points and return arrays with the same
leading shape, so that the same code serves one car and N particles. A few have a
one-box twin for the simulation's per-tick work on one car (:func:`box_corners_one`,
:meth:`OrientedBox.contains_any`, :func:`box_gap`), where NumPy's per-call overhead would
cost more than the arithmetic: the same operations, the same values.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numba
import numpy as np

__all__ = ["OrientedBox", "Polyline", "box_corners", "box_corners_one", "box_gap", "boxes_overlap",
           "rotated_corners", "wrap_angle"]


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) wrapped to [-pi, pi) [rad]."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class Polyline:
    """A path through ordered waypoints, parametrised by arc length ``s`` [m].

    ValueError for fewer than 2 points, points that are not finite, or two consecutive
    waypoints at the same place.
    """

    points: np.ndarray  # (P, 2) waypoints [m]
    # Derived (P - 1 segments): lengths [m], arc length at each waypoint (P,) [m]; for the
    # hot paths, contiguous segment starts and unit directions, and the per-segment slope
    # d(point)/ds that numpy.interp would use between waypoints; the same numbers as
    # Python floats, for one point at a time (a car, not particles): plain float arithmetic
    # in the same order gives the same values without NumPy's per-call overhead.
    _len: np.ndarray = field(init=False, repr=False, compare=False)
    _s0: np.ndarray = field(init=False, repr=False, compare=False)
    _x0: np.ndarray = field(init=False, repr=False, compare=False)
    _y0: np.ndarray = field(init=False, repr=False, compare=False)
    _ux: np.ndarray = field(init=False, repr=False, compare=False)
    _uy: np.ndarray = field(init=False, repr=False, compare=False)
    _slope: np.ndarray = field(init=False, repr=False, compare=False)
    _py: tuple[tuple[float, float, float, float, float, float], ...] = field(init=False, repr=False,
                                                                             compare=False)
    _py_slope: list[tuple[float, float]] = field(init=False, repr=False, compare=False)
    _py_points: list[tuple[float, float]] = field(init=False, repr=False, compare=False)
    _py_s0: list[float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"a polyline needs at least 2 points of shape (P, 2), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("a polyline has waypoints that are not finite numbers")
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        if np.any(lengths <= 1e-9):
            raise ValueError("a polyline has two consecutive waypoints at the same place")
        s0 = np.concatenate([[0.0], np.cumsum(lengths)])
        x0, y0 = pts[:-1, 0].copy(), pts[:-1, 1].copy()
        ux, uy = (seg[:, 0] / lengths).copy(), (seg[:, 1] / lengths).copy()
        slope = seg / np.diff(s0)[:, None]
        derived = {
            "points": pts, "_len": lengths, "_s0": s0, "_x0": x0, "_y0": y0, "_ux": ux, "_uy": uy,
            "_slope": slope,
            "_py": tuple(zip(x0.tolist(), y0.tolist(), ux.tolist(), uy.tolist(), lengths.tolist(),
                             s0[:-1].tolist(), strict=True)),
            "_py_slope": [tuple(row) for row in slope.tolist()],
            "_py_points": [tuple(row) for row in pts.tolist()],
            "_py_s0": s0.tolist(),
        }
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    @property
    def length(self) -> float:
        """Total arc length [m]."""
        return float(self._s0[-1])

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length ``s`` [m] of the closest point on the path, and the signed lateral
        offset [m] (positive to the left of the direction of travel), for points ``(..., 2)``."""
        xy = np.asarray(xy, dtype=float)
        lead = xy.shape[:-1]
        flat = xy.reshape(-1, 2)
        if len(flat) == 1 and math.isfinite(flat[0, 0]) and math.isfinite(flat[0, 1]):
            s1, lat1 = self._project_one(float(flat[0, 0]), float(flat[0, 1]))
            return np.full(lead, s1), np.full(lead, lat1)
        # (S, M) layout, segments along axis 0: the elementwise work runs over the long axis.
        ux, uy = self._ux[:, None], self._uy[:, None]
        px = flat[:, 0] - self._x0[:, None]  # from each segment's start
        py = flat[:, 1] - self._y0[:, None]
        t = px * ux
        t += py * uy
        np.minimum(np.maximum(t, 0.0, out=t), self._len[:, None], out=t)  # along each segment, clamped
        px -= t * ux  # now the offset from the closest point of each segment
        py -= t * uy
        d2 = px * px
        d2 += py * py
        k = np.argmin(d2, axis=0)
        cols = np.arange(len(flat))
        s = self._s0[k] + t[k, cols]
        lateral = self._ux[k] * py[k, cols] - self._uy[k] * px[k, cols]
        return s.reshape(lead), lateral.reshape(lead)

    def project_point(self, x: float, y: float) -> tuple[float, float]:
        """:meth:`project` of one point ``(x, y)`` [m] as Python floats ``(s, lateral)`` [m]:
        the same values, without NumPy's per-call overhead."""
        if math.isfinite(x) and math.isfinite(y):
            return self._project_one(x, y)
        s, lateral = self.project(np.array([x, y], dtype=float))
        return float(s), float(lateral)

    def _project_one(self, x: float, y: float) -> tuple[float, float]:
        """:meth:`project` of one finite point, the same operations on Python floats."""
        best = math.inf
        s_best = lat_best = 0.0
        for x0, y0, ux, uy, length, s0 in self._py:
            px, py = x - x0, y - y0
            t = min(max(px * ux + py * uy, 0.0), length)
            px -= t * ux
            py -= t * uy
            d2 = px * px + py * py
            if d2 < best:  # the first minimum, as numpy.argmin
                best, s_best, lat_best = d2, s0 + t, ux * py - uy * px
        return s_best, lat_best

    def point_at(self, s: np.ndarray | float) -> np.ndarray:
        """Point(s) at arc length ``s`` [m], shape ``(..., 2)``; clamped to the ends.

        Linear interpolation between waypoints, computed as ``numpy.interp`` does (same
        values), for both coordinates at once.
        """
        s = np.asarray(s, dtype=float)
        shape = s.shape
        if s.size == 1 and math.isfinite(s.flat[0]):
            return np.array(self._point_one(float(s.flat[0]))).reshape((*shape, 2))
        s = s.reshape(-1)
        s0 = self._s0
        k = np.searchsorted(s0, s, side="right") - 1
        np.clip(k, 0, len(s0) - 2, out=k)
        out = self._slope[k] * np.maximum(s - s0[k], 0.0)[:, None] + self.points[k]
        out[s >= s0[-1]] = self.points[-1]
        result: np.ndarray = out.reshape((*shape, 2))
        return result

    def _point_one(self, s: float) -> tuple[float, float]:
        """:meth:`point_at` of one finite arc length, the same operations on Python floats."""
        s0 = self._py_s0
        if s >= s0[-1]:
            return self._py_points[-1]
        k = min(max(bisect.bisect_right(s0, s) - 1, 0), len(s0) - 2)
        d = max(s - s0[k], 0.0)
        (sx, sy), (px, py) = self._py_slope[k], self._py_points[k]
        return sx * d + px, sy * d + py


@dataclass(frozen=True)
class OrientedBox:
    """A rectangle in the plane: centre [m], heading of its x axis [rad], half sizes [m]."""

    center: np.ndarray  # (2,)
    heading: float
    half: np.ndarray  # (2,) half length along local x, half width along local y

    @functools.cached_property
    def _floats(self) -> tuple[float, float, float, float, float, float]:
        """The numbers :meth:`contains_any` reads, as Python floats (it runs every tick)."""
        return (float(self.center[0]), float(self.center[1]), math.cos(self.heading), math.sin(self.heading),
                float(self.half[0]), float(self.half[1]))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether point(s) ``(..., 2)`` lie inside (boundary included)."""
        d = np.asarray(xy, dtype=float) - self.center
        c, s = np.cos(self.heading), np.sin(self.heading)
        lx = c * d[..., 0] + s * d[..., 1]
        ly = -s * d[..., 0] + c * d[..., 1]
        inside: np.ndarray = (np.abs(lx) <= self.half[0]) & (np.abs(ly) <= self.half[1])
        return inside

    def contains_any(self, points: Iterable[tuple[float, float]]) -> bool:
        """Whether any of a few points ``(x, y)`` [m] lies inside (boundary included): on
        Python floats, ``contains(points).any()`` without NumPy's per-call overhead (the
        same operations, so the same answer)."""
        cx, cy, c, s, hx, hy = self._floats
        for x, y in points:
            dx, dy = x - cx, y - cy
            if abs(c * dx + s * dy) <= hx and abs(-s * dx + c * dy) <= hy:
                return True
        return False

    def corners(self) -> np.ndarray:
        """The four corners ``(4, 2)``, counter-clockwise."""
        return box_corners(self.center, self.heading, self.half)


_UNIT_CORNERS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def box_corners(center: np.ndarray, heading: np.ndarray | float, half: np.ndarray) -> np.ndarray:
    """Corners ``(..., 4, 2)`` of rectangles with centres ``(..., 2)``, headings ``(...)`` [rad]
    and half sizes ``(2,)`` [m], counter-clockwise."""
    center = np.asarray(center, dtype=float)
    heading = np.asarray(heading, dtype=float)
    return rotated_corners(center[..., 0], center[..., 1], np.cos(heading), np.sin(heading), half)


def rotated_corners(cx: np.ndarray, cy: np.ndarray, cos: np.ndarray, sin: np.ndarray,
                    half: np.ndarray) -> np.ndarray:
    """:func:`box_corners` from centre coordinates and the heading's cosine and sine
    (arrays of one shape ``(...)``), for callers that already have them."""
    local = _UNIT_CORNERS * np.asarray(half, dtype=float)  # (4, 2)
    lx, ly = local[:, 0], local[:, 1]
    c, s = np.asarray(cos)[..., None], np.asarray(sin)[..., None]
    out = np.empty((*np.broadcast_shapes(np.shape(cx), np.shape(cos)), 4, 2))
    out[..., 0] = np.asarray(cx)[..., None] + c * lx - s * ly
    out[..., 1] = np.asarray(cy)[..., None] + s * lx + c * ly
    return out


def box_corners_one(cx: float, cy: float, cos: float, sin: float, hx: float,
                    hy: float) -> list[tuple[float, float]]:
    """:func:`rotated_corners` of one box on Python floats (the same operations, so the same
    values): centre ``(cx, cy)`` [m], the heading's cosine and sine, half sizes ``hx, hy``
    [m]; four corners ``(x, y)`` [m], counter-clockwise."""
    chx, shx, chy, shy = cos * hx, sin * hx, cos * hy, sin * hy
    return [(cx + chx - shy, cy + shx + chy), (cx - chx - shy, cy - shx + chy),
            (cx - chx + shy, cy - shx - chy), (cx + chx + shy, cy + shx - chy)]


def box_gap(a: np.ndarray | Sequence[tuple[float, float]],
            b: np.ndarray | Sequence[tuple[float, float]]) -> float:
    """Distance [m] between two convex polygons (the cars' collision boxes) given by their
    corners ``(n, 2)`` [m] in order around each (either way round): 0 if they overlap or
    touch (separating axes), else the smallest vertex-to-edge distance both ways; what
    ``shapely.distance`` gives for the two polygons, up to float rounding.

    One pair per call, compiled (Numba): about 2 µs from Python with lists of corners (0.3
    µs of it the compiled core, ``_box_gap``, which other kernels call), where shapely
    takes 10 µs and the same steps on Python floats 7 µs.
    """
    return float(_box_gap(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)))


@numba.njit(cache=True, nogil=True)
def _box_gap(a: np.ndarray, b: np.ndarray) -> float:  # pragma: no cover - compiled
    sep_a, d2_a = _edges_seen(a, b)
    sep_b, d2_b = _edges_seen(b, a)
    if not (sep_a or sep_b):
        return 0.0
    return math.sqrt(min(d2_a, d2_b))


@numba.njit(cache=True, nogil=True)
def _edges_seen(p: np.ndarray, q: np.ndarray) -> tuple[bool, float]:  # pragma: no cover - compiled
    """Whether an edge of convex polygon ``p`` has every vertex of ``q`` strictly outside
    its line (a separating axis), and the smallest squared distance [m^2] from a vertex of
    ``q`` to an edge of ``p`` that it lies outside of or on (where the closest point of
    ``p`` to an outside vertex always lies)."""
    turn = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[1, 1]) - (p[1, 1] - p[0, 1]) * (p[2, 0] - p[1, 0])
    sign = 1.0 if turn > 0.0 else -1.0  # counter-clockwise: the outward normal is (ey, -ex)
    separated = False
    d2_min = math.inf
    for i in range(p.shape[0]):
        x0, y0 = p[i - 1, 0], p[i - 1, 1]
        x1, y1 = p[i, 0], p[i, 1]
        ex, ey = x1 - x0, y1 - y0
        nx, ny = sign * ey, -sign * ex
        length2 = ex * ex + ey * ey
        outside = 0
        for j in range(q.shape[0]):
            dx, dy = q[j, 0] - x0, q[j, 1] - y0
            side = nx * dx + ny * dy  # |e| times the signed distance from the edge's line
            if side < 0.0:
                continue
            if side > 0.0:
                outside += 1
            along = dx * ex + dy * ey
            if along <= 0.0:  # closest to the edge's start
                d2 = dx * dx + dy * dy
            elif along >= length2:  # closest to its end
                fx, fy = q[j, 0] - x1, q[j, 1] - y1
                d2 = fx * fx + fy * fy
            else:
                d2 = side * side / length2
            d2_min = min(d2_min, d2)
        separated |= outside == q.shape[0]
    return separated, d2_min


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether rectangles ``a[k]`` and ``b[k]`` overlap (boundary included), for corner
    arrays ``(K, 4, 2)`` [m] as :func:`cdf_mj.model.geometry.box_corners` gives; separating axes."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    edges = np.concatenate([a[:, 1:3] - a[:, 0:2], b[:, 1:3] - b[:, 0:2]], axis=1)  # (K, 4, 2)
    axes = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)
    pa = np.einsum("kcj,kaj->kac", a, axes)  # (K, axes, corners)
    pb = np.einsum("kcj,kaj->kac", b, axes)
    overlap: np.ndarray = np.all((pa.max(-1) >= pb.min(-1)) & (pb.max(-1) >= pa.min(-1)), axis=-1)
    return overlap
