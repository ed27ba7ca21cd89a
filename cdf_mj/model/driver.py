"""Drivers: the obstacle's intent-and-belief controller and the ego's nominal controller.

The obstacle's control ``u1 = h(x1, B, I)`` (paper eq. 4) is a finite state machine over
arrays of shape ``(N, ...)``: the same compiled per-car code
(:mod:`cdf_mj.model.kernels`) drives the one simulated obstacle (N = 1) and every
particle of the filter (whose fused kernels call it particle by particle). Its belief ``B`` is a point estimate of the
ego's pose ``[x, y, theta, v]`` or nothing (``has_belief`` false); it is updated by
:func:`update_belief` (paper's ``g``): a new observation replaces it, otherwise it is
dead-reckoned at the believed speed.

Modes (``Mode``; it and ``Intent`` live in :mod:`cdf_mj.model.modes`, re-exported here):

========== ===========================================================================
WAITING    at the stop line; goes once its stop is over (``may_go``: the world's dwell
           has elapsed, or the filter's departure-hazard draw) and its belief says clear
GOING      pulling out along its route; yields if its belief says not clear
YIELDING   braking (then stopped); goes again once its belief says clear
COMMITTED  past the commit point: keeps going whatever it believes
========== ===========================================================================

"Clear" for a left-turner: no belief, or the believed ego is past the conflict point
(by ``passed_margin``), or the believed ego is further than ``clear_distance`` [m] from
the conflict point *and* needs more than the critical gap [s] to reach it. A right-turner
does not cross the ego's lane and is always clear.

The behaviour of a driver is a :class:`DriverParams`, one field per per-car trait of
:data:`cdf_mj.traits.PER_CAR`: floats for the simulated obstacle
(``DriverParams.from_config``), ``(N,)`` arrays for the filter's particles, each of which
draws its own from the filter's prior (:class:`cdf_mj.config.DriverPrior`).
"""

from __future__ import annotations

import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from cdf_mj.config import DriverPrior, Ego, ObstacleDriver, Pursuit, ScenarioConfig
from cdf_mj.model import kernels
from cdf_mj.model.geometry import Polyline
from cdf_mj.model.kernels import RouteTable, pack_driver, pack_ego
from cdf_mj.model.layout import Layout
from cdf_mj.model.modes import Intent, Mode  # re-exported: the vocabulary's home is modes
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.traits import PER_CAR, SHARED, with_traits

__all__ = [
    "DriverModel",
    "DriverParams",
    "Intent",
    "Mode",
    "bicycle_step",
    "ego_control",
    "obstacle_control",
    "obstacle_control_one",
    "pure_pursuit",
    "road_clear",
    "update_belief",
    "update_belief_one",
]


@dataclass(frozen=True)
class DriverModel:
    """Everything the drivers need: the layout's routes and points, the obstacle car's
    limits as plain floats (for the per-tick code), the tick, the route following and the
    traits shared by every car; and the same packed for the compiled kernels
    (:mod:`cdf_mj.model.kernels`): ``table`` holds the routes left, right, ego (route
    indexes 0, 1, 2) and ``cfg`` the driver's floats. ``params`` is the world's driver
    (None in the filter's model, whose particles carry their own); ``ego`` the ego's
    nominal controller (:func:`ego_control`; None where nobody drives the ego with it)."""

    routes: tuple[Polyline, Polyline]  # obstacle route per Intent
    route_ego: Polyline
    s_commit: np.ndarray  # (2,) arc length of the commit point on each obstacle route [m]
    conflict: np.ndarray  # (2,) conflict point [m]
    wheelbase: float  # [m] of the obstacle
    max_steer: float  # [rad] of the obstacle
    max_brake: float  # [m/s^2], positive
    max_accel: float  # [m/s^2]
    dt: float  # [s] the tick
    pursuit: Pursuit  # the obstacle's route following (and the ego's, in ego_control)
    shared: Mapping[str, float]  # the traits every car shares (cdf_mj.traits.SHARED): passed_margin [m], ...
    params: DriverParams | None = None  # the world's driver behaviour (floats)
    ego: Ego | None = None
    table: RouteTable = field(init=False, repr=False, compare=False)
    cfg: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        conflict, s_commit = np.asarray(self.conflict, dtype=float), np.asarray(self.s_commit, dtype=float)
        cfg = pack_driver({"dt": self.dt, "wheelbase": self.wheelbase, "max_steer": self.max_steer,
                           "max_brake": self.max_brake, "lookahead": self.pursuit.lookahead,
                           "lookahead_gain": self.pursuit.lookahead_gain, **self.shared,
                           "conflict_x": conflict[0], "conflict_y": conflict[1], "s_commit_left": s_commit[0],
                           "s_commit_right": s_commit[1]})
        cfg.flags.writeable = False
        object.__setattr__(self, "table", RouteTable.of((*self.routes, self.route_ego)))
        object.__setattr__(self, "cfg", cfg)

    @property
    def passed_margin(self) -> float:
        """[m] a believed ego past the conflict point by this is gone (a shared trait)."""
        return self.shared["passed_margin"]

    def param_rows(self, n: int) -> np.ndarray:
        """:attr:`params` as ``(n, P)`` rows for the kernels (one row kept: the world's car).
        ValueError for a model without one driver (the filter's)."""
        if self.params is None:
            raise ValueError("this driver model has no single driver (the filter's): give params")
        if n != 1:
            return self.params.rows(n)
        row: np.ndarray | None = self.__dict__.get("_param_row")
        if row is None:
            row = self.params.rows(1)
            row.flags.writeable = False
            object.__setattr__(self, "_param_row", row)
        return row

    def control_traits(self) -> tuple[float, ...]:
        """The traits of the model's one driver that :func:`cdf_mj.model.kernels.control`
        takes (acceleration, turn speed, yield brake, critical gap, clear distance), as
        Python floats, kept (the world's car reads them every tick). ValueError as
        :meth:`param_rows`."""
        kept: tuple[float, ...] | None = self.__dict__.get("_control_traits")
        if kept is None:
            kept = tuple(_CONTROL_ARGS(self.param_rows(1)[0].tolist()))
            object.__setattr__(self, "_control_traits", kept)
        return kept

    @classmethod
    def from_layout(cls, layout: Layout, driver: ObstacleDriver | DriverPrior, pursuit: Pursuit, dt: float, *,
                    ego: Ego | None = None) -> DriverModel:
        """The drivers of a junction: routes, conflict and commit points of ``layout``,
        the obstacle's limits from ``layout.obstacle``, the shared traits (``passed_margin``,
        ...; and, for the world's :class:`~cdf_mj.config.ObstacleDriver`, its behaviour
        ``params``) from ``driver``: the world's driver, or the filter's model of it
        (:class:`~cdf_mj.config.DriverPrior`); ``pursuit`` the route following, ``dt`` [s]
        the tick, ``ego`` the ego's nominal controller (for :func:`ego_control`)."""
        routes = layout.obstacle_routes
        s_commit = np.array([r.project(layout.commit)[0] for r in routes])
        car = layout.obstacle
        params = DriverParams.from_config(driver) if isinstance(driver, ObstacleDriver) else None
        return cls(routes=routes, route_ego=layout.route_ego, s_commit=s_commit,
                   conflict=layout.conflict, wheelbase=car.wheelbase, max_steer=car.max_steer,
                   max_brake=car.max_brake, max_accel=car.max_accel, dt=float(dt), pursuit=pursuit,
                   shared={name: float(getattr(driver, name)) for name in SHARED}, params=params, ego=ego)

    @classmethod
    def of_world(cls, layout: Layout, config: ScenarioConfig) -> DriverModel:
        """The world's drivers (:meth:`from_layout`): ``config``'s obstacle driver, pure
        pursuit, tick and ego."""
        return cls.from_layout(layout, config.obstacle, config.pursuit, config.timing.dt, ego=config.ego)


#: Route index of the ego's route in ``DriverModel.table``.
EGO_ROUTE = 2
#: A row of per-car traits -> the per-car arguments of :func:`cdf_mj.model.kernels.control`, in its order.
_CONTROL_ARGS = operator.itemgetter(kernels.P_ACCEL, kernels.P_TURN, kernels.P_YIELD, kernels.P_GAP, kernels.P_CLEAR)


@dataclass(frozen=True)
@with_traits("car")
class DriverParams:
    """A driver's behaviour: floats (one driver) or ``(N,)`` arrays (one per particle), one
    field per per-car trait of :data:`cdf_mj.traits.PER_CAR` (``accel`` [m/s^2],
    ``turn_speed`` [m/s], ``yield_brake`` [m/s^2], ``critical_gap`` [s], ``clear_distance``
    [m]; see :data:`cdf_mj.traits.TRAITS`), in that order."""

    if TYPE_CHECKING:  # the fields are the schema's (cdf_mj.traits.with_traits)
        def __init__(self, *values: float | np.ndarray, **traits: float | np.ndarray) -> None: ...
        def __getattr__(self, name: str) -> float | np.ndarray: ...

    def rows(self, n: int) -> np.ndarray:
        """The behaviour as an ``(n, P)`` array, columns :data:`~cdf_mj.traits.PER_CAR` (for
        the kernels)."""
        out = np.empty((n, len(PER_CAR)))
        for j, name in enumerate(PER_CAR):
            out[:, j] = getattr(self, name)
        return out

    @classmethod
    def from_config(cls, obstacle: ObstacleDriver) -> DriverParams:
        """The simulated obstacle's behaviour: the world driver's values."""
        return cls(**{name: getattr(obstacle, name) for name in PER_CAR})


def _rows(a: np.ndarray, width: int) -> np.ndarray:
    """``a`` as C-contiguous float rows ``(M, width)`` (``a`` itself if it is one)."""
    if (type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == 2 and a.shape[1] == width
            and a.flags.c_contiguous):
        return a
    return np.ascontiguousarray(np.asarray(a, dtype=float).reshape(-1, width))


def _per_row(a: np.ndarray | bool | int, n: int, dtype: type) -> np.ndarray:
    """One value per row as a C-contiguous ``(n,)`` array of ``dtype`` (``a`` itself if it
    is one: callers that write into it pass a copy)."""
    if type(a) is np.ndarray and a.dtype == dtype and a.shape == (n,) and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a), (n,)), dtype=dtype)


def bicycle_step(x: np.ndarray, u: np.ndarray, dt: float, wheelbase: float) -> np.ndarray:
    """The paper's kinematic bicycle ``f``: one explicit Euler step of length ``dt`` [s].

    ``x`` is ``(..., 4)`` = [x, y, theta, v] (rear axle, world frame); ``u`` is ``(..., 2)`` =
    [acceleration m/s^2, steering angle rad], noise already added (the two broadcast).
    Speed stays >= 0, as the cars' actuators cannot reverse.
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    lead = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    xs = _rows(np.broadcast_to(x, (*lead, 4)), 4)
    us = _rows(np.broadcast_to(u, (*lead, 2)), 2)
    out: np.ndarray = kernels.bicycle_rows(xs, us, float(dt), float(wheelbase)).reshape((*lead, 4))
    return out


def pure_pursuit(route: Polyline, pose: np.ndarray, s: np.ndarray, lookahead: np.ndarray,
                 wheelbase: float, max_steer: float) -> np.ndarray:
    """Steering angle(s) [rad] that point the rear axle at the route point ``lookahead``
    metres ahead of arc length ``s``. ``pose`` is ``(..., 4)``; ``s`` and ``lookahead``
    broadcast to its leading shape."""
    pose = np.asarray(pose, dtype=float)
    lead = pose.shape[:-1]
    table = RouteTable.of((route,))
    s_rows = np.ascontiguousarray(np.broadcast_to(np.asarray(s, dtype=float), lead)).reshape(-1)
    ahead = np.ascontiguousarray(np.broadcast_to(np.asarray(lookahead, dtype=float), lead)).reshape(-1)
    seg = np.full(s_rows.size, -1, dtype=np.int64)
    steer: np.ndarray = kernels.steer_rows(table.table, table.nseg, table.ends, 0, _rows(pose, 4), s_rows,
                                           ahead, float(wheelbase), float(max_steer), seg).reshape(lead)
    return steer


def road_clear(model: DriverModel, belief: np.ndarray, has_belief: np.ndarray,
               intent: np.ndarray, params: DriverParams | None = None) -> np.ndarray:
    """Whether each driver believes it may pull out (see the module docstring).

    ``belief`` ``(N, 4)``; ``params`` gives the critical gap [s] and clear distance [m]
    (float or ``(N,)``); default: the model's scenario. An ego nearer than the clear
    distance is never clear, so a slow or stopped ego near the conflict point (time to
    arrive ``ahead / v`` long) is not taken for a gap.
    """
    belief = _rows(belief, 4)
    n = len(belief)
    p = model.param_rows(n) if params is None else params.rows(n)
    clear: np.ndarray = kernels.clear_rows(model.cfg, belief, _per_row(has_belief, n, np.bool_),
                                           _per_row(intent, n, np.int64), p)
    return clear


def obstacle_control(model: DriverModel, pose: np.ndarray, mode: np.ndarray, belief: np.ndarray,
                     has_belief: np.ndarray, intent: np.ndarray, params: DriverParams | None = None,
                     may_go: np.ndarray | bool = True,
                     segment: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The obstacle driver ``h(x1, B, I)`` for ``N`` samples at once.

    Args:
        pose: ``(N, 4)`` own rear-axle pose [x m, y m, theta rad, v m/s], world frame.
        mode: ``(N,)`` current :class:`Mode`.
        belief: ``(N, 4)`` believed ego pose (ignored where ``has_belief`` is false).
        has_belief: ``(N,)`` whether the driver has ever seen the ego.
        intent: ``(N,)`` :class:`Intent`.
        params: behaviour, floats or ``(N,)`` arrays (default: the model's scenario).
        may_go: ``(N,)`` or one bool: whether a WAITING driver's stop is over on this tick
            (it then goes if its belief says clear); yielding drivers go again when clear.
        segment: ``(N,)`` int64, each car's route segment from its last call, updated in
            place (the projection tracks from it, :mod:`cdf_mj.model.kernels`); default:
            the full search.

    Returns:
        ``u`` ``(N, 2)`` = [acceleration m/s^2, steering rad] without process noise, and the
        new mode ``(N,)``.
    """
    pose = _rows(pose, 4)
    n = len(pose)
    belief = _rows(belief, 4)
    if segment is None:
        segment = np.full(n, -1, dtype=np.int64)
    if len(belief) != n or segment.shape != (n,) or segment.dtype != np.int64:
        raise ValueError(f"obstacle_control: {n} poses need {n} beliefs (got {len(belief)}) and an int64 "
                         f"segment array of shape ({n},) (got {segment.dtype} {segment.shape})")
    tab = model.table
    rows = model.param_rows(n) if params is None else params.rows(n)
    mode, has_belief = _per_row(mode, n, np.int64), _per_row(has_belief, n, np.bool_)
    intent, may_go = _per_row(intent, n, np.int64), _per_row(may_go, n, np.bool_)
    if n == 1:  # the simulated car, every tick
        return _one_obstacle(model, pose, mode, belief, has_belief, intent, rows, may_go, segment)
    u, new = kernels.obstacle_control_rows(tab.table, tab.nseg, tab.ends, model.cfg, pose, mode, belief, has_belief,
                                           intent, rows, may_go, segment)
    return u, new


def _one_obstacle(model: DriverModel, pose: np.ndarray, mode: np.ndarray, belief: np.ndarray,
                  has_belief: np.ndarray, intent: np.ndarray, params: np.ndarray, may_go: np.ndarray,
                  segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`obstacle_control` of one car: the per-car kernel that ``obstacle_control_rows``
    loops over (:func:`cdf_mj.model.kernels.control`), called from Python (the row loop is
    not compiled for one car)."""
    a, steer, new, segment[0] = obstacle_control_one(
        model, pose[0].tolist(), int(mode[0]), belief[0].tolist(), bool(has_belief[0]), int(intent[0]),
        bool(may_go[0]), _CONTROL_ARGS(params[0].tolist()), int(segment[0]))
    return np.array([[a, steer]]), np.array([new], dtype=np.int64)


def obstacle_control_one(model: DriverModel, pose: Sequence[float], mode: int, belief: Sequence[float],
                         has_belief: bool, intent: int, may_go: bool, traits: Sequence[float] | None = None,
                         segment: int = -1) -> tuple[float, float, int, int]:
    """:func:`obstacle_control` of one car on Python numbers (the world's car, every tick):
    its pose ``[x m, y m, theta rad, v m/s]``, :class:`Mode`, believed ego pose (read where
    ``has_belief``), :class:`Intent`, whether its stop is over, and its traits (default:
    the model's own driver, :meth:`DriverModel.control_traits`); ``segment`` is its route
    segment from the last call (-1: the full search). Returns the acceleration [m/s^2],
    steering [rad], new mode and segment: the per-car kernel that ``obstacle_control_rows``
    loops over (:func:`cdf_mj.model.kernels.control`), called from Python."""
    tab = model.table
    x, y, th, v = pose
    bx, by, bth, bv = belief
    a, steer, new, seg = kernels.control(tab.table, tab.nseg, tab.ends, model.cfg, intent, x, y, th, v, segment,
                                         mode, has_belief, bx, by, bth, bv, may_go,
                                         *(model.control_traits() if traits is None else traits))
    return a, steer, new, seg


def update_belief(belief: np.ndarray, has_belief: np.ndarray, observed: np.ndarray,
                  observation: np.ndarray, dt: float, wheelbase: float) -> tuple[np.ndarray, np.ndarray]:
    """The belief update ``g(B, O)``: take the observation where there is one, else carry
    the old belief forward by dead reckoning at its believed speed and heading (the
    bicycle of ``wheelbase`` [m] with no control: the heading stays).

    Shapes: ``belief``/``observation`` ``(N, 4)`` (one observation ``(4,)`` is shared),
    ``has_belief``/``observed`` ``(N,)``. Returns new arrays.
    """
    new = np.array(belief, dtype=float, copy=True).reshape(-1, 4)
    n = len(new)
    has = np.array(_per_row(has_belief, n, np.bool_), copy=True)
    obs = _rows(np.broadcast_to(np.asarray(observation, dtype=float), (n, 4)), 4)
    seen = _per_row(observed, n, np.bool_)
    if n == 1:  # the simulated car, every tick: believe_rows' step, its per-car helper called from Python
        update_belief_one(new, has, obs[0] if seen[0] else None, dt)
        return new, has
    kernels.believe_rows(new, has, seen, obs, float(dt))
    return new, has


def update_belief_one(belief: np.ndarray, has_belief: np.ndarray, observation: Sequence[float] | np.ndarray | None,
                      dt: float) -> None:
    """:func:`update_belief` of one driver in place: row 0 of ``belief`` ``(1, 4)`` takes
    ``observation`` (the ego's pose as observed) if there is one and ``has_belief[0]``
    becomes True; else a belief held is dead-reckoned one tick of ``dt`` [s]."""
    if observation is not None:
        belief[0] = observation
        has_belief[0] = True
    elif has_belief[0]:
        kernels.dead_reckon(belief, 0, float(dt))


def _ego_vector(model: DriverModel, car: CarGeometry) -> np.ndarray:
    """The ego controller's float vector (:func:`cdf_mj.model.kernels.pack_ego`) of
    ``model``'s ego settings and pursuit and ``car``, packed once per model and car (the
    per-tick call reuses it)."""
    kept: tuple[CarGeometry, np.ndarray] | None = model.__dict__.get("_ego_vector")
    if kept is not None and kept[0] is car:
        return kept[1]
    ego = model.ego
    if ego is None:
        raise ValueError("ego_control: this driver model has no ego settings (DriverModel.from_layout(..., ego=...))")
    vector = pack_ego({"lookahead": model.pursuit.lookahead, "lookahead_gain": model.pursuit.lookahead_gain,
                       "wheelbase": car.wheelbase, "max_steer": car.max_steer, "speed": ego.speed,
                       "speed_gain": ego.speed_gain, "max_brake": car.max_brake, "max_accel": car.max_accel})
    object.__setattr__(model, "_ego_vector", (car, vector))
    return vector


def ego_control(model: DriverModel, car: CarGeometry, pose: np.ndarray,
                brake: np.ndarray | bool) -> np.ndarray:
    """The ego's nominal controller ``h(x2, x1, I2)``: follow its route at the nominal
    speed (``model.ego``) with the model's pure pursuit, or brake at the car's maximum rate
    where ``brake``.

    ``car`` is the ego's geometry (``Layout.ego``: wheelbase, actuator limits); ``pose``
    ``(..., 4)`` ``[x m, y m, theta rad, v m/s]``, world frame; returns ``(..., 2)`` =
    [acceleration m/s^2, steering rad]. ValueError for a model built without ``ego``.
    """
    pose = np.asarray(pose, dtype=float)
    tab = model.table
    limits = _ego_vector(model, car)
    if pose.shape == (4,) and isinstance(brake, (bool, np.bool_)):  # one car, the per-tick call
        x, y, th, v = pose.tolist()
        accel, steer = kernels.ego_control(tab.table, tab.nseg, tab.ends, EGO_ROUTE, x, y, th, v, bool(brake), limits)
        return np.array([accel, steer])
    rows = _rows(pose, 4)
    brake_rows = _per_row(np.broadcast_to(brake, pose.shape[:-1]).reshape(-1), len(rows), np.bool_)
    u: np.ndarray = kernels.ego_control_rows(tab.table, tab.nseg, tab.ends, EGO_ROUTE, rows, brake_rows,
                                             limits).reshape((*pose.shape[:-1], 2))
    return u
