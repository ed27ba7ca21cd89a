"""Compiled per-car code of the drivers: route projection, the obstacle driver's state
machine, pure pursuit, the belief update and the kinematic bicycle, one car at a time.

These Numba functions are the single implementation of the driver model. The array
functions of :mod:`cdf_mj.model.driver` (one simulated car, or any N) loop over them, and
the particle filter's fused kernels (:mod:`cdf_mj.inference.kernels`) call them per
particle, so the world's obstacle and every hypothesis of the filter drive by the same
code. All are ``numba.njit(cache=True)``: compiled on first use after an install (a few
seconds, once), then loaded from Numba's cache (``__pycache__`` beside this file, or
``NUMBA_CACHE_DIR``).

Routes are packed into a :class:`RouteTable`: for route ``r`` and segment ``k``, the row
``table[r, k] = [x0, y0, ux, uy, length, s0, reach2]`` (segment start [m], unit direction,
length [m], arc length at its start [m], and the route's tracking radius squared [m^2],
below), ``nseg[r]`` segments, ``ends[r]`` the last waypoint.

Projection onto a route *tracks*: a car keeps the index of the segment it was last
projected on, and the next projection walks from there to the neighbouring segment while
that one is nearer (a descent on the distance along the route), instead of searching all
segments. A car near its route, moving less than a segment per tick, gets the same
closest point as the full search (tests/test_kernels.py checks it over whole episodes);
a car found further from its route than the route's tracking radius, or a segment index
< 0, gets the full search (the first minimum, as
:meth:`cdf_mj.model.geometry.Polyline.project`). The tracking radius is
:data:`TRACK_RADIUS`, or the route's tightest local radius of turn where that is smaller
(:func:`tracking_radius`): beyond it, inside a tight turn, the walk can stop at a local
nearest segment.

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``.
"""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import numba
import numpy as np

from cdf_mj.model.geometry import Polyline
from cdf_mj.model.modes import COMMITTED, GOING, RIGHT, WAITING, YIELDING  # Numba constants
from cdf_mj.traits import PER_CAR, SHARED

__all__ = ["DRIVER_FIELDS", "EGO_FIELDS", "LAYOUT", "LAYOUTS", "RouteTable", "compile_pending", "helper",
           "layout_digest", "offsets", "pack", "pack_driver", "pack_ego", "tracking_radius"]

F = TypeVar("F", bound=Callable[..., Any])

#: Entries of the float vector ``cfg`` that the driver kernels read (:func:`pack_driver`): the
#: tick [s], the obstacle car's limits, its pure pursuit, the traits shared by every car
#: (:data:`cdf_mj.traits.SHARED`), the conflict point and the commit point on each route [m].
DRIVER_FIELDS = ("dt", "wheelbase", "max_steer", "max_brake", "lookahead", "lookahead_gain", *SHARED,
                 "conflict_x", "conflict_y", "s_commit_left", "s_commit_right")
#: Entries of the ego controller's float vector (:func:`pack_ego`, :func:`ego_control`).
EGO_FIELDS = ("lookahead", "lookahead_gain", "wheelbase", "max_steer", "speed", "speed_gain", "max_brake",
              "max_accel")
#: [m] Beyond this distance from its route (or the route's tighter radius of turn,
#: :func:`tracking_radius`) a car's tracked projection is checked by the full search.
TRACK_RADIUS = 3.0
#: The segment index that asks :func:`project` for the full search (an int64, not the
#: literal -1, for which Numba would compile the projection a second time).
NO_SEGMENT = np.int64(-1)


def offsets(fields: tuple[str, ...]) -> dict[str, int]:
    """Name -> index of a packed float vector's entries."""
    return {name: i for i, name in enumerate(fields)}


def pack(fields: tuple[str, ...], values: Mapping[str, float]) -> np.ndarray:
    """The float vector of ``fields``, each entry taken from ``values`` by its name;
    ValueError naming the names missing or not among ``fields``."""
    missing, extra = sorted(set(fields) - set(values)), sorted(set(values) - set(fields))
    if missing or extra:
        raise ValueError(f"pack: missing {missing}, unknown {extra}; the fields are {', '.join(fields)}")
    return np.array([values[name] for name in fields], dtype=float)


def layout_digest(*layouts: tuple[str, ...]) -> str:
    """A short digest of the names (orders) of packed vectors and columns: see :data:`LAYOUT`."""
    return hashlib.sha256(repr(layouts).encode()).hexdigest()[:12]


# Index constants, plain ints computed from the names at import (Numba reads them as
# compile-time constants): the driver's vector, the ego's and the per-car parameter columns.
_AT, _EGO_AT = offsets(DRIVER_FIELDS), offsets(EGO_FIELDS)
C_DT, C_WHEELBASE, C_MAX_STEER, C_MAX_BRAKE = _AT["dt"], _AT["wheelbase"], _AT["max_steer"], _AT["max_brake"]
C_LOOKAHEAD, C_GAIN, C_PASSED = _AT["lookahead"], _AT["lookahead_gain"], _AT["passed_margin"]
C_CX, C_CY, C_COMMIT = _AT["conflict_x"], _AT["conflict_y"], _AT["s_commit_left"]  # commit of intent i: C_COMMIT + i
E_LOOKAHEAD, E_GAIN, E_WHEELBASE, E_MAX_STEER = (_EGO_AT[n] for n in ("lookahead", "lookahead_gain", "wheelbase",
                                                                      "max_steer"))
E_SPEED, E_SPEED_GAIN, E_MAX_BRAKE, E_MAX_ACCEL = (_EGO_AT[n] for n in ("speed", "speed_gain", "max_brake",
                                                                        "max_accel"))
P_ACCEL, P_TURN, P_YIELD, P_GAP, P_CLEAR = (PER_CAR.index(n) for n in ("accel", "turn_speed", "yield_brake",
                                                                       "critical_gap", "clear_distance"))
if _AT["s_commit_right"] != C_COMMIT + RIGHT:
    raise ValueError("DRIVER_FIELDS: s_commit_right must follow s_commit_left (the kernels read C_COMMIT + intent)")
#: The names the index constants above are computed from.
LAYOUTS = (DRIVER_FIELDS, EGO_FIELDS, PER_CAR)
#: Numba's cache keys a kernel on this file's text, not on :data:`LAYOUTS`: their digest
#: (:func:`layout_digest`) written here puts them in the text, so that a new layout
#: recompiles. tests/test_traits.py checks it and gives the new value.
LAYOUT = "8cc0a86ccbca"
#: Whether Numba's cache may be used: only while :data:`LAYOUT` is the digest of the layouts
#: now. After a change of the traits' schema that moves a column or an offset, until the
#: stamp is updated, the kernels compile afresh on every run (a warning says so): slower
#: to start, never a stale kernel reading the old offsets.
CACHE = layout_digest(*LAYOUTS) == LAYOUT
if not CACHE:
    warnings.warn(f"{__name__}: the packed layouts changed (digest {layout_digest(*LAYOUTS)}, stamp {LAYOUT}): "
                  "compiling without Numba's cache; set LAYOUT to the new digest (tests/test_traits.py)",
                  RuntimeWarning, stacklevel=1)


@dataclass(frozen=True, eq=False)
class RouteTable:
    """Polylines packed for the kernels: ``table`` ``(R, S, 7)``, ``nseg`` ``(R,)``,
    ``ends`` ``(R, 2)`` (see the module docstring); rows past ``nseg[r]`` are unused."""

    table: np.ndarray
    nseg: np.ndarray
    ends: np.ndarray

    @classmethod
    def of(cls, routes: tuple[Polyline, ...]) -> RouteTable:
        """The table of ``routes`` (route ``r`` = ``routes[r]``)."""
        n = max(len(r.points) - 1 for r in routes)
        table = np.zeros((len(routes), n, 7))
        for r, route in enumerate(routes):
            k = len(route.points) - 1
            table[r, :k] = np.column_stack([route._x0, route._y0, route._ux, route._uy, route._len,
                                            route._s0[:-1], np.full(k, tracking_radius(route) ** 2)])
        nseg = np.array([len(r.points) - 1 for r in routes], dtype=np.int64)
        ends = np.array([r.points[-1] for r in routes], dtype=float)
        for a in (table, nseg, ends):
            a.flags.writeable = False
        return cls(table, nseg, ends)


def tracking_radius(route: Polyline) -> float:
    """[m] how far from ``route`` a tracked projection is trusted: :data:`TRACK_RADIUS`, or
    the route's tightest local radius of turn if smaller. At an inner waypoint turning by
    ``theta`` between segments of lengths ``a`` and ``b`` that radius is ``min(a, b) /
    theta`` (a polyline along a circle of radius R gives R); a point nearer the route than
    every such radius lies on one normal of it only, so the walk's local nearest segment
    is the nearest."""
    ux, uy = route._ux, route._uy
    turn = np.abs(np.arctan2(ux[:-1] * uy[1:] - uy[:-1] * ux[1:], ux[:-1] * ux[1:] + uy[:-1] * uy[1:]))
    shorter = np.minimum(route._len[:-1], route._len[1:])
    with np.errstate(divide="ignore"):
        radius = np.where(turn > 0.0, shorter / turn, np.inf)
    return float(min(TRACK_RADIUS, radius.min(initial=np.inf)))


def helper(fn: F, cache: bool | None = None) -> F:
    """Compile a per-car helper: ``numba.njit(cache=CACHE, nogil=True)`` without Numba's
    reference counting (``_nrt=False``). A helper allocates nothing, and a kernel calls it
    once per particle with array arguments, whose reference counts Numba would otherwise
    raise and drop on every call: two atomic operations per array, 39 ns a call against
    1.5 ns without (``scripts/kernel_costs.py``, docs/PERFORMANCE.md). ``cache``: whether
    Numba's cache may be used (default: this module's :data:`CACHE`; a kernel module that
    reads layouts of its own passes its own)."""
    compile_: Any = numba.njit  # _nrt is a compiler flag that numba's stubs do not list
    return compile_(cache=CACHE if cache is None else cache, nogil=True,  # type: ignore[no-any-return]
                    _nrt=False)(fn)


def pack_driver(values: Mapping[str, float]) -> np.ndarray:
    """The float vector ``cfg`` of :data:`DRIVER_FIELDS`, by name (:func:`pack`); kernels of
    other modules append their own entries after these."""
    return pack(DRIVER_FIELDS, values)


def pack_ego(values: Mapping[str, float]) -> np.ndarray:
    """The ego controller's float vector of :data:`EGO_FIELDS`, by name (:func:`pack`)."""
    return pack(EGO_FIELDS, values)


@helper
def _segment(table: np.ndarray, r: int, k: int, x: float, y: float) -> tuple[float, float]:
    """Squared distance [m^2] from (x, y) to segment ``k`` of route ``r``, and the arc
    length [m] of the closest point."""
    px = x - table[r, k, 0]
    py = y - table[r, k, 1]
    ux, uy = table[r, k, 2], table[r, k, 3]
    t = min(max(px * ux + py * uy, 0.0), table[r, k, 4])
    px -= t * ux
    py -= t * uy
    return px * px + py * py, table[r, k, 5] + t


@helper
def _nearest(table: np.ndarray, nseg: np.ndarray, r: int, x: float, y: float) -> tuple[float, int]:
    """The full search of :func:`project`: every segment, the first minimum."""
    best, s_best, k_best = math.inf, 0.0, 0
    for k in range(nseg[r]):
        d2, s = _segment(table, r, k, x, y)
        if d2 < best:  # the first minimum, as numpy.argmin
            best, s_best, k_best = d2, s, k
    return s_best, k_best


@helper
def project(table: np.ndarray, nseg: np.ndarray, r: int, x: float, y: float, k0: int) -> tuple[float, int]:
    """Arc length [m] of the closest point of route ``r`` to (x, y) and its segment,
    tracking from segment ``k0`` (the full search when ``k0 < 0`` or out of range, or
    when the tracked point is further than the route's tracking radius)."""
    n = nseg[r]
    if k0 < 0 or k0 >= n:
        return _nearest(table, nseg, r, x, y)
    best, s_best = _segment(table, r, k0, x, y)
    k = k0
    while k + 1 < n:  # walk ahead while nearer
        d2, s = _segment(table, r, k + 1, x, y)
        if d2 >= best:
            break
        best, s_best, k = d2, s, k + 1
    if k == k0:
        while k > 0:  # else back
            d2, s = _segment(table, r, k - 1, x, y)
            if d2 >= best:
                break
            best, s_best, k = d2, s, k - 1
    if best > table[r, k, 6]:  # beyond the route's tracking radius: a local nearest may not be the nearest
        return _nearest(table, nseg, r, x, y)
    return s_best, k


@helper
def point_at(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, s: float,
             k0: int) -> tuple[float, float]:
    """The point [m] of route ``r`` at arc length ``s`` (clamped to its ends), searching
    from segment ``k0``."""
    n = nseg[r]
    if s >= table[r, n - 1, 5] + table[r, n - 1, 4]:
        return ends[r, 0], ends[r, 1]
    k = min(max(k0, 0), n - 1)
    while k + 1 < n and table[r, k + 1, 5] <= s:
        k += 1
    while k > 0 and table[r, k, 5] > s:
        k -= 1
    d = max(s - table[r, k, 5], 0.0)
    return table[r, k, 0] + table[r, k, 2] * d, table[r, k, 1] + table[r, k, 3] * d


@numba.njit(cache=CACHE, nogil=True, inline="always")
def ahead_of_conflict(cx: float, cy: float, x: float, y: float, th: float) -> float:
    """[m] how far the conflict point (cx, cy) lies ahead of a car at (x, y) heading ``th``,
    along its heading (negative once past it). Scalars only, inlined where it is called
    (no compiled function of its own to pay for at a cold start)."""
    return float((cx - x) * math.cos(th) + (cy - y) * math.sin(th))


@numba.njit(cache=CACHE, nogil=True, inline="always")
def passed_or_far(passed_margin: float, ahead: float, v: float, critical_gap: float, clear_distance: float) -> bool:
    """The clear rule's test of an ego ``ahead`` [m] of the conflict point at speed ``v``
    [m/s]: past it by ``passed_margin``, or further than ``clear_distance`` and more than
    ``critical_gap`` [s] away (scalars only, inlined)."""
    if ahead < -passed_margin:
        return True
    return bool(ahead > clear_distance and ahead > critical_gap * max(v, 0.0))


@helper
def clear(cfg: np.ndarray, intent: int, has_belief: bool, bx: float, by: float, bth: float, bv: float,
          critical_gap: float, clear_distance: float) -> bool:
    """The driver's clear rule (:func:`cdf_mj.model.driver.road_clear`) for one driver."""
    if intent == RIGHT or not has_belief:
        return True
    return passed_or_far(cfg[C_PASSED], ahead_of_conflict(cfg[C_CX], cfg[C_CY], bx, by, bth), bv, critical_gap,
                         clear_distance)


@helper
def steer_to(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, x: float, y: float, c: float,
             s_th: float, s: float, k: int, lookahead: float, wheelbase: float, max_steer: float) -> float:
    """Pure pursuit: the steering angle [rad] pointing the rear axle at route ``r``'s point
    ``lookahead`` [m] ahead of arc length ``s`` (segment ``k``), for a car at (x, y) with
    heading cosine ``c`` and sine ``s_th`` and the given wheelbase [m]; within
    +-``max_steer`` [rad]."""
    tx, ty = point_at(table, nseg, ends, r, s + lookahead, k)
    dx, dy = tx - x, ty - y
    dist2 = max(dx * dx + dy * dy, 1e-12)
    # atan(2 L sin(alpha) / dist) with alpha = atan2(dy, dx) - theta, sin(alpha) = (dy c - dx s) / dist.
    steer = math.atan(2.0 * wheelbase * (dy * c - dx * s_th) / dist2)
    return min(max(steer, -max_steer), max_steer)


@helper
def drive(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, cfg: np.ndarray, intent: int, x: float,
          y: float, c: float, s_th: float, v: float, s: float, k: int, mode: int, is_clear: bool, may_go: bool,
          accel: float, turn_speed: float, yield_brake: float) -> tuple[float, float, int]:
    """The obstacle driver ``h`` of one car (:func:`cdf_mj.model.driver.obstacle_control`):
    its acceleration [m/s^2], steering [rad] and new mode, from its position, the cosine
    and sine of its heading, its speed, its arc length ``s`` on its own route (segment
    ``k``), its mode, whether its belief says clear (a committed driver ignores it),
    whether its stop is over, and its behaviour."""
    past_commit = s >= cfg[C_COMMIT + intent]
    new = mode
    if ((mode == WAITING and may_go) or mode == YIELDING) and is_clear:
        new = GOING
    if new == GOING and past_commit:
        new = COMMITTED  # before yielding: past it, no yield
    if mode == GOING and not is_clear and not past_commit:
        new = YIELDING
    if new == YIELDING:
        a = -yield_brake
    elif new == WAITING:
        a = -cfg[C_MAX_BRAKE]
    else:  # moving: towards the turn speed within the car's limits
        a = min(max((turn_speed - v) / cfg[C_DT], -cfg[C_MAX_BRAKE]), accel)
    steer = steer_to(table, nseg, ends, intent, x, y, c, s_th, s, k,
                     cfg[C_LOOKAHEAD] + cfg[C_GAIN] * v, cfg[C_WHEELBASE], cfg[C_MAX_STEER])
    return a, steer, new


@helper
def control(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, cfg: np.ndarray, intent: int, x: float,
            y: float, th: float, v: float, k: int, mode: int, has_belief: bool, bx: float, by: float, bth: float,
            bv: float, may_go: bool, accel: float, turn_speed: float, yield_brake: float, critical_gap: float,
            clear_distance: float) -> tuple[float, float, int, int]:
    """The obstacle driver of one car from its pose, kept segment ``k`` and belief:
    projection, clear rule and :func:`drive`; returns its acceleration, steering, new mode
    and new segment."""
    s, k = project(table, nseg, intent, x, y, k)
    ok = clear(cfg, intent, has_belief, bx, by, bth, bv, critical_gap, clear_distance)
    a, steer, new = drive(table, nseg, ends, cfg, intent, x, y, math.cos(th), math.sin(th), v, s, k, mode, ok,
                          may_go, accel, turn_speed, yield_brake)
    return a, steer, new, k


@numba.njit(cache=CACHE, nogil=True)
def obstacle_control_rows(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, cfg: np.ndarray,
                           pose: np.ndarray, mode: np.ndarray, belief: np.ndarray, has_belief: np.ndarray,
                           intent: np.ndarray, params: np.ndarray, may_go: np.ndarray,
                           seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`drive` for N cars (``params`` ``(N, P)``, the per-car traits
    :data:`cdf_mj.traits.PER_CAR`); ``seg`` ``(N,)`` is each car's segment, updated."""
    n = pose.shape[0]
    u = np.empty((n, 2))
    new = np.empty(n, dtype=np.int64)
    for i in range(n):
        u[i, 0], u[i, 1], new[i], seg[i] = control(
            table, nseg, ends, cfg, intent[i], pose[i, 0], pose[i, 1], pose[i, 2], pose[i, 3], seg[i], mode[i],
            has_belief[i], belief[i, 0], belief[i, 1], belief[i, 2], belief[i, 3], may_go[i], params[i, P_ACCEL],
            params[i, P_TURN], params[i, P_YIELD], params[i, P_GAP], params[i, P_CLEAR])
    return u, new


@numba.njit(cache=CACHE, nogil=True)
def clear_rows(cfg: np.ndarray, belief: np.ndarray, has_belief: np.ndarray, intent: np.ndarray,
               params: np.ndarray) -> np.ndarray:
    """:func:`clear` for N drivers (``params`` as in :func:`obstacle_control_rows`)."""
    n = belief.shape[0]
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        out[i] = clear(cfg, intent[i], has_belief[i], belief[i, 0], belief[i, 1], belief[i, 2],
                       belief[i, 3], params[i, P_GAP], params[i, P_CLEAR])
    return out


@helper
def bicycle(x: float, y: float, th: float, v: float, c: float, s: float, accel: float, steer: float, dt: float,
            wheelbase: float) -> tuple[float, float, float, float]:
    """The paper's kinematic bicycle ``f``, one explicit Euler step (speed kept >= 0);
    ``c`` and ``s`` are the cosine and sine of the heading ``th``."""
    step = v * dt
    return x + step * c, y + step * s, th + step / wheelbase * math.tan(steer), max(v + accel * dt, 0.0)


@numba.njit(cache=CACHE, nogil=True)
def bicycle_rows(x: np.ndarray, u: np.ndarray, dt: float, wheelbase: float) -> np.ndarray:
    """:func:`bicycle` for rows ``x`` ``(M, 4)`` and ``u`` ``(M, 2)``."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        th = x[i, 2]
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = bicycle(x[i, 0], x[i, 1], th, x[i, 3], math.cos(th),
                                                             math.sin(th), u[i, 0], u[i, 1], dt, wheelbase)
    return out


@helper
def dead_reckon(belief: np.ndarray, i: int, dt: float) -> None:
    """Carry belief row ``i`` forward one tick at its believed speed and heading (the
    bicycle with no control: the heading stays)."""
    step = belief[i, 3] * dt
    belief[i, 0] += step * math.cos(belief[i, 2])
    belief[i, 1] += step * math.sin(belief[i, 2])
    belief[i, 3] = max(belief[i, 3], 0.0)


@numba.njit(cache=CACHE, nogil=True)
def believe_rows(belief: np.ndarray, has_belief: np.ndarray, observed: np.ndarray, observation: np.ndarray,
                 dt: float) -> None:
    """The belief update ``g`` in place for N drivers: take the observation where there is
    one, else dead-reckon a belief held."""
    for i in range(belief.shape[0]):
        if observed[i]:
            for j in range(4):
                belief[i, j] = observation[i, j]
            has_belief[i] = True
        elif has_belief[i]:
            dead_reckon(belief, i, dt)


@numba.njit(cache=CACHE, nogil=True)
def project_rows(table: np.ndarray, nseg: np.ndarray, r: np.ndarray, xy: np.ndarray,
                 seg: np.ndarray) -> np.ndarray:
    """:func:`project` for N points ``xy`` ``(N, 2)`` on their routes ``r``; ``seg`` updated."""
    out = np.empty(xy.shape[0])
    for i in range(xy.shape[0]):
        out[i], seg[i] = project(table, nseg, r[i], xy[i, 0], xy[i, 1], seg[i])
    return out


@numba.njit(cache=CACHE, nogil=True)
def steer_rows(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, pose: np.ndarray,
               s: np.ndarray, lookahead: np.ndarray, wheelbase: float, max_steer: float,
               seg: np.ndarray) -> np.ndarray:
    """:func:`steer_to` for N poses ``(N, 4)`` on route ``r`` at arc lengths ``s`` (``seg``
    their segments, or < 0) with look-aheads ``lookahead`` [m]."""
    out = np.empty(pose.shape[0])
    for i in range(pose.shape[0]):
        th = pose[i, 2]
        out[i] = steer_to(table, nseg, ends, r, pose[i, 0], pose[i, 1], math.cos(th), math.sin(th), s[i],
                          seg[i], lookahead[i], wheelbase, max_steer)
    return out


@helper
def ego_control(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, x: float, y: float, th: float,
                v: float, brake: bool, car: np.ndarray) -> tuple[float, float]:
    """The ego's nominal controller for one pose on route ``r``: pure pursuit and
    ``speed_gain (v_nominal - v)`` within its limits, or its full braking if ``brake``;
    ``car`` the vector of :data:`EGO_FIELDS` (:func:`pack_ego`: look-ahead m, look-ahead
    gain s, wheelbase m, max steer rad, nominal speed m/s, speed gain 1/s, max brake
    m/s^2, max accel m/s^2). Returns [acceleration m/s^2, steering rad]."""
    s, k = project(table, nseg, r, x, y, NO_SEGMENT)
    steer = steer_to(table, nseg, ends, r, x, y, math.cos(th), math.sin(th), s, k,
                     car[E_LOOKAHEAD] + car[E_GAIN] * v, car[E_WHEELBASE], car[E_MAX_STEER])
    brake_rate = car[E_MAX_BRAKE]
    return (-brake_rate if brake else min(max(car[E_SPEED_GAIN] * (car[E_SPEED] - v), -brake_rate),
                                          car[E_MAX_ACCEL])), steer


@numba.njit(cache=CACHE, nogil=True)
def ego_control_rows(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, pose: np.ndarray,
                     brake: np.ndarray, car: np.ndarray) -> np.ndarray:
    """:func:`ego_control` for N poses ``(N, 4)``: ``(N, 2)``."""
    out = np.empty((pose.shape[0], 2))
    for i in range(pose.shape[0]):
        out[i, 0], out[i, 1] = ego_control(table, nseg, ends, r, pose[i, 0], pose[i, 1], pose[i, 2], pose[i, 3],
                                           brake[i], car)
    return out


def compile_pending() -> str | None:
    """Where Numba caches the package's kernels, if the driver model (which every episode
    runs) has never been compiled there: the first run after an install compiles the
    kernels it needs, about 10 s on a 2-core machine for an episode of the CDF
    (docs/PERFORMANCE.md). None once it has, or if this Numba's cache cannot be read
    (nothing is guessed). A stale cache after an upgrade is not detected: Numba then
    compiles again, silently."""
    try:
        cache: Any = drive._cache  # type: ignore[attr-defined]  # a numba Dispatcher
        folder = str(cache.cache_path)
        index = os.path.join(folder, cache._impl.filename_base + ".nbi")
    except Exception:  # private Numba attributes: say nothing rather than guess
        return None
    return None if os.path.exists(index) else folder
