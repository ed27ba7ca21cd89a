"""The particle filter's compiled kernels: one pass over the particles per stage.

:class:`cdf_mj.inference.particle_filter.ParticleFilter` keeps its particles in NumPy
arrays and calls these Numba functions (``cache=True``: compiled once per install, then
loaded from the cache) for its stages:

- :func:`predict`: per particle, the observation event (its beta draw, then its line of
  sight only if it looks), the belief update ``g``, the driver ``h`` (the same compiled
  state machine and pure pursuit as the simulated obstacle, :mod:`cdf_mj.model.kernels`),
  the mode jumps, process noise, the bicycle ``f`` and the projection of the new pose
  onto its route, tracked from the segment it was on;
- :func:`weigh`: likelihood, normalised weights and the effective sample size;
- :func:`posterior`: P(left), P(seen) and P(cutoff);
- :func:`resample`: stratified resampling, parameter jitter and intent floor, then
  :func:`gather` of the other particle arrays into new arrays the caller allocates;
- :func:`left_futures`: the left-turners' futures for the risk decision rule.

Random numbers come from the filter's own ``numpy.random.Generator``, passed in: Numba
draws from the same bit generator with NumPy's algorithms, so a filter's stream is fixed
by its seed alone (the same records with 1, 2 or Ray workers). Draws are made only where
they matter (the observation noise of a driver who looks and sees, the departure draw
of a driver free to go), particle by particle, in index order.

Lines of sight are cached per particle (``sight``: -1 not yet known, 0 hidden, 1 seen)
for one pose array and one ego pose: P(cutoff), the futures and the next tick's looks
need the same answers and compute each once. The occluders are the buildings'
footprints (:class:`cdf_mj.model.occlusion.Occluders`) packed by :func:`pack_boxes`; the
test is the same separating-axis test as :meth:`Occluders.visible` (touching blocks).
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Mapping

import numba
import numpy as np

from cdf_mj.model import kernels as drv
from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING, YIELDING
from cdf_mj.model.occlusion import Occluders
from cdf_mj.traits import THETA

__all__ = ["FILTER_FIELDS", "LAYOUT", "LAYOUTS", "pack_boxes", "pack_filter"]

#: Entries of the filter's float vector ``cfg`` after the driver's (:data:`cdf_mj.model.kernels.DRIVER_FIELDS`):
#: mode jump [1/tick], the obstacle's actuator ranges, its process noise, the driver's
#: observation noise, its eye, the ego's terms, the cut-off rule and the re-initialisation.
FILTER_FIELDS = ("mode_jump", "accel_lo", "accel_hi", "steer_lo", "steer_hi", "nu_accel", "nu_steer",
                 "obs_pos", "obs_heading", "obs_speed", "eye_x", "eye_y", "s_enter", "stop_margin",
                 "clear_margin", "ego_brake", "ego_latency", "t_slowest", "paper_rule", "reinit_maha2")
# Index constants, plain ints computed from the names at import (compile-time constants to Numba).
_AT = drv.offsets(drv.DRIVER_FIELDS + FILTER_FIELDS)
F_JUMP, F_ACC_LO, F_ACC_HI, F_STEER_LO, F_STEER_HI = (_AT[n] for n in ("mode_jump", "accel_lo", "accel_hi",
                                                                       "steer_lo", "steer_hi"))
F_NU_A, F_NU_S, F_OBS_POS, F_OBS_HEAD, F_OBS_SPEED = (_AT[n] for n in ("nu_accel", "nu_steer", "obs_pos",
                                                                       "obs_heading", "obs_speed"))
F_EYE_X, F_EYE_Y, F_S_ENTER, F_STOP_MARGIN, F_CLEAR_MARGIN = (_AT[n] for n in ("eye_x", "eye_y", "s_enter",
                                                                               "stop_margin", "clear_margin"))
F_EGO_BRAKE, F_EGO_LATENCY, F_T_SLOWEST, F_PAPER, F_REINIT = (_AT[n] for n in ("ego_brake", "ego_latency",
                                                                               "t_slowest", "paper_rule",
                                                                               "reinit_maha2"))
# Columns of the per-particle parameters theta (cdf_mj.traits.THETA).
T_ACCEL, T_TURN, T_YIELD, T_GAP, T_CLEAR, T_BETA, T_PGO = (THETA.index(n) for n in (
    "accel", "turn_speed", "yield_brake", "critical_gap", "clear_distance", "beta", "p_go"))
#: The names the index constants above and those of the driver kernels it calls are computed from.
LAYOUTS = (*drv.LAYOUTS, FILTER_FIELDS, THETA)
#: Numba's cache keys a kernel on this file's text, not on :data:`LAYOUTS`: their digest
#: (:func:`cdf_mj.model.kernels.layout_digest`) written here puts them in the text, so that
#: a new layout recompiles. tests/test_traits.py checks it and gives the new value.
LAYOUT = "49c203255b40"
#: Whether Numba's cache may be used: only while :data:`LAYOUT` is the digest of the layouts
#: now. After a change of the traits' schema that moves a column or an offset, until the
#: stamp is updated, the kernels compile afresh on every run (a warning says so): slower
#: to start, never a stale kernel reading the old offsets.
CACHE = drv.layout_digest(*LAYOUTS) == LAYOUT
if not CACHE:
    warnings.warn(f"{__name__}: the packed layouts changed (digest {drv.layout_digest(*LAYOUTS)}, stamp {LAYOUT}): "
                  "compiling without Numba's cache; set LAYOUT to the new digest (tests/test_traits.py)",
                  RuntimeWarning, stacklevel=1)
#: This module's per-car helpers, cached as :data:`CACHE` says.
helper = functools.partial(drv.helper, cache=CACHE)

_TWO_PI = 2.0 * math.pi
_BELOW_ONE = np.nextafter(1.0, 0.0)


def pack_filter(values: Mapping[str, float]) -> np.ndarray:
    """The filter's float vector ``cfg``: the driver's entries and :data:`FILTER_FIELDS`,
    each by name (:func:`cdf_mj.model.kernels.pack`)."""
    return drv.pack(drv.DRIVER_FIELDS + FILTER_FIELDS, values)


def pack_boxes(occluders: Occluders, eye_height: float) -> np.ndarray:
    """The buildings for the kernels: rows ``[cos, sin, cx, cy, hx, hy, active]`` (heading
    of the box's x axis, centre in the box frame, half sizes [m]; active: it spans the
    eye's height [m] and so can block a sight line)."""
    c, s = np.cos(occluders.heading), np.sin(occluders.heading)
    cx = c * occluders.center[:, 0] + s * occluders.center[:, 1]
    cy = -s * occluders.center[:, 0] + c * occluders.center[:, 1]
    active = (occluders.bottom <= eye_height) & (occluders.top >= eye_height)
    return np.ascontiguousarray(np.column_stack([c, s, cx, cy, occluders.half, active.astype(float)]))


# ---------------------------------------------------------------------------------- draws
@numba.njit(cache=CACHE, nogil=True)
def _uniform(rng: np.random.Generator) -> float:
    """One ``rng.random()`` draw. A function of its own: the kernels draw at many places,
    and each inlined draw would make Numba compile the generator's code again."""
    return rng.random()


@numba.njit(cache=CACHE, nogil=True)
def _normal(rng: np.random.Generator) -> float:
    """One ``rng.standard_normal()`` draw (see :func:`_uniform`)."""
    return rng.standard_normal()


# ---------------------------------------------------------------------------------- sight
@numba.njit(cache=CACHE, nogil=True)
def sight_prep(boxes: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ego's sight targets ``(K, 2)`` in every box frame ``(B, K, 2)``, and per box
    whether all of them lie beyond its +x, -x, +y, -y side ``(B, 4)``."""
    nb, k = boxes.shape[0], targets.shape[0]
    loc = np.empty((nb, k, 2))
    beyond = np.ones((nb, 4), dtype=np.bool_)
    for b in range(nb):
        c, s, hx, hy = boxes[b, 0], boxes[b, 1], boxes[b, 4], boxes[b, 5]
        for j in range(k):
            x = c * targets[j, 0] + s * targets[j, 1] - boxes[b, 2]
            y = -s * targets[j, 0] + c * targets[j, 1] - boxes[b, 3]
            loc[b, j, 0], loc[b, j, 1] = x, y
            beyond[b, 0] &= x > hx
            beyond[b, 1] &= x < -hx
            beyond[b, 2] &= y > hy
            beyond[b, 3] &= y < -hy
    return loc, beyond


@helper
def eye_sees(ex: float, ey: float, boxes: np.ndarray, loc: np.ndarray, beyond: np.ndarray) -> bool:
    """Whether an eye at (ex, ey) [m] sees any of the targets of :func:`sight_prep`: one
    whose sight segment meets no active box."""
    nb, k = loc.shape[0], loc.shape[1]
    for j in range(k):
        blocked = False
        for b in range(nb):
            if boxes[b, 6] == 0.0:
                continue
            c, s, hx, hy = boxes[b, 0], boxes[b, 1], boxes[b, 4], boxes[b, 5]
            ax = c * ex + s * ey - boxes[b, 2]
            ay = -s * ex + c * ey - boxes[b, 3]
            if ((ax > hx and beyond[b, 0]) or (ax < -hx and beyond[b, 1]) or (ay > hy and beyond[b, 2])
                    or (ay < -hy and beyond[b, 3])):
                continue  # the eye and every target beyond the same side: it blocks nothing
            bx, by = loc[b, j, 0], loc[b, j, 1]
            if (ax > hx and bx > hx) or (ax < -hx and bx < -hx) or (ay > hy and by > hy) or (
                    ay < -hy and by < -hy):
                continue
            if abs(ax * by - ay * bx) > hx * abs(by - ay) + hy * abs(bx - ax):
                continue  # the segment's line passes the box
            blocked = True
            break
        if not blocked:
            return True
    return False


@helper
def _sees(i: int, pose: np.ndarray, cfg: np.ndarray, boxes: np.ndarray, loc: np.ndarray, beyond: np.ndarray,
          sight: np.ndarray) -> bool:
    """Particle ``i``'s line of sight to the ego, from the cache or computed into it."""
    known = int(sight[i])
    if known >= 0:
        return known == 1
    c, s = math.cos(pose[i, 2]), math.sin(pose[i, 2])
    ex = pose[i, 0] + c * cfg[F_EYE_X] - s * cfg[F_EYE_Y]
    ey = pose[i, 1] + s * cfg[F_EYE_X] + c * cfg[F_EYE_Y]
    seen = eye_sees(ex, ey, boxes, loc, beyond)
    sight[i] = 1 if seen else 0
    return seen


@numba.njit(cache=CACHE, nogil=True)
def sight_rows(pose: np.ndarray, cfg: np.ndarray, boxes: np.ndarray, targets: np.ndarray,
               sight: np.ndarray) -> np.ndarray:
    """Every particle's line of sight ``(N,)`` bool, filling the cache ``sight``."""
    loc, beyond = sight_prep(boxes, targets)
    out = np.empty(pose.shape[0], dtype=np.bool_)
    for i in range(pose.shape[0]):
        out[i] = _sees(i, pose, cfg, boxes, loc, beyond, sight)
    return out


# ------------------------------------------------------------------------------- arcs
@helper
def _arc(i: int, table: np.ndarray, nseg: np.ndarray, pose: np.ndarray, intent: np.ndarray, s: np.ndarray,
         seg: np.ndarray, s_route: np.ndarray) -> float:
    """Particle ``i``'s arc length [m] on its own route: kept, or (new pose, new intent)
    projected by the full search."""
    if seg[i] < 0 or s_route[i] != intent[i]:
        s[i], seg[i] = drv.project(table, nseg, intent[i], pose[i, 0], pose[i, 1], drv.NO_SEGMENT)
        s_route[i] = intent[i]
    return float(s[i])


@numba.njit(cache=CACHE, nogil=True)
def arcs(table: np.ndarray, nseg: np.ndarray, pose: np.ndarray, intent: np.ndarray, s: np.ndarray,
         seg: np.ndarray, s_route: np.ndarray) -> None:
    """Every particle's arc length on its own route, into ``s`` (see :func:`_arc`)."""
    for i in range(pose.shape[0]):
        _arc(i, table, nseg, pose, intent, s, seg, s_route)


# ------------------------------------------------------------------------------- ego
@helper
def ego_terms(cfg: np.ndarray, ego: np.ndarray) -> tuple[float, float]:
    """[s] until the ego, holding its speed, has cleared the obstacle's path (0 once it
    has, ``inf`` if stopped), and the ticks left before its last chance to brake and
    stop short of it (``inf`` if (nearly) stopped, 0 once too late)."""
    v = ego[3]
    ahead = drv.ahead_of_conflict(cfg[drv.C_CX], cfg[drv.C_CY], ego[0], ego[1], ego[2])
    rest = ahead + cfg[F_CLEAR_MARGIN]
    t_clear = 0.0 if rest <= 0.0 else rest / v if v > 0.1 else math.inf
    if v < 0.1:
        return t_clear, math.inf
    slack = ahead - cfg[F_STOP_MARGIN] - v * v / (2.0 * cfg[F_EGO_BRAKE])  # [m] before braking
    t = slack / v - cfg[F_EGO_LATENCY]
    return t_clear, float(max(math.ceil(t / cfg[drv.C_DT] - 1e-9), 0.0))


@helper
def arrival(s_enter: float, s: float, v: float, a: float, v_turn: float) -> float:
    """[s] until a left-turner at arc length ``s`` [m] and speed ``v`` [m/s], accelerating at
    ``a`` up to ``v_turn``, reaches ``s_enter`` (its first corner in the ego's lane)."""
    rem = max(s_enter - s, 0.0)
    t_acc = max(v_turn - v, 0.0) / a
    d_acc = v * t_acc + 0.5 * a * t_acc * t_acc
    if rem <= d_acc:
        return (math.sqrt(v * v + 2.0 * a * rem) - v) / a
    return t_acc + (rem - d_acc) / max(v_turn, 0.1)


@numba.njit(cache=CACHE, nogil=True, inline="always")
def ticks_to_commit(s_commit: float, dt: float, arc: float, v: float, a: float) -> int:
    """Ticks of ``dt`` [s] a left-turner at arc length ``arc`` [m] and speed ``v`` [m/s],
    accelerating at ``a`` [m/s^2], needs to reach its commit point ``s_commit`` [m]: the
    ticks on which a look can still stop it (scalars only, inlined)."""
    remaining = max(s_commit - arc, 0.0)
    ticks: int = math.ceil((math.sqrt(v * v + 2.0 * a * remaining) - v) / a / dt - 1e-9)
    return ticks


# ---------------------------------------------------------------------------- predict
@numba.njit(cache=CACHE, nogil=True)
def predict(rng: np.random.Generator, cfg: np.ndarray, table: np.ndarray, nseg: np.ndarray, ends: np.ndarray,
            boxes: np.ndarray, targets: np.ndarray, ego: np.ndarray, pose: np.ndarray, mode: np.ndarray,
            belief: np.ndarray, has_belief: np.ndarray, intent: np.ndarray, theta: np.ndarray, s: np.ndarray,
            seg: np.ndarray, s_route: np.ndarray, sight: np.ndarray) -> np.ndarray:
    """One tick of every particle (see the module docstring): returns the new poses
    ``(N, 4)``; updates ``mode``, ``belief``, ``has_belief`` and the arcs ``s``, ``seg``,
    ``s_route`` (now of the new poses) in place. ``sight`` is the cache of the old poses."""
    n = pose.shape[0]
    out = np.empty((n, 4))
    loc, beyond = sight_prep(boxes, targets)
    dt = cfg[drv.C_DT]
    jump_p = cfg[F_JUMP]
    for i in range(n):
        # look (k) and believe (g)
        if _uniform(rng) < theta[i, T_BETA] and _sees(i, pose, cfg, boxes, loc, beyond, sight):
            belief[i, 0] = ego[0] + _normal(rng) * cfg[F_OBS_POS]
            belief[i, 1] = ego[1] + _normal(rng) * cfg[F_OBS_POS]
            belief[i, 2] = ego[2] + _normal(rng) * cfg[F_OBS_HEAD]
            belief[i, 3] = ego[3] + _normal(rng) * cfg[F_OBS_SPEED]
            has_belief[i] = True
        elif has_belief[i]:
            drv.dead_reckon(belief, i, dt)
        # act (h)
        r = intent[i]
        arc = _arc(i, table, nseg, pose, intent, s, seg, s_route)
        md = mode[i]
        ok = md == COMMITTED or drv.clear(cfg, r, has_belief[i], belief[i, 0], belief[i, 1], belief[i, 2],
                                          belief[i, 3], theta[i, T_GAP], theta[i, T_CLEAR])
        may_go = False
        if md == WAITING and ok:  # its stop is over by its departure hazard
            may_go = _uniform(rng) < theta[i, T_PGO]
        x, y, th, v = pose[i, 0], pose[i, 1], pose[i, 2], pose[i, 3]
        c, sn = math.cos(th), math.sin(th)
        a, steer, md = drv.drive(table, nseg, ends, cfg, r, x, y, c, sn, v, arc, seg[i], md, ok, may_go,
                                 theta[i, T_ACCEL], theta[i, T_TURN], theta[i, T_YIELD])
        if jump_p > 0.0 and _uniform(rng) < jump_p:
            if md in (WAITING, YIELDING):
                md = GOING  # takes the gap whatever it saw
                has_belief[i] = False
                a = theta[i, T_ACCEL]
            elif md == GOING:
                md = YIELDING  # hesitates for a tick
                a = -theta[i, T_YIELD]
        mode[i] = md
        a = min(max(a + _normal(rng) * cfg[F_NU_A], cfg[F_ACC_LO]), cfg[F_ACC_HI])
        steer = min(max(steer + _normal(rng) * cfg[F_NU_S], cfg[F_STEER_LO]), cfg[F_STEER_HI])
        # move (f), and where that puts it on its route
        x, y, th, v = drv.bicycle(x, y, th, v, c, sn, a, steer, dt, cfg[drv.C_WHEELBASE])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x, y, th, v
        s[i], seg[i] = drv.project(table, nseg, r, x, y, seg[i])
    return out


# ------------------------------------------------------------------------------ update
@numba.njit(cache=CACHE, nogil=True)
def weigh(pose: np.ndarray, meas: np.ndarray, cov_inv: np.ndarray, logw: np.ndarray,
          reinit_maha2: float) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Log-weights times the likelihood of the measured pose ``N(meas | pose, Sigma)``,
    shifted to a maximum of 0, the normalised weights and the ESS; ``ok`` false (and the
    arrays empty) when every squared Mahalanobis distance exceeds ``reinit_maha2``."""
    n = pose.shape[0]
    out = np.empty(n)
    nearest = math.inf
    top = -math.inf
    d = np.empty(4)
    for i in range(n):
        for j in range(4):
            d[j] = pose[i, j] - meas[j]
        if not -math.pi <= d[2] < math.pi:
            d[2] = (d[2] + math.pi) % _TWO_PI - math.pi
        m2 = 0.0
        for j in range(4):
            acc = 0.0
            for k in range(4):
                acc += d[k] * cov_inv[k, j]
            m2 += acc * d[j]
        nearest = min(nearest, m2)
        out[i] = logw[i] - 0.5 * m2
        top = max(top, out[i])
    if not nearest <= reinit_maha2:
        return np.empty(0), np.empty(0), 0.0, False
    # normalise()'s steps, written here: calling it would compile it for every cold start,
    # where it is otherwise needed only for log-weights assigned from outside.
    w = np.empty(n)
    total = 0.0
    for i in range(n):
        out[i] -= top
        w[i] = math.exp(out[i])
        total += w[i]
    sq = 0.0
    for i in range(n):
        w[i] /= total
        sq += w[i] * w[i]
    return out, w, min(max(1.0 / sq, 1.0), float(n)), True


@numba.njit(cache=CACHE, nogil=True)
def normalise(logw: np.ndarray) -> tuple[np.ndarray, float]:
    """Weights ``exp(logw - max)`` normalised, and the ESS."""
    n = logw.shape[0]
    top = -math.inf
    for i in range(n):
        top = max(top, logw[i])
    w = np.empty(n)
    total = 0.0
    for i in range(n):
        w[i] = math.exp(logw[i] - top)
        total += w[i]
    sq = 0.0
    for i in range(n):
        w[i] /= total
        sq += w[i] * w[i]
    return w, min(max(1.0 / sq, 1.0), float(n))


@helper
def _cutoff(i: int, cfg: np.ndarray, pose: np.ndarray, mode: np.ndarray, intent: np.ndarray,
            theta: np.ndarray, arc: float, sees: bool, t_clear: float, ticks_to_stop: float) -> float:
    """The probability that particle ``i`` cuts the ego off (see
    :meth:`cdf_mj.inference.particle_filter.ParticleFilter.cutoff_probability`)."""
    md = mode[i]
    if intent[i] != LEFT or (md != GOING and md != COMMITTED):
        return 0.0
    if cfg[F_PAPER] != 0.0:
        return 1.0
    v, a = pose[i, 3], theta[i, T_ACCEL]
    p = 1.0
    if md == GOING:
        ticks = min(ticks_to_commit(cfg[drv.C_COMMIT + LEFT], cfg[drv.C_DT], arc, v, a), ticks_to_stop)
        beta = theta[i, T_BETA] if sees else 0.0
        p = (1.0 - beta) ** ticks
    # Pulls out behind the ego? Only once the ego clears the conflict point sooner than the
    # slowest driver of the prior could get there.
    if p > 0.0 and t_clear < cfg[F_T_SLOWEST] and arrival(cfg[F_S_ENTER], arc, v, a, theta[i, T_TURN]) > t_clear:
        p = 0.0
    return p


@numba.njit(cache=CACHE, nogil=True)
def cutoff_rows(cfg: np.ndarray, table: np.ndarray, nseg: np.ndarray, boxes: np.ndarray, targets: np.ndarray,
                ego: np.ndarray, pose: np.ndarray, mode: np.ndarray, intent: np.ndarray, theta: np.ndarray,
                s: np.ndarray, seg: np.ndarray, s_route: np.ndarray, sight: np.ndarray) -> np.ndarray:
    """Every particle's cut-off probability ``(N,)``."""
    loc, beyond = sight_prep(boxes, targets)
    t_clear, ticks = ego_terms(cfg, ego)
    n = pose.shape[0]
    out = np.zeros(n)
    for i in range(n):
        md = mode[i]
        if intent[i] == LEFT and md in (GOING, COMMITTED):
            arc = _arc(i, table, nseg, pose, intent, s, seg, s_route)
            sees = md == GOING and theta[i, T_BETA] > 0.0 and _sees(i, pose, cfg, boxes, loc, beyond, sight)
            out[i] = _cutoff(i, cfg, pose, mode, intent, theta, arc, sees, t_clear, ticks)
    return out


@numba.njit(cache=CACHE, nogil=True)
def posterior(w: np.ndarray, cfg: np.ndarray, table: np.ndarray, nseg: np.ndarray, boxes: np.ndarray,
              targets: np.ndarray, ego: np.ndarray, pose: np.ndarray, mode: np.ndarray, has_belief: np.ndarray,
              intent: np.ndarray, theta: np.ndarray, s: np.ndarray, seg: np.ndarray, s_route: np.ndarray,
              sight: np.ndarray) -> tuple[float, float, float]:
    """P(left), P(seen) and P(cutoff) (0 once the ego has cleared the obstacle's path) of
    the weights ``w``, each clipped into [0, 1] against rounding."""
    t_clear, ticks = ego_terms(cfg, ego)
    exposed = t_clear > 0.0
    loc, beyond = sight_prep(boxes, targets)
    p_left = p_seen = p_cut = 0.0
    for i in range(w.shape[0]):
        wi = w[i]
        if has_belief[i]:
            p_seen += wi
        if intent[i] != LEFT:
            continue
        p_left += wi
        md = mode[i]
        if exposed and wi > 0.0 and md in (GOING, COMMITTED):
            arc = _arc(i, table, nseg, pose, intent, s, seg, s_route)
            sees = md == GOING and theta[i, T_BETA] > 0.0 and _sees(i, pose, cfg, boxes, loc, beyond, sight)
            p_cut += wi * _cutoff(i, cfg, pose, mode, intent, theta, arc, sees, t_clear, ticks)
    return min(max(p_left, 0.0), 1.0), min(max(p_seen, 0.0), 1.0), min(max(p_cut, 0.0), 1.0)


# ---------------------------------------------------------------------------- resample
@numba.njit(cache=CACHE, nogil=True)
def _cumulative(w: np.ndarray) -> np.ndarray:
    """The cumulative sums of the weights ``w`` in numpy.cumsum's order (sequential),
    normalised to end at exactly 1; ValueError if they do not have a positive finite sum."""
    n = w.shape[0]
    c = np.empty(n)
    total = 0.0
    for i in range(n):
        total += w[i]
        c[i] = total
    if not 0.0 < total < math.inf:
        raise ValueError("weights must have a positive finite sum")
    if total != 1.0:
        c /= total
    c[-1] = 1.0
    return c


@numba.njit(cache=CACHE, nogil=True)
def resample_indexes(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Resampling of weights ``w`` (finite, >= 0) with the uniforms ``u`` in [0, 1): one
    per particle (stratified) or one for all (systematic, ``u`` of length 1). Index ``i``
    is the first ``j`` with ``C_j > (i + u_i) / N`` for the cumulative sums ``C``
    normalised to end at exactly 1 (``numpy.searchsorted(C, positions, "right")``),
    positions clamped below 1 (:mod:`cdf_mj.inference.resampling`). ValueError if the
    weights do not have a positive finite sum."""
    n = w.shape[0]
    c = _cumulative(w)
    shared = u.shape[0] != n
    out = np.empty(n, dtype=np.intp)
    j = 0
    for i in range(n):
        pos = min((i + (u[0] if shared else u[i])) / n, _BELOW_ONE)
        while c[j] <= pos:  # positions increase with i: one walk along C
            j += 1
        out[i] = j
    return out


@numba.njit(cache=CACHE, nogil=True)
def resample(rng: np.random.Generator, w: np.ndarray, theta: np.ndarray, mode: np.ndarray, intent: np.ndarray,
             jitter_std: np.ndarray, lo: np.ndarray, hi: np.ndarray, intent_floor: float,
             p_left: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stratified resampling (N uniforms): the indexes of the particles kept, and their
    parameters and intents after :func:`rejuvenate`. The caller gathers the other
    particle arrays."""
    n = w.shape[0]
    u = np.empty(n)
    for i in range(n):
        u[i] = _uniform(rng)
    keep = resample_indexes(w, u)
    theta2, intent2 = rejuvenate(rng, keep, theta, mode, intent, jitter_std, lo, hi, intent_floor, p_left)
    return keep, theta2, intent2


@numba.njit(cache=CACHE, nogil=True)
def rejuvenate(rng: np.random.Generator, keep: np.ndarray, theta: np.ndarray, mode: np.ndarray,
               intent: np.ndarray, jitter_std: np.ndarray, lo: np.ndarray, hi: np.ndarray, intent_floor: float,
               p_left: float) -> tuple[np.ndarray, np.ndarray]:
    """The parameters and intents of the particles ``keep`` after the jitter (six normals
    per particle, kept in ``[lo, hi]``) and the intent floor (one uniform per particle; a
    held-back particle drawn redraws its intent, one uniform each)."""
    n = keep.shape[0]
    n_theta = theta.shape[1]
    jitter = jitter_std.shape[0]
    theta2 = np.empty((n, n_theta))
    intent2 = np.empty(n, dtype=np.int64)
    for i in range(n):
        k = keep[i]
        intent2[i] = intent[k]
        for j in range(n_theta):
            x = theta[k, j]
            if j < jitter:
                x = min(max(x + _normal(rng) * jitter_std[j], lo[j]), hi[j])
            theta2[i, j] = x
    if intent_floor > 0.0:
        redraw = np.empty(n, dtype=np.bool_)
        for i in range(n):
            md = mode[keep[i]]
            redraw[i] = _uniform(rng) < intent_floor and md in (WAITING, YIELDING)
        for i in range(n):
            if redraw[i]:
                intent2[i] = LEFT if _uniform(rng) < p_left else RIGHT
    return theta2, intent2


@numba.njit(cache=CACHE, nogil=True)
def kld_bound(k: int, epsilon: float, z: float) -> float:
    """Fox's (2003) KLD-sampling bound: the sample size at which, with probability
    ``Phi(z)``, the Kullback-Leibler divergence between a sample's distribution over ``k``
    occupied bins and the true one is at most ``epsilon`` (the Wilson-Hilferty
    approximation of the chi-square quantile); 0 for one bin."""
    if k < 2:
        return 0.0
    a = 2.0 / (9.0 * (k - 1))
    c = 1.0 - a + math.sqrt(a) * z
    return (k - 1) / (2.0 * epsilon) * c * c * c


@numba.njit(cache=CACHE, nogil=True)
def resample_to(rng: np.random.Generator, w: np.ndarray, m: int) -> np.ndarray:
    """Stratified resampling of ``m`` particles from the weights ``w``: ``m`` uniforms, index
    ``i`` the first ``j`` with ``C_j > (i + u_i) / m`` (for ``m`` = N the indexes of
    :func:`resample_indexes`, the same arithmetic)."""
    u = np.empty(m)
    for i in range(m):
        u[i] = _uniform(rng)
    c = _cumulative(w)
    out = np.empty(m, dtype=np.intp)
    j = 0
    for i in range(m):
        pos = min((i + u[i]) / m, _BELOW_ONE)
        while c[j] <= pos:
            j += 1
        out[i] = j
    return out


@numba.njit(cache=CACHE, nogil=True)
def kld_bins(keep: np.ndarray, pose: np.ndarray, mode: np.ndarray, intent: np.ndarray, has_belief: np.ndarray,
             bin_pos: float, bin_speed: float) -> int:
    """How many bins of the state the particles ``keep`` occupy: the position on a
    ``bin_pos`` [m] grid, the speed on a ``bin_speed`` [m/s] grid, the mode, the intent and
    whether it has seen the ego (an open-addressing set of the bins' keys)."""
    m = keep.shape[0]
    size, bits = 1, 0
    while size < 4 * m:  # at most a quarter full
        size *= 2
        bits += 1
    slots = np.zeros(size, dtype=np.int64)  # a key + 1; 0 is an empty slot
    k = 0
    for i in range(m):
        j = keep[i]
        bx = np.int64(math.floor(pose[j, 0] / bin_pos)) & 0xFFFFF
        by = np.int64(math.floor(pose[j, 1] / bin_pos)) & 0xFFFFF
        bv = np.int64(math.floor(pose[j, 3] / bin_speed)) & 0x3FF
        h = (((((((bx << 20) | by) << 10 | bv) << 2 | mode[j]) << 1 | intent[j]) << 1) | np.int64(has_belief[j])) + 1
        # Fibonacci hashing: the product's high bits, which every bit of the key moves.
        slot = np.int64((np.uint64(h) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits)) if bits else 0
        while slots[slot] != 0 and slots[slot] != h:
            slot = (slot + 1) & (size - 1)
        if slots[slot] == 0:
            slots[slot] = h
            k += 1
    return k


@numba.njit(cache=CACHE, nogil=True)
def kld_resample(rng: np.random.Generator, w: np.ndarray, pose: np.ndarray, mode: np.ndarray, intent: np.ndarray,
                 has_belief: np.ndarray, bin_pos: float, bin_speed: float, epsilon: float, z: float, n_min: int,
                 n_max: int) -> np.ndarray:
    """KLD-resampling: stratified resampling of ``n_min`` particles (:func:`resample_to`);
    while :func:`kld_bound` asks more for the bins they occupy (:func:`kld_bins`), of that
    many instead (at most ``n_max``). Returns the indexes kept. Where the posterior fills
    few bins this is stratified resampling of ``n_min`` particles, draw for draw."""
    m = n_min
    while True:
        keep = resample_to(rng, w, m)
        bins = kld_bins(keep, pose, mode, intent, has_belief, bin_pos, bin_speed)
        need = min(max(math.ceil(kld_bound(bins, epsilon, z)), n_min), n_max)
        if need <= m:
            return keep
        m = need


@numba.njit(cache=CACHE, nogil=True)
def gather(keep: np.ndarray, pose: np.ndarray, belief: np.ndarray, mode: np.ndarray, has_belief: np.ndarray,
           s: np.ndarray, seg: np.ndarray, s_route: np.ndarray, sight: np.ndarray, pose2: np.ndarray,
           belief2: np.ndarray, mode2: np.ndarray, has2: np.ndarray, s2: np.ndarray, seg2: np.ndarray,
           route2: np.ndarray, sight2: np.ndarray) -> None:
    """Row ``keep[i]`` of each particle array into row ``i`` of its new array (given, so
    that nothing is allocated here and no tuple of arrays goes back to Python)."""
    for i in range(keep.shape[0]):
        k = keep[i]
        for j in range(4):
            pose2[i, j] = pose[k, j]
            belief2[i, j] = belief[k, j]
        mode2[i], has2[i], s2[i], seg2[i], route2[i], sight2[i] = (mode[k], has_belief[k], s[k], seg[k],
                                                                   s_route[k], sight[k])


# ----------------------------------------------------------------------------- futures
@numba.njit(cache=CACHE, nogil=True)
def left_futures(w: np.ndarray, cfg: np.ndarray, table: np.ndarray, nseg: np.ndarray, boxes: np.ndarray,
                 targets: np.ndarray, ego: np.ndarray, pose: np.ndarray, mode: np.ndarray, belief: np.ndarray,
                 has_belief: np.ndarray, intent: np.ndarray, theta: np.ndarray, s: np.ndarray, seg: np.ndarray,
                 s_route: np.ndarray, sight: np.ndarray,
                 react_ticks: int) -> tuple[np.ndarray, int]:
    """:meth:`cdf_mj.inference.particle_filter.ParticleFilter.futures` in one pass: a table
    ``(6, N)`` whose first ``m`` columns (``m`` returned with it) are the weight, arc length
    [m], speed [m/s], acceleration [m/s^2], cruise speed [m/s] and delay [s] of every
    left-turner that may go on (a finite delay and a positive weight). "Held
    back until the believed ego has passed" is the driver's own clear rule
    (:func:`cdf_mj.model.kernels.clear`: passed, or far by distance and gap)."""
    n = w.shape[0]
    loc, beyond = sight_prep(boxes, targets)
    # Where the ego is, as a driver who looks now would judge it (the clear rule's terms).
    ego_ahead = drv.ahead_of_conflict(cfg[drv.C_CX], cfg[drv.C_CY], ego[0], ego[1], ego[2])
    out = np.empty((6, n))  # rows: weight, arc length, speed, acceleration, cruise speed, delay
    m = 0
    for i in range(n):
        wi = w[i]
        if intent[i] != LEFT or wi <= 0.0:
            continue
        md = mode[i]
        v = pose[i, 3]
        a = theta[i, T_ACCEL]
        delay = 0.0
        if md in (WAITING, YIELDING):
            v = 0.0
            if has_belief[i]:
                ahead = drv.ahead_of_conflict(cfg[drv.C_CX], cfg[drv.C_CY], belief[i, 0], belief[i, 1], belief[i, 2])
                bv = belief[i, 3]
                if not drv.passed_or_far(cfg[drv.C_PASSED], ahead, bv, theta[i, T_GAP], theta[i, T_CLEAR]):
                    if bv <= 0.1:  # held back until the believed ego has passed
                        continue
                    delay = max((ahead + cfg[drv.C_PASSED]) / bv, 0.0)
            if md == WAITING:  # and it leaves at its hazard: within the reaction window, or later
                wi *= 1.0 - (1.0 - theta[i, T_PGO]) ** react_ticks
        arc = _arc(i, table, nseg, pose, intent, s, seg, s_route)
        # Looks ahead of it before its commit point stop it only if it would then judge the
        # ego not clear (a far or passed ego is no reason to yield).
        if (md != COMMITTED
                and not drv.passed_or_far(cfg[drv.C_PASSED], ego_ahead, ego[3], theta[i, T_GAP], theta[i, T_CLEAR])
                and _sees(i, pose, cfg, boxes, loc, beyond, sight)):
            wi *= (1.0 - theta[i, T_BETA]) ** ticks_to_commit(cfg[drv.C_COMMIT + LEFT], cfg[drv.C_DT], arc, v, a)
        if wi <= 0.0:
            continue
        out[0, m], out[1, m], out[2, m], out[3, m], out[4, m], out[5, m] = wi, arc, v, a, theta[i, T_TURN], delay
        m += 1
    return out, m
