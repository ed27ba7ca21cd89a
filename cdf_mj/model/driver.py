"""Drivers: the obstacle's intent-and-belief controller and the ego's nominal controller.

The obstacle's control ``u1 = h(x1, B, I)`` (paper eq. 4) is a finite state machine over
arrays of shape ``(N, ...)``: the same function drives the one simulated obstacle
(N = 1) and every particle of the filter. Its belief ``B`` is a point estimate of the
ego's pose ``[x, y, theta, v]`` or nothing (``has_belief`` false); it is updated by
:func:`update_belief` (paper's ``g``): a new observation replaces it, otherwise it is
dead-reckoned at the believed speed.

Modes (``Mode``):

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

The behaviour of a driver is a :class:`DriverParams`: floats for the simulated obstacle
(``DriverParams.from_config``), ``(N,)`` arrays for the filter's particles, each of which
draws its own from the filter's prior (:class:`cdf_mj.config.DriverPrior`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.model.geometry import Polyline
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry

__all__ = [
    "DriverModel",
    "DriverParams",
    "Intent",
    "Mode",
    "bicycle_step",
    "ego_control",
    "obstacle_control",
    "pure_pursuit",
    "road_clear",
    "update_belief",
]


class Mode(IntEnum):
    """Discrete mode of the obstacle driver's finite state machine."""

    WAITING = 0
    GOING = 1
    YIELDING = 2
    COMMITTED = 3


class Intent(IntEnum):
    """The obstacle's intent, constant during an episode."""

    LEFT = 0
    RIGHT = 1


@dataclass(frozen=True)
class DriverModel:
    """Everything the drivers need: the layout's routes and points, the obstacle car's
    limits as plain floats (for the per-tick code), and the config's behaviour."""

    routes: tuple[Polyline, Polyline]  # obstacle route per Intent
    route_ego: Polyline
    s_commit: np.ndarray  # (2,) arc length of the commit point on each obstacle route [m]
    conflict: np.ndarray  # (2,) conflict point [m]
    wheelbase: float  # [m] of the obstacle
    max_steer: float  # [rad] of the obstacle
    max_brake: float  # [m/s^2], positive
    max_accel: float  # [m/s^2]
    config: ScenarioConfig

    @property
    def params(self) -> DriverParams:
        """The scenario's driver behaviour (floats), the default of the driver functions."""
        return DriverParams.from_config(self.config)

    @classmethod
    def from_layout(cls, layout: Layout, config: ScenarioConfig) -> DriverModel:
        """The drivers of a junction: routes, conflict and commit points of ``layout``,
        the obstacle's limits from ``layout.obstacle``, behaviour from ``config``."""
        routes = layout.obstacle_routes
        s_commit = np.array([r.project(layout.commit)[0] for r in routes])
        car = layout.obstacle
        return cls(routes=routes, route_ego=layout.route_ego, s_commit=s_commit,
                   conflict=layout.conflict, wheelbase=car.wheelbase, max_steer=car.max_steer,
                   max_brake=car.max_brake, max_accel=car.max_accel, config=config)


@dataclass(frozen=True)
class DriverParams:
    """A driver's behaviour: floats (one driver) or ``(N,)`` arrays (one per particle)."""

    accel: float | np.ndarray  # [m/s^2] pulling-out acceleration
    turn_speed: float | np.ndarray  # [m/s] cruise speed through and after the turn
    yield_brake: float | np.ndarray  # [m/s^2] braking when it yields, positive
    critical_gap: float | np.ndarray  # [s] the believed ego's time to arrive must exceed it
    clear_distance: float | np.ndarray  # [m] a believed ego nearer the conflict point is never clear

    @classmethod
    def from_config(cls, config: ScenarioConfig) -> DriverParams:
        """The simulated obstacle's behaviour: the scenario's values."""
        return cls(accel=config.obstacle_accel, turn_speed=config.obstacle_turn_speed,
                   yield_brake=config.obstacle_yield_brake, critical_gap=config.critical_gap,
                   clear_distance=config.clear_distance)


def bicycle_step(x: np.ndarray, u: np.ndarray, dt: float, wheelbase: float) -> np.ndarray:
    """The paper's kinematic bicycle ``f``: one explicit Euler step of length ``dt`` [s].

    ``x`` is ``(..., 4)`` = [x, y, theta, v] (rear axle, world frame); ``u`` is ``(..., 2)`` =
    [acceleration m/s^2, steering angle rad], noise already added. Speed stays >= 0,
    as the cars' actuators cannot reverse.
    """
    x = np.asarray(x, dtype=float)
    px, py, th, v = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
    step = v * dt
    out = np.empty(np.broadcast_shapes(x.shape, (*u.shape[:-1], 4)))
    out[..., 0] = px + step * np.cos(th)
    out[..., 1] = py + step * np.sin(th)
    out[..., 2] = th + step / wheelbase * np.tan(u[..., 1])
    out[..., 3] = np.maximum(v + u[..., 0] * dt, 0.0)
    return out


def pure_pursuit(route: Polyline, pose: np.ndarray, s: np.ndarray, lookahead: np.ndarray,
                 wheelbase: float, max_steer: float) -> np.ndarray:
    """Steering angle(s) [rad] that point the rear axle at the route point ``lookahead``
    metres ahead of arc length ``s``. ``pose`` is ``(..., 4)``."""
    target = route.point_at(s + lookahead)
    dx = target[..., 0] - pose[..., 0]
    dy = target[..., 1] - pose[..., 1]
    alpha = np.arctan2(dy, dx) - pose[..., 2]
    dist = np.maximum(np.hypot(dx, dy), 1e-6)
    steer: np.ndarray = np.clip(np.arctan(2.0 * wheelbase * np.sin(alpha) / dist), -max_steer, max_steer)
    return steer


# Plain ints for the hot paths (IntEnum attribute access costs a Python call each time).
_WAITING, _GOING, _YIELDING, _COMMITTED = (int(m) for m in Mode)
_LEFT, _RIGHT = int(Intent.LEFT), int(Intent.RIGHT)


def _by_intent(intent: np.ndarray, n_routes: int) -> Iterator[tuple[int, slice | np.ndarray]]:
    """``(k, rows)`` per route with samples: ``rows`` is ``slice(None)`` when every sample
    has intent ``k`` (no gather needed: one car, or particles of one intent), else a mask."""
    for k in range(n_routes):
        mask = intent == k
        if mask.all():
            yield k, slice(None)
            return
        if mask.any():
            yield k, mask


def _project_by_intent(model: DriverModel, xy: np.ndarray, intent: np.ndarray) -> np.ndarray:
    """Arc length on each sample's own route [m]."""
    s = np.empty(xy.shape[:-1])
    for k, rows in _by_intent(intent, len(model.routes)):
        s[rows] = model.routes[k].project(xy[rows])[0]
    return s


def road_clear(model: DriverModel, belief: np.ndarray, has_belief: np.ndarray,
               intent: np.ndarray, params: DriverParams | None = None) -> np.ndarray:
    """Whether each driver believes it may pull out (see the module docstring).

    ``params`` gives the critical gap [s] and clear distance [m] (float or ``(N,)``);
    default: the model's scenario. An ego nearer than the clear distance is never clear,
    so a slow or stopped ego near the conflict point (time to arrive ``ahead / v`` long)
    is not taken for a gap.
    """
    p = params or model.params
    dx = model.conflict[0] - belief[..., 0]
    dy = model.conflict[1] - belief[..., 1]
    ahead = dx * np.cos(belief[..., 2]) + dy * np.sin(belief[..., 2])  # [m] to the conflict
    passed = ahead < -model.config.passed_margin
    far = (ahead > p.clear_distance) & (ahead > p.critical_gap * np.maximum(belief[..., 3], 0.0))
    clear: np.ndarray = (~has_belief) | passed | far | (intent == _RIGHT)
    return clear


def obstacle_control(model: DriverModel, pose: np.ndarray, mode: np.ndarray, belief: np.ndarray,
                     has_belief: np.ndarray, intent: np.ndarray, params: DriverParams | None = None,
                     may_go: np.ndarray | bool = True) -> tuple[np.ndarray, np.ndarray]:
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

    Returns:
        ``u`` ``(N, 2)`` = [acceleration m/s^2, steering rad] without process noise, and the
        new mode ``(N,)``.
    """
    cfg = model.config
    p = params or model.params
    s = _project_by_intent(model, pose[:, :2], intent)
    clear = road_clear(model, belief, has_belief, intent, p)
    past_commit = s >= model.s_commit[intent]

    new = mode.copy()
    going = mode == _GOING
    new[(((mode == _WAITING) & may_go) | (mode == _YIELDING)) & clear] = _GOING
    new[(new == _GOING) & past_commit] = _COMMITTED  # before yielding: past it, no yield
    new[going & ~clear & ~past_commit] = _YIELDING

    v = pose[:, 3]
    u = np.empty((len(v), 2))
    accel = u[:, 0]
    # Moving (going or committed): towards the turn speed within the car's limits.
    np.clip((p.turn_speed - v) / cfg.dt, -model.max_brake, p.accel, out=accel)
    yielding = new == _YIELDING
    if yielding.any():
        brake = p.yield_brake
        accel[yielding] = -(brake[yielding] if isinstance(brake, np.ndarray) else brake)
    accel[new == _WAITING] = -model.max_brake

    lookahead = cfg.lookahead + cfg.lookahead_gain * v
    for k, rows in _by_intent(intent, len(model.routes)):
        u[rows, 1] = pure_pursuit(model.routes[k], pose[rows], s[rows], lookahead[rows],
                                  model.wheelbase, model.max_steer)
    return u, new


def update_belief(belief: np.ndarray, has_belief: np.ndarray, observed: np.ndarray,
                  observation: np.ndarray, dt: float, wheelbase: float) -> tuple[np.ndarray, np.ndarray]:
    """The belief update ``g(B, O)``: take the observation where there is one, else carry
    the old belief forward by dead reckoning at its believed speed and heading.

    Shapes: ``belief``/``observation`` ``(N, 4)``, ``has_belief``/``observed`` ``(N,)``.
    """
    new = belief.copy()
    if observation.shape != belief.shape:  # one observation for every driver
        observation = np.broadcast_to(observation, belief.shape)
    carry = has_belief & ~observed  # only these are dead-reckoned; the rest are replaced or kept
    if carry.any():
        rows = belief[carry]
        new[carry] = bicycle_step(rows, np.zeros((*rows.shape[:-1], 2)), dt, wheelbase)
    new[observed] = observation[observed]
    return new, has_belief | observed


def ego_control(model: DriverModel, car: CarGeometry, pose: np.ndarray,
                brake: np.ndarray | bool) -> np.ndarray:
    """The ego's nominal controller ``h(x2, x1, I2)``: follow its route at the nominal
    speed, or brake at the car's maximum rate where ``brake``.

    ``car`` is the ego's geometry (``Layout.ego``: wheelbase, actuator limits); ``pose``
    ``(..., 4)`` ``[x m, y m, theta rad, v m/s]``, world frame; returns ``(..., 2)`` =
    [acceleration m/s^2, steering rad].
    """
    cfg = model.config
    pose = np.asarray(pose, dtype=float)
    s, _ = model.route_ego.project(pose[..., :2])
    steer = pure_pursuit(model.route_ego, pose, s, cfg.lookahead + cfg.lookahead_gain * pose[..., 3],
                         car.wheelbase, car.max_steer)
    accel = np.clip(cfg.ego_speed_gain * (cfg.ego_speed - pose[..., 3]), -car.max_brake,
                    car.max_accel)
    accel = np.where(brake, -car.max_brake, accel)
    return np.stack([accel, steer], axis=-1)
