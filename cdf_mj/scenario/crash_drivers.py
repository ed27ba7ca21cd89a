"""Obstacle drivers that cut off: the junction-crash behaviours, on the machinery of
:mod:`cdf_mj.scenario.drivers` and as apart from the filter's model as those (this module
imports neither :mod:`cdf_mj.model.driver`, nor its kernels, nor the filter).

The families of :mod:`cdf_mj.scenario.drivers` look at the ego all the time and so almost
never pull out in front of it. What happens at real T-junctions is better known: the
minor-road driver who looked but failed to see the oncoming car is the classic cause of
these crashes, and misjudged approach speed, a look that has gone stale and creeping out
to see are measured behaviours. Each family below is one of them; docs/DRIVERS.md gives
every range with its source and the share of left-turners each cuts off.

================= =======================================================================
looked-but-failed looks at the main road every ``look_interval``; a look fails to register
                  the ego with a probability that rises as the ego is smaller in its view
                  and more hidden (:func:`look_failure`), and on a look that saw nothing
                  it goes
misjudged-speed   gap acceptance, looking all the time, on the ego's speed perceived as
                  ``speed_factor`` (< 1) of the truth: it takes gaps that are too short
distracted        looked once, then looked away for ``glance_away`` and goes after its
                  dwell on that stale look, without a fresh one
creeper           edges forward past its line at walking pace to see; goes as soon as it
                  takes the gap (its critical gap may be short), or stops again at the end
                  of its creep (``restop_chance``) for a pause before it judges again
================= =======================================================================

What they share (:class:`_CrashDriver`): the episode starts at the end of the driver's stop
(at rest on its line); what it knows of the ego is its *picture*, the latest look that a
reaction time has brought to its decisions (the ego's position and speed as that look
registered them, or nothing); it goes when its picture gives it the gap (gap acceptance as
in :class:`~cdf_mj.scenario.drivers.GapAcceptanceDriver`: a perceived ego further than
``min_distance`` and ``critical_gap`` away in time, or none); once moving it no longer
weighs the gap but brakes (before its commit distance) only for an ego it perceives within
``min_distance``: a driver who has pulled out is committed to the manoeuvre in its mind
long before it is on the road. ::

    driver = make_driver("looked-but-failed")       # cdf_mj.scenario.drivers.make_driver
    driver.reset(layout, intent=0, rng=rng)         # draws this episode's parameters
    driver.ego_share = 0.6                          # sight "share": set by the world each tick
    accel, steer = driver.control(t, pose, ego_or_None, dt)

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``; "progress" is the rear axle's arc length past the stop position.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

import numpy as np

from cdf_mj.model.layout import Layout
from cdf_mj.model.modes import COMMITTED, GOING, WAITING, YIELDING
from cdf_mj.scenario.drivers import (
    AT_REST,
    AT_TARGET,
    PULL_UP_SPEED,
    _CommonParams,
    _Driver,
    span,
)

__all__ = ["DETECTION_SLOPE", "CreeperDriver", "CreeperParams", "DistractedDriver", "DistractedParams",
           "LookedButFailedDriver", "LookedButFailedParams", "MisjudgedSpeedDriver", "MisjudgedSpeedParams",
           "angular_width", "look_failure"]

DETECTION_SLOPE = 2.0  # Weibull slope of the detection function (contrast detection: 2-4; shallow: salience)

#: What a look registered of the ego: its position [m] and its speed as perceived [m/s].
Seen = tuple[float, float, float]


def angular_width(distance: float, width: float) -> float:
    """[rad] the angle that a car ``width`` [m] wide subtends face-on at ``distance`` [m]
    from the eye. ValueError for a width that is not > 0 or a distance that is not >= 0."""
    if not (width > 0.0 and distance >= 0.0):  # NaN fails too
        raise ValueError(f"angular_width: width={width!r} must be > 0 and distance={distance!r} >= 0 [m]")
    return 2.0 * math.atan2(0.5 * width, distance)


def look_failure(distance: float, width: float, share: float, lapse: float, threshold: float) -> float:
    """The probability in [0, 1] that one look fails to register a car ``width`` [m] wide,
    ``distance`` [m] from the eye, of which the share ``share`` in [0, 1] of its sight points
    is in view: ``1 - (1 - lapse) (1 - exp(-(share theta / threshold)^k))`` with ``theta`` its
    :func:`angular_width` [rad], ``threshold`` [rad] the visible angular width registered by
    ``1 - 1/e`` (63 %) of attentive looks and ``k`` = :data:`DETECTION_SLOPE` (a Weibull
    psychometric function). It rises with the distance and falls with the share: 1 for a
    hidden car (share 0), ``lapse`` for one filling the view. ValueError for an argument
    out of its range."""
    if not (0.0 <= share <= 1.0 and 0.0 <= lapse <= 1.0 and threshold > 0.0):
        raise ValueError(f"look_failure: share={share!r} and lapse={lapse!r} must be in [0, 1], "
                         f"threshold={threshold!r} > 0 [rad]")
    visible = share * angular_width(distance, width) / threshold
    return 1.0 - (1.0 - lapse) * -math.expm1(-visible ** DETECTION_SLOPE)


# ------------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class _CrashParams(_CommonParams):
    """The ranges the crash families share (the common ones, a driver set to go, a brisker pull-out)."""

    reaction_time: tuple[float, float] = span(
        (0.5, 1.0), 0.0, 5.0, "s", "a driver who expects the event: 0.7-0.75 s (Green 2000); at its line it is "
                                   "set to go")
    max_accel: tuple[float, float] = span(
        (1.5, 2.5), 0.1, 10.0, "m/s^2", "comfortable starts from rest: 1.5-2.0 (field studies reviewed by Long "
                                        "2000), up to a brisk 2.5")


@dataclass(frozen=True)
class LookedButFailedParams(_CrashParams):
    """Looked but failed to see: the common ranges, a short rest of its stop, its looks and
    how they fail (:func:`look_failure`)."""

    dwell: tuple[float, float] = span(
        (0.0, 1.0), 0.0, 60.0, "s", "what is left of a 1-3 s stop when the episode starts")
    look_interval: tuple[float, float] = span(
        (0.3, 1.0), 0.05, 10.0, "s", "a look each way and back: fixations and head turns of 0.3-1 s")
    lapse: tuple[float, float] = span(
        (0.05, 0.2), 0.0, 1.0, "1", "looks that miss a car in full view (LBFTS with the other vehicle plainly "
                                    "visible: Herslund & Jorgensen 2003; Brown 2005); no per-look rate is published")
    conspicuity: tuple[float, float] = span(
        (2.0, 4.0), 0.01, 90.0, "deg", "visible width registered by 63 % of attentive looks: a car (1.8 m) missed "
                                       "by about half the looks at 35-50 m, a motorcycle (0.8 m) at half that")


@dataclass(frozen=True)
class MisjudgedSpeedParams(_CrashParams):
    """Misjudged approach speed: the common ranges, a short rest of its stop and the factor
    on the ego's speed as it perceives it."""

    dwell: tuple[float, float] = span(
        (0.0, 1.0), 0.0, 60.0, "s", "what is left of a 1-3 s stop when the episode starts")
    speed_factor: tuple[float, float] = span(
        (0.5, 0.9), 0.05, 1.0, "1", "perceived / true approach speed: gaps judged partly by distance (Staplin "
                                    "1995; Spek et al. 2006), arrival judged late (Horswill et al. 2005)")
    critical_gap: tuple[float, float] = span(
        (4.0, 6.0), 0.1, 30.0, "s", "a lag (the first car to come), accepted shorter than a gap between cars: "
                                    "critical lag about 4 s (Raff & Hart 1950), minor-road left turns 4-6.5 s "
                                    "in field studies (Brilon et al. 1999)")


@dataclass(frozen=True)
class DistractedParams(_CrashParams):
    """Distracted: the common ranges, a short rest of its stop, and how long its eyes were
    off the main road between its last look and its pull-out. It starts at rest on its line."""

    dwell: tuple[float, float] = span(
        (0.0, 1.0), 0.0, 60.0, "s", "what is left of a 1-3 s stop when the episode starts")
    glance_away: tuple[float, float] = span(
        (2.0, 6.0), 0.0, 60.0, "s", "eyes off the road > 2 s doubles crash risk (Klauer et al. 2006); texting "
                                    "takes 4.6 s of 6 (Olson et al. 2009); NHTSA's guidelines allow 12 s a task")
    approach_distance: tuple[float, float] = span(
        (0.0, 0.0), 0.0, 0.0, "m", "at rest on its line: its last look may be before the episode")
    approach_speed: tuple[float, float] = span(
        (0.0, 0.0), 0.0, 0.0, "m/s", "at rest")


@dataclass(frozen=True)
class CreeperParams(_CrashParams):
    """A creeper: the common ranges, its creep, a short critical gap and its second stop."""

    critical_gap: tuple[float, float] = span(
        (2.0, 5.0), 0.1, 30.0, "s", "from the shortest gaps accepted (2 s, as aggressive's) to below the HCM's "
                                    "6.4 s: nosed out, it needs less time to clear the road")
    commit_distance: tuple[float, float] = span(
        (2.5, 4.5), 0.0, 50.0, "m", "past its creep, out to the near lane's centre")
    creep_distance: tuple[float, float] = span(
        (0.5, 2.0), 0.0, 10.0, "m", "nosing out to the near lane's edge to see along the main road")
    creep_speed: tuple[float, float] = span(
        (0.5, 1.5), 0.1, 5.0, "m/s", "walking pace")
    restop_chance: tuple[float, float] = span(
        (0.2, 0.5), 0.0, 1.0, "1", "the chance this episode that it stops again at the end of its creep")
    restop_pause: tuple[float, float] = span(
        (1.0, 3.0), 0.0, 60.0, "s", "a second full stop, as long as a stop at a stop sign (1-3 s, as "
                                    "gap-acceptance's dwell): an assumption, no study times a second stop")

    def _conflicts(self) -> list[str]:
        if self.creep_distance[1] > self.commit_distance[0]:
            return [f"creep_distance={self.creep_distance} must end at or before commit_distance="
                    f"{self.commit_distance} starts [m]: a creeping driver has not committed"]
        return []


# ------------------------------------------------------------------------------- drivers
class _CrashDriver(_Driver):
    """Shared machinery of the crash families (see the module docstring): its looks, its
    picture, the go judgement and the commitment once moving. Subclasses give ``family``,
    ``Params``, :meth:`_looks_at`, :meth:`_register` and :meth:`_act`."""

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        super().reset(layout, intent, rng)
        self._rng = rng  # its per-look draws come after its parameters' (the same per seed)
        self._looks: deque[tuple[float, Seen | None]] = deque()  # (when [s], what it registered)
        self._tick = 0.0  # [s] the time of the coming tick (for looking)
        eye, ego = layout.obstacle.eye_offset, layout.ego
        self._eye = (float(eye[0]), float(eye[1]))  # [m] the driver's eye in its chassis frame
        self._ego_centre = (float(ego.hull_offset[0]), float(ego.hull_offset[1]))  # [m] in the ego's frame
        self._ego_width = float(2.0 * ego.hull_half[1])  # [m]

    @property
    def looking(self) -> bool:
        """Whether it looks for the ego on the coming tick (a left-turner not yet committed,
        at a time of its looks)."""
        return self._crosses and self.mode != COMMITTED and self._looks_at(self._tick)

    def control(self, t: float, pose: np.ndarray, ego: np.ndarray | None, dt: float) -> tuple[float, float]:
        """Its controls ``(acceleration m/s^2, steering rad)`` at time ``t`` [s] from its own
        pose ``[x, y, theta, v]`` and the ego's true pose when it is in its line of sight
        this tick (else None), within the car's limits; updates :attr:`mode`. A look it takes
        this tick registers what :meth:`_register` says. RuntimeError before :meth:`reset`."""
        if not self._p:
            raise RuntimeError("call reset(layout, intent, rng) before control()")
        x, y, th, v = (float(c) for c in pose)
        if self._crosses and self.mode != COMMITTED and self._looks_at(t):
            self._looks.append(self._register(t, x, y, th, ego))
        s, _ = self._path.project_point(x, y)
        accel = self._act(t, s - self._s_line, v)
        self._tick = t + dt
        return min(max(accel, -self._max_brake), self._max_accel), self._steer(x, y, th, v, s)

    # ------------------------------------------------------------------ hooks
    def _looks_at(self, t: float) -> bool:
        """Whether it looks at ``t`` [s] (all the time, by default)."""
        return True

    def _register(self, t: float, x: float, y: float, th: float, ego: np.ndarray | None) -> tuple[float, Seen | None]:
        """A look at ``t`` [s] from its pose: ``(when, what it registered)`` (the ego as it is)."""
        if ego is None:
            return t, None
        return t, (float(ego[0]), float(ego[1]), float(ego[3]))

    def _act(self, t: float, x: float, v: float) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    # ------------------------------------------------------------------ parts
    def _picture(self, t: float) -> tuple[bool, Seen | None]:
        """``(looked, seen)``: whether a look has reached its decisions at ``t`` [s] (one
        taken ``reaction_time`` ago or earlier), and what the latest such look registered."""
        t_p = t - self._p["reaction_time"] + 1e-9
        looks = self._looks
        while len(looks) >= 2 and looks[1][0] <= t_p:
            looks.popleft()
        if not looks or looks[0][0] > t_p:
            return False, None
        return True, looks[0][1]

    def _ahead(self, seen: Seen) -> float:
        """[m] from the perceived ego's front bumper to the conflict point along its route
        (-inf once its rear bumper is past it)."""
        s_ego, _ = self._route_ego.project_point(seen[0], seen[1])
        if s_ego - self._ego_rear > self._s_conflict:
            return -math.inf
        return self._s_conflict - (s_ego + self._ego_front)

    def _near(self, seen: Seen | None) -> bool:
        """Whether it perceives the ego within ``min_distance`` of the conflict point (and not
        past it): the one thing that stops it once it has pulled out."""
        if not self._crosses or seen is None:
            return False
        ahead = self._ahead(seen)
        return -math.inf < ahead <= self._p["min_distance"]

    def _at_line(self, t: float, x: float, v: float) -> float | None:
        """On the approach (if it starts upstream): towards a stop on its line, else None once
        it has come to rest there (``_rest_since`` set)."""
        if self._rest_since is None:
            if x >= -AT_TARGET and v < AT_REST:
                self._rest_since = t
            else:
                return self._stop_at(0.0, x, v, max(self._p["approach_speed"], PULL_UP_SPEED))
        return None

    def _go(self, t: float, x: float, v: float) -> float:
        """Out of its wait: the IDM towards ``turn_speed``, braking to a stop short of its
        commit distance for an ego it perceives within ``min_distance`` until committed."""
        p = self._p
        self._leave(x, not self._near(self._picture(t)[1]))
        if self.mode == YIELDING:
            if v < AT_REST / 2.0:
                return self._hold()
            room = max(p["commit_distance"] - x, AT_TARGET)
            return -min(max(v * v / (2.0 * room), p["comfort_brake"]), self._max_brake)
        return self._idm(v, p["turn_speed"])

    def _has_gap(self, t: float) -> bool:
        """Whether its picture at ``t`` [s] gives it the gap: always for a right-turner (it
        crosses no lane of the ego), else once a look has reached its decisions and that
        look registered no ego or one that :meth:`_gap_ok` accepts."""
        if not self._crosses:
            return True
        looked, seen = self._picture(t)
        return looked and self._gap_ok(seen)

    def _stop_then_judge(self, t: float, x: float, v: float) -> float:
        """Rest on its line for ``dwell``, then go once its picture gives it the gap."""
        if self.mode == WAITING:
            approach = self._at_line(t, x, v)
            if approach is not None:
                return approach
            assert self._rest_since is not None
            if t - self._rest_since < self._p["dwell"] - 1e-9 or not self._has_gap(t):
                return self._hold()
            self.mode = GOING
        return self._go(t, x, v)


class LookedButFailedDriver(_CrashDriver):
    """Looked but failed to see (see the module docstring): it looks every ``look_interval``
    from the episode's start; a look fails, registering no ego, with the probability
    :func:`look_failure` of the ego's distance from its eye, its width and the share of it in
    view (:attr:`ego_share`, set by the world: sight ``"share"``; 1 where nobody sets it),
    one uniform drawn per look whether or not the ego is in sight. It rests ``dwell`` on its
    line, then goes on a look that gives it the gap (a failed one does)."""

    family = "looked-but-failed"
    Params = LookedButFailedParams
    accepts = LookedButFailedParams
    sight: ClassVar[str] = "share"

    def __init__(self, params: LookedButFailedParams | None = None) -> None:
        super().__init__(params)
        self.ego_share = 1.0  # the share of the ego's sight points in view this tick (the world sets it)

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        super().reset(layout, intent, rng)
        self._next_look = 0.0
        self.ego_share = 1.0

    def failure(self, pose: np.ndarray, ego: np.ndarray, share: float) -> float:
        """The probability that a look from ``pose`` misses the ego at ``ego`` (poses
        ``[x, y, theta, v]``) with ``share`` of it in view, for this episode's ``lapse`` and
        ``conspicuity`` (:func:`look_failure`; distance from its eye to the ego's box centre).
        RuntimeError before :meth:`reset`."""
        if not self._p:
            raise RuntimeError("call reset(layout, intent, rng) before failure()")
        x, y, th = (float(c) for c in pose[:3])
        ex, ey, eth = (float(c) for c in ego[:3])
        (ox, oy), (cx, cy) = self._eye, self._ego_centre
        eye = (x + ox * math.cos(th) - oy * math.sin(th), y + ox * math.sin(th) + oy * math.cos(th))
        centre = (ex + cx * math.cos(eth) - cy * math.sin(eth), ey + cx * math.sin(eth) + cy * math.cos(eth))
        return look_failure(math.dist(eye, centre), self._ego_width, min(max(share, 0.0), 1.0),
                            self._p["lapse"], math.radians(self._p["conspicuity"]))

    def _looks_at(self, t: float) -> bool:
        return t >= self._next_look - 1e-9

    def _register(self, t: float, x: float, y: float, th: float, ego: np.ndarray | None) -> tuple[float, Seen | None]:
        self._next_look = t + self._p["look_interval"]
        u = float(self._rng.random())  # drawn on every look: the same draws whatever it sees
        if ego is None or u < self.failure(np.array([x, y, th]), ego, self.ego_share):
            return t, None
        return t, (float(ego[0]), float(ego[1]), float(ego[3]))

    def _act(self, t: float, x: float, v: float) -> float:
        return self._stop_then_judge(t, x, v)


class MisjudgedSpeedDriver(_CrashDriver):
    """Misjudged approach speed (see the module docstring): it looks all the time, registers
    the ego's speed as ``speed_factor`` of the truth, rests ``dwell`` on its line and goes
    once its picture gives it the gap: one that is ``1 / speed_factor`` too long in its eyes."""

    family = "misjudged-speed"
    Params = MisjudgedSpeedParams
    accepts = MisjudgedSpeedParams

    def _register(self, t: float, x: float, y: float, th: float, ego: np.ndarray | None) -> tuple[float, Seen | None]:
        if ego is None:
            return t, None
        return t, (float(ego[0]), float(ego[1]), self._p["speed_factor"] * float(ego[3]))

    def _act(self, t: float, x: float, v: float) -> float:
        return self._stop_then_judge(t, x, v)


class DistractedDriver(_CrashDriver):
    """Distracted (see the module docstring): at rest on its line, it goes at ``dwell`` on
    its last look, taken ``glance_away`` before then, with no fresh one. A last look before
    the episode's start is of the ego where it was then: moved back along its heading at its
    speed (the world's ego drives at its speed before the episode) from where it is at the
    start, if it is in sight then (else the look saw no ego). If that stale look does not give
    it the gap, it looks again, all the time, and goes once it has the gap; once it has
    pulled out its eyes are back on the road."""

    family = "distracted"
    Params = DistractedParams
    accepts = DistractedParams

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        super().reset(layout, intent, rng)
        self._t_look = self._p["dwell"] - self._p["glance_away"]  # [s] its last look (< 0: before the start)
        self._stale = True  # on its stale look still

    def _looks_at(self, t: float) -> bool:
        if not self._stale:
            return True
        return not self._looks and t >= max(self._t_look, 0.0) - 1e-9

    def _register(self, t: float, x: float, y: float, th: float, ego: np.ndarray | None) -> tuple[float, Seen | None]:
        if not self._stale or self._t_look >= t - 1e-9:
            return super()._register(t, x, y, th, ego)
        if ego is None:  # not in sight at the start: its look saw no ego
            return self._t_look, None
        back = float(ego[3]) * (t - self._t_look)  # [m] the ego's run since its look
        eth = float(ego[2])
        return self._t_look, (float(ego[0]) - back * math.cos(eth), float(ego[1]) - back * math.sin(eth),
                              float(ego[3]))

    def _act(self, t: float, x: float, v: float) -> float:
        if self.mode == WAITING:
            if self._stale and t >= self._p["dwell"] - 1e-9:
                self._stale = False  # it decides now, on its last look; fresh looks from the next tick on
                if self._has_gap(t):
                    self.mode = GOING
            elif self._stale or not self._has_gap(t):
                return self._hold()
            else:
                self.mode = GOING
        if self.mode == WAITING:
            return self._hold()
        return self._go(t, x, v)


class CreeperDriver(_CrashDriver):
    """A creeper (see the module docstring): from the episode's start it edges forward at
    ``creep_speed`` towards ``creep_distance`` past its line, looking all the time, and goes
    as soon as its picture gives it the (short) gap; if it does not, it waits at the end of
    its creep. With the chance ``restop_chance`` (one uniform drawn at reset) it stops again
    at the end of its creep whatever it saw, stands ``restop_pause`` and only then judges."""

    family = "creeper"
    extra_draws = ("restops",)  # 1: it stops again at the end of its creep this episode, 0: it does not
    Params = CreeperParams
    accepts = CreeperParams

    def reset(self, layout: Layout, intent: int, rng: np.random.Generator) -> None:
        super().reset(layout, intent, rng)
        self.restops = bool(rng.random() < self._p["restop_chance"])  # this episode it stops again
        self.params = MappingProxyType({**self.params, "restops": float(self.restops)})  # in the records
        self._restop_since: float | None = None  # [s] when it came to rest at the end of its creep

    def _act(self, t: float, x: float, v: float) -> float:
        p = self._p
        if self.mode == WAITING:
            approach = self._at_line(t, x, v)
            if approach is not None:
                return approach
            creep = self._stop_at(p["creep_distance"], x, v, p["creep_speed"])
            if self.restops:
                if self._restop_since is None:
                    if x < p["creep_distance"] - AT_TARGET or v >= AT_REST:
                        return creep
                    self._restop_since = t
                if t - self._restop_since < p["restop_pause"] - 1e-9:
                    return self._hold()
            if not self._has_gap(t):
                return creep
            self.mode = GOING
        return self._go(t, x, v)
