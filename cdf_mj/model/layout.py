"""The junction's static layout: everything a driver, the filter or a planner may know
about the scene, in NumPy only.

A :class:`Layout` holds the routes, the conflict and commit points, the stop line and
the ego's lane, the start poses, the occluding buildings and both cars' dimensions. It is
read once from an MJCF scene (:meth:`cdf_mj.sim.scene.Scene.layout`) or built by hand; it
holds nothing that changes during an episode, so whoever gets a layout cannot read the
simulator's state. World frame throughout: x east, y north, metres; headings [rad] from
the x axis; poses ``[x, y, theta, v]`` of the rear axle with speed [m/s]. ::

    layout = scene.layout()
    layout.route_left.project(xy)          # arc length [m] and lateral offset [m]
    layout.ego_lane.contains(corners)      # points (..., 2) inside the ego's lane
    layout.obstacle.eye(poses)             # the obstacle driver's eye (..., 3) [m]
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from cdf_mj.model.geometry import OrientedBox, Polyline
from cdf_mj.model.occlusion import Occluders
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["Layout"]


def _read_only(value: np.ndarray, size: int, name: str, problems: list[str]) -> np.ndarray:
    """``value`` as a read-only float array of shape ``(size,)``; a problem noted if it is not
    finite numbers of that shape."""
    try:
        out = np.array(value, dtype=float)
    except (TypeError, ValueError):
        out = np.full(size, np.nan)
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        problems.append(f"{name} must be {size} finite numbers, got {value!r}")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, eq=False)
class Layout:
    """The static scene as the models see it (see the module docstring for frames and units).

    Attributes:
        route_ego: the ego's route, in its direction of travel.
        route_left: the obstacle's route when it turns left (crossing the ego's lane).
        route_right: the obstacle's route when it turns right.
        conflict: ``(2,)`` where a left-turner enters the ego's lane [m].
        commit: ``(2,)`` the point on the obstacle's way past which it no longer yields [m].
        stop_line: the obstacle's stop line (a box on the ground).
        ego_lane: the area of the ego's lane (a box on the ground).
        ego_start: ``(4,)`` the ego's nominal start pose (speed 0).
        obstacle_start: ``(4,)`` the obstacle's start pose (speed 0).
        occluders: the buildings that block sight lines.
        ego: the ego car's dimensions and actuator limits (default: our car,
            :meth:`CarGeometry.ours`).
        obstacle: the obstacle car's dimensions and actuator limits (default: our car).

    Point and pose arrays are stored read-only; ValueError (one message listing every bad
    field) if one is not finite numbers of its shape or a field has the wrong type.
    """

    route_ego: Polyline
    route_left: Polyline
    route_right: Polyline
    conflict: np.ndarray
    commit: np.ndarray
    stop_line: OrientedBox
    ego_lane: OrientedBox
    ego_start: np.ndarray
    obstacle_start: np.ndarray
    occluders: Occluders
    ego: CarGeometry = field(default_factory=CarGeometry.ours)
    obstacle: CarGeometry = field(default_factory=CarGeometry.ours)

    def __post_init__(self) -> None:
        problems: list[str] = []
        for name, size in (("conflict", 2), ("commit", 2), ("ego_start", 4), ("obstacle_start", 4)):
            object.__setattr__(self, name, _read_only(getattr(self, name), size, name, problems))
        for names, kind in ((("route_ego", "route_left", "route_right"), Polyline),
                            (("stop_line", "ego_lane"), OrientedBox), (("occluders",), Occluders),
                            (("ego", "obstacle"), CarGeometry)):
            for name in names:
                if not isinstance(getattr(self, name), kind):
                    problems.append(f"{name} must be a {kind.__name__}, "
                                    f"got {type(getattr(self, name)).__name__}")
        if problems:
            raise ValueError(f"Layout: {'; '.join(problems)}")

    def with_cars(self, ego: CarGeometry | None = None,
                  obstacle: CarGeometry | None = None) -> Layout:
        """This junction with other cars (``None`` keeps a car's geometry; both ``None``: this
        very layout, so that what is cached per layout stays cached)."""
        if ego is None and obstacle is None:
            return self
        return dataclasses.replace(self, ego=ego if ego is not None else self.ego,
                                   obstacle=obstacle if obstacle is not None else self.obstacle)

    @property
    def obstacle_routes(self) -> tuple[Polyline, Polyline]:
        """The obstacle's routes indexed by :class:`cdf_mj.model.driver.Intent`: (left, right)."""
        return (self.route_left, self.route_right)
