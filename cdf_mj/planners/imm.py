"""The intent-only baseline ``imm``, with the risk rule (``imm-risk``) and the layered rule
(``imm-layered``).

An IMM over one route filter per intent (:class:`RouteKalmanFilter`: the obstacle's
progress along its left or right route); it brakes when P(conflict) = sum over intents
of P(intent) x [that intent's predicted motion meets the ego within the horizon] reaches
a threshold. It models no belief: it cannot know whether the obstacle has seen the ego.
It sees what every planner sees (:class:`cdf_mj.planners.PlannerInput`: the measured
system pose), predicts the ego holding its speed along its heading, and holds its brake
once decided (:class:`cdf_mj.planners.base.DecidingPlanner` with the threshold rule);
``imm-risk`` and ``imm-layered`` decide by the rules of :mod:`cdf_mj.planners.decision`.
Its parameters are :class:`IMMConfig`; the defaults were chosen on seeds 0-199 only
(docs/ANALYSIS.md says how)::

    from cdf_mj.planners.imm import IMMConfig, IMMPlanner
    record = run_episode(config, seed=7, planner=IMMPlanner(IMMConfig(threshold=0.8)))

Each tick runs compiled (:mod:`cdf_mj.planners.baseline_kernels`): the IMM's step, the
predicted paths and their box tests. The compiled IMM is filterpy's ``IMMEstimator`` over
:class:`RouteKalmanFilter`, computed by the kernels; an instance with ``reference = True``
runs filterpy itself (:attr:`IMMPlanner.reference`), the reference that
tests/test_baselines_compiled.py holds the compiled IMM to (states, covariances and mode
probabilities within 1e-9 every tick, the same records). This module imports filterpy
(about 1 s); the registry loads it with the first ``imm`` planner made.

Frames and units: world frame (x east, y north), metres, seconds, radians; poses are
rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import IMMEstimator, KalmanFilter

from cdf_mj.config import MAX_SPEED, LayeredConfig, RiskConfig
from cdf_mj.model.conflict import Futures
from cdf_mj.model.driver import Intent
from cdf_mj.model.geometry import Polyline, wrap_angle
from cdf_mj.model.kernels import RouteTable
from cdf_mj.model.layout import Layout
from cdf_mj.planners import baseline_kernels as kern
from cdf_mj.planners.base import DecidingPlanner, PlannerContext, PlannerInput, ThresholdRule, as_config
from cdf_mj.planners.baseline_common import (
    IMM_LAYERS,
    baseline_rule,
    check_field,
    finite_number,
    first_conflict,
    look_ahead_times,
    route_heading,
    straight_path,
)

__all__ = ["IMMConfig", "IMMLayeredPlanner", "IMMPlanner", "IMMRiskPlanner", "RouteKalmanFilter"]


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
        check_field(finite_number(self.horizon) and 0 < self.horizon <= 10, "horizon", self.horizon,
                    "in (0, 10] [s]")
        check_field(finite_number(self.margin) and 0 <= self.margin <= 5, "margin", self.margin,
                    "in [0, 5] [m]")
        check_field(finite_number(self.threshold) and 0 < self.threshold <= 1, "threshold",
                    self.threshold, "in (0, 1]")
        check_field(finite_number(self.switch_prob) and 0 < self.switch_prob < 0.5, "switch_prob",
                    self.switch_prob, "in (0, 0.5)")
        for name in ("pos_std", "heading_std", "speed_std", "accel_change_std", "heading_window"):
            v = getattr(self, name)
            check_field(finite_number(v) and v > 0, name, v, "a finite number > 0")
        init = tuple(self.init_std)
        check_field(len(init) == 3 and all(finite_number(v) and v > 0 for v in init), "init_std",
                    self.init_std, "3 finite numbers > 0 ([s m, v m/s, a m/s^2])")
        check_field(finite_number(self.max_speed) and 0 < self.max_speed <= MAX_SPEED, "max_speed", self.max_speed,
                    f"in (0, {MAX_SPEED:g}] [m/s]")
        check_field(finite_number(self.p_left) and 0 <= self.p_left <= 1, "p_left", self.p_left,
                    "in [0, 1] (a probability)")

    def replace(self, **changes: Any) -> IMMConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


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

    Not seeing the other car: the IMM starts at its first measurement (before it, no track:
    P(conflict) 0 and no hypothesis for the risk rules), and a tick without one (a dropout,
    or the car out of an occluded sensor's sight, ``sensing.occluded``) only predicts: the
    track coasts along each intent's route at its estimated speed and acceleration, its
    covariance growing, as a tracker does; the next measurement corrects it.

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
        self.rule = baseline_rule(risk, layered, ThresholdRule(self.params.threshold))

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Take the routes and footprints from the layout and ``dt`` from ``context``; its
        prior P(left) and speed cap are its own (:class:`IMMConfig`). The IMM starts at the
        first measurement."""
        super().reset(context, rng)
        p, layout = self.params, context.layout
        self._ego, self._obstacle, self._dt = layout.ego, layout.obstacle, context.dt
        self._routes = dict(zip((Intent.LEFT, Intent.RIGHT), layout.obstacle_routes, strict=True))
        self._times = look_ahead_times(p.horizon, context.dt)
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
    """:class:`IMMPlanner` with the layered rule (default :data:`~cdf_mj.planners.baseline_common.IMM_LAYERS` and
    :class:`RiskConfig`), registered as ``imm-layered``."""

    name = "imm-layered"

    def __init__(self, params: IMMConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, risk, IMM_LAYERS if layered is None else layered)


class IMMRiskPlanner(IMMPlanner):
    """:class:`IMMPlanner` with the risk rule (default :class:`RiskConfig`), registered as ``imm-risk``."""

    name = "imm-risk"

    def __init__(self, params: IMMConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, RiskConfig() if risk is None else risk)
