"""Benchmarks timed against a physics floor measured at the same moments (the machine is
shared and noisy).

    cdf-mj bench                    # physics, rays, filter stages at N = 250/1000/10000, planners
    cdf-mj bench --reproduce        # and the paper's reproduction with 1 and 2 workers

Every row is a set of interleaved repeats: after each timed repeat of the row, a floor
sample (:class:`FloorProbe`: one timed block of ``substeps`` ``mj_step``, one planner tick
of physics, on the scene with both cars apart at their start). A row reports the minimum
of its times, their median and interquartile range, and its ratio to the floor (``x
floor``): its least time per planner tick over the least floor sample taken between its
repeats, with the median and spread of the paired ratios (each repeat over the floor
sample(s) right after it). A slow moment of the host then slows a row and its floor
together; the minimum of each is what the code costs when nothing else runs (pin the
process to one core with ``taskset -c 0``).

The clock (:data:`CLOCKS`) is by default the CPU time of this process
(``time.process_time``): on a shared core, a process that takes turns with others is
stalled for whole scheduler slices, which a timed block longer than a slice (an episode, a
filter replay) almost always contains and a floor sample (0.1 ms) almost never does, so
that wall times would swell the rows and not the floor. ``clock="wall"`` times wall
seconds (``time.perf_counter``), as the bench did before. The reproduction rows are wall
times whatever the clock (they measure parallel workers); the startup rows, with the CPU
clock, are the CPU time of their child processes.

Per planner tick: a per-tick row (a filter tick, an env step) or a per-call row (one call
a tick) as it is, an episode row per tick of its episodes, a reproduction row per recorded
tick, a one-off cost (startup, compiling) as a whole. The reproduction rows are wall times
of whole runs, with the parallel efficiency ``T(1) / (k T(k))`` and the peak resident
memory of a worker; the startup rows (:func:`bench_startup`) are times of fresh Python
processes.

Rows that a target of issue 27 is read off carry a :class:`Reading`; :func:`format_rows`
prints the targets first (:data:`GOALS`: one line each, met or MISSED), then every row, and
under the table a check that the floor stayed under the physics-tick row
(:func:`floor_check`).
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import mujoco
import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.checks import substeps
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene
from cdf_mj.sim.visibility import ego_visible, isovist

__all__ = [
    "CLOCKS",
    "DEFAULT_CLOCK",
    "GOALS",
    "FloorProbe",
    "Goal",
    "PhysicsFloor",
    "Reading",
    "Row",
    "bench_core",
    "bench_env",
    "bench_filter",
    "bench_planners",
    "bench_reproduction",
    "bench_startup",
    "floor_check",
    "format_rows",
    "format_targets",
    "physics_floor",
]

_T = TypeVar("_T")

PHYSICS_TICK_ROW = "planner tick of physics"  # the start of the row the floor must stay under

Clock = Literal["cpu", "wall"]
# The clocks a bench times with [s]: this process's CPU time, or wall time.
CLOCKS: dict[str, Callable[[], float]] = {"cpu": time.process_time, "wall": time.perf_counter}
#: The default clock: CPU time where it ticks finely enough to time a block of physics
#: (Linux, macOS: nanoseconds), else wall time (Windows' is 15.6 ms).
DEFAULT_CLOCK: Clock = "cpu" if time.get_clock_info("process_time").resolution <= 1e-6 else "wall"
_CLOCK_WORDS = {"cpu": "CPU time of this process (time.process_time; the startup rows: of their child processes)",
                "wall": "wall time (time.perf_counter)"}


def _quartiles(xs: Sequence[float]) -> tuple[float, float, float]:
    """First quartile, median and third quartile of ``xs`` (all three the value if one)."""
    if len(xs) == 1:
        return xs[0], xs[0], xs[0]
    q1, q2, q3 = statistics.quantiles(xs, n=4, method="inclusive")
    return q1, q2, q3


def _iqr(xs: Sequence[float]) -> float:
    """Interquartile range of ``xs`` over their median [fraction] (0 for one value)."""
    q1, q2, q3 = _quartiles(xs)
    return (q3 - q1) / q2 if q2 > 0 else 0.0


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
        self.world, self.config = _setup(scene, config)
        self.substeps = substeps(self.world.model.opt.timestep, self.config.timing.dt, self.world.source)
        self.samples: list[float] = []

    def block(self) -> float:
        """One floor sample [s], kept."""
        m, d, n, clock = self.world.model, self.world.data, self.substeps, self.time
        _at_start(self.world, self.config)
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


@dataclass(frozen=True)
class Reading:
    """A target (a :class:`Goal`, by its ``what``) read off the row that carries it:
    ``value`` in the goal's unit where the row's times alone do not give it (x real time,
    MB, %), and how it was measured, in words (``text``)."""

    goal: str
    value: float | None = None
    text: str = ""


@dataclass(frozen=True)
class Row:
    """One row of the table: the wall times [s] of its interleaved repeats and the floor
    samples [s] taken right after each.

    ``per_tick``: each repeat's time per planner tick [s], where a repeat is several
    ticks (episodes, a reproduction run); empty where the time of a repeat is already one
    tick's or one call's (or a one-off cost, compared whole). ``floor``: one floor sample
    per repeat (the least of those taken right after it), or empty (a row timed apart
    from the probe: its ratio is against the run's floor).
    """

    what: str
    times: tuple[float, ...]
    note: str = ""
    per_tick: tuple[float, ...] = ()
    floor: tuple[float, ...] = ()
    readings: tuple[Reading, ...] = ()

    def __post_init__(self) -> None:
        if not self.times:
            raise ValueError(f"row {self.what!r} has no times")
        for name in ("per_tick", "floor"):
            if getattr(self, name) and len(getattr(self, name)) != len(self.times):
                raise ValueError(f"row {self.what!r}: {len(getattr(self, name))} {name} for {len(self.times)} times")

    @property
    def seconds(self) -> float:
        """[s] the least time of a repeat."""
        return min(self.times)

    @property
    def median(self) -> float:
        """[s] the median time of a repeat."""
        return statistics.median(self.times)

    @property
    def spread(self) -> float:
        """Interquartile range of the times over their median [fraction]."""
        return _iqr(self.times)

    def _per_tick(self) -> tuple[float, ...]:
        return self.per_tick or self.times

    def floor_tick(self, run: PhysicsFloor | None = None) -> float:
        """[s] the floor this row divides by: the least of its own floor samples, else the
        run's floor ``run`` (ValueError without either)."""
        if self.floor:
            return min(self.floor)
        if run is None:
            raise ValueError(f"row {self.what!r} has no floor samples of its own and no run floor was given")
        return run.tick

    def ratio(self, run: PhysicsFloor | None = None) -> float:
        """``x floor``: the least time per planner tick over :meth:`floor_tick`."""
        return min(self._per_tick()) / max(self.floor_tick(run), 1e-12)  # (a clock too coarse reads 0)

    def paired_ratios(self, run: PhysicsFloor | None = None) -> tuple[float, ...]:
        """Each repeat's time per planner tick over the floor sample taken right after it
        (over :meth:`floor_tick` for a row without floor samples)."""
        if self.floor:
            return tuple(t / max(f, 1e-12) for t, f in zip(self._per_tick(), self.floor, strict=True))
        return tuple(t / max(self.floor_tick(run), 1e-12) for t in self._per_tick())


@dataclass(frozen=True)
class Goal:
    """A target of issue 27: ``quantity op bound``, read off a row by a :class:`Reading`.

    ``quantity``: ``"x floor"`` (the row's :meth:`Row.ratio`), ``"time"`` (its least
    time [s]), ``"steps/s"`` (one over its least time), or one the reading gives:
    ``"x real time"`` (simulated over wall seconds), ``"MB"`` (10^6 bytes), ``"%"``.
    """

    what: str
    quantity: Literal["x floor", "time", "steps/s", "x real time", "MB", "%"]
    op: Literal["<=", "<", ">="]
    bound: float

    @property
    def text(self) -> str:
        """The target in words, e.g. ``<= 2x floor``."""
        seconds = f"{self.bound * 1e3:g} ms" if self.bound < 1 else f"{self.bound:g} s"
        bound = {"x floor": f"{self.bound:g}x floor", "time": seconds,
                 "steps/s": f"{self.bound:g} steps/s", "x real time": f"{self.bound:g}x real time",
                 "MB": f"{self.bound:g} MB", "%": f"{self.bound:g} %"}[self.quantity]
        return f"{self.op} {bound}"

    def met(self, value: float) -> bool:
        """Whether ``value`` (in the goal's quantity) meets it (a NaN never does)."""
        if math.isnan(value):
            return False
        return value <= self.bound if self.op == "<=" else value < self.bound if self.op == "<" else value >= self.bound

    def value(self, row: Row, reading: Reading, run: PhysicsFloor | None) -> float:
        """The measured value of ``reading`` off ``row``, in the goal's quantity."""
        if self.quantity == "x floor":
            return row.ratio(run)
        if self.quantity == "time":
            return row.seconds
        if self.quantity == "steps/s":
            return 1.0 / row.seconds
        if reading.value is None:
            raise ValueError(f"a reading of {self.what!r} ({self.quantity}) needs its value")
        return reading.value


# The targets of issue 27, in its order (and two of issue 16 from the reproduction rows).
GOALS: tuple[Goal, ...] = (
    Goal("filter tick + decision, N = 1000", "x floor", "<=", 2.0),
    Goal("filter tick + decision, N = 10 000", "time", "<=", 1e-3),
    Goal("CDF episode (planner cdf)", "x real time", ">=", 300.0),
    Goal("imm episode", "x real time", ">=", 200.0),
    Goal("imm-risk episode", "x real time", ">=", 200.0),
    Goal("cv-risk episode", "x real time", ">=", 200.0),
    Goal("Gymnasium env step without the filter", "x floor", "<=", 1.5),
    Goal("env step with the filter", "steps/s", ">=", 3000.0),
    Goal("cold start with an empty Numba cache", "time", "<", 5.0),
    Goal("memory per worker", "MB", "<=", 300.0),
    Goal("parallel efficiency at 2 workers", "%", ">=", 90.0),
)
_GOAL = {g.what: g for g in GOALS}


def _reading(goal: str, value: float | None = None, text: str = "") -> Reading:
    """A reading of the goal called ``goal`` (KeyError for a goal not in :data:`GOALS`)."""
    return Reading(_GOAL[goal].what, value, text)


def _interleaved(fn: Callable[[int], _T], repeats: int, probe: FloorProbe,
                 blocks: int = 1) -> tuple[list[float], list[_T], list[float]]:
    """Times [s] (``probe``'s clock) and results of ``fn(i)`` for i in range(repeats), after
    one warm-up call, each followed by ``blocks`` floor samples (their least is that repeat's floor)."""
    fn(-1)
    probe.take(blocks)
    clock = probe.time
    times, results, floors = [], [], []
    for i in range(repeats):
        t0 = clock()
        result = fn(i)
        times.append(clock() - t0)
        results.append(result)
        floors.append(probe.take(blocks))
    return times, results, floors


def _timed_row(what: str, fn: Callable[[int], object], repeats: int, probe: FloorProbe, note: str = "",
               readings: tuple[Reading, ...] = ()) -> Row:
    """A row of ``repeats`` calls of ``fn(i)`` (after a warm-up call), a floor sample after each."""
    times, _, floors = _interleaved(fn, repeats, probe)
    return Row(what, tuple(times), note, floor=tuple(floors), readings=readings)


def _one_off(what: str, sec: float, note: str, probe: FloorProbe, per_tick: float | None = None,
             readings: tuple[Reading, ...] = (), blocks: int = 10) -> Row:
    """A row of one run that took ``sec`` [s], with the least of ``blocks`` floor samples
    taken right after it."""
    return Row(what, (sec,), note, () if per_tick is None else (per_tick,), (probe.take(blocks),), readings)


def _ticks(end_time: float, dt: float) -> int:
    """Planner ticks of ``dt`` [s] in an episode that ended at ``end_time`` [s] (at least 1)."""
    return max(round(end_time / dt), 1)


@dataclass
class _Passes:
    """Episodes timed in passes over the same seeds, floor samples after each episode."""

    walls: list[float] = field(default_factory=list)  # [s] of each pass (all its episodes; the probe's clock)
    ticks: list[int] = field(default_factory=list)  # planner ticks of each pass
    simulated: list[float] = field(default_factory=list)  # [s] simulated time of each pass
    floor: list[float] = field(default_factory=list)  # [s] the least floor sample of each pass
    speeds: list[float] = field(default_factory=list)  # simulated over timed seconds of each episode

    def row(self, what: str, seeds: int, note: str = "", readings: tuple[Reading, ...] = ()) -> Row:
        """The row: each pass's mean time an episode, and per tick."""
        return Row(what, tuple(w / seeds for w in self.walls), note,
                   tuple(w / t for w, t in zip(self.walls, self.ticks, strict=True)), tuple(self.floor), readings)

    @property
    def fastest(self) -> float:
        """x real time of the fastest pass: its simulated over its timed seconds."""
        return max(s / w for s, w in zip(self.simulated, self.walls, strict=True))

    @property
    def median_speed(self) -> float:
        """x real time, the median over every episode of every pass (as before passes)."""
        return statistics.median(self.speeds)


def _episode_passes(fn: Callable[[int], EpisodeRecord], seeds: Sequence[int], passes: int, dt: float,
                    probe: FloorProbe) -> _Passes:
    """Time ``fn(seed)`` for every seed, ``passes`` times over (a pass over all seeds, then
    the next) with ``probe``'s clock, after one warm-up episode on ``seeds[0] - 1``; 3 floor samples after each
    episode (a pass's floor: the least of its samples)."""
    fn(seeds[0] - 1)
    out = _Passes()
    clock = probe.time
    for _ in range(passes):
        wall, ticks, sim, floor = 0.0, 0, 0.0, math.inf
        for seed in seeds:
            t0 = clock()
            rec = fn(seed)
            sec = clock() - t0
            floor = min(floor, probe.take(3))
            wall, ticks, sim = wall + sec, ticks + _ticks(rec.end_time, dt), sim + rec.end_time
            out.speeds.append(rec.end_time / max(sec, 1e-9))
        out.walls.append(wall)
        out.ticks.append(ticks)
        out.simulated.append(sim)
        out.floor.append(floor)
    return out


def _setup(scene: str | Path, config: ScenarioConfig | None) -> tuple[Scene, ScenarioConfig]:
    cfg = config or ScenarioConfig()
    return Scene.load(scene, names=cfg.names), cfg


def _at_start(world: Scene, cfg: ScenarioConfig) -> None:
    """Both cars at their start sites, the ego at its nominal speed, the obstacle at rest."""
    layout = world.layout()
    ego = layout.ego_start.copy()
    ego[3] = cfg.ego.speed
    world.reset(ego, layout.obstacle_start)


def bench_core(episodes: int = 10, scene: str | Path = DEFAULT_SCENE,
               config: ScenarioConfig | None = None, probe: FloorProbe | None = None,
               repeats: int = 3) -> list[Row]:
    """Rows for the scenario's building blocks, on ``scene`` (an MJCF path) with ``config``:
    the floor itself (``100 * repeats`` floor samples in a row), one ``mj_step``, a planner
    tick of physics, the sight lines and the isovist (``100 * repeats`` calls each), and
    two labelled episodes of ``episodes`` seeds in ``repeats`` passes; the floor samples
    from ``probe`` (a new one if not given)."""
    probe = probe or FloorProbe(scene, config)
    world, cfg = _setup(scene, config)
    layout = world.layout()
    n_sub, calls = probe.substeps, 100 * repeats
    probe.block()  # warm-up
    floor = tuple(probe.block() for _ in range(calls))
    rows: list[Row] = [
        Row("mj_step (two cars): a floor sample over its steps", tuple(f / n_sub for f in floor), "",
            floor=floor),
        Row(f"physics floor: {n_sub} mj_step per planner tick of {cfg.timing.dt:g} s", floor,
            "a floor sample: the unit of the x floor column", floor=floor)]

    def tick(i: int) -> float:
        _at_start(world, cfg)  # like a floor sample: from the start (and the reset untimed)
        t0 = probe.time()
        world.step(n_sub)
        return probe.time() - t0

    _, ticks, floors = _interleaved(tick, calls, probe)
    rows.append(Row(f"{PHYSICS_TICK_ROW} ({n_sub} steps + contact check)", tuple(ticks),
                    "from the start, like a floor sample: never under the floor", floor=tuple(floors)))
    _at_start(world, cfg)
    world.sync()
    eye = layout.obstacle.eye(layout.obstacle_start)
    rows.append(_timed_row("ego_visible (5 sight lines, mj_multiRay)", lambda i: ego_visible(world), calls, probe))
    rows.append(_timed_row("isovist 360 rays + shapely polygon", lambda i: isovist(world, eye).polygon, calls,
                           probe))
    seeds = range(1000, 1000 + episodes)
    dt = cfg.timing.dt
    constant = _episode_passes(lambda s: run_episode(cfg, s, "constant", world), seeds, repeats, dt, probe)
    rows.append(constant.row("episode, constant (labels itself)", episodes))
    reactive = _episode_passes(lambda s: run_episode(cfg, s, "reactive", world), seeds, repeats, dt, probe)
    best = min(reactive.walls) / episodes
    rows.append(reactive.row("episode, reactive + counterfactual", episodes,
                             f"target < 50 ms (issue 12): {'met' if best < 0.05 else 'MISSED'}"))
    return rows


def _duration(sec: float) -> str:
    """A time [s] in its most readable unit."""
    if sec < 1e-3:
        return f"{sec * 1e6:.1f} µs"
    if sec < 10:
        return f"{sec * 1e3:.2f} ms"
    return f"{sec:.1f} s"


def _times(x: float) -> str:
    """A ratio as the x floor column writes it."""
    return f"{x:.2f}x" if x < 10 else f"{x:.0f}x"


def _spread_cell(row: Row) -> str:
    """The median time, the IQR over it [%] and the number of repeats of ``row``."""
    if len(row.times) == 1:
        return "one run"
    return f"{_duration(row.median)} ({100 * row.spread:.0f} %, n {len(row.times)})"


def _in_words(row: Row) -> str:
    """The median, IQR and repeats of ``row`` in brackets, for the targets table."""
    if len(row.times) == 1:
        return "(one run)"
    return f"(median {_duration(row.median)}, IQR {100 * row.spread:.0f} %, n {len(row.times)})"


def _ratio_cell(row: Row, floor: PhysicsFloor | None) -> str:
    """``x floor`` of ``row``, and the median and IQR [%] of its paired ratios."""
    paired = row.paired_ratios(floor)
    if len(paired) == 1:
        return f"{_times(row.ratio(floor))} (one run)"
    return f"{_times(row.ratio(floor))} ({_times(statistics.median(paired))}, {100 * _iqr(paired):.0f} %)"


def floor_check(rows: Sequence[Row], floor: PhysicsFloor | None = None) -> str:
    """The footnote on the floor against the physics-tick row (``planner tick of physics
    ...``), which runs the floor's steps and more and so can never be cheaper: ``floor
    check: ok ...``, or ``floor check: VIOLATED ...`` where the least floor sample taken
    between that row's repeats, or the run's floor ``floor``, exceeds the row's least time
    (a slow moment, or a floor that measures something else)."""
    found = [r for r in rows if r.what.startswith(PHYSICS_TICK_ROW)]
    if not found:
        return "floor check: no physics-tick row in this run, nothing to check."
    row = found[0]
    bad = []
    if row.floor and min(row.floor) > row.seconds:
        bad.append(f"the floor sampled between its repeats ({_duration(min(row.floor))})")
    if floor is not None and floor.tick > row.seconds:
        bad.append(f"the floor of the run ({_duration(floor.tick)})")
    if bad:
        return (f"floor check: VIOLATED: {' and '.join(bad)} exceeded the physics-tick row "
                f"({_duration(row.seconds)}), which runs the same steps and more; the floor and the row were "
                "not timed alike, or a slow moment hit the row: read the x floor column with care.")
    return (f"floor check: ok, the floor ({_duration(row.floor_tick(floor))}) stayed under the physics-tick row "
            f"({_duration(row.seconds)}, {_times(row.ratio(floor))}).")


_NOT_RUN = {  # how to get a target's row where this run had none
    "filter tick + decision, N = 1000": "not run (--particles without 1000)",
    "filter tick + decision, N = 10 000": "not run (--particles without 10000)",
    "Gymnasium env step without the filter": "not run (--only-reproduce, or no Gymnasium)",
    "env step with the filter": "not run (--only-reproduce, or no Gymnasium)",
    "memory per worker": "not run (--reproduce)",
    "parallel efficiency at 2 workers": "not run (--reproduce with --workers 1,2)",
}


def format_targets(rows: Sequence[Row], floor: PhysicsFloor | None = None) -> str:
    """Markdown table of the targets (:data:`GOALS`, in order), one line each: what, the
    measured figure (least over the interleaved repeats, with the median and IQR), the
    ``x floor`` of the row it is read off, the target, and ``met``, ``MISSED`` or ``not
    run`` (no row in ``rows`` carries a reading of it). Where several rows read one target
    (memory per worker), the worst reading counts."""
    out = ["| target | measured: min (median, IQR, repeats) | x floor | goal | verdict |", "|---|---|---|---|---|"]
    for goal in GOALS:
        found = [(row, reading) for row in rows for reading in row.readings if reading.goal == goal.what]
        if not found:
            out.append(f"| {goal.what} | {_NOT_RUN.get(goal.what, 'not run (--only-reproduce)')} | - | {goal.text} "
                       "| not run |")
            continue
        values = [goal.value(row, reading, floor) for row, reading in found]
        worst = (max if goal.op in ("<=", "<") else min)(range(len(found)), key=lambda i: values[i])
        row, reading = found[worst]
        value = values[worst]
        if goal.quantity in ("x floor", "time"):
            measured = f"{_duration(row.seconds)} {_in_words(row)}"
        elif goal.quantity == "steps/s":
            measured = f"{value:.0f} steps/s: {_duration(row.seconds)} a step {_in_words(row)}"
        else:
            measured = reading.text or f"{value:g}"
        if reading.text and goal.quantity in ("x floor", "time", "steps/s"):
            measured += f"; {reading.text}"
        out.append(f"| {goal.what} | {measured} | {_ratio_cell(row, floor)} | {goal.text} | "
                   f"{'met' if goal.met(value) else 'MISSED'} |")
    return "\n".join(out)


def format_rows(rows: Sequence[Row], floor: PhysicsFloor | None = None) -> str:
    """Markdown tables of benchmark rows, times in the most readable unit.

    First, where any row carries a :class:`Reading`, the targets (:func:`format_targets`);
    then every row: the least time of its repeats, their median, IQR (over the median) and
    count (``one run`` for the reproduction and startup rows: wall times of one run, their
    notes say so), and with ``floor`` (the run's floor, for rows without floor samples of
    their own) an ``x floor`` column (:meth:`Row.ratio`, with the median and IQR of the
    paired ratios); over the tables, ``floor``'s clock, and under them, what x floor divides
    by, the run's floor and :func:`floor_check`.
    """
    table = list(rows)
    out = [f"Machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
           f"MuJoCo {mujoco.__version__}, NumPy {np.__version__}", ""]
    if floor:
        out[-1:] = [f"Clock: {_CLOCK_WORDS[floor.clock]}; the times, x real time and steps/s below are of "
                    f"that clock, except the reproduction rows' (wall time).", ""]
    if any(row.readings for row in table):
        out += ["Targets (each the least time over interleaved repeats; x floor: its row's):", "",
                format_targets(table, floor), "", "Rows:", ""]
    head = ["what", "min", "median (IQR, n)", *(["x floor (median, IQR)"] if floor else []), "note"]
    out += [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for row in table:
        cells = [row.what, _duration(row.seconds), _spread_cell(row), *([_ratio_cell(row, floor)] if floor else [])]
        out.append(f"| {' | '.join([*cells, row.note])} |")
    if floor:
        q1, q2, q3 = _quartiles(floor.samples or (floor.tick,))
        out += ["", f"x floor: each row's least time per planner tick over the least floor sample taken between its "
                    f"repeats (a floor sample: one timed block of {floor.substeps} mj_step, one planner tick of "
                    "physics, both cars apart at their start; a row without samples of its own: the run's floor); "
                    "in brackets the median and IQR of the paired ratios, each repeat over the floor sample right "
                    "after it. Episode rows per tick of their episodes (a repeat: one pass over the seeds; a "
                    "labelling counterfactual's ticks not counted), reproduction rows per recorded tick (wall "
                    "time, all workers), one-off rows (startup, compiling) whole.",
                f"floor of this run: {len(floor.samples) or 1} samples, least {_duration(floor.tick)} "
                f"({_duration(floor.step)} an mj_step), median {_duration(q2)}, "
                f"IQR {100 * (q3 - q1) / max(q2, 1e-12):.0f} %.",
                floor_check(table, floor)]
    return "\n".join(out)


def bench_filter(n_values: tuple[int, ...] = (250, 1000, 10000), passes: int = 9,
                 scene: str | Path = DEFAULT_SCENE, config: ScenarioConfig | None = None,
                 probe: FloorProbe | None = None) -> list[Row]:
    """One particle-filter tick at each N, stage by stage: a repeat is one replay of the
    recorded episode, timed as its mean per tick [s], with 5 floor samples after it.

    Replays the measured system poses of a recorded cut-off episode (seed 1, constant
    planner) through the real :class:`ParticleFilter` stages, in the order the ``cdf``
    planner calls them: ``predict`` (one compiled pass: look, believe, act, move),
    ``weigh`` (likelihood, normalised weights, the posterior with P(cutoff)),
    ``resample`` (every tick, as in the paper), then the decision on the resampled
    particles (the default layered rule: the particles' futures, the compiled rollouts
    against the ego's four plans and the follow layer). The first row of each N is the
    whole tick, decision included; version 0.2's risk rule (three plans, going on rolled
    only where deferring collides) is timed on the same particles, apart. ``passes`` timed
    replays after one warm-up replay (which also compiles the kernels, or loads them from
    Numba's cache); the floor samples from ``probe`` (a new one if not given).
    """
    from cdf_mj.config import CDFConfig
    from cdf_mj.inference.particle_filter import ParticleFilter
    from cdf_mj.planners.base import PlannerContext, PlannerInput
    from cdf_mj.planners.decision import LayeredRule, RiskRule

    probe = probe or FloorProbe(scene, config)
    world, cfg = _setup(scene, config)
    trace = run_episode(cfg, 1, "constant", world, trace=True).trace
    assert trace is not None  # asked for
    poses = np.array(trace["poses"])
    ticks = len(poses) - 1
    stages = ("tick", "predict", "weigh", "resample", "decide", "risk")
    rows: list[Row] = []
    context = PlannerContext.of(world.layout(), cfg)
    rule, layered = RiskRule(CDFConfig().risk), LayeredRule(CDFConfig().layered, CDFConfig().risk)
    rule.reset(context)
    goals = {1000: "filter tick + decision, N = 1000", 10000: "filter tick + decision, N = 10 000"}
    for n in n_values:
        pf = ParticleFilter.from_layout(world.layout(), CDFConfig(n_particles=n), np.random.default_rng(0),
                                        cfg.timing.dt)
        predictor = _FilterFutures(pf)
        times: dict[str, list[float]] = {s: [] for s in stages}  # [s] per tick, the mean of each replay
        floors: list[float] = []
        clock = probe.time
        for pass_i in range(passes + 1):  # the first pass warms up and is not timed
            total = dict.fromkeys(stages, 0.0)
            pf.reset(poses[0])
            layered.reset(context)
            for k in range(1, len(poses)):
                c0 = clock()
                pf.predict(poses[k - 1])
                c1 = clock()
                pf.weigh(poses[k])
                c2 = clock()
                pf.resample()
                c3 = clock()
                layered.command(predictor, PlannerInput(t=k * cfg.timing.dt, poses=poses[k], obstacle_in_lane=False))
                c4 = clock()
                rule.decide(predictor, poses[k][0], False)
                c5 = clock()
                for stage, dt in zip(stages, (c4 - c0, c1 - c0, c2 - c1, c3 - c2, c4 - c3, c5 - c4), strict=True):
                    total[stage] += dt
            floor = probe.take(5)
            if pass_i:
                floors.append(floor)
                for stage in stages:
                    times[stage].append(total[stage] / ticks)
        floor_t = tuple(floors)

        def row(what: str, stage: str, note: str = "", readings: tuple[Reading, ...] = ()) -> Row:
            return Row(what, tuple(times[stage]), note, floor=floor_t, readings=readings)  # noqa: B023

        decide = min(times["decide"])
        reads = (_reading(goals[n], text=f"{ticks} ticks of seed 1, {passes} replays"),) if n in goals else ()
        rows += [row(f"filter tick + decision N={n} ({ticks} ticks of seed 1, {passes} replays)", "tick",
                     readings=reads),
                 row("  predict (look, believe, act, move: one compiled pass)", "predict"),
                 row("  weigh (likelihood, normalise, posterior with P(cutoff))", "weigh"),
                 row("  resample (stratified, gather, jitter, intent floor)", "resample"),
                 row("  decision (layered rule: futures, compiled rollouts of 4 plans, follow layer)", "decide",
                     "target <= 0.2 ms at N=1000 (issue 25): " + ("met" if decide <= 2e-4 else "MISSED")
                     if n == 1000 else ""),
                 row("  (apart) version 0.2's risk rule on the same particles", "risk")]
    return rows


class _FilterFutures:
    """The risk rule's view of a bare filter (what the ``cdf`` planner gives it)."""

    def __init__(self, pf: Any) -> None:
        self.pf = pf

    def alarm(self) -> float:
        return float(self.pf.posterior().p_cutoff)

    def futures(self, react_ticks: int) -> Any:
        return self.pf.futures(react_ticks)


_EPISODE_GOALS = {"cdf": "CDF episode (planner cdf)", "imm": "imm episode", "imm-risk": "imm-risk episode",
                  "cv-risk": "cv-risk episode"}


def bench_planners(episodes: int = 10, scene: str | Path = DEFAULT_SCENE,
                   config: ScenarioConfig | None = None, probe: FloorProbe | None = None,
                   repeats: int = 3) -> list[Row]:
    """One episode (no counterfactual) of every registered planner: ``repeats`` passes over
    ``episodes`` seeds from 2000, 3 floor samples after each episode (from ``probe``, a new
    one if not given). A repeat is a pass: its mean time an episode, and per tick. The
    note says how many times faster than real time the episodes ran: the simulated over
    the wall seconds of the fastest pass (what the targets judge), and the median over
    every episode."""
    from cdf_mj.planners.registry import PLANNERS, make_planner

    probe = probe or FloorProbe(scene, config)
    world, cfg = _setup(scene, config)
    rows: list[Row] = []
    seeds = range(2000, 2000 + episodes)
    for name in sorted(PLANNERS):
        def episode(seed: int, name: str = name) -> EpisodeRecord:
            return run_episode(cfg, seed, make_planner(name), world, label=False)

        timed = _episode_passes(episode, seeds, repeats, cfg.timing.dt, probe)
        fastest, median = timed.fastest, timed.median_speed
        note = (f"{fastest:.0f}x faster than real time in the fastest of {repeats} passes over {episodes} seeds "
                f"(all its seeds together); {median:.0f}x the median episode")
        reads: tuple[Reading, ...] = ()
        if name in _EPISODE_GOALS:
            reads = (_reading(_EPISODE_GOALS[name], fastest,
                              f"{fastest:.0f}x real time in the fastest pass over {episodes} seeds ({median:.0f}x "
                              f"the median of {len(timed.speeds)} episodes); "
                              f"{_duration(min(timed.walls) / episodes)} an episode"),)
        rows.append(timed.row(f"episode, {name} (no counterfactual)", episodes, note, reads))
    return rows


def bench_env(seconds: float = 1.0, repeats: int = 3, scene: str | Path = DEFAULT_SCENE,
              config: ScenarioConfig | None = None, probe: FloorProbe | None = None) -> list[Row]:
    """Time per step of the Gymnasium environment (one 0.1 s planner tick, seeded random
    actions) without the filter, with it, and with the defaults (filter and the labelling
    counterfactual at each reset): ``repeats`` runs of ``seconds`` each, 5 floor samples
    (from ``probe``, a new one if not given) after each. A step row times the ``step``
    calls alone (the policy's sampling of the action and the resets are not in it); the
    resets of the same runs (random actions end an episode in about 20 steps) are a row of
    their own, per reset. No rows without Gymnasium."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return []
    from cdf_mj.envs.t_intersection import TIntersectionEnv

    probe = probe or FloorProbe(scene, config)
    clock = probe.time
    world, cfg = _setup(scene, config)
    rows: list[Row] = []
    variants: tuple[tuple[str, dict[str, Any], str | None], ...] = (
        ("no filter", {"run_filter": False, "label": False}, "Gymnasium env step without the filter"),
        ("with the filter", {"label": False}, "env step with the filter"),
        ("defaults: filter and labels", {}, None))
    for what, kwargs, goal in variants:
        env = TIntersectionEnv(scene=world, config=cfg, **kwargs)
        env.action_space.seed(0)
        env.reset(seed=0)
        env.step(env.action_space.sample())  # warm-up
        per_step, floors, per_reset, reset_floors = [], [], [], []
        for rep in range(repeats):
            env.reset(seed=rep)
            steps = resets = 0
            in_steps = in_resets = 0.0
            start = clock()
            while clock() - start < seconds:
                action = env.action_space.sample()
                t0 = clock()
                _obs, _r, terminated, truncated, _info = env.step(action)
                t1 = clock()
                in_steps, steps = in_steps + t1 - t0, steps + 1
                if terminated or truncated:
                    env.reset()
                    in_resets, resets = in_resets + clock() - t1, resets + 1
            per_step.append(in_steps / steps)
            floors.append(probe.take(5))
            if resets:
                per_reset.append(in_resets / resets)
                reset_floors.append(floors[-1])
        note = f"{1.0 / min(per_step):.0f} steps/s at the least time a step (steps alone)"
        reads = (_reading(goal, text=f"{repeats} runs of {seconds:g} s"),) if goal else ()
        rows.append(Row(f"env step, {what}", tuple(per_step), note, floor=tuple(floors), readings=reads))
        if per_reset:  # (a run too short to end an episode has none)
            rows.append(Row(f"env reset, {what}", tuple(per_reset), "per reset, in the same runs",
                            floor=tuple(reset_floors)))
    return rows


def bench_reproduction(episodes: int = 1000, workers: tuple[int, ...] = (1, 2),
                       planners: tuple[str, ...] = ("cdf", "reactive"),
                       progress: bool = False, scene: str | Path = DEFAULT_SCENE,
                       config: ScenarioConfig | None = None, probe: FloorProbe | None = None) -> list[Row]:
    """Wall time of the paper's reproduction (``episodes`` seeds from 0, every planner,
    labels included) with each worker count, in fresh temporary directories; 10 floor
    samples (from ``probe``, a new one if not given) after each run.

    Rows: one per worker count (note: parallel efficiency against the first count, peak
    resident memory of a worker), with the targets of issue 16 (<= 25 s on 2 workers of
    this 2-core machine, efficiency >= 90 % at 2 workers against 1, <= 300 MB per worker).
    """
    from cdf_mj.experiments.experiment import run_experiment

    probe = probe or FloorProbe(scene, config)
    dt = (config or ScenarioConfig()).timing.dt
    rows: list[Row] = []
    base: tuple[int, float] | None = None
    for k in sorted(set(workers)):  # the fewest first: the efficiencies are against it
        with tempfile.TemporaryDirectory(prefix="cdf-mj-bench-") as tmp:
            result = run_experiment(tmp, range(episodes), planners, config, scene=scene,
                                    progress=progress, workers=k)
        wall = result.wall_time
        mb = result.peak_worker_rss_mb * 1.048576
        notes = [f"wall time of one run on {result.workers} worker(s) ({result.backend}); "
                 f"{len(result)} records, {result.failed} failed",
                 f"peak memory per worker {result.peak_worker_rss_mb:.0f} MiB"]
        reads = [_reading("memory per worker", mb, f"{mb:.0f} MB ({result.peak_worker_rss_mb:.0f} MiB): the peak of "
                                                   f"a worker in the run on {k} worker(s)")]
        if base is None:
            base = (k, wall)
        else:
            eff = base[1] * base[0] / (k * wall)
            notes.append(f"efficiency {100 * eff:.0f} % against {base[0]} worker(s)")
            if k == 2 and base[0] == 1:
                reads.append(_reading("parallel efficiency at 2 workers", 100 * eff,
                                      f"{100 * eff:.0f} %: T(1) / (2 T(2)), {_duration(base[1])} and "
                                      f"{_duration(wall)}, {episodes} seeds"))
        if k == 2 and episodes == 1000:
            notes.append(f"target <= 25 s (issue 16): {'met' if wall <= 25 else 'MISSED'}")
        ticks = sum(_ticks(r["end_time"], dt) for r in result.records if "end_time" in r)
        rows.append(_one_off(f"reproduction: {episodes} seeds x {'+'.join(planners)}, {k} worker(s)", wall,
                             "; ".join(notes), probe, wall / max(ticks, 1), tuple(reads)))
    return rows


def bench_startup(planner: str = "cdf", seed: int = 0, probe: FloorProbe | None = None) -> list[Row]:
    """What a fresh Python process pays before its first tick runs at speed, on the default
    scene and scenario: two rows, each a time of new processes (with ``probe``'s CPU
    clock, their CPU time, user and system; the note gives the wall time too), 10 floor
    samples (from ``probe``, a new one if not given) after each.

    - ``numba first call``: in a fresh process (``NUMBA_CACHE_DIR`` unset: Numba's cache
      as installed), one episode of ``planner`` without labels minus a second run of it
      (timed in that process with ``probe``'s clock):
      compiling the package's Numba kernels, or loading them from the cache (and starting
      Numba itself). The note says how many kernels were loaded or compiled, and where the
      cache lives (the directories Numba read or wrote, checked for its ``*.nbi`` index
      files).
    - ``cold start``: ``python -m cdf_mj episode --planner planner`` (what ``cdf-mj
      episode`` runs) with ``NUMBA_CACHE_DIR`` pointing at a new empty directory, so that
      every kernel compiles; target < 5 s (issue 27; < 10 s in issue 16).
    """
    probe = probe or FloorProbe()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    probe_code = (f"from cdf_mj.experiments.bench import _first_calls; "
                  f"_first_calls({planner!r}, {seed}, {probe.clock!r})")
    t0 = time.perf_counter()
    done = _run_python(["-c", probe_code], env)
    wall = time.perf_counter() - t0
    first = json.loads(done.stdout.strip().splitlines()[-1])
    kernels = first["kernels"]
    hits = sum(k["hits"] for k in kernels.values())
    misses = sum(k["misses"] for k in kernels.values())
    paths = sorted({k["cache_path"] for k in kernels.values()})
    indexed = [p for p in paths if any(Path(p).glob("*.nbi"))]
    where = ", ".join(indexed) if indexed else "none found (nothing written)"
    rows = [_one_off(
        f"numba first call (compile or cache load): episode, {planner}, in a fresh process",
        first["first"] - first["second"],
        f"first episode minus the second; {len(kernels)} kernels: {hits} loaded from Numba's cache, "
        f"{misses} compiled; cache: {where}; the process took {wall:.1f} s of wall time", probe)]

    with tempfile.TemporaryDirectory(prefix="cdf-mj-numba-") as cache:
        t0, c0 = time.perf_counter(), _children_cpu()
        done = _run_python(["-m", "cdf_mj", "episode", "--planner", planner, "--seed", str(seed)],
                           {**env, "NUMBA_CACHE_DIR": cache})
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        compiled = len(list(Path(cache).rglob("*.nbi")))
    json.loads(done.stdout)  # the record it printed: the episode ran to the end
    # What a user waits for: the wall time of the process (its CPU time beside it), whatever the clock.
    rows.append(_one_off(
        f"cold start: cdf-mj episode --planner {planner}, empty Numba cache", wall,
        f"wall time of a new process (python -m cdf_mj episode, labels included; CPU {cpu:.1f} s); {compiled} "
        f"kernels compiled into an empty NUMBA_CACHE_DIR; target < 5 s (issue 27): {'met' if wall < 5 else 'MISSED'}",
        probe, readings=(_reading("cold start with an empty Numba cache", text=f"{compiled} kernels compiled"),)
        if planner == "cdf" else ()))
    return rows


def _children_cpu() -> float:
    """[s] CPU time, user and system, of this process's finished children (NaN where the
    platform does not tell)."""
    try:
        import resource
    except ImportError:  # not on Windows
        return math.nan
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run_python(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run this Python with ``args`` and ``env``; ChildProcessError (an OSError: ``cdf-mj``
    reports it in one line and exits 1) with the end of its stderr if it fails."""
    done = subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ChildProcessError(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return done


def _first_calls(planner: str, seed: int, clock: Clock = "wall") -> None:
    """The fresh process of :func:`bench_startup`: print as JSON the times [s] (``clock``)
    of two runs of one episode of ``planner`` (no labels) and the cache path, hits and
    misses of every Numba kernel of the package that they loaded or compiled."""
    import numba

    scene = Scene.load()
    now = CLOCKS[clock]
    t1 = now()
    run_episode(None, seed, planner, scene, label=False)
    t2 = now()
    run_episode(None, seed, planner, scene, label=False)
    t3 = now()
    kernels = {}
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] != "cdf_mj":
            continue
        for value in vars(module).values():
            if isinstance(value, numba.core.dispatcher.Dispatcher):
                stats = value.stats
                hits, misses = sum(stats.cache_hits.values()), sum(stats.cache_misses.values())
                if hits or misses:
                    kernels[f"{value.py_func.__module__}.{value.py_func.__name__}"] = {
                        "hits": hits, "misses": misses, "cache_path": stats.cache_path}
    print(json.dumps({"first": t2 - t1, "second": t3 - t2, "kernels": kernels}))
