"""Joint belief-intent inference: a particle filter over the CDF's dynamic Bayesian network.

Each particle is one hypothesis of the hidden DBN state ``X_t = [S_t, B_t, I]`` plus the
obstacle driver's mode and its own driver parameters: the obstacle's pose, whether it has
seen the ego and what it believes, its intent, its state-machine mode, and its beta,
critical gap, clear distance, acceleration, turn speed, yield braking and departure
hazard, drawn at reset from the filter's own prior (``CDFConfig.prior``, a
:class:`cdf_mj.config.DriverPrior`), not copied from the world. The filter reads from the
:class:`ScenarioConfig` only the tick ``dt``, the observation and process noise, the
route-following look-ahead and ``passed_margin`` (a believed ego this far past the
conflict point is gone: a geometric margin of the junction, not a trait of the driver).
The ego's pose is known to the ego and is shared by all particles (it is the measured
one).

One tick (``dt``), as in the simulation (:mod:`cdf_mj.scenario.episode`):

``predict(S_t)``
    every particle draws its own observation event (its beta, if the ego is in its line
    of sight from its own eye), updates its own belief (``g``), runs the *same* driver
    state machine as the simulated obstacle (:func:`cdf_mj.model.driver.obstacle_control`)
    with its own parameters and process noise, and moves by the paper's kinematic
    bicycle ``f``. A waiting particle whose belief says clear leaves with its departure
    hazard (per tick ``1 - exp(-h dt)``); with probability ``mode_jump`` a particle that
    is not committed jumps (held back -> going, going -> yielding).
``update(S_{t+1})``
    weights ``w ∝ N(x1 | measured x1, Sigma)`` kept as log-weights, normalised after
    subtracting their maximum; stratified resampling when the effective sample size
    falls below ``resample_ess_fraction * N`` (every step by default, as in the paper),
    after which a fraction ``intent_floor`` of the particles still held back redraw their
    intent from the prior. If every likelihood vanishes, the particles are re-initialised at the
    measurement with their discrete state and parameters redrawn from the prior.

Outputs (:class:`Posterior`): P(left), P(right), P(seen), P(cutoff) and the ESS, where
P(cutoff) is the weighted probability that the obstacle cuts the ego off: a committed
left-turner does; a left-turner pulling out on a clear belief (mode GOING) does unless
it sees the ego on one of the r ticks left before its commit point, (1 - beta)^r with
the "predictive" rule, or fully with the paper's rule (``CDFConfig.cutoff_rule``). The
looks r count only until the ego's last chance to stop short of the obstacle's path
(braking ``CDFConfig.ego_brake`` after ``ego_latency``): past that, waiting for the
driver to see it is no option. It is counted while the ego itself is exposed
(:meth:`ParticleFilter.ego_exposed`: it has not yet cleared the obstacle's path), else 0.
:meth:`ParticleFilter.futures` gives the left-turners' futures that the risk decision
rule (:mod:`cdf_mj.planners.decision`) rolls forward. ::

    pf = ParticleFilter.from_layout(scene.layout(), ScenarioConfig(), CDFConfig(), rng)
    pf.reset(S0)
    for S in measurements:
        pf.predict(S_prev); post = pf.update(S)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from cdf_mj.config import CDFConfig, DriverPrior, ScenarioConfig
from cdf_mj.inference.resampling import effective_sample_size, stratified_resample
from cdf_mj.model.conflict import Futures
from cdf_mj.model.driver import (
    DriverModel,
    DriverParams,
    Intent,
    Mode,
    bicycle_step,
    obstacle_control,
    update_belief,
)
from cdf_mj.model.geometry import OrientedBox, wrap_angle
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import Occluders, sight_targets
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["THETA", "ParticleFilter", "Posterior", "draw_parameters"]


# Plain ints for the per-tick code (IntEnum attribute access costs a Python call each time).
_LEFT, _RIGHT = int(Intent.LEFT), int(Intent.RIGHT)
_WAITING, _GOING, _YIELDING, _COMMITTED = (int(m) for m in Mode)
#: Columns of the per-particle parameter array ``ParticleFilter.theta`` (N, 7).
THETA = ("accel", "turn_speed", "yield_brake", "critical_gap", "clear_distance", "beta", "p_go")


def draw_parameters(prior: DriverPrior, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` drivers' parameters drawn from ``prior``: an ``(n, 7)`` array with the columns
    :data:`THETA` (uniform on each range; the departure hazard log-uniform and stored as
    its per-tick probability ``p_go = 1 - exp(-h dt)``)."""
    theta = np.empty((n, len(THETA)))
    for j, name in enumerate(THETA[:-1]):
        lo, hi = getattr(prior, name)
        theta[:, j] = rng.uniform(lo, hi, n) if hi > lo else lo
    lo, hi = prior.departure_hazard
    hazard = np.exp(rng.uniform(math.log(lo), math.log(hi), n)) if hi > lo else np.full(n, lo)
    theta[:, -1] = -np.expm1(-hazard * dt)
    return theta


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


@numba.njit(cache=True, nogil=True)
def _left_futures(weights: np.ndarray, intent: np.ndarray, mode: np.ndarray, arc: np.ndarray, speed: np.ndarray,
                  theta: np.ndarray, belief: np.ndarray, has_belief: np.ndarray, sees: np.ndarray,
                  conflict_x: float, conflict_y: float, passed_margin: float, s_commit: float, dt: float,
                  react_ticks: int, ego: np.ndarray) -> tuple[np.ndarray, ...]:  # pragma: no cover - compiled
    """:meth:`ParticleFilter.futures` in one pass over the particles: the weight, arc length
    [m], speed [m/s], acceleration [m/s^2], cruise speed [m/s] and delay [s] of every
    left-turner that may go on (a finite delay and a positive weight). "Held back until
    the believed ego has passed" is the driver's own clear rule
    (:func:`cdf_mj.model.driver.road_clear`: passed, or far by distance and gap), per
    particle; tests/test_decision.py checks the two agree."""
    n = weights.shape[0]
    # Where the ego is, as a driver who looks now would judge it (the clear rule's terms).
    ego_ahead = (conflict_x - ego[0]) * math.cos(ego[2]) + (conflict_y - ego[1]) * math.sin(ego[2])
    ego_passed = ego_ahead < -passed_margin
    w_out, s_out, v_out = np.empty(n), np.empty(n), np.empty(n)
    a_out, vm_out, d_out = np.empty(n), np.empty(n), np.empty(n)
    m = 0
    for i in range(n):
        w = weights[i]
        if intent[i] != _LEFT or w <= 0.0:
            continue
        md = mode[i]
        v = speed[i]
        a = theta[i, 0]
        delay = 0.0
        if md in (_WAITING, _YIELDING):
            v = 0.0
            if has_belief[i]:
                bx, by, bth, bv = belief[i, 0], belief[i, 1], belief[i, 2], belief[i, 3]
                ahead = (conflict_x - bx) * math.cos(bth) + (conflict_y - by) * math.sin(bth)
                passed = ahead < -passed_margin
                far = ahead > theta[i, 4] and ahead > theta[i, 3] * max(bv, 0.0)
                if not (passed or far):  # held back until the believed ego has passed
                    if bv <= 0.1:
                        continue
                    delay = max((ahead + passed_margin) / bv, 0.0)
            if md == _WAITING:  # and it leaves at its hazard: within the reaction window, or later
                w *= 1.0 - (1.0 - theta[i, 6]) ** react_ticks
        # Looks ahead of it before its commit point stop it only if it would then judge the
        # ego not clear (a far or passed ego is no reason to yield).
        seen_clear = ego_passed or (ego_ahead > theta[i, 4] and ego_ahead > theta[i, 3] * max(ego[3], 0.0))
        if md != _COMMITTED and sees[i] and not seen_clear:
            remaining = max(s_commit - arc[i], 0.0)
            t_commit = (math.sqrt(v * v + 2.0 * a * remaining) - v) / a
            w *= (1.0 - theta[i, 5]) ** math.ceil(t_commit / dt - 1e-9)
        if w <= 0.0:
            continue
        w_out[m], s_out[m], v_out[m], a_out[m], vm_out[m], d_out[m] = w, arc[i], v, a, theta[i, 1], delay
        m += 1
    return w_out[:m], s_out[:m], v_out[:m], a_out[:m], vm_out[:m], d_out[:m]


class ParticleFilter:
    """Vectorised particle filter over ``[obstacle pose, mode, belief, seen, intent]``.

    Args:
        model: the junction's routes and points (the same as the simulation's); its
            ``config`` gives only ``dt``, ``passed_margin`` and the pure-pursuit look-ahead.
        obstacle: the obstacle's dimensions (eye, wheelbase, actuator ranges).
        ego: the ego's dimensions (footprint for line of sight, braking).
        occluders: building boxes for vectorised line of sight.
        scenario: the tick ``dt`` and the observation and process noise levels.
        cdf: filter parameters (N, Sigma, thresholds, the driver prior, rejuvenation,
            the ego's braking and latency).
        rng: the Generator of all the filter's randomness (nothing is drawn before reset).
        ego_lane: the ego's lane area: where the obstacle's route first puts it into the
            lane (without it: where its nose reaches the conflict point).
    """

    def __init__(self, model: DriverModel, obstacle: CarGeometry, ego: CarGeometry,
                 occluders: Occluders, scenario: ScenarioConfig, cdf: CDFConfig,
                 rng: np.random.Generator, ego_lane: OrientedBox | None = None) -> None:
        self.model, self.obstacle, self.ego, self.occluders = model, obstacle, ego, occluders
        self.scenario, self.cdf, self.rng = scenario, cdf, rng
        self.n = cdf.n_particles
        self._cov_inv = np.linalg.inv(cdf.covariance)
        self._obs_std = np.array([scenario.obs_noise_pos, scenario.obs_noise_pos,
                                  scenario.obs_noise_heading, scenario.obs_noise_speed])
        self._nu_std = cdf.process_noise_scale * np.array([scenario.noise_accel, scenario.noise_steer])
        self.prior = prior = cdf.prior
        self._ego_brake = cdf.ego_brake if cdf.ego_brake is not None else ego.max_brake  # [m/s^2]
        # The ego must stop with its nose short of the obstacle's side [m from its rear axle].
        self._stop_margin = float(ego.hull_offset[0] + ego.hull_half[0] + obstacle.hull_half[1])
        # The ego has cleared the obstacle's path once its tail is past the conflict point by
        # the obstacle's half width [m, rear axle past the conflict point].
        self._clear_margin = float(ego.hull_half[0] - ego.hull_offset[0] + obstacle.hull_half[1])
        # Arc length on the left route [m] at which the obstacle first puts a corner into
        # the ego's lane (its nose at the conflict point without a lane box).
        route = model.routes[_LEFT]
        s_conflict = float(route.project(model.conflict)[0])
        self._s_enter = s_conflict - float(obstacle.hull_offset[0] + obstacle.hull_half[0])
        if ego_lane is not None:
            s_grid = np.arange(0.0, s_conflict, 0.05)
            xy, ahead = route.point_at(s_grid), route.point_at(s_grid + 0.05)
            heading = np.arctan2(ahead[:, 1] - xy[:, 1], ahead[:, 0] - xy[:, 0])
            poses = np.column_stack([xy, heading, np.zeros_like(heading)])
            inside = np.flatnonzero(ego_lane.contains(obstacle.footprint(poses)).any(axis=-1))
            if inside.size:
                self._s_enter = float(s_grid[inside[0]])
        # Kernel jitter of the continuous parameters after each resampling: std = this
        # fraction of each prior range, values kept inside the range.
        ranges = np.array([getattr(prior, name) for name in THETA[:-1]], dtype=float)
        self._theta_lo, self._theta_hi = ranges[:, 0], ranges[:, 1]
        self._jitter_std = cdf.param_jitter * (self._theta_hi - self._theta_lo)
        # [s] the slowest plausible driver needs from a standstill at the line into the lane.
        self._t_slowest = float(self._arrival(np.zeros(1), np.zeros(1), np.array([prior.accel[0]]),
                                              np.array([prior.turn_speed[0]]))[0])
        self.skipped_updates = 0  # measurements that were NaN or infinite
        self.reinits = 0  # times every likelihood vanished
        self._ego: np.ndarray | None = None
        self._ego_targets: np.ndarray | None = None
        self._arc: np.ndarray = np.zeros(0)  # arc length on the left route of the pose array _arc_of
        self._arc_of: np.ndarray | None = None
        self._sight: np.ndarray = np.zeros(0, dtype=bool)  # ego visible from each eye, for _sight_of
        self._sight_of: tuple[np.ndarray, np.ndarray] | None = None
        # The particles (N rows after reset): obstacle pose (N, 4), driver mode (N,), belief
        # (N, 4), whether the driver has seen the ego (N,), intent (N,).
        self.pose = np.zeros((0, 4))
        self.mode = np.zeros(0, dtype=int)
        self.belief = np.zeros((0, 4))
        self.has_belief = np.zeros(0, dtype=bool)
        self.intent = np.zeros(0, dtype=int)
        self.theta = np.zeros((0, len(THETA)))  # per-particle driver parameters, columns THETA
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
                   layout.occluders, scenario, cdf, rng, layout.ego_lane)

    # ------------------------------------------------------------------ state
    def reset(self, system_pose: np.ndarray) -> Posterior:
        """Prior at the first measurement ``S_0`` (2, 4): the obstacle where it is
        measured, waiting, never having seen the ego; intent and driver parameters from
        the prior (``CDFConfig.prior``)."""
        system_pose = np.asarray(system_pose, dtype=float)
        if not np.all(np.isfinite(system_pose)):
            raise ValueError(f"the first system pose must be finite, got {system_pose.tolist()}")
        n = self.n
        self.pose = np.repeat(system_pose[1][None], n, axis=0)
        self.intent = self._draw_intent(n)
        self.mode = np.full(n, _WAITING)
        self.belief = np.zeros((n, 4))
        self.has_belief = np.zeros(n, dtype=bool)
        self.theta = draw_parameters(self.prior, n, self.scenario.dt, self.rng)
        self.logw = np.zeros(n)
        self._ego = system_pose[0].copy()
        self._ego_targets = None
        return self.posterior()

    def _draw_intent(self, n: int) -> np.ndarray:
        """``n`` intents from the prior P(left)."""
        return np.where(self.rng.random(n) < self.prior.p_left, _LEFT, _RIGHT)

    @property
    def params(self) -> DriverParams:
        """The particles' driver parameters as ``(N,)`` arrays (views of ``theta``)."""
        t = self.theta
        return DriverParams(accel=t[:, 0], turn_speed=t[:, 1], yield_brake=t[:, 2],
                            critical_gap=t[:, 3], clear_distance=t[:, 4])

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
        """Per particle, the probability that it cuts the ego off (N,), see ``cutoff_rule``.

        With the predictive rule a left-turner counts only if it enters the ego's lane
        (accelerating at its own rate up to its turn speed) before the ego, holding its
        speed, has cleared the conflict point: one that pulls out behind the ego is no
        cut-off (the scenario's own label), and braking for it would stop the ego in its
        path."""
        left = self.intent == _LEFT
        committed = left & (self.mode == _COMMITTED)
        p: np.ndarray = committed.astype(float)
        going = left & (self.mode == _GOING)
        if self.cdf.cutoff_rule == "paper":
            p[going] = 1.0
            return p
        # Pulls out behind the ego? Only worth testing once the ego clears the conflict
        # point sooner than the slowest driver of the prior could get there.
        t_clear = self.ego_time_to_clear()
        behind_test = t_clear < self._t_slowest
        # One projection on the left route for every particle that needs its arc length.
        rows = np.flatnonzero(going | committed) if behind_test else np.flatnonzero(going)
        if rows.size == 0:
            return p
        s_rows = self.left_arc()[rows]
        in_going = going[rows]
        idx = rows[in_going]
        if idx.size:
            s = s_rows[in_going]
            v = self.pose[idx, 3]
            a = self.theta[idx, 0]
            dt = self.scenario.dt
            remaining = np.maximum(self.model.s_commit[_LEFT] - s, 0.0)  # [m]
            t_commit = (np.sqrt(v * v + 2.0 * a * remaining) - v) / a
            ticks = np.minimum(np.ceil(t_commit / dt - 1e-9), self.ego_ticks_to_stop())
            beta = self.theta[idx, 5] * self.sees_ego()[idx]
            p[idx] = (1.0 - beta) ** ticks
        if behind_test:
            counted = p[rows] > 0.0
            moving = rows[counted]
            if moving.size:
                behind = self._arrival(s_rows[counted], self.pose[moving, 3], self.theta[moving, 0],
                                       self.theta[moving, 1]) > t_clear
                p[moving[behind]] = 0.0
        return p

    def _arrival(self, s: np.ndarray, v: np.ndarray, a: np.ndarray, v_turn: np.ndarray) -> np.ndarray:
        """[s] until the left-turners enter the ego's lane: from arc length ``s``
        and speed ``v``, accelerating at ``a`` up to ``v_turn``, then at that speed."""
        rem = np.maximum(self._s_enter - s, 0.0)  # [m]
        t_acc = np.maximum(v_turn - v, 0.0) / a  # [s] to the turn speed
        d_acc = v * t_acc + 0.5 * a * t_acc * t_acc  # [m] covered meanwhile
        accelerating = (np.sqrt(v * v + 2.0 * a * rem) - v) / a
        cruising = t_acc + (rem - d_acc) / np.maximum(v_turn, 0.1)
        t: np.ndarray = np.where(rem <= d_acc, accelerating, cruising)
        return t

    def ego_time_to_clear(self) -> float:
        """[s] until the ego, holding its speed, has cleared the obstacle's path at the
        conflict point (its tail past it by the obstacle's half width); ``inf`` if stopped."""
        ego = self._ego_pose()
        v = float(ego[3])
        ahead = ((self.model.conflict[0] - ego[0]) * math.cos(ego[2])
                 + (self.model.conflict[1] - ego[1]) * math.sin(ego[2]))  # [m]
        rest = ahead + self._clear_margin
        if rest <= 0.0:
            return 0.0
        return rest / v if v > 0.1 else math.inf

    def ego_ticks_to_stop(self) -> float:
        """Ticks left before the ego's last chance to brake (``ego_brake`` after
        ``ego_latency``) and stop with its nose short of the obstacle's path at the
        conflict point; ``inf`` for an ego that is (nearly) stopped, 0 once too late."""
        ego = self._ego_pose()
        v = float(ego[3])
        if v < 0.1:
            return math.inf
        ahead = ((self.model.conflict[0] - ego[0]) * math.cos(ego[2])
                 + (self.model.conflict[1] - ego[1]) * math.sin(ego[2]))  # [m]
        slack = ahead - self._stop_margin - v * v / (2.0 * self._ego_brake)  # [m] before braking
        t = slack / v - self.cdf.ego_latency  # [s]
        return float(max(math.ceil(t / self.scenario.dt - 1e-9), 0))

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
        """Whether the (known) ego could still be cut off: it has not yet cleared the
        obstacle's path at the conflict point (its tail past it by the obstacle's half
        width, :meth:`ego_time_to_clear`). An explicit test of the ego's exposure, not the
        obstacle driver's gap acceptance (a deviation from the paper, docs/DECISION.md)."""
        return self.ego_time_to_clear() > 0.0

    def left_arc(self) -> np.ndarray:
        """[m] every particle's arc length on the left route ``(N,)``, computed once per
        pose array (the filter assigns a new one whenever the particles move)."""
        if self._arc_of is not self.pose:
            self._arc = self.model.routes[_LEFT].project(self.pose[:, :2])[0]
            self._arc_of = self.pose
        return self._arc

    def sees_ego(self) -> np.ndarray:
        """Whether the ego is in each particle driver's line of sight ``(N,)``, computed once
        per pose array and ego pose."""
        targets = self._targets()
        cached = self._sight_of
        if cached is None or cached[0] is not self.pose or cached[1] is not targets:
            self._sight = self.occluders.visible(self.obstacle.eye(self.pose), targets)
            self._sight_of = (self.pose, targets)
        return self._sight

    def futures(self, react_ticks: int = 1) -> Futures:
        """The left-turners' futures for the risk decision rule
        (:class:`cdf_mj.model.conflict.Futures`), each particle weighted by its weight
        times the probability that its driver goes on into the ego's lane:

        - committed: goes on (probability 1, now);
        - going: unless it sees the ego on one of the ticks before its commit point,
          ``(1 - beta_i visible_i)^r``, from now (a look stops it only where its clear rule
          would find the ego it sees not clear);
        - yielding with a clear belief: goes again now, with the same looks ahead of it;
        - held back by a belief of an ego coming: goes once that believed (dead-reckoned)
          ego is past the conflict point by ``passed_margin``;
        - waiting at the line: as the last two, leaving within the ``react_ticks`` ticks
          after it may (its departure hazard; the tick it leaves on it moves), before the
          ego could react to it.

        Its own acceleration and turn speed, from its current speed (0 once held back).
        """
        out = _left_futures(self.weights, self.intent, self.mode, self.left_arc(), self.pose[:, 3], self.theta,
                            self.belief, self.has_belief, self.sees_ego(), float(self.model.conflict[0]),
                            float(self.model.conflict[1]), float(self.model.config.passed_margin),
                            float(self.model.s_commit[_LEFT]), self.scenario.dt, react_ticks, self._ego_pose())
        return Futures(*out)

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
        n, rng = self.n, self.rng
        observed = rng.random(n) < self.theta[:, 5]
        idx = np.flatnonzero(observed)
        if idx.size:
            observed[idx] = self.occluders.visible(self.obstacle.eye(self.pose[idx]), self._targets())
        return observed, self._ego_pose() + rng.standard_normal((n, 4)) * self._obs_std

    def believe(self, observed: np.ndarray, observation: np.ndarray) -> None:
        """Each particle's belief update ``g``."""
        self.belief, self.has_belief = update_belief(self.belief, self.has_belief, observed,
                                                     observation, self.scenario.dt, self.ego.wheelbase)

    def act(self) -> np.ndarray:
        """The driver ``h`` of every particle (updates its mode; a waiting particle whose
        stop is over by its departure-hazard draw goes if clear), the mode jumps, plus
        process noise, clipped to the actuator ranges; returns ``u`` ``(N, 2)``."""
        rng, n = self.rng, self.n
        params = self.params
        may_go = rng.random(n) < self.theta[:, 6]
        u, mode = obstacle_control(self.model, self.pose, self.mode, self.belief,
                                   self.has_belief, self.intent, params, may_go)
        if self.cdf.mode_jump > 0.0:
            jump = rng.random(n) < self.cdf.mode_jump
            if jump.any():
                go = jump & ((mode == _WAITING) | (mode == _YIELDING))
                stop = jump & (mode == _GOING)
                mode[go] = _GOING  # takes the gap whatever it saw
                self.has_belief = self.has_belief & ~go
                u[go, 0] = self.theta[go, 0]
                mode[stop] = _YIELDING  # hesitates for a tick
                u[stop, 0] = -self.theta[stop, 2]
        self.mode = mode
        u = u + rng.standard_normal((n, 2)) * self._nu_std
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
        the particles are re-initialised at the measurement (counted in ``reinits``; see
        :meth:`reinitialise`). Stages: ``weigh``, ``resample``.
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
            self.reinitialise(meas)
            return self.posterior()
        self.logw = self.logw - 0.5 * maha2
        self.logw -= self.logw.max()
        return self.posterior()

    def reinitialise(self, measured: np.ndarray) -> None:
        """Every likelihood vanished: all particles at the measured obstacle pose (4,),
        weights uniform. With ``reinit_redraw`` (default) the discrete state is redrawn
        so that no hypothesis stays dead: intent from the prior, mode going if the car is
        measured moving (> 0.5 m/s) else waiting, seen the ego with probability 1/2 (its
        belief then the ego's pose with observation noise), and the driver parameters
        from the prior. Without it, the particles keep their discrete hypotheses."""
        n, rng = self.n, self.rng
        self.reinits += 1
        self.pose = np.repeat(np.asarray(measured, dtype=float)[None], n, axis=0)
        self.logw = np.zeros(n)
        if not self.cdf.reinit_redraw:
            return
        self.intent = self._draw_intent(n)
        self.mode = np.full(n, _GOING if measured[3] > 0.5 else _WAITING)
        self.has_belief = rng.random(n) < 0.5
        self.belief = np.where(self.has_belief[:, None],
                               self._ego_pose() + rng.standard_normal((n, 4)) * self._obs_std, 0.0)
        self.theta = draw_parameters(self.prior, n, self.scenario.dt, rng)

    def resample(self) -> None:
        """Stratified resampling of every particle array; weights back to uniform. Then
        the continuous driver parameters get a small Gaussian jitter (``param_jitter``;
        not the departure hazard), and a fraction ``intent_floor`` of the particles
        still held back (waiting or yielding) redraw their intent from the prior."""
        keep = stratified_resample(self.weights, self.rng)
        arc = self._arc if self._arc_of is self.pose else None
        sight = self._sight_of[1] if self._sight_of is not None and self._sight_of[0] is self.pose else None
        self.pose, self.mode, self.belief = self.pose[keep], self.mode[keep], self.belief[keep]
        # The resampled particles' arc lengths and lines of sight are their ancestors'.
        if arc is not None:
            self._arc, self._arc_of = arc[keep], self.pose
        if sight is not None:
            self._sight, self._sight_of = self._sight[keep], (self.pose, sight)
        self.has_belief, self.intent, self.theta = self.has_belief[keep], self.intent[keep], self.theta[keep]
        self.logw = np.zeros(self.n)
        if self.cdf.param_jitter > 0.0:  # static parameters would collapse onto one ancestor
            jittered = self.rng.standard_normal((self.n, len(THETA) - 1))
            jittered *= self._jitter_std
            jittered += self.theta[:, :-1]
            np.maximum(jittered, self._theta_lo, out=jittered)  # np.clip, in place: a third of the time
            np.minimum(jittered, self._theta_hi, out=jittered)
            self.theta[:, :-1] = jittered
        if self.cdf.intent_floor > 0.0:
            # Only drivers still held back (waiting, yielding): where the routes have parted,
            # the other intent is no hypothesis worth keeping.
            redraw = np.flatnonzero((self.rng.random(self.n) < self.cdf.intent_floor)
                                    & ((self.mode == _WAITING) | (self.mode == _YIELDING)))
            if redraw.size:
                self.intent[redraw] = self._draw_intent(redraw.size)
