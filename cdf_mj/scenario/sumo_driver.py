"""Eclipse SUMO drives the obstacle: its junction and car-following models, in-process
(libsumo), on a network generated from the scene's layout (``obstacle.family = "sumo"``).

An optional extra (``sumo``: the ``eclipse-sumo`` and ``libsumo`` wheels); without it the
family fails with one line naming the extra. What SUMO's models represent, and what they
do not (no sight lines: overlooking a foe stands in for occlusion), is in docs/SUMO.md. ::

    driver = SumoDriver()                              # or SumoDriver(SumoParams(...))
    driver.reset(layout, intent=0, rng=rng)            # draws SUMO's driver parameters and seed
    scene.reset(ego=..., obstacle=driver.start)        # [x, y, theta, v]
    accel, steer = driver.control(t, pose, ego, dt)    # one SUMO step of dt per tick
    driver.mode, driver.params                         # Mode int read from SUMO; the drawn values

**The network** (:func:`build_network`, cached per layout): one lane each way, as wide as the
ego's lane; the ego's road is the major road, the obstacle's side road a minor road with a
stop sign (a ``priority_stop`` junction: every movement from it stops, then yields). SUMO
places a car by the centre of its front bumper, MuJoCo by its rear axle: the network's lanes
are the *front-bumper paths* of the layout's routes (the path swept by the front bumper of a
car whose rear axle follows the route, its heading along the route), so that a SUMO car on a
lane is a MuJoCo car on the route. On the straights they are the routes themselves; in the
turns they run outside them (by up to about 1 m in the default scene; docs/SUMO.md). The side
road's lane ends where the front bumper is at the obstacle's start (on the stop line); the
turns' internal lanes end where their front path has rejoined its lane's centre line; the
ego's lane enters the junction half a lane width before the side road's lane centre.

**A tick** (:meth:`SumoDriver.control`): the ego's pose, carried one tick ahead at its
speed, is written into SUMO (a vehicle on the major road, moved with ``moveToXY`` and its
speed set, so that SUMO's junction model sees a foe with right of way), SUMO steps ``dt``
(``--step-length`` = the world's tick), and the MuJoCo car follows the SUMO car: a speed
servo on SUMO's speed with a correction for the along-path position (time constant
:data:`POSITION_TIME`), and pure pursuit on the route. :attr:`SumoDriver.tracking` keeps the
largest distance between the two (tests/test_sumo.py bounds it).

**Modes**, read from SUMO's state: waiting (on the side road, or standing at the line within
its stop-sign wait), yielding (standing at the line past its stop-sign wait: held by a foe;
or braking harder than :data:`YIELD_DECEL` in the junction), going, committed (its rear
axle past the layout's commit point).

**Drawn per episode** (:class:`SumoParams`, each range with its source): SUMO's
``impatience``, ``jmIgnoreFoeProb`` and ``jmIgnoreFoeSpeed`` (overlooking a foe),
``jmTimegapMinor``, ``jmStopSignWait``, ``sigma``, ``speedFactor``, ``accel`` and ``decel``;
and SUMO's ``--seed``, from the episode's generator: the same seed gives the same poses.

libsumo runs one simulation per process: it starts once, each episode loads the network
anew (on the first tick, when the tick length is known) with a route file of its own, and it
closes at exit, pool workers' exits included. Two SUMO worlds in one process cannot run at
once (a RuntimeError says so); parallel experiments run one per worker process. A forked
process (a pool worker of a parent that ran SUMO episodes) starts its own simulation and
temporary folder at its first episode; an episode loaded before the fork is refused there.
Networks are cached in the user's cache folder (``$XDG_CACHE_HOME/cdf_mj/sumo``).

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``. SUMO's angles are navigational (degrees clockwise from north).
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import math
import multiprocessing.util
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType, ModuleType
from typing import Any, ClassVar
from xml.sax.saxutils import quoteattr

import numpy as np

from cdf_mj.extras import require
from cdf_mj.model.geometry import Polyline
from cdf_mj.model.layout import Layout
from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING, YIELDING
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.scenario.drivers import LOOKAHEAD, LOOKAHEAD_GAIN, FamilyParams, span

__all__ = ["FEATURE", "SumoDriver", "SumoError", "SumoNetwork", "SumoParams", "build_network", "front_path"]

FEATURE = "obstacle.family = 'sumo'"  # what the user asked for, in the missing-extra message

# The network.
NETWORK_VERSION = 1  # part of the cache key: bump when the generated network changes
UPSTREAM = 60.0  # [m] of side road before the stop line (room for an approach) and of major road
EXTEND = 250.0  # [m] the routes continued straight past their ends (a car never runs off SUMO's net)
PATH_STEP = 0.25  # [m] sampling of a front-bumper path through a turn
ON_LINE = 0.02  # [m] a front path this near its final centre line has left the junction
SAME_POINT = 0.05  # [m] where two front paths must agree (the stop point; the left turn's lane)
ROAD_SPEED = 13.89  # [m/s] every lane's speed limit: 50 km/h, SUMO's default edge speed (urban roads)
TURN_LATERAL_ACCEL = 5.5  # [m/s^2] a turn's speed limit sqrt(a R): netconvert's --junctions.limit-turn-speed
# The follower.
POSITION_TIME = 0.5  # [s] time constant of the MuJoCo car's along-path position correction
AT_REST = 0.2  # [m/s] below this a car is at rest
YIELD_DECEL = 1.0  # [m/s^2] braking harder than this in the junction before its commit point: yielding
HOLD_BRAKE = 2.0  # [m/s^2] the brake that keeps the MuJoCo car at rest where SUMO's stands
# [m/s^2] the ego's decel in SUMO: the ego's comfortable braking (ego.comfort_brake). SUMO's
# minor-road drivers expect a major-road car to brake for them at its decel: at SUMO's default
# 4.5 they pulled out 2.4-3.9 s ahead of a 13.4 m/s ego; at 2 they wait for gaps up to 6 s.
EGO_DECEL = 2.0
# SUMO's vehicle ids and its one simulation per process.
OBSTACLE, EGO = "obstacle", "ego"
_SUMO_OPTIONS = ("--step-method.ballistic", "true",  # constant acceleration within a step, as MuJoCo's car
                 "--collision.action", "none",  # the world, not SUMO, decides what a touch means
                 "--time-to-teleport", "-1",  # a car held at its line stays there
                 "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
                 "--xml-validation", "never")


class SumoError(RuntimeError):
    """SUMO failed: netconvert refused a network or libsumo a simulation (one line, SUMO's
    own message)."""


# ---------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class SumoParams(FamilyParams):
    """SUMO's driver parameters, drawn uniformly per episode (see :class:`FamilyParams`).
    The fields carry SUMO's own vType attribute names (its docs, "Definition of Vehicles,
    Vehicle Types, and Routes": junction model and car-following parameters), except the
    approach, which is this package's (as in :mod:`cdf_mj.scenario.drivers`)."""

    impatience: tuple[float, float] = span(
        (0.0, 0.5), 0.0, 1.0, "1", "SUMO default 0; up to 0.5: drivers who count on the ego braking for them a "
                                   "little (1: at its full deceleration)")
    jmIgnoreFoeProb: tuple[float, float] = span(
        (0.0, 0.5), 0.0, 1.0, "1/step", "SUMO default 0; SUMO draws it anew every step: (0, 0.5) at 0.1 s steps "
                                        "makes a fifth to a quarter of left-turners cut off (docs/SUMO.md)")
    jmIgnoreFoeSpeed: tuple[float, float] = span(
        (20.0, 25.0), 0.0, 60.0, "m/s", "SUMO default 0 (only standing foes are overlooked); above the ego speeds "
                                        "of the presets and falsification spaces (9-18 m/s): the ego may be "
                                        "overlooked at any of them")
    jmTimegapMinor: tuple[float, float] = span(
        (0.5, 1.5), 0.0, 10.0, "s", "SUMO default 1 s (net time gap ahead of a prioritised car; uncalibrated, "
                                    "J. Erdmann on the sumo-user list): half to one and a half of it")
    jmStopSignWait: tuple[float, float] = span(
        (0.0, 1.0), 0.0, 60.0, "s", "what is left at t = 0 of SUMO's default 1 s stop: the episode starts at "
                                    "any moment of it (the world's own driver may leave at t = 0)")
    sigma: tuple[float, float] = span(
        (0.2, 0.8), 0.0, 1.0, "1", "Krauss driver imperfection around SUMO's default 0.5")
    speedFactor: tuple[float, float] = span(
        (0.8, 1.2), 0.1, 3.0, "1", "SUMO's passenger default draws normc(1, 0.1, 0.2, 2): its central 95 %")
    accel: tuple[float, float] = span(
        (1.5, 3.0), 0.1, 10.0, "m/s^2", "SUMO passenger default 2.6; pulling out from a stop 1.5-3 "
                                        "(clipped to the car's maximum)")
    decel: tuple[float, float] = span(
        (3.0, 4.5), 0.1, 10.0, "m/s^2", "SUMO passenger default 4.5 (its comfortable maximum); from 3 "
                                        "(clipped to the car's maximum braking)")
    approach_distance: tuple[float, float] = span(
        (0.0, 0.0), 0.0, UPSTREAM - 10.0, "m", "starts at the line, as the world's driver does")
    approach_speed: tuple[float, float] = span(
        (0.0, 0.0), 0.0, ROAD_SPEED, "m/s", "starts at rest")


# ------------------------------------------------------------------------------ geometry
def _front_distance(car: CarGeometry) -> float:
    """Rear axle to the front bumper [m]."""
    return float(car.hull_offset[0] + car.hull_half[0])


def _heading_knots(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A polyline's heading as a continuous function of arc length: each segment's heading,
    ramped linearly across each interior waypoint over half the shorter neighbouring segment
    either side (the heading of a car whose rear axle follows the polyline). Returns the
    knots ``(s [m], heading [rad])`` and the waypoints' arc lengths [m]."""
    seg = np.diff(points, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    s_w = np.concatenate([[0.0], np.cumsum(lengths)])
    heads = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    ks, kh = [0.0], [float(heads[0])]
    for i in range(1, len(points) - 1):
        if abs(heads[i] - heads[i - 1]) < 1e-9:
            continue
        w = 0.5 * min(lengths[i - 1], lengths[i])
        ks += [s_w[i] - w, s_w[i] + w]
        kh += [float(heads[i - 1]), float(heads[i])]
    ks.append(float(s_w[-1]))
    kh.append(float(heads[-1]))
    return np.array(ks), np.array(kh), s_w


def _extended(route: Polyline, before: float, after: float) -> Polyline:
    """``route`` continued straight ``before`` [m] back from its start and ``after`` [m] on
    from its end (along its first and last segments)."""
    pts = np.asarray(route.points, dtype=float)
    d0 = (pts[1] - pts[0]) / np.hypot(*(pts[1] - pts[0]))
    d1 = (pts[-1] - pts[-2]) / np.hypot(*(pts[-1] - pts[-2]))
    out = [pts]
    if before > 0.0:
        out.insert(0, (pts[0] - before * d0)[None])
    if after > 0.0:
        out.append((pts[-1] + after * d1)[None])
    return Polyline(np.vstack(out))


def front_path(route: Polyline, front: float) -> tuple[np.ndarray, np.ndarray]:
    """The path of the front bumper's centre of a car whose rear axle follows ``route`` with
    its heading along it (:func:`_heading_knots`), ``front`` [m] ahead of the rear axle.
    Returns ``(s, points)``: the rear axle's arc length [m] along ``route`` (N,) and the front
    bumper's points (N, 2) [m], sampled every :data:`PATH_STEP` through the turns and at the
    ends of the straights."""
    ks, kh, s_w = _heading_knots(np.asarray(route.points, dtype=float))
    s = np.union1d(s_w, ks)
    if len(ks) > 2:  # through the turns: from the first ramp to the last, finely
        s = np.union1d(s, np.arange(ks[1], ks[-2], PATH_STEP))
    h = np.interp(s, ks, kh)
    pts = route.point_at(s) + front * np.stack([np.cos(h), np.sin(h)], axis=-1)
    keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-3])
    return s[keep], pts[keep]


def _off_line(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] of each point (N, 2) from the straight line through ``a`` and ``b``."""
    d = (b - a) / np.hypot(*(b - a))
    rel = points - a
    return np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0])


def _exit_index(points: np.ndarray) -> int:
    """The index of the first point of a front path from which on it stays on its final
    centre line (within :data:`ON_LINE`): where the turn has left the junction."""
    off = np.flatnonzero(_off_line(points, points[-2], points[-1]) > ON_LINE)
    return int(off[-1]) + 1 if len(off) else 0


def _arc(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length [m] along points (N, 2)."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])


def _shape(points: np.ndarray) -> str:
    return " ".join(f"{x:.3f},{y:.3f}" for x, y in np.asarray(points, dtype=float))


# ------------------------------------------------------------------------------- network
@dataclass(frozen=True)
class SumoNetwork:
    """A SUMO network of a layout (:func:`build_network`): the file, the routes' edge ids
    and how SUMO's lanes map onto the layout's routes.

    Attributes:
        net_file: the ``.net.xml`` (in the per-layout cache).
        directory: its folder, with the plain XML netconvert read (``.nod``, ``.edg``, ``.con``).
        routes: SUMO's edge ids of the ego's route and of the obstacle's (left, right).
        paths: the obstacle's rear-axle paths (left, right): its routes from :data:`UPSTREAM`
            before the start to :data:`EXTEND` past their end.
        along: per obstacle path, ``(s, sigma)``: the rear axle's arc length [m] along the
            path and the front bumper's arc length [m] along SUMO's lanes, measured from the
            path's start, at the same samples.
        line: ``sigma`` [m] of the stop point (the side road's lane end) on both paths.
        ego_lane: the centre line of SUMO's ego lanes end to end (the front-bumper path of the
            ego's route, :data:`UPSTREAM` before it to :data:`EXTEND` past it).
        ego_entry: arc length [m] along ``ego_lane`` where the ego's road enters the junction
            (the end of its first edge).
    """

    net_file: Path
    directory: Path
    routes: tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]
    paths: tuple[Polyline, Polyline]
    along: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    line: float
    ego_lane: Polyline
    ego_entry: float


def _cache_root() -> Path:
    """Where networks are kept: this user's cache folder, ``$XDG_CACHE_HOME/cdf_mj/sumo``
    (``~/.cache/cdf_mj/sumo`` where ``XDG_CACHE_HOME`` is unset or not absolute, as the XDG
    base directory specification has it). Not the shared temporary directory: there another
    user could make the folder first and hand this process networks of theirs."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    root = Path(base) if os.path.isabs(base) else Path.home() / ".cache"
    return root / "cdf_mj" / "sumo"


def _plain_xml(layout: Layout) -> tuple[dict[str, str], dict[str, Any]]:
    """The network's plain XML (nodes, edges, connections; netconvert's input) and what the
    driver needs to map it; ValueError (one line) for a layout SUMO's network cannot take."""
    lf_obs, lf_ego = _front_distance(layout.obstacle), _front_distance(layout.ego)
    half = float(layout.ego_lane.half[1])  # every lane as wide as the ego's
    width = 2.0 * half
    left = _extended(layout.route_left, UPSTREAM, EXTEND)
    right = _extended(layout.route_right, UPSTREAM, EXTEND)
    (sl, pl), (sr, pr) = front_path(left, lf_obs), front_path(right, lf_obs)
    # The stop point: the front bumper at the obstacle's start, on both routes.
    x0, y0, th0 = (float(v) for v in layout.obstacle_start[:3])
    stop = np.array([x0 + lf_obs * math.cos(th0), y0 + lf_obs * math.sin(th0)])
    il0, ir0 = int(np.argmin(np.hypot(*(pl - stop).T))), int(np.argmin(np.hypot(*(pr - stop).T)))
    if np.hypot(*(pl[il0] - stop)) > SAME_POINT or np.hypot(*(pr[ir0] - stop)) > SAME_POINT:
        raise ValueError("the obstacle's routes do not start at its start site (its front bumper on the stop "
                         "line): SUMO's side road cannot end there")
    if np.max(_off_line(np.vstack([pl[: il0 + 1], pr[: ir0 + 1]]), pl[0], stop)) > SAME_POINT:
        raise ValueError("the obstacle's left and right routes part before its front bumper reaches the stop "
                         "line: SUMO's turns begin at the line")
    il, ir = _exit_index(pl), _exit_index(pr)
    if il <= il0 or ir <= ir0:
        raise ValueError("an obstacle route does not turn past the stop line: SUMO needs a left and a right turn")
    ego = _extended(layout.route_ego, UPSTREAM, EXTEND)
    pe = front_path(ego, lf_ego)[1]
    ego_line = Polyline(pe)
    # The left turn joins the ego's lane: its front path from its exit on lies on the ego's.
    tail = pl[il:]
    if np.max(np.abs([ego_line.project_point(float(x), float(y))[1] for x, y in tail])) > SAME_POINT:
        raise ValueError("the obstacle's left route does not end in the ego's lane: SUMO's left turn must join it")
    sig_e = _arc(pe)
    sig_in = ego_line.project_point(*(float(c) for c in stop))[0] - half
    sig_out = ego_line.project_point(*(float(c) for c in pl[il]))[0]
    if not 0.0 < sig_in < sig_out < sig_e[-1]:
        raise ValueError("the obstacle's left turn joins the ego's lane before the side road: SUMO cannot order "
                         "the junction")
    e_in, e_out = (np.array(ego_line.point_at(v)) for v in (sig_in, sig_out))
    inside = (sig_e > sig_in) & (sig_e < sig_out)
    ego_in = np.vstack([pe[sig_e < sig_in], e_in])
    ego_mid = np.vstack([e_in, pe[inside], e_out])
    ego_out = np.vstack([e_out, pe[sig_e > sig_out]])
    # The other lane of the major road, towards the right turn's exit (so that the right
    # turn, too, is a minor movement that stops at the sign).
    rd = (pr[-1] - pr[-2]) / np.hypot(*(pr[-1] - pr[-2]))
    opp_end = pr[ir] + float(np.dot(e_out - pr[ir], rd)) * rd
    opp_start = opp_end - (UPSTREAM + EXTEND) * rd
    if float(np.dot(pr[ir] - opp_end, rd)) <= 0.0:
        raise ValueError("the obstacle's right turn leaves the junction beyond the left turn's exit: SUMO cannot "
                         "lay the major road's other lane")
    side_start = stop - UPSTREAM * np.array([math.cos(th0), math.sin(th0)])
    ends = {"side_in": (stop, stop - side_start), "ego_in": (e_in, e_in - ego_in[-2]),
            "ego_out": (e_out, ego_out[1] - e_out), "right_out": (pr[ir], pr[ir + 1] - pr[ir]),
            "opp_in": (opp_end, rd)}
    centre = np.mean([p for p, _ in ends.values()], axis=0)
    border = []
    for p, d in ends.values():
        n = np.array([-d[1], d[0]]) / np.hypot(*d)
        border += [p + half * n, p - half * n]
    border_pts = np.array(border)
    order = np.argsort(np.arctan2(border_pts[:, 1] - centre[1], border_pts[:, 0] - centre[0]))
    poly = border_pts[order]
    poly = poly[np.concatenate([[True], np.hypot(*np.diff(poly, axis=0).T) > 1e-2])]

    def turn_speed(route: Polyline) -> float:
        """SUMO's speed limit of a turn, sqrt(a R), R its mean radius [m] (arc over angle)."""
        pts = np.asarray(route.points, dtype=float)
        seg = np.diff(pts, axis=0)
        heads = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        s_w = _arc(pts)
        bends = np.flatnonzero(np.abs(np.diff(heads)) > 1e-9) + 1
        radius = (s_w[bends[-1]] - s_w[bends[0]]) / max(abs(heads[-1] - heads[0]), 1e-9) if len(bends) > 1 else 0.0
        return min(math.sqrt(TURN_LATERAL_ACCEL * radius), ROAD_SPEED) if radius > 0.0 else ROAD_SPEED

    nodes = {"J": (centre, "priority_stop"), "side": (side_start, "dead_end"), "west": (pe[0], "dead_end"),
             "east": (pe[-1], "dead_end"), "rightEnd": (pr[-1], "dead_end"), "oppStart": (opp_start, "dead_end")}
    nod = ["<nodes>"]
    for name, (p, kind) in nodes.items():
        extra = f' shape="{_shape(poly)}"' if name == "J" else ""
        nod.append(f'    <node id="{name}" x="{p[0]:.3f}" y="{p[1]:.3f}" type="{kind}"{extra}/>')
    nod.append("</nodes>")
    edges = {"side_in": ("side", "J", 1, np.vstack([side_start, stop])), "ego_in": ("west", "J", 2, ego_in),
             "ego_out": ("J", "east", 2, ego_out), "right_out": ("J", "rightEnd", 2, pr[ir:]),
             "opp_in": ("oppStart", "J", 2, np.vstack([opp_start, opp_end]))}
    edg = ["<edges>"]
    for name, (a, b, prio, pts) in edges.items():
        edg.append(f'    <edge id="{name}" from="{a}" to="{b}" priority="{prio}" numLanes="1" speed="{ROAD_SPEED}" '
                   f'width="{width:.3f}" spreadType="center" shape="{_shape(pts)}"/>')
    edg.append("</edges>")
    con = ["<connections>",
           f'    <connection from="side_in" to="ego_out" fromLane="0" toLane="0" '
           f'speed="{turn_speed(layout.route_left):.2f}" shape="{_shape(pl[il0:il + 1])}"/>',
           f'    <connection from="side_in" to="right_out" fromLane="0" toLane="0" '
           f'speed="{turn_speed(layout.route_right):.2f}" shape="{_shape(pr[ir0:ir + 1])}"/>',
           f'    <connection from="ego_in" to="ego_out" fromLane="0" toLane="0" shape="{_shape(ego_mid)}"/>',
           f'    <connection from="opp_in" to="right_out" fromLane="0" toLane="0" '
           f'shape="{_shape(np.vstack([opp_end, pr[ir]]))}"/>',
           "</connections>"]
    files = {"net.nod.xml": "\n".join(nod) + "\n", "net.edg.xml": "\n".join(edg) + "\n",
             "net.con.xml": "\n".join(con) + "\n"}
    # The obstacle's front arc length along SUMO's lanes: the path's own, from the side road's
    # start (the front path's samples before the side road's start are dropped).
    along = []
    for s, p, i0 in ((sl, pl, il0), (sr, pr, ir0)):
        sig = _arc(p)
        sig = sig - sig[i0] + UPSTREAM  # the stop point is UPSTREAM along the side road
        along.append((s, sig))
    info = {"paths": (left, right), "along": tuple(along), "line": UPSTREAM, "ego_lane": ego_line,
            "ego_entry": float(sig_in)}
    return files, info


def _layout_key(layout: Layout, sumo_version: str) -> str:
    """A hash of everything of ``layout`` the network is made of (and of the generator's
    and SUMO's versions)."""
    data = {
        "v": NETWORK_VERSION, "sumo": sumo_version,
        "routes": [np.round(r.points, 6).tolist() for r in (layout.route_ego, layout.route_left, layout.route_right)],
        "start": np.round(layout.obstacle_start, 6).tolist(), "lane": round(float(layout.ego_lane.half[1]), 6),
        "front": [round(_front_distance(c), 6) for c in (layout.ego, layout.obstacle)],
    }
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:20]


_NETWORKS: dict[int, tuple[Layout, SumoNetwork]] = {}  # per Layout object (immutable), in this process


def build_network(layout: Layout) -> SumoNetwork:
    """The SUMO network of ``layout`` (see the module docstring), from the per-layout cache
    or made by netconvert into it (a temporary file renamed into place: safe for concurrent
    workers). ImportError (one line, naming the ``sumo`` extra) without SUMO; ValueError for
    a layout SUMO's network cannot take; :class:`SumoError` when netconvert fails (its
    message)."""
    cached = _NETWORKS.get(id(layout))
    if cached is not None and cached[0] is layout:
        return cached[1]
    libsumo = _libsumo()
    files, info = _plain_xml(layout)
    key = _layout_key(layout, str(libsumo.getVersion()[1]))
    folder = _cache_root() / key
    net = folder / "net.net.xml"
    if not net.is_file():
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SumoError(f"cannot make SUMO's network cache {folder} ({exc.strerror}): set XDG_CACHE_HOME to a "
                            "folder of yours") from None
        _netconvert(files, folder)
    network = SumoNetwork(net_file=net, directory=folder,
                          routes=(("ego_in", "ego_out"), ("side_in", "ego_out"), ("side_in", "right_out")),
                          paths=info["paths"], along=info["along"], line=info["line"], ego_lane=info["ego_lane"],
                          ego_entry=info["ego_entry"])
    _NETWORKS[id(layout)] = (layout, network)
    return network


def _first_error(text: str) -> str:
    """SUMO's first error message in ``text`` on one line (an ``Error:`` line ending in a
    colon runs on into the next line), else its first line, else ''."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    for i, line in enumerate(lines):
        if line.startswith("Error"):
            return f"{line} {lines[i + 1]}" if line.endswith(":") and i + 1 < len(lines) else line
    return lines[0] if lines else ""


def _netconvert(files: Mapping[str, str], folder: Path) -> None:
    """Write the plain XML into ``folder`` and run netconvert on it; its output is renamed
    into place as ``net.net.xml`` only when complete. SumoError (one line) when it fails."""
    sumolib = require("sumolib", "sumo", FEATURE)
    binary = sumolib.checkBinary("netconvert")
    if shutil.which(binary) is None:
        raise SumoError(f"{FEATURE}: netconvert not found ({binary}); the sumo extra's eclipse-sumo brings it")
    work = Path(tempfile.mkdtemp(prefix=".build-", dir=folder))
    for name, text in files.items():
        (work / name).write_text(text, encoding="utf-8")
    out = work / "net.net.xml"
    cmd = [binary, "--node-files", "net.nod.xml", "--edge-files", "net.edg.xml", "--connection-files",
           "net.con.xml", "--output-file", out.name, "--offset.disable-normalization", "true",
           "--no-turnarounds", "true", "--junctions.join", "false", "--no-warnings", "true"]
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    if proc.returncode != 0 or not out.is_file():  # its input stays in `work`, for a look
        why = _first_error(proc.stderr + "\n" + proc.stdout) or f"exit status {proc.returncode}"
        raise SumoError(f"netconvert failed on the network in {work}: {why}")
    for name in files:
        os.replace(work / name, folder / name)
    os.replace(out, folder / "net.net.xml")  # last: readers look for this file
    shutil.rmtree(work, ignore_errors=True)


# ---------------------------------------------------------------------------- simulation
class _Simulation:
    """The process's one libsumo simulation: started once per process, loaded per episode,
    closed at exit (``atexit``, and :class:`multiprocessing.util.Finalize` for pool workers,
    which leave with ``os._exit``).

    The state is per process (:attr:`pid`): a forked child (a pool worker of a parent that
    ran SUMO episodes) inherits the parent's, and on its first load starts afresh, with a
    folder of its own and ``libsumo.start``. libsumo runs no threads of its own, so the
    child's memory holds an intact copy of the parent's simulation; ``libsumo.start`` closes
    that copy and loads anew (the same seed gives the same poses as in a fresh process,
    tests/test_sumo.py). The child never steps the copy (:meth:`owns`) and never removes the
    parent's folder (:meth:`close`).
    """

    pid: ClassVar[int] = -1  # the process the state below belongs to
    started: ClassVar[bool] = False
    owner: ClassVar[object | None] = None  # the episode that loaded it last
    folder: ClassVar[Path | None] = None  # this process's: the episodes' route files, SUMO's messages
    route: ClassVar[Path | None] = None  # the route file of the loaded episode (SUMO reads it as it runs)

    @classmethod
    def _here(cls) -> None:
        """This process's state: after a fork, the child's starts empty."""
        if cls.pid != os.getpid():
            cls.pid, cls.started, cls.owner, cls.folder, cls.route = os.getpid(), False, None, None, None

    @classmethod
    def owns(cls, owner: object) -> bool:
        """Whether ``owner``'s episode is the one loaded in this process's simulation."""
        cls._here()
        return owner is not None and cls.owner is owner

    @classmethod
    def load(cls, libsumo: ModuleType, routes: str, args: list[str], owner: object) -> None:
        """Load an episode: ``routes`` (a route file's text) into a route file of its own,
        then SUMO with ``args`` and that file; the previous episode's file is removed.
        SumoError (one line, SUMO's first error) when SUMO refuses."""
        cls._here()
        if cls.folder is None:
            cls.folder = Path(tempfile.mkdtemp(prefix="cdf_mj-sumo-episode-"))
        fd, name = tempfile.mkstemp(prefix="episode-", suffix=".rou.xml", dir=cls.folder)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(routes)
        previous, cls.route, cls.owner = cls.route, Path(name), None
        log = cls.folder / "sumo.stderr"  # SUMO's own messages of a load, read if it fails
        args = [*args, "--route-files", name]
        try:
            with _stderr_to(log):
                if cls.started:
                    libsumo.load(args)
                else:
                    libsumo.start(["sumo", *args])
                    cls.started = True
                    cls._close_at_exit(libsumo)
        except (libsumo.TraCIException, libsumo.FatalTraCIError) as exc:
            text = log.read_text(encoding="utf-8", errors="replace") if log.is_file() else ""
            why = _first_error(text) or " ".join(str(exc).split())
            raise SumoError(f"SUMO could not load the episode: {why}") from None
        finally:
            if previous is not None:  # SUMO closed the previous episode (even when this load failed)
                previous.unlink(missing_ok=True)
        cls.owner = owner

    @classmethod
    def _close_at_exit(cls, libsumo: ModuleType) -> None:
        """:meth:`close` at this process's exit, once: at the interpreter's exit, and at a
        multiprocessing worker's (whose finalizers run before its ``os._exit``)."""
        atexit.unregister(cls.close)  # one inherited from the parent, if any
        atexit.register(cls.close, libsumo)
        multiprocessing.util.Finalize(None, cls.close, args=(libsumo,), exitpriority=10)

    @classmethod
    def close(cls, libsumo: ModuleType) -> None:
        """Close this process's simulation and remove its folder; nothing in a process that
        only inherited them."""
        if cls.pid != os.getpid():
            return
        if cls.started:
            cls.started, cls.owner = False, None
            with contextlib.suppress(Exception):  # already closed: nothing to do at exit
                libsumo.close()
        if cls.folder is not None:
            shutil.rmtree(cls.folder, ignore_errors=True)
            cls.folder = cls.route = None


@contextlib.contextmanager
def _sumo_errors(libsumo: ModuleType, what: str) -> Iterator[None]:
    """libsumo's exceptions inside as :class:`SumoError`: ``what`` and SUMO's message, on one line."""
    try:
        yield
    except (libsumo.TraCIException, libsumo.FatalTraCIError) as exc:
        raise SumoError(f"{what}: {' '.join(str(exc).split())}") from None


@contextlib.contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """The process's standard error (file descriptor 2, where SUMO's C++ writes) into
    ``path`` for the duration."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(path, "wb") as sink:
            os.dup2(sink.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _libsumo() -> ModuleType:
    """libsumo, or ImportError naming the ``sumo`` extra."""
    return require("libsumo", "sumo", FEATURE)


# -------------------------------------------------------------------------------- driver
class SumoDriver:
    """The obstacle driven by Eclipse SUMO (see the module docstring); a
    :class:`~cdf_mj.scenario.drivers.WorldDriver`.

    Args:
        params: the ranges to draw from (default: :class:`SumoParams`'s).

    ValueError for parameters of another kind. Attributes after :meth:`reset`: ``mode``,
    ``params`` (the drawn values and ``seed``, SUMO's), ``start``; after each tick
    ``tracking`` [m], the largest distance so far between the MuJoCo car's rear axle and
    where SUMO's car puts it (along the path and across it, together: about 0.1 m, 0.26 m at
    most in tests/test_sumo.py's runs), and ``sumo_state``
    (SUMO's obstacle: edge id, front bumper ``x, y`` [m], speed [m/s], acceleration [m/s^2],
    waiting time [s]).
    """

    family = "sumo"
    sight: ClassVar[str] = "all"  # SUMO has no sight lines: it is handed the ego's true pose every tick
    Params: ClassVar[type[FamilyParams]] = SumoParams

    def __init__(self, params: SumoParams | None = None) -> None:
        if params is None:
            params = SumoParams()
        if not isinstance(params, SumoParams):
            raise ValueError(f"driver family 'sumo' takes SumoParams, got {type(params).__name__}")
        _libsumo()  # the missing extra is one line at once, not at the first tick
        self.ranges = params
        self.mode = WAITING
        self.params: Mapping[str, float] = MappingProxyType({})
        self.start = np.zeros(4)
        self.tracking = 0.0
        self.sumo_state: tuple[str, float, float, float, float, float] | None = None
        self._p: dict[str, float] = {}
        self._token: object | None = None
        self._pid = -1  # the process that loaded this episode

    @property
    def looking(self) -> bool:
        """Always: SUMO's junction and car-following models see every car on every step."""
        return True

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        """Start an episode: the network of ``layout`` (built or cached), ``intent``
        (:class:`~cdf_mj.model.modes.Intent` int: 0 left, 1 right), this episode's parameters
        and SUMO's seed drawn from ``rng``. SUMO itself loads on the first :meth:`control`
        (which gives the tick). ValueError for another intent."""
        if int(intent) not in (LEFT, RIGHT):
            raise ValueError(f"intent must be {LEFT} (left) or {RIGHT} (right), got {intent!r}")
        self._net = net = build_network(layout)
        p = self.ranges.draw(rng)
        p["seed"] = float(rng.integers(0, 2**31 - 1))
        car = layout.obstacle
        p["accel"] = min(p["accel"], car.max_accel)
        p["decel"] = min(p["decel"], car.max_brake)
        self._p = p
        self.params = MappingProxyType(dict(p))
        self._layout, self._intent = layout, int(intent)
        self._path = net.paths[self._intent]
        self._s_of, self._sig_of = net.along[self._intent]
        s_start = self._path.project_point(*(float(c) for c in layout.obstacle_start[:2]))[0]
        d = p["approach_distance"]
        x0, y0 = self._path.point_at(s_start - d).tolist()
        self.start = np.array([x0, y0, float(layout.obstacle_start[2]), p["approach_speed"]])
        self._s_commit = self._path.project_point(*(float(c) for c in layout.commit))[0]
        self._wheelbase, self._max_steer = car.wheelbase, car.max_steer
        self._max_brake, self._max_accel = car.max_brake, car.max_accel
        self._ego_front = _front_distance(layout.ego)
        self.mode = WAITING
        self.tracking = 0.0
        self.sumo_state = None
        self._token = None  # SUMO loads at the first tick
        self._dt = 0.0
        self._ego_in = False
        self._s_ref = float(np.interp(net.line - d, self._sig_of, self._s_of))  # where SUMO puts the rear axle
        self._v_ref = p["approach_speed"]

    # ------------------------------------------------------------------ the tick
    def control(self, t: float, pose: np.ndarray, ego: np.ndarray | None, dt: float) -> tuple[float, float]:
        """Its controls ``(acceleration m/s^2, steering rad)`` for the tick from ``t`` [s],
        from its own pose ``[x, y, theta, v]`` and the ego's true pose (None: SUMO carries
        its ego on at the speed it was last given), within the car's limits; one SUMO step
        of ``dt`` [s]; updates :attr:`mode`. RuntimeError before :meth:`reset`, when
        another SUMO episode has loaded this process's simulation since, or in a process
        forked after the episode loaded; ValueError for a ``dt`` other than the episode's
        first; :class:`SumoError` when SUMO fails (every libsumo error, on one line)."""
        if not self._p:
            raise RuntimeError("call reset(layout, intent, rng) before control()")
        libsumo = _libsumo()
        if self._token is None:
            self._load(libsumo, ego, dt)
        elif self._pid != os.getpid():
            raise RuntimeError(f"this SUMO episode was loaded in process {self._pid}, not this one ({os.getpid()}): "
                               "reset() the driver in the process that runs it")
        elif not _Simulation.owns(self._token):
            raise RuntimeError("another SUMO episode has loaded this process's one SUMO simulation since this one "
                               "started: run one SUMO world at a time per process")
        elif abs(dt - self._dt) > 1e-9:
            raise ValueError(f"dt={dt} s: this episode's SUMO steps {self._dt} s")
        if ego is not None:
            self._place_ego(libsumo, ego, dt)
        with _sumo_errors(libsumo, f"SUMO failed to step at t={t:.1f} s"):
            libsumo.simulationStep()
        return self._follow(libsumo, pose, dt)

    def _load(self, libsumo: ModuleType, ego: np.ndarray | None, dt: float) -> None:
        """Load this episode into the process's SUMO: the network, the two cars' types and
        routes (the obstacle at its start; the ego at ``ego``, if given), one step to insert
        them."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt={dt!r} must be a positive number of seconds")
        self._dt = dt
        if not self._net.net_file.is_file():  # the cache was cleared under a running process: build it again
            _NETWORKS.pop(id(self._layout), None)
            self._net = build_network(self._layout)
        token = object()
        args = ["--net-file", str(self._net.net_file), "--step-length", repr(dt), "--seed", str(int(self._p["seed"])),
                *_SUMO_OPTIONS]
        _Simulation.load(libsumo, self._routes(ego), args, token)
        self._token, self._pid = token, os.getpid()
        with _sumo_errors(libsumo, "SUMO failed to insert the cars at t=0.0 s"):
            libsumo.simulationStep()  # inserts both cars where they start: SUMO's state of t = 0
        if OBSTACLE not in libsumo.vehicle.getIDList():
            raise SumoError("SUMO did not insert the obstacle at its start")
        if ego is not None:
            self._ego_added(libsumo)

    def _routes(self, ego: np.ndarray | None) -> str:
        """This episode's route file: the two vTypes, the routes, the cars."""
        p, layout = self._p, self._layout
        obs, car = layout.obstacle, layout.ego
        jm = ("impatience", "jmIgnoreFoeProb", "jmIgnoreFoeSpeed", "jmTimegapMinor", "jmStopSignWait", "sigma",
              "speedFactor", "accel", "decel")
        attrs = " ".join(f"{k}={quoteattr(repr(float(p[k])))}" for k in jm)
        net = self._net
        lines = [
            "<routes>",
            f'    <vType id="obstacle" vClass="passenger" length="{obs.length:.3f}" width="{obs.width:.3f}" '
            f'emergencyDecel="{obs.max_brake:.3f}" speedDev="0" {attrs}/>',
            f'    <vType id="ego" vClass="passenger" length="{car.length:.3f}" width="{car.width:.3f}" '
            f'accel="{car.max_accel:.3f}" decel="{EGO_DECEL:.3f}" emergencyDecel="{car.max_brake:.3f}" '
            'sigma="0" speedFactor="1" speedDev="0"/>',
            f'    <route id="ego" edges="{" ".join(net.routes[0])}"/>',
            f'    <route id="obstacle" edges="{" ".join(net.routes[1 + self._intent])}"/>',
        ]
        depart = net.line - p["approach_distance"]
        cars = [(0, f'    <vehicle id="{OBSTACLE}" type="obstacle" route="obstacle" depart="0" departLane="0" '
                    f'departPos="{depart:.3f}" departSpeed="{p["approach_speed"]:.3f}"/>')]
        if ego is not None:
            pos, speed = self._ego_depart(ego)
            cars.append((1, f'    <vehicle id="{EGO}" type="ego" route="ego" depart="0" departLane="0" '
                            f'departPos="{pos:.3f}" departSpeed="{speed:.3f}"/>'))
        return "\n".join([*lines, *(c for _, c in sorted(cars)), "</routes>"]) + "\n"

    def _ego_depart(self, ego: np.ndarray) -> tuple[float, float]:
        """Where the ego's front bumper is along SUMO's first ego edge [m] (within it), and its
        speed [m/s], at most the road's limit (SUMO refuses a car that enters faster; the next
        tick's ``setSpeed`` gives it its own)."""
        x, y, th, v = (float(c) for c in ego)
        fx, fy = x + self._ego_front * math.cos(th), y + self._ego_front * math.sin(th)
        s = self._net.ego_lane.project_point(fx, fy)[0]
        return min(max(s, 0.1), self._net.ego_entry - 0.1), min(max(v, 0.0), ROAD_SPEED)

    def _ego_added(self, libsumo: ModuleType) -> None:
        """Hand the ego's SUMO car to the world: no checks of SUMO's own on its speed, no lane changes."""
        with _sumo_errors(libsumo, "SUMO cannot hand the ego to the world"):
            libsumo.vehicle.setSpeedMode(EGO, 0)
            libsumo.vehicle.setLaneChangeMode(EGO, 0)
        self._ego_in = True

    def _place_ego(self, libsumo: ModuleType, ego: np.ndarray, dt: float) -> None:
        """The ego's pose carried one tick ahead at its speed (SUMO's state after this step
        is that of ``t + dt``), written into SUMO as its front bumper's position and heading,
        and its speed."""
        x, y, th, v = (float(c) for c in ego)
        c, s = math.cos(th), math.sin(th)
        run = max(v, 0.0) * dt + self._ego_front
        if not self._ego_in:  # first seen on this tick: it joins SUMO on its road
            pos, speed = self._ego_depart(ego)
            with _sumo_errors(libsumo, f"SUMO cannot add the ego at x={x:.1f} m, y={y:.1f} m, v={v:.1f} m/s"):
                libsumo.vehicle.add(EGO, "ego", typeID="ego", depart="now", departPos=f"{pos:.3f}",
                                    departSpeed=f"{speed:.3f}")
            self._ego_added(libsumo)
        with _sumo_errors(libsumo, f"SUMO cannot place the ego at x={x:.1f} m, y={y:.1f} m"):  # off SUMO's roads
            libsumo.vehicle.moveToXY(EGO, "", 0, x + run * c, y + run * s, 90.0 - math.degrees(th), 1)
            libsumo.vehicle.setSpeed(EGO, max(v, 0.0))

    def _follow(self, libsumo: ModuleType, pose: np.ndarray, dt: float) -> tuple[float, float]:
        """The MuJoCo car's controls towards SUMO's car after this step, and the mode."""
        x, y, th, v = (float(c) for c in pose)
        s, lateral = self._path.project_point(x, y)
        self.tracking = max(self.tracking, math.hypot(s - self._s_ref, lateral))
        veh = libsumo.vehicle
        if OBSTACLE in libsumo.vehicle.getIDList():
            road = veh.getRoadID(OBSTACLE)
            fx, fy = veh.getPosition(OBSTACLE)
            v_ref, a_ref, wait = veh.getSpeed(OBSTACLE), veh.getAcceleration(OBSTACLE), veh.getWaitingTime(OBSTACLE)
            sig = self._net.line - self._p["approach_distance"] + veh.getDistance(OBSTACLE)
            self.sumo_state = (road, float(fx), float(fy), float(v_ref), float(a_ref), float(wait))
            self._mode(road, v_ref, a_ref, wait, sig)
        else:  # it has driven off SUMO's network: on at its last speed
            v_ref, a_ref, sig = self._v_ref, 0.0, math.nan
            self.mode = COMMITTED
        s_prev = self._s_ref
        if math.isfinite(sig):  # SUMO's front bumper on its path -> the rear axle on the route
            self._s_ref = float(np.interp(sig, self._sig_of, self._s_of))
            v_ref *= self._rear_rate(sig)
        else:
            self._s_ref = s_prev + v_ref * dt
        self._v_ref = v_ref
        # Speed servo: SUMO's speed after this step (its rear axle's), corrected by the rear
        # axle's position error at the start of the step (MuJoCo's car at t against SUMO's at t).
        v_cmd = max(v_ref + (s_prev - s) / POSITION_TIME, 0.0)
        accel = (v_cmd - v) / dt
        if v_cmd <= 0.0 and v < AT_REST:
            accel = min(accel, -HOLD_BRAKE)
        accel = min(max(accel, -self._max_brake), self._max_accel)
        return accel, self._steer(x, y, th, v, s)

    def _rear_rate(self, sig: float) -> float:
        """d(rear axle's arc length)/d(front bumper's) at the front's arc length ``sig`` [m]:
        below 1 in a turn, where the front bumper swings wide; 1 on the straights."""
        sig_of, s_of = self._sig_of, self._s_of
        k = min(max(int(np.searchsorted(sig_of, sig, side="right")) - 1, 0), len(sig_of) - 2)
        return float((s_of[k + 1] - s_of[k]) / (sig_of[k + 1] - sig_of[k]))

    def _mode(self, road: str, v: float, a: float, wait: float, sig: float) -> None:
        """The mode from SUMO's state (see the module docstring)."""
        if self.mode == COMMITTED or float(np.interp(sig, self._sig_of, self._s_of)) >= self._s_commit:
            self.mode = COMMITTED
        elif road == "side_in":
            held = v < AT_REST and wait > self._p["jmStopSignWait"] + self._dt
            self.mode = YIELDING if held else WAITING
        elif road.startswith(":"):  # in the junction, short of its commit point
            self.mode = YIELDING if a < -YIELD_DECEL or (v < AT_REST and a <= 0.0) else GOING
        else:
            self.mode = COMMITTED

    def _steer(self, x: float, y: float, th: float, v: float, s: float) -> float:
        """Pure pursuit on the route: the steering [rad] that points the rear axle at the
        path's point a look-ahead ahead of arc length ``s``, within the car's limit."""
        tx, ty = self._path.point_at(s + LOOKAHEAD + LOOKAHEAD_GAIN * max(v, 0.0)).tolist()
        dx, dy = tx - x, ty - y
        lateral = dy * math.cos(th) - dx * math.sin(th)
        steer = math.atan(2.0 * self._wheelbase * lateral / max(dx * dx + dy * dy, 1e-9))
        return min(max(steer, -self._max_steer), self._max_steer)
