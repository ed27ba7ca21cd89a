"""Joint belief-intent inference: a particle filter over the CDF's dynamic Bayesian network.

Each particle is one hypothesis of the hidden DBN state ``X_t = [S_t, B_t, I]`` plus the
obstacle driver's mode and its own driver parameters: the obstacle's pose, whether it has
seen the ego and what it believes, its intent, its state-machine mode, and its beta,
critical gap, clear distance, acceleration, turn speed, yield braking and departure
hazard, drawn at reset from the filter's own prior (``CDFConfig.prior``, a
:class:`cdf_mj.config.DriverPrior`), not copied from the world. The filter reads nothing
of the world's :class:`~cdf_mj.config.ScenarioConfig`: its tick ``dt`` is the planner's,
and the driver's observation noise, route following and ``passed_margin`` are the
prior's, its process noise ``CDFConfig.process_noise`` (defaults: the world's defaults).
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
    A tick without a measurement (a NaN row) is skipped; where the ego's sensor is
    ``occluded`` (it sees the other car only in its own line of sight) it is information
    instead: a particle whose obstacle the ego's eye would have seen past the buildings
    is weighted by ``miss`` (the sensor's probability of missing a car in sight), a
    hidden one keeps its weight (negative information; docs/OCCLUSION.md).

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

    pf = ParticleFilter.from_layout(scene.layout(), CDFConfig(), rng, dt=0.1)
    pf.reset(S0)
    for S in measurements:
        pf.predict(S_prev); post = pf.update(S)
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import numpy as np

from cdf_mj.config import CDFConfig, DriverPrior
from cdf_mj.inference import kernels
from cdf_mj.model.conflict import Futures
from cdf_mj.model.driver import DriverModel, DriverParams, Intent, Mode
from cdf_mj.model.geometry import OrientedBox
from cdf_mj.model.kernels import DRIVER_FIELDS
from cdf_mj.model.layout import Layout
from cdf_mj.model.occlusion import Occluders, sight_targets
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.traits import PER_CAR, THETA

__all__ = ["APPROACH", "APPROACH_STEP", "MISS_PROBABILITY", "THETA", "ParticleFilter", "Posterior", "draw_parameters"]

#: The occluded ego sensor's probability of missing the other car while it is in the ego's
#: line of sight, per tick: what a tick without a measurement weighs a particle in sight by.
#: The world's own sensor misses none (only its dropouts, ``sensing.dropout``); 0.05 leaves
#: room for the 2D sight model's error against MuJoCo's rays (grazing lines, heights), so
#: that a hypothesis in sight survives a few missed ticks rather than being gone after one.
MISS_PROBABILITY = 0.05
#: [m] How far up the side road an occluded ego's filter looks for an obstacle unseen at the
#: start (:meth:`ParticleFilter.unseen_start`): 3 s at 10 m/s, the prior's fastest turn speed.
APPROACH = 30.0
#: [m] The spacing of the places it looks at on that approach.
APPROACH_STEP = 0.5


# Plain ints for the per-tick code (IntEnum attribute access costs a Python call each time).
_LEFT, _RIGHT = int(Intent.LEFT), int(Intent.RIGHT)
_WAITING, _GOING, _YIELDING, _COMMITTED = (int(m) for m in Mode)


def draw_parameters(prior: DriverPrior, n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` drivers' parameters drawn from ``prior``: an ``(n, len(THETA))`` array with the columns
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


#: The particle arrays and the dtype the kernels are compiled for.
_PARTICLE_DTYPES = (("pose", np.float64), ("mode", np.int64), ("belief", np.float64), ("has_belief", np.bool_),
                    ("intent", np.int64), ("theta", np.float64), ("logw", np.float64))


def _published(a: np.ndarray) -> np.ndarray:
    """``a``, made read-only: the arrays whose identity keys the filter's caches (poses,
    log-weights) are replaced, never edited in place."""
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class Posterior:
    """The filter's answer at one tick. Probabilities in [0, 1]; ESS in [1, N]."""

    p_left: float
    p_right: float
    p_seen: float  # P(the obstacle has observed the ego)
    p_cutoff: float  # P(left-turner pulling out on a clear belief)
    ess: float  # effective sample size before resampling

    def to_dict(self) -> dict[str, float]:
        """JSON-serialisable view (``dataclasses.asdict`` without its deep copy: every
        field is a float)."""
        return {"p_left": self.p_left, "p_right": self.p_right, "p_seen": self.p_seen, "p_cutoff": self.p_cutoff,
                "ess": self.ess}


class ParticleFilter:
    """Particle filter over ``[obstacle pose, mode, belief, seen, intent]``, its stages
    compiled (:mod:`cdf_mj.inference.kernels`).

    Args:
        model: the junction's routes and points (the same as the simulation's), the tick
            ``dt`` [s] and the filter's route following and ``passed_margin`` (the model
            built from ``cdf.prior``: :meth:`from_layout`).
        obstacle: the obstacle's dimensions (eye, wheelbase, actuator ranges).
        ego: the ego's dimensions (footprint for line of sight, braking).
        occluders: building boxes for line of sight.
        cdf: filter parameters (N, Sigma, thresholds, the driver prior with its observation
            noise, the process noise, rejuvenation, the ego's braking and latency).
        rng: the Generator of all the filter's randomness (nothing is drawn before reset).
        ego_lane: the ego's lane area: where the obstacle's route first puts it into the
            lane (without it: where its nose reaches the conflict point).
        occluded: the ego's sensor sees the obstacle only in its own line of sight (from the
            ego's eye, ``ego.eye``, past ``occluders``): a tick without a measurement weighs
            the particles by it (:meth:`weigh`), and the filter may start without one
            (:meth:`reset`). False (default): a missing measurement says nothing.
        miss: [0, 1] with ``occluded``, the sensor's probability of missing an obstacle in
            its line of sight per tick (default :data:`MISS_PROBABILITY`).

    The particle arrays (``pose``, ``mode``, ``belief``, ``has_belief``, ``intent``,
    ``theta``, ``logw``) are public. Each tick gives the moving ones (``pose``, ``mode``,
    ``belief``, ``has_belief``) new arrays: one read earlier keeps its values. ``pose`` and
    ``logw`` are read-only (the arc lengths, lines of sight and weights are cached per
    array): assign new arrays of N rows to change them; a particle array of another
    length is a ValueError at the next stage.
    """

    def __init__(self, model: DriverModel, obstacle: CarGeometry, ego: CarGeometry,
                 occluders: Occluders, cdf: CDFConfig, rng: np.random.Generator,
                 ego_lane: OrientedBox | None = None, *, occluded: bool = False,
                 miss: float = MISS_PROBABILITY) -> None:
        if not isinstance(occluded, bool):
            raise TypeError(f"ParticleFilter: occluded must be a bool, got {type(occluded).__name__}")
        if isinstance(miss, bool) or not isinstance(miss, (int, float)) or not 0.0 <= miss <= 1.0:
            raise ValueError(f"ParticleFilter: miss={miss!r} is out of range: must be a probability in [0, 1]")
        self.model, self.obstacle, self.ego, self.occluders = model, obstacle, ego, occluders
        self.occluded = occluded
        # log(miss): the weight of a particle in sight on a tick without a measurement (-inf at 0).
        self._log_miss = math.log(miss) if miss > 0.0 else -math.inf
        self.cdf, self.rng, self.dt = cdf, rng, model.dt
        #: The most particles (``cdf.n_particles``); ``n`` is how many there are now: fewer
        #: after a resampling where the count is adaptive (``cdf.adaptive``).
        self.n_max = self.n = cdf.n_particles
        adaptive = cdf.adaptive
        # KLD-sampling's terms (bins, epsilon, its quantile z, n_min), or None: a fixed count.
        self._kld = None if adaptive is None else (
            float(adaptive.bin_pos), float(adaptive.bin_speed), float(adaptive.epsilon),
            statistics.NormalDist().inv_cdf(1.0 - adaptive.delta), int(adaptive.n_min))
        self._cov_inv = np.ascontiguousarray(np.linalg.inv(cdf.covariance))
        self.prior = prior = cdf.prior
        ego_brake = cdf.ego_brake if cdf.ego_brake is not None else ego.max_brake  # [m/s^2]
        # The ego must stop with its nose short of the obstacle's side [m from its rear axle].
        stop_margin = float(ego.hull_offset[0] + ego.hull_half[0] + obstacle.hull_half[1])
        # The ego has cleared the obstacle's path once its tail is past the conflict point by
        # the obstacle's half width [m, rear axle past the conflict point].
        clear_margin = float(ego.hull_half[0] - ego.hull_offset[0] + obstacle.hull_half[1])
        # Arc length on the left route [m] at which the obstacle first puts a corner into
        # the ego's lane (its nose at the conflict point without a lane box).
        route = model.routes[_LEFT]
        s_conflict = float(route.project(model.conflict)[0])
        s_enter = s_conflict - float(obstacle.hull_offset[0] + obstacle.hull_half[0])
        if ego_lane is not None:
            s_grid = np.arange(0.0, s_conflict, 0.05)
            xy, ahead = route.point_at(s_grid), route.point_at(s_grid + 0.05)
            heading = np.arctan2(ahead[:, 1] - xy[:, 1], ahead[:, 0] - xy[:, 0])
            poses = np.column_stack([xy, heading, np.zeros_like(heading)])
            inside = np.flatnonzero(ego_lane.contains(obstacle.footprint(poses)).any(axis=-1))
            if inside.size:
                s_enter = float(s_grid[inside[0]])
        # Kernel jitter of the continuous parameters after each resampling: std = this
        # fraction of each prior range, values kept inside the range.
        ranges = np.array([getattr(prior, name) for name in THETA[:-1]], dtype=float)
        self._theta_lo, self._theta_hi = ranges[:, 0].copy(), ranges[:, 1].copy()
        self._jitter_std = cdf.param_jitter * (self._theta_hi - self._theta_lo)
        # [s] the slowest plausible driver needs from a standstill at the line into the lane.
        t_slowest = kernels.arrival(s_enter, 0.0, 0.0, prior.accel[0], prior.turn_speed[0])
        nu = cdf.process_noise_scale * np.array([cdf.process_noise.accel, cdf.process_noise.steer])
        seen = prior.observation
        # Everything the kernels read, as one float vector, by name (kernels.FILTER_FIELDS).
        self._cfg = kernels.pack_filter({
            **dict(zip(DRIVER_FIELDS, model.cfg.tolist(), strict=True)), "mode_jump": cdf.mode_jump,
            "accel_lo": obstacle.accel_range[0], "accel_hi": obstacle.accel_range[1],
            "steer_lo": obstacle.steer_range[0], "steer_hi": obstacle.steer_range[1], "nu_accel": nu[0],
            "nu_steer": nu[1], "obs_pos": seen.pos, "obs_heading": seen.heading, "obs_speed": seen.speed,
            "eye_x": obstacle.eye_offset[0], "eye_y": obstacle.eye_offset[1], "s_enter": s_enter,
            "stop_margin": stop_margin, "clear_margin": clear_margin, "ego_brake": ego_brake,
            "ego_latency": cdf.ego_latency, "t_slowest": t_slowest, "paper_rule": float(cdf.cutoff_rule == "paper"),
            "reinit_maha2": cdf.reinit_mahalanobis ** 2})
        self._boxes = kernels.pack_boxes(occluders, float(obstacle.eye_offset[2]))
        # Read-only, as the driver model's own cfg and route table: the kernels they share
        # (the driver's) are then compiled for one array type, not two.
        for a in (self._cfg, self._boxes, self._cov_inv, self._theta_lo, self._theta_hi,
                  self._jitter_std):
            a.flags.writeable = False
        self._routes = model.table
        self.skipped_updates = 0  # measurements that were NaN or infinite
        self.unseen_updates = 0  # of those, ticks weighed by the ego's not seeing the obstacle (occluded)
        self.reinits = 0  # times every likelihood vanished
        self._ego: np.ndarray | None = None
        self._ego_values: list[float] = []  # the same as a list, to compare a new pose with
        self._ego_targets = np.zeros((5, 2))
        # The particles (N rows after reset): obstacle pose (N, 4), driver mode (N,), belief
        # (N, 4), whether the driver has seen the ego (N,), intent (N,).
        self.pose = np.zeros((0, 4))
        self.mode = np.zeros(0, dtype=np.int64)
        self.belief = np.zeros((0, 4))
        self.has_belief = np.zeros(0, dtype=bool)
        self.intent = np.zeros(0, dtype=np.int64)
        self.theta = np.zeros((0, len(THETA)))  # per-particle driver parameters, columns THETA
        # Log-weights (N,). Assign a new array to change them, never edit one in place:
        # `weights` is computed once per array.
        self.logw = np.zeros(0)
        self._w = np.zeros(0)  # weights of the log-weight array _w_of
        self._w_of: np.ndarray | None = None
        self._ess = 0.0
        # Per particle: arc length on its own route [m], its segment (-1: not known), the
        # route they are of; line of sight to the ego (-1 not known) of the pose array and
        # ego targets in _sight_of.
        self._s = np.zeros(0)
        self._seg = np.zeros(0, dtype=np.int64)
        self._s_route = np.zeros(0, dtype=np.int64)
        self._s_of: np.ndarray | None = None
        self._sight = np.zeros(0, dtype=np.int8)
        self._sight_of: tuple[np.ndarray, np.ndarray] | None = None
        self._checked: tuple[np.ndarray, ...] | None = None  # the particle arrays of the last check

    @classmethod
    def from_layout(cls, layout: Layout, cdf: CDFConfig, rng: np.random.Generator, dt: float, *,
                    occluded: bool = False, miss: float = MISS_PROBABILITY) -> ParticleFilter:
        """A filter for a junction (``Scene.layout()``: its routes, buildings and cars),
        ticked every ``dt`` [s] (the planner's tick), with its own driver model
        (``cdf.prior``); ``occluded`` and ``miss``: the ego's sensor (see the class)."""
        model = DriverModel.from_layout(layout, cdf.prior, cdf.prior.pursuit, dt)
        return cls(model, layout.obstacle, layout.ego, layout.occluders, cdf, rng, layout.ego_lane,
                   occluded=occluded, miss=miss)

    # ------------------------------------------------------------------ state
    def reset(self, system_pose: np.ndarray) -> Posterior:
        """Prior at the first measurement ``S_0`` (2, 4): the obstacle where it is
        measured, waiting, never having seen the ego; intent and driver parameters from
        the prior (``CDFConfig.prior``).

        With an ``occluded`` sensor the obstacle's row may be NaN (not in the ego's sight
        at the start): the obstacle is then somewhere the ego's eye does not see
        (:meth:`unseen_start`), and what the ego goes on not seeing weighs the particles
        from the next tick on. ValueError for a non-finite ego pose, or a non-finite
        obstacle row without an occluded sensor."""
        system_pose = np.asarray(system_pose, dtype=float)
        unseen = (system_pose.shape == (2, 4) and self.occluded and bool(np.all(np.isfinite(system_pose[0])))
                  and bool(np.all(np.isnan(system_pose[1]))))
        if unseen:
            system_pose = np.stack([system_pose[0], self.waiting_pose()])
        if system_pose.shape != (2, 4) or not np.all(np.isfinite(system_pose)):
            raise ValueError(f"the first system pose must be finite, of shape (2, 4), got {system_pose.tolist()}")
        n = self.n = self.n_max
        self.pose = _published(np.repeat(system_pose[1][None], n, axis=0))
        self.intent = self._draw_intent(n)
        self.mode = np.full(n, _WAITING, dtype=np.int64)
        self.belief = np.zeros((n, 4))
        self.has_belief = np.zeros(n, dtype=bool)
        self.theta = draw_parameters(self.prior, n, self.dt, self.rng)
        self._uniform()
        self._ego, self._ego_values = None, []
        self.set_ego(system_pose)
        if unseen:
            self.unseen_start()
        return self.posterior()

    def unseen_start(self) -> None:
        """Place the particles where the obstacle may be unseen at the start: on the side
        road's approach up to :data:`APPROACH` [m] upstream of where the drivers wait
        (:meth:`waiting_pose`, every :data:`APPROACH_STEP`), at the places the ego's eye does
        not see. Where the waiting place itself is hidden, half of them wait there, at rest
        (the filter's drivers start so); the others come down the approach (mode going, at
        a speed drawn from 0 to the prior's fastest turn speed), uniformly over its hidden
        places. Where nothing is hidden they all wait at the waiting place (a missed
        measurement of a car in sight). Intents, beliefs and parameters are kept."""
        n, rng = self.n, self.rng
        wait = self.waiting_pose()
        back = np.arange(0.0, APPROACH + 1e-9, APPROACH_STEP)  # [m] upstream of the waiting place
        places = np.repeat(wait[None], len(back), axis=0)
        places[:, 0] -= back * math.cos(wait[2])
        places[:, 1] -= back * math.sin(wait[2])
        hidden = ~self.in_sight(places)
        if not hidden.any():
            return  # all waiting at the waiting place, as reset put them
        approach = np.flatnonzero(hidden[1:]) + 1
        waits = rng.random(n) < 0.5 if hidden[0] else np.zeros(n, dtype=bool)
        if approach.size == 0:
            waits[:] = True
        going = ~waits
        pick = np.zeros(n, dtype=np.int64)  # the waiting place
        if going.any():
            pick[going] = approach[rng.integers(0, approach.size, int(going.sum()))]
        pose = places[pick]
        pose[:, 3] = np.where(waits, 0.0, rng.uniform(0.0, self.prior.turn_speed[1], n))
        self.pose = _published(pose)
        self.mode = np.where(waits, _WAITING, _GOING).astype(np.int64)
        self._mark_checked()

    def waiting_pose(self) -> np.ndarray:
        """Where the filter's drivers wait: the start of their routes (the stop line),
        heading along the route, at rest ``[x m, y m, theta rad, 0]`` (world frame)."""
        points = self.model.routes[_LEFT].points
        (x0, y0), (x1, y1) = points[0], points[1]
        return np.array([x0, y0, math.atan2(y1 - y0, x1 - x0), 0.0])

    def in_sight(self, poses: np.ndarray | None = None) -> np.ndarray:
        """Whether the ego's eye (``ego.eye`` of its last pose) sees the obstacle at each of
        ``poses`` ``(M, 4)`` (default: the particles') ``(M,)``: any of its hull corners and
        centre (:func:`~cdf_mj.model.occlusion.sight_targets`) past the buildings (the 2D model
        of :class:`~cdf_mj.model.occlusion.Occluders`, which :mod:`cdf_mj.sim.visibility`
        casts with MuJoCo rays)."""
        eye = self.ego.eye(self._ego_pose())
        targets = sight_targets(self.obstacle, self.pose if poses is None else np.asarray(poses, dtype=float))
        seen: np.ndarray = self.occluders.visible(np.broadcast_to(eye, (len(targets), 3)), targets)
        return seen

    def _draw_intent(self, n: int) -> np.ndarray:
        """``n`` intents from the prior P(left)."""
        return np.where(self.rng.random(n) < self.prior.p_left, _LEFT, _RIGHT).astype(np.int64)

    @property
    def params(self) -> DriverParams:
        """The particles' driver parameters as ``(N,)`` arrays (views of ``theta``)."""
        t = self.theta
        return DriverParams(**{name: t[:, j] for j, name in enumerate(PER_CAR)})  # THETA starts with PER_CAR

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights (N,). Computed once per ``logw`` array: the filter assigns
        a new array whenever the log-weights change, never edits one it has weighed."""
        if self._w_of is not self.logw:
            self._check_particles()
            w, self._ess = kernels.normalise(np.ascontiguousarray(self.logw, dtype=float))
            self._set_weights(w, self.logw)
        return self._w

    def _uniform(self) -> None:
        """Equal weights: log-weights 0, weights 1/N, ESS N."""
        self.logw = _published(np.zeros(self.n))
        self._ess = float(self.n)
        self._set_weights(np.full(self.n, 1.0 / self.n), self.logw)

    def _set_weights(self, w: np.ndarray, logw: np.ndarray) -> None:
        w.flags.writeable = False  # shared by every reader until the log-weights change
        self._w, self._w_of = w, logw

    def _caches(self, check: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The per-particle caches the kernels read and fill, after checking the particle
        arrays (:meth:`_check_particles`; ``check=False`` for a kernel that reads only the
        poses): arc length, segment and route of the current pose array (reset to "not
        known" for a pose array the filter did not move itself), and the line of sight of
        the current pose array and ego pose."""
        if check:
            self._check_particles()
        n = len(self.pose)
        if self._s_of is not self.pose:
            self._s, self._seg, self._s_route = np.zeros(n), np.full(n, -1, dtype=np.int64), np.zeros(n, np.int64)
            self._s_of = self.pose
        cached = self._sight_of
        if cached is None or cached[0] is not self.pose or cached[1] is not self._ego_targets:
            self._sight = np.full(n, -1, dtype=np.int8)
            self._sight_of = (self.pose, self._ego_targets)
        return self._s, self._seg, self._s_route, self._sight

    def posterior(self) -> Posterior:
        """P(left), P(right), P(seen), P(cutoff) and ESS of the current weights."""
        w = self.weights
        s, seg, route, sight = self._caches()
        p_left, p_seen, p_cutoff = kernels.posterior(
            w, self._cfg, self._routes.table, self._routes.nseg, self._boxes, self._ego_targets, self._ego_pose(),
            self.pose, self.mode, self.has_belief, self.intent, self.theta, s, seg, route, sight)
        return Posterior(p_left=p_left, p_right=1.0 - p_left, p_seen=p_seen, p_cutoff=p_cutoff, ess=self._ess)

    def cutoff_probability(self) -> np.ndarray:
        """Per particle, the probability that it cuts the ego off (N,), see ``cutoff_rule``.

        A committed left-turner does; a going one does unless it sees the ego on one of
        the ticks left before its commit point (``(1 - beta)^r``, looks counted until the
        ego's last chance to stop, :meth:`ego_ticks_to_stop`), or fully with the paper's
        rule. With the predictive rule a left-turner counts only if it enters the ego's
        lane (accelerating at its own rate up to its turn speed) before the ego, holding
        its speed, has cleared the conflict point: one that pulls out behind the ego is no
        cut-off (the scenario's own label), and braking for it would stop the ego in its
        path."""
        s, seg, route, sight = self._caches()
        p: np.ndarray = kernels.cutoff_rows(self._cfg, self._routes.table, self._routes.nseg, self._boxes,
                                            self._ego_targets, self._ego_pose(), self.pose, self.mode, self.intent,
                                            self.theta, s, seg, route, sight)
        return p

    def ego_time_to_clear(self) -> float:
        """[s] until the ego, holding its speed, has cleared the obstacle's path at the
        conflict point (its tail past it by the obstacle's half width); ``inf`` if stopped."""
        return float(kernels.ego_terms(self._cfg, self._ego_pose())[0])

    def ego_ticks_to_stop(self) -> float:
        """Ticks left before the ego's last chance to brake (``ego_brake`` after
        ``ego_latency``) and stop with its nose short of the obstacle's path at the
        conflict point; ``inf`` for an ego that is (nearly) stopped, 0 once too late."""
        return float(kernels.ego_terms(self._cfg, self._ego_pose())[1])

    def _ego_pose(self) -> np.ndarray:
        """The ego's pose (4,) the filter last took; RuntimeError before :meth:`reset`."""
        if self._ego is None:
            raise RuntimeError("the particle filter has no measurement yet: call reset(S0) first")
        return self._ego

    def _check_particles(self) -> None:
        """RuntimeError before :meth:`reset`; ValueError if a particle array assigned from
        outside does not have the filter's N rows (the kernels index them unchecked). An
        array assigned from outside in another dtype or layout is converted (and ``pose``,
        ``logw`` made read-only): each kernel is compiled for one type of each argument.
        Arrays already checked (the same objects as at the last check) are not checked again:
        the filter replaces its arrays, never their type or rows (``pose`` and ``logw`` made
        writeable again are checked again)."""
        last = self._checked
        if (last is not None and last[0] is self.pose and last[1] is self.mode and last[2] is self.belief
                and last[3] is self.has_belief and last[4] is self.intent and last[5] is self.theta
                and last[6] is self.logw and not (self.pose.flags.writeable or self.logw.flags.writeable)):
            return  # (five times a tick: no generator expression)
        if len(self.pose) == 0:
            raise RuntimeError("the particle filter has no particles yet: call reset(S0) first")
        n = self.n
        for name, dtype in _PARTICLE_DTYPES:
            value = getattr(self, name)
            if len(value) != n:
                raise ValueError(f"ParticleFilter.{name} has {len(value)} rows, the filter has N = {n} particles")
            if type(value) is not np.ndarray or value.dtype != dtype or not value.flags.c_contiguous or (
                    name in ("pose", "logw") and value.flags.writeable):
                value = np.array(value, dtype=dtype, order="C")  # a copy: the caller's array stays theirs
                setattr(self, name, _published(value) if name in ("pose", "logw") else value)
        self._mark_checked()

    def _mark_checked(self) -> None:
        """Take the particle arrays as they are now as checked: after :meth:`_check_particles`,
        and after a stage that replaced checked arrays by its kernels' own (the types and
        rows the kernels take; ``pose`` and ``logw`` read-only)."""
        self._checked = (self.pose, self.mode, self.belief, self.has_belief, self.intent, self.theta, self.logw)

    def ego_exposed(self) -> bool:
        """Whether the (known) ego could still be cut off: it has not yet cleared the
        obstacle's path at the conflict point (its tail past it by the obstacle's half
        width, :meth:`ego_time_to_clear`). An explicit test of the ego's exposure, not the
        obstacle driver's gap acceptance (a deviation from the paper, docs/DECISION.md)."""
        return self.ego_time_to_clear() > 0.0

    def arc(self) -> np.ndarray:
        """[m] every particle's arc length on its own route ``(N,)`` (left or right, by its
        intent), kept from the projection after its last move."""
        s, seg, route, _ = self._caches()
        kernels.arcs(self._routes.table, self._routes.nseg, self.pose, self.intent, s, seg, route)
        arc: np.ndarray = s.copy()
        return arc

    def sees_ego(self) -> np.ndarray:
        """Whether the ego is in each particle driver's line of sight ``(N,)``, computed once
        per pose array and ego pose."""
        sight = self._caches(check=False)[3]  # it reads the poses alone, of any number
        seen: np.ndarray = kernels.sight_rows(self.pose, self._cfg, self._boxes, self._ego_targets, sight)
        return seen

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
        s, seg, route, sight = self._caches()
        table, m = kernels.left_futures(self.weights, self._cfg, self._routes.table, self._routes.nseg, self._boxes,
                                        self._ego_targets, self._ego_pose(), self.pose, self.mode, self.belief,
                                        self.has_belief, self.intent, self.theta, s, seg, route, sight,
                                        int(react_ticks))
        return Futures(*table[:, :m])

    # ------------------------------------------------------------------ one tick
    def predict(self, system_pose: np.ndarray | None = None) -> None:
        """Propagate every particle through one tick of the DBN from ``S_t``, in one
        compiled pass (:func:`cdf_mj.inference.kernels.predict`): each particle looks
        (``k``: its beta draw, then its line of sight), updates its belief (``g``), drives
        (``h``: its mode, the departure hazard and the mode jumps, pure pursuit, process
        noise clipped to the actuator ranges) and moves (the bicycle ``f``).

        The ego's pose comes from ``system_pose[0]`` when it is finite, else the last one.
        """
        self.set_ego(system_pose)
        ego = self._ego_pose()
        s, seg, route, sight = self._caches()
        # New arrays for everything that moves (the kernel writes them): an array the filter
        # has handed out is never changed afterwards, and a copy of the filter is independent.
        mode, belief, has_belief = self.mode.copy(), self.belief.copy(), self.has_belief.copy()
        s, seg, route = s.copy(), seg.copy(), route.copy()
        tab = self._routes
        pose = kernels.predict(self.rng, self._cfg, tab.table, tab.nseg, tab.ends, self._boxes, self._ego_targets,
                               ego, self.pose, mode, belief, has_belief, self.intent, self.theta, s, seg, route,
                               sight)
        self.mode, self.belief, self.has_belief = mode, belief, has_belief
        self._s, self._seg, self._s_route = s, seg, route
        self.pose = self._s_of = _published(pose)  # the arcs now are those of the new poses
        self._mark_checked()

    def set_ego(self, system_pose: np.ndarray | None) -> None:
        """Take the ego's pose from ``system_pose[0]`` where it is finite."""
        if system_pose is not None:
            values = np.asarray(system_pose, dtype=float)[0].tolist()
            if values != self._ego_values and all(math.isfinite(v) for v in values):
                self._ego_values = values
                self._ego = ego = np.array(values)
                self._ego_targets = sight_targets(self.ego, ego)

    def update(self, system_pose: np.ndarray) -> Posterior:
        """Weight by the measured obstacle pose, resample, and return the posterior.

        A non-finite measurement is skipped (counted in ``skipped_updates``); with an
        ``occluded`` sensor a NaN obstacle row weighs the particles by what the ego did not
        see (:meth:`weigh`) and they are resampled as after a measurement. If every
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
        posterior of these weights (before any resampling).

        Without a measurement (a non-finite obstacle row) the weights stay, unless the
        sensor is ``occluded``: then each particle whose obstacle is in the ego's line of
        sight (:meth:`in_sight`) is weighted by ``miss`` and each hidden one by 1, the
        likelihood of not seeing it (counted in ``unseen_updates``)."""
        system_pose = np.asarray(system_pose, dtype=float)
        self.set_ego(system_pose)  # the ego's pose now, for P(cutoff)
        meas = system_pose[1]
        self._check_particles()
        if not _finite(meas):
            self.skipped_updates += 1
            if self.occluded and np.all(np.isnan(meas)):
                self._weigh_unseen()
            return self.posterior()
        logw, w, ess, ok = kernels.weigh(self.pose, meas, self._cov_inv, np.ascontiguousarray(self.logw, dtype=float),
                                         float(self._cfg[kernels.F_REINIT]))
        if not ok:
            self.reinitialise(meas)
            return self.posterior()
        self.logw = _published(logw)
        self._mark_checked()
        self._ess = ess
        self._set_weights(w, logw)
        return self.posterior()

    def _weigh_unseen(self) -> None:
        """Negative information: the log-weights of the particles in the ego's sight plus
        log(miss), normalised (a new array); the ESS of the result."""
        self.unseen_updates += 1
        seen = self.in_sight()
        if not seen.any() or seen.all():
            return  # the same likelihood for every particle: nothing to tell them apart
        logw = np.where(seen, self.logw + self._log_miss, self.logw)
        top = logw.max()
        if not math.isfinite(top):  # every particle weighed out (miss = 0 and none hidden alive): no news
            return
        logw = logw - top  # finite: a hidden particle keeps its (finite) log-weight
        w, self._ess = kernels.normalise(logw)
        self.logw = _published(logw)
        self._mark_checked()
        self._set_weights(w, self.logw)

    def reinitialise(self, measured: np.ndarray) -> None:
        """Every likelihood vanished: all particles at the measured obstacle pose (4,),
        weights uniform. With ``reinit_redraw`` (default) the discrete state is redrawn
        so that no hypothesis stays dead: intent from the prior, mode going if the car is
        measured moving (> 0.5 m/s) else waiting, seen the ego with probability 1/2 (its
        belief then the ego's pose with observation noise), and the driver parameters
        from the prior (as many particles as the most, ``n_max``). Without it, the particles
        keep their discrete hypotheses (and their count)."""
        n = self.n = self.n_max if self.cdf.reinit_redraw else self.n
        rng = self.rng
        self.reinits += 1
        self.pose = _published(np.repeat(np.asarray(measured, dtype=float)[None], n, axis=0))
        self._uniform()
        if not self.cdf.reinit_redraw:
            return
        self.intent = self._draw_intent(n)
        self.mode = np.full(n, _GOING if measured[3] > 0.5 else _WAITING, dtype=np.int64)
        self.has_belief = rng.random(n) < 0.5
        obs_std = self._cfg[[kernels.F_OBS_POS, kernels.F_OBS_POS, kernels.F_OBS_HEAD, kernels.F_OBS_SPEED]]
        self.belief = np.where(self.has_belief[:, None],
                               self._ego_pose() + rng.standard_normal((n, 4)) * obs_std, 0.0)
        self.theta = draw_parameters(self.prior, n, self.dt, rng)

    def resample(self) -> None:
        """Stratified resampling of every particle array (their arc lengths and lines of
        sight go with them); weights back to uniform. Then the continuous driver
        parameters get a small Gaussian jitter (``param_jitter``; not the departure
        hazard), and a fraction ``intent_floor`` of the particles still held back (waiting
        or yielding) redraw their intent from the prior."""
        s, seg, route, sight = self._caches()
        jitter = self._jitter_std if self.cdf.param_jitter > 0.0 else self._jitter_std[:0]
        floor, p_left = float(self.cdf.intent_floor), float(self.prior.p_left)
        if self._kld is None:
            keep, self.theta, self.intent = kernels.resample(self.rng, self.weights, self.theta, self.mode,
                                                             self.intent, jitter, self._theta_lo, self._theta_hi,
                                                             floor, p_left)
        else:
            keep = kernels.kld_resample(self.rng, self.weights, self.pose, self.mode, self.intent, self.has_belief,
                                        *self._kld, self.n_max)
            self.theta, self.intent = kernels.rejuvenate(self.rng, keep, self.theta, self.mode, self.intent, jitter,
                                                         self._theta_lo, self._theta_hi, floor, p_left)
            self.n = len(keep)
        rows = len(keep)
        new = [np.empty((rows, *a.shape[1:]), dtype=a.dtype)
               for a in (self.pose, self.belief, self.mode, self.has_belief, s, seg, route, sight)]
        kernels.gather(keep, self.pose, self.belief, self.mode, self.has_belief, s, seg, route, sight, *new)
        self.pose, self.belief, self.mode, self.has_belief, self._s, self._seg, self._s_route, self._sight = new
        _published(self.pose)
        self._s_of = self.pose
        self._sight_of = (self.pose, self._ego_targets)
        self._uniform()
        self._mark_checked()
