"""scripts/option_frontier.py: the frontier over real episodes (pooled counts that add up,
the targets judged from them, a page with its figure), and bad input as one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "option_frontier.py"
frontier = load_script(SCRIPT, "option_frontier_script")


def test_the_frontier_pools_the_scenarios_and_writes_its_page(tmp_path, capsys):
    doc = tmp_path / "FRONTIER.md"
    assert frontier.main(["--episodes", "1", "--out", str(tmp_path / "runs"), "--doc", str(doc), "--workers", "1"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| option-") or line.startswith("| cdf |")]
    n = len(frontier.SCENARIOS)
    pooled = [row for row in rows if f"({n}) |" in row]
    assert len(pooled) == len(frontier.EMERGENCY) * len(frontier.ANTICIPATE) + 1  # every option point and cdf
    assert doc.read_text().startswith("<!-- made by: python scripts/option_frontier.py")
    assert (tmp_path / "img" / "frontier" / "frontier.png").stat().st_size > 1000
    # A second call reads the runs back (resumed) and prints the same page.
    assert frontier.main(["--episodes", "1", "--out", str(tmp_path / "runs"), "--doc", ""]) == 0
    assert capsys.readouterr().out == out


def test_a_point_meets_the_targets_only_with_no_collision_and_both_rates_low():
    rate = frontier.Rate
    assert frontier.Pooled(0, 100, rate(5, 80), rate(0, 80), 0.0).meets
    assert not frontier.Pooled(1, 100, rate(5, 80), rate(0, 80), 0.0).meets
    assert not frontier.Pooled(0, 100, rate(9, 80), rate(0, 80), 0.0).meets
    assert not frontier.Pooled(0, 100, rate(5, 80), rate(1, 80), 0.0).meets


def test_bad_input_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        frontier.main(["--episodes", "0"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage:") or "option_frontier: error: " in err
    assert "--episodes" in err


def test_an_output_that_is_not_a_directory_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    with pytest.raises(SystemExit) as exit_:
        frontier.main(["--episodes", "1", "--out", str(tmp_path / "file"), "--doc", ""])
    assert exit_.value.code == 2
    last = capsys.readouterr().err.splitlines()[-1]
    assert last.startswith("option_frontier: error: ") and "Not a directory" in last
