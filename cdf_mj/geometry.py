"""Planar geometry, vectorised over leading axes: polylines (routes), oriented boxes.

All coordinates are world-frame metres in the ground plane (x east, y north).
Functions take arrays of shape ``(..., 2)`` for points and return arrays with the same
leading shape, so that the same code serves one car and N particles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Polyline", "OrientedBox", "wrap_angle"]


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) wrapped to [-pi, pi) [rad]."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@dataclass(frozen=True)
class Polyline:
    """A path through ordered waypoints, parametrised by arc length ``s`` [m]."""

    points: np.ndarray  # (P, 2) waypoints [m]

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"a polyline needs at least 2 points of shape (P, 2), got {pts.shape}")
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        if np.any(lengths <= 1e-9):
            raise ValueError("a polyline has two consecutive identical waypoints")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "_seg", seg)
        object.__setattr__(self, "_len", lengths)
        object.__setattr__(self, "_unit", seg / lengths[:, None])
        object.__setattr__(self, "_s0", np.concatenate([[0.0], np.cumsum(lengths)]))

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
        ux, uy = self._unit[:, 0], self._unit[:, 1]
        px = flat[:, 0, None] - self.points[:-1, 0]  # (M, S) from each segment's start
        py = flat[:, 1, None] - self.points[:-1, 1]
        t = np.clip(px * ux + py * uy, 0.0, self._len)
        rx = px - t * ux
        ry = py - t * uy
        k = np.argmin(rx * rx + ry * ry, axis=1)
        rows = np.arange(len(flat))
        s = self._s0[k] + t[rows, k]
        lateral = ux[k] * ry[rows, k] - uy[k] * rx[rows, k]
        return s.reshape(lead), lateral.reshape(lead)

    def point_at(self, s: np.ndarray) -> np.ndarray:
        """Point(s) at arc length ``s`` [m], shape ``(..., 2)``; clamped to the ends."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.length)
        return np.stack([np.interp(s, self._s0, self.points[:, 0]),
                         np.interp(s, self._s0, self.points[:, 1])], axis=-1)


@dataclass(frozen=True)
class OrientedBox:
    """A rectangle in the plane: centre [m], heading of its x axis [rad], half sizes [m]."""

    center: np.ndarray  # (2,)
    heading: float
    half: np.ndarray  # (2,) half length along local x, half width along local y

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether point(s) ``(..., 2)`` lie inside (boundary included)."""
        d = np.asarray(xy, dtype=float) - self.center
        c, s = np.cos(self.heading), np.sin(self.heading)
        lx = c * d[..., 0] + s * d[..., 1]
        ly = -s * d[..., 0] + c * d[..., 1]
        return (np.abs(lx) <= self.half[0]) & (np.abs(ly) <= self.half[1])

    def corners(self) -> np.ndarray:
        """The four corners ``(4, 2)``, counter-clockwise."""
        return box_corners(self.center, self.heading, self.half)


_UNIT_CORNERS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def box_corners(center: np.ndarray, heading: np.ndarray | float, half: np.ndarray) -> np.ndarray:
    """Corners ``(..., 4, 2)`` of rectangles with centres ``(..., 2)``, headings ``(...)`` [rad]
    and half sizes ``(2,)`` [m], counter-clockwise."""
    center = np.asarray(center, dtype=float)
    heading = np.asarray(heading, dtype=float)
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    local = _UNIT_CORNERS * np.asarray(half, dtype=float)  # (4, 2)
    x = center[..., None, 0] + c * local[:, 0] - s * local[:, 1]
    y = center[..., None, 1] + s * local[:, 0] + c * local[:, 1]
    return np.stack([x, y], axis=-1)
