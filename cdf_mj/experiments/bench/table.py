"""The bench's tables in Markdown: the targets first (:func:`format_targets`), then every row
(:func:`format_rows`), and under them a check that the floor stayed under the physics-tick
row (:func:`floor_check`)."""

from __future__ import annotations

import platform
import statistics
from collections.abc import Sequence

import mujoco
import numpy as np

from cdf_mj.experiments.bench.floor import PhysicsFloor
from cdf_mj.experiments.bench.rows import GOALS, PHYSICS_TICK_ROW, Row, duration, iqr, quartiles

__all__ = ["floor_check", "format_rows", "format_targets"]

_CLOCK_WORDS = {"cpu": "CPU time of this process (time.process_time; the startup rows: of their child processes)",
                "wall": "wall time (time.perf_counter)"}


def _times(x: float) -> str:
    """A ratio as the x floor column writes it."""
    return f"{x:.2f}x" if x < 10 else f"{x:.0f}x"


def _spread_cell(row: Row) -> str:
    """The median time, the IQR over it [%] and the number of repeats of ``row``."""
    if len(row.times) == 1:
        return "one run"
    return f"{duration(row.median)} ({100 * row.spread:.0f} %, n {len(row.times)})"


def _in_words(row: Row) -> str:
    """The median, IQR and repeats of ``row`` in brackets, for the targets table."""
    if len(row.times) == 1:
        return "(one run)"
    return f"(median {duration(row.median)}, IQR {100 * row.spread:.0f} %, n {len(row.times)})"


def _ratio_cell(row: Row, floor: PhysicsFloor | None) -> str:
    """``x floor`` of ``row``, and the median and IQR [%] of its paired ratios."""
    paired = row.paired_ratios(floor)
    if len(paired) == 1:
        return f"{_times(row.ratio(floor))} (one run)"
    return f"{_times(row.ratio(floor))} ({_times(statistics.median(paired))}, {100 * iqr(paired):.0f} %)"


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
        bad.append(f"the floor sampled between its repeats ({duration(min(row.floor))})")
    if floor is not None and floor.tick > row.seconds:
        bad.append(f"the floor of the run ({duration(floor.tick)})")
    if bad:
        return (f"floor check: VIOLATED: {' and '.join(bad)} exceeded the physics-tick row "
                f"({duration(row.seconds)}), which runs the same steps and more; the floor and the row were "
                "not timed alike, or a slow moment hit the row: read the x floor column with care.")
    return (f"floor check: ok, the floor ({duration(row.floor_tick(floor))}) stayed under the physics-tick row "
            f"({duration(row.seconds)}, {_times(row.ratio(floor))}).")


_NOT_RUN = {  # how to get a target's row where this run had none
    "filter tick + decision, N = 1000": "not run (--scale-particles without 1000)",
    "filter tick + decision, N = 10 000": "not run (--scale-particles without 10000)",
    "Gymnasium env step without the filter": "not run (--only-reproduce, or no Gymnasium)",
    "env step with the filter": "not run (--only-reproduce, or no Gymnasium)",
    "memory per worker": "not run (--reproduce)",
    "parallel efficiency at 2 workers": "not run (--reproduce with --scale-workers 1,2)",
    "falsification throughput on 2 workers": "not run (--reproduce)",
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
            measured = f"{duration(row.seconds)} {_in_words(row)}"
        elif goal.quantity == "steps/s":
            measured = f"{value:.0f} steps/s: {duration(row.seconds)} a step {_in_words(row)}"
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
        cells = [row.what, duration(row.seconds), _spread_cell(row), *([_ratio_cell(row, floor)] if floor else [])]
        out.append(f"| {' | '.join([*cells, row.note])} |")
    if floor:
        q1, q2, q3 = quartiles(floor.samples or (floor.tick,))
        out += ["", f"x floor: each row's least time per planner tick over the least floor sample taken between its "
                    f"repeats (a floor sample: one timed block of {floor.substeps} mj_step, one planner tick of "
                    "physics, both cars apart at their start; a row without samples of its own: the run's floor); "
                    "in brackets the median and IQR of the paired ratios, each repeat over the floor sample right "
                    "after it. Episode rows per tick of their episodes (a repeat: one pass over the seeds; a "
                    "labelling counterfactual's ticks not counted), reproduction rows per recorded tick (wall "
                    "time, all workers), one-off rows (startup, compiling) whole.",
                f"floor of this run: {len(floor.samples) or 1} samples, least {duration(floor.tick)} "
                f"({duration(floor.step)} an mj_step), median {duration(q2)}, "
                f"IQR {100 * (q3 - q1) / max(q2, 1e-12):.0f} %.",
                floor_check(table, floor)]
    return "\n".join(out)
