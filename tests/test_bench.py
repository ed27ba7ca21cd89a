"""The benchmark command prints every row it promises, with targets judged from the figures."""

from __future__ import annotations

import os
import re

import pytest

from cdf_mj.cli import main
from cdf_mj.experiments.bench import PhysicsFloor, _run_python, format_rows, physics_floor
from cdf_mj.planners.registry import PLANNERS


def test_bench_prints_filter_planner_and_scaling_rows(capsys):
    assert main(["bench", "--episodes", "1", "--particles", "100", "--env-seconds", "0.05", "--reproduce",
                 "--reproduce-episodes", "3", "--workers", "1,2", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "| filter tick + decision N=100 " in out and "|   predict (look, believe, act, move" in out
    for name in PLANNERS:
        assert f"| episode, {name} (no counterfactual) |" in out
    for what in ("no filter", "with the filter", "defaults: filter and labels"):
        assert re.search(rf"\| env step, {what} \| [\d.]+ (µs|ms) \| [\d.]+x \| \d+ steps/s[^|]* \|", out), what
    assert re.search(r"\| env step, with the filter \| .* steps/s; target >= 3000 steps/s: (met|MISSED) \|", out)
    one = re.search(r"\| reproduction: 3 seeds x cdf\+reactive, 1 worker\(s\) \| ([\d.]+) (ms|s) \| [\d.]+x \| (.*) \|",
                    out)
    two = re.search(r"\| reproduction: 3 seeds x cdf\+reactive, 2 worker\(s\) \| ([\d.]+) (ms|s) \| [\d.]+x \| (.*) \|",
                    out)
    assert one and two
    assert "6 records, 0 failed" in one.group(3) and "efficiency" in two.group(3)
    assert re.search(r"peak memory per worker \d+ MiB", two.group(3))
    # Every row has its ratio to the physics floor of this run, which is said under the table.
    rows = [line for line in out.splitlines() if line.startswith("| ") and not line.startswith("| what")]
    assert rows and all(re.match(r"\| [^|]+ \| [\d.]+ (µs|ms|s) \| [\d.]+x \| ", row) for row in rows)
    assert re.search(r"\| physics floor: 20 mj_step per planner tick of 0.1 s \| [\d.]+ µs \| 1.00x \|", out)
    assert re.search(r"^x floor: time per planner tick over the physics floor of this run, 20 mj_step", out, re.M)
    # Startup: Numba's first call (and where its cache is), a cold episode with its target.
    first = re.search(r"\| numba first call \(compile or cache load\).*; (\d+) kernels: (\d+) loaded from Numba's "
                      r"cache, (\d+) compiled; cache: ([^;]+);", out)
    assert first and int(first.group(1)) >= 1 and int(first.group(2)) + int(first.group(3)) >= int(first.group(1))
    assert "__pycache__" in first.group(4) or "numba" in first.group(4).lower()
    assert re.search(r"\| cold start: cdf-mj episode --planner cdf, empty Numba cache \| [\d.]+ (ms|s) \| \d+x \| .*"
                     r"\d+ kernels compiled into an empty NUMBA_CACHE_DIR; target < 10 s: (met|MISSED) \|", out)


def test_format_rows_divides_each_rows_time_per_tick_by_the_floor():
    floor = PhysicsFloor(step=5e-6, substeps=20)  # 100 µs per tick
    table = format_rows([("per tick", 250e-6, "a note"), ("episode", 0.1, "", 300e-6)], floor)
    assert "| what | time | x floor | note |" in table and "|---|---|---|---|" in table
    assert "| per tick | 250.0 µs | 2.50x | a note |" in table
    assert "| episode | 100.00 ms | 3.00x |  |" in table  # its time per tick, not its time
    assert "| per tick | 250.0 µs | a note |" in format_rows([("per tick", 250e-6, "a note")])  # no floor: no column


def test_the_physics_floor_is_one_ticks_steps():
    floor = physics_floor(repeats=50)
    assert floor.substeps == 20 and 0 < floor.step < 1e-3
    assert floor.tick == pytest.approx(20 * floor.step)


def test_bench_refuses_bad_lists(capsys):
    assert main(["bench", "--particles", "0,100"]) == 2
    assert "positive integers" in capsys.readouterr().err


def test_a_startup_probe_that_fails_is_an_error_the_cli_reports_in_one_line():
    """A fresh process of the startup rows that fails raises ChildProcessError (an OSError,
    which ``cdf-mj`` reports in one line with a non-zero status), naming its stderr."""
    with pytest.raises(ChildProcessError, match="no such planner here"):
        _run_python(["-c", "import sys; sys.exit('no such planner here')"], dict(os.environ))
