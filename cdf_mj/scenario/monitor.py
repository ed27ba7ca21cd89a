"""The CDF filter watching two cars in a simulation that someone else steps: give it the
cars' poses every 0.1 s, get the posterior and the brake decision.

The filter needs the junction's :class:`~cdf_mj.model.layout.Layout` (routes, sites,
buildings) and a few dimensions of each car (:class:`~cdf_mj.model.vehicle.CarGeometry`;
default: our car), nothing from MuJoCo. Poses are ``[x, y, yaw, speed]`` of each car's
rear-axle centre in the world frame: x, y [m], heading of the car's forward axis from the
world x axis towards y [rad], speed along that heading [m/s]. ::

    from cdf_mj.scenario.monitor import CDFMonitor

    monitor = CDFMonitor(layout, ego=CarGeometry.ours(), obstacle=their_car, rng=0)
    for t, ego_pose, obstacle_pose in my_simulation():      # every 0.1 s of simulated time
        decision = monitor.observe(t, ego_pose, obstacle_pose)
        my_ego.set_acceleration(decision.accel)             # [m/s^2]; decision.brake: braking hard
    monitor.save_trace("episode.jsonl")                     # cdf-mj render --trace episode.jsonl

:func:`attach` is the convenience for a MuJoCo model: it reads the layout from the model
by name (:class:`cdf_mj.config.SceneNames`; docs/SCENES.md) and each car's pose from a
named body of any kind (our planar joints, a free joint, a mocap body, a nested chain),
after which :meth:`CDFMonitor.step` reads the poses and observes them::

    monitor = attach(model, data, names, rng=0,
                     obstacle=TrackedCar(body="their_car", rear_axle=(-1.35, 0.0), geometry=their_car))
    nstep = round(monitor.scenario.timing.dt / model.opt.timestep)  # physics steps per 0.1 s tick
    while ...:
        decision = monitor.step()
        mujoco.mj_step(model, data, nstep=nstep)

An ego whose sensor sees the other car only in its line of sight (the common case): give
``scenario`` with ``sensing={"occluded": True}`` and pass 4 NaN as ``obstacle_pose`` on
every tick your sensor does not see it (with ``record_trace=False``). The filter then reads
not seeing as information: each hypothesis of the other car that the ego's eye (the ``ego``
car's :meth:`~cdf_mj.model.vehicle.CarGeometry.eye`) would have seen past the layout's
buildings loses weight (:data:`~cdf_mj.inference.particle_filter.MISS_PROBABILITY` per
tick), a hidden one keeps it; before the first sight it starts with the other car where
the ego cannot see it: coming down the side road's hidden approach, or waiting at a hidden
stop line (docs/OCCLUSION.md). Without it a NaN is a dropout, which tells nothing.

``planner=`` (of both) puts another registered planner in the CDF's place, to compare
them on your testbed as the package's tables do: ``CDFMonitor(layout, planner="imm-layered")``,
``"reactive"``, or one of yours (``cdf_mj.register``); its decisions have ``posterior``
None and its trace no posterior.

This module imports neither MuJoCo nor :mod:`cdf_mj.sim` until :func:`attach` is called
(or a :class:`~cdf_mj.sim.scene.Scene` is given). How a car's body is read is
:mod:`cdf_mj.sim.tracking` (:class:`TrackedCar`), the trace file is
:mod:`cdf_mj.scenario.trace_file` (:func:`read_trace`, :class:`MonitorTrace`); both are
re-exported here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames, check_seed
from cdf_mj.inference.particle_filter import ParticleFilter, Posterior
from cdf_mj.model import road
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners.base import DecidingPlanner, Planner, PlannerContext, PlannerInput, intervenes
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.registry import bind_planner
from cdf_mj.records import jsonable
from cdf_mj.scenario.ego_agent import PlannerCommand
from cdf_mj.scenario.trace_file import TRACE_FORMAT, MonitorTrace, TraceError, read_trace, write_trace

if TYPE_CHECKING:
    import mujoco

    from cdf_mj.sim.scene import Scene
    from cdf_mj.sim.tracking import TrackedCar

__all__ = ["TRACE_FORMAT", "CDFMonitor", "Decision", "MonitorTrace", "PoseSource", "TraceError",
           "TrackedCar", "attach", "read_trace"]

#: [s] how far the time between two observations may be from ``dt`` (rounding only).
TIME_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Decision:
    """The monitor's answer at one control step."""

    t: float  # [s] simulated time of the measurement
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, yaw rad, v m/s]
    # P(left), P(right), P(seen), P(cutoff), effective sample size; None for a planner
    # without a posterior (``reactive``, ``imm-*``, ``cv-*``, a user's: CDFMonitor.has_posterior).
    # Annotated Posterior, as the Gymnasium env (always the cdf) reads it so.
    posterior: Posterior | None
    brake: bool  # the rule brakes hard now: its command is at or beyond LayeredConfig.hard_brake
    # (the layered rule), or it brakes fully (the risk rule may release; the paper's threshold
    # rule, P(cutoff) >= tau, holds it from the first yes); for another planner: its graded
    # command at or beyond its hard_brake, or its yes (held unless it releases_brake), as
    # the ego of run_episode reads it (cdf_mj.scenario.ego_agent.PlannerCommand)
    brake_time: float | None  # [s] the first step at which it braked hard
    accel: float = math.nan  # [m/s^2] the acceleration to apply until the next step, negative when
    # braking: the ego's speed hold towards its nominal speed (speed_gain (v_nominal - v)),
    # capped by the rule's command, within the ego car's limits (its full brake when it brakes
    # with a yes/no rule)


class PoseSource(Protocol):
    """Where an attached monitor reads the time [s] and the system pose ``(2, 4)``
    (:mod:`cdf_mj.sim.tracking` has those of :func:`attach` and of a Scene). A source that
    also has ``forget()`` is told so by :meth:`CDFMonitor.reset` (it drops what it kept of
    the last read)."""

    timestep: float  # [s] the simulation's step, for messages

    def read(self) -> tuple[float, np.ndarray]:
        """The simulated time [s] and the poses of ego and obstacle ``(2, 4)``."""
        ...


def _pose(value: Sequence[float] | np.ndarray, what: str, missing: bool = False) -> np.ndarray:
    """``value`` as 4 finite floats (or, where ``missing`` is allowed, 4 NaN: no measurement),
    or one ValueError naming ``what``."""
    try:
        pose = np.array(value, dtype=float)
    except (TypeError, ValueError):
        pose = np.full(0, np.nan)
    if pose.shape != (4,) or not (np.all(np.isfinite(pose)) or (missing and np.all(np.isnan(pose)))):
        raise ValueError(f"CDFMonitor.observe: {what} must be 4 finite numbers [x m, y m, yaw rad, "
                         f"speed m/s] (rear axle, world frame){' or 4 NaN' if missing else ''}, "
                         f"got {_show(value)}")
    return pose


def _show(value: object) -> str:
    """A short repr of a bad input for a message."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else text[:77] + "..."


def _name(planner: Planner) -> str:
    """A planner's name for messages and the trace header."""
    return str(getattr(planner, "name", None) or type(planner).__name__)


def _planner(planner: object, cdf: CDFConfig) -> Planner:
    """The monitor's planner: a registered name built as experiments build it (with what it
    takes of ``cdf``: :func:`~cdf_mj.planners.registry.bind_planner`), or a Planner object;
    ValueError naming the registered planners, or TypeError naming what was given."""
    if isinstance(planner, Planner):
        return planner
    if not isinstance(planner, str):
        raise TypeError(f"CDFMonitor: planner must be a registered planner's name or a cdf_mj.planners.Planner, "
                        f"got {_show(planner)} of type {type(planner).__name__}")
    if planner == "cdf":  # the same filter and rule as the `cdf` planner, built as ever
        return CDFPlanner(cdf)
    try:
        return bind_planner(planner, cdf).make()
    except ValueError as exc:
        raise ValueError(f"CDFMonitor: {exc}") from None


def _rule_of(planner: Planner) -> dict[str, Any]:
    """The header's ``rule`` (its name, None without one) and ``threshold`` (where it has
    one in (0, 1]) of a planner without a posterior."""
    rule = planner.rule if isinstance(planner, DecidingPlanner) else None
    name = getattr(rule, "name", None)
    if name not in ("threshold", "risk", "layered"):
        return {"rule": None}
    value = getattr(rule, "threshold", None) if name == "threshold" else getattr(getattr(rule, "config", None),
                                                                                 "brake", None)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0 < value <= 1):
        return {"rule": name}
    return {"rule": name, "threshold": float(value)}


class CDFMonitor:
    """The CDF particle filter watching two cars whose simulation someone else steps.

    Args:
        layout: the junction (:meth:`cdf_mj.sim.scene.Scene.layout`,
            :func:`cdf_mj.sim.scene.read_layout`, or built by hand); a
            :class:`~cdf_mj.sim.scene.Scene` is also accepted, and then :meth:`step` reads
            its poses (what the Gymnasium env does).
        scenario: ``dt`` (the tick), the observation noise and the scene names kept in
            the trace; default :class:`ScenarioConfig`. Tell the rule your ego's own
            latency and noise through its ``sensing`` with ``told=True`` (e.g.
            ``{"brake_latency": 2, "told": True}`` for brakes that act 0.2 s late): its
            margins grow by them (measured: on a narrow rotated junction, a car stopping in
            the lane and brakes 0.2 s late, 1 touch in 12 cut-off seeds untold, none told).
            ``{"occluded": True}``: your ego's sensor sees the other car only in its line of
            sight, so that a missing measurement (NaN) is read as not seeing it (module
            docstring).
        cdf: the filter and its decision rule (N, Sigma, its driver model, ``decision``:
            the risk rule or the paper's threshold tau); default :class:`CDFConfig`.
        rng: the Generator of the filter's randomness, or a seed (an integer from 0 to
            :data:`~cdf_mj.config.MAX_SEED`; ValueError otherwise), or None (fresh entropy).
        ego, obstacle: the cars' dimensions, replacing the layout's (default: the
            layout's, which is our car's for a layout built by hand).
        source: where :meth:`step` reads time and poses (set by :func:`attach`).
        nominal_speed: [m/s] the speed the ego's own controller holds when the rule does
            not brake (:class:`~cdf_mj.planners.base.PlannerContext`); default the
            scenario's ego speed, 13.4 m/s (:func:`cdf_mj.config.scaled` scales it for a
            testbed at another scale). Give your ego's cruise speed if it is another.
        planner: what decides instead of the CDF, to compare rules on your testbed as the
            package's tables do: a registered name (``"imm-layered"``, ``"reactive"``,
            ``"cv-layered"``, one of yours from :func:`~cdf_mj.planners.register`; built
            by :func:`~cdf_mj.planners.registry.bind_planner` with what it takes of
            ``cdf``, as experiments build it) or a :class:`~cdf_mj.planners.base.Planner`
            object. Default ``"cdf"``: the CDF filter with ``cdf``'s rule. ValueError
            listing the registered names for an unknown one; TypeError for an object that
            is not a Planner. A planner without a posterior (anything but the ``cdf*``
            planners) gives ``Decision.posterior`` None, has no :attr:`filter`, and its
            trace holds no posterior (:meth:`save_trace`).

    The decision rule assumes that its decisions are carried out: the ego applies
    ``Decision.accel`` (its speed hold towards ``nominal_speed`` capped by the rule's
    command: the layered rule's gentle slowing, its car following, or the full brake) until
    the next step; its plans reason about that ego. An ego that does not follow them makes
    the risk estimates of later ticks those of an ego it is not.

    :meth:`observe` must be called every ``scenario.timing.dt`` of simulated time (to
    :data:`TIME_TOLERANCE`): the filter's dynamics assume that tick, so a simulation whose
    timestep does not divide ``dt`` is refused, not followed. After resetting your
    simulation, call :meth:`reset`. Every observation is kept in :attr:`trace`
    (:meth:`save_trace` writes it) unless ``record_trace`` is False.
    """

    def __init__(self, layout: Layout | Scene, scenario: ScenarioConfig | None = None,
                 cdf: CDFConfig | None = None, rng: np.random.Generator | int | None = None, *,
                 ego: CarGeometry | None = None, obstacle: CarGeometry | None = None,
                 source: PoseSource | None = None, record_trace: bool = True,
                 nominal_speed: float | None = None, planner: str | Planner = "cdf") -> None:
        self.scene: Scene | None = None
        if not isinstance(layout, Layout):
            if not callable(getattr(layout, "layout", None)):
                raise TypeError(f"CDFMonitor: layout must be a Layout (or a Scene), got "
                                f"{type(layout).__name__}")
            self.scene = layout
            if source is None:
                from cdf_mj.sim.tracking import ScenePoseSource

                source = ScenePoseSource(layout)
            layout = layout.layout()
        for name, car in (("ego", ego), ("obstacle", obstacle)):
            if car is not None and not isinstance(car, CarGeometry):
                raise TypeError(f"CDFMonitor: {name} must be a CarGeometry, got {type(car).__name__}")
        self.layout = layout.with_cars(ego, obstacle)
        self.scenario = scenario or ScenarioConfig()
        self.cdf = cdf or CDFConfig()
        # What the ego knows: the map, the tick, its own nominal controller (ValueError here).
        self.context = PlannerContext.of(self.layout, self.scenario)
        if nominal_speed is not None:
            self.context = dataclasses.replace(self.context, nominal_speed=nominal_speed)
        self.source = source
        self.record_trace = record_trace
        self.rng = rng if isinstance(rng, np.random.Generator) else \
            np.random.default_rng(None if rng is None else check_seed(rng, "rng"))
        self.planner: Planner = _planner(planner, self.cdf)
        self._command = PlannerCommand(self.planner, self.layout.ego.max_brake)
        self.reset()

    @property
    def has_posterior(self) -> bool:
        """Whether the planner is a CDF filter (``cdf``, ``cdf-risk``, ``cdf-threshold``):
        only then has a decision a ``posterior`` and the monitor a :attr:`filter`."""
        return isinstance(self.planner, CDFPlanner)

    @property
    def filter(self) -> ParticleFilter:
        """The particle filter of the current episode; AttributeError for a planner without one."""
        if not isinstance(self.planner, CDFPlanner):
            raise AttributeError(f"CDFMonitor.filter: planner {_name(self.planner)!r} has no particle filter "
                                 "(only the cdf planners have one); its decisions have posterior None")
        return self.planner.filter

    def reset(self) -> None:
        """Forget the episode: the next observation starts the filter from the prior, and a
        new trace.

        The filter's random stream goes on from where it was, so a replayed episode gets
        other draws; build a new monitor with the same ``rng`` seed to repeat one exactly."""
        self._last_t: float | None = None
        self.planner.reset(self.context, self.rng)
        self._command.reset()  # the planner's kind as it is after its reset
        self.decision: Decision | None = None
        self.trace: list[dict[str, Any]] = []
        forget = getattr(self.source, "forget", None)
        if forget is not None:  # a source that differentiates positions (BodyPoseSource)
            forget()

    def observe(self, t: float, ego_pose: Sequence[float] | np.ndarray,
                obstacle_pose: Sequence[float] | np.ndarray) -> Decision:
        """One filter tick on the poses measured at simulated time ``t`` [s].

        The first call after :meth:`reset` starts the filter at the measured pose (the
        obstacle waiting, an unseen ego, intent from the prior); later calls weigh the
        particles by the new measurement and resample; the decision rule reads them; then
        they are propagated one tick.
        An ``obstacle_pose`` of 4 NaN is no measurement (a sensor's dropout): the filter
        skips its weighing and only predicts, as the ``cdf`` planner does; with
        ``scenario.sensing.occluded`` it is the ego's not seeing the other car, which
        weighs the hypotheses the ego would have seen down (and may be the first call: the
        filter then starts with the other car unseen: on the side road's hidden approach, or at
        a hidden stop line). Taken only with
        ``record_trace=False`` (a trace file holds measured poses).
        ValueError, with nothing changed, for a pose that is not 4 finite numbers, a time
        that is not finite or goes back, or a time ``dt`` away from the last one.
        """
        try:
            t = float(t)
        except (TypeError, ValueError):
            t = math.nan
        if not math.isfinite(t):
            raise ValueError(f"CDFMonitor.observe: t must be a finite time [s], got {_show(t)}")
        poses = np.stack([_pose(ego_pose, "ego_pose"),
                          _pose(obstacle_pose, "obstacle_pose", missing=not self.record_trace)])
        self._check_time(t)
        x, y, th = (float(v) for v in poses[1, :3])
        # No measurement (4 NaN): not in the lane.
        in_lane = not math.isnan(x) and road.in_lane(self.layout, self.layout.obstacle.footprint_one(x, y, th))
        command = self._command(PlannerInput(t=t, poses=poses, obstacle_in_lane=in_lane))
        brake = self._command.braking
        self._last_t = t
        post = self.planner.posterior if isinstance(self.planner, CDFPlanner) else None
        ctx, car = self.context, self.layout.ego
        hold = ctx.speed_gain * (ctx.nominal_speed - float(poses[0, 3]))  # the ego's speed hold
        accel = min(max(min(hold, command), -car.max_brake), car.max_accel)
        # Every intervention (EgoAgent's rule; the speed hold is the monitor's own controller).
        own = min(max(hold, -car.max_brake), car.max_accel)
        acts = min(max(command, -car.max_brake), car.max_accel)
        intervening = intervenes(acts, own, car.max_brake)
        self.decision = Decision(t=t, poses=poses, posterior=post, brake=brake,
                                 brake_time=self.brake_time, accel=accel)
        if self.record_trace:
            row = {"t": t, "ego": poses[0].tolist(), "obstacle": poses[1].tolist(),
                   **({"posterior": post.to_dict()} if post is not None else {}),
                   "brake": self.decision.brake, "accel": accel, "command": acts, "own": own,
                   "intervening": intervening}
            rule = self.planner.rule if isinstance(self.planner, DecidingPlanner) else None
            self.trace.append(row | ({k: float(v) for k, v in rule.values().items()} if rule is not None else {}))
        return self.decision

    @property
    def brake_time(self) -> float | None:
        """[s] the first observation at which the rule braked, None if it has not."""
        t = self._command.brake_time
        return round(t, 6) if t is not None else None

    def step(self) -> Decision:
        """Read the time and both poses from the attached simulation, then :meth:`observe`."""
        if self.source is None:
            raise RuntimeError("CDFMonitor.step: this monitor reads no simulation; call "
                               "observe(t, ego_pose, obstacle_pose), or build it with attach()")
        t, poses = self.source.read()
        return self.observe(t, poses[0], poses[1])

    def _check_time(self, t: float) -> None:
        if self._last_t is None:
            return
        dt, elapsed = self.scenario.timing.dt, t - self._last_t
        if elapsed <= 0.0:
            raise ValueError(f"CDFMonitor: time went back or stood still ({self._last_t:.6g} s, "
                             f"then {t:.6g} s); call reset() after resetting your simulation")
        if not math.isclose(elapsed, dt, abs_tol=TIME_TOLERANCE):
            step = self.source.timestep if self.source is not None else None
            hint = (f"; the model's timestep {step:g} s must divide it (step "
                    f"{dt / step:.4g} times per tick)" if step and abs(dt / step - round(dt / step)) > 1e-6
                    else "")
            raise ValueError(f"CDFMonitor: {elapsed:.6g} s of simulated time since the last call; "
                             f"call it every dt={dt} s{hint}, or reset() after resetting the "
                             "simulation")

    # ------------------------------------------------------------------ trace
    def trace_header(self) -> dict[str, Any]:
        """The first line of a trace file: format, scene names, configs, the decision rule and
        the threshold of what it brakes on (``risk`` for the risk rule, P(cutoff) for the
        threshold rule), car geometries. Another planner than ``cdf`` is named
        (``"planner"``); one without a posterior has ``"posterior": false``, no ``cdf`` nor
        ``tau``, and its rule's name and threshold where it has them (else ``"rule": null``)."""
        if not isinstance(self.planner, CDFPlanner):
            return {"format": TRACE_FORMAT, "names": jsonable(self.scenario.names),
                    "scenario": jsonable(self.scenario), "planner": _name(self.planner), "posterior": False,
                    **_rule_of(self.planner),
                    "ego": self.layout.ego.to_dict(), "obstacle": self.layout.obstacle.to_dict()}
        cdf = self.planner.cdf  # the planner's own (cdf-risk and cdf-threshold set their rule)
        return {"format": TRACE_FORMAT, "names": jsonable(self.scenario.names),
                "scenario": jsonable(self.scenario), "cdf": jsonable(cdf),
                "tau": float(cdf.tau), "rule": self.planner.rule.name,
                "threshold": float(cdf.tau if cdf.decision == "threshold" else cdf.risk.brake),
                "ego": self.layout.ego.to_dict(),
                "obstacle": self.layout.obstacle.to_dict()} | (
                    {"planner": _name(self.planner)} if _name(self.planner) != "cdf" else {})

    def save_trace(self, path: str | Path) -> Path:
        """Write the trace since the last :meth:`reset` as JSON lines: the header
        (:meth:`trace_header`), then one object per observation ``{"t", "ego", "obstacle",
        "posterior", "brake", "accel"}`` (and ``"risk"`` with the risk rule; no
        ``"posterior"`` for a planner without one). The file appears complete or not at all."""
        return write_trace(path, self.trace_header(), self.trace)


def attach(model: mujoco.MjModel, data: mujoco.MjData, names: SceneNames | None = None,
           scenario: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
           rng: np.random.Generator | int | None = None, *,
           ego: TrackedCar | CarGeometry | None = None,
           obstacle: TrackedCar | CarGeometry | None = None,
           record_trace: bool = True, nominal_speed: float | None = None,
           planner: str | Planner = "cdf") -> CDFMonitor:
    """A :class:`CDFMonitor` on your model and data; :meth:`CDFMonitor.step` then reads
    the poses from ``data`` and observes them.

    The junction is read by ``names`` (routes, sites, buildings: docs/SCENES.md); each car
    by its :class:`TrackedCar` (a bare :class:`CarGeometry` is ``TrackedCar(geometry=...)``):
    its pose from a body, its dimensions as given, or else from our car's elements. With a
    geometry given nothing else of that car is read, so a wrong ``front_axle`` cannot give
    a wrong wheelbase, and a car without an eye site or a named hull is fine. ``names``
    defaults to ``scenario.names``; ``nominal_speed`` is the monitor's (the ego's cruise
    speed [m/s], default the scenario's), ``planner`` what decides (default ``"cdf"``; a
    registered name or a Planner: :class:`CDFMonitor`). SceneError lists every problem of
    the junction; a missing body or car element is one SceneError naming it and the fix.
    """
    from cdf_mj.sim.scene import read_layout
    from cdf_mj.sim.tracking import BodyPoseSource, TrackedCar, find_bodies

    scenario = scenario or ScenarioConfig(names=names or SceneNames())
    names = names or scenario.names
    if names != scenario.names:
        scenario = dataclasses.replace(scenario, names=names)
    tracked = []
    for which, car in (("ego", ego), ("obstacle", obstacle)):
        if car is None or isinstance(car, CarGeometry):
            car = TrackedCar(geometry=car)
        if not isinstance(car, TrackedCar):
            raise TypeError(f"attach: {which} must be a TrackedCar or a CarGeometry, got "
                            f"{type(car).__name__}")
        tracked.append(car)
    bodies = find_bodies(model, names, *tracked)
    layout = read_layout(model, names, ego=tracked[0].geometry, obstacle=tracked[1].geometry)
    source = BodyPoseSource(model, data, bodies, tracked)  # SceneError: data of another model
    return CDFMonitor(layout, scenario, cdf, rng, source=source, record_trace=record_trace,
                      nominal_speed=nominal_speed, planner=planner)


#: Names that moved to :mod:`cdf_mj.sim.tracking`, read from there on first access (it
#: imports MuJoCo): the module's name for each.
_TRACKING = {"TrackedCar": "TrackedCar", "_BodySource": "BodyPoseSource", "_SceneSource": "ScenePoseSource"}


def __getattr__(name: str) -> Any:
    """:class:`TrackedCar` (and the pose sources) on first access (PEP 562)."""
    if name in _TRACKING:
        from cdf_mj.sim import tracking

        return getattr(tracking, _TRACKING[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
