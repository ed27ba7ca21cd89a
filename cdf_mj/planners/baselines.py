"""Baseline planners that the CDF paper argues against, on the same footing as ``cdf``.

==========  ===========================================================================
cv          constant-velocity predictor (the velocity-obstacle assumption): extrapolate
            the obstacle and the ego in straight lines at their measured speeds and
            brake when their collision boxes (the obstacle's widened by a margin) meet
            within a horizon
imm         intent-only estimator: filterpy's ``IMMEstimator`` over one Kalman filter
            per intent, each following the obstacle along its own route (left or
            right); brakes when P(conflict) = sum over intents of P(intent) x
            [that intent's predicted motion meets the ego within the horizon]
            reaches a threshold. It models no belief: it cannot know whether the
            obstacle has seen the ego
==========  ===========================================================================

Both see what every planner sees (:class:`cdf_mj.planners.PlannerInput`: the measured
system pose), predict the ego holding its speed along its heading, and hold their
brake once decided (:class:`cdf_mj.planners.base.DecidingPlanner` with the threshold
rule); ``cv-risk`` and ``imm-risk`` decide with the risk rule instead
(:mod:`cdf_mj.planners.decision`). Their parameters are the frozen
dataclasses :class:`CVConfig` and :class:`IMMConfig`; the defaults were chosen on seeds
0-199 only (docs/ANALYSIS.md says how). :mod:`cdf_mj.planners.base` registers both names
(this module, and filterpy, load on first use), so ``cdf-mj experiment --planners
cdf,reactive,cv,imm`` and worker processes know them::

    from cdf_mj.planners.baselines import IMMConfig, IMMPlanner
    record = run_episode(config, seed=7, planner=IMMPlanner(IMMConfig(threshold=0.8)))

Each tick runs compiled (:mod:`cdf_mj.planners.baseline_kernels`): the IMM's step, the
predicted paths and their box tests. The IMM is filterpy's ``IMMEstimator`` over
:class:`RouteKalmanFilter`, computed by the kernels; an instance with ``reference = True``
runs filterpy itself (:attr:`IMMPlanner.reference`), the reference that
tests/test_baselines_compiled.py holds the compiled IMM to (states, covariances and mode
probabilities within 1e-9 every tick, the same records).

Frames and units: world frame (x east, y north), metres, seconds, radians; poses are
rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import IMMEstimator, KalmanFilter

from cdf_mj.config import MAX_SPEED, LayeredConfig, RiskConfig
from cdf_mj.model.conflict import Futures
from cdf_mj.model.driver import Intent
from cdf_mj.model.geometry import Polyline, boxes_overlap, wrap_angle
from cdf_mj.model.kernels import RouteTable
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners import baseline_kernels as kern
from cdf_mj.planners.base import DecidingPlanner, DecisionRule, PlannerContext, PlannerInput, as_config
from cdf_mj.planners.decision import LayeredRule, RiskRule, ThresholdRule

__all__ = [
    "BASELINE_LAYERS",
    "CVConfig",
    "CVLayeredPlanner",
    "CVPlanner",
    "CVRiskPlanner",
    "IMMConfig",
    "IMMLayeredPlanner",
    "IMMPlanner",
    "IMMRiskPlanner",
    "RouteKalmanFilter",
    "boxes_overlap",
    "first_conflict",
    "route_heading",
    "straight_path",
]


def _require(ok: bool, name: str, value: object, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def _finite_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


# ----------------------------------------------------------------- parameters
@dataclass(frozen=True)
class CVConfig:
    """Parameters of the constant-velocity planner ``cv`` (chosen on seeds 0-199)."""

    # Chosen on seeds 0-199 by the largest (avoided - false-alarm rate) over horizons
    # {0.5, 1, 1.5, 2, 2.5} s at margin 0.3 m, then margins 0 and 0.15 m at 1-2 s (the grid
    # in docs/ANALYSIS.md): 1.5 s, 0 m avoided 72/80 with 50/200 false alarms, every one a
    # right-turner.
    horizon: float = 1.5  # [s] look-ahead of the straight-line extrapolation
    margin: float = 0.0  # [m] added to each half size of the obstacle's collision box

    def __post_init__(self) -> None:
        _require(_finite_number(self.horizon) and 0 < self.horizon <= 10, "horizon", self.horizon,
                 "in (0, 10] [s]")
        _require(_finite_number(self.margin) and 0 <= self.margin <= 5, "margin", self.margin,
                 "in [0, 5] [m]")

    def replace(self, **changes: Any) -> CVConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class IMMConfig:
    """Parameters of the intent-only IMM planner ``imm``.

    The filter models and noise levels are set from the scenario's geometry and from how
    closely a route-following car keeps to its route (lateral offset up to about 0.2 m,
    heading about 0.15 rad off the route's tangent); ``horizon`` and ``threshold`` were
    chosen on seeds 0-199.
    """

    # Chosen on seeds 0-199 by the largest (avoided - false-alarm rate) over horizon
    # {1, 1.5, 2} s x threshold {0.6, 0.8, 0.9, 0.95}: 1.5 s and 0.95 avoided 80/80 with 0/200
    # false alarms there; 2 s brakes 0.5 s earlier but false-alarms on 2.5-19 % (docs/ANALYSIS.md).
    horizon: float = 1.5  # [s] look-ahead of each intent's predicted motion
    margin: float = 0.3  # [m] added to each half size of the obstacle's collision box
    threshold: float = 0.95  # brake when P(conflict) >= threshold, in (0, 1]
    switch_prob: float = 0.001  # per-tick P(intent changes) in the IMM's Markov matrix
    pos_std: float = 0.25  # [m] measurement std of the obstacle's position about its route
    heading_std: float = 0.1  # [rad] measurement std of its heading about the route tangent
    speed_std: float = 0.2  # [m/s] measurement std of its speed
    # [m/s^2] std of the change of the acceleration over one tick (process noise: the variance
    # of filterpy's Q_discrete_white_noise(dim=3)). 10 m/s^2 per tick is a loose model (more
    # than the car's own limits allow): the filter follows the measured progress closely.
    accel_change_std: float = 10.0
    init_std: tuple[float, float, float] = (0.2, 0.3, 1.5)  # [m, m/s, m/s^2] of [s, v, a] at t=0
    # The IMM's own model of the other driver (never the world's): the prior P(left) of
    # its intent (the paper's 0.75) and the cap of its predicted speed [m/s], the middle of
    # the CDF prior's turn speeds (6-10 m/s). Before version 0.2 both were read from the
    # world's scenario, which told the IMM the true values of every preset.
    p_left: float = 0.75
    max_speed: float = 8.0
    heading_window: float = 0.5  # [m] half window of the route tangent's central difference

    def __post_init__(self) -> None:
        _require(_finite_number(self.horizon) and 0 < self.horizon <= 10, "horizon", self.horizon,
                 "in (0, 10] [s]")
        _require(_finite_number(self.margin) and 0 <= self.margin <= 5, "margin", self.margin,
                 "in [0, 5] [m]")
        _require(_finite_number(self.threshold) and 0 < self.threshold <= 1, "threshold",
                 self.threshold, "in (0, 1]")
        _require(_finite_number(self.switch_prob) and 0 < self.switch_prob < 0.5, "switch_prob",
                 self.switch_prob, "in (0, 0.5)")
        for name in ("pos_std", "heading_std", "speed_std", "accel_change_std", "heading_window"):
            v = getattr(self, name)
            _require(_finite_number(v) and v > 0, name, v, "a finite number > 0")
        init = tuple(self.init_std)
        _require(len(init) == 3 and all(_finite_number(v) and v > 0 for v in init), "init_std",
                 self.init_std, "3 finite numbers > 0 ([s m, v m/s, a m/s^2])")
        _require(_finite_number(self.max_speed) and 0 < self.max_speed <= MAX_SPEED, "max_speed", self.max_speed,
                 f"in (0, {MAX_SPEED:g}] [m/s]")
        _require(_finite_number(self.p_left) and 0 <= self.p_left <= 1, "p_left", self.p_left,
                 "in [0, 1] (a probability)")

    def replace(self, **changes: Any) -> IMMConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


# ----------------------------------------------------------------- conflict prediction
def first_conflict(ego_car: CarGeometry, obstacle_car: CarGeometry, ego_path: np.ndarray,
                   obstacle_path: np.ndarray, margin: float, dt: float) -> float | None:
    """Time [s] from now of the first predicted overlap of the two collision boxes, the
    obstacle's widened by ``margin`` [m] on each side, or ``None`` within the paths.

    ``ego_path``/``obstacle_path`` are ``(K, 4)`` predicted poses ``[x, y, theta, v]``
    (world frame) at ``0, dt, ..., (K-1) dt`` [s]; the cars' footprints come from their
    geometries (``Layout.ego``, ``Layout.obstacle``).
    """
    wide = dataclasses.replace(obstacle_car, hull_half=obstacle_car.hull_half + margin)
    hit = boxes_overlap(ego_car.footprint(ego_path), wide.footprint(obstacle_path))
    k = np.flatnonzero(hit)
    return round(float(k[0] * dt), 6) if k.size else None


def straight_path(pose: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses ``(K, 4)`` of a car holding its heading and speed from ``pose`` at ``times`` [s]
    (the planners run its compiled twin, :func:`cdf_mj.planners.baseline_kernels.straight_path`)."""
    x, y, th, v = (float(p) for p in pose)
    d = max(v, 0.0) * np.asarray(times, dtype=float)
    out = np.empty((len(d), 4))
    out[:, 0] = x + d * math.cos(th)
    out[:, 1] = y + d * math.sin(th)
    out[:, 2] = th
    out[:, 3] = v
    return out


def route_heading(route: Polyline, s: np.ndarray | float, window: float = 0.5) -> np.ndarray:
    """Heading [rad] of ``route`` at arc length(s) ``s`` [m]: the direction of the chord of
    length ``2 window`` [m] centred on ``s`` (shifted inside the route near its ends). The
    planners compute it compiled, in :func:`cdf_mj.planners.baseline_kernels.route_path`."""
    s = np.asarray(s, dtype=float)
    w = min(window, 0.5 * route.length)
    lo = route.point_at(np.clip(s - w, 0.0, route.length - 2 * w))
    hi = route.point_at(np.clip(s + w, 2 * w, route.length))
    heading: np.ndarray = np.arctan2(hi[..., 1] - lo[..., 1], hi[..., 0] - lo[..., 0])
    return heading


def _times(horizon: float, dt: float) -> np.ndarray:
    """Look-ahead times ``0, dt, ...`` [s] up to ``horizon`` [s] (inclusive within rounding)."""
    return np.arange(math.floor(horizon / dt + 1e-9) + 1) * dt


#: The layered rule of ``imm-layered`` and ``cv-layered``: their anticipation threshold,
#: chosen on seeds 0-199 by the rule that chose the CDF's (scripts/tune_layers.py). With one
#: hypothesis each (a risk is 0 or its weight), every threshold tried gave the same avoided
#: shares and false alarms; the time lost and the last tie-break, the larger, chose 0.5.
BASELINE_LAYERS = LayeredConfig(anticipate=0.5, anticipate_release=0.25)


def _rule(risk: RiskConfig | Mapping[str, Any] | None, layered: LayeredConfig | Mapping[str, Any] | None,
          otherwise: DecisionRule) -> DecisionRule:
    """The layered rule where ``layered`` is given (with ``risk`` for its emergency layer),
    else the risk rule where ``risk`` is, else ``otherwise`` (the predictor's threshold rule)."""
    if layered is not None:
        return LayeredRule(as_config(layered, LayeredConfig, "layered"), as_config(risk, RiskConfig, "risk"))
    return RiskRule(as_config(risk, RiskConfig, "risk")) if risk is not None else otherwise


# ----------------------------------------------------------------- constant velocity
class CVPlanner(DecidingPlanner):
    """Constant-velocity predictor (velocity obstacle): brake when the straight-line
    extrapolations of the obstacle and of the ego at their measured speeds put their
    boxes in contact within ``horizon`` (its threshold rule), or with the risk rule on the
    obstacle's straight-line path (``risk``; registered as ``cv-risk``). ``summary()``
    holds the decision time and the predicted time to conflict at that moment.

    Args:
        params: horizon and margin (default :class:`CVConfig`).
        risk: run with :class:`~cdf_mj.planners.decision.RiskRule` of these parameters
            instead of the threshold rule.
    """

    name = "cv"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        self.params = as_config(params, CVConfig, "params")
        self.rule = _rule(risk, layered, ThresholdRule(1.0))

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Take the cars' footprints from the layout and the tick ``dt`` from ``context``."""
        super().reset(context, rng)
        layout = context.layout
        self._ego, self._obstacle, self._dt = layout.ego, layout.obstacle, context.dt
        self._times = _times(self.params.horizon, context.dt)
        # The kernels' cars (the obstacle's box widened by the margin) and a buffer of the pose.
        self._cars = (kern.car_vector(layout.ego), kern.car_vector(layout.obstacle, self.params.margin))
        self._poses = np.zeros((2, 4))
        self._future_times: np.ndarray | None = None  # ticks 1..K of the rule's horizon [s]
        self.conflict_in: float | None = None
        self._obstacle_pose = np.zeros(4)

    def time_to_conflict(self, poses: np.ndarray) -> float | None:
        """Predicted time [s] to the first conflict under constant velocities from the
        system pose ``(2, 4)`` (ego, obstacle), or None within the horizon (:func:`first_conflict`
        of the two :func:`straight_path`, compiled)."""
        poses = np.asarray(poses, dtype=float)
        if poses.shape != (2, 4):
            raise ValueError(f"time_to_conflict: poses must be (2, 4) rows [x, y, theta, v] of the ego and the "
                             f"obstacle, got shape {poses.shape}")
        self._poses[:] = poses
        k = kern.straight_conflict(self._poses, self._times, *self._cars)
        return round(k * self._dt, 6) if k >= 0 else None

    def observe(self, obs: PlannerInput) -> None:
        """Predict the conflict (until the decision, for the threshold rule); keep the
        obstacle's pose for its straight-line future."""
        self.record(obs.t)
        if not np.isfinite(obs.poses[1]).all():  # no measurement of the obstacle: its last one stands
            return
        self._obstacle_pose = obs.poses[1]
        if self.decision_time is None and not self.rule.releases:
            self.conflict_in = self.time_to_conflict(obs.poses)

    def alarm(self) -> float:
        """1 if a conflict is predicted within the horizon, else 0."""
        return 1.0 if self.conflict_in is not None else 0.0

    def futures(self, react_ticks: int) -> np.ndarray:
        """The obstacle's straight-line path at its measured speed, ticks ``1..K`` of the
        rule's horizon ``(K, 4)``."""
        if self._future_times is None:
            n = max(1, math.ceil(self.rule.config.horizon / self._dt - 1e-9))  # type: ignore[attr-defined]
            self._future_times = np.arange(1, n + 1) * self._dt
        x, y, th, v = (float(p) for p in self._obstacle_pose)
        return kern.straight_path(x, y, th, v, self._future_times)

    def summary(self) -> dict[str, Any]:
        """Rule, decision and release times [s], the brakes, the time to conflict [s]
        predicted at the decision (threshold rule) and, with the risk rule, its history."""
        info = {"rule": self.rule.name, "decision_time": self.decision_time, "release_time": self.release_time,
                "brakes": self.brakes, "predicted_conflict_in": self.conflict_in}
        if self.anticipated:  # a graded rule slowed for the obstacle's entry: it predicted the cut-off
            info["prediction"] = "Cutoff"
        return {**info, "history": self.history} if self.rule.releases else info


class CVLayeredPlanner(CVPlanner):
    """:class:`CVPlanner` with the layered rule (default :data:`BASELINE_LAYERS` and
    :class:`RiskConfig`), registered as ``cv-layered``."""

    name = "cv-layered"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, risk, BASELINE_LAYERS if layered is None else layered)


class CVRiskPlanner(CVPlanner):
    """:class:`CVPlanner` with the risk rule (default :class:`RiskConfig`), registered as ``cv-risk``."""

    name = "cv-risk"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, RiskConfig() if risk is None else risk)


# ----------------------------------------------------------------- intent-only IMM
class RouteKalmanFilter(KalmanFilter):  # type: ignore[misc]  # filterpy has no type information
    """Kalman filter of the obstacle's progress along one route.

    State ``x = [s m, v m/s, a m/s^2]``: arc length along the route from the stop line,
    speed and acceleration, with a constant-acceleration model (white jerk). Measurement
    ``z = [x m, y m, theta rad, v m/s]``, the measured obstacle pose, predicted as the
    route's point and tangent at ``s`` and the speed; the measurement is linearised at
    the predicted ``s`` on every update (an extended Kalman update) and the heading
    residual is wrapped to [-pi, pi). Its ``likelihood`` is that of this residual, which
    is what :class:`filterpy.kalman.IMMEstimator` compares between intents.

    The reference of the compiled IMM (:func:`cdf_mj.planners.baseline_kernels.imm_step`),
    which :class:`IMMPlanner` runs unless its ``reference`` is set.
    """

    def __init__(self, route: Polyline, dt: float, params: IMMConfig) -> None:
        super().__init__(dim_x=3, dim_z=4)
        self.route = route
        self.window = params.heading_window
        self.F, self.Q, self.R = _imm_model(dt, params)
        self.P = np.diag(np.square(params.init_std))

    def measurement(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predicted measurement ``h(x)`` (4,) and its Jacobian (4, 3) at state ``x``."""
        s = float(np.ravel(x)[0])
        eps, w = 0.05, self.window
        p0, p1 = self.route.point_at(np.array([s - eps, s + eps]))
        th = route_heading(self.route, np.array([s - eps, s, s + eps]), w)
        hx = np.array([*self.route.point_at(s), th[1], float(np.ravel(x)[1])])
        H = np.zeros((4, 3))
        H[0:2, 0] = (p1 - p0) / (2 * eps)
        H[2, 0] = float(wrap_angle(th[2] - th[0])) / (2 * eps)
        H[3, 1] = 1.0
        return hx, H

    def update(self, z: np.ndarray, R: np.ndarray | None = None, H: np.ndarray | None = None) -> None:
        """Extended Kalman update with the measured pose ``z`` (4,) (see the class); ``R``
        replaces the measurement noise for this update; ``H`` is ignored: the Jacobian is
        that of the route at the predicted state."""
        z = np.ravel(np.asarray(z, dtype=float))
        hx, Hj = self.measurement(self.x)
        resid = z - hx
        resid[2] = float(wrap_angle(resid[2]))
        self.H = Hj
        super().update(resid + Hj @ np.ravel(self.x), R=R)


def _imm_model(dt: float, params: IMMConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(F, Q, R)`` of a route filter: the constant-acceleration motion over ``dt`` [s], its
    process noise (white jerk: the variance of the acceleration's change over one tick) and
    the measurement noise of ``[x, y, theta, v]``."""
    F = np.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q: np.ndarray = Q_discrete_white_noise(dim=3, dt=dt, var=params.accel_change_std ** 2)
    R = np.diag(np.square([params.pos_std, params.pos_std, params.heading_std, params.speed_std]))
    return F, Q, R


@functools.lru_cache(maxsize=16)
def _route_table(layout: Layout) -> RouteTable:
    """The obstacle's routes (left, right) packed for the kernels, cached per layout."""
    return kern.slope_table(layout.obstacle_routes)


class _CompiledIMM:
    """The state of the compiled IMM (:func:`cdf_mj.planners.baseline_kernels.imm_step`): per
    intent the route filter's state ``x[i] = [s m, v m/s, a m/s^2]`` and covariance ``P[i]``,
    the mode probabilities ``mu`` and the IMM's ``cbar``, ``omega`` and ``likelihood``, as the
    attributes of filterpy's ``IMMEstimator`` and its filters hold them; ``M``, ``F``, ``Q``,
    ``R`` its models."""

    def __init__(self, x: np.ndarray, P: np.ndarray, mu: np.ndarray, M: np.ndarray,
                 model: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        self.x, self.P, self.M = x, P, M
        self.F, self.Q, self.R = model
        self.mu = mu
        self.likelihood = np.zeros(len(mu))
        # IMMEstimator's _compute_mixing_probabilities, as it does it at its start.
        self.cbar = np.dot(mu, M)
        self.omega = np.zeros((len(mu), len(mu)))
        for i in range(len(mu)):
            for j in range(len(mu)):
                self.omega[i, j] = (M[i, j] * mu[i]) / self.cbar[j]


class IMMPlanner(DecidingPlanner):
    """Intent-only planner: an IMM over per-intent route filters; brake when
    P(conflict) >= ``threshold``.

    P(conflict) = sum over intents of the IMM's mode probability times 1 if that intent's
    filter, extrapolated along its route at constant acceleration (speed kept in
    ``[0, max_speed]``), meets the ego holding its speed within ``horizon``. The prior
    P(left) is its own ``IMMConfig.p_left``. Its prediction for the episode is ``Cutoff`` if
    it braked, else its most probable intent at the end (left -> ``Yield``, right ->
    ``Right``), as for ``cdf``. ``summary()`` holds the prediction, the decision time and
    the per-tick history of P(left) and P(conflict).

    With ``risk`` (registered as ``imm-risk``) it decides by
    :class:`~cdf_mj.planners.decision.RiskRule` instead: the left intent's filter state
    (arc length, speed, acceleration, speed capped at ``max_speed``) weighted by P(left)
    is its one hypothesis; it models no yielding, so a left-turner on its way goes on.

    The IMM runs compiled (:func:`cdf_mj.planners.baseline_kernels.imm_step`); with
    :attr:`reference` set it runs filterpy's ``IMMEstimator`` over :class:`RouteKalmanFilter`.

    Args:
        params: filter models, horizon and threshold (default :class:`IMMConfig`).
        risk: run with the risk rule of these parameters instead of the threshold rule.
    """

    name = "imm"
    history_keys = ("p_left", "p_conflict")
    #: Run filterpy's ``IMMEstimator`` over :class:`RouteKalmanFilter` and the NumPy paths and
    #: box tests (the code the compiled IMM was written from: the reference that
    #: tests/test_baselines_compiled.py holds it to) instead of the compiled IMM. Set it on an
    #: instance before its ``reset`` (it holds for the episode); the same records, several times slower.
    reference: bool = False

    def __init__(self, params: IMMConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        self.params = as_config(params, IMMConfig, "params")
        self.rule = _rule(risk, layered, ThresholdRule(self.params.threshold))

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Take the routes and footprints from the layout and ``dt`` from ``context``; its
        prior P(left) and speed cap are its own (:class:`IMMConfig`). The IMM starts at the
        first measurement."""
        super().reset(context, rng)
        p, layout = self.params, context.layout
        self._ego, self._obstacle, self._dt = layout.ego, layout.obstacle, context.dt
        self._routes = dict(zip((Intent.LEFT, Intent.RIGHT), layout.obstacle_routes, strict=True))
        self._times = _times(p.horizon, context.dt)
        self._max_speed = p.max_speed
        self._p_left = p.p_left
        self._p_conflict = 0.0
        # The kernels' routes and cars (the obstacle's box widened by the margin), buffers of
        # the measured pose, the ego's pose and the intents' conflicts.
        self._table = _route_table(layout)
        self._cars = (kern.car_vector(layout.ego), kern.car_vector(layout.obstacle, p.margin))
        self._z, self._ego_pose, self._hits = np.zeros(4), np.zeros(4), np.zeros(2)
        self._reference = bool(self.reference)  # for the whole episode
        #: The running IMM: filterpy's ``IMMEstimator`` (``reference``) or the compiled IMM's
        #: state; None before the first measurement.
        self.imm: Any = None

    def _start(self, obstacle_pose: np.ndarray) -> Any:
        p = self.params
        # Clip the prior away from 0 and 1 so that the IMM's mixing stays defined.
        prior = min(max(self._p_left, 1e-6), 1 - 1e-6)
        e = p.switch_prob
        M = np.array([[1 - e, e], [e, 1 - e]])
        if self._reference:
            filters = []
            for intent in (Intent.LEFT, Intent.RIGHT):
                kf = RouteKalmanFilter(self._routes[intent], self._dt, p)
                s, _ = kf.route.project(obstacle_pose[:2])
                kf.x = np.array([[float(s)], [float(obstacle_pose[3])], [0.0]])
                filters.append(kf)
            return IMMEstimator(filters, np.array([prior, 1 - prior]), M)
        x = np.zeros((2, 3))
        for intent in (Intent.LEFT, Intent.RIGHT):
            s, _ = self._routes[intent].project(obstacle_pose[:2])
            x[intent] = (float(s), float(obstacle_pose[3]), 0.0)
        P = np.stack([np.diag(np.square(p.init_std))] * 2)
        mu = np.array([prior, 1 - prior])
        return _CompiledIMM(x, P, mu / np.sum(mu), M, _imm_model(self._dt, p))

    def _imm(self) -> Any:
        """The running IMM; RuntimeError before the first measurement."""
        if self.imm is None:
            raise RuntimeError("the IMM starts at the first measurement: call brake() first")
        return self.imm

    def _step(self, measured: bool) -> None:
        """One step of the compiled IMM on the measured pose in ``_z`` (predict only without one)."""
        m = self.imm
        t = self._table
        kern.imm_step(m.x, m.P, m.mu, m.cbar, m.omega, m.likelihood, m.M, m.F, m.Q, m.R, t.table, t.nseg, t.ends,
                      self._z, measured, self.params.heading_window)

    def estimates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the running IMM's per-intent filter states ``(2, 3)`` ``[s m, v m/s, a
        m/s^2]``, their covariances ``(2, 3, 3)`` and the mode probabilities ``(2,)`` (left,
        right); RuntimeError before the first measurement."""
        imm = self._imm()
        if self._reference:
            return (np.array([np.ravel(f.x) for f in imm.filters]), np.array([f.P for f in imm.filters]),
                    np.array(imm.mu, dtype=float))
        return imm.x.copy(), imm.P.copy(), imm.mu.copy()

    def _state(self, intent: Intent) -> tuple[float, float, float]:
        """``(s m, v m/s, a m/s^2)`` of this intent's filter."""
        imm = self._imm()
        x = np.ravel(imm.filters[int(intent)].x) if self._reference else imm.x[int(intent)]
        s, v, a = (float(q) for q in x)
        return s, v, a

    @property
    def mode_probabilities(self) -> np.ndarray:
        """Current P(left), P(right) of the IMM (sums to 1)."""
        if self.imm is None:
            return np.array([self._p_left, 1 - self._p_left])
        mu: np.ndarray = np.array(self.imm.mu, dtype=float)
        return mu

    def predicted_path(self, intent: Intent) -> np.ndarray:
        """Poses ``(K, 4)`` of the obstacle over the horizon if it has this intent: its filter's
        state extrapolated along the route at constant acceleration, speed in [0, max_speed]."""
        s, v, a = self._state(intent)
        if not self._reference:
            t = self._table
            return kern.route_path(t.table, t.nseg, t.ends, int(intent), s, v, a,
                                   self._times, self._dt, self._max_speed, self.params.heading_window)
        route = self._routes[intent]
        speed = np.clip(v + a * self._times, 0.0, self._max_speed)
        arc = s + np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * self._dt)])
        xy = route.point_at(arc)
        out = np.empty((len(arc), 4))
        out[:, :2] = xy
        out[:, 2] = route_heading(route, arc, self.params.heading_window)
        out[:, 3] = speed
        return out

    def conflict_probability(self, ego_pose: np.ndarray) -> float:
        """P(conflict within the horizon) = sum over intents of P(intent) x conflict(intent)."""
        mus = self._imm().mu
        if self._reference:
            ego_path = straight_path(ego_pose, self._times)
            hits = [first_conflict(self._ego, self._obstacle, ego_path, self.predicted_path(intent),
                                   self.params.margin, self._dt) is not None for intent in (Intent.LEFT, Intent.RIGHT)]
        else:
            ego_pose = np.asarray(ego_pose, dtype=float)
            if ego_pose.shape != (4,):
                raise ValueError(f"conflict_probability: the ego's pose must be [x, y, theta, v], got shape "
                                 f"{ego_pose.shape}")
            self._ego_pose[:] = ego_pose
            t = self._table
            kern.imm_conflicts(self.imm.x, t.table, t.nseg, t.ends, self._ego_pose, self._times, self._dt,
                               self._max_speed, self.params.heading_window, *self._cars, self._hits)
            hits = [bool(h) for h in self._hits]
        total = 0.0
        for mu, hit in zip(mus, hits, strict=True):
            total += float(mu) if hit else 0.0
        return min(max(total, 0.0), 1.0)

    def observe(self, obs: PlannerInput) -> None:
        """One IMM step on the measured obstacle pose (the start at the first tick), then
        P(conflict)."""
        z = obs.poses[1]
        measured = bool(np.isfinite(z).all())
        if self.imm is None:
            if not measured:  # it starts at the first measurement of the obstacle
                self.record(obs.t, p_left=self._p_left, p_conflict=0.0)
                return
            self.imm = self._start(z)
        elif self._reference:
            self.imm.predict()
            if measured:  # a missing measurement (a dropout): prediction only
                self.imm.update(z)
        else:
            if measured:
                self._z[:] = z
            self._step(measured)
        self._p_conflict = self.conflict_probability(obs.poses[0])
        self.record(obs.t, p_left=self.imm.mu[Intent.LEFT], p_conflict=self._p_conflict)

    def alarm(self) -> float:
        """P(conflict) of this tick."""
        return self._p_conflict

    def futures(self, react_ticks: int) -> Futures:
        """The left intent's filter state as one hypothesis, weighted by P(left); none before
        the first measurement of the obstacle."""
        if self.imm is None:
            return Futures.empty()
        s, v, a = self._state(Intent.LEFT)
        return Futures(weight=np.array([float(self._imm().mu[Intent.LEFT])]), s=np.array([s]),
                       v=np.array([max(v, 0.0)]), accel=np.array([a]), v_max=np.array([float(self._max_speed)]),
                       delay=np.zeros(1))


class IMMLayeredPlanner(IMMPlanner):
    """:class:`IMMPlanner` with the layered rule (default :data:`BASELINE_LAYERS` and
    :class:`RiskConfig`), registered as ``imm-layered``."""

    name = "imm-layered"

    def __init__(self, params: IMMConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, risk, BASELINE_LAYERS if layered is None else layered)


class IMMRiskPlanner(IMMPlanner):
    """:class:`IMMPlanner` with the risk rule (default :class:`RiskConfig`), registered as ``imm-risk``."""

    name = "imm-risk"

    def __init__(self, params: IMMConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, RiskConfig() if risk is None else risk)
