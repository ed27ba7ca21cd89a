"""What the two baseline predictors (:mod:`cdf_mj.planners.cv`, :mod:`cdf_mj.planners.imm`)
share: the checks of their parameters, their predicted paths and box test in NumPy (the
references of their compiled twins in :mod:`cdf_mj.planners.baseline_kernels`), their
look-ahead times, and the rule each decides by (:func:`baseline_rule`, with
:data:`BASELINE_LAYERS` and :data:`IMM_LAYERS` for the layered rule of ``cv-layered`` and
``imm-layered``).

Frames and units: world frame (x east, y north), metres, seconds, radians; poses are
rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from cdf_mj.config import LayeredConfig, RiskConfig
from cdf_mj.model.geometry import Polyline, boxes_overlap
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.planners.base import DecisionRule, as_config
from cdf_mj.planners.decision import LayeredRule, RiskRule

__all__ = ["BASELINE_LAYERS", "IMM_LAYERS", "baseline_rule", "check_field", "finite_number", "first_conflict",
           "look_ahead_times", "route_heading", "straight_path"]


def check_field(ok: bool, name: str, value: object, allowed: str) -> None:
    """ValueError ``NAME=VALUE is out of range: must be ALLOWED`` unless ``ok`` (a
    parameter's check)."""
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range: must be {allowed}")


def finite_number(v: object) -> bool:
    """Whether ``v`` is a finite int or float (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def first_conflict(ego_car: CarGeometry, obstacle_car: CarGeometry, ego_path: np.ndarray,
                   obstacle_path: np.ndarray, margin: float, dt: float) -> float | None:
    """Time [s] from now of the first predicted overlap of the two collision boxes, the
    obstacle's widened by ``margin`` [m] on each side, or ``None`` within the paths.

    ``ego_path``/``obstacle_path`` are ``(K, 4)`` predicted poses ``[x, y, theta, v]``
    (world frame) at ``0, dt, ..., (K-1) dt`` [s]; the cars' footprints come from their
    geometries (``Layout.ego``, ``Layout.obstacle``).
    """
    wide = dataclasses.replace(obstacle_car, hull_half=obstacle_car.hull_half + margin)
    hit = boxes_overlap(ego_car.footprint(ego_path), wide.footprint(obstacle_path))
    k = np.flatnonzero(hit)
    return round(float(k[0] * dt), 6) if k.size else None


def straight_path(pose: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses ``(K, 4)`` of a car holding its heading and speed from ``pose`` at ``times`` [s]
    (the planners run its compiled twin, :func:`cdf_mj.planners.baseline_kernels.straight_path`)."""
    x, y, th, v = (float(p) for p in pose)
    d = max(v, 0.0) * np.asarray(times, dtype=float)
    out = np.empty((len(d), 4))
    out[:, 0] = x + d * math.cos(th)
    out[:, 1] = y + d * math.sin(th)
    out[:, 2] = th
    out[:, 3] = v
    return out


def route_heading(route: Polyline, s: np.ndarray | float, window: float = 0.5) -> np.ndarray:
    """Heading [rad] of ``route`` at arc length(s) ``s`` [m]: the direction of the chord of
    length ``2 window`` [m] centred on ``s`` (shifted inside the route near its ends). The
    planners compute it compiled, in :func:`cdf_mj.planners.baseline_kernels.route_path`."""
    s = np.asarray(s, dtype=float)
    w = min(window, 0.5 * route.length)
    lo = route.point_at(np.clip(s - w, 0.0, route.length - 2 * w))
    hi = route.point_at(np.clip(s + w, 2 * w, route.length))
    heading: np.ndarray = np.arctan2(hi[..., 1] - lo[..., 1], hi[..., 0] - lo[..., 0])
    return heading


def look_ahead_times(horizon: float, dt: float) -> np.ndarray:
    """Look-ahead times ``0, dt, ...`` [s] up to ``horizon`` [s] (inclusive within rounding)."""
    return np.arange(math.floor(horizon / dt + 1e-9) + 1) * dt


#: The layered rule of ``cv-layered``, chosen on seeds 0-199 by the declared objective of
#: scripts/tune_option.py (the one that chose the CDF's and the IMM's): with one hypothesis
#: (a risk is 0 or 1) every candidate gave the same collisions, interventions and time lost,
#: and the tie-break (the smaller threshold) chose version 0.3's anticipation at 0.1.
BASELINE_LAYERS = LayeredConfig(anticipation="go", anticipate=0.1, anticipate_release=0.05)
#: The layered rule of ``imm-layered``, chosen by the same objective: the option rule
#: (slow once going on 0.5 s more would lose the comfortable brake's option with
#: probability 0.9); every candidate had the same one collision on the development seeds.
IMM_LAYERS = LayeredConfig(anticipation="option", option_time=0.5, anticipate=0.9, anticipate_release=0.45)


def baseline_rule(risk: RiskConfig | Mapping[str, Any] | None, layered: LayeredConfig | Mapping[str, Any] | None,
                  otherwise: DecisionRule) -> DecisionRule:
    """The layered rule where ``layered`` is given (with ``risk`` for its emergency layer),
    else the risk rule where ``risk`` is, else ``otherwise`` (the predictor's threshold rule)."""
    if layered is not None:
        return LayeredRule(as_config(layered, LayeredConfig, "layered"), as_config(risk, RiskConfig, "risk"))
    return RiskRule(as_config(risk, RiskConfig, "risk")) if risk is not None else otherwise
