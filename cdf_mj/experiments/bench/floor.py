"""The physics floor every bench row is timed against, and the clocks it is timed with.

A floor sample (:class:`FloorProbe`) is one timed block of ``substeps`` ``mj_step`` (one
planner tick of physics) on the scene with both cars apart at their start;
:class:`PhysicsFloor` is the least of them per step. :data:`CLOCKS` are the clocks a bench
times with (:data:`DEFAULT_CLOCK`: this process's CPU time where it ticks finely enough).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import mujoco

from cdf_mj.config import ScenarioConfig
from cdf_mj.sim.checks import substeps
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["CLOCKS", "DEFAULT_CLOCK", "Clock", "FloorProbe", "PhysicsFloor", "load_scene", "physics_floor",
           "put_at_start"]

Clock = Literal["cpu", "wall"]
#: The clocks a bench times with [s]: this process's CPU time, or wall time.
CLOCKS: dict[str, Callable[[], float]] = {"cpu": time.process_time, "wall": time.perf_counter}
#: The default clock: CPU time where it ticks finely enough to time a block of physics
#: (Linux, macOS: nanoseconds), else wall time (Windows' is 15.6 ms).
DEFAULT_CLOCK: Clock = "cpu" if time.get_clock_info("process_time").resolution <= 1e-6 else "wall"


@dataclass(frozen=True)
class PhysicsFloor:
    """What physics alone costs per planner tick: ``substeps`` MuJoCo steps (``dt /
    timestep``), both cars apart and at speed (no contacts).

    ``samples`` are the floor samples [s] it was read from, each one timed block of
    ``substeps`` steps; ``step`` is the least of them over ``substeps`` (a floor built
    from a step time alone has no samples).
    """

    step: float  # [s] one mj_step (two cars): the least floor sample over substeps
    substeps: int  # physics steps per planner tick
    samples: tuple[float, ...] = ()  # [s] floor samples, one planner tick of physics each, in order
    clock: Clock = "cpu"  # what the samples were timed with (CLOCKS)

    @property
    def tick(self) -> float:
        """[s] physics of one planner tick: the floor under any tick of an episode."""
        return self.step * self.substeps

    @classmethod
    def of(cls, samples: Sequence[float], substeps: int, clock: Clock = "cpu") -> PhysicsFloor:
        """The floor of ``samples`` [s] (at least one), blocks of ``substeps`` steps each
        timed with ``clock``."""
        if not samples:
            raise ValueError("a physics floor needs at least one sample")
        return cls(min(samples) / substeps, substeps, tuple(samples), clock)


class FloorProbe:
    """Takes floor samples on its own copy of ``scene`` (so that it disturbs no world a
    row runs on): each one the wall time [s] of ``substeps`` ``mj_step`` (one planner tick
    of ``config.timing.dt``), both cars put back at their start first (untimed), the ego at
    its nominal speed and the obstacle at rest. Keeps every sample of the run.

    ``clock`` (:data:`CLOCKS`) times the samples, and every row timed against them
    (:attr:`time`)."""

    def __init__(self, scene: str | Path = DEFAULT_SCENE, config: ScenarioConfig | None = None,
                 clock: Clock = "cpu") -> None:
        if clock not in CLOCKS:
            raise ValueError(f"unknown clock {clock!r}: expected one of {', '.join(CLOCKS)}")
        self.clock: Clock = clock
        self.time = CLOCKS[clock]  # [s] the clock's reading now
        self.world, self.config = load_scene(scene, config)
        self.substeps = substeps(self.world.model.opt.timestep, self.config.timing.dt, self.world.source)
        self.samples: list[float] = []

    def block(self) -> float:
        """One floor sample [s], kept."""
        m, d, n, clock = self.world.model, self.world.data, self.substeps, self.time
        put_at_start(self.world, self.config)
        t0 = clock()
        for _ in range(n):
            mujoco.mj_step(m, d)
        sec = clock() - t0
        self.samples.append(sec)
        return sec

    def take(self, blocks: int = 1) -> float:
        """The least of ``blocks`` floor samples [s] taken now (all kept)."""
        return min(self.block() for _ in range(max(blocks, 1)))

    def floor(self) -> PhysicsFloor:
        """The floor of every sample so far (taking one if there is none)."""
        if not self.samples:
            self.block()
        return PhysicsFloor.of(self.samples, self.substeps, self.clock)


def physics_floor(scene: str | Path = DEFAULT_SCENE, config: ScenarioConfig | None = None,
                  repeats: int = 200, clock: Clock = "cpu") -> PhysicsFloor:
    """The floor of ``repeats`` floor samples (:class:`FloorProbe`) taken in a row on
    ``scene`` with ``config`` and timed with ``clock``, after one untimed warm-up sample."""
    probe = FloorProbe(scene, config, clock)
    probe.block()
    probe.samples.clear()
    for _ in range(max(repeats, 1)):
        probe.block()
    return probe.floor()


def load_scene(scene: str | Path, config: ScenarioConfig | None) -> tuple[Scene, ScenarioConfig]:
    """``scene`` (an MJCF path) loaded with the names of ``config`` (default
    ``ScenarioConfig()``), and that config."""
    cfg = config or ScenarioConfig()
    return Scene.load(scene, names=cfg.names), cfg


def put_at_start(world: Scene, cfg: ScenarioConfig) -> None:
    """Both cars at their start sites, the ego at its nominal speed, the obstacle at rest."""
    layout = world.layout()
    ego = layout.ego_start.copy()
    ego[3] = cfg.ego.speed
    world.reset(ego, layout.obstacle_start)
