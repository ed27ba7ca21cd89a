"""Where and when the ego and a left-turning obstacle collide: the junction's conflict map
and the compiled rollouts of the risk decision rule.

A left-turner crosses into the ego's lane and then drives along it, so whether the two
collision boxes overlap depends only on two arc lengths: ``s`` of the obstacle on its
left route and ``q`` of the ego on its route. :class:`ConflictMap` tabulates, for every
``s`` (0.1 m apart, the route extended straight past its end), the interval
``[q_lo(s), q_hi(s)]`` of the ego's arc lengths at which the boxes (each widened by a
margin) overlap: one table per junction and pair of cars, built once in a compiled pass
(0.03 s for the package's junction, whose routes run 150 m on) and cached per layout. The
*conflict zone* is the stretch of the ego's route that the obstacle sweeps while it
turns in: the ego's arc lengths at which its box overlaps the obstacle's anywhere from
the obstacle's first overlap with the ego's path until its rear axle reaches the
conflict point.

:class:`Futures` are weighted hypotheses of the obstacle's motion along that route
(arc length, speed, acceleration up to a cruise speed, a delay before it moves), as a
predictor gives them; :func:`collision_masses` rolls each forward on the tick grid
against the ego's plans (:func:`ego_plans`: going on, going on and then braking,
braking now) and sums the weights of those that collide, by which plans they collide
with. Both are Numba kernels (``cache=True``: compiled once per install, then loaded);
the hypotheses are looped over once, with an early exit. ::

    cmap = conflict_map(layout, margin=0.3)
    plans = ego_plans(cmap.ego_arc(ego_pose), v, v_nom, gain, a_max, b, n_defer, n_steps, dt)
    masses = collision_masses(f.weight, f.s, f.v, f.accel, f.v_max, f.delay, plans, dt,
                              cmap.ds, cmap.q_lo, cmap.q_hi, cmap.q_lo_ahead, GO, DEFER)

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from cdf_mj.model import road
from cdf_mj.model.geometry import Polyline, _box_gap
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry

__all__ = [
    "BRAKE",
    "DEFER",
    "FULL_SIZE_LENGTH",
    "GO",
    "ConflictMap",
    "Futures",
    "collision_masses",
    "conflict_map",
    "ego_plans",
    "lane_entry",
    "resolution",
    "right_turn_overlap",
    "route_poses",
    "widened",
]

#: Rows of :func:`ego_plans` and bits of :func:`collision_masses`' index: the ego goes on
#: at its nominal speed; goes on for ``n_defer`` ticks, then brakes; brakes now.
GO, DEFER, BRAKE = 0, 1, 2

# Resolution of the tables for full-size cars; for smaller cars (a 1:10 testbed) every one
# of these lengths shrinks with the cars (:func:`resolution`), so that a table's spacing
# stays the same fraction of a car wherever the junction's scale puts it.
_DS = 0.1  # [m] table spacing along both routes
_EXTEND = 60.0  # [m] the routes go on straight past their last waypoint by this much
_WINDOW = 0.5  # [m] half chord of a route's heading (route_poses)
#: [m] Cars this long or longer use the lengths above (the package's car, whose scenario
#: they were set for); a shorter pair scales them by its shorter car's length over this
#: one, so that a junction and cars shrunk together give the same tables, shrunk.
FULL_SIZE_LENGTH = 4.6


def resolution(layout: Layout) -> float:
    """The factor in (0, 1] on the tables' spacings for ``layout``'s cars: 1 for full-size
    cars (both at least :data:`FULL_SIZE_LENGTH` long), else the shorter car's length over it."""
    return min(1.0, min(layout.ego.length, layout.obstacle.length) / FULL_SIZE_LENGTH)


def route_poses(route: Polyline, s: np.ndarray, window: float = _WINDOW) -> np.ndarray:
    """Poses ``(len(s), 4)`` (speed 0) on ``route`` at arc lengths ``s`` [m]: the point and the
    direction of the chord of ``2 window`` [m] about it; past the last waypoint the route
    goes on straight along its last segment."""
    s = np.asarray(s, dtype=float)
    end = route.length
    last = route.points[-1] - route.points[-2]
    last = last / np.hypot(*last)
    xy = route.point_at(np.minimum(s, end)) + np.maximum(s - end, 0.0)[:, None] * last
    lo = np.clip(s - window, 0.0, end)
    hi = np.clip(s + window, 0.0, end)
    a, b = route.point_at(lo), route.point_at(hi)
    heading = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
    heading[s + window > end] = math.atan2(last[1], last[0])
    out = np.zeros((len(s), 4))
    out[:, :2], out[:, 2] = xy, heading
    return out


def _reach_centre(car: CarGeometry) -> float:
    """[m] half the diagonal of the car's collision box."""
    return float(np.hypot(*car.hull_half))


def _centres(car: CarGeometry, poses: np.ndarray) -> np.ndarray:
    """Centres ``(len(poses), 2)`` [m] of the car's collision box at rear-axle poses."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    ox, oy = car.hull_offset
    return np.column_stack([poses[:, 0] + c * ox - s * oy, poses[:, 1] + s * ox + c * oy])


@dataclass(frozen=True, eq=False)
class ConflictMap:
    """The overlap table of one junction and pair of cars (see the module docstring).

    Attributes:
        route_ego: the ego's route (``q`` is arc length on it) [m].
        ds: [m] spacing of the table along the obstacle's left route, from ``s = 0``.
        q_lo, q_hi: ``(J,)`` the ego's arc lengths [m] between which the boxes overlap with
            the obstacle at ``s = j ds``; ``inf``/``-inf`` where they never do.
        q_lo_ahead: ``(J,)`` the least ``q_lo`` from ``j`` on [m].
        zone: ``(q_lo, q_hi)`` [m] the conflict zone on the ego's route.
        margin: [m] added to each half size of both boxes.
        window: [m] half chord of the routes' headings (:func:`route_poses`) at this
            junction's resolution.
    """

    route_ego: Polyline
    ds: float
    q_lo: np.ndarray
    q_hi: np.ndarray
    q_lo_ahead: np.ndarray
    zone: tuple[float, float]
    margin: float
    window: float = _WINDOW

    @classmethod
    def build(cls, layout: Layout, margin: float = 0.0) -> ConflictMap:
        """The table of ``layout``'s left route, ego route and cars, boxes widened by ``margin`` [m]."""
        left, ego_route = layout.route_left, layout.route_ego
        k = resolution(layout)
        ds, window = _DS * k, _WINDOW * k
        s = np.arange(0.0, left.length + _EXTEND * k, ds)
        q = np.arange(0.0, ego_route.length + _EXTEND * k, ds)
        obs, ego = route_poses(left, s, window), route_poses(ego_route, q, window)
        wide_obs = widened(layout.obstacle, margin)
        wide_ego = widened(layout.ego, margin)
        q_lo, q_hi = _overlaps(wide_obs, obs, wide_ego, ego, q)
        first = np.flatnonzero(np.isfinite(q_lo))
        if first.size == 0:
            raise ValueError("the obstacle's left route never meets the ego's route: no conflict to "
                             "assess (check the routes of the scene)")
        s_conflict = float(left.project(layout.conflict)[0])
        sweep = slice(first[0], max(first[0] + 1, int(s_conflict / ds) + 1))
        zone = (float(np.min(q_lo[sweep])), float(np.max(q_hi[sweep])))
        q_lo_ahead = np.minimum.accumulate(q_lo[::-1])[::-1].copy()
        for a in (q_lo, q_hi, q_lo_ahead):
            a.flags.writeable = False
        return cls(route_ego=ego_route, ds=ds, q_lo=q_lo, q_hi=q_hi, q_lo_ahead=q_lo_ahead, zone=zone,
                   margin=margin, window=window)

    def ego_arc(self, ego_pose: np.ndarray) -> float:
        """[m] the ego's arc length on its route for its pose ``(4,)``."""
        return self.route_ego.project_point(float(ego_pose[0]), float(ego_pose[1]))[0]

    def inside(self, q: float) -> bool:
        """Whether the ego at arc length ``q`` [m] is inside the conflict zone."""
        return self.zone[0] <= q <= self.zone[1]

    def cleared(self, q: float) -> bool:
        """Whether the ego at arc length ``q`` [m] has left the conflict zone behind."""
        return q > self.zone[1]


def widened(car: CarGeometry, margin: float) -> CarGeometry:
    """``car`` with ``margin`` [m] added to each half size of its collision box (a car at
    :class:`CarGeometry`'s largest size too: :meth:`CarGeometry.padded`)."""
    return car.padded(margin) if margin else car


def _overlaps(car_a: CarGeometry, poses_a: np.ndarray, car_b: CarGeometry, poses_b: np.ndarray,
              q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose of car ``a``, the least and greatest ``q`` [m] of the poses of car ``b`` whose
    collision boxes it overlaps or touches (``inf``/``-inf`` if none): candidate pairs are
    box centres within the sum of the half diagonals, then the exact box test, in one
    compiled pass."""
    reach = _reach_centre(car_a) + _reach_centre(car_b)
    return _overlap_table(car_a.footprint(poses_a), car_b.footprint(poses_b), _centres(car_a, poses_a),
                          _centres(car_b, poses_b), q, reach)


@functools.lru_cache(maxsize=16)
def lane_entry(layout: Layout, within: float = math.pi / 2) -> int:
    """The first index of :class:`ConflictMap`'s tables (``s = j ds`` [m] on the obstacle's
    left route) at which the obstacle's collision box is in the ego's lane
    (:func:`cdf_mj.model.road.in_lane`) heading the ego's way within ``within`` [rad] of the
    ego's route there: from it on the obstacle counts as a car ahead in the ego's lane, to
    keep the RSS distance behind (:func:`collision_masses`' ``lane_from``); past the table's
    end if it never is. Cached per layout."""
    if not 0.0 <= within <= math.pi:
        raise ValueError(f"lane_entry: within={within!r} must be in [0, pi] [rad]")
    left, ego_route = layout.route_left, layout.route_ego
    k = resolution(layout)
    ds = _DS * k
    s = np.arange(0.0, left.length + _EXTEND * k, ds)
    poses = route_poses(left, s, _WINDOW * k)
    for j, pose in enumerate(poses):
        q = ego_route.project_point(float(pose[0]), float(pose[1]))[0]
        heading = float(route_poses(ego_route, np.array([q]), _WINDOW * k)[0, 2])
        if road.heading_within(float(pose[2]), heading, within) and road.in_lane(
                layout, layout.obstacle.footprint_one(float(pose[0]), float(pose[1]), float(pose[2]))):
            return j
    return len(s)


@functools.lru_cache(maxsize=16)
def right_turn_overlap(layout: Layout) -> float | None:
    """[m] the first arc length on the obstacle's right route (0.1 m apart for full-size
    cars, :func:`resolution`) at which its
    collision box overlaps the ego's, the ego anywhere on its route; None if it never does.
    The drivers' model, and every predictor built on it, takes a right-turner for one that
    never meets the ego: where this is not None (a long car, a tight right turn), a
    right-turner can hit the ego unforeseen. Cached per layout."""
    right, ego_route = layout.route_right, layout.route_ego
    k = resolution(layout)
    s = np.arange(0.0, right.length, _DS * k)
    q = np.arange(0.0, ego_route.length + _EXTEND * k, _DS * k)
    q_lo, _ = _overlaps(layout.obstacle, route_poses(right, s, _WINDOW * k), layout.ego,
                        route_poses(ego_route, q, _WINDOW * k), q)
    hit = np.flatnonzero(np.isfinite(q_lo))
    return float(s[hit[0]]) if hit.size else None


@numba.njit(cache=True, nogil=True)
def _overlap_table(obs: np.ndarray, ego: np.ndarray, obs_c: np.ndarray, ego_c: np.ndarray, q: np.ndarray,
                   reach: float) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Per obstacle box ``obs[j]`` (corners ``(4, 2)``), the least and greatest ``q[i]`` of
    the ego boxes ``ego[i]`` that it overlaps or touches (``inf``/``-inf`` if none), testing
    only pairs whose centres are within ``reach`` [m]."""
    q_lo = np.full(obs.shape[0], np.inf)
    q_hi = np.full(obs.shape[0], -np.inf)
    r2 = reach * reach
    for j in range(obs.shape[0]):
        for i in range(ego.shape[0]):
            dx, dy = obs_c[j, 0] - ego_c[i, 0], obs_c[j, 1] - ego_c[i, 1]
            if dx * dx + dy * dy <= r2 and _box_gap(obs[j], ego[i]) == 0.0:
                q_lo[j] = min(q_lo[j], q[i])
                q_hi[j] = max(q_hi[j], q[i])
    return q_lo, q_hi


@functools.lru_cache(maxsize=16)
def conflict_map(layout: Layout, margin: float = 0.0) -> ConflictMap:
    """:meth:`ConflictMap.build`, cached per layout object and margin (a scene's layout is
    the same object for all its episodes)."""
    return ConflictMap.build(layout, margin)


@dataclass(frozen=True)
class Futures:
    """Weighted hypotheses of a left-turner's motion along its route, ``(M,)`` arrays.

    ``weight`` is the probability of the hypothesis times the probability that the driver
    goes on along it (does not yield); from ``delay`` [s] on it moves from arc length
    ``s`` [m] with speed ``v`` [m/s] changing at ``accel`` [m/s^2] and kept in
    ``[0, v_max]`` [m/s]; before ``delay`` it stands. Right-turners never enter the ego's
    lane and are left out.
    """

    weight: np.ndarray
    s: np.ndarray
    v: np.ndarray
    accel: np.ndarray
    v_max: np.ndarray
    delay: np.ndarray

    @classmethod
    def empty(cls) -> Futures:
        """No hypothesis of a left-turner."""
        z = np.zeros(0)
        return cls(z, z, z, z, z, z)


@numba.njit(cache=True, nogil=True)
def ego_plans(q0: float, v0: float, v_nominal: float, gain: float, max_accel: float, max_brake: float,
              n_defer: int, n_steps: int, dt: float) -> np.ndarray:  # pragma: no cover - compiled
    """The ego's arc length [m] at ticks ``1..n_steps`` ``(3, n_steps)`` under the plans
    :data:`GO` (its nominal controller: acceleration ``gain (v_nominal - v)`` within
    ``[-max_brake, max_accel]``), :data:`DEFER` (that for ``n_defer`` ticks, then braking at
    ``max_brake`` [m/s^2]) and :data:`BRAKE` (braking now); from arc length ``q0`` [m]
    and speed ``v0`` [m/s], constant acceleration within a tick, speed kept >= 0."""
    out = np.empty((3, n_steps))
    for plan in range(3):
        brake_from = n_steps if plan == 0 else (n_defer if plan == 1 else 0)
        q, v = q0, v0
        for k in range(n_steps):
            a = -max_brake if k >= brake_from else min(max(gain * (v_nominal - v), -max_brake), max_accel)
            v1 = v + a * dt
            if v1 < 0.0:  # stops within the tick
                q += v * v / (2.0 * max_brake) if a < 0.0 else 0.0
                v = 0.0
            else:
                q += 0.5 * (v + v1) * dt
                v = v1
            out[plan, k] = q
    return out


@numba.njit(cache=True, nogil=True)
def collision_masses(weight: np.ndarray, s0: np.ndarray, v0: np.ndarray, accel: np.ndarray,
                     v_max: np.ndarray, delay: np.ndarray, plans: np.ndarray, dt: float, ds: float,
                     q_lo: np.ndarray, q_hi: np.ndarray, q_lo_ahead: np.ndarray,
                     lazy: int = -1, gate: int = -1, rss_rows: int = 0, rss_brake: float = 1.0,
                     lane_from: int = 0, lead_brake: float = 1.0) -> np.ndarray:  # pragma: no cover - compiled
    """Total weight of the hypotheses (:class:`Futures` arrays) by the plans they collide
    with: ``out[m]`` for the bit mask ``m`` (bit ``p`` set: it collides with plan row ``p``
    of ``plans``, the ego's arc lengths ``(P, K)`` at ticks ``1..K`` of ``dt`` [s]).

    Each hypothesis is rolled forward tick by tick (speed ``v0 + accel (t - delay)`` kept in
    ``[0, v_max]``, trapezoidal arc length); it collides with a plan at the first tick its
    arc length puts the ego's inside ``[q_lo, q_hi]`` of the table (``ds`` [m] apart).
    Past the table's end nothing collides. ``q_lo_ahead[j]`` is the least ``q_lo`` from
    ``j`` on: once it lies beyond a plan's furthest arc length, that plan can no longer
    collide with the hypothesis (its arc length never decreases), which ends its roll.

    With plan rows ``lazy`` and ``gate`` (not -1), plan ``lazy`` is followed only for the
    hypotheses that collide with plan ``gate``: the others' ``lazy`` bit stays unset, so
    only the masses with the ``gate`` bit set are exact for ``lazy`` (the risk rule reads
    GO only together with DEFER, and going on is the plan whose rolls are longest).

    Once a single plan is left open (most often going on, behind a car that has merged
    ahead), its roll skips the table while the plan's arc length is short of ``q_lo_ahead``
    where the hypothesis last was (no overlap can come before it: the hypothesis only moves
    on): the same masks, about a fifth less time in CDF episodes at N = 1000 (docs/PERFORMANCE.md).

    The plan rows in the bit mask ``rss_rows`` (plans that end braking at ``rss_brake``
    [m/s^2]) also collide with a hypothesis that leaves them short of the RSS distance behind
    the obstacle once it is in the ego's lane heading its way (table index ``lane_from`` on,
    :func:`lane_entry`): on a tick on which the ego is behind the obstacle's box, the plan's
    stopping point (its last arc length plus the braking distance from its last tick's
    speed) reaches past where the ego's box would touch the obstacle's had the obstacle
    braked to a stop from then at ``lead_brake`` [m/s^2]. This is the RSS longitudinal rule
    (docs/DECISION.md) with the plan itself as the ego's response and its braking; with no
    such row (0) the masks are as without these arguments."""
    n_plans, n_steps = plans.shape
    full = (1 << n_plans) - 1
    lazy_bit = (1 << lazy) if lazy >= 0 else 0
    gate_bit = (1 << gate) if gate >= 0 else 0
    out = np.zeros(1 << n_plans)
    n_table = q_lo.shape[0]
    inv_ds, half_dt = 1.0 / ds, 0.5 * dt
    first = 0  # the first table entry with an overlap: before it nothing can collide
    while first < n_table and not q_lo[first] <= q_hi[first]:
        first += 1
    s_first = (first - 0.5) * ds  # [m] below it, the table index is below first
    furthest = np.empty(n_plans)  # [m] each plan's last arc length (the RSS row's: its stop, if further)
    for p in range(n_plans):
        furthest[p] = plans[p, n_steps - 1]
    stops = np.empty(n_plans)  # [m] where the RSS rows stop
    for p in range(n_plans):
        if (rss_rows >> p) & 1:
            v_end = 0.0  # [m/s] its last speed, from its last tick's advance at the constant brake
            if n_steps > 1:
                v_end = (plans[p, n_steps - 1] - plans[p, n_steps - 2]) / dt - 0.5 * rss_brake * dt
            stops[p] = plans[p, n_steps - 1] + max(v_end, 0.0) ** 2 / (2.0 * rss_brake)
            furthest[p] = max(furthest[p], stops[p])
    inv_2b = 0.5 / lead_brake
    single = np.full(1 << n_plans, -1, dtype=np.int64)
    for p in range(n_plans):
        single[full ^ (1 << p)] = p
    for i in range(weight.shape[0]):
        w = weight[i]
        if w <= 0.0:
            continue
        s, v, a, vm, d = s0[i], v0[i], accel[i], v_max[i], delay[i]
        if vm < v:
            vm = v
        v_start = v if d <= 0.0 else 0.0  # a held-back driver stands, then pulls away
        v_prev = v_start
        mask = 0
        done = 0  # plans that collided or no longer can
        for k in range(n_steps):
            t = (k + 1) * dt
            v_now = min(max(v_start + a * (t - d), 0.0), vm) if t > d else 0.0
            s += (v_prev + v_now) * half_dt
            v_prev = v_now
            if s < s_first:
                continue
            j = int(s * inv_ds + 0.5)
            if j >= n_table:
                break
            if j < first:
                continue
            ahead = q_lo_ahead[j]
            lo, hi = q_lo[j], q_hi[j]
            for p in range(n_plans):
                bit = 1 << p
                if done & bit:
                    continue
                q = plans[p, k]
                if lo <= q <= hi:
                    mask |= bit
                    done |= bit
                elif ahead > furthest[p]:
                    done |= bit
                elif (rss_rows >> p) & 1 and j >= lane_from and q < lo:  # behind it in the lane: short of RSS?
                    j_stop = min(int((s + v_now * v_now * inv_2b) * inv_ds + 0.5), n_table - 1)
                    if stops[p] >= q_lo[j_stop]:
                        mask |= bit
                        done |= bit
            settled = done | lazy_bit if (done & gate_bit) and not (mask & gate_bit) else done
            if settled == full:
                break
            p = single[done]
            if p >= 0 and not (rss_rows >> p) & 1:  # one plan left (a lazy one only if its gate collided): alone
                far = furthest[p]
                kk = k + 1
                while kk < n_steps:
                    # Short of the least overlap ahead, no tick can overlap (plan and
                    # hypothesis only move on): the table is not read.
                    while kk < n_steps and plans[p, kk] < ahead:
                        t = (kk + 1) * dt
                        v_now = min(max(v_start + a * (t - d), 0.0), vm) if t > d else 0.0
                        s += (v_prev + v_now) * half_dt
                        v_prev = v_now
                        kk += 1
                    if kk >= n_steps:
                        break
                    t = (kk + 1) * dt
                    v_now = min(max(v_start + a * (t - d), 0.0), vm) if t > d else 0.0
                    s += (v_prev + v_now) * half_dt
                    v_prev = v_now
                    j = int(s * inv_ds + 0.5)
                    if j >= n_table:
                        break
                    q = plans[p, kk]
                    if q_lo[j] <= q <= q_hi[j]:
                        mask |= 1 << p
                        break
                    ahead = q_lo_ahead[j]
                    if ahead > far:
                        break
                    kk += 1
                break
        out[mask] += w
    return out
