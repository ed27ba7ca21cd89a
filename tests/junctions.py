"""Varied T-junction scenes for tests, built with the MjSpec API only (no XML).

:func:`build_junction` lays out the paper's T-junction (``models/xml/intersection.xml``)
for any lane width, then places it in the world: mirrored (left-hand traffic), rotated
about the junction centre by any angle and moved, with the element names of any
:class:`~cdf_mj.config.SceneNames` and with or without buildings. Both our cars are
added with :func:`cdf_mj.sim.spec.add_car` at their start poses. ::

    from tests.junctions import Placement, build_junction, junction_scene
    scene = junction_scene(rotation=0.7, mirror=True, lane_width=3.2)   # a Scene
    spec = build_junction(names=SceneNames(ego_prefix="av/"), cars=False)  # add your own cars
    small = build_junction(scale=0.1, cars=False)   # a 1:10 testbed: 0.37 m lanes, no cars

The local frame (before placement) is the frame of ``models/xml``: x east, y north,
metres, radians; the main road runs along x centred on y = 0, the ego drives east in the
southern lane, the side road comes from the north and the obstacle faces south.
:class:`Placement` maps local points and headings to the world, and ``scale`` shrinks
or grows the whole junction about its local origin (every length and height; a testbed at
1:10 is ``scale=0.1``), after which the local frame is still in full-size metres.

Mirroring (``mirror=True``, y -> -y before the rotation) gives left-hand traffic: the ego
drives east in the *northern* lane, the side road comes from the south, and the turn that
crosses the ego's lane is a right turn of the obstacle as seen in the world. The names keep
their meaning (docs/SCENES.md): ``route_left`` is still the route that crosses the ego's
lane into it, ``route_right`` the one that turns away into the far lane.

Each geometric choice copies ``models/xml`` relative to the lanes (lane width ``w``, lane
centre ``c = w / 2``): stop line 1 m before the main road's edge, the obstacle's rear axle
3.65 m behind it (front bumper on the line), commit point 1.45 m ahead of the start,
conflict point 4.35 m east of the side lane's centre on the ego's lane centre, turn radii 7 m
(left) and 6 m (right), routes extended to +-150 m, building faces set back as in the
paper's scene (the northern ones just let the waiting driver see along the main road).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.spec import add_car

__all__ = ["Placement", "build_junction", "junction_scene", "start_poses"]

EGO_START_X = -40.8  # [m] local x of the ego's rear-axle start (models/xml)
ROUTE_END = 150.0  # [m] how far the straight route ends reach from the centre
TIMESTEP = 0.005  # [s] physics step (20 per 0.1 s tick)
DEFAULT_NAMES = SceneNames()


@dataclass(frozen=True)
class Placement:
    """Where the local junction lies in the world: ``world = R(rotation) @ M @ (scale *
    local) + center`` with ``M = diag(1, -1)`` when mirrored. ``rotation`` [rad] about the
    junction centre, ``center`` [m] the world position of the local origin, ``scale`` the
    testbed's scale (0.1: 1:10)."""

    rotation: float = 0.0
    mirror: bool = False
    center: tuple[float, float] = (0.0, 0.0)
    scale: float = 1.0

    def point(self, xy: np.ndarray | tuple[float, float]) -> np.ndarray:
        """Local points ``(..., 2)`` [m] in the world frame."""
        p = self.scale * np.array(xy, dtype=float)
        if self.mirror:
            p[..., 1] = -p[..., 1]
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        return np.stack([c * p[..., 0] - s * p[..., 1] + self.center[0],
                         s * p[..., 0] + c * p[..., 1] + self.center[1]], axis=-1)

    def heading(self, theta: float) -> float:
        """A local heading [rad] in the world frame, wrapped to (-pi, pi]."""
        return math.remainder((-theta if self.mirror else theta) + self.rotation, 2 * math.pi)

    def pose(self, pose: np.ndarray | tuple[float, ...]) -> np.ndarray:
        """A local pose ``[x, y, theta, v]`` in the world frame (the speed scaled as the lengths)."""
        x, y, th, v = (float(p) for p in pose)
        return np.array([*self.point((x, y)), self.heading(th), self.scale * v])


def _quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def _arc(cx: float, cy: float, r: float, a0: float, a1: float, n: int) -> list[tuple[float, float]]:
    return [(cx + r * math.cos(a0 + (a1 - a0) * k / n), cy + r * math.sin(a0 + (a1 - a0) * k / n))
            for k in range(n + 1)]


def _local_geometry(w: float, left_radius: float, right_radius: float) -> dict:
    """Points [m] and headings [rad] of the junction in the local frame, for lane width ``w``."""
    c = w / 2.0
    stop_y = w + 1.0  # the stop line, 1 m before the main road's edge
    start_y = stop_y + 3.65  # the obstacle's rear axle: its front bumper on the stop line
    if left_radius - c >= start_y or right_radius + c >= start_y:
        raise ValueError(f"turn radii {left_radius}, {right_radius} m do not fit lanes of {w} m")
    return {
        "c": c, "stop_y": stop_y, "start_y": start_y,
        "ego_start": (EGO_START_X, -c, 0.0, 0.0),
        "obstacle_start": (-c, start_y, -math.pi / 2, 0.0),
        "commit": (-c, start_y - 1.45),
        "conflict": (-c + 4.35, -c),
        "route_ego": [(-ROUTE_END, -c), (ROUTE_END, -c)],
        "route_left": [(-c, start_y),
                       *_arc(-c + left_radius, -c + left_radius, left_radius, math.pi, 1.5 * math.pi, 8),
                       (ROUTE_END, -c)],
        "route_right": [(-c, start_y),
                        *_arc(-c - right_radius, c + right_radius, right_radius, 0.0, -0.5 * math.pi, 6),
                        (-ROUTE_END, c)],
        # name suffix: centre (x, y), half sizes (x, y, z); faces set back as in models/xml
        "buildings": {
            "_nw": ((-(40 + w + 2.8) / 2, (start_y - 0.85 + 30) / 2),
                    ((40 - w - 2.8) / 2, (30 - start_y + 0.85) / 2, 6.0)),
            "_ne": (((40 + w + 2.8) / 2, (start_y - 0.85 + 30) / 2),
                    ((40 - w - 2.8) / 2, (30 - start_y + 0.85) / 2, 6.0)),
            "_sw": ((-21.0, -(30 + w + 3.8) / 2), (19.0, (30 - w - 3.8) / 2, 5.0)),
            "_se": ((21.0, -(30 + w + 3.8) / 2), (19.0, (30 - w - 3.8) / 2, 5.0)),
        },
    }


def start_poses(*, rotation: float = 0.0, mirror: bool = False, lane_width: float = 3.7,
                center: tuple[float, float] = (0.0, 0.0), scale: float = 1.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """The ego's and the obstacle's start poses ``[x, y, theta, 0]`` in the world frame, as
    :func:`build_junction` places them (for cars of your own)."""
    g = _local_geometry(lane_width, 7.0, 6.0)
    place = Placement(rotation, mirror, center, scale)
    return place.pose(g["ego_start"]), place.pose(g["obstacle_start"])


def build_junction(*, rotation: float = 0.0, mirror: bool = False, lane_width: float = 3.7,
                   names: SceneNames = DEFAULT_NAMES, buildings: bool = True, cars: bool = True,
                   center: tuple[float, float] = (0.0, 0.0), left_radius: float = 7.0,
                   right_radius: float = 6.0, camera: str | None = "top", scale: float = 1.0
                   ) -> mujoco.MjSpec:
    """A T-junction as an ``MjSpec`` (see the module docstring for the layout).

    Args:
        rotation: turn of the whole junction about its centre [rad], counter-clockwise.
        mirror: left-hand traffic (the local y axis flipped before the rotation).
        lane_width: width of every lane [m] (3.7 in models/xml).
        names: the element names to give (prefixes included).
        buildings: the four corner buildings (geoms ``<building_prefix>_nw`` and so on).
        cars: add both our cars with ``add_car`` at their start poses.
        center: world position of the junction centre [m].
        left_radius, right_radius: the obstacle's turn radii [m] (rear axle).
        camera: name of a camera 70 m above the centre looking down, or None for none.
        scale: the whole junction's scale (every length and height; 0.1: a 1:10 testbed
            with 0.37 m lanes), the arguments above in full-size metres; only without our
            full-size ``cars``.

    Options: timestep 0.005 s, integrator implicitfast, angles in radians, an offscreen
    buffer of 1280 x 720.
    """
    if cars and scale != 1.0:
        raise ValueError(f"build_junction: our cars are full size; with scale={scale} add your own (cars=False)")
    g = _local_geometry(lane_width, left_radius, right_radius)
    place = Placement(rotation, mirror, center, scale)
    w, c, k = lane_width, g["c"], scale
    spec = mujoco.MjSpec()
    spec.modelname = "junction"
    spec.compiler.degree = False
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.visual.global_.offwidth, spec.visual.global_.offheight = 1280, 720
    world = spec.worldbody
    cx, cy = center
    world.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[200 * k, 200 * k, 0.1],
                   pos=[cx, cy, 0], rgba=[0.3, 0.38, 0.26, 1], contype=0, conaffinity=0)
    road_rgba = [0.22, 0.22, 0.24, 1]
    side_len = 40.0
    for name, (x, y), (hx, hy) in (("road_main", (0.0, 0.0), (ROUTE_END, w)),
                                   ("road_side", (0.0, w + side_len / 2), (w, side_len / 2))):
        world.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, pos=[*place.point((x, y)), 0.005 * k],
                       quat=_quat(place.heading(0.0)), size=[hx * k, hy * k, 0.005 * k], rgba=road_rgba,
                       contype=0, conaffinity=0, group=0)
    if camera is not None:
        world.add_camera(name=camera, pos=[cx, cy, 70.0 * k], fovy=60.0)

    def site(name: str, xy: tuple[float, float], heading: float = 0.0, box: tuple | None = None) -> None:
        s = world.add_site(name=name, pos=[*place.point(xy), 0.0], quat=_quat(place.heading(heading)),
                           group=4)
        if box is not None:
            s.type = mujoco.mjtGeom.mjGEOM_BOX
            s.size = [b * k for b in (*box, 0.02)]

    site(names.ego_start, g["ego_start"][:2], g["ego_start"][2])
    site(names.obstacle_start, g["obstacle_start"][:2], g["obstacle_start"][2])
    site(names.stop_line, (-c, g["stop_y"] + 0.15), box=(c, 0.15))
    site(names.ego_lane, (0.0, -c), box=(ROUTE_END, c))
    site(names.conflict, g["conflict"])
    site(names.commit, g["commit"])
    for body_name, key in ((names.route_ego, "route_ego"), (names.route_left, "route_left"),
                           (names.route_right, "route_right")):
        body = world.add_body(name=body_name)
        for xy in place.point(np.array(g[key])):
            body.add_site(pos=[*xy, 0.0], group=4)
    if buildings:
        for suffix, (xy, half) in g["buildings"].items():
            world.add_geom(name=names.building_prefix + suffix, type=mujoco.mjtGeom.mjGEOM_BOX,
                           pos=[*place.point(xy), half[2] * k], quat=_quat(place.heading(0.0)),
                           size=[h * k for h in half], rgba=[0.72, 0.64, 0.52, 1], group=1,
                           contype=1, conaffinity=2)
    if cars:
        for prefix, key, paint in ((names.ego_prefix, "ego_start", (0.8, 0.1, 0.1, 1.0)),
                                   (names.obstacle_prefix, "obstacle_start", (0.1, 0.25, 0.8, 1.0))):
            pose = place.pose(g[key])
            add_car(spec, prefix, pos=(pose[0], pose[1]), yaw=pose[2], paint=paint)
    return spec


def junction_scene(**kwargs: object) -> Scene:
    """:func:`build_junction` with these keyword arguments, compiled into a :class:`Scene`
    (with our cars; ``names`` is passed on to the scene)."""
    names = kwargs.get("names", DEFAULT_NAMES)
    assert isinstance(names, SceneNames)
    spec = build_junction(**kwargs)  # type: ignore[arg-type]
    shown = ", ".join(f"{k}={v!r}" for k, v in kwargs.items() if k != "names")
    return Scene.from_model(spec.compile(), names=names, source=f"junction({shown})")
