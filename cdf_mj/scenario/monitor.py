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
        if decision.brake: ...                              # the CDF's rule says brake now
    monitor.save_trace("episode.jsonl")                     # cdf-mj render --trace episode.jsonl

:func:`attach` is the convenience for a MuJoCo model: it reads the layout from the model
by name (:class:`cdf_mj.config.SceneNames`; docs/SCENES.md) and each car's pose from a
named body of any kind (our planar joints, a free joint, a mocap body, a nested chain),
after which :meth:`CDFMonitor.step` reads the poses and observes them::

    monitor = attach(model, data, names, rng=0,
                     obstacle=TrackedCar(body="their_car", rear_axle=(-1.35, 0.0), geometry=their_car))
    nstep = round(monitor.scenario.dt / model.opt.timestep)  # physics steps per 0.1 s tick
    while ...:
        decision = monitor.step()
        mujoco.mj_step(model, data, nstep=nstep)

This module imports neither MuJoCo nor :mod:`cdf_mj.sim` until :func:`attach` is called.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames
from cdf_mj.inference.particle_filter import ParticleFilter, Posterior
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners.base import PlannerInput
from cdf_mj.planners.cdf import CDFPlanner

if TYPE_CHECKING:
    import mujoco

    from cdf_mj.sim.scene import Scene

__all__ = ["TRACE_FORMAT", "CDFMonitor", "Decision", "MonitorTrace", "PoseSource", "TraceError",
           "TrackedCar", "attach", "read_trace"]

#: The ``format`` of the header line of a trace file (:meth:`CDFMonitor.save_trace`).
TRACE_FORMAT = "cdf_mj.monitor_trace/1"
#: [s] how far the time between two observations may be from ``dt`` (rounding only).
TIME_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Decision:
    """The monitor's answer at one control step."""

    t: float  # [s] simulated time of the measurement
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, yaw rad, v m/s]
    posterior: Posterior  # P(left), P(right), P(seen), P(cutoff), effective sample size
    brake: bool  # the CDF's decision rule brakes now (CDFConfig.decision: the risk rule may
    # release; the paper's threshold rule, P(cutoff) >= tau, holds it from the first yes)
    brake_time: float | None  # [s] the first step at which it braked


class PoseSource(Protocol):
    """Where an attached monitor reads the time [s] and the system pose ``(2, 4)``."""

    timestep: float  # [s] the simulation's step, for messages

    def read(self) -> tuple[float, np.ndarray]:
        """The simulated time [s] and the poses of ego and obstacle ``(2, 4)``."""
        ...


def _pose(value: Sequence[float] | np.ndarray, what: str) -> np.ndarray:
    """``value`` as 4 finite floats, or one ValueError naming ``what``."""
    try:
        pose = np.array(value, dtype=float)
    except (TypeError, ValueError):
        pose = np.full(0, np.nan)
    if pose.shape != (4,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"CDFMonitor.observe: {what} must be 4 finite numbers [x m, y m, yaw rad, "
                         f"speed m/s] (rear axle, world frame), got {_show(value)}")
    return pose


def _show(value: object) -> str:
    """A short repr of a bad input for a message."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else text[:77] + "..."


def _jsonable(value: Any) -> Any:
    """Configs (dataclasses, tuples, NumPy values) as plain JSON values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, enum.Enum):
        return _jsonable(value.value)
    return value


class CDFMonitor:
    """The CDF particle filter watching two cars whose simulation someone else steps.

    Args:
        layout: the junction (:meth:`cdf_mj.sim.scene.Scene.layout`,
            :func:`cdf_mj.sim.scene.read_layout`, or built by hand); a
            :class:`~cdf_mj.sim.scene.Scene` is also accepted, and then :meth:`step` reads
            its poses (what the Gymnasium env does).
        scenario: ``dt`` (the tick), the observation noise and the scene names kept in
            the trace; default :class:`ScenarioConfig`.
        cdf: the filter and its decision rule (N, Sigma, its driver model, ``decision``:
            the risk rule or the paper's threshold tau); default :class:`CDFConfig`.
        rng: the Generator of the filter's randomness, or a seed.
        ego, obstacle: the cars' dimensions, replacing the layout's (default: the
            layout's, which is our car's for a layout built by hand).
        source: where :meth:`step` reads time and poses (set by :func:`attach`).

    The decision rule assumes that its decisions are carried out: the ego brakes at its
    car's maximum rate when ``Decision.brake`` is true and otherwise holds or regains its
    nominal speed (``scenario.ego_speed``); its release and its plans reason about that
    ego. An ego that does not follow them makes the risk estimates of later ticks those of
    an ego it is not.

    :meth:`observe` must be called every ``scenario.dt`` of simulated time (to
    :data:`TIME_TOLERANCE`): the filter's dynamics assume that tick, so a simulation whose
    timestep does not divide ``dt`` is refused, not followed. After resetting your
    simulation, call :meth:`reset`. Every observation is kept in :attr:`trace`
    (:meth:`save_trace` writes it) unless ``record_trace`` is False.
    """

    def __init__(self, layout: Layout | Scene, scenario: ScenarioConfig | None = None,
                 cdf: CDFConfig | None = None, rng: np.random.Generator | int | None = None, *,
                 ego: CarGeometry | None = None, obstacle: CarGeometry | None = None,
                 source: PoseSource | None = None, record_trace: bool = True) -> None:
        self.scene: Scene | None = None
        if not isinstance(layout, Layout):
            if not callable(getattr(layout, "layout", None)):
                raise TypeError(f"CDFMonitor: layout must be a Layout (or a Scene), got "
                                f"{type(layout).__name__}")
            self.scene = layout
            source = source or _SceneSource(layout)
            layout = layout.layout()
        for name, car in (("ego", ego), ("obstacle", obstacle)):
            if car is not None and not isinstance(car, CarGeometry):
                raise TypeError(f"CDFMonitor: {name} must be a CarGeometry, got {type(car).__name__}")
        self.layout = layout.with_cars(ego, obstacle)
        self.scenario = scenario or ScenarioConfig()
        self.cdf = cdf or CDFConfig()
        self.source = source
        self.record_trace = record_trace
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.planner = CDFPlanner(self.cdf)  # the same filter and rule as the `cdf` planner
        self.reset()

    @property
    def filter(self) -> ParticleFilter:
        """The particle filter of the current episode."""
        return self.planner.filter

    def reset(self) -> None:
        """Forget the episode: the next observation starts the filter from the prior, and a
        new trace.

        The filter's random stream goes on from where it was, so a replayed episode gets
        other draws; build a new monitor with the same ``rng`` seed to repeat one exactly."""
        self._last_t: float | None = None
        self.planner.reset(self.layout, self.scenario, self.rng)
        self.decision: Decision | None = None
        self.trace: list[dict[str, Any]] = []
        if isinstance(self.source, _BodySource):
            self.source.forget()

    def observe(self, t: float, ego_pose: Sequence[float] | np.ndarray,
                obstacle_pose: Sequence[float] | np.ndarray) -> Decision:
        """One filter tick on the poses measured at simulated time ``t`` [s].

        The first call after :meth:`reset` starts the filter at the measured pose (the
        obstacle waiting, an unseen ego, intent from the prior); later calls weigh the
        particles by the new measurement and resample; the decision rule reads them; then
        they are propagated one tick.
        ValueError, with nothing changed, for a pose that is not 4 finite numbers, a time
        that is not finite or goes back, or a time ``dt`` away from the last one.
        """
        try:
            t = float(t)
        except (TypeError, ValueError):
            t = math.nan
        if not math.isfinite(t):
            raise ValueError(f"CDFMonitor.observe: t must be a finite time [s], got {_show(t)}")
        poses = np.stack([_pose(ego_pose, "ego_pose"), _pose(obstacle_pose, "obstacle_pose")])
        self._check_time(t)
        x, y, th = (float(v) for v in poses[1, :3])
        in_lane = self.layout.ego_lane.contains_any(self.layout.obstacle.footprint_one(x, y, th))
        brake = self.planner.brake(PlannerInput(t=t, poses=poses, obstacle_in_lane=in_lane))
        self._last_t = t
        post = self.planner.posterior
        self.decision = Decision(t=t, poses=poses, posterior=post, brake=brake,
                                 brake_time=self.brake_time)
        if self.record_trace:
            row = {"t": t, "ego": poses[0].tolist(), "obstacle": poses[1].tolist(),
                   "posterior": post.to_dict(), "brake": self.decision.brake}
            self.trace.append(row | {k: float(v) for k, v in self.planner.rule.values().items()})
        return self.decision

    @property
    def brake_time(self) -> float | None:
        """[s] the first observation at which the rule braked, None if it has not."""
        t = self.planner.decision_time
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
        dt, elapsed = self.scenario.dt, t - self._last_t
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
        threshold rule), car geometries."""
        return {"format": TRACE_FORMAT, "names": _jsonable(self.scenario.names),
                "scenario": _jsonable(self.scenario), "cdf": _jsonable(self.cdf),
                "tau": float(self.cdf.tau), "rule": self.planner.rule.name,
                "threshold": float(self.cdf.risk.brake if self.cdf.decision == "risk" else self.cdf.tau),
                "ego": self.layout.ego.to_dict(),
                "obstacle": self.layout.obstacle.to_dict()}

    def save_trace(self, path: str | Path) -> Path:
        """Write the trace since the last :meth:`reset` as JSON lines: the header
        (:meth:`trace_header`), then one object per observation ``{"t", "ego", "obstacle",
        "posterior", "brake"}`` (and ``"risk"`` with the risk rule). The file appears complete
        or not at all."""
        path = Path(path)
        lines = [json.dumps(self.trace_header(), allow_nan=False)]
        lines += [json.dumps(row, allow_nan=False) for row in self.trace]
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent if str(path.parent) else ".")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write("\n".join(lines) + "\n")
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)  # an ordinary file's mode (mkstemp's is 0600)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path


class _SceneSource:
    """Time and poses of a :class:`~cdf_mj.sim.scene.Scene` (our cars, by their joints)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.timestep = float(scene.model.opt.timestep)

    def read(self) -> tuple[float, np.ndarray]:
        return float(self.scene.data.time), self.scene.poses()


# ------------------------------------------------------------------ attach to MuJoCo
@dataclass(frozen=True)
class TrackedCar:
    """How :func:`attach` reads one car.

    Attributes:
        body: the body whose pose is the car's (default: the car's prefix + ``chassis``
            of the :class:`SceneNames`). Any body: planar or free joints, a mocap body, a
            child of other moving bodies.
        rear_axle: ``(x, y)`` [m] the rear axle's centre in that body's frame (a chassis
            origin at the car's centre: ``(-wheelbase / 2, 0)`` or so). The pose given to
            the filter is this point's.
        heading: [rad] the car's forward direction in the body frame, from the body's x
            axis about its z axis (0: x forward; ``pi / 2``: y forward).
        geometry: the car's dimensions in its rear-axle frame; default: read from the
            model's elements of our car (``front_axle``, ``hull``, ``eye``, ``accel``,
            ``steer``: :func:`cdf_mj.sim.scene.car_geometry`), which only our car has.
    """

    body: str | None = None
    rear_axle: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0
    geometry: CarGeometry | None = None

    def __post_init__(self) -> None:
        try:
            x, y = (float(v) for v in self.rear_axle)
            heading = float(self.heading)
        except (TypeError, ValueError):
            x = y = heading = math.nan
        if not all(math.isfinite(v) for v in (x, y, heading)):
            raise ValueError(f"TrackedCar: rear_axle must be (x, y) [m] and heading [rad] finite, got "
                             f"rear_axle={self.rear_axle!r}, heading={self.heading!r}")
        object.__setattr__(self, "rear_axle", (x, y))
        object.__setattr__(self, "heading", heading)
        if self.geometry is not None and not isinstance(self.geometry, CarGeometry):
            raise TypeError(f"TrackedCar: geometry must be a CarGeometry, got {type(self.geometry).__name__}")


class _BodySource:
    """Rear-axle poses of two named bodies of any kind, read from the user's ``MjData``.

    The user's data is only read: its ``qpos``, ``qvel`` and mocap poses are copied into a
    private ``MjData`` whose kinematics and velocities are computed there (exact after
    ``mj_step``, whose own derived quantities are those of the step's start). Speed is the
    rear axle's velocity along the heading; a body that no degree of freedom moves (a
    mocap body) has none in MuJoCo, so its speed is the rear axle's displacement since the
    last read along the heading over the elapsed time (0 at the first read).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, bodies: Sequence[int],
                 cars: Sequence[TrackedCar]) -> None:
        import mujoco

        self._mj = mujoco
        self.model, self.data = model, data
        self.timestep = float(model.opt.timestep)
        self.scratch = mujoco.MjData(model)
        self.bodies = list(bodies)
        self.offsets = [np.array([c.rear_axle[0], c.rear_axle[1], 0.0]) for c in cars]
        self.forward = [np.array([math.cos(c.heading), math.sin(c.heading), 0.0]) for c in cars]
        self.moved = [self._has_dofs(b) for b in self.bodies]
        self._last: tuple[float, np.ndarray] | None = None

    def _has_dofs(self, body: int) -> bool:
        """Whether any joint moves ``body`` (on it or on one of its ancestors)."""
        m = self.model
        while body > 0:
            if m.body_dofnum[body] > 0:
                return True
            body = int(m.body_parentid[body])
        return False

    def forget(self) -> None:
        """Drop the last read (after a reset: no finite difference across it)."""
        self._last = None

    def read(self) -> tuple[float, np.ndarray]:
        mj, m, d, s = self._mj, self.model, self.data, self.scratch
        s.qpos[:], s.qvel[:] = d.qpos, d.qvel
        s.mocap_pos[:], s.mocap_quat[:] = d.mocap_pos, d.mocap_quat
        mj.mj_kinematics(m, s)
        mj.mj_comPos(m, s)
        mj.mj_comVel(m, s)
        t = float(d.time)
        poses = np.zeros((2, 4))
        points = np.zeros((2, 3))
        vel = np.zeros(6)
        for i, body in enumerate(self.bodies):
            rot = s.xmat[body].reshape(3, 3)
            arm = rot @ self.offsets[i]
            points[i] = s.xpos[body] + arm
            fwd = rot @ self.forward[i]
            yaw = math.atan2(fwd[1], fwd[0])
            heading = np.array([math.cos(yaw), math.sin(yaw), 0.0])
            if self.moved[i]:
                mj.mj_objectVelocity(m, s, mj.mjtObj.mjOBJ_XBODY, body, vel, 0)  # [rot, lin] at xpos, world axes
                speed = float((vel[3:] + np.cross(vel[:3], arm)) @ heading)
            elif self._last is not None and t > self._last[0]:
                speed = float((points[i] - self._last[1][i]) @ heading / (t - self._last[0]))
            else:
                speed = 0.0
            poses[i] = (points[i, 0], points[i, 1], yaw, speed)
        self._last = (t, points)
        return t, poses


def attach(model: mujoco.MjModel, data: mujoco.MjData, names: SceneNames | None = None,
           scenario: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
           rng: np.random.Generator | int | None = None, *,
           ego: TrackedCar | CarGeometry | None = None,
           obstacle: TrackedCar | CarGeometry | None = None,
           record_trace: bool = True) -> CDFMonitor:
    """A :class:`CDFMonitor` on your model and data; :meth:`CDFMonitor.step` then reads
    the poses from ``data`` and observes them.

    The junction is read by ``names`` (routes, sites, buildings: docs/SCENES.md); each car
    by its :class:`TrackedCar` (a bare :class:`CarGeometry` is ``TrackedCar(geometry=...)``):
    its pose from a body, its dimensions as given, or else from our car's elements. With a
    geometry given nothing else of that car is read, so a wrong ``front_axle`` cannot give
    a wrong wheelbase, and a car without an eye site or a named hull is fine. ``names``
    defaults to ``scenario.names``. SceneError lists every problem of the junction; a
    missing body or car element is one SceneError naming it and the fix.
    """
    from cdf_mj.sim.checks import SceneError
    from cdf_mj.sim.scene import read_layout

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
    import mujoco

    bodies = []
    for which, car, prefix in (("ego", tracked[0], names.ego_prefix),
                               ("obstacle", tracked[1], names.obstacle_prefix)):
        body = car.body or prefix + names.chassis
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        if bid <= 0:
            raise SceneError(f"attach: the {which} car's body '{body}' is not in the model (the world "
                             f"body cannot be a car); name it with TrackedCar(body=...) or the "
                             f"{which}_prefix and chassis of SceneNames")
        bodies.append(bid)
    if bodies[0] == bodies[1]:
        raise SceneError(f"attach: ego and obstacle are both body '{model.body(bodies[0]).name}'")
    layout = read_layout(model, names, ego=tracked[0].geometry, obstacle=tracked[1].geometry)
    if data.qpos.size != model.nq or data.xpos.shape[0] != model.nbody or data.mocap_pos.shape[0] != model.nmocap:
        raise SceneError("attach: the MjData given does not belong to this model (its sizes differ)")
    source = _BodySource(model, data, bodies, tracked)
    return CDFMonitor(layout, scenario, cdf, rng, source=source, record_trace=record_trace)


# ------------------------------------------------------------------ reading a trace
class TraceError(ValueError):
    """A trace file that cannot be read: one line naming ``file:line`` and what is wrong."""


@dataclass(frozen=True)
class MonitorTrace:
    """A trace file read back (:func:`read_trace`).

    ``times`` (K,) [s]; ``poses`` (K, 2, 4) rear-axle ``[x m, y m, yaw rad, v m/s]`` of ego
    and obstacle, world frame; ``posterior`` maps ``t`` and each probability (``p_left``,
    ``p_right``, ``p_seen``, ``p_cutoff``, ``ess``, and ``risk`` for the risk rule) to (K,)
    arrays. ``rule`` is the decision rule (``threshold`` for traces written before the
    risk rule) and ``threshold`` the value at which it brakes on its quantity.
    """

    path: Path
    header: dict[str, Any]
    names: SceneNames
    ego: CarGeometry
    obstacle: CarGeometry
    tau: float
    times: np.ndarray
    poses: np.ndarray
    posterior: dict[str, np.ndarray]
    brake: np.ndarray  # (K,) bool: the brake decision per observation
    rule: str = "threshold"
    threshold: float = math.nan

    @property
    def brake_time(self) -> float | None:
        """[s] the first observation with the brake decision, None if never."""
        idx = np.flatnonzero(self.brake)
        return round(float(self.times[idx[0]]), 6) if idx.size else None


_POSTERIOR_KEYS = ("p_left", "p_right", "p_seen", "p_cutoff", "ess")


def read_trace(path: str | Path) -> MonitorTrace:
    """Read a file of :meth:`CDFMonitor.save_trace`. TraceError ``file:line: what`` for a
    file that is missing, not JSON lines, of another format, or with a bad field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TraceError(f"{path}: cannot read the trace ({getattr(exc, 'strerror', None) or exc})") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()]
    if not lines:
        raise TraceError(f"{path}:1: empty file; a trace starts with a header line ({TRACE_FORMAT})")
    rows: list[tuple[int, dict[str, Any]]] = []
    for no, line in lines:
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise TraceError(f"{path}:{no}: not JSON ({exc.msg} at column {exc.colno})") from None
        if not isinstance(obj, dict):
            raise TraceError(f"{path}:{no}: expected a JSON object, got {type(obj).__name__}")
        rows.append((no, obj))
    no, header = rows[0]
    if header.get("format") != TRACE_FORMAT:
        raise TraceError(f"{path}:{no}: not a monitor trace: the header's format is "
                         f"{header.get('format')!r}, expected {TRACE_FORMAT!r}")
    valid = [f.name for f in dataclasses.fields(SceneNames)]
    unknown = sorted(set(header.get("names") or {}) - set(valid)) if isinstance(header.get("names"), dict) else []
    if "names" in header and not isinstance(header["names"], dict):
        raise TraceError(f"{path}:{no}: the header's 'names' must be an object of SceneNames fields")
    if unknown:
        raise TraceError(f"{path}:{no}: the header's 'names' has unknown key(s) {', '.join(unknown)}; "
                         f"valid: {', '.join(valid)}")
    try:
        names = SceneNames(**header["names"])
        ego = CarGeometry.from_dict(header["ego"])
        obstacle = CarGeometry.from_dict(header["obstacle"])
        tau = float(header["tau"])
    except KeyError as exc:
        raise TraceError(f"{path}:{no}: the header lacks {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise TraceError(f"{path}:{no}: bad header: {' '.join(str(exc).split())}") from None
    rule, threshold = header.get("rule", "threshold"), header.get("threshold", tau)
    for key, value in (("tau", tau), ("threshold", threshold)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and 0.0 < value <= 1.0):
            raise TraceError(f"{path}:{no}: the header's {key!r} must be in (0, 1], got {header.get(key, value)!r}")
    if rule not in ("threshold", "risk"):
        raise TraceError(f"{path}:{no}: the header's 'rule' must be 'threshold' or 'risk', got {rule!r}")
    keys = (*_POSTERIOR_KEYS, "risk") if rule == "risk" else _POSTERIOR_KEYS
    if len(rows) < 2:
        raise TraceError(f"{path}:{no}: the trace has no observation after its header")
    times: list[float] = []
    poses: list[np.ndarray] = []
    brake: list[bool] = []
    post: dict[str, list[float]] = {k: [] for k in keys}
    for no, row in rows[1:]:
        try:
            t = float(row["t"])
            pose = np.array([row["ego"], row["obstacle"]], dtype=float)
            p = {**row["posterior"], **({"risk": row["risk"]} if rule == "risk" else {})}
            values = [float(p[k]) for k in keys]
            b = row["brake"]
        except KeyError as exc:
            raise TraceError(f"{path}:{no}: the observation lacks {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise TraceError(f"{path}:{no}: bad observation: {' '.join(str(exc).split())}") from None
        if pose.shape != (2, 4) or not np.all(np.isfinite(pose)) or not math.isfinite(t):
            raise TraceError(f"{path}:{no}: 'ego' and 'obstacle' must be 4 finite numbers each "
                             "and 't' a finite time")
        if times and t <= times[-1]:
            raise TraceError(f"{path}:{no}: time {t:g} s does not follow {times[-1]:g} s")
        if not isinstance(b, bool):
            raise TraceError(f"{path}:{no}: 'brake' must be true or false, got {b!r}")
        bad = [k for k, v in zip(keys, values, strict=True)
               if not math.isfinite(v) or (v < 0.0 if k == "ess" else not 0.0 <= v <= 1.0)]
        if bad:
            raise TraceError(f"{path}:{no}: 'posterior' has {', '.join(bad)} out of range "
                             "(probabilities in [0, 1], ess a finite number >= 0)")
        times.append(t)
        poses.append(pose)
        brake.append(b)
        for k, v in zip(keys, values, strict=True):
            post[k].append(v)
    posterior = {"t": np.array(times)} | {k: np.array(v) for k, v in post.items()}
    return MonitorTrace(path=path, header=header, names=names, ego=ego, obstacle=obstacle, tau=tau,
                        times=np.array(times), poses=np.array(poses), posterior=posterior,
                        brake=np.array(brake, dtype=bool), rule=rule, threshold=float(threshold))
