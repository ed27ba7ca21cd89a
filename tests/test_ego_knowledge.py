"""Planners and the monitor are told only what an ego can know.

Every registered planner and the monitor are run twice on the same measurements: once
told the default world, once told a world whose every field about the obstacle driver
(its intent prior, beta, acceleration, turn speed, gaps, dwell, look-ahead, its
observation and process noise) is NaN. Their decisions and summaries must not change:
a planner that read any of those fields would decide differently, or raise.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.planners.base import PlannerContext, PlannerInput
from cdf_mj.planners.registry import PLANNERS, make_planner
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.sim.scene import Scene

#: What the ego knows of the world's configuration: its tick, its own controller, the names.
EGO_FIELDS = {"timing", "ego", "names", "dt", "duration", "ego_speed", "ego_speed_gain", "ego_start_spread"}


def _poisoned(value: Any) -> Any:
    """A number or tuple of numbers as NaN (the same shape)."""
    if isinstance(value, tuple):
        return tuple(_poisoned(v) for v in value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return math.nan
    return value


def poison(config: Any, keep: set[str] = EGO_FIELDS) -> Any:
    """A copy of ``config`` with every numeric field outside ``keep`` NaN, nested groups
    included, bypassing validation (as a buggy caller or a corrupted file could)."""
    out = dataclasses.replace(config) if dataclasses.is_dataclass(config) else config
    for f in dataclasses.fields(out):
        if f.name in keep:
            continue
        value = getattr(out, f.name)
        new = poison(value, set()) if dataclasses.is_dataclass(value) else _poisoned(value)
        object.__setattr__(out, f.name, new)
    return out


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene.load()


@pytest.fixture(scope="module")
def measurements(scene: Scene) -> list[PlannerInput]:
    """The measured system poses of a Cutoff seed (the obstacle pulls out), per tick."""
    rec = run_episode(ScenarioConfig(), seed=1, planner="constant", scene=scene, label=False, trace=True)
    assert rec.trace is not None
    times, poses = rec.trace["t"], np.asarray(rec.trace["poses"])
    return [PlannerInput(t=t, poses=p, obstacle_in_lane=False) for t, p in zip(times, poses, strict=True)]


def _decisions(name: str, context: PlannerContext, inputs: list[PlannerInput]) -> tuple[list[bool], Any]:
    planner = make_planner(name)
    planner.reset(context, np.random.default_rng(5))
    return [bool(planner.brake(m)) for m in inputs], planner.summary()


def _leaves(value: Any) -> list[Any]:
    if dataclasses.is_dataclass(value):
        return [v for f in dataclasses.fields(value) for v in _leaves(getattr(value, f.name))]
    return [v for item in value for v in _leaves(item)] if isinstance(value, tuple) else [value]


def test_the_poisoned_world_is_poisoned():
    bad = poison(ScenarioConfig())
    leaves = [v for f in dataclasses.fields(bad) if f.name not in EGO_FIELDS for v in _leaves(getattr(bad, f.name))]
    numbers = [v for v in leaves if isinstance(v, float)]
    assert len(numbers) >= 20 and all(math.isnan(v) for v in numbers)
    assert bad.timing == ScenarioConfig().timing and bad.ego == ScenarioConfig().ego


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_no_planner_reads_a_field_of_the_world_driver(name, scene, measurements):
    layout = scene.layout()
    told = _decisions(name, PlannerContext.of(layout, ScenarioConfig()), measurements)
    poisoned = _decisions(name, PlannerContext.of(layout, poison(ScenarioConfig())), measurements)
    assert poisoned == told
    if name in ("cdf", "imm", "cdf-threshold"):
        assert any(told[0]), f"{name} should brake on this cut-off, or the test shows nothing"


def test_the_monitor_reads_no_field_of_the_world_driver(scene, measurements):
    layout = scene.layout()
    runs = []
    for config in (ScenarioConfig(), poison(ScenarioConfig())):
        monitor = CDFMonitor(layout, config, rng=3, record_trace=False)
        runs.append([(d.brake, d.posterior.p_cutoff) for m in measurements
                     for d in [monitor.observe(m.t, m.poses[0], m.poses[1])]])
    assert runs[0] == runs[1] and any(brake for brake, _ in runs[0])
