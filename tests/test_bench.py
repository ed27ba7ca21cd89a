"""The benchmark command prints every row it promises and the targets first, each row
timed against the physics floor sampled between its repeats, targets judged from the
figures."""

from __future__ import annotations

import os
import re

import pytest

from cdf_mj.cli import main
from cdf_mj.experiments.bench import (
    GOALS,
    FloorProbe,
    PhysicsFloor,
    Reading,
    Row,
    floor_check,
    format_rows,
    format_targets,
    physics_floor,
)
from cdf_mj.experiments.bench.startup import _run_python
from cdf_mj.planners.registry import PLANNERS

_TIME = r"[\d.]+ (µs|ms|s)"
_RATIO = r"[\d.]+x \(([\d.]+x, \d+ %|one run)\)"


def _rows(out: str, head: str) -> list[str]:
    """The body lines of the Markdown table of ``out`` whose header starts with ``head``."""
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(head))
    body = []
    for line in lines[start + 2:]:
        if not line.startswith("| "):
            break
        body.append(line)
    return body


def test_bench_prints_the_targets_first_then_every_row_against_its_floor(capsys):
    assert main(["bench", "--episodes", "1", "--repeats", "1", "--particles", "100,1000", "--env-seconds", "0.05",
                 "--reproduce", "--reproduce-episodes", "3", "--workers", "1,2", "--falsify-episodes", "4",
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    # The targets come first, one line per target of issue 27, each with its x floor and a verdict.
    assert out.index("| target |") < out.index("| what |")
    targets = _rows(out, "| target |")
    assert [line.split(" | ")[0][2:] for line in targets] == [g.what for g in GOALS]
    for goal, line in zip(GOALS, targets, strict=True):
        if goal.what == "filter tick + decision, N = 10 000":  # not in --particles
            assert line.endswith(f"| - | {goal.text} | not run |"), line
        else:
            assert re.search(rf" \| {_RATIO} \| {re.escape(goal.text)} \| (met|MISSED) \|$", line), line
    assert "| <= 2x floor |" in targets[0] and "| >= 300x real time |" in targets[2] and "| < 5 s |" in targets[8]
    assert re.search(r"\| CDF episode \(planner cdf\) \| \d+x real time in the fastest pass over 1 seeds", targets[2])
    assert re.search(r"\| memory per worker \| \d+ MB \(\d+ MiB\)", targets[9])
    assert re.search(r"\| parallel efficiency at 2 workers \| \d+ %: T\(1\) / \(2 T\(2\)\)", targets[10])
    assert re.search(r"\| falsification throughput on 2 workers \| [\d.]+ episodes/s: 4 episodes of cdf on the "
                     r"space 'default' in [\d.]+ \w+ \(wall\) on 2 worker\(s\) \| ", targets[11]), targets[11]
    assert "| >= 60 episodes/s |" in targets[11]
    # Every row: least time, median (IQR, repeats) or one run, x floor with the paired ratios.
    rows = _rows(out, "| what |")
    assert rows and all(re.match(rf"\| [^|]+ \| {_TIME} \| ({_TIME} \(\d+ %, n \d+\)|one run) \| {_RATIO} \| ", row)
                        for row in rows), "\n".join(rows)
    assert "| filter tick + decision N=100 " in out and "|   predict (look, believe, act, move" in out
    for name in PLANNERS:
        assert f"| episode, {name} (no counterfactual) |" in out
    for what in ("no filter", "with the filter", "defaults: filter and labels"):
        assert re.search(rf"\| env step, {what} \| {_TIME} \| one run \| {_RATIO} \| \d+ steps/s", out), what
    assert "| env reset, no filter |" in out  # the resets of the same runs, apart
    assert re.search(rf"\| physics floor: 20 mj_step per planner tick of 0.1 s \| {_TIME} \| {_TIME} \(\d+ %, "
                     r"n 100\) \| 1.00x \(1.00x, 0 %\) \|", out)
    assert re.search(r"\| planner tick of physics \(20 steps \+ contact check\) \| .* n 100\) \|", out)
    one = re.search(rf"\| reproduction: 3 seeds x cdf\+reactive, 1 worker\(s\) \| {_TIME} \| one run \| {_RATIO} "
                    r"\| (?P<note>.*) \|", out)
    two = re.search(rf"\| reproduction: 3 seeds x cdf\+reactive, 2 worker\(s\) \| {_TIME} \| one run \| {_RATIO} "
                    r"\| (?P<note>.*) \|", out)
    assert one and two
    assert "6 records, 0 failed" in one["note"] and "efficiency" in two["note"]
    assert re.search(r"peak memory per worker \d+ MiB", two["note"])
    # Under the table: what x floor divides by, the run's floor, and the floor against the physics tick.
    assert re.search(r"^x floor: each row's least time per planner tick over the least floor sample", out, re.M)
    assert re.search(rf"^floor of this run: \d+ samples, least {_TIME} \({_TIME} an mj_step\)", out, re.M)
    assert re.search(r"^floor check: (ok, the floor|VIOLATED)", out, re.M)
    # Startup: Numba's first call (and where its cache is), a cold episode with its target.
    first = re.search(r"\| numba first call \(compile or cache load\).*; (\d+) kernels: (\d+) loaded from Numba's "
                      r"cache, (\d+) compiled; cache: ([^;]+);", out)
    assert first and int(first.group(1)) >= 1 and int(first.group(2)) + int(first.group(3)) >= int(first.group(1))
    assert "__pycache__" in first.group(4) or "numba" in first.group(4).lower()
    assert re.search(r"\| cold start: cdf-mj episode --planner cdf, empty Numba cache \| .* \| one run \| \d+x "
                     r"\(one run\) \| wall time of a new process .*\d+ kernels compiled into an empty "
                     r"NUMBA_CACHE_DIR; target < 5 s "
                     r"\(issue 27\): (met|MISSED) \|", out)


def test_a_rows_ratio_is_over_the_floor_sampled_between_its_repeats():
    run = PhysicsFloor.of([50e-6, 60e-6], 20)  # a quieter moment than the row's: not what it divides by
    row = Row("r", (300e-6, 200e-6, 250e-6), floor=(100e-6, 80e-6, 125e-6))
    assert row.seconds == 200e-6 and row.median == 250e-6
    assert row.floor_tick(run) == 80e-6
    assert row.ratio(run) == pytest.approx(2.5)  # least time over least floor sample
    assert row.paired_ratios(run) == pytest.approx((3.0, 2.5, 2.0))  # each repeat over the sample after it
    assert row.spread == pytest.approx((275e-6 - 225e-6) / 250e-6)  # IQR over the median
    # An episode row divides its time per tick; a row without samples of its own, by the run's floor.
    episode = Row("e", (0.03, 0.02), per_tick=(300e-6, 200e-6), floor=(100e-6, 100e-6))
    assert episode.ratio() == pytest.approx(2.0) and episode.paired_ratios() == pytest.approx((3.0, 2.0))
    assert Row("apart", (150e-6,)).ratio(run) == pytest.approx(3.0)
    with pytest.raises(ValueError, match="no floor samples"):
        Row("apart", (150e-6,)).ratio()
    with pytest.raises(ValueError, match="2 floor for 3 times"):
        Row("bad", (1.0, 2.0, 3.0), floor=(1.0, 2.0))


def test_format_rows_shows_the_least_time_the_spread_and_the_ratio():
    floor = PhysicsFloor.of([100e-6, 120e-6], 20)
    row = Row("per tick", (300e-6, 200e-6, 250e-6), "a note", floor=(100e-6, 80e-6, 125e-6))
    table = format_rows([row, Row("one-run episode", (0.1,), "", (300e-6,))], floor)
    assert "| what | min | median (IQR, n) | x floor (median, IQR) | note |" in table
    assert "| per tick | 200.0 µs | 250.0 µs (20 %, n 3) | 2.50x (2.50x, 20 %) | a note |" in table
    assert "| one-run episode | 100.00 ms | one run | 3.00x (one run) |  |" in table  # per tick, run floor
    assert "floor of this run: 2 samples, least 100.0 µs (5.0 µs an mj_step), median 110.0 µs" in table
    assert "Targets" not in table  # no row reads a target
    assert "Clock: CPU time of this process (time.process_time" in table  # the floor's clock, said first
    assert "Clock: wall time" in format_rows([row], PhysicsFloor.of([100e-6], 20, "wall"))
    plain = format_rows([Row("per tick", (250e-6,), "a note")])  # no floor: no column, no footnote
    assert "| per tick | 250.0 µs | one run | a note |" in plain and "x floor" not in plain


def test_the_floor_check_reports_a_floor_above_the_physics_tick():
    tick = "planner tick of physics (20 steps + contact check)"
    ok = Row(tick, (98e-6, 97e-6), floor=(95e-6, 96e-6))
    assert floor_check([ok], PhysicsFloor.of([94e-6], 20)).startswith("floor check: ok, the floor (95.0 µs)")
    slow_floor = Row(tick, (98e-6, 97e-6), floor=(99e-6, 100e-6))  # every floor sample above the row's least time
    line = floor_check([slow_floor], PhysicsFloor.of([94e-6], 20))
    assert line.startswith("floor check: VIOLATED: the floor sampled between its repeats (99.0 µs) exceeded the "
                           "physics-tick row (97.0 µs)")
    assert "the floor of the run (120.0 µs)" in floor_check([ok], PhysicsFloor.of([120e-6], 20))
    assert line in format_rows([slow_floor], PhysicsFloor.of([94e-6], 20))  # said under the table
    assert "no physics-tick row" in floor_check([Row("other", (1.0,))])


def test_targets_are_judged_on_the_interleaved_figures():
    floor = PhysicsFloor.of([100e-6], 20)
    rows = [Row("filter", (250e-6, 190e-6), floor=(100e-6, 100e-6), readings=(Reading(GOALS[0].what),)),
            Row("cdf", (0.02,), per_tick=(400e-6,), floor=(100e-6,),
                readings=(Reading("CDF episode (planner cdf)", 320.0, "320x real time"),)),
            Row("env", (400e-6, 300e-6), floor=(100e-6, 100e-6), readings=(Reading("env step with the filter"),)),
            Row("cold", (6.0,), floor=(100e-6,), readings=(Reading("cold start with an empty Numba cache"),)),
            Row("one", (1.0,), floor=(1e-4,), readings=(Reading("memory per worker", 250.0, "250 MB"),)),
            Row("two", (1.0,), floor=(1e-4,), readings=(Reading("memory per worker", 310.0, "310 MB"),))]
    lines = {line.split(" | ")[0][2:]: line for line in format_targets(rows, floor).splitlines()[2:]}
    assert len(lines) == len(GOALS)
    assert lines[GOALS[0].what] == (f"| {GOALS[0].what} | 190.0 µs (median 220.0 µs, IQR 14 %, n 2) "
                                    "| 1.90x (2.20x, 14 %) | <= 2x floor | met |")
    assert lines["CDF episode (planner cdf)"] == ("| CDF episode (planner cdf) | 320x real time | 4.00x (one run) "
                                                  "| >= 300x real time | met |")
    assert re.search(r"\| 3333 steps/s: 300.0 µs a step .* \| >= 3000 steps/s \| met \|$",
                     lines["env step with the filter"])
    assert lines["cold start with an empty Numba cache"].endswith("| < 5 s | MISSED |")
    assert "| 310 MB |" in lines["memory per worker"] and lines["memory per worker"].endswith("MISSED |")  # the worst
    assert lines["imm episode"].endswith("| - | >= 200x real time | not run |")
    assert "Targets (each the least time" in format_rows(rows, floor)


def test_the_physics_floor_is_one_ticks_steps_timed_as_one_block():
    floor = physics_floor(repeats=50)
    assert floor.substeps == 20 and len(floor.samples) == 50 and 0 < floor.step < 1e-3
    assert floor.tick == pytest.approx(min(floor.samples))
    probe = FloorProbe(clock="wall")
    least = probe.take(3)
    assert len(probe.samples) == 3 and least == min(probe.samples) and probe.floor().tick == pytest.approx(least)
    assert probe.floor().clock == "wall" and floor.clock == "cpu"
    with pytest.raises(ValueError, match="unknown clock 'sundial'"):
        FloorProbe(clock="sundial")  # type: ignore[arg-type]


def test_bench_refuses_bad_lists(capsys):
    assert main(["bench", "--particles", "0,100"]) == 2
    assert "positive integers" in capsys.readouterr().err
    assert main(["bench", "--repeats", "0"]) == 2
    assert "--repeats" in capsys.readouterr().err


def test_a_startup_probe_that_fails_is_an_error_the_cli_reports_in_one_line():
    """A fresh process of the startup rows that fails raises ChildProcessError (an OSError,
    which ``cdf-mj`` reports in one line with a non-zero status), naming its stderr."""
    with pytest.raises(ChildProcessError, match="no such planner here"):
        _run_python(["-c", "import sys; sys.exit('no such planner here')"], dict(os.environ))
