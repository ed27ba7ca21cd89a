"""Safety and comfort margins of one episode, read from the true poses tick by tick, and
their summary over many episodes (docs/SAFETY.md gives every formula).

A :class:`SafetyRecorder` is an episode observer (``run_episode(..., observers=[rec])``):
after every tick it reads the world's true system pose (``step.tick.poses``, never what
the planner was given), the ego's brake flag and whether the ego touched the obstacle,
and keeps O(1) running values (20-30 µs a tick, no shapely). :meth:`~SafetyRecorder.result`
gives the episode's :class:`SafetyMetrics`; :func:`safety_summary` reduces many of them
(or records that carry them under ``"safety"``) to medians, minima and shares with Wilson
intervals for a table. ::

    rec = SafetyRecorder()                      # SafetyParams() by default
    record = run_episode(config, seed=1, planner="cdf-threshold", observers=[rec])
    rec.result().to_dict()                      # JSON; None where a metric never happened
    safety_summary([m1, m2, m3])                # {"min_ttc": {"n", "median", "min", "max"}, ...}

The recorder can also be fed by hand (a trace read back, a test):
``rec.observe(t, poses, braking, collision)`` with ``poses`` ``(2, 4)`` ego and obstacle
``[x m, y m, theta rad, v m/s]`` (rear axle, world frame: x east, y north).

Definitions in brief (frames and names as :class:`cdf_mj.model.layout.Layout`):

- *gap* [m]: distance between the two collision boxes (:func:`~cdf_mj.model.geometry.box_gap`,
  the very number the world's ``min_gap`` takes), 0 when they touch;
- *closing speed* [m/s]: ``-d gap / dt`` with both boxes moved rigidly along their
  velocities ``v (cos theta, sin theta)``, which equals ``(v_ego - v_obs) . n`` with ``n``
  the unit vector from the ego's closest point to the obstacle's; TTC = gap / closing speed
  where that is > 0;
- *in the lane*: the obstacle's box meets the ego lane's box
  (:func:`cdf_mj.model.road.in_lane`); *ahead in the lane*: in the lane, and its box
  centre's arc length on the ego's route is greater than the ego's
  (:func:`cdf_mj.model.road.ahead`): the world's words, which the episode's end and car
  following ask too; the RSS distance is
  :func:`cdf_mj.model.road.rss_distance` with :class:`SafetyParams`
  (:meth:`SafetyParams.rss_distance`);
- *conflict area*: the square of the ego lane's width centred on the point of the ego's
  route nearest ``layout.conflict``, sides along and across the route there.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from cdf_mj.analysis.metrics import Rate
from cdf_mj.config import MAX_BRAKE
from cdf_mj.model import road
from cdf_mj.model.geometry import OrientedBox, box_gap
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.records import EpisodeRecord, completed
from cdf_mj.traits import MAX_ACCEL, MAX_DURATION, bounded, check, validate

__all__ = ["CLOSING_STEP", "CONFLICT_FIRST", "SUMMARY_FIELDS", "SafetyMetrics", "SafetyParams", "SafetyRecorder",
           "StepLike", "closing_speed", "safety_summary"]

#: [s] Step of the one-sided difference that gives the closing speed: the boxes moved this long
#: along their velocities (1 µs: the difference's error is below 1e-4 m/s even at a 1 cm gap).
CLOSING_STEP = 1e-6
#: Who was in the conflict area first: ``SafetyMetrics.conflict_first``'s values.
CONFLICT_FIRST = ("ego", "obstacle", "both")


@dataclass(frozen=True)
class SafetyParams:
    """The parameters of the safety metrics. ValueError naming the field and its bounds.

    RSS (Shalev-Shwartz, Shammah, Shashua 2017), the longitudinal safe distance behind a car
    ahead: ``rho`` the ego's response time [s]; ``a_acc`` the ego's largest acceleration
    during it [m/s^2]; ``b_min`` the ego's braking it can count on afterwards [m/s^2];
    ``b_max`` the largest braking of the car ahead [m/s^2]. Defaults: 0.2 s, and the limits
    of the package's car (``CarGeometry.ours()``: acceleration 3 m/s^2, braking 4.877
    m/s^2 = 16 ft/s^2 for both cars; the ego's planners brake at that full rate, so it can
    count on it; lower ``b_min`` for a margin). :meth:`of_cars` takes them from other cars.

    ``hard_brake`` [m/s^2]: a deceleration at or above it is hard braking (0.3 g, the usual
    threshold of naturalistic driving studies): it is counted in ``hard_brake_time`` and
    left out of the comfort jerk. ``ttc_critical`` [s]: a brake onset at a time to collision
    below it is late (the share :func:`safety_summary` reports).
    """

    rho: float = bounded(0.2, 0.0, MAX_DURATION, "s")
    a_acc: float = bounded(3.0, 0.0, MAX_ACCEL, "m/s^2")
    b_min: float = bounded(MAX_BRAKE, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    b_max: float = bounded(MAX_BRAKE, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    hard_brake: float = bounded(3.0, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    ttc_critical: float = bounded(1.5, 0.0, MAX_DURATION, "s", open_low=True)

    def __post_init__(self) -> None:
        validate(self, "SafetyParams.")

    @classmethod
    def of_cars(cls, layout: Layout, **changes: float) -> SafetyParams:
        """The parameters for ``layout``'s cars: ``a_acc`` and ``b_min`` the ego's
        acceleration and braking limits, ``b_max`` the obstacle's braking limit [m/s^2];
        ``changes`` override any field."""
        cars = {"a_acc": layout.ego.max_accel, "b_min": layout.ego.max_brake, "b_max": layout.obstacle.max_brake}
        return cls(**{**cars, **changes})

    def to_dict(self) -> dict[str, float]:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)

    def rss_distance(self, v_r: float, v_f: float) -> float:
        """[m] The RSS safe distance (:func:`cdf_mj.model.road.rss_distance`) with these
        parameters: ``v_r`` the rear (ego) car's speed, ``v_f`` the front car's along the
        ego's direction [m/s], each taken as 0 where negative."""
        return road.rss_distance(v_r, v_f, self.rho, self.a_acc, self.b_min, self.b_max)


def __getattr__(name: str) -> Callable[[float, float, SafetyParams], float]:
    """The deprecated ``rss_distance(v_r, v_f, params)`` (one is exported: the road's)."""
    if name != "rss_distance":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn("cdf_mj.analysis.safety.rss_distance(v_r, v_f, params) is deprecated; use "
                  "params.rss_distance(v_r, v_f) or cdf_mj.model.road.rss_distance", DeprecationWarning, stacklevel=2)
    return lambda v_r, v_f, params: params.rss_distance(v_r, v_f)


def _moved(car: CarGeometry, pose: list[float], dt: float) -> list[tuple[float, float]]:
    """Corners of ``car``'s box at ``pose`` moved ``dt`` [s] along its velocity."""
    x, y, theta, v = pose
    c, s = math.cos(theta), math.sin(theta)
    return car.footprint_one(x + dt * v * c, y + dt * v * s, theta)


def _closing(ego: CarGeometry, obstacle: CarGeometry, e: list[float], o: list[float], gap: float) -> float:
    """[m/s] The rate at which ``gap`` [m] shrinks (see :func:`closing_speed`)."""
    return (gap - box_gap(_moved(ego, e, CLOSING_STEP), _moved(obstacle, o, CLOSING_STEP))) / CLOSING_STEP


def closing_speed(layout: Layout, poses: np.ndarray) -> float:
    """[m/s] The rate at which the gap between the two cars' boxes shrinks at the system pose
    ``poses`` ``(2, 4)`` (ego, obstacle; rear axle ``[x, y, theta, v]``, world frame), the
    boxes moved rigidly along their velocities ``v (cos theta, sin theta)``: for boxes apart,
    ``(v_ego - v_obs) . n`` with ``n`` the unit vector between their closest points. The
    cars' turning is left out (a pose has no yaw rate)."""
    e, o = np.asarray(poses, dtype=float).tolist()
    return _closing(layout.ego, layout.obstacle, e, o, road.car_gap(layout.ego, e, layout.obstacle, o))


# ------------------------------------------------------------------------------ one episode
_FLOATS = ("brake_time", "ttc_at_brake", "min_ttc", "min_headway", "min_gap", "pet", "peak_decel", "peak_jerk",
           "peak_jerk_comfort", "hard_brake_time")
_COUNTS = ("ticks", "following_ticks", "rss_ticks", "brake_switches", "brake_applications")


@dataclass(frozen=True)
class SafetyMetrics:
    """The safety and comfort margins of one episode (docs/SAFETY.md). ``None``: never
    happened (no brake onset, never closing, never following, no second car in the area...).

    Attributes:
        ticks: ticks observed.
        collision: the ego touched the obstacle (then ``min_gap`` and ``min_ttc`` are 0).
        brake_time: [s] the first tick the ego braked.
        ttc_at_brake: [s] time to collision at ``brake_time`` (None: not closing then).
        min_ttc: [s] the least time to collision over the ticks with the obstacle in the lane.
        min_headway: [s] the least gap / ego speed with the obstacle ahead in the lane.
        min_gap: [m] the least gap between the two collision boxes.
        pet: [s] post-encroachment time: the second car's entry into the conflict area less
            the first car's exit from it; 0 if both were in it on one tick.
        conflict_first: which car entered the conflict area first, ``"ego"``,
            ``"obstacle"`` or ``"both"`` (one tick); None if neither did.
        following_ticks: ticks with the obstacle ahead in the ego's lane.
        rss_ticks: those of them with gap < the RSS safe distance (:meth:`SafetyParams.rss_distance`).
        brake_switches: changes of the brake flag (on or off), from off at the start.
        brake_applications: its off-to-on changes.
        peak_decel: [m/s^2] the largest deceleration over one tick (0 if it never slowed).
        peak_jerk: [m/s^3] the largest |change of acceleration| between consecutive ticks.
        peak_jerk_comfort: [m/s^3] the same between ticks neither of which brakes hard.
        hard_brake_time: [s] time spent decelerating at ``hard_brake`` or more.

    ValueError naming the field if a number is negative or not finite, a count is not a
    non-negative integer, or ``rss_ticks > following_ticks``.
    """

    ticks: int
    collision: bool
    brake_time: float | None
    ttc_at_brake: float | None
    min_ttc: float | None
    min_headway: float | None
    min_gap: float | None
    pet: float | None
    conflict_first: str | None
    following_ticks: int
    rss_ticks: int
    brake_switches: int
    brake_applications: int
    peak_decel: float | None
    peak_jerk: float | None
    peak_jerk_comfort: float | None
    hard_brake_time: float

    def __post_init__(self) -> None:
        for name in _FLOATS:
            value = getattr(self, name)
            check(value is None or (not isinstance(value, bool) and isinstance(value, (int, float))
                                    and math.isfinite(value) and value >= 0.0), f"SafetyMetrics.{name}", value,
                  "None or a finite number >= 0")
        for name in _COUNTS:
            value = getattr(self, name)
            check(isinstance(value, int) and not isinstance(value, bool) and value >= 0, f"SafetyMetrics.{name}",
                  value, "an integer >= 0")
        check(isinstance(self.collision, bool), "SafetyMetrics.collision", self.collision, "true or false")
        check(self.conflict_first is None or self.conflict_first in CONFLICT_FIRST, "SafetyMetrics.conflict_first",
              self.conflict_first, f"None or one of {', '.join(CONFLICT_FIRST)}")
        check(self.rss_ticks <= self.following_ticks, "SafetyMetrics.rss_ticks", self.rss_ticks,
              f"<= following_ticks = {self.following_ticks}")
        check(self.brake_applications <= self.brake_switches, "SafetyMetrics.brake_applications",
              self.brake_applications, f"<= brake_switches = {self.brake_switches}")

    @property
    def rss_share(self) -> float | None:
        """Share of the following ticks closer than the RSS safe distance (None: none)."""
        return self.rss_ticks / self.following_ticks if self.following_ticks else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view, with ``rss_share``; :meth:`from_dict` reads it back."""
        return {**dataclasses.asdict(self), "rss_share": self.rss_share}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SafetyMetrics:
        """The metrics of a :meth:`to_dict` dict (``rss_share`` is derived, not read);
        ValueError naming a missing or unknown key, or a bad value."""
        if not isinstance(data, Mapping):
            raise ValueError(f"SafetyMetrics: expected an object, got {type(data).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        problems = [f"key {k!r} is missing" for k in names if k not in data]
        problems += [f"key {k!r} is unknown" for k in sorted(set(data) - {*names, "rss_share"})]
        if problems:
            raise ValueError(f"SafetyMetrics: {'; '.join(problems)}")
        return cls(**{k: data[k] for k in names})


@dataclass(frozen=True)
class _Areas:
    """What the recorder needs of a layout, computed once: the layout, its cars and the
    corners ``(4, 2)`` [m] of the conflict area."""

    layout: Layout
    ego: CarGeometry
    obstacle: CarGeometry
    conflict: np.ndarray

    @classmethod
    def of(cls, layout: Layout) -> _Areas:
        """The areas of ``layout`` (see the module docstring for the conflict area)."""
        route = layout.route_ego
        s = route.project_point(float(layout.conflict[0]), float(layout.conflict[1]))[0]
        a, b = route.point_at(max(s - 0.5, 0.0)), route.point_at(min(s + 0.5, route.length))
        half = float(layout.ego_lane.half[1])
        square = OrientedBox(center=route.point_at(s), heading=math.atan2(b[1] - a[1], b[0] - a[0]),
                             half=np.array([half, half]))
        return cls(layout, layout.ego, layout.obstacle, square.corners())


class _TickLike(Protocol):
    """What the recorder reads of the world's tick (:class:`cdf_mj.scenario.world.Tick`)."""

    @property
    def t(self) -> float: ...  # [s] at the start of the tick
    @property
    def poses(self) -> np.ndarray: ...  # (2, 4) true system pose at the start of the tick
    @property
    def collision(self) -> str | None: ...  # "obstacle" | "building" if the ego touched one


class _WorldLike(Protocol):
    @property
    def layout(self) -> Layout: ...


class StepLike(Protocol):
    """What the recorder reads of an :class:`cdf_mj.scenario.episode.EpisodeTick`."""

    @property
    def braking(self) -> bool: ...
    @property
    def tick(self) -> _TickLike: ...
    @property
    def world(self) -> _WorldLike: ...


def _lower(current: float | None, value: float) -> float:
    """The least of a running minimum (None: none yet) and ``value``."""
    return value if current is None or value < current else current


class SafetyRecorder:
    """An episode observer that accumulates :class:`SafetyMetrics` (see the module docstring).

    Args:
        params: the metrics' parameters (default :class:`SafetyParams`).
        layout: the junction; default: the first tick's ``step.world.layout`` (needed before
            :meth:`observe` is called by hand).

    One recorder per episode: ValueError if a tick's time is not after the last one's.
    """

    def __init__(self, params: SafetyParams | None = None, layout: Layout | None = None) -> None:
        self.params = params or SafetyParams()
        self._areas = _Areas.of(layout) if layout is not None else None
        self._ticks = self._following = self._rss = self._switches = self._applications = 0
        self._collision = False
        self._t: float | None = None  # last tick's time [s]
        self._braking = False
        self._brake_time: float | None = None
        self._ttc_at_brake: float | None = None
        self._min_ttc: float | None = None
        self._min_headway: float | None = None
        self._min_gap: float | None = None
        self._was_following = False
        # Conflict area per car (ego, obstacle): first tick in, last tick in, first tick out after it [s].
        self._enter: list[float | None] = [None, None]
        self._exit: list[float | None] = [None, None]
        # Speed profile: last speed [m/s], last acceleration [m/s^2] and its tick length [s].
        self._v = 0.0
        self._a: float | None = None
        self._dt = 0.0
        self._peak_decel: float | None = None
        self._peak_jerk: float | None = None
        self._peak_jerk_comfort: float | None = None
        self._hard_time = 0.0

    def __call__(self, step: StepLike) -> None:
        """Record one tick of an episode (the :data:`cdf_mj.scenario.episode.Observer` call)."""
        if self._areas is None:
            self._areas = _Areas.of(step.world.layout)
        tick = step.tick
        self.observe(tick.t, tick.poses, step.braking, tick.collision)

    def observe(self, t: float, poses: np.ndarray, braking: bool, collision: str | None = None) -> None:
        """Record one tick: its start time ``t`` [s], the true system pose ``poses`` ``(2, 4)``
        at that time, whether the ego braked over it and what it touched (``"obstacle"``...)."""
        areas = self._areas
        if areas is None:
            raise ValueError("SafetyRecorder: no layout yet; give SafetyRecorder(layout=...) to observe by hand")
        t = float(t)
        if self._t is not None and not t > self._t:
            raise ValueError(f"SafetyRecorder: tick time t={t} s is not after the last one, {self._t} s; "
                             "a recorder records one episode (make a new one per episode)")
        e, o = np.asarray(poses, dtype=float).tolist()
        ego_box, obs_box = areas.ego.footprint_one(*e[:3]), areas.obstacle.footprint_one(*o[:3])
        gap = box_gap(ego_box, obs_box)
        self._min_gap = _lower(self._min_gap, gap)
        in_lane = road.in_lane(areas.layout, obs_box)
        closing: float | None = None
        if in_lane or (braking and self._brake_time is None):
            closing = _closing(areas.ego, areas.obstacle, e, o, gap)
        ttc = (gap / closing if closing > 0.0 else None) if closing is not None else None
        if in_lane and ttc is not None:
            self._min_ttc = _lower(self._min_ttc, ttc)
        self._was_following = in_lane and road.ahead(areas.layout, o, areas.obstacle, e, areas.ego)
        if self._was_following:
            self._following += 1
            if e[3] > 0.0:
                self._min_headway = _lower(self._min_headway, gap / e[3])
            v_f = o[3] * math.cos(o[2] - e[2])  # the obstacle's speed along the ego's heading
            self._rss += gap < self.params.rss_distance(e[3], v_f)
        for k, box in enumerate((ego_box, obs_box)):
            if box_gap(box, areas.conflict) == 0.0:
                self._enter[k] = t if self._enter[k] is None else self._enter[k]
                self._exit[k] = None
            elif self._enter[k] is not None and self._exit[k] is None:
                self._exit[k] = t
        if braking != self._braking:
            self._switches += 1
            self._applications += braking
        if braking and self._brake_time is None:
            self._brake_time, self._ttc_at_brake = t, ttc
        self._speed(t, e[3])
        if collision == "obstacle":
            self._collision = True
        self._braking, self._t = bool(braking), t
        self._ticks += 1

    def _speed(self, t: float, v: float) -> None:
        """Deceleration and jerk from the ego's speed ``v`` [m/s] at tick time ``t`` [s]: the
        acceleration over the last tick is the difference of speeds over its length."""
        if self._t is None:
            self._v = v
            return
        dt = t - self._t
        a = (v - self._v) / dt
        self._peak_decel = max(self._peak_decel or 0.0, -a)
        hard = self.params.hard_brake
        if -a >= hard:
            self._hard_time += dt
        if self._a is not None:
            jerk = abs(a - self._a) / (0.5 * (dt + self._dt))  # between the two ticks' midpoints
            self._peak_jerk = max(self._peak_jerk or 0.0, jerk)
            if -a < hard and -self._a < hard:
                self._peak_jerk_comfort = max(self._peak_jerk_comfort or 0.0, jerk)
        self._v, self._a, self._dt = v, a, dt

    def _pet(self) -> tuple[float | None, str | None]:
        """Post-encroachment time [s] and which car entered the conflict area first."""
        (e_in, o_in), (e_out, o_out) = self._enter, self._exit
        if e_in is None and o_in is None:
            return None, None
        if e_in is None or o_in is None:
            return None, "ego" if o_in is None else "obstacle"
        if e_in == o_in:
            return 0.0, "both"
        first_out, second_in, first = (e_out, o_in, "ego") if e_in < o_in else (o_out, e_in, "obstacle")
        if first_out is None or first_out > second_in:  # both in the area on one tick
            return 0.0, first
        return round(second_in - first_out, 9), first  # tick times are rounded to 1e-6 s

    def result(self) -> SafetyMetrics:
        """The metrics of the ticks recorded so far."""
        pet, first = self._pet()
        hit = self._collision
        return SafetyMetrics(
            ticks=self._ticks, collision=hit, brake_time=self._brake_time, ttc_at_brake=self._ttc_at_brake,
            min_ttc=0.0 if hit else self._min_ttc,
            min_headway=0.0 if hit and self._was_following else self._min_headway,
            min_gap=0.0 if hit else self._min_gap, pet=pet, conflict_first=first,
            following_ticks=self._following, rss_ticks=int(self._rss), brake_switches=self._switches,
            brake_applications=int(self._applications), peak_decel=self._peak_decel, peak_jerk=self._peak_jerk,
            peak_jerk_comfort=self._peak_jerk_comfort, hard_brake_time=round(self._hard_time, 9))


# ------------------------------------------------------------------------------ many episodes
#: The metrics :func:`safety_summary` gives the median, minimum and maximum of.
SUMMARY_FIELDS = ("ttc_at_brake", "min_ttc", "min_headway", "min_gap", "pet", "brake_switches",
                  "brake_applications", "peak_decel", "peak_jerk", "peak_jerk_comfort", "hard_brake_time",
                  "rss_share")


def _as_metrics(item: Any) -> SafetyMetrics | None:
    """The metrics of a :class:`SafetyMetrics`, its dict, or a record (dict or object)
    carrying one under ``safety``; None for a record without them."""
    if item is None or isinstance(item, SafetyMetrics):
        return item
    if isinstance(item, Mapping):
        if "safety" in item or "seed" in item:  # a record (one written before the metrics has none)
            return _as_metrics(item.get("safety"))
        return SafetyMetrics.from_dict(item)
    if isinstance(item, EpisodeRecord) or hasattr(item, "safety"):
        return _as_metrics(getattr(item, "safety", None))
    raise ValueError(f"safety_summary: expected SafetyMetrics, their dict or a record with 'safety', "
                     f"got {type(item).__name__}")


def _share(k: int, n: int) -> dict[str, Any]:
    """:meth:`Rate.to_dict` of ``k`` of ``n``, with ``value`` None (not NaN) when ``n`` is 0."""
    out = Rate(k, n).to_dict()
    return {**out, "value": out["value"] if n else None}


def _stats(values: list[float]) -> dict[str, Any]:
    """``n``, ``median``, ``min``, ``max`` of the values (None without any)."""
    if not values:
        return {"n": 0, "median": None, "min": None, "max": None}
    return {"n": len(values), "median": float(statistics.median(values)), "min": float(min(values)),
            "max": float(max(values))}


def safety_summary(items: Iterable[Any], params: SafetyParams | None = None) -> dict[str, Any]:
    """The safety metrics of many episodes, for a table.

    ``items``: :class:`SafetyMetrics`, their :meth:`~SafetyMetrics.to_dict` dicts, or
    records (dicts or objects) that carry them under ``"safety"``; failed records and
    records whose ``safety`` is None are left out. Returns a JSON-serialisable dict:

    - ``episodes``: how many were summarised;
    - per metric of :data:`SUMMARY_FIELDS`: ``{"n", "median", "min", "max"}`` over the
      episodes in which it happened (``n`` of them);
    - shares as :meth:`cdf_mj.analysis.metrics.Rate.to_dict` (with 95 % Wilson intervals):
      ``late_brake`` brake onsets with TTC below ``params.ttc_critical``, of all onsets;
      ``rss_episodes`` episodes with any following tick closer than the RSS distance, of
      those with following ticks; ``rss_ticks`` such ticks pooled over episodes, of all
      following ticks (ticks of one episode are not independent: its interval is too
      narrow, read ``rss_episodes`` for a test); ``collisions`` episodes with contact.
    """
    params = params or SafetyParams()
    metrics = [m for m in map(_as_metrics, completed(items)) if m is not None]
    out: dict[str, Any] = {"episodes": len(metrics)}
    for name in SUMMARY_FIELDS:
        out[name] = _stats([v for m in metrics if (v := getattr(m, name)) is not None])
    onsets = [m for m in metrics if m.brake_time is not None]
    late = sum(1 for m in onsets if m.ttc_at_brake is not None and m.ttc_at_brake < params.ttc_critical)
    following = [m for m in metrics if m.following_ticks]
    out["late_brake"] = _share(late, len(onsets))
    out["rss_episodes"] = _share(sum(1 for m in following if m.rss_ticks), len(following))
    out["rss_ticks"] = _share(sum(m.rss_ticks for m in following), sum(m.following_ticks for m in following))
    out["collisions"] = _share(sum(m.collision for m in metrics), len(metrics))
    return out
