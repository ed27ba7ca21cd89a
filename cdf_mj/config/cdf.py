"""The CDF filter's and decision rule's configuration: its own model of the other driver
(:class:`DriverPrior`), the risk rule (:class:`RiskConfig`), the layered rule's layers
(:class:`LayeredConfig`) and the filter (:class:`CDFConfig`). Re-exported by
:mod:`cdf_mj.config`."""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cdf_mj.config.scenario import MAX_PARTICLES, Observation, ProcessNoise, Pursuit
from cdf_mj.traits import MAX_ACCEL, MAX_DURATION, MAX_JERK, MAX_LENGTH, bounded, validate, with_traits
from cdf_mj.traits import check as _check
from cdf_mj.traits import within as _within

__all__ = ["AdaptiveConfig", "CDFConfig", "DriverPrior", "LayeredConfig", "RiskConfig"]

#: The CDF's decision rules (``CDFConfig.decision``).
DECISIONS = ("layered", "risk", "threshold")

@dataclass(frozen=True)
@with_traits("prior")
class DriverPrior:
    """The CDF filter's own model of the other driver: priors, not the world's values.

    The traits of :data:`cdf_mj.traits.TRAITS` that the filter models, by the same names
    as :class:`ObstacleDriver`: each particle draws its own parameters at reset (uniform on
    ``(low, high)``: ``beta``, ``accel``, ``turn_speed``, ``yield_brake``,
    ``critical_gap``, ``clear_distance``; the departure hazard log-uniform), so the filter
    covers plausible drivers and survives a world whose driver differs from its defaults.
    A pair with ``low == high`` fixes a value. ``p_left`` and ``passed_margin`` are single
    values; ``observation`` and ``pursuit`` are the driver's perception noise and route
    following as the filter models them. Defaults equal the world's defaults where the
    filter takes one value. ValueError on a range that is not a finite ``(low, high)`` with
    ``low <= high`` inside the field's domain.
    """

    # Departure hazard [1/s]: a driver waiting at the line whose belief says clear leaves
    # with this rate (memoryless; per tick 1 - exp(-h dt)), so a standing car stays
    # explained by "still waiting" and the going and right-turn hypotheses live on. Mean
    # dwell 1/h: 0.25 s (pulls out at once) to 2.5 s (waits); log-uniform.
    departure_hazard: tuple[float, float] = bounded((0.4, 4.0), 0.0, 1000.0, "1/s", open_low=True)
    observation: Observation = field(default_factory=Observation)  # noise of the ego it observes
    pursuit: Pursuit = field(default_factory=Pursuit)  # its route following

    if TYPE_CHECKING:  # the trait fields are the schema's (cdf_mj.traits.with_traits)
        def __init__(self, **values: Any) -> None: ...
        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self) -> None:
        _groups_of_mappings(self, {"observation": Observation, "pursuit": Pursuit})
        validate(self, "DriverPrior.")

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


def _groups_of_mappings(obj: Any, kinds: Mapping[str, type]) -> None:
    """Fields of the frozen ``obj`` read back from JSON as mappings, made objects of their
    classes; ValueError naming a field that is neither."""
    for name, cls in kinds.items():
        value = getattr(obj, name)
        if isinstance(value, Mapping):
            try:
                value = cls(**value)
            except TypeError as exc:
                raise ValueError(f"{name}: {exc}") from None
            object.__setattr__(obj, name, value)
        _check(isinstance(value, cls), name, value, f"a {cls.__name__} object (or a mapping of its fields)")


@dataclass(frozen=True)
class RiskConfig:
    """The risk decision rule (:class:`cdf_mj.planners.decision.RiskRule`), shared by every
    predictor that runs with it (``cdf``, ``imm-risk``, ``cv-risk``).

    Each tick the predictor's hypotheses of the obstacle's future are rolled forward
    against three plans of the ego: going on at its nominal speed, going on for one more
    decision interval plus ``latency`` and then braking at its maximum rate, and braking
    now. The ego brakes when the probability of a collision that deferring would make
    unavoidable (it collides whether the ego goes on or brakes after the deferral)
    reaches ``brake``, provided braking now is no riskier; a braking ego releases (and
    returns to its nominal speed) once that risk of going on is below ``release`` or,
    inside the conflict zone, below the risk of staying there (braking on). ValueError
    naming the field for a threshold outside (0, 1], ``release > brake``, a negative
    latency or a horizon outside (0, 30] s. ``brake`` was chosen on seeds 0-199 only, by a
    rule fixed beforehand (scripts/tune_risk.py, docs/DECISION.md); ``release`` is half of it.
    """

    brake: float = 0.5  # brake when P(collision if braking is deferred) >= this, in (0, 1]
    release: float = 0.25  # release when that risk falls below this, in (0, brake]
    latency: float = 0.1  # [s] margin on top of one decision interval before the brake acts
    horizon: float = 5.0  # [s] look-ahead of the rollouts
    margin: float = 0.3  # [m] added to each half size of both collision boxes

    def __post_init__(self) -> None:
        _check(_within(self.brake, 0.0, 1.0, open_low=True), "brake", self.brake, "in (0, 1]")
        _check(_within(self.release, 0.0, 1.0, open_low=True), "release", self.release, "in (0, 1]")
        _check(self.release <= self.brake, "release", self.release,
               f"at most the brake threshold {self.brake} (hysteresis: release below, brake at or above)")
        _check(_within(self.latency, 0.0, 10.0), "latency", self.latency, "in [0, 10] [s]")
        _check(_within(self.horizon, 0.0, 30.0, open_low=True), "horizon", self.horizon, "in (0, 30] [s]")
        _check(_within(self.margin, 0.0, 5.0), "margin", self.margin, "in [0, 5] [m]")

    def replace(self, **changes: Any) -> RiskConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


#: What the layered rule's anticipation layer may read (:attr:`LayeredConfig.anticipation`).
ANTICIPATIONS = ("option", "go")


@dataclass(frozen=True)
class LayeredConfig:
    """The layers of the graded rule (:class:`cdf_mj.planners.decision.LayeredRule`) on top
    of the emergency layer's :class:`RiskConfig` (its thresholds, latency margin, horizon
    and box margin). Every acceleration is in m/s^2 and scales with the testbed
    (:func:`cdf_mj.config.scaled`); docs/DECISION.md explains each layer.

    - *anticipate*: slow down at ``comfort_brake`` once the anticipation's risk reaches
      ``anticipate``; stop slowing once it is below ``anticipate_release``. With
      ``anticipation = "option"`` (the option rule) the risk is the probability of a
      collision going on that going on ``option_time`` [s] more (plus a tick and what the
      ego is told of its latency and noise) would leave beyond the comfortable brake: the
      ego keeps the option of slowing comfortably and uses it only when the belief says a
      cut-off is likely as that option runs out, never on a prior far from the junction.
      With ``"go"`` (version 0.3's) it is the probability of a collision if the ego goes
      on. Chosen on seeds 0-199 per predictor by an objective declared beforehand
      (scripts/tune_option.py; version 0.3's by scripts/tune_layers.py).
    - *emergency*: brake at the car's maximum once the probability of a collision that
      deferring the full brake by one tick plus ``RiskConfig.latency`` plus
      ``emergency_margin`` (plus the latency and noise the ego is told,
      :class:`~cdf_mj.planners.base.PlannerContext`) would leave unavoidable reaches
      ``RiskConfig.brake`` (release below ``RiskConfig.release``).
    - *follow*: behind a car ahead in the ego's lane heading at most 90 degrees off the ego's
      way (one still turning in, or standing across the lane, counts), the intelligent
      driver model with ``time_gap`` and ``min_gap``, braking at most ``comfort_brake`` by
      itself; the full brake whenever the gap is below the RSS safe distance (response time
      one tick plus the latencies, the car ahead braking at its car's maximum, the ego at
      its own).
    - ``dwell``: a hard brake, and a slow-down, is held at least this long.
    - *anticipate* also stops slowing (after the dwell) once slowing is riskier than going
      on: an ego that slows into the conflict it meant to let pass goes on instead.
    - ``comfort_jerk``: every command outside the full brake changes by at most this much
      per second (the ego's comfort); the full brake comes at once.
    - ``standoff``: when the ego and the other car have both stood still this long (the
      other not in the ego's lane), the other is taken to wait for the ego: hypotheses of it
      pulling away later are left out until it moves (no deadlock). "Standing" is below
      ``stand_speed``.
    - ``hard_brake``: commands at or beyond this deceleration are a brake (``Decision.brake``,
      records' ``brake_time``, the false alarms); 0.3 g, the naturalistic-driving threshold.

    ValueError naming the field for a value out of its range, ``anticipate_release >
    anticipate``, or ``comfort_brake >= hard_brake`` (slowing would count as braking).
    """

    # The CDF's, chosen on seeds 0-199 by scripts/tune_layers.py (docs/DECISION.md).
    anticipate: float = bounded(0.1, 0.0, 1.0, "1", open_low=True)
    anticipate_release: float = bounded(0.05, 0.0, 1.0, "1", open_low=True)
    comfort_brake: float = bounded(2.5, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    comfort_jerk: float = bounded(5.0, 0.0, MAX_JERK, "m/s^3", open_low=True)
    emergency_margin: float = bounded(0.3, 0.0, 10.0, "s")
    time_gap: float = bounded(1.5, 0.0, MAX_DURATION, "s", open_low=True)
    min_gap: float = bounded(2.0, 0.0, MAX_LENGTH, "m")
    dwell: float = bounded(0.5, 0.0, MAX_DURATION, "s")
    standoff: float = bounded(2.0, 0.0, MAX_DURATION, "s", open_low=True)
    stand_speed: float = bounded(0.5, 0.0, 10.0, "m/s", open_low=True)
    hard_brake: float = bounded(3.0, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    # What the anticipation layer reads (docs/DECISION.md). "option": keep the option: slow
    # only once going on for `option_time` more would leave a collision that the comfortable
    # brake could no longer avoid, with probability `anticipate`. "go": version 0.3's rule,
    # slow once a collision going on has probability `anticipate`.
    anticipation: str = "go"
    option_time: float = bounded(1.0, 0.0, MAX_DURATION, "s")
    # With "option": the probability of slowing short of the RSS distance behind the car
    # merging ahead at which the slowing escalates to the full brake (None: `anticipate`,
    # as before this field; docs/FRONTIER.md measures the rule with it apart).
    escalate: float | None = None

    def __post_init__(self) -> None:
        validate(self, "layered.")
        _check(isinstance(self.anticipation, str) and self.anticipation in ANTICIPATIONS, "layered.anticipation",
               self.anticipation, " or ".join(map(repr, ANTICIPATIONS)))
        _check(self.escalate is None or _within(self.escalate, 0.0, 1.0, open_low=True), "layered.escalate",
               self.escalate, "None or in (0, 1] (a probability)")
        _check(self.anticipate_release <= self.anticipate, "layered.anticipate_release", self.anticipate_release,
               f"at most layered.anticipate = {self.anticipate} (hysteresis)")
        _check(self.comfort_brake < self.hard_brake, "layered.comfort_brake", self.comfort_brake,
               f"below layered.hard_brake = {self.hard_brake} m/s^2 (slowing is not braking hard)")

    def replace(self, **changes: Any) -> LayeredConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class AdaptiveConfig:
    """An adaptive particle count: KLD-sampling's bound (Fox 2003, "Adapting the sample size
    in particle filters through KLD-sampling") at each resampling.

    The filter resamples ``n_min`` particles (stratified) and counts the bins of the
    obstacle's state they occupy (its position on a ``bin_pos`` grid, its speed on a
    ``bin_speed`` grid, its mode, intent and whether it has seen the ego); while Fox's
    bound asks for more particles for that many bins (so that, with probability
    ``1 - delta``, the Kullback-Leibler divergence between the sample's distribution over
    the bins and the posterior's is at most ``epsilon``), it resamples that many instead
    and counts again (:func:`cdf_mj.inference.kernels.kld_resample`). At least ``n_min``
    (the driver parameters and beliefs, which no bin resolves, keep that many), at most
    ``CDFConfig.n_particles``: few where the measurement pins the other car's pose, more
    where its hypotheses spread out (an occluded sensor's unseen approach, a lost track).
    ValueError naming the field for a value out of its range.
    """

    epsilon: float = bounded(0.05, 0.0, 1.0, "1", open_low=True)
    delta: float = bounded(0.01, 0.0, 0.5, "1", open_low=True)
    n_min: int = 500
    bin_pos: float = bounded(0.5, 1e-3, MAX_LENGTH, "m")  # [m] (a finer grid overflows the bins' keys)
    bin_speed: float = bounded(0.5, 1e-3, 100.0, "m/s")

    def __post_init__(self) -> None:
        validate(self, "adaptive.")
        _check(isinstance(self.n_min, numbers.Integral) and not isinstance(self.n_min, bool)
               and 1 <= self.n_min <= MAX_PARTICLES, "adaptive.n_min", self.n_min,
               f"an integer in [1, {MAX_PARTICLES:.0e}]")

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CDFConfig:
    """Parameters of the CDF particle filter and planner (chosen on seeds 0-199 only).

    ``likelihood_std`` gives a diagonal Sigma; ``likelihood_cov`` (4x4) overrides it.
    Units follow the pose [x m, y m, theta rad, v m/s]. ValueError naming the field for any
    value that is not finite or beyond its bound (``n_particles`` <= :data:`MAX_PARTICLES`).
    """

    n_particles: int = 1000  # N
    # Std of the Gaussian likelihood N(S_t, Sigma) of the measured obstacle pose. It also
    # absorbs the mismatch between the filter's Euler bicycle and MuJoCo's dynamics.
    likelihood_std: tuple[float, float, float, float] = (0.3, 0.3, 0.05, 0.3)
    likelihood_cov: tuple[tuple[float, ...], ...] | None = None
    # Brake when P(cutoff) >= tau. Tuned on seeds 0-199: 0.85 decides at 0.9 s (2.5 % false
    # alarms, all cut-offs avoided); 0.9 decides a tick later (1 %, 95 % avoided).
    tau: float = 0.85
    # P(cutoff) rule. "predictive": a left-turner that is pulling out but not yet past its
    # commit point still cuts off only if it does not see the ego on the r ticks it has
    # left before the commit point, probability (1 - beta)^r (the DBN's own forecast of
    # its observation process, in closed form). "paper": every left-turner pulling out
    # counts fully: those whose belief says clear (the paper's rule: intent left and
    # belief clear) and those already committed, which go whatever they believe.
    cutoff_rule: str = "predictive"
    # Resample when ESS < fraction * N; 1.0 resamples every step, as in the paper.
    resample_ess_fraction: float = 1.0
    # All likelihoods vanish when every particle is further than this Mahalanobis
    # distance from the measurement; the filter then re-initialises around it.
    reinit_mahalanobis: float = 12.0
    # Filter process noise = this factor x process_noise (a little wider than the world's).
    process_noise_scale: float = 1.5
    # The filter's own process noise nu [m/s^2, rad] before the factor: the world's defaults.
    process_noise: ProcessNoise = field(default_factory=ProcessNoise)
    # The filter's own driver model (priors of its parameters), not the world's.
    prior: DriverPrior = field(default_factory=lambda: DriverPrior())
    # Rejuvenation of the discrete state, so that no hypothesis dies for good:
    # per tick, a driver that is not committed jumps with this probability: held back
    # (waiting, yielding) -> going, disregarding what it saw (it forgets its belief, so it
    # no longer counts in P(seen)); going -> yielding (one tick).
    mode_jump: float = 0.005  # [1/tick]
    # After each resampling this fraction of the particles still held back (waiting,
    # yielding) redraw their intent from the prior, so that while the car stands
    # P(right) and P(left) stay above a floor of about this fraction x prior.
    intent_floor: float = 0.02
    # When every likelihood vanishes, redraw the discrete state (intent, mode, seen) and
    # the driver parameters from the prior around the measurement (True), or keep the
    # particles' discrete hypotheses and move their poses only (False, the old filter).
    reinit_redraw: bool = True
    # After each resampling the particles' continuous driver parameters move by a Gaussian
    # of std = this fraction of each prior range (kept inside it), so that they do not
    # collapse onto one ancestor's values (seen: every particle's turn speed 9.1 m/s
    # against the world's 8, 3 m ahead after 7 s, then a re-initialisation).
    param_jitter: float = 0.02
    # The ego's braking [m/s^2] and reaction latency [s] in the filter's prediction: a
    # going left-turner's looks count only until the ego's last chance to stop short of
    # its path. None: the layout's ego car (actuator `accel`'s lower bound). Latency 0:
    # here a decision brakes within the same 0.1 s tick.
    ego_brake: float | None = None
    ego_latency: float = 0.0
    # When to brake. "layered" (default): LayeredConfig's graded rule (anticipate, emergency
    # with RiskConfig, follow) on the particles rolled forward. "risk": version 0.2's rule,
    # the full brake at the last safe moment, released when the risk falls. "threshold":
    # the paper's rule, brake once P(cutoff) >= tau and hold it to the end.
    decision: str = "layered"
    risk: RiskConfig = field(default_factory=lambda: RiskConfig())
    layered: LayeredConfig = field(default_factory=lambda: LayeredConfig())
    # How many particles: None, always n_particles; an AdaptiveConfig, as many as
    # KLD-sampling asks for at each resampling, from its n_min up to n_particles.
    adaptive: AdaptiveConfig | None = None

    def __post_init__(self) -> None:
        # read back from JSON (settings.json)
        _groups_of_mappings(self, {"prior": DriverPrior, "risk": RiskConfig, "process_noise": ProcessNoise,
                                   "layered": LayeredConfig})
        _check(isinstance(self.decision, str) and self.decision in DECISIONS, "decision",
               self.decision, "'layered', 'risk' or 'threshold' (the paper's)")
        _check(_within(self.mode_jump, 0.0, 0.5), "mode_jump", self.mode_jump, "in [0, 0.5] [1/tick]")
        _check(_within(self.intent_floor, 0.0, 1.0), "intent_floor", self.intent_floor, "in [0, 1]")
        _check(isinstance(self.reinit_redraw, bool), "reinit_redraw", self.reinit_redraw,
               "True or False")
        _check(_within(self.param_jitter, 0.0, 1.0), "param_jitter", self.param_jitter,
               "in [0, 1] (a fraction of each prior range)")
        _check(self.ego_brake is None or _within(self.ego_brake, 0.0, MAX_ACCEL, open_low=True),
               "ego_brake", self.ego_brake, f"None (the ego car's) or in (0, {MAX_ACCEL:g}] [m/s^2]")
        _check(_within(self.ego_latency, 0.0, 10.0), "ego_latency", self.ego_latency, "in [0, 10] [s]")
        _check(isinstance(self.n_particles, numbers.Integral) and not isinstance(self.n_particles, bool)
               and 1 <= self.n_particles <= MAX_PARTICLES, "n_particles", self.n_particles,
               f"an integer in [1, {MAX_PARTICLES:.0e}] (memory: ~0.3 GB per filter at the bound)")
        if self.adaptive is not None:
            _groups_of_mappings(self, {"adaptive": AdaptiveConfig})
            _check(self.adaptive.n_min <= self.n_particles, "adaptive.n_min", self.adaptive.n_min,
                   f"at most n_particles = {self.n_particles} (the most particles)")
        _check(_within(self.tau, 0.0, 1.0, open_low=True), "tau", self.tau, "in (0, 1]")
        _check(isinstance(self.cutoff_rule, str) and self.cutoff_rule in ("predictive", "paper"),
               "cutoff_rule", self.cutoff_rule, "'predictive' or 'paper'")
        _check(_within(self.resample_ess_fraction, 0.0, 1.0), "resample_ess_fraction",
               self.resample_ess_fraction, "in [0, 1]")
        _check(_within(self.reinit_mahalanobis, 0.0, 1e3, open_low=True), "reinit_mahalanobis",
               self.reinit_mahalanobis, "in (0, 1000] (a Mahalanobis distance)")
        _check(_within(self.process_noise_scale, 0.0, 100.0), "process_noise_scale",
               self.process_noise_scale, "in [0, 100] (a factor on the scenario's noise)")
        std = self.likelihood_std
        _check(not isinstance(std, (str, bytes, Mapping)) and hasattr(std, "__len__") and len(std) == 4
               and all(_within(s, 0.0, MAX_LENGTH, open_low=True) for s in std), "likelihood_std",
               self.likelihood_std, f"4 finite values in (0, {MAX_LENGTH:g}] [m, m, rad, m/s]")
        if self.likelihood_cov is not None:
            try:
                cov_ok = np.asarray(self.likelihood_cov, dtype=float).shape == (4, 4)
            except (TypeError, ValueError, OverflowError):
                cov_ok = False
            _check(cov_ok, "likelihood_cov", self.likelihood_cov, "a 4x4 matrix of numbers (Sigma)")
        cov = self.covariance
        try:
            ok = bool(np.all(np.isfinite(cov))) and np.allclose(cov, cov.T)
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            ok = False
        _check(ok, "likelihood_cov", self.likelihood_cov,
               "a finite, symmetric, positive definite 4x4 matrix (Sigma)")

    @property
    def covariance(self) -> np.ndarray:
        """Sigma as a 4x4 array."""
        if self.likelihood_cov is not None:
            cov = np.asarray(self.likelihood_cov, dtype=float)
            if cov.shape != (4, 4):
                raise ValueError(f"likelihood_cov must be 4x4, got shape {cov.shape}")
            return cov
        return np.diag(np.square(np.asarray(self.likelihood_std, dtype=float)))

    def replace(self, **changes: Any) -> CDFConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> CDFConfig:
        """The config of a dict (:meth:`to_dict`, as read from settings.json); fields it
        leaves out take their defaults."""
        return cls(**data)

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


