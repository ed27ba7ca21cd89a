"""Joint belief-intent inference: a particle filter over the CDF's dynamic Bayesian network.

Each particle is one hypothesis of the hidden DBN state ``X_t = [S_t, B_t, I]`` plus the
obstacle driver's mode: the obstacle's pose, whether it has seen the ego and what it
believes, its intent and its state-machine mode. The ego's pose is known to the ego and
is shared by all particles (it is the measured one).

One tick (``dt``), as in the simulation (:mod:`cdf_mj.scenario.episode`):

``predict(S_t)``
    every particle draws its own observation event (probability beta, if the ego is in
    its line of sight from its own eye), updates its own belief (``g``), runs the *same*
    driver state machine as the simulated obstacle (:func:`cdf_mj.model.driver.obstacle_control`)
    with process noise, and moves by the paper's kinematic bicycle ``f``.
``update(S_{t+1})``
    weights ``w ∝ N(x1 | measured x1, Sigma)`` kept as log-weights, normalised after
    subtracting their maximum; stratified resampling when the effective sample size
    falls below ``resample_ess_fraction * N`` (every step by default, as in the paper).

Outputs (:class:`Posterior`): P(left), P(right), P(seen), P(cutoff) and the ESS, where
P(cutoff) is the weighted probability that the obstacle cuts the ego off: a committed
left-turner does; a left-turner pulling out on a clear belief (mode GOING) does unless
it sees the ego on one of the r ticks left before its commit point, (1 - beta)^r with
the "predictive" rule, or fully with the paper's rule (``CDFConfig.cutoff_rule``). It is
counted while the ego itself is exposed (:meth:`ParticleFilter.ego_exposed`: not past
the conflict point and within the critical gap of it), else 0. ::

    pf = ParticleFilter.from_layout(scene.layout(), ScenarioConfig(), CDFConfig(), rng)
    pf.reset(S0)
    for S in measurements:
        pf.predict(S_prev); post = pf.update(S)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference.resampling import effective_sample_size, stratified_resample
from cdf_mj.model.driver import DriverModel, Intent, Mode, bicycle_step, obstacle_control, road_clear, update_belief
from cdf_mj.model.geometry import wrap_angle
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import Occluders, sight_targets
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["ParticleFilter", "Posterior"]


# Plain ints for the per-tick code (IntEnum attribute access costs a Python call each time).
_LEFT, _GOING, _COMMITTED = int(Intent.LEFT), int(Mode.GOING), int(Mode.COMMITTED)


def _finite(a: np.ndarray) -> bool:
    """Whether a small array (a pose) is all finite."""
    return all(math.isfinite(x) for x in a.flat)


def _unit(p: float) -> float:
    """A probability summed from weights, clipped into [0, 1] against rounding."""
    return float(min(max(p, 0.0), 1.0))


@dataclass(frozen=True)
class Posterior:
    """The filter's answer at one tick. Probabilities in [0, 1]; ESS in [1, N]."""

    p_left: float
    p_right: float
    p_seen: float  # P(the obstacle has observed the ego)
    p_cutoff: float  # P(left-turner pulling out on a clear belief)
    ess: float  # effective sample size before resampling

    def to_dict(self) -> dict[str, float]:
        """JSON-serialisable view."""
        return asdict(self)


class ParticleFilter:
    """Vectorised particle filter over ``[obstacle pose, mode, belief, seen, intent]``.

    Args:
        model: the drivers' geometry and behaviour (the same as the simulation's).
        obstacle: the obstacle's dimensions (eye, wheelbase, actuator ranges).
        ego: the ego's dimensions (footprint for line of sight).
        occluders: building boxes for vectorised line of sight.
        scenario: scenario parameters (beta, noise levels, prior P(left)).
        cdf: filter parameters (N, Sigma, thresholds).
        rng: the Generator of all the filter's randomness.
    """

    def __init__(self, model: DriverModel, obstacle: CarGeometry, ego: CarGeometry,
                 occluders: Occluders, scenario: ScenarioConfig, cdf: CDFConfig,
                 rng: np.random.Generator) -> None:
        self.model, self.obstacle, self.ego, self.occluders = model, obstacle, ego, occluders
        self.scenario, self.cdf, self.rng = scenario, cdf, rng
        self.n = cdf.n_particles
        self._cov_inv = np.linalg.inv(cdf.covariance)
        self._obs_std = np.array([scenario.obs_noise_pos, scenario.obs_noise_pos,
                                  scenario.obs_noise_heading, scenario.obs_noise_speed])
        self._nu_std = cdf.process_noise_scale * np.array([scenario.noise_accel, scenario.noise_steer])
        self.skipped_updates = 0  # measurements that were NaN or infinite
        self.reinits = 0  # times every likelihood vanished
        self._ego: np.ndarray | None = None
        self._ego_targets: np.ndarray | None = None
        # The particles (N rows after reset): obstacle pose (N, 4), driver mode (N,), belief
        # (N, 4), whether the driver has seen the ego (N,), intent (N,).
        self.pose = np.zeros((0, 4))
        self.mode = np.zeros(0, dtype=int)
        self.belief = np.zeros((0, 4))
        self.has_belief = np.zeros(0, dtype=bool)
        self.intent = np.zeros(0, dtype=int)
        # Log-weights (N,). Assign a new array to change them, never edit one in place:
        # `weights` is computed once per array.
        self.logw = np.zeros(0)
        self._w = np.zeros(0)  # weights of the log-weight array _w_of
        self._w_of: np.ndarray | None = None

    @classmethod
    def from_layout(cls, layout: Layout, scenario: ScenarioConfig, cdf: CDFConfig,
                    rng: np.random.Generator) -> ParticleFilter:
        """A filter for a junction (``Scene.layout()``): its routes, buildings and cars."""
        return cls(DriverModel.from_layout(layout, scenario), layout.obstacle, layout.ego,
                   layout.occluders, scenario, cdf, rng)

    # ------------------------------------------------------------------ state
    def reset(self, system_pose: np.ndarray) -> Posterior:
        """Prior at the first measurement ``S_0`` (2, 4): the obstacle where it is
        measured, waiting, never having seen the ego; intent from the prior."""
        system_pose = np.asarray(system_pose, dtype=float)
        if not np.all(np.isfinite(system_pose)):
            raise ValueError(f"the first system pose must be finite, got {system_pose.tolist()}")
        n = self.n
        self.pose = np.repeat(system_pose[1][None], n, axis=0)
        self.intent = np.where(self.rng.random(n) < self.scenario.p_left, Intent.LEFT, Intent.RIGHT)
        self.mode = np.full(n, Mode.WAITING)
        self.belief = np.zeros((n, 4))
        self.has_belief = np.zeros(n, dtype=bool)
        self.logw = np.zeros(n)
        self._ego = system_pose[0].copy()
        self._ego_targets = None
        return self.posterior()

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights (N,). Computed once per ``logw`` array: the filter assigns
        a new array whenever the log-weights change, never edits one it has weighed."""
        if self._w_of is not self.logw:
            w = np.exp(self.logw - self.logw.max())
            w /= w.sum()
            w.flags.writeable = False  # shared by every reader until the log-weights change
            self._w, self._w_of = w, self.logw
        return self._w

    def posterior(self) -> Posterior:
        """P(left), P(right), P(seen), P(cutoff) and ESS of the current weights."""
        w = self.weights
        left = self.intent == _LEFT
        p_left = _unit(w[left].sum())
        p_cutoff = _unit(w @ self.cutoff_probability()) if self.ego_exposed() else 0.0
        return Posterior(p_left=p_left, p_right=1.0 - p_left, p_seen=_unit(w[self.has_belief].sum()),
                         p_cutoff=p_cutoff, ess=float(effective_sample_size(w)))

    def cutoff_probability(self) -> np.ndarray:
        """Per particle, the probability that it cuts the ego off (N,), see ``cutoff_rule``."""
        left = self.intent == _LEFT
        p: np.ndarray = (left & (self.mode == _COMMITTED)).astype(float)
        going = left & (self.mode == _GOING)
        if self.cdf.cutoff_rule == "paper":
            p[going] = 1.0
            return p
        idx = np.flatnonzero(going)
        if idx.size:
            cfg = self.scenario
            s = self.model.routes[_LEFT].project(self.pose[idx, :2])[0]
            remaining = np.maximum(self.model.s_commit[_LEFT] - s, 0.0)  # [m]
            v = self.pose[idx, 3]
            t_commit = (np.sqrt(v * v + 2.0 * cfg.obstacle_accel * remaining) - v) / cfg.obstacle_accel
            ticks = np.ceil(t_commit / cfg.dt - 1e-9)  # looks left before the commit point
            beta = cfg.beta * self.occluders.visible(self.obstacle.eye(self.pose[idx]), self._targets())
            p[idx] = (1.0 - beta) ** ticks
        return p

    def _ego_pose(self) -> np.ndarray:
        """The ego's pose (4,) the filter last took; RuntimeError before :meth:`reset`."""
        if self._ego is None:
            raise RuntimeError("the particle filter has no measurement yet: call reset(S0) first")
        return self._ego

    def _targets(self) -> np.ndarray:
        """The ego's sight-line targets ``(5, 2)``: its hull corners and centre (cached per pose)."""
        targets = self._ego_targets
        if targets is None:
            targets = self._ego_targets = sight_targets(self.ego, self._ego_pose())
        return targets

    def ego_exposed(self) -> bool:
        """Whether the (known) ego could still be cut off: it has not passed the conflict
        point and would reach it within the critical gap. The driver's own "clear" rule,
        applied to the true ego pose instead of a belief."""
        clear = road_clear(self.model, self._ego_pose()[None], np.array([True]), np.array([Intent.LEFT]))
        return not bool(clear[0])

    # ------------------------------------------------------------------ one tick
    def predict(self, system_pose: np.ndarray | None = None) -> None:
        """Propagate every particle through one tick of the DBN from ``S_t``.

        The ego's pose comes from ``system_pose[0]`` when it is finite, else the last one.
        The stages are methods of their own (``look``, ``believe``, ``act``, ``move``),
        called in this order, so that a benchmark can time the real code.
        """
        self.set_ego(system_pose)
        self.believe(*self.look())
        self.move(self.act())

    def set_ego(self, system_pose: np.ndarray | None) -> None:
        """Take the ego's pose from ``system_pose[0]`` where it is finite."""
        if system_pose is not None:
            ego = np.asarray(system_pose, dtype=float)[0]
            if _finite(ego) and (self._ego is None or not np.array_equal(ego, self._ego)):
                self._ego = ego.copy()
                self._ego_targets = None

    def look(self) -> tuple[np.ndarray, np.ndarray]:
        """Observation events ``(N,)`` (beta draw, then line of sight only where it matters)
        and the noisy observations ``(N, 4)`` of the ego (``k``)."""
        cfg, n, rng = self.scenario, self.n, self.rng
        observed = rng.random(n) < cfg.beta
        idx = np.flatnonzero(observed)
        if idx.size:
            observed[idx] = self.occluders.visible(self.obstacle.eye(self.pose[idx]), self._targets())
        return observed, self._ego_pose() + rng.standard_normal((n, 4)) * self._obs_std

    def believe(self, observed: np.ndarray, observation: np.ndarray) -> None:
        """Each particle's belief update ``g``."""
        self.belief, self.has_belief = update_belief(self.belief, self.has_belief, observed,
                                                     observation, self.scenario.dt, self.ego.wheelbase)

    def act(self) -> np.ndarray:
        """The driver ``h`` of every particle (updates its mode) plus process noise,
        clipped to the actuator ranges; returns ``u`` ``(N, 2)``."""
        u, self.mode = obstacle_control(self.model, self.pose, self.mode, self.belief,
                                        self.has_belief, self.intent)
        u = u + self.rng.standard_normal((self.n, 2)) * self._nu_std
        u[:, 0] = np.clip(u[:, 0], self.obstacle.accel_range[0], self.obstacle.accel_range[1])
        u[:, 1] = np.clip(u[:, 1], self.obstacle.steer_range[0], self.obstacle.steer_range[1])
        return u

    def move(self, u: np.ndarray) -> None:
        """The bicycle ``f`` for every particle."""
        self.pose = bicycle_step(self.pose, u, self.scenario.dt, self.obstacle.wheelbase)

    def update(self, system_pose: np.ndarray) -> Posterior:
        """Weight by the measured obstacle pose, resample, and return the posterior.

        A non-finite measurement is skipped (counted in ``skipped_updates``). If every
        particle is implausible (all Mahalanobis distances above ``reinit_mahalanobis``),
        the particles' poses are re-initialised at the measurement, keeping their
        discrete hypotheses (counted in ``reinits``). Stages: ``weigh``, ``resample``.
        """
        post = self.weigh(system_pose)
        if post.ess < self.cdf.resample_ess_fraction * self.n:
            self.resample()
        return post

    def weigh(self, system_pose: np.ndarray) -> Posterior:
        """The likelihood of the measured obstacle pose, normalised log-weights, and the
        posterior of these weights (before any resampling)."""
        system_pose = np.asarray(system_pose, dtype=float)
        self.set_ego(system_pose)  # the ego's pose now, for P(cutoff)
        meas = system_pose[1]
        if not _finite(meas):
            self.skipped_updates += 1
            return self.posterior()
        d = self.pose - meas
        d[:, 2] = wrap_angle(d[:, 2])
        maha2 = ((d @ self._cov_inv) * d).sum(axis=1)
        if maha2.min() > self.cdf.reinit_mahalanobis ** 2:
            self.reinits += 1
            self.pose = np.repeat(meas[None], self.n, axis=0)
            self.logw = np.zeros(self.n)
            return self.posterior()
        self.logw = self.logw - 0.5 * maha2
        self.logw -= self.logw.max()
        return self.posterior()

    def resample(self) -> None:
        """Stratified resampling of every particle array; weights back to uniform."""
        keep = stratified_resample(self.weights, self.rng)
        self.pose, self.mode, self.belief = self.pose[keep], self.mode[keep], self.belief[keep]
        self.has_belief, self.intent = self.has_belief[keep], self.intent[keep]
        self.logw = np.zeros(self.n)
