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
import json
from collections.abc import Mapping
from typing import Any

from cdf_mj.config.cdf import AdaptiveConfig, CDFConfig, DriverPrior, LayeredConfig, RiskConfig
from cdf_mj.config.scale import scaled, unit_of
from cdf_mj.config.scenario import (
    AFTER_MERGE,
    DRIVER_FAMILIES,
    FLAT_KEYS,
    GROUPS,
    MAX_ACCEL,
    MAX_BRAKE,
    MAX_DURATION,
    MAX_EPISODES,
    MAX_LENGTH,
    MAX_PARTICLES,
    MAX_SEED,
    MAX_SPEED,
    MAX_START_SPREAD,
    MAX_TOLD_LATENCY,
    MAX_TOLD_STD,
    MAX_WORKERS,
    SCENARIO_KEYS,
    AfterMerge,
    Ego,
    FlatKeyWarning,
    Observation,
    ObstacleDriver,
    ProcessNoise,
    Pursuit,
    ScenarioConfig,
    SceneNames,
    Sensing,
    Timing,
    check_seed,
    scenario_key,
)

__all__ = [
    "AFTER_MERGE",
    "DRIVER_FAMILIES",
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
    "MAX_TOLD_LATENCY",
    "MAX_TOLD_STD",
    "MAX_WORKERS",
    "SCENARIO_KEYS",
    "AdaptiveConfig",
    "AfterMerge",
    "CDFConfig",
    "DriverPrior",
    "Ego",
    "FlatKeyWarning",
    "LayeredConfig",
    "Observation",
    "ObstacleDriver",
    "ProcessNoise",
    "Pursuit",
    "RiskConfig",
    "ScenarioConfig",
    "SceneNames",
    "Sensing",
    "Timing",
    "check_seed",
    "normalise_settings",
    "scaled",
    "scenario_key",
    "unit_of",
]

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
