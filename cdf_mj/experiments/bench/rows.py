"""A bench row (:class:`Row`: the times of its interleaved repeats and the floor samples
taken right after each), the targets it is judged by (:data:`GOALS`, :class:`Goal`,
:class:`Reading`), and how the jobs time their repeats against a :class:`FloorProbe`
(:func:`interleaved`, :func:`timed_row`, :func:`one_off`, :func:`episode_passes`).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, TypeVar

from cdf_mj.experiments.bench.floor import FloorProbe, PhysicsFloor
from cdf_mj.records import EpisodeRecord

__all__ = ["GOALS", "PHYSICS_TICK_ROW", "EpisodePasses", "Goal", "Reading", "Row", "duration", "episode_passes",
           "goal_reading", "interleaved", "iqr", "one_off", "planner_ticks", "quartiles", "timed_row"]

_T = TypeVar("_T")

#: The start of the physics-tick row, which the floor must stay under.
PHYSICS_TICK_ROW = "planner tick of physics"


def quartiles(xs: Sequence[float]) -> tuple[float, float, float]:
    """First quartile, median and third quartile of ``xs`` (all three the value if one)."""
    if len(xs) == 1:
        return xs[0], xs[0], xs[0]
    q1, q2, q3 = statistics.quantiles(xs, n=4, method="inclusive")
    return q1, q2, q3


def iqr(xs: Sequence[float]) -> float:
    """Interquartile range of ``xs`` over their median [fraction] (0 for one value)."""
    q1, q2, q3 = quartiles(xs)
    return (q3 - q1) / q2 if q2 > 0 else 0.0


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
        return iqr(self.times)

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
    ``"x real time"`` (simulated over wall seconds), ``"MB"`` (10^6 bytes), ``"%"``,
    ``"episodes/s"`` (episodes over wall seconds).
    """

    what: str
    quantity: Literal["x floor", "time", "steps/s", "x real time", "MB", "%", "episodes/s"]
    op: Literal["<=", "<", ">="]
    bound: float

    @property
    def text(self) -> str:
        """The target in words, e.g. ``<= 2x floor``."""
        seconds = f"{self.bound * 1e3:g} ms" if self.bound < 1 else f"{self.bound:g} s"
        bound = {"x floor": f"{self.bound:g}x floor", "time": seconds,
                 "steps/s": f"{self.bound:g} steps/s", "x real time": f"{self.bound:g}x real time",
                 "MB": f"{self.bound:g} MB", "%": f"{self.bound:g} %",
                 "episodes/s": f"{self.bound:g} episodes/s"}[self.quantity]
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


# The targets of issue 27, in its order (two of issue 16 from the reproduction rows, and issue
# 38's falsification throughput).
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
    Goal("falsification throughput on 2 workers", "episodes/s", ">=", 60.0),
)
_GOAL = {g.what: g for g in GOALS}


def goal_reading(goal: str, value: float | None = None, text: str = "") -> Reading:
    """A reading of the goal called ``goal`` (KeyError for a goal not in :data:`GOALS`)."""
    return Reading(_GOAL[goal].what, value, text)


def interleaved(fn: Callable[[int], _T], repeats: int, probe: FloorProbe,
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


def timed_row(what: str, fn: Callable[[int], object], repeats: int, probe: FloorProbe, note: str = "",
              readings: tuple[Reading, ...] = ()) -> Row:
    """A row of ``repeats`` calls of ``fn(i)`` (after a warm-up call), a floor sample after each."""
    times, _, floors = interleaved(fn, repeats, probe)
    return Row(what, tuple(times), note, floor=tuple(floors), readings=readings)


def one_off(what: str, sec: float, note: str, probe: FloorProbe, per_tick: float | None = None,
            readings: tuple[Reading, ...] = (), blocks: int = 10) -> Row:
    """A row of one run that took ``sec`` [s], with the least of ``blocks`` floor samples
    taken right after it."""
    return Row(what, (sec,), note, () if per_tick is None else (per_tick,), (probe.take(blocks),), readings)


def planner_ticks(end_time: float, dt: float) -> int:
    """Planner ticks of ``dt`` [s] in an episode that ended at ``end_time`` [s] (at least 1)."""
    return max(round(end_time / dt), 1)


@dataclass
class EpisodePasses:
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


def episode_passes(fn: Callable[[int], EpisodeRecord], seeds: Sequence[int], passes: int, dt: float,
                   probe: FloorProbe) -> EpisodePasses:
    """Time ``fn(seed)`` for every seed, ``passes`` times over (a pass over all seeds, then
    the next) with ``probe``'s clock, after one warm-up episode on ``seeds[0] - 1``; 3 floor samples after each
    episode (a pass's floor: the least of its samples)."""
    fn(seeds[0] - 1)
    out = EpisodePasses()
    clock = probe.time
    for _ in range(passes):
        wall, ticks, sim, floor = 0.0, 0, 0.0, math.inf
        for seed in seeds:
            t0 = clock()
            rec = fn(seed)
            sec = clock() - t0
            floor = min(floor, probe.take(3))
            wall, ticks, sim = wall + sec, ticks + planner_ticks(rec.end_time, dt), sim + rec.end_time
            out.speeds.append(rec.end_time / max(sec, 1e-9))
        out.walls.append(wall)
        out.ticks.append(ticks)
        out.simulated.append(sim)
        out.floor.append(floor)
    return out


def duration(sec: float) -> str:
    """A time [s] in its most readable unit."""
    if sec < 1e-3:
        return f"{sec * 1e6:.1f} µs"
    if sec < 10:
        return f"{sec * 1e3:.2f} ms"
    return f"{sec:.1f} s"
