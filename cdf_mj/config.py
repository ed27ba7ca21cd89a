"""Configuration of the scenario: every free parameter the paper leaves open, in one place.

Geometry (roads, routes, stop line, commit point, buildings, wheelbase, actuator limits)
lives in the MJCF scene; this module holds the behavioural and statistical parameters.
Each field says its unit and why it has its value; ``docs/PARAMETERS.md`` tells the
calibration story. Objects are frozen and validated when built::

    from cdf_mj.config import ScenarioConfig
    cfg = ScenarioConfig(beta=0.1)          # ValueError if out of range
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MAX_BRAKE", "CDFConfig", "DriverPrior", "ScenarioConfig", "SceneNames"]

#: Maximum braking of a passenger car on a moderate-friction road, 16 ft/s^2 [m/s^2].
MAX_BRAKE = 16 * 0.3048


def _check(cond: bool, name: str, value: object, allowed: str) -> None:
    if not cond:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _pair_ok(pair: Any, low: float, positive: bool = False) -> bool:
    """Whether ``pair`` is a finite ``(lo, hi)`` of numbers with ``low <= lo <= hi``
    (``lo > low`` where ``positive``)."""
    try:
        first, second = pair
        lo, hi = float(first), float(second)
    except (TypeError, ValueError):
        return False
    return _finite(lo, hi) and (lo > low if positive else lo >= low) and lo <= hi


@dataclass(frozen=True)
class SceneNames:
    """Names of the MJCF elements that the code reads. The only place Python spells them.

    Car names are the car file's names with the placement prefix (``ego_``, ``obstacle_``).
    Give your own to read a scene with other names, e.g.
    ``SceneNames(ego_prefix="av/", route_ego="av_path")``; docs/SCENES.md says what each
    element is used for. ValueError on an empty name or equal car prefixes.

    What is read of a car depends on the use: a :class:`cdf_mj.sim.scene.Scene` (which
    drives the cars) reads every car field; :func:`cdf_mj.scenario.monitor.attach` (which
    only watches them) reads the ``chassis`` body's pose, plus ``front_axle``, ``hull``,
    ``eye``, ``accel`` and ``steer`` for the car's dimensions only when no
    :class:`cdf_mj.model.vehicle.CarGeometry` is given for it.
    """

    ego_prefix: str = "ego_"
    obstacle_prefix: str = "obstacle_"
    chassis: str = "chassis"  # body whose pose is the car's (origin on the rear axle in our car)
    front_axle: str = "front_axle"  # body; its x offset is the wheelbase (not read with a CarGeometry)
    joint_x: str = "x"  # slide joint of the chassis along its frame's x [m]
    joint_y: str = "y"  # slide joint of the chassis along its frame's y [m]
    joint_yaw: str = "yaw"  # hinge joint of the chassis about z [rad]
    hull: str = "hull"  # geom: collision box of a car (not read with a CarGeometry)
    eye: str = "eye"  # site: the driver's eye point (not read with a CarGeometry)
    accel: str = "accel"  # actuator [m/s^2]
    steer: str = "steer"  # actuator: steering command [rad]
    steer_joint: str = "steer"  # hinge joint: the steering angle [rad] (reset by Scene)
    ego_start: str = "ego_start"  # site: rear-axle start pose of the ego
    obstacle_start: str = "obstacle_start"  # site: rear-axle start pose of the obstacle
    stop_line: str = "stop_line"  # site (box)
    ego_lane: str = "ego_lane"  # site (box): the ego's lane area
    conflict: str = "conflict"  # site: where a left-turner enters the ego lane
    commit: str = "obstacle_commit"  # site: past it the obstacle no longer yields
    route_ego: str = "route_ego"  # body whose child sites are waypoints
    route_left: str = "route_obstacle_left"
    route_right: str = "route_obstacle_right"
    building_prefix: str = "building"  # geoms whose name starts with it occlude

    def __post_init__(self) -> None:
        bad = [f.name for f in dataclasses.fields(self)
               if not isinstance(getattr(self, f.name), str) or not getattr(self, f.name)]
        if bad:
            raise ValueError(f"SceneNames: {', '.join(bad)} must be non-empty strings")
        if self.ego_prefix == self.obstacle_prefix:
            raise ValueError(f"SceneNames: ego_prefix and obstacle_prefix are both "
                             f"{self.ego_prefix!r}; the two cars need different prefixes")

    @property
    def planar_joints(self) -> tuple[str, str, str]:
        """The chassis joints x, y, yaw (unprefixed)."""
        return (self.joint_x, self.joint_y, self.joint_yaw)


@dataclass(frozen=True)
class ScenarioConfig:
    """Behavioural and statistical parameters of the T-intersection scenario.

    Units: metres, seconds, radians. ``dt`` is the paper's planner/filter tick.
    """

    # --- timing -------------------------------------------------------------------
    dt: float = 0.1  # [s] planner, driver and observation tick (paper: 0.1 s)
    duration: float = 8.0  # [s] episode length; the ego passes the junction in ~4 s

    # --- observation model (paper section 2) --------------------------------------
    beta: float = 0.05  # [1/step] P(obstacle observes the ego | ego visible), paper: 0.05
    obs_noise_pos: float = 0.5  # [m] std of the observed ego position e_t
    obs_noise_heading: float = 0.02  # [rad] std of the observed ego heading
    obs_noise_speed: float = 0.5  # [m/s] std of the observed ego speed

    # --- intent -------------------------------------------------------------------
    p_left: float = 0.75  # prior P(intent = left), paper: 0.75

    # --- ego ----------------------------------------------------------------------
    ego_speed: float = 13.4  # [m/s] nominal speed, about 30 mph (paper)
    # Uniform spread of the ego start along its route, added to site `ego_start` [m].
    # Calibrated so that about half the cut-offs enter the ego lane beyond the
    # reactive planner's stopping distance (see docs/PARAMETERS.md).
    ego_start_spread: tuple[float, float] = (-8.0, 8.0)
    ego_speed_gain: float = 1.0  # [1/s] proportional speed hold of the nominal controller

    # --- obstacle driver ----------------------------------------------------------
    obstacle_accel: float = 2.5  # [m/s^2] pulling-out acceleration (moderate, urban)
    obstacle_turn_speed: float = 8.0  # [m/s] cruise speed through and after the turn
    obstacle_yield_brake: float = 4.0  # [m/s^2] braking when it decides to yield
    # Critical gap: the obstacle goes if the believed ego needs longer than this to
    # reach the conflict point. 5 s is a typical accepted gap for a left turn from a
    # minor road (HCM gives 6-7 s); any ego seen in this scenario is inside it.
    critical_gap: float = 5.0  # [s]
    passed_margin: float = 3.0  # [m] believed ego beyond the conflict point by this = gone
    # Clearance in space: a believed ego nearer than this to the conflict point (and not
    # past it by passed_margin) is never clear, whatever its speed. About two car lengths
    # measured at the ego's rear axle: its 3.65 m nose plus the width the left-turner
    # sweeps in the ego lane, with a margin. Without it a stopped ego a few metres before
    # the conflict point has a time to arrive of ahead / 0.1 m/s = 45-65 s and looks clear.
    clear_distance: float = 10.0  # [m]
    # Dwell at the stop line: uniform (low, high) [s], drawn once per episode. t = 0 is
    # the end of the obstacle's full stop in the paper's scenario (it pulls out at once;
    # the calibration of the commit point and of the ego's start assumes it), so the
    # default is (0, 0); a driver at a stop sign typically waits 0.5-2 s after stopping
    # (the stop-and-wait preset).
    stop_dwell: tuple[float, float] = (0.0, 0.0)
    # P(the driver looks once more, on the tick it would leave the line, and sees the ego
    # if it is in its line of sight), on top of the beta draw. 0 keeps the paper's
    # observation process (beta alone); a careful driver at a stop sign: about 0.5.
    departure_look: float = 0.0
    # A driver who hesitates: with probability `hesitation` per episode, once it has left
    # the line it stops again after `hesitation_creep` [m] (nosing out to see, within the
    # 1.45 m to the commit point of models/xml; a longer creep would be past it), stands a
    # pause drawn uniformly from `hesitation_pause` [s], then goes on as its belief says
    # (looking again with `departure_look`). The filter's model has no such stop: it is a
    # test of model mismatch (the hesitant preset). 0 by default: the paper's driver.
    hesitation: float = 0.0
    hesitation_creep: float = 0.7  # [m] travelled from the line before the stop
    hesitation_pause: tuple[float, float] = (0.5, 1.5)  # [s] uniform
    lookahead: float = 3.0  # [m] pure-pursuit look-ahead at standstill
    lookahead_gain: float = 0.3  # [s] look-ahead grows with speed: L = lookahead + gain * v

    # --- process noise nu (paper eq. for f) -----------------------------------------
    noise_accel: float = 0.3  # [m/s^2] std of nu_1, added to the commanded acceleration
    noise_steer: float = 0.01  # [rad] std of nu_2, added to the commanded steering

    # Names of the scene elements the code reads (defaults match models/xml/scene.xml).
    names: SceneNames = field(default_factory=lambda: SceneNames())

    def __post_init__(self) -> None:
        _check(_finite(self.dt) and self.dt > 0, "dt", self.dt, "> 0 [s]")
        _check(_finite(self.duration) and self.duration >= self.dt, "duration", self.duration,
               f">= dt = {self.dt} [s]")
        _check(_finite(self.beta) and 0.0 <= self.beta <= 1.0, "beta", self.beta, "in [0, 1]")
        _check(_finite(self.p_left) and 0.0 <= self.p_left <= 1.0, "p_left", self.p_left, "in [0, 1]")
        for name in ("obs_noise_pos", "obs_noise_heading", "obs_noise_speed", "noise_accel",
                     "noise_steer", "passed_margin", "lookahead_gain"):
            v = getattr(self, name)
            _check(_finite(v) and v >= 0, name, v, ">= 0")
        for name in ("ego_speed", "obstacle_accel", "obstacle_turn_speed", "obstacle_yield_brake",
                     "critical_gap", "lookahead", "ego_speed_gain"):
            v = getattr(self, name)
            _check(_finite(v) and v > 0, name, v, "> 0")
        lo, hi = self.ego_start_spread
        _check(_finite(lo, hi) and lo <= hi, "ego_start_spread", self.ego_start_spread,
               "a finite (low, high) pair with low <= high [m]")
        _check(_pair_ok(self.stop_dwell, 0.0), "stop_dwell", self.stop_dwell,
               "a finite (low, high) pair with 0 <= low <= high [s]")
        _check(_finite(self.departure_look) and 0.0 <= self.departure_look <= 1.0,
               "departure_look", self.departure_look, "in [0, 1]")
        _check(_finite(self.clear_distance) and self.clear_distance >= 0, "clear_distance",
               self.clear_distance, ">= 0 [m]")
        _check(_finite(self.hesitation) and 0.0 <= self.hesitation <= 1.0,
               "hesitation", self.hesitation, "in [0, 1]")
        _check(_finite(self.hesitation_creep) and self.hesitation_creep > 0, "hesitation_creep",
               self.hesitation_creep, "> 0 [m]")
        _check(_pair_ok(self.hesitation_pause, 0.0), "hesitation_pause", self.hesitation_pause,
               "a finite (low, high) pair with 0 <= low <= high [s]")

    @property
    def n_ticks(self) -> int:
        """Number of planner ticks in an episode."""
        return round(self.duration / self.dt)

    def replace(self, **changes: Any) -> ScenarioConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-serialisable view, for records and result directories."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class DriverPrior:
    """The CDF filter's own model of the other driver: priors, not the world's values.

    Each particle draws its own parameters at reset (uniform on ``(low, high)``; the
    departure hazard log-uniform), so the filter covers plausible drivers and survives a
    world whose driver differs from its defaults. A pair with ``low == high`` fixes a
    value. ValueError on a range that is not a finite ``(low, high)`` with
    ``low <= high`` inside the field's domain.
    """

    p_left: float = 0.75  # prior P(intent = left), the paper's 0.75
    beta: tuple[float, float] = (0.03, 0.07)  # [1/tick] P(observes a visible ego); paper 0.05
    critical_gap: tuple[float, float] = (4.0, 7.0)  # [s] accepted gap (HCM: 6-7 s for a left turn)
    accel: tuple[float, float] = (1.5, 3.0)  # [m/s^2] pulling-out acceleration (car limit 3.0)
    turn_speed: tuple[float, float] = (6.0, 10.0)  # [m/s] cruise speed through the turn
    yield_brake: tuple[float, float] = (3.0, 5.0)  # [m/s^2] braking when it yields
    clear_distance: tuple[float, float] = (7.0, 13.0)  # [m] a nearer ego is never clear
    # Departure hazard [1/s]: a driver waiting at the line whose belief says clear leaves
    # with this rate (memoryless; per tick 1 - exp(-h dt)), so a standing car stays
    # explained by "still waiting" and the going and right-turn hypotheses live on. Mean
    # dwell 1/h: 0.25 s (pulls out at once) to 2.5 s (waits); log-uniform.
    departure_hazard: tuple[float, float] = (0.4, 4.0)

    def __post_init__(self) -> None:
        _check(_finite(self.p_left) and 0.0 <= self.p_left <= 1.0, "DriverPrior.p_left",
               self.p_left, "in [0, 1]")
        _check(_pair_ok(self.beta, 0.0) and self.beta[1] <= 1.0, "DriverPrior.beta", self.beta,
               "a (low, high) pair with 0 <= low <= high <= 1")
        for name in ("critical_gap", "accel", "turn_speed", "yield_brake", "departure_hazard"):
            _check(_pair_ok(getattr(self, name), 0.0, positive=True), f"DriverPrior.{name}",
                   getattr(self, name), "a finite (low, high) pair with 0 < low <= high")
        _check(_pair_ok(self.clear_distance, 0.0), "DriverPrior.clear_distance",
               self.clear_distance, "a finite (low, high) pair with 0 <= low <= high [m]")

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CDFConfig:
    """Parameters of the CDF particle filter and planner (chosen on seeds 0-199 only).

    ``likelihood_std`` gives a diagonal Sigma; ``likelihood_cov`` (4x4) overrides it.
    Units follow the pose [x m, y m, theta rad, v m/s].
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
    # Filter process noise = this factor x the scenario's (a little wider than the truth).
    process_noise_scale: float = 1.5
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

    def __post_init__(self) -> None:
        if isinstance(self.prior, dict):  # read back from JSON (settings.json): lists -> pairs
            raw: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in self.prior.items()}
            object.__setattr__(self, "prior", DriverPrior(**raw))
        _check(isinstance(self.prior, DriverPrior), "prior", self.prior, "a DriverPrior")
        _check(_finite(self.mode_jump) and 0.0 <= self.mode_jump <= 0.5, "mode_jump",
               self.mode_jump, "in [0, 0.5] [1/tick]")
        _check(_finite(self.intent_floor) and 0.0 <= self.intent_floor <= 1.0, "intent_floor",
               self.intent_floor, "in [0, 1]")
        _check(isinstance(self.reinit_redraw, bool), "reinit_redraw", self.reinit_redraw,
               "True or False")
        _check(_finite(self.param_jitter) and 0.0 <= self.param_jitter <= 1.0, "param_jitter",
               self.param_jitter, "in [0, 1] (a fraction of each prior range)")
        _check(self.ego_brake is None or (isinstance(self.ego_brake, (int, float))
                                          and _finite(self.ego_brake) and self.ego_brake > 0),
               "ego_brake", self.ego_brake, "None (the ego car's) or > 0 [m/s^2]")
        _check(_finite(self.ego_latency) and self.ego_latency >= 0, "ego_latency",
               self.ego_latency, ">= 0 [s]")
        _check(isinstance(self.n_particles, int) and not isinstance(self.n_particles, bool)
               and self.n_particles >= 1, "n_particles",
               self.n_particles, "an integer >= 1")
        _check(_finite(self.tau) and 0.0 < self.tau <= 1.0, "tau", self.tau, "in (0, 1]")
        _check(self.cutoff_rule in ("predictive", "paper"), "cutoff_rule", self.cutoff_rule,
               "'predictive' or 'paper'")
        _check(_finite(self.resample_ess_fraction) and 0.0 <= self.resample_ess_fraction <= 1.0,
               "resample_ess_fraction", self.resample_ess_fraction, "in [0, 1]")
        _check(_finite(self.reinit_mahalanobis) and self.reinit_mahalanobis > 0,
               "reinit_mahalanobis", self.reinit_mahalanobis, "> 0")
        _check(_finite(self.process_noise_scale) and self.process_noise_scale >= 0,
               "process_noise_scale", self.process_noise_scale, ">= 0")
        std = tuple(self.likelihood_std)
        _check(len(std) == 4 and _finite(*std) and all(s > 0 for s in std), "likelihood_std",
               self.likelihood_std, "4 finite values > 0")
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

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)
