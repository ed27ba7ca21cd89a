"""The scenario's configuration: the world's behavioural and statistical parameters by
owner (timing, the ego, the obstacle driver, its observation of the ego, route following,
process noise, the scene's names), the old flat keys mapped onto them, and the bounds of
every count. Re-exported by :mod:`cdf_mj.config`."""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from cdf_mj.traits import MAX_ACCEL, MAX_DURATION, MAX_JERK, MAX_LENGTH, MAX_SPEED, bounded, validate, with_traits
from cdf_mj.traits import check as _check
from cdf_mj.traits import within as _within

__all__ = ["AFTER_MERGE", "DRIVER_FAMILIES", "FLAT_KEYS", "GROUPS", "MAX_ACCEL", "MAX_BRAKE", "MAX_DURATION",
           "MAX_EPISODES", "MAX_LENGTH", "MAX_PARTICLES", "MAX_SEED", "MAX_SPEED", "MAX_START_SPREAD",
           "MAX_TOLD_LATENCY", "MAX_TOLD_STD",
           "MAX_WORKERS", "SCENARIO_KEYS", "VERSION_0_1_WORLD", "AfterMerge", "Ego", "FlatKeyWarning", "Observation",
           "ObstacleDriver", "ProcessNoise", "Pursuit", "ScenarioConfig", "SceneNames", "Sensing", "Timing",
           "check_seed", "scenario_key"]

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
#: What a planner may be told of its own sensing (``sensing.told``; the bounds of
#: ``PlannerContext``): the measurement's and the brake's latency together [s], and the
#: std of the measured position [m].
MAX_TOLD_LATENCY = 10.0
MAX_TOLD_STD = 100.0


def check_seed(seed: object, name: str = "seed") -> int:
    """``seed`` as an ``int`` if it is an integer (``int`` or a NumPy integer, not a bool)
    from 0 to :data:`MAX_SEED`; ValueError naming ``name`` and the range otherwise. Every
    seed the package takes (an episode's, an experiment's, the environment's, the
    monitor's) passes here."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or not 0 <= int(seed) <= MAX_SEED:
        raise ValueError(f"{name}={seed!r} is out of range: must be an integer from 0 to {MAX_SEED} "
                         "(2^53 - 1, exact in JSON)")
    return int(seed)

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
    duration: float = 15.0  # [s] episode length at most; the ego passes the junction in ~4 s
    # The episode ends once the ego's rear axle is this far past the conflict point [m]
    # (and, with `until_clear`, no car is ahead of it in its lane), or at `duration`.
    end_distance: float = bounded(60.0, 0.0, MAX_LENGTH, "m")
    until_clear: bool = True  # also wait until no car is ahead of the ego in its lane
    # The label's horizon [m past the conflict point]: a constant-speed ego that gets this far
    # without touching the obstacle was not cut off (the counterfactual run ends here).
    label_distance: float = bounded(20.0, 0.0, MAX_LENGTH, "m")

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(_within(self.duration, self.dt, MAX_DURATION), "timing.duration", self.duration,
               f"in [dt = {self.dt}, {MAX_DURATION:g}] [s]")
        _check(isinstance(self.until_clear, bool), "timing.until_clear", self.until_clear, "true or false")

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
    # Behind a car that has merged into its lane the nominal controller follows it (the
    # intelligent driver model's interaction term: desired gap min_gap + v time_gap +
    # v dv / (2 sqrt(a b)), a = the car's largest acceleration, b = comfort_brake), braking at
    # most follow_brake; without `follow` it holds its speed whatever is ahead (the paper's
    # ego, and always the label's counterfactual).
    follow: bool = True
    time_gap: float = bounded(1.5, 0.0, MAX_DURATION, "s", open_low=True)  # desired time headway
    min_gap: float = bounded(2.0, 0.0, MAX_LENGTH, "m")  # desired bumper gap at standstill
    comfort_brake: float = bounded(2.0, 0.0, MAX_ACCEL, "m/s^2", open_low=True)  # IDM's b
    # The most the nominal controller brakes for a car ahead: an adaptive cruise control's
    # limit (ISO 15622 allows 3.5 m/s^2); harder braking is the planner's (emergency) call.
    follow_brake: float = bounded(3.5, 0.0, MAX_ACCEL, "m/s^2", open_low=True)
    # The ego's actuator for a graded planner's commands: its acceleration changes by at
    # most this per second (50: the full brake, 4.877 m/s^2, builds within one 0.1 s tick,
    # as the paper's brake did; the layered rule limits its own commands to its comfort
    # jerk outside the full brake). A yes/no planner's brake and release act at once.
    jerk_limit: float = bounded(50.0, 0.0, MAX_JERK, "m/s^3", open_low=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(isinstance(self.follow, bool), "ego.follow", self.follow, "true or false")


#: The obstacle's driver families (``obstacle.family``): the traits' state machine
#: (``model``) and those of :mod:`cdf_mj.scenario.drivers`, which checks that it has these.
DRIVER_FAMILIES = ("model", "gap-acceptance", "rolling-stop", "aggressive", "off-route", "looked-but-failed",
                   "misjudged-speed", "distracted", "creeper", "sumo")


@dataclass(frozen=True)
@with_traits("world")
class ObstacleDriver(_Group):
    """The world's obstacle driver: one field per trait of :data:`cdf_mj.traits.TRAITS`
    (``accel``, ``turn_speed``, ``critical_gap``, ``stop_dwell``, ...), each with the
    trait's default and checked against its range; the schema gives each one's unit and
    meaning, docs/PARAMETERS.md its calibration. Read only by the world: the filter has
    its own model of the driver (:class:`DriverPrior`)."""

    _prefix: ClassVar[str] = "obstacle."
    # Which driver drives the obstacle: "model", the state machine of these traits (the
    # filter's own model: the matched, easy case), or a family written apart from it
    # (cdf_mj.scenario.drivers: gap acceptance with a reaction time and the intelligent
    # driver model, a rolling stop, an aggressive driver, a driver off the scene's route),
    # each with its own parameters drawn per episode; the traits above then go unread.
    family: str = "model"
    if TYPE_CHECKING:  # the fields are the schema's (cdf_mj.traits.with_traits)
        def __init__(self, **traits: Any) -> None: ...
        def __getattr__(self, name: str) -> Any: ...

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(self.family in DRIVER_FAMILIES, "obstacle.family", self.family,
               f"one of {', '.join(DRIVER_FAMILIES)}")


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


#: What the obstacle may do once it is in the ego's lane (:class:`AfterMerge`).
AFTER_MERGE = ("keep", "slow", "brake", "stop")


@dataclass(frozen=True)
class AfterMerge(_Group):
    """What the obstacle does once it has entered the ego's lane: a world option, drawn per
    episode from the ranges (uniform), which the filter's model knows nothing of.

    ``keep`` (default): its driver goes on as it would. ``slow``: after ``at`` [m] in the lane
    it decelerates at ``decel`` [m/s^2] to ``slow_to`` times its speed there, then holds
    that. ``brake``: after ``at`` [m] in the lane it brakes at ``brake`` [m/s^2] to a stop
    and stands. ``stop``: an aborted turn: it brakes at ``brake`` to a stop on entering the lane
    and stands. ValueError for another behaviour or a range out of its bounds.
    """

    _prefix: ClassVar[str] = "after_merge."
    behaviour: str = "keep"
    decel: tuple[float, float] = bounded((1.5, 2.5), 0.0, MAX_ACCEL, "m/s^2", open_low=True)  # slowing
    slow_to: tuple[float, float] = bounded((0.3, 0.6), 0.0, 1.0, "1")  # of its speed when it starts slowing
    brake: tuple[float, float] = bounded((3.5, 5.0), 0.0, MAX_ACCEL, "m/s^2", open_low=True)  # to a stop
    at: tuple[float, float] = bounded((5.0, 25.0), 0.0, MAX_LENGTH, "m")  # in the lane before slowing, braking
    # Once in the ego's lane behind the ego, the obstacle keeps a following distance to it
    # (the ego's IDM parameters: cdf_mj.model.road.follow_accel), as any driver would; without
    # it the obstacle's driver drives into an ego that brakes in front of it.
    follows: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(self.behaviour in AFTER_MERGE, "after_merge.behaviour", self.behaviour, " or ".join(AFTER_MERGE))
        _check(isinstance(self.follows, bool), "after_merge.follows", self.follows, "true or false")


@dataclass(frozen=True)
class Sensing(_Group):
    """The ego's sensing of the obstacle and its brake's actuation: what the world gives its
    planner. Records keep the truth. All zero (default): perfect, as in the paper.

    Each tick the planner's measurement of the obstacle's pose is the true one ``latency``
    ticks old, plus Gaussian noise of std ``pos`` (each axis), ``heading``, ``speed``; with
    probability ``dropout`` there is none (its row is NaN and it is not in the lane). The
    ego's own pose is exact. A brake the ego decides acts ``brake_latency`` ticks later (a
    release too). Integers for the latencies [ticks of ``timing.dt``]. With ``occluded`` the
    ego measures the obstacle only while its sensor sees it (docs/OCCLUSION.md).
    """

    _prefix: ClassVar[str] = "sensing."
    pos: float = bounded(0.0, 0.0, MAX_LENGTH, "m")  # std of the measured obstacle position, each axis
    heading: float = bounded(0.0, 0.0, math.pi, "rad")  # std of its measured heading
    speed: float = bounded(0.0, 0.0, MAX_SPEED, "m/s")  # std of its measured speed
    dropout: float = bounded(0.0, 0.0, 1.0, "1")  # P(no measurement of the obstacle) per tick
    latency: int = bounded(0, 0, 100, "tick")  # ticks by which the obstacle's measurement is late
    brake_latency: int = bounded(0, 0, 100, "tick")  # ticks between a brake decision and the actuator
    # Whether the ego's planner is told these figures (its own sensors' latency and position
    # noise, and its brake's latency: PlannerContext), as a real ego knows its own hardware;
    # by default it is not (the stress suite's untold cases).
    told: bool = False
    # Whether the ego's sensor sees the obstacle only in its own line of sight: rays from its
    # sensor mount (the ego's CarGeometry.eye) to the obstacle's hull corners and centre, past
    # the buildings (MuJoCo rays); while none reaches it, there is no measurement (its row is
    # NaN and it is not in the lane, as a dropout). Its planner knows its sensor is so. False:
    # the paper's full observation, through the buildings.
    occluded: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        _check(isinstance(self.told, bool), "sensing.told", self.told, "true or false")
        _check(isinstance(self.occluded, bool), "sensing.occluded", self.occluded, "true or false")
        for name in ("latency", "brake_latency"):
            v = getattr(self, name)
            _check(isinstance(v, int) and not isinstance(v, bool), f"sensing.{name}", v,
                   "a whole number of ticks in [0, 100]")

    @property
    def perfect(self) -> bool:
        """Whether the planner gets the truth, at once, and its brake acts at once."""
        return not (self.pos or self.heading or self.speed or self.dropout or self.latency or self.brake_latency
                    or self.occluded)


#: The groups of :class:`ScenarioConfig` (all but ``names``) and their classes.
GROUPS: Mapping[str, type[Any]] = MappingProxyType({
    "timing": Timing, "ego": Ego, "obstacle": ObstacleDriver, "observation": Observation, "pursuit": Pursuit,
    "noise": ProcessNoise, "after_merge": AfterMerge, "sensing": Sensing})
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


class FlatKeyWarning(DeprecationWarning):
    """A flat key of version 0.1 (:data:`FLAT_KEYS`) was read, in code (``ScenarioConfig(beta=...)``)
    or in a user's input (``--set``, a preset or space file:
    :mod:`cdf_mj.config.user_values`); the message names what to write instead. The
    command line shows each as a one-line note on stderr."""


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
    ``after_merge`` :class:`AfterMerge`: what the obstacle does once in the ego's lane
    ``sensing``     :class:`Sensing`: the ego's noisy, late or missing measurements
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
    after_merge: AfterMerge = field(default_factory=AfterMerge)
    sensing: Sensing = field(default_factory=Sensing)
    # Names of the scene elements the code reads (defaults match models/xml/scene.xml).
    names: SceneNames = field(default_factory=SceneNames)

    def __init__(self, timing: Timing | Mapping[str, Any] | None = None, ego: Ego | Mapping[str, Any] | None = None,
                 obstacle: ObstacleDriver | Mapping[str, Any] | None = None,
                 observation: Observation | Mapping[str, Any] | None = None,
                 pursuit: Pursuit | Mapping[str, Any] | None = None,
                 noise: ProcessNoise | Mapping[str, Any] | None = None,
                 names: SceneNames | Mapping[str, Any] | None = None,
                 after_merge: AfterMerge | Mapping[str, Any] | None = None,
                 sensing: Sensing | Mapping[str, Any] | None = None, **keys: Any) -> None:
        given = {"timing": timing, "ego": ego, "obstacle": obstacle, "observation": observation,
                 "pursuit": pursuit, "noise": noise, "names": names, "after_merge": after_merge,
                 "sensing": sensing}
        values = {**{k: v for k, v in given.items() if v is not None}, **keys}
        for name, value in _apply(_DEFAULT_GROUPS, values, TypeError, warn=True).items():
            object.__setattr__(self, name, value)
        _check(isinstance(self.names, SceneNames), "names", self.names,
               "a SceneNames (e.g. SceneNames(route_ego='av_path'))")
        for name, cls in GROUPS.items():
            value = getattr(self, name)
            _check(isinstance(value, cls), name, value, f"a {cls.__name__} object (or a mapping of its fields)")
        ticks = self.timing.n_ticks
        for name in ("latency", "brake_latency"):  # a latency as long as the episode leaves nothing to see
            v = getattr(self.sensing, name)
            _check(v < ticks, f"sensing.{name}", v, f"fewer ticks than the episode's {ticks} "
                                                     f"(timing.duration / timing.dt)")
        sensing, dt = self.sensing, self.timing.dt
        if sensing.told:  # what the planner is told: within what a planner takes (PlannerContext.of)
            told = (sensing.latency + sensing.brake_latency) * dt
            _check(told <= MAX_TOLD_LATENCY, "sensing.latency + sensing.brake_latency",
                   sensing.latency + sensing.brake_latency, f"at most {MAX_TOLD_LATENCY:g} s of timing.dt = {dt:g} s "
                   f"ticks where sensing.told (it tells the planner {told:g} s)")
            _check(sensing.pos <= MAX_TOLD_STD, "sensing.pos", sensing.pos,
                   f"at most {MAX_TOLD_STD:g} m where sensing.told (the std it tells the planner)")

    if not TYPE_CHECKING:  # the flat reads of version 0.1: not for the package's own code
        def __getattr__(self, name: str) -> Any:
            dotted = FLAT_KEYS.get(name)
            if dotted is None:
                raise AttributeError(f"'ScenarioConfig' object has no attribute {name!r}")
            warnings.warn(f"ScenarioConfig.{name} is deprecated; read config.{dotted}", FlatKeyWarning,
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
        flat (a settings.json of version 0.1, read in that version's world,
        :data:`VERSION_0_1_WORLD`; no warning: stored results stay readable)."""
        flat = bool(data) and all(key in FLAT_KEYS or key == "names" for key in data)
        base = _VERSION_0_1_GROUPS if flat else _DEFAULT_GROUPS
        return cls(**_apply(base, data, ValueError, warn=False))

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
                          FlatKeyWarning, stacklevel=stacklevel)
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


#: What version 0.1's world was, where today's defaults differ (fields it did not have):
#: episodes that ended 20 m past the conflict point, an ego and an obstacle that followed no
#: one. A flat settings.json (that version's) reads in that world.
VERSION_0_1_WORLD: Mapping[str, Any] = MappingProxyType({
    "timing.end_distance": 20.0, "timing.until_clear": False, "ego.follow": False, "after_merge.follows": False})
_VERSION_0_1_GROUPS: Mapping[str, Any] = MappingProxyType(
    _apply(_DEFAULT_GROUPS, VERSION_0_1_WORLD, ValueError, warn=False))


