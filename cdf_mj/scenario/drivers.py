"""Obstacle drivers the filter was not derived from: the world's side only.

The filter's driver model (:mod:`cdf_mj.model.driver`) is a compiled state machine with
sparse random looks, a dead-reckoned belief, a critical gap and a clear distance. The
drivers here are written apart from it (this module imports neither it, nor its kernels,
nor the filter; only the shared vocabulary of :mod:`cdf_mj.model.modes` and of the road,
:mod:`cdf_mj.model.road`) from traffic-engineering models, so that a world driven by them
tests the filter on behaviour it was not built to invert:

================ ========================================================================
gap-acceptance   stops at the line, waits a dwell, creeps forward while it waits, looks
                 continuously with a reaction time, accepts a gap longer than its
                 critical gap, speeds up by the intelligent driver model (IDM), aborts
                 (brakes) if the gap closes before its commit distance
rolling-stop     never comes to rest: slows to a rolling speed at the line and decides
                 there, accelerating away or braking hard
aggressive       gap acceptance with short gaps (2-3.5 s), short reaction, strong
                 acceleration, short dwell
off-route        gap acceptance on a turn path of its own: the scene's route shifted
                 sideways by up to about a metre (cutting the corner or swinging wide)
================ ========================================================================

Four more families, the junction-crash behaviours that cut off (``looked-but-failed``,
``misjudged-speed``, ``distracted``, ``creeper``), live in :mod:`cdf_mj.scenario.crash_drivers`
on the machinery here; :data:`FAMILIES` names them all and loads that module when one of
them is first asked for. ``sumo`` (:data:`OPTIONAL_FAMILIES`) is a co-simulated driver of
an optional extra, imported only by :func:`make_driver`. docs/DRIVERS.md lists every family,
its ranges and their sources.

Each family has a frozen dataclass of ``(low, high)`` ranges (:class:`GapAcceptanceParams`,
:class:`RollingStopParams`, :class:`AggressiveParams`, :class:`OffRouteParams`), drawn
uniformly per episode from the episode's generator in ``reset``; every family has a
``path_offset`` (any family can leave the route; a right-turner only ever cuts its corner,
as a wide arc would reach into the ego's lane) and an approach (a start upstream of the
line, moving). The world places the car at ``driver.start`` and calls ``control`` once a
tick::

    driver = make_driver("gap-acceptance")          # or make_driver(name, GapAcceptanceParams(...))
    driver.reset(layout, intent=0, rng=rng)         # draws this episode's parameters
    scene.reset(ego=..., obstacle=driver.start)     # [x, y, theta, v]
    accel, steer = driver.control(t, pose, ego_if_in_sight_else_None, dt)
    driver.mode, driver.params                      # for records (Mode ints, drawn floats)

What ``ego`` the world hands over each tick is the family's ``sight`` (see :class:`WorldDriver`):
the ego's pose while it is in the driver's line of sight (``"line"``, the default), that and
the visible share of the ego in :attr:`ego_share` (``"share"``), or the ego's pose always
(``"all"``: a co-simulated driver that decides itself what it perceives).

Their IDM is :func:`cdf_mj.model.road.idm`'s full form (free-road term, ``s_star="dynamic"``).

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``. "Progress" is the arc length [m] of the rear axle along the driver's
own path past its stop position (``layout.obstacle_start``: the front bumper on the stop
line); negative on the approach.
"""

from __future__ import annotations

import importlib
import math
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from cdf_mj.model.geometry import Polyline
from cdf_mj.model.layout import Layout
from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING, YIELDING
from cdf_mj.model.road import idm

__all__ = ["FAMILIES", "OPTIONAL_FAMILIES", "SIGHTS", "AggressiveDriver", "AggressiveParams", "FamilyParams",
           "GapAcceptanceDriver", "GapAcceptanceParams", "OffRouteDriver", "OffRouteParams", "RollingStopDriver",
           "RollingStopParams", "WorldDriver", "make_driver", "offset_path"]

IDM_HEADWAY = 1.0  # [s] the IDM's time headway T to a virtual standing car (city traffic: 1.0-1.5 s)
IDM_JAM = 1.0  # [m] jam distance s0; a stop target is a virtual standing car s0 beyond it
LOOKAHEAD = 2.0  # [m] pure pursuit look-ahead at standstill (short: the turns have 6-7 m radii)
LOOKAHEAD_GAIN = 0.2  # [s] growth of the look-ahead with speed
AT_REST = 0.2  # [m/s] below this a car is at rest (for the dwell and the holds)
AT_TARGET = 0.1  # [m] within this of a stop target, a car at rest has arrived
PULL_UP_SPEED = 3.0  # [m/s] least desired speed up to the line (for an approach drawn at rest)
PATH_STEP = 0.25  # [m] sampling of an offset path
MOVING_EGO = 0.1  # [m/s] a perceived ego slower than this never arrives (its time to arrive is infinite)

#: What a family is shown of the ego each tick (its ``sight``): ``"line"`` the ego's true pose
#: while in its line of sight, else None; ``"share"`` the same and, before ``control``, the share
#: of the ego's sight points it sees in ``ego_share``; ``"all"`` the ego's true pose every tick.
SIGHTS = ("line", "share", "all")


def span(default: tuple[float, float], low: float, high: float, unit: str, why: str) -> Any:
    """A range field ``(low, high)`` of a family's parameters, its bounds ``[low, high]``
    in ``unit``, and the one-line reason for its default."""
    return field(default=default, metadata={"bounds": (low, high), "unit": unit, "why": why})


@dataclass(frozen=True)
class FamilyParams:
    """Base of a family's parameters: every field a ``(low, high)`` range drawn uniformly
    per episode. ValueError (one message naming every bad field and its bounds) for a
    range that is not two finite numbers with ``bound_low <= low <= high <= bound_high``."""

    def __post_init__(self) -> None:
        problems: list[str] = []
        for f in fields(self):
            lo_b, hi_b = f.metadata["bounds"]
            value = getattr(self, f.name)
            try:
                low, high = (float(v) for v in value)
            except (TypeError, ValueError):
                low = high = math.nan
            if not (math.isfinite(low) and math.isfinite(high) and lo_b <= low <= high <= hi_b):
                problems.append(f"{f.name}={value!r} must be (low, high), finite, with "
                                f"{lo_b:g} <= low <= high <= {hi_b:g} [{f.metadata['unit']}]")
            else:
                object.__setattr__(self, f.name, (low, high))
        if not problems:
            problems = self._conflicts()
        if problems:
            raise ValueError(f"{type(self).__name__}: {'; '.join(problems)}")

    def _conflicts(self) -> list[str]:
        """Problems between fields (each field already valid on its own)."""
        return []

    def draw(self, rng: np.random.Generator) -> dict[str, float]:
        """One episode's values: each field uniform in its range, in field order (the same
        generator state gives the same values)."""
        return {f.name: float(rng.uniform(*getattr(self, f.name))) for f in fields(self)}


@dataclass(frozen=True)
class _CommonParams(FamilyParams):
    """Ranges every family draws (units in brackets; the reasons for the defaults beside)."""

    reaction_time: tuple[float, float] = span(
        (0.5, 1.5), 0.0, 5.0, "s", "perception-reaction times of alert drivers at junctions: 0.5-1.5 s")
    critical_gap: tuple[float, float] = span(
        (6.0, 7.5), 0.1, 30.0, "s", "HCM base critical headway, minor-street left turn: 7.1 s (two-lane major road)")
    min_distance: tuple[float, float] = span(
        (8.0, 15.0), 0.0, 200.0, "m", "a car this near the conflict point is 'here' whatever its speed")
    commit_distance: tuple[float, float] = span(
        (1.5, 4.0), 0.0, 50.0, "m", "front past the main road's edge to near its centre line: stopping "
                                    "there would block the crossed lane")
    turn_speed: tuple[float, float] = span(
        (4.5, 8.0), 0.5, 30.0, "m/s", "left-turn speeds at urban junctions: 15-30 km/h")
    max_accel: tuple[float, float] = span(
        (1.0, 2.0), 0.1, 10.0, "m/s^2", "IDM a: 0.73-1.0 (Treiber et al.); pulling out from a stop up to 2")
    comfort_brake: tuple[float, float] = span(
        (1.5, 3.0), 0.1, 10.0, "m/s^2", "IDM b: 1.67 (Treiber et al. 2000); 2-3 when stopping for a junction")
    path_offset: tuple[float, float] = span(
        (0.0, 0.0), -3.0, 3.0, "m", "on the scene's route (> 0 cuts the corner, < 0 swings wide)")
    approach_distance: tuple[float, float] = span(
        (0.0, 0.0), 0.0, 200.0, "m", "starts at the line, as the world's driver does")
    approach_speed: tuple[float, float] = span(
        (0.0, 0.0), 0.0, 30.0, "m/s", "starts at rest")


@dataclass(frozen=True)
class GapAcceptanceParams(_CommonParams):
    """Gap acceptance (see the module docstring): the common ranges and the stop's."""

    dwell: tuple[float, float] = span(
        (1.0, 3.0), 0.0, 60.0, "s", "a full stop at a stop sign lasts about 1-3 s before a driver moves")
    creep_distance: tuple[float, float] = span(
        (0.3, 1.0), 0.0, 10.0, "m", "nosing past the line to see along the main road, short of the lane")
    creep_speed: tuple[float, float] = span(
        (0.5, 1.5), 0.1, 5.0, "m/s", "walking pace")

    def _conflicts(self) -> list[str]:
        if self.creep_distance[1] > self.commit_distance[0]:
            return [f"creep_distance={self.creep_distance} must end at or before commit_distance="
                    f"{self.commit_distance} starts [m]: a creeping driver has not committed"]
        return []


@dataclass(frozen=True)
class AggressiveParams(GapAcceptanceParams):
    """An aggressive gap-acceptance driver: short gaps, quick, strong."""

    reaction_time: tuple[float, float] = span(
        (0.3, 0.7), 0.0, 5.0, "s", "an alert, anticipating driver")
    critical_gap: tuple[float, float] = span(
        (2.0, 3.5), 0.1, 30.0, "s", "the shortest gaps accepted in gap-acceptance studies: 2-3.5 s")
    min_distance: tuple[float, float] = span(
        (4.0, 8.0), 0.0, 200.0, "m", "squeezes in ahead of a near car")
    commit_distance: tuple[float, float] = span(
        (1.2, 2.5), 0.0, 50.0, "m", "commits as soon as its nose is out")
    turn_speed: tuple[float, float] = span(
        (7.0, 10.0), 0.5, 30.0, "m/s", "a fast turn: 25-36 km/h")
    max_accel: tuple[float, float] = span(
        (2.0, 3.0), 0.1, 10.0, "m/s^2", "hard pull-out: near a passenger car's 3 m/s^2 limit")
    comfort_brake: tuple[float, float] = span(
        (2.5, 3.5), 0.1, 10.0, "m/s^2", "brakes late and firmly")
    dwell: tuple[float, float] = span(
        (0.0, 0.8), 0.0, 60.0, "s", "barely stops")
    creep_distance: tuple[float, float] = span(
        (0.5, 1.2), 0.0, 10.0, "m", "noses further out")
    creep_speed: tuple[float, float] = span(
        (1.0, 2.0), 0.1, 5.0, "m/s", "brisk creep")


@dataclass(frozen=True)
class OffRouteParams(GapAcceptanceParams):
    """A gap-acceptance driver whose turn path is not the scene's route."""

    path_offset: tuple[float, float] = span(
        (-1.0, 1.0), -3.0, 3.0, "m", "drivers cut the corner or swing wide by up to about a metre")


@dataclass(frozen=True)
class RollingStopParams(_CommonParams):
    """A rolling stop: comes down the side road and never comes to rest at the line."""

    critical_gap: tuple[float, float] = span(
        (5.0, 7.0), 0.1, 30.0, "s", "a little below the HCM 7.1 s: it judges on the move")
    approach_distance: tuple[float, float] = span(
        (10.0, 20.0), 0.0, 200.0, "m", "in sight of the line, a few car lengths up the side road")
    approach_speed: tuple[float, float] = span(
        (5.0, 8.0), 0.0, 30.0, "m/s", "a side street at 20-30 km/h")
    rolling_speed: tuple[float, float] = span(
        (1.5, 4.0), 0.5, 15.0, "m/s", "rolling stops are made at about 5-15 km/h")
    hard_brake: tuple[float, float] = span(
        (3.5, 5.0), 0.5, 10.0, "m/s^2", "firm to full braking (clipped to the car's maximum)")


def offset_path(route: Polyline, offset: float) -> Polyline:
    """``route`` shifted sideways through its turn: by ``offset`` [m] towards the inside of
    the turn (> 0 cuts the corner, < 0 swings wide), a half-sine bump over the arc length
    between its first and last bending waypoints (at least 4 m long), none on the straights.
    The route itself for offset 0 or a route without a bend."""
    pts = np.asarray(route.points, dtype=float)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    s_w = np.concatenate([[0.0], np.cumsum(lengths)])
    heads = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    bends = np.flatnonzero(np.abs(np.diff(heads)) > 1e-6) + 1  # interior waypoints where it turns
    if offset == 0.0 or len(bends) == 0:
        return route
    turn = float(heads[-1] - heads[0])
    side = 1.0 if turn >= 0.0 else -1.0  # the inside of a left (counter-clockwise) turn is the left
    s_a, s_b = float(s_w[bends[0]]), float(s_w[bends[-1]])
    half = max((s_b - s_a) / 2.0, 2.0)
    mid = (s_a + s_b) / 2.0
    s_a, s_b = max(mid - half, 0.0), min(mid + half, route.length)
    s = np.union1d(s_w, np.arange(s_a, s_b, PATH_STEP))
    wh = np.concatenate([[heads[0]], (heads[:-1] + heads[1:]) / 2.0, [heads[-1]]])  # heading at waypoints
    h = np.interp(s, s_w, wh)
    bump = np.where((s > s_a) & (s < s_b), np.sin(np.pi * (s - s_a) / (s_b - s_a)), 0.0)
    lateral = side * offset * bump
    out = route.point_at(s) + lateral[:, None] * np.stack([-np.sin(h), np.cos(h)], axis=-1)
    keep = np.concatenate([[True], np.hypot(*np.diff(out, axis=0).T) > 1e-6])
    return Polyline(out[keep])


@runtime_checkable
class WorldDriver(Protocol):
    """What the world calls (see the module docstring): ``reset`` once per episode,
    ``control`` once per tick; ``mode``, ``params`` and ``start`` for the world and records.

    Optional, read by the world's obstacle agent
    (:class:`~cdf_mj.scenario.obstacle_agent.ObstacleAgent`) where a family has it:

    ``sight`` (one of :data:`SIGHTS`; ``"line"`` where absent) says what ``control`` is handed
    as ``ego``. ``"line"``: on a tick where the driver is :attr:`looking`, the ego's true pose
    if its eye has a line of sight to any of the ego's sight points (MuJoCo rays past the
    buildings), else None; never on other ticks. ``"share"``: the same, and before
    ``control`` the agent sets the driver's ``ego_share`` to the share in [0, 1] of the ego's
    five sight points its eye sees (:func:`cdf_mj.sim.visibility.visible_share`; 0 on ticks it
    does not look). ``"all"``: the ego's true pose on every tick, whatever the sight lines and
    :attr:`looking`: a co-simulated driver that decides itself what it perceives.
    """

    family: str
    mode: int  # a cdf_mj.model.modes.Mode int: 0 waiting, 1 going, 2 yielding, 3 committed
    params: Mapping[str, float]  # this episode's drawn values
    start: np.ndarray  # (4,) where the world places the car at t = 0: [x m, y m, theta rad, v m/s]

    @property
    def looking(self) -> bool:
        """Whether it looks for the ego on this tick (the world casts its line of sight only then)."""

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None: ...

    def control(self, t: float, pose: np.ndarray, ego: np.ndarray | None, dt: float) -> tuple[float, float]: ...


class _Driver:
    """Shared machinery: the path, perception with a reaction time, gap acceptance, pure
    pursuit and the IDM. Subclasses give ``family``, ``Params`` and :meth:`_accel`."""

    family: str  # set per class (an instance attribute to the protocol)
    Params: ClassVar[type[FamilyParams]]
    # Draws of ``params`` beside the ranges of ``Params`` (each a float, e.g. 1 or 0 for a yes/no draw)
    extra_draws: ClassVar[tuple[str, ...]] = ()
    accepts: ClassVar[type[FamilyParams]]
    sight: ClassVar[str] = "line"  # what the world shows it of the ego (SIGHTS; see WorldDriver)

    def __init__(self, params: FamilyParams | None = None) -> None:
        if params is None:
            params = self.Params()
        if not isinstance(params, self.accepts):
            raise ValueError(f"driver family {self.family!r} takes {self.accepts.__name__}, "
                             f"got {type(params).__name__}")
        self.ranges = params
        self.mode = WAITING
        self.params: Mapping[str, float] = MappingProxyType({})
        self.start = np.zeros(4)
        self._p: dict[str, float] = {}
        self._crosses = False

    @property
    def looking(self) -> bool:
        """Whether the ego's pose can still change what it does (a left-turner not yet
        committed): the world may skip its line-of-sight test otherwise."""
        return self._crosses and self.mode != COMMITTED

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        """Start an episode at ``layout`` with ``intent`` (0 left: crossing; 1 right): draw
        this episode's parameters from ``rng`` (the same draws whatever the intent) and
        set :attr:`start`. ValueError for another intent."""
        if intent not in (LEFT, RIGHT):
            raise ValueError(f"intent={intent!r} must be 0 (left, crossing) or 1 (right)")
        self._p = p = self.ranges.draw(rng)
        self.params = MappingProxyType(dict(p))
        # A right-turner swinging wide would reach into the ego's lane, which the scenario rules
        # out (the filter and every planner take it for impossible): it only cuts its corner.
        offset = p["path_offset"] if intent == LEFT else max(p["path_offset"], 0.0)
        route = offset_path(layout.obstacle_routes[int(intent)], offset)
        x0, y0, th0, _ = (float(v) for v in layout.obstacle_start)
        d = p["approach_distance"]
        sx, sy = x0 - d * math.cos(th0), y0 - d * math.sin(th0)
        if d > 0.0 and math.dist((sx, sy), route.points[0]) > 1e-6:
            route = Polyline(np.vstack([[sx, sy], route.points]))
        self._path = route
        self._s_line = route.project_point(x0, y0)[0]
        self.start = np.array([sx, sy, th0, p["approach_speed"]])
        car, ego = layout.obstacle, layout.ego
        self._wheelbase, self._max_steer = car.wheelbase, car.max_steer
        self._max_brake, self._max_accel = car.max_brake, car.max_accel
        self._ego_front = float(ego.hull_offset[0] + ego.hull_half[0])  # rear axle to front bumper [m]
        self._ego_rear = float(ego.hull_half[0] - ego.hull_offset[0])  # rear axle to rear bumper [m]
        self._route_ego = layout.route_ego
        self._s_conflict = layout.route_ego.project_point(*(float(c) for c in layout.conflict))[0]
        self._crosses = int(intent) == LEFT
        self._seen: deque[tuple[float, float, float, float, float]] = deque()
        self.mode = WAITING
        self._rest_since: float | None = None

    def control(self, t: float, pose: np.ndarray, ego: np.ndarray | None, dt: float) -> tuple[float, float]:
        """Its controls ``(acceleration m/s^2, steering rad)`` at time ``t`` [s] from its own
        pose ``[x, y, theta, v]`` and the ego's true pose when it is in its line of sight
        this tick (else None), within the car's limits; updates :attr:`mode`. ``dt`` [s]
        is the tick (the drivers are timed by ``t``). RuntimeError before :meth:`reset`."""
        if not self._p:
            raise RuntimeError("call reset(layout, intent, rng) before control()")
        x, y, th, v = (float(c) for c in pose)
        if ego is not None:
            ex, ey, eth, ev = (float(c) for c in ego)
            self._seen.append((t, ex, ey, eth, ev))
        s, _ = self._path.project_point(x, y)
        ok = self._gap_ok(self._perceived(t))
        accel = self._accel(t, s - self._s_line, v, ok)
        return min(max(accel, -self._max_brake), self._max_accel), self._steer(x, y, th, v, s)

    # ------------------------------------------------------------------ parts
    def _perceived(self, t: float) -> tuple[float, float, float] | None:
        """The ego as it perceives it at ``t``: where it was ``reaction_time`` ago, from the
        last sighting at or before then carried on at its speed and heading; ``(x, y, v)``,
        or None before its first sighting has reached it."""
        t_p = t - self._p["reaction_time"] + 1e-9
        seen = self._seen
        while len(seen) >= 2 and seen[1][0] <= t_p:
            seen.popleft()
        if not seen or seen[0][0] > t_p:
            return None
        ts, ex, ey, eth, ev = seen[0]
        run = max(ev, 0.0) * (t_p - ts)
        return ex + run * math.cos(eth), ey + run * math.sin(eth), ev

    def _gap_ok(self, ego: tuple[float, float, float] | None) -> bool:
        """Whether it accepts the gap: a right-turner always (it crosses no lane of the ego);
        a left-turner when it perceives no ego, the ego's rear bumper is past the conflict
        point, or the ego's front is further than ``min_distance`` from it and more than
        ``critical_gap`` away in time at its perceived speed."""
        if not self._crosses or ego is None:
            return True
        ex, ey, ev = ego
        s_ego, _ = self._route_ego.project_point(ex, ey)
        if s_ego - self._ego_rear > self._s_conflict:
            return True
        ahead = self._s_conflict - (s_ego + self._ego_front)
        if ahead <= self._p["min_distance"]:
            return False
        return ev < MOVING_EGO or ahead > self._p["critical_gap"] * ev

    def _steer(self, x: float, y: float, th: float, v: float, s: float) -> float:
        """Pure pursuit: the steering [rad] that points the rear axle at its path's point a
        look-ahead ahead of arc length ``s``, within the car's limit."""
        tx, ty = self._path.point_at(s + LOOKAHEAD + LOOKAHEAD_GAIN * max(v, 0.0)).tolist()
        dx, dy = tx - x, ty - y
        lateral = dy * math.cos(th) - dx * math.sin(th)
        steer = math.atan(2.0 * self._wheelbase * lateral / max(dx * dx + dy * dy, 1e-9))
        return min(max(steer, -self._max_steer), self._max_steer)

    def _hold(self) -> float:
        """Braking that keeps a car at rest (the actuators do not reverse)."""
        return -self._p["comfort_brake"]

    def _idm(self, v: float, v0: float, gap: float = math.inf) -> float:
        """The full IDM (:func:`cdf_mj.model.road.idm`) at speed ``v`` towards desired speed
        ``v0`` [m/s], behind a virtual standing car ``gap`` [m] ahead (``inf``: free road),
        with this episode's maximum acceleration and comfortable deceleration."""
        return idm(v, 0.0, gap, a_max=self._p["max_accel"], b=self._p["comfort_brake"], time_gap=IDM_HEADWAY,
                   min_gap=IDM_JAM, v0=v0, s_star="dynamic", gap_floor=0.05)

    def _stop_at(self, target: float, x: float, v: float, v0: float) -> float:
        """Towards a stop with the rear axle at progress ``target`` [m]: the IDM behind a
        virtual standing car there (``s0`` beyond it); a hold once arrived."""
        if target - x <= AT_TARGET and v < AT_REST:
            return self._hold()
        return self._idm(v, v0, target - x + IDM_JAM)

    def _leave(self, x: float, ok: bool) -> None:
        """The mode once it has left its line: committed past ``commit_distance``, else
        going while it accepts the gap and yielding while it does not."""
        if self.mode == COMMITTED or x >= self._p["commit_distance"]:
            self.mode = COMMITTED
        else:
            self.mode = GOING if ok else YIELDING

    def _accel(self, t: float, x: float, v: float, ok: bool) -> float:  # pragma: no cover - abstract
        raise NotImplementedError


class GapAcceptanceDriver(_Driver):
    """Comes to rest at the line (approaching it, if it starts upstream, by the IDM behind a
    virtual standing car on the line), waits ``dwell`` (at least its reaction time: it has
    looked since it stopped), then goes once it accepts the gap; while it does not, creeps
    ``creep_distance`` at ``creep_speed`` and waits there. Going:
    the IDM towards ``turn_speed``; an abort (``v^2 / 2d`` braking to stop before the commit
    distance, at least ``comfort_brake``) when the gap closes before ``commit_distance``."""

    family = "gap-acceptance"
    Params = GapAcceptanceParams
    accepts = GapAcceptanceParams

    def _accel(self, t: float, x: float, v: float, ok: bool) -> float:
        p = self._p
        if self.mode == WAITING:
            if self._rest_since is None:
                if x >= -AT_TARGET and v < AT_REST:
                    self._rest_since = t
                else:
                    return self._stop_at(0.0, x, v, max(p["approach_speed"], PULL_UP_SPEED))
            if t - self._rest_since < max(p["dwell"], p["reaction_time"]) - 1e-9:  # it looks before it goes
                return self._hold()
            if not ok:  # creeps forward to see, and waits there
                return self._stop_at(p["creep_distance"], x, v, p["creep_speed"])
        self._leave(x, ok)
        if self.mode == YIELDING:
            if v < AT_REST / 2.0:
                return self._hold()
            room = max(p["commit_distance"] - x, AT_TARGET)
            return -min(max(v * v / (2.0 * room), p["comfort_brake"]), self._max_brake)
        return self._idm(v, p["turn_speed"])


class AggressiveDriver(GapAcceptanceDriver):
    """Gap acceptance with :class:`AggressiveParams`: short gaps and reaction, strong pull-out."""

    family = "aggressive"
    Params = AggressiveParams


class OffRouteDriver(GapAcceptanceDriver):
    """Gap acceptance with :class:`OffRouteParams`: its own turn path, off the scene's route."""

    family = "off-route"
    Params = OffRouteParams


class RollingStopDriver(_Driver):
    """Comes down the side road at ``approach_speed``, slows uniformly to reach
    ``rolling_speed`` at the line, and decides there without stopping (perception with its
    reaction time): the IDM towards ``turn_speed`` if it accepts the gap, else
    ``hard_brake`` to a stop, going again once it accepts; committed past
    ``commit_distance``."""

    family = "rolling-stop"
    Params = RollingStopParams
    accepts = RollingStopParams

    def _accel(self, t: float, x: float, v: float, ok: bool) -> float:
        p = self._p
        if self.mode == WAITING and x < 0.0:  # on the approach: reach the rolling speed at the line
            roll = p["rolling_speed"]
            need = (roll * roll - v * v) / (2.0 * max(-x, 0.05))
            return min(self._idm(v, max(p["approach_speed"], roll)), need)
        self._leave(x, ok)
        if self.mode == YIELDING:
            return -min(p["hard_brake"], self._max_brake) if v >= AT_REST / 2.0 else self._hold()
        return self._idm(v, p["turn_speed"])


def _load(target: str) -> Any:
    """The object a ``"module:Name"`` string names, imported now."""
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


class _Families(Mapping[str, "type[_Driver]"]):
    """The families by name, each a class or a ``"module:Class"`` string imported on first
    use (Gymnasium's registry style): :mod:`cdf_mj.scenario.crash_drivers` builds on this
    module, so this module names its classes without importing it."""

    def __init__(self, entries: Mapping[str, type[_Driver] | str]) -> None:
        self._entries: dict[str, type[_Driver] | str] = dict(entries)

    def __getitem__(self, name: str) -> type[_Driver]:
        entry = self._entries[name]
        if isinstance(entry, str):
            entry = self._entries[name] = _load(entry)
        return entry

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"FAMILIES({', '.join(self._entries)})"


_CRASH = "cdf_mj.scenario.crash_drivers"

#: The driver families by name (their classes; those of :mod:`cdf_mj.scenario.crash_drivers`
#: are imported on first use).
FAMILIES: Mapping[str, type[_Driver]] = _Families({
    **{cls.family: cls for cls in (GapAcceptanceDriver, RollingStopDriver, AggressiveDriver, OffRouteDriver)},
    "looked-but-failed": f"{_CRASH}:LookedButFailedDriver",
    "misjudged-speed": f"{_CRASH}:MisjudgedSpeedDriver",
    "distracted": f"{_CRASH}:DistractedDriver",
    "creeper": f"{_CRASH}:CreeperDriver",
})

#: Families of optional extras, as ``"module:Class"``: imported by :func:`make_driver` only
#: (not in :data:`FAMILIES`, which needs nothing beyond the package's own requirements).
OPTIONAL_FAMILIES: Mapping[str, str] = MappingProxyType({
    "sumo": "cdf_mj.scenario.sumo_driver:SumoDriver",  # Eclipse SUMO co-simulation (the sumo extra)
})


def make_driver(family: str, params: FamilyParams | None = None) -> WorldDriver:
    """A driver of ``family`` with ``params`` (default: the family's default ranges).
    ValueError for an unknown family (naming the known ones), parameters of another kind,
    or an optional family whose module is not there (its own errors, such as a missing
    extra, come through as it raises them)."""
    cls = FAMILIES.get(family)
    if cls is None and family in OPTIONAL_FAMILIES:
        target = OPTIONAL_FAMILIES[family]
        try:
            cls = _load(target)
        except ModuleNotFoundError as exc:
            if exc.name != target.partition(":")[0]:
                raise
            raise ValueError(f"driver family {family!r} is not available here: {exc.name} is missing") from None
    if cls is None:
        known = ", ".join([*FAMILIES, *OPTIONAL_FAMILIES])
        raise ValueError(f"unknown driver family {family!r}: known families are {known}")
    return cls(params)


def _idm_accel(v: float, v0: float, a: float, b: float, gap: float = math.inf, v_lead: float = 0.0) -> float:
    return idm(v, v_lead, gap, a_max=a, b=b, time_gap=IDM_HEADWAY, min_gap=IDM_JAM, v0=v0, s_star="dynamic",
               gap_floor=0.05)


def __getattr__(name: str) -> Any:
    """``idm_accel`` of version 0.3 (the families' IDM), now :func:`cdf_mj.model.road.idm`
    with ``s_star="dynamic"``, ``gap_floor=0.05``; with a DeprecationWarning."""
    if name != "idm_accel":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import warnings

    warnings.warn('cdf_mj.scenario.drivers.idm_accel is deprecated; use cdf_mj.model.road.idm(v, v_lead, gap, '
                  'a_max=a, b=b, time_gap=IDM_HEADWAY, min_gap=IDM_JAM, v0=v0, s_star="dynamic", gap_floor=0.05)',
                  DeprecationWarning, stacklevel=2)
    return _idm_accel
