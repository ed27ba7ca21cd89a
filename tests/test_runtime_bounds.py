"""Bounds on what a run may cost and on what the library takes (issue 28): list arguments
of the command line, empty output paths, seeds, a planner's answer, a scene's timestep,
buildings over a car's start or route, ``min_gap`` at a building contact, and the Ray
probe against a server that is not Ray."""

from __future__ import annotations

import pytest

from cdf_mj import cli
from tests.cli_helpers import assert_one_line_error, run_cli


# ------------------------------------------------------------------ command line lists
@pytest.mark.parametrize(("argv", "needle"), [
    (["bench", "--particles", ",".join(["100"] * 20_000)], "--particles"),
    (["bench", "--workers", ",".join(["1"] * 101)], "--workers"),
    (["sweep", "beta", "--values", ",".join(["0.5"] * 101)], "--values"),
])
def test_a_list_argument_holds_at_most_100_items(capsys, argv, needle):
    with pytest.raises(ValueError, match="1 to 100"):  # CLIError while parsing: before any run
        cli.build_parser().parse_args(argv)
    status, out, err = run_cli(capsys, *argv)
    assert_one_line_error(status, out, err, needle, "1 to 100")


def test_a_list_of_100_items_is_read():
    from cdf_mj.cli.args import MAX_LIST_ITEMS, _comma_list, _particles
    from cdf_mj.cli.sweep import MAX_SWEEP_VALUES, _value_list

    assert MAX_SWEEP_VALUES == MAX_LIST_ITEMS == 100
    assert _comma_list(_particles, "positive integers")(",".join(["7"] * 100)) == [7] * 100
    assert _value_list("0.5, 1e-3,") == [0.5, 1e-3]


_CHEAP = ("--episodes", "1", "--planners", "constant", "--workers", "1", "--quiet")  # fails fast before the fix


@pytest.mark.parametrize("argv", [
    ["experiment", *_CHEAP], ["reproduce", *_CHEAP], ["sweep", "beta", "--values", "0.5", "--no-figure", *_CHEAP],
    ["report", "."], ["render", "--seed", "1", "--planner", "constant", "--set", "timing.duration=0.2"],
])
@pytest.mark.parametrize("out", ["", "  "])
def test_an_empty_out_path_is_refused(capsys, tmp_path, monkeypatch, argv, out):
    monkeypatch.chdir(tmp_path)
    status, stdout, err = run_cli(capsys, *argv, "--out", out)
    assert_one_line_error(status, stdout, err, "--out", "empty path")
    assert list(tmp_path.iterdir()) == []  # nothing written into the working directory
