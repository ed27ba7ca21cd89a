"""A testbed at another scale: :func:`scaled` gives every configuration at a length scale
by one stated law (kinematic similarity). Re-exported by :mod:`cdf_mj.config`."""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, TypeVar

import numpy as np

from cdf_mj.traits import check as _check
from cdf_mj.traits import within as _within

__all__ = ["scaled", "unit_of"]

C = TypeVar("C")
#: Exponent of the length scale by unit under :func:`scaled`'s law (kinematic similarity).
KINEMATIC_SCALING: Mapping[str, int] = MappingProxyType(
    {"m": 1, "m/s": 1, "m/s^2": 1, "m/s^3": 1, "s": 0, "1/s": 0, "1/tick": 0, "tick": 0, "rad": 0, "1": 0})
_POSE_UNITS = ("m", "m", "rad", "m/s")  # [x, y, theta, v]
#: Units of the numbers of configurations whose fields declare none (:func:`cdf_mj.traits.bounded`
#: does): ``Class.field`` -> unit, per component for a pose (or its covariance's rows and columns).
UNITS: Mapping[str, Any] = MappingProxyType({
    "Timing.duration": "s", "RiskConfig.brake": "1", "RiskConfig.release": "1", "RiskConfig.latency": "s",
    "RiskConfig.horizon": "s", "RiskConfig.margin": "m", "CDFConfig.n_particles": "1",
    "CDFConfig.likelihood_std": _POSE_UNITS, "CDFConfig.likelihood_cov": (_POSE_UNITS, _POSE_UNITS),
    "CDFConfig.tau": "1", "CDFConfig.resample_ess_fraction": "1", "CDFConfig.reinit_mahalanobis": "1",
    "CDFConfig.process_noise_scale": "1", "CDFConfig.mode_jump": "1/tick", "CDFConfig.intent_floor": "1",
    "CDFConfig.param_jitter": "1", "CDFConfig.ego_brake": "m/s^2", "CDFConfig.ego_latency": "s",
    "AdaptiveConfig.n_min": "1"})


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
                             "(cdf_mj.traits.bounded, or cdf_mj.config.scale.UNITS)")
        elif unit != "1" and KINEMATIC_SCALING.get(unit) != 0:  # what scales (a count stays an int)
            k = _factor(unit, length_scale)
            if isinstance(value, numbers.Real):
                changes[f.name] = value * k
            elif np.ndim(k) == 2:  # a pose's covariance
                changes[f.name] = tuple(tuple(float(x) for x in row) for row in np.asarray(value, dtype=float) * k)
            else:  # a pose (a factor per component) or a (low, high) pair
                changes[f.name] = tuple(float(v) * float(kv) for v, kv in
                                        zip(value, np.broadcast_to(k, (len(value),)), strict=True))
    return dataclasses.replace(config, **changes)  # type: ignore[type-var]
