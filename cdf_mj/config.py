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

__all__ = ["MAX_BRAKE", "CDFConfig", "ScenarioConfig", "SceneNames"]

#: Maximum braking of a passenger car on a moderate-friction road, 16 ft/s^2 [m/s^2].
MAX_BRAKE = 16 * 0.3048


def _check(cond: bool, name: str, value: object, allowed: str) -> None:
    if not cond:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


@dataclass(frozen=True)
class SceneNames:
    """Names of the MJCF elements that the code reads. The only place Python spells them.

    Car names are the car file's names with the placement prefix (``ego_``, ``obstacle_``).
    Give your own to read a scene with other names, e.g.
    ``SceneNames(ego_prefix="av/", route_ego="av_path")``; docs/SCENES.md says what each
    element is used for. ValueError on an empty name or equal car prefixes.
    """

    ego_prefix: str = "ego_"
    obstacle_prefix: str = "obstacle_"
    chassis: str = "chassis"  # body, origin on the rear axle
    front_axle: str = "front_axle"  # body; its x offset is the wheelbase
    joint_x: str = "x"  # slide joint of the chassis along its frame's x [m]
    joint_y: str = "y"  # slide joint of the chassis along its frame's y [m]
    joint_yaw: str = "yaw"  # hinge joint of the chassis about z [rad]
    hull: str = "hull"  # collision box of a car
    eye: str = "eye"  # site: the driver's eye point
    accel: str = "accel"  # actuator [m/s^2]
    steer: str = "steer"  # actuator [rad]
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

    def __post_init__(self) -> None:
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
