"""Compiled kernels of the baseline planners (:mod:`cdf_mj.planners.cv`, :mod:`cdf_mj.planners.imm`) and of the risk
rule's test of one predicted path (:meth:`cdf_mj.planners.decision.RiskRule._path_masses`).

The same steps as the NumPy and filterpy code they replace, on arrays, one call per tick:

- :func:`imm_step`: one step of the intent-only IMM, as filterpy's ``IMMEstimator`` over two
  :class:`~cdf_mj.planners.imm.RouteKalmanFilter` runs it: the mixing, each filter's
  Kalman predict, then (with a measurement) each filter's extended Kalman update on the
  route (the route's point and tangent at the predicted arc length, heading residual
  wrapped), the Gaussian likelihood of its residual, the mode probabilities and the
  mixing probabilities of the next step;
- :func:`route_path`, :func:`straight_path`: predicted poses along a route at constant
  acceleration, and in a straight line at constant speed
  (:meth:`~cdf_mj.planners.imm.IMMPlanner.predicted_path`,
  :func:`~cdf_mj.planners.baseline_common.straight_path`);
- :func:`first_overlap`, :func:`straight_conflict`, :func:`imm_conflicts`: the first tick at
  which two cars' collision boxes overlap along two paths
  (:func:`~cdf_mj.planners.baseline_common.first_conflict`), for the ``cv`` and ``imm`` predictors;
- :func:`path_mask`: which of the ego's plans (arc lengths on its route) a predicted
  obstacle path collides with, the risk rule's masses for ``cv-risk`` and ``cv-layered``.

The arithmetic follows the NumPy code operation by operation (the same order, no fused
multiply-adds), so that the paths, footprints and box tests give the same values; the
IMM's matrix products and its likelihood (a Cholesky factor here, SciPy's eigen-decomposition
in filterpy) agree to rounding (tests/test_baselines_compiled.py holds them to 1e-9 over
whole episodes). Routes are the tables of :class:`cdf_mj.model.kernels.RouteTable` with the
slopes of :meth:`~cdf_mj.model.geometry.Polyline.point_at` in place of the unit directions
(:func:`slope_table`), read by :func:`cdf_mj.model.kernels.point_at`. A car is the float
vector ``[ox, oy, hx, hy]`` (:func:`car_vector`): the centre of its collision box in its
chassis frame and its half sizes [m].

Only the baselines and the risk rule's path test call these (a ``cdf`` episode compiles
none of them); ``cache=True``: compiled once per install, then loaded from Numba's cache.

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

from cdf_mj.model import kernels as drv
from cdf_mj.model.geometry import Polyline
from cdf_mj.model.kernels import RouteTable
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["car_vector", "first_overlap", "imm_conflicts", "imm_step", "path_mask", "route_path",
           "slope_table", "straight_conflict", "straight_path"]

#: This module's allocation-free helpers (Numba without reference counting); it reads no
#: packed layout of its own, so Numba's cache is always used.
helper = functools.partial(drv.helper, cache=True)

_TWO_PI = 2.0 * math.pi
_LOG_2PI = math.log(2.0 * math.pi)
_TINY = 2.2250738585072014e-308  # sys.float_info.min: filterpy's floor of a likelihood
_EPS = 0.05  # [m] half step of the measurement Jacobian's central differences (RouteKalmanFilter)
#: Segment 0 (the start of a search) as an int64: a literal 0 would make Numba compile the
#: callee a second time for it (as :data:`cdf_mj.model.kernels.NO_SEGMENT`).
_FIRST = np.int64(0)


def slope_table(routes: tuple[Polyline, ...]) -> RouteTable:
    """``RouteTable.of(routes)`` with columns 2-3 (the unit directions) replaced by each
    segment's slope d(point)/ds, the factor :meth:`Polyline.point_at` interpolates with (the
    same up to rounding): :func:`cdf_mj.model.kernels.point_at` on it gives ``point_at``'s
    values bit for bit. Read-only arrays."""
    base = RouteTable.of(routes)
    table = base.table.copy()
    for r, route in enumerate(routes):
        table[r, :len(route.points) - 1, 2:4] = route._slope
    table.flags.writeable = False
    return RouteTable(table, base.nseg, base.ends)


def car_vector(car: CarGeometry, margin: float = 0.0) -> np.ndarray:
    """``[ox, oy, hx + margin, hy + margin]`` [m]: the centre of ``car``'s collision box in its
    chassis frame and its half sizes, each widened by ``margin`` [m]."""
    half = car.hull_half + margin
    return np.array([car.hull_offset[0], car.hull_offset[1], half[0], half[1]], dtype=np.float64)


# ----------------------------------------------------------------- geometry helpers
@helper
def _wrap(a: float) -> float:  # pragma: no cover - compiled
    """:func:`cdf_mj.model.geometry.wrap_angle` of one angle [rad]: into [-pi, pi)."""
    return (a + math.pi) % _TWO_PI - math.pi


@helper
def _point(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int,
           s: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """Route ``r``'s point [m] at arc length ``s`` [m] (clamped to its ends)."""
    return drv.point_at(table, nseg, ends, r, s, _FIRST)


@helper
def _length(table: np.ndarray, nseg: np.ndarray, r: int) -> float:  # pragma: no cover - compiled
    """[m] the arc length of route ``r`` (``Polyline.length``)."""
    n = nseg[r]
    return float(table[r, n - 1, 5] + table[r, n - 1, 4])


@helper
def _heading(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, s: float, window: float,
             length: float) -> float:  # pragma: no cover - compiled
    """:func:`cdf_mj.planners.baseline_common.route_heading` at one arc length ``s`` [m] of route ``r``
    (``length`` [m] long): the direction [rad] of the chord of ``2 window`` [m] about ``s``."""
    w = min(window, 0.5 * length)
    x0, y0 = _point(table, nseg, ends, r, min(max(s - w, 0.0), length - 2 * w))
    x1, y1 = _point(table, nseg, ends, r, min(max(s + w, 2 * w), length))
    return math.atan2(y1 - y0, x1 - x0)


@helper
def _corners(car: np.ndarray, x: float, y: float, th: float, out: np.ndarray,
             i: int) -> None:  # pragma: no cover - compiled
    """``CarGeometry.footprint`` of one pose into ``out[i]`` ``(4, 2)``: the corners [m] of the
    collision box of ``car`` (:func:`car_vector`), counter-clockwise."""
    c, s = math.cos(th), math.sin(th)
    ox, oy, hx, hy = car[0], car[1], car[2], car[3]
    cx = x + c * ox - s * oy
    cy = y + s * ox + c * oy
    out[i, 0, 0], out[i, 0, 1] = cx + c * hx - s * hy, cy + s * hx + c * hy
    out[i, 1, 0], out[i, 1, 1] = cx + c * -hx - s * hy, cy + s * -hx + c * hy
    out[i, 2, 0], out[i, 2, 1] = cx + c * -hx - s * -hy, cy + s * -hx + c * -hy
    out[i, 3, 0], out[i, 3, 1] = cx + c * hx - s * -hy, cy + s * hx + c * -hy


@helper
def _overlap(a: np.ndarray, i: int, b: np.ndarray, j: int) -> bool:  # pragma: no cover - compiled
    """:func:`cdf_mj.model.geometry.boxes_overlap` of rectangles ``a[i]`` and ``b[j]`` (corners
    ``(4, 2)``): separating axes along the normals of two edges of each, boundary included."""
    for e in range(4):
        box = a if e < 2 else b
        k = i if e < 2 else j
        m = e % 2
        ax = -(box[k, m + 1, 1] - box[k, m, 1])
        ay = box[k, m + 1, 0] - box[k, m, 0]
        a_lo = a_hi = a[i, 0, 0] * ax + a[i, 0, 1] * ay
        b_lo = b_hi = b[j, 0, 0] * ax + b[j, 0, 1] * ay
        for c in range(1, 4):
            pa = a[i, c, 0] * ax + a[i, c, 1] * ay
            pb = b[j, c, 0] * ax + b[j, c, 1] * ay
            a_lo, a_hi = min(a_lo, pa), max(a_hi, pa)
            b_lo, b_hi = min(b_lo, pb), max(b_hi, pb)
        if not (a_hi >= b_lo and b_hi >= a_lo):
            return False
    return True


# ----------------------------------------------------------------- paths and conflicts
@numba.njit(cache=True, nogil=True)
def straight_path(x: float, y: float, th: float, v: float, times: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Poses ``(K, 4)`` of a car holding its heading ``th`` [rad] and speed ``v`` [m/s] from
    ``(x, y)`` [m] at ``times`` ``(K,)`` [s] (:func:`cdf_mj.planners.baseline_common.straight_path`)."""
    out = np.empty((times.shape[0], 4))
    c, s = math.cos(th), math.sin(th)
    speed = max(v, 0.0)
    for k in range(times.shape[0]):
        d = speed * times[k]
        out[k, 0] = x + d * c
        out[k, 1] = y + d * s
        out[k, 2] = th
        out[k, 3] = v
    return out


@numba.njit(cache=True, nogil=True)
def route_path(table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, r: int, s: float, v: float, a: float,
               times: np.ndarray, dt: float, max_speed: float, window: float) -> np.ndarray:  # pragma: no cover
    """Poses ``(K, 4)`` along route ``r`` at ``times`` ``(K,)`` [s] (``0, dt, ...``) from arc length
    ``s`` [m], speed ``v`` [m/s] and acceleration ``a`` [m/s^2]: speed kept in ``[0, max_speed]``,
    arc length by the trapezoid rule, heading the route's chord of ``2 window`` [m]
    (:meth:`cdf_mj.planners.imm.IMMPlanner.predicted_path`)."""
    n = times.shape[0]
    out = np.empty((n, 4))
    length = _length(table, nseg, r)
    travelled, previous = 0.0, 0.0
    for k in range(n):
        speed = min(max(v + a * times[k], 0.0), max_speed)
        if k > 0:
            travelled += 0.5 * (speed + previous) * dt
        previous = speed
        arc = s + travelled
        out[k, 0], out[k, 1] = _point(table, nseg, ends, r, arc)
        out[k, 2] = _heading(table, nseg, ends, r, arc, window, length)
        out[k, 3] = speed
    return out


@numba.njit(cache=True, nogil=True)
def first_overlap(ego_car: np.ndarray, obstacle_car: np.ndarray, ego_path: np.ndarray,
                  obstacle_path: np.ndarray) -> int:  # pragma: no cover - compiled
    """The first index ``k`` at which the collision boxes of the two cars (:func:`car_vector`)
    overlap at poses ``ego_path[k]`` and ``obstacle_path[k]`` (``(K, 4)`` each), or -1."""
    a = np.empty((1, 4, 2))
    b = np.empty((1, 4, 2))
    for k in range(min(ego_path.shape[0], obstacle_path.shape[0])):
        _corners(ego_car, ego_path[k, 0], ego_path[k, 1], ego_path[k, 2], a, _FIRST)
        _corners(obstacle_car, obstacle_path[k, 0], obstacle_path[k, 1], obstacle_path[k, 2], b, _FIRST)
        if _overlap(a, _FIRST, b, _FIRST):
            return k
    return -1


@numba.njit(cache=True, nogil=True)
def straight_conflict(poses: np.ndarray, times: np.ndarray, ego_car: np.ndarray,
                      obstacle_car: np.ndarray) -> int:  # pragma: no cover - compiled
    """:func:`first_overlap` of the straight-line paths (:func:`straight_path`) of the ego and
    the obstacle from their poses ``poses`` ``(2, 4)`` at ``times`` [s], or -1 (the ``cv``
    predictor's conflict)."""
    ego = straight_path(poses[0, 0], poses[0, 1], poses[0, 2], poses[0, 3], times)
    obstacle = straight_path(poses[1, 0], poses[1, 1], poses[1, 2], poses[1, 3], times)
    return first_overlap(ego_car, obstacle_car, ego, obstacle)


@numba.njit(cache=True, nogil=True)
def imm_conflicts(x: np.ndarray, table: np.ndarray, nseg: np.ndarray, ends: np.ndarray, ego_pose: np.ndarray,
                  times: np.ndarray, dt: float, max_speed: float, window: float, ego_car: np.ndarray,
                  obstacle_car: np.ndarray, hits: np.ndarray) -> None:  # pragma: no cover - compiled
    """Whether each intent's predicted motion meets the ego within the horizon: ``hits[r]`` 1
    if the obstacle on route ``r`` with the state ``x[r] = [s m, v m/s, a m/s^2]``
    (:func:`route_path`) and the ego holding its speed from ``ego_pose`` ``(4,)``
    (:func:`straight_path`) put their collision boxes in contact at one of ``times`` [s],
    else 0."""
    ego = straight_path(ego_pose[0], ego_pose[1], ego_pose[2], ego_pose[3], times)
    for r in range(x.shape[0]):
        path = route_path(table, nseg, ends, r, x[r, 0], x[r, 1], x[r, 2], times, dt, max_speed, window)
        hits[r] = 1.0 if first_overlap(ego_car, obstacle_car, ego, path) >= 0 else 0.0


@numba.njit(cache=True, nogil=True)
def path_mask(plans: np.ndarray, path: np.ndarray, k: int, table: np.ndarray, nseg: np.ndarray, ends: np.ndarray,
              last: np.ndarray, last_heading: float, window: float, ego_car: np.ndarray,
              obstacle_car: np.ndarray) -> int:  # pragma: no cover - compiled
    """The bit mask of the ego's plans (rows of ``plans`` ``(P, K)``, arc lengths [m] on route 0
    of the table) whose collision box overlaps the obstacle's on the predicted ``path``
    ``(K', 4)`` at one of the first ``k`` ticks: the ego's poses as
    :func:`cdf_mj.model.conflict.route_poses` gives them (chord of ``2 window`` [m]; past the
    route's end straight on along ``last``, its unit direction, heading ``last_heading`` [rad]);
    ``ego_car`` and ``obstacle_car`` as :func:`car_vector` (widened by the rule's margin)."""
    obstacle = np.empty((k, 4, 2))
    for i in range(k):
        _corners(obstacle_car, path[i, 0], path[i, 1], path[i, 2], obstacle, i)
    ego = np.empty((1, 4, 2))
    end = _length(table, nseg, _FIRST)
    mask = 0
    for p in range(plans.shape[0]):
        for i in range(k):
            q = plans[p, i]
            px, py = _point(table, nseg, ends, _FIRST, min(q, end))
            beyond = max(q - end, 0.0)
            x, y = px + beyond * last[0], py + beyond * last[1]
            if q + window > end:
                th = last_heading
            else:
                x0, y0 = _point(table, nseg, ends, _FIRST, min(max(q - window, 0.0), end))
                x1, y1 = _point(table, nseg, ends, _FIRST, min(max(q + window, 0.0), end))
                th = math.atan2(y1 - y0, x1 - x0)
            _corners(ego_car, x, y, th, ego, _FIRST)
            if _overlap(ego, _FIRST, obstacle, i):
                mask |= 1 << p
                break
    return mask


# ----------------------------------------------------------------- the IMM
@numba.njit(cache=True, nogil=True, error_model="numpy")  # a zero total gives NaN, as filterpy's
def imm_step(x: np.ndarray, P: np.ndarray, mu: np.ndarray, cbar: np.ndarray, omega: np.ndarray,
             likelihood: np.ndarray, M: np.ndarray, F: np.ndarray, Q: np.ndarray, R: np.ndarray, table: np.ndarray,
             nseg: np.ndarray, ends: np.ndarray, z: np.ndarray, measured: bool,
             window: float) -> None:  # pragma: no cover - compiled
    """One step of the IMM over the route filters, in place (the module docstring).

    ``x`` ``(N, 3)`` and ``P`` ``(N, 3, 3)``: each filter's state ``[s m, v m/s, a m/s^2]`` on
    route ``r = 0..N-1`` of the table and its covariance; ``mu`` ``(N,)`` the mode
    probabilities, ``cbar`` ``(N,)`` their prediction ``mu @ M`` and ``omega`` ``(N, N)`` the
    mixing probabilities (``M[i, j] mu[i] / cbar[j]``), ``likelihood`` ``(N,)`` each filter's
    likelihood of the last measurement; ``M`` the Markov matrix, ``F``, ``Q`` the motion
    model and its noise, ``R`` ``(4, 4)`` the measurement noise. The predict always runs;
    the update with the measured pose ``z = [x m, y m, theta rad, v m/s]`` only if
    ``measured`` (``mu``, ``cbar``, ``omega`` and ``likelihood`` change only then).
    ``window`` [m]: half chord of the route tangent.
    """
    n = x.shape[0]
    # Mixing: each filter starts from the omega-weighted mixture of all filters.
    xs = np.zeros((n, 3))
    Ps = np.zeros((n, 3, 3))
    for i in range(n):
        for j in range(n):
            for a in range(3):
                xs[i, a] += x[j, a] * omega[j, i]
        for j in range(n):
            w = omega[j, i]
            for a in range(3):
                for b in range(3):
                    Ps[i, a, b] += w * ((x[j, a] - xs[i, a]) * (x[j, b] - xs[i, b]) + P[j, a, b])
    # Predict: x = F x, P = F P F' + Q.
    FP = np.empty((3, 3))
    for i in range(n):
        for a in range(3):
            acc = 0.0
            for b in range(3):
                acc += F[a, b] * xs[i, b]
            x[i, a] = acc
            for b in range(3):
                acc = 0.0
                for c in range(3):
                    acc += F[a, c] * Ps[i, c, b]
                FP[a, b] = acc
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for c in range(3):
                    acc += FP[a, c] * F[b, c]
                P[i, a, b] = acc + Q[a, b]
    if not measured:
        return
    H = np.zeros((4, 3))
    y = np.empty(4)
    PHT = np.empty((3, 4))
    S = np.empty((4, 4))
    L = np.zeros((4, 4))
    SI = np.empty((4, 4))
    K = np.empty((3, 4))
    A = np.empty((3, 3))
    AP = np.empty((3, 3))
    KR = np.empty((3, 4))
    for i in range(n):
        # The route's measurement at the predicted arc length and its Jacobian.
        s = x[i, 0]
        length = _length(table, nseg, i)
        p0x, p0y = _point(table, nseg, ends, i, s - _EPS)
        p1x, p1y = _point(table, nseg, ends, i, s + _EPS)
        th0 = _heading(table, nseg, ends, i, s - _EPS, window, length)
        th1 = _heading(table, nseg, ends, i, s, window, length)
        th2 = _heading(table, nseg, ends, i, s + _EPS, window, length)
        hx, hy = _point(table, nseg, ends, i, s)
        H[0, 0] = (p1x - p0x) / (2 * _EPS)
        H[1, 0] = (p1y - p0y) / (2 * _EPS)
        H[2, 0] = _wrap(th2 - th0) / (2 * _EPS)
        H[3, 1] = 1.0
        y[0], y[1], y[2], y[3] = z[0] - hx, z[1] - hy, _wrap(z[2] - th1), z[3] - x[i, 1]
        # S = H P H' + R and its Cholesky factor L (S = L L').
        for a in range(3):
            for b in range(4):
                acc = 0.0
                for c in range(3):
                    acc += P[i, a, c] * H[b, c]
                PHT[a, b] = acc
        for a in range(4):
            for b in range(4):
                acc = 0.0
                for c in range(3):
                    acc += H[a, c] * PHT[c, b]
                S[a, b] = acc + R[a, b]
        for a in range(4):
            for b in range(a + 1):
                acc = S[a, b]
                for c in range(b):
                    acc -= L[a, c] * L[b, c]
                L[a, b] = math.sqrt(acc) if a == b else acc / L[b, b]
        # S^-1 = L'^-1 L^-1 (SI holds L^-1 first), the Mahalanobis distance and log det S.
        for a in range(4):
            for b in range(4):
                SI[a, b] = 0.0
            SI[a, a] = 1.0 / L[a, a]
            for b in range(a):
                acc = 0.0
                for c in range(b, a):
                    acc += L[a, c] * SI[c, b]
                SI[a, b] = -acc / L[a, a]
        maha, logdet = 0.0, 0.0
        for a in range(4):
            acc = 0.0
            for b in range(a + 1):
                acc += SI[a, b] * y[b]
            maha += acc * acc
            logdet += 2.0 * math.log(L[a, a])
        for a in range(4):  # L^-1 -> S^-1, lower triangle from the bottom row up, then mirrored
            for b in range(a + 1):
                acc = 0.0
                for c in range(a, 4):
                    acc += SI[c, a] * SI[c, b]
                L[a, b] = acc
        for a in range(4):
            for b in range(4):
                SI[a, b] = L[a, b] if b <= a else L[b, a]
        for a in range(4):  # L back to a clean factor buffer for the next filter
            for b in range(4):
                L[a, b] = 0.0
        lik = math.exp(-0.5 * (4 * _LOG_2PI + logdet + maha))
        likelihood[i] = lik if lik != 0.0 else _TINY
        # K = P H' S^-1; x += K y; P = (I - K H) P (I - K H)' + K R K'.
        for a in range(3):
            for b in range(4):
                acc = 0.0
                for c in range(4):
                    acc += PHT[a, c] * SI[c, b]
                K[a, b] = acc
        for a in range(3):
            acc = 0.0
            for b in range(4):
                acc += K[a, b] * y[b]
            x[i, a] += acc
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for c in range(4):
                    acc += K[a, c] * H[c, b]
                A[a, b] = (1.0 if a == b else 0.0) - acc
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for c in range(3):
                    acc += A[a, c] * P[i, c, b]
                AP[a, b] = acc
            for b in range(4):
                acc = 0.0
                for c in range(4):
                    acc += K[a, c] * R[c, b]
                KR[a, b] = acc
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for c in range(3):
                    acc += AP[a, c] * A[b, c]
                kr = 0.0
                for c in range(4):
                    kr += KR[a, c] * K[b, c]
                P[i, a, b] = acc + kr
    # Mode probabilities, then the mixing probabilities of the next step.
    total = 0.0
    for i in range(n):
        mu[i] = cbar[i] * likelihood[i]
        total += mu[i]
    for i in range(n):
        mu[i] /= total
    for j in range(n):
        acc = 0.0
        for i in range(n):
            acc += mu[i] * M[i, j]
        cbar[j] = acc
    for i in range(n):
        for j in range(n):
            omega[i, j] = (M[i, j] * mu[i]) / cbar[j]
