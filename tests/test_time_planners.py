"""scripts/time_planners.py: planners timed in alternation against the physics floor."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "time_planners.py"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300,
                          cwd=ROOT, stdin=subprocess.DEVNULL)


def test_it_prints_each_planner_against_the_first_and_the_floor() -> None:
    proc = _run("--planner", "reactive,cdf-option", "--episodes", "1", "--rounds", "2", "--seed", "3")
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("seeds 3-3, 2 rounds")
    rows = {line.split()[0]: line for line in lines[1:]}
    assert set(rows) == {"reactive", "cdf-option", "constant"}  # the floor is added
    assert "x1.00 of reactive" in rows["reactive"] and "x1.00 of the physics floor" in rows["constant"]


def test_bad_input_is_one_line_and_exit_2() -> None:
    for args in (("--planner", "nope"), ("--episodes", "0"), ("--rounds", "x")):
        proc = _run(*args)
        assert proc.returncode == 2 and proc.stdout == ""
        assert len(proc.stderr.strip().splitlines()) == 1 and proc.stderr.startswith("time_planners: error: ")
