"""Configuration of the scenario: every free parameter the paper leaves open, in one place.

Geometry (roads, routes, stop line, commit point, buildings, wheelbase, actuator limits)
lives in the MJCF scene; this module holds the behavioural and statistical parameters.
Each field says its unit and why it has its value; ``docs/PARAMETERS.md`` tells the
calibration story. Objects are frozen and validated when built::

    from cdf_mj.config import ScenarioConfig
    cfg = ScenarioConfig(obstacle={"beta": 0.1})        # ValueError if out of range
    cfg = ScenarioConfig().with_values({"obstacle.beta": 0.1, "ego.speed": 12.0})   # by dotted key
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import numbers
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np

from cdf_mj.traits import MAX_ACCEL, MAX_DURATION, MAX_LENGTH, MAX_SPEED, bounded, validate, with_traits
from cdf_mj.traits import check as _check
from cdf_mj.traits import within as _within

__all__ = [
    "FLAT_KEYS",
    "GROUPS",
    "MAX_ACCEL",
    "MAX_BRAKE",
    "MAX_DURATION",
    "MAX_EPISODES",
    "MAX_LENGTH",
    "MAX_PARTICLES",
    "MAX_SEED",
    "MAX_SPEED",
    "MAX_START_SPREAD",
    "MAX_WORKERS",
    "SCENARIO_KEYS",
    "CDFConfig",
    "DriverPrior",
    "Ego",
    "Observation",
    "ObstacleDriver",
    "ProcessNoise",
    "Pursuit",
    "RiskConfig",
    "ScenarioConfig",
    "SceneNames",
    "Timing",
    "normalise_settings",
    "scaled",
    "scenario_key",
    "unit_of",
]

#: Maximum braking of a passenger car on a moderate-friction road, 16 ft/s^2 [m/s^2].
MAX_BRAKE = 16 * 0.3048

# Upper bounds, checked when a configuration is built (and by the CLI before any work), so
# that an absurd number is one clear error up front, never an allocation without bound, an
# overflow or records of nonsense later. Each is far beyond any meaningful value.
#: Particles of the CDF filter: ~40 arrays of N float64 per filter, ~0.3 GB at 10^6 [1].
MAX_PARTICLES = 10**6
#: Episodes of one run: 10^7 records of ~1 kB fill ~10 GB and take days on one core [1].
MAX_EPISODES = 10**7
#: Largest seed: every seed is exact in any JSON reader (a double holds integers to 2^53) [1].
MAX_SEED = 2**53 - 1
#: Worker processes of one run: beyond any single machine's cores [1].
MAX_WORKERS = 1024
#: Shift of the ego start along its route, either way: a junction scene's scale [m].
MAX_START_SPREAD = 200.0

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


G = TypeVar("G", bound="_Group")


class _Group:
    """A group of :class:`ScenarioConfig`: a frozen dataclass whose fields are checked
    against their ranges (:func:`cdf_mj.traits.bounded`), named ``<group>.<field>`` in
    errors."""

    _prefix: ClassVar[str] = ""

    def __post_init__(self) -> None:
        validate(self, self._prefix)

    def replace(self: G, **changes: Any) -> G:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view."""
        return dataclasses.asdict(self)  # type: ignore[call-overload]


@dataclass(frozen=True)
class Timing(_Group):
    """The tick and the episode's length. ValueError unless ``0 < dt <= 1`` and
    ``dt <= duration <= 600`` [s]."""

    _prefix: ClassVar[str] = "timing."
    dt: float = bounded(0.1, 0.0, 1.0, "s", open_low=True, note="(the paper's tick is 0.1 s)")  # planner, driver
    # and observation tick [s] (paper: 0.1 s)
    duration: float = 8.0  # [s] episode length; the ego passes the junction in ~4 s

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(_within(self.duration, self.dt, MAX_DURATION), "timing.duration", self.duration,
               f"in [dt = {self.dt}, {MAX_DURATION:g}] [s]")

    @property
    def n_ticks(self) -> int:
        """Number of planner ticks in an episode."""
        return round(self.duration / self.dt)


@dataclass(frozen=True)
class Ego(_Group):
    """The ego's nominal controller: what the ego knows of itself (its planner gets it)."""

    _prefix: ClassVar[str] = "ego."
    speed: float = bounded(13.4, 0.0, MAX_SPEED, "m/s", open_low=True)  # nominal speed, about 30 mph (paper)
    # Uniform spread of the ego start along its route, added to site `ego_start` [m].
    # Calibrated so that about half the cut-offs enter the ego lane beyond the
    # reactive planner's stopping distance (see docs/PARAMETERS.md).
    start_spread: tuple[float, float] = bounded((-8.0, 8.0), -MAX_START_SPREAD, MAX_START_SPREAD, "m",
                                                note="(a shift of the start site along the ego's route)")
    speed_gain: float = bounded(1.0, 0.0, 1000.0, "1/s", open_low=True)  # proportional speed hold


@dataclass(frozen=True)
@with_traits("world")
class ObstacleDriver(_Group):
    """The world's obstacle driver: one field per trait of :data:`cdf_mj.traits.TRAITS`
    (``accel``, ``turn_speed``, ``critical_gap``, ``stop_dwell``, ...), each with the
    trait's default and checked against its range; the schema gives each one's unit and
    meaning, docs/PARAMETERS.md its calibration. Read only by the world: the filter has
    its own model of the driver (:class:`DriverPrior`)."""

    _prefix: ClassVar[str] = "obstacle."
    if TYPE_CHECKING:  # the fields are the schema's (cdf_mj.traits.with_traits)
        def __init__(self, **traits: Any) -> None: ...
        def __getattr__(self, name: str) -> Any: ...


@dataclass(frozen=True)
class Observation(_Group):
    """The obstacle driver's observation noise: std of the observed ego pose ``e_t``."""

    _prefix: ClassVar[str] = "observation."
    pos: float = bounded(0.5, 0.0, MAX_LENGTH, "m")  # of the observed ego position
    heading: float = bounded(0.02, 0.0, math.pi, "rad")  # of the observed ego heading
    speed: float = bounded(0.5, 0.0, MAX_SPEED, "m/s")  # of the observed ego speed


@dataclass(frozen=True)
class Pursuit(_Group):
    """Route following (pure pursuit) of a car: look-ahead ``L = lookahead + gain * v``."""

    _prefix: ClassVar[str] = "pursuit."
    lookahead: float = bounded(3.0, 0.0, MAX_LENGTH, "m", open_low=True)  # at standstill
    lookahead_gain: float = bounded(0.3, 0.0, MAX_DURATION, "s")  # growth with speed


@dataclass(frozen=True)
class ProcessNoise(_Group):
    """Process noise ``nu`` (paper eq. for f): std of what is added to each control."""

    _prefix: ClassVar[str] = "noise."
    accel: float = bounded(0.3, 0.0, MAX_ACCEL, "m/s^2")  # nu_1, on the commanded acceleration
    steer: float = bounded(0.01, 0.0, math.pi, "rad")  # nu_2, on the commanded steering


#: The groups of :class:`ScenarioConfig` (all but ``names``) and their classes.
GROUPS: Mapping[str, type[Any]] = MappingProxyType({
    "timing": Timing, "ego": Ego, "obstacle": ObstacleDriver, "observation": Observation, "pursuit": Pursuit,
    "noise": ProcessNoise})
#: Every settable key of a :class:`ScenarioConfig`, dotted: ``"timing.dt"``, ``"obstacle.beta"``, ...
SCENARIO_KEYS: tuple[str, ...] = tuple(f"{g}.{f.name}" for g, cls in GROUPS.items() for f in dataclasses.fields(cls))
#: The flat keys of version 0.1 (``ScenarioConfig(beta=...)``, old ``--set`` keys, preset
#: files and settings.json) -> their dotted keys. Read by everything that reads old input.
FLAT_KEYS: Mapping[str, str] = MappingProxyType({
    "dt": "timing.dt", "duration": "timing.duration",
    "ego_speed": "ego.speed", "ego_start_spread": "ego.start_spread", "ego_speed_gain": "ego.speed_gain",
    "p_left": "obstacle.p_left", "beta": "obstacle.beta", "obstacle_accel": "obstacle.accel",
    "obstacle_turn_speed": "obstacle.turn_speed", "obstacle_yield_brake": "obstacle.yield_brake",
    "critical_gap": "obstacle.critical_gap", "clear_distance": "obstacle.clear_distance",
    "passed_margin": "obstacle.passed_margin", "stop_dwell": "obstacle.stop_dwell",
    "departure_look": "obstacle.departure_look", "hesitation": "obstacle.hesitation",
    "hesitation_creep": "obstacle.hesitation_creep", "hesitation_pause": "obstacle.hesitation_pause",
    "obs_noise_pos": "observation.pos", "obs_noise_heading": "observation.heading",
    "obs_noise_speed": "observation.speed", "lookahead": "pursuit.lookahead",
    "lookahead_gain": "pursuit.lookahead_gain", "noise_accel": "noise.accel", "noise_steer": "noise.steer"})


def scenario_key(key: str) -> str:
    """The dotted key of a dotted or flat (:data:`FLAT_KEYS`) key; ValueError naming it and
    the valid keys if it is neither."""
    dotted = FLAT_KEYS.get(key, key)
    if dotted not in SCENARIO_KEYS:
        raise ValueError(f"unknown scenario key {key!r}; valid keys: {', '.join(SCENARIO_KEYS)}")
    return dotted


@dataclass(frozen=True, init=False)
class ScenarioConfig:
    """Behavioural and statistical parameters of the T-intersection scenario, by owner:

    ==============  ===========================================================================
    ``timing``      :class:`Timing`: ``dt`` (the paper's planner/filter tick), ``duration``
    ``ego``         :class:`Ego`: the ego's nominal ``speed``, ``start_spread``, ``speed_gain``
    ``obstacle``    :class:`ObstacleDriver`: the world's obstacle driver (the traits)
    ``observation`` :class:`Observation`: the obstacle driver's noise on the ego it observes
    ``pursuit``     :class:`Pursuit`: both cars' route following
    ``noise``       :class:`ProcessNoise`: process noise on both cars' controls
    ``names``       :class:`SceneNames`: the scene elements the code reads
    ==============  ===========================================================================

    Units: metres, seconds, radians. Build it from groups, from dotted keys
    (``ScenarioConfig().with_values({"obstacle.beta": 0.1})``) or from a dict
    (:meth:`from_dict`: nested as :meth:`to_dict` gives, or the flat settings of version
    0.1). The flat keywords of version 0.1 (``ScenarioConfig(beta=0.1)``,
    ``config.replace(beta=0.1)``, reading ``config.beta``) still work through
    :data:`FLAT_KEYS`, with a DeprecationWarning naming the dotted key. ValueError naming
    the field (dotted) and its range for any value that is not a finite number within its
    physical range (e.g. ``timing.duration`` <= 600 s), and for ``names`` that are not a
    :class:`SceneNames` (a mapping of its fields is converted).
    """

    timing: Timing = field(default_factory=Timing)
    ego: Ego = field(default_factory=Ego)
    obstacle: ObstacleDriver = field(default_factory=ObstacleDriver)
    observation: Observation = field(default_factory=Observation)
    pursuit: Pursuit = field(default_factory=Pursuit)
    noise: ProcessNoise = field(default_factory=ProcessNoise)
    # Names of the scene elements the code reads (defaults match models/xml/scene.xml).
    names: SceneNames = field(default_factory=SceneNames)

    def __init__(self, timing: Timing | Mapping[str, Any] | None = None, ego: Ego | Mapping[str, Any] | None = None,
                 obstacle: ObstacleDriver | Mapping[str, Any] | None = None,
                 observation: Observation | Mapping[str, Any] | None = None,
                 pursuit: Pursuit | Mapping[str, Any] | None = None,
                 noise: ProcessNoise | Mapping[str, Any] | None = None,
                 names: SceneNames | Mapping[str, Any] | None = None, **keys: Any) -> None:
        given = {"timing": timing, "ego": ego, "obstacle": obstacle, "observation": observation,
                 "pursuit": pursuit, "noise": noise, "names": names}
        values = {**{k: v for k, v in given.items() if v is not None}, **keys}
        for name, value in _apply(_DEFAULT_GROUPS, values, TypeError, warn=True).items():
            object.__setattr__(self, name, value)
        _check(isinstance(self.names, SceneNames), "names", self.names,
               "a SceneNames (e.g. SceneNames(route_ego='av_path'))")
        for name, cls in GROUPS.items():
            value = getattr(self, name)
            _check(isinstance(value, cls), name, value, f"a {cls.__name__} object (or a mapping of its fields)")

    if not TYPE_CHECKING:  # the flat reads of version 0.1: not for the package's own code
        def __getattr__(self, name: str) -> Any:
            dotted = FLAT_KEYS.get(name)
            if dotted is None:
                raise AttributeError(f"'ScenarioConfig' object has no attribute {name!r}")
            warnings.warn(f"ScenarioConfig.{name} is deprecated; read config.{dotted}", DeprecationWarning,
                          stacklevel=2)
            return self.get(dotted)

    @property
    def n_ticks(self) -> int:
        """Number of planner ticks in an episode."""
        return self.timing.n_ticks

    def get(self, key: str) -> Any:
        """The value of a dotted key (``"obstacle.beta"``); ValueError for an unknown key."""
        group, _, name = scenario_key(key).partition(".")
        return getattr(getattr(self, group), name)

    def with_values(self, values: Mapping[str, Any]) -> ScenarioConfig:
        """A copy with the given values (validated again): dotted keys (``"obstacle.beta"``),
        groups (a group object, or a mapping of some of its fields) or flat keys of version
        0.1 (with a DeprecationWarning). ValueError naming an unknown key."""
        return ScenarioConfig(**_apply(self._groups(), values, ValueError, warn=True, stacklevel=3))

    def replace(self, **changes: Any) -> ScenarioConfig:
        """A copy with some fields changed (validated again), as :meth:`with_values`."""
        return ScenarioConfig(**_apply(self._groups(), changes, TypeError, warn=True, stacklevel=3))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ScenarioConfig:
        """The config of a dict: nested (:meth:`to_dict`, groups may leave fields out) or
        flat (a settings.json of version 0.1; no warning: stored results stay readable)."""
        return cls(**_apply(_DEFAULT_GROUPS, data, ValueError, warn=False))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view, nested by group, for records and result directories."""
        return dataclasses.asdict(self)

    def _groups(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


_DEFAULT_GROUPS: Mapping[str, Any] = MappingProxyType({**{g: cls() for g, cls in GROUPS.items()},
                                                       "names": SceneNames()})


def _apply(base: Mapping[str, Any], values: Mapping[str, Any], error: type[Exception], *, warn: bool,
           stacklevel: int = 3) -> dict[str, Any]:
    """The groups of ``base`` (group name -> object) with ``values`` applied: group objects
    replace, mappings of a group's fields and dotted or flat keys change fields (a flat key
    with a DeprecationWarning where ``warn``). ``error`` for an unknown key."""
    out = dict(base)
    changes: dict[str, dict[str, Any]] = {}
    for key, value in values.items():
        if key in out:
            if isinstance(value, Mapping):
                changes.setdefault(key, {}).update(value)
            else:
                out[key] = value  # its type is checked by ScenarioConfig
            continue
        if key in FLAT_KEYS and warn:
            warnings.warn(f"ScenarioConfig: the flat key {key!r} is deprecated; use {FLAT_KEYS[key]!r}",
                          DeprecationWarning, stacklevel=stacklevel)
        try:
            group, _, name = scenario_key(key).partition(".")
        except ValueError as exc:
            raise error(f"ScenarioConfig: {exc}") from None
        changes.setdefault(group, {})[name] = value
    for group, fields in changes.items():
        current, cls = out[group], GROUPS.get(group, SceneNames)
        _check(isinstance(current, cls), group, current, f"a {cls.__name__} object (or a mapping of its fields)")
        try:
            out[group] = dataclasses.replace(current, **fields)
        except TypeError:
            known = ", ".join(f.name for f in dataclasses.fields(current))
            raise ValueError(f"{group}: unknown key among {sorted(fields)}; the keys are {known}") from None
    return out


def normalise_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """A settings dict (settings.json) as this version writes it: its ``scenario`` (flat or
    nested) and ``cdf`` rebuilt with today's fields (defaults for those it lacks), as JSON
    would read them back; a part that cannot be rebuilt is left as it is."""
    out = dict(settings)
    for key, cls in (("scenario", ScenarioConfig), ("cdf", CDFConfig)):
        if isinstance(out.get(key), Mapping):
            with contextlib.suppress(TypeError, ValueError):
                out[key] = json.loads(json.dumps(cls.from_dict(out[key]).to_dict()))
    return out


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
    # When to brake. "risk" (default): RiskConfig's rule on the particles rolled forward,
    # released when the risk falls. "threshold": the paper's rule, brake once P(cutoff) >= tau
    # and hold it to the end.
    decision: str = "risk"
    risk: RiskConfig = field(default_factory=lambda: RiskConfig())

    def __post_init__(self) -> None:
        # read back from JSON (settings.json)
        _groups_of_mappings(self, {"prior": DriverPrior, "risk": RiskConfig, "process_noise": ProcessNoise})
        _check(isinstance(self.decision, str) and self.decision in ("risk", "threshold"), "decision",
               self.decision, "'risk' or 'threshold' (the paper's)")
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


# ------------------------------------------------------------------ a testbed at another scale
C = TypeVar("C")
#: Exponent of the length scale by unit under :func:`scaled`'s law (kinematic similarity).
KINEMATIC_SCALING: Mapping[str, int] = MappingProxyType(
    {"m": 1, "m/s": 1, "m/s^2": 1, "s": 0, "1/s": 0, "1/tick": 0, "rad": 0, "1": 0})
_POSE_UNITS = ("m", "m", "rad", "m/s")  # [x, y, theta, v]
#: Units of the numbers of configurations whose fields declare none (:func:`cdf_mj.traits.bounded`
#: does): ``Class.field`` -> unit, per component for a pose (or its covariance's rows and columns).
UNITS: Mapping[str, Any] = MappingProxyType({
    "Timing.duration": "s", "RiskConfig.brake": "1", "RiskConfig.release": "1", "RiskConfig.latency": "s",
    "RiskConfig.horizon": "s", "RiskConfig.margin": "m", "CDFConfig.n_particles": "1",
    "CDFConfig.likelihood_std": _POSE_UNITS, "CDFConfig.likelihood_cov": (_POSE_UNITS, _POSE_UNITS),
    "CDFConfig.tau": "1", "CDFConfig.resample_ess_fraction": "1", "CDFConfig.reinit_mahalanobis": "1",
    "CDFConfig.process_noise_scale": "1", "CDFConfig.mode_jump": "1/tick", "CDFConfig.intent_floor": "1",
    "CDFConfig.param_jitter": "1", "CDFConfig.ego_brake": "m/s^2", "CDFConfig.ego_latency": "s"})


def unit_of(config: Any, name: str) -> Any:
    """The unit of field ``name`` of the configuration dataclass ``config``: its declared
    range's (:func:`cdf_mj.traits.bounded`, the traits) or :data:`UNITS`'; None if neither."""
    f = next(f for f in dataclasses.fields(config) if f.name == name)
    declared = f.metadata.get("range")
    return declared.unit if declared is not None else UNITS.get(f"{type(config).__name__}.{name}")


def _factor(unit: Any, s: float) -> Any:
    """The factor (an array for a pose, a matrix for its covariance) of ``unit`` at scale ``s``."""
    if isinstance(unit, tuple):
        if isinstance(unit[0], tuple):
            return np.outer(_factor(unit[0], s), _factor(unit[1], s))
        return np.array([_factor(u, s) for u in unit])
    return s ** KINEMATIC_SCALING[unit]


def scaled(config: C, length_scale: float) -> C:
    """``config`` (:class:`ScenarioConfig`, :class:`CDFConfig`, :class:`RiskConfig`, any of
    their groups) for a testbed at ``length_scale`` times full size (0.1: 1:10), by the
    law of kinematic similarity: every length [m], speed [m/s] and acceleration [m/s^2]
    (and the std of one) times ``length_scale``; times [s], rates, angles [rad],
    probabilities and counts unchanged. A pose ``[x, y, theta, v]`` scales by component.

    Why this law: the filter's model is kinematic (a bicycle: dx/dt = v cos(theta),
    dtheta/dt = v tan(delta) / wheelbase, dv/dt = a) with a driver who decides in time
    (the tick, the per-tick probability of a look, the critical gap, the departure
    hazard), and it has no mass, force or gravity. Under this law every trajectory of the
    full-size scenario is one of the testbed's, at the same times and steering angles, so
    what was tuned at full size (on seeds 0-199) and the risk rule's horizon and latency
    hold unchanged at the same 0.1 s tick. Froude similarity (lengths x s, speeds and
    times x sqrt(s), accelerations unchanged) keeps what gravity and tyre grip do alike,
    which the model has not; it would shorten the tick and every time of the tuning, and
    change what each per-tick probability means. The cars are not configurations: give
    their :class:`~cdf_mj.model.vehicle.CarGeometry` as measured (the risk rule plans the
    ego's braking with its ``accel_range``).

    The result is validated as any config. ValueError for a scale outside (0, 100] or a
    number of ``config`` whose unit is not declared (a field added without one).
    """
    _check(_within(length_scale, 0.0, 100.0, open_low=True), "length_scale", length_scale,
           "in (0, 100] (0.1: a testbed at 1:10)")
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(config):  # type: ignore[arg-type]
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            changes[f.name] = scaled(value, length_scale)
        elif value is None or isinstance(value, (str, bool)) or not isinstance(value, (numbers.Real, tuple, list)):
            continue  # names, rules, switches, a covariance not given
        elif (unit := unit_of(config, f.name)) is None:
            raise ValueError(f"scaled: {type(config).__name__}.{f.name} declares no unit; give it one "
                             "(cdf_mj.traits.bounded, or cdf_mj.config.UNITS)")
        elif unit != "1":
            k = _factor(unit, length_scale)
            if isinstance(value, numbers.Real):
                changes[f.name] = value * k
            elif np.ndim(k) == 2:  # a pose's covariance
                changes[f.name] = tuple(tuple(float(x) for x in row) for row in np.asarray(value, dtype=float) * k)
            else:  # a pose (a factor per component) or a (low, high) pair
                changes[f.name] = tuple(float(v) * float(kv) for v, kv in
                                        zip(value, np.broadcast_to(k, (len(value),)), strict=True))
    return dataclasses.replace(config, **changes)  # type: ignore[type-var]
