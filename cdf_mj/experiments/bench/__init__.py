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

One module per job, each returning its rows; the names below are re-exported here:

==================  ======================================================================
``floor``           the clocks, :class:`PhysicsFloor`, :class:`FloorProbe`, :func:`physics_floor`
``rows``            :class:`Row`, the targets (:data:`GOALS`, :class:`Goal`, :class:`Reading`),
                    and how the jobs time their repeats against the probe
``table``           :func:`format_rows`, :func:`format_targets`, :func:`floor_check`
``core``            :func:`bench_core`: physics, sight lines, isovist, two labelled episodes
``filter_tick``     :func:`bench_filter`: the filter's stages and the decision at each N
``planners``        :func:`bench_planners`: an episode of every registered planner
``env``             :func:`bench_env`: the Gymnasium environment's steps and resets
``reproduction``    :func:`bench_reproduction`: the paper's reproduction on 1 and 2 workers
``startup``         :func:`bench_startup`: Numba's first call and a cold start
==================  ======================================================================

The falsification throughput (episodes a second of a falsification's estimate on 2
workers) is a job of the falsifier's layer: :func:`cdf_mj.falsify.throughput.bench_falsification`.
"""

from __future__ import annotations

from cdf_mj.experiments.bench.core import bench_core
from cdf_mj.experiments.bench.env import bench_env
from cdf_mj.experiments.bench.filter_tick import bench_filter
from cdf_mj.experiments.bench.floor import CLOCKS, DEFAULT_CLOCK, FloorProbe, PhysicsFloor, physics_floor
from cdf_mj.experiments.bench.planners import bench_planners
from cdf_mj.experiments.bench.reproduction import bench_reproduction
from cdf_mj.experiments.bench.rows import GOALS, Goal, Reading, Row
from cdf_mj.experiments.bench.startup import bench_startup
from cdf_mj.experiments.bench.table import floor_check, format_rows, format_targets

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
