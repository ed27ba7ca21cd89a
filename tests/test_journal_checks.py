"""What a falsification run reads back and where it writes (issue 39, causes 1, 2, 3, 8, 9):
every journal line checked (finite robustness, a ``failed`` that follows from it, one
outcome per episode, nesting bounded) before it steers a resumed search; the journal never
reached through a link or a FIFO; an estimate in which episodes raised never reliable; and
one kind of run per directory, so that no command replaces another's ``settings.json``.

None of these runs an episode: the journals are written line by line, and every refusal
comes before the first episode."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.falsify.estimate import Estimate
from cdf_mj.falsify.evaluate import ERROR_ROBUSTNESS, JOURNAL_FILE, Evaluation, Journal, key_of

SPACE = '''description = "One dimension, for journals written by hand."

[failure]
margin = "gap"
threshold = 0.0

[dims."ego.start_spread"]
range = [-8.0, 8.0]
'''


def _line(seed: int = 1, robustness: float = 2.5, failed: bool = False, error: str | None = None,
          changes: dict[str, object] | None = None) -> str:
    """A journal line of an episode of planner ``reactive`` at point ``(0.5,)`` (``changes``
    replace fields after the key is made)."""
    ev = Evaluation("reactive", seed, (0.5,), (), robustness, failed, {} if error else {"min_gap": 1.0}, error)
    data = {**ev.to_dict(), **(changes or {})}
    return json.dumps(data) + "\n"


def _journal(tmp_path: Path, *lines: str) -> Path:
    path = tmp_path / JOURNAL_FILE
    path.write_text("".join(lines))
    return path


def _refused(path: Path, *needles: str) -> None:
    before = path.read_bytes()
    with pytest.raises(ValueError, match=r"is not an evaluation|records an episode") as info:
        Journal(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    for needle in needles:
        assert needle in message, (needle, message)
    assert path.read_bytes() == before  # nothing truncated or appended


# ----------------------------------------------------------------- cause 1: values
def test_a_well_formed_journal_is_read(tmp_path):
    path = _journal(tmp_path, _line(1), _line(2, -0.5, True), _line(3, ERROR_ROBUSTNESS, False, "boom"),
                    _line(1))  # the same episode twice with the same outcome: harmless
    journal = Journal(path)
    journal.close()
    assert len(journal.entries) == 3
    assert journal.get("reactive", 2, (0.5,)).failed


@pytest.mark.parametrize(("line", "needle"), [
    ('{"key": "x", "robustness": Infinity}', "line 2 is not an evaluation"),
    (_line(2).replace("2.5", "Infinity"), "robustness inf is not a finite number"),
    (_line(2).replace("2.5", "NaN"), "robustness nan is not a finite number"),
    (_line(2).replace("2.5", "-Infinity"), "robustness -inf is not a finite number"),
    (_line(2, -0.5, False), "'failed' is false for robustness -0.5"),
    (_line(2, 3.0, True), "'failed' is true for robustness 3.0"),
    (_line(2, changes={"failed": "yes"}), "'failed' is not true or false"),
    (_line(2, changes={"robustness": "2.5"}), "robustness '2.5' is not a finite number"),
    (_line(2, 0.5, False, "boom"), "an episode that raised has robustness 1000"),
    (_line(2, changes={"seed": 1.5}), "'seed' is not an integer"),
    (_line(2, changes={"seed": True}), "'seed' is not an integer"),
    (_line(2, changes={"point": [float("inf")]}), "'point' is not a list of finite numbers"),
    (_line(2, changes={"summary": []}), "'summary' not an object"),
])
def test_a_journal_value_the_writer_never_writes_is_one_line_naming_the_file_and_line(tmp_path, line, needle):
    _refused(_journal(tmp_path, _line(1), line, _line(3)), "line 2", needle, "the file is damaged")


def test_an_episode_recorded_twice_with_another_outcome_is_one_line_naming_both_lines(tmp_path):
    path = _journal(tmp_path, _line(1, 2.5), _line(2), _line(1, -1.0, True))
    _refused(path, "line 3 records an episode of line 1 again with another outcome")


def test_an_infinite_robustness_never_reaches_the_search(tmp_path):
    """The turn-4 case: one robustness set to Infinity made a resumed falsify diverge."""
    path = _journal(tmp_path, _line(1), _line(2).replace("2.5", "Infinity"))
    with pytest.raises(ValueError, match="not a finite number"):
        Journal(path)


# ----------------------------------------------------------------- cause 2: nesting
@pytest.mark.parametrize("depth", [100, 5000, 200_000])
def test_a_deeply_nested_journal_line_is_one_line_not_a_recursion_error(tmp_path, depth):
    path = _journal(tmp_path, _line(1), "[" * depth + "]" * depth + "\n", _line(3))
    _refused(path, "line 2 is not an evaluation (nested too deeply)")


def test_a_journal_line_that_is_not_utf8_is_one_line(tmp_path):
    path = tmp_path / JOURNAL_FILE
    path.write_bytes(_line(1).encode() + b'{"key": "\xff\xfe"}\n')
    _refused(path, "line 2 is not an evaluation")


# ----------------------------------------------------------------- cause 3: links
def test_a_journal_linked_elsewhere_is_refused_and_nothing_is_written_there(tmp_path):
    outside = tmp_path / "outside.jsonl"
    outside.write_text("")
    run = tmp_path / "run"
    run.mkdir()
    (run / JOURNAL_FILE).symlink_to(outside)
    with pytest.raises(ValueError, match="is a symbolic link: the journal must be a regular file") as info:
        Journal(run / JOURNAL_FILE)
    assert "\n" not in str(info.value)
    assert outside.read_bytes() == b""
    (run / JOURNAL_FILE).unlink()
    (run / JOURNAL_FILE).symlink_to(tmp_path / "absent.jsonl")  # a dangling link: not created through
    with pytest.raises(ValueError, match="symbolic link"):
        Journal(run / JOURNAL_FILE)
    assert not (tmp_path / "absent.jsonl").exists()


@pytest.mark.parametrize("kind", ["fifo", "directory"])
def test_a_journal_that_is_not_a_regular_file_is_refused_without_blocking(tmp_path, kind):
    path = tmp_path / JOURNAL_FILE
    os.mkfifo(path) if kind == "fifo" else path.mkdir()
    with pytest.raises(ValueError, match="not a regular file"):
        Journal(path)


def test_falsify_into_a_directory_with_a_linked_journal_is_one_line(tmp_path, capsys):
    space = tmp_path / "one.toml"
    space.write_text(SPACE)
    outside = tmp_path / "outside.jsonl"
    outside.write_text("")
    out = tmp_path / "run"
    out.mkdir()
    (out / JOURNAL_FILE).symlink_to(outside)
    status, stdout, err = run_cli(capsys, "falsify", "--space", str(space), "--planner", "reactive",
                                  "--workers", "1", "--out", str(out), "--quiet", "--no-figure")
    assert_one_line_error(status, stdout, err, JOURNAL_FILE, "symbolic link")
    assert outside.read_bytes() == b""


def test_falsify_resumed_on_a_damaged_journal_is_one_line_before_any_episode(tmp_path, capsys):
    space = tmp_path / "one.toml"
    space.write_text(SPACE)
    out = tmp_path / "run"
    out.mkdir()
    (out / JOURNAL_FILE).write_text(_line(1) + _line(2).replace("2.5", "Infinity"))
    status, stdout, err = run_cli(capsys, "falsify", "--space", str(space), "--planner", "reactive",
                                  "--workers", "1", "--out", str(out), "--quiet", "--no-figure")
    assert_one_line_error(status, stdout, err, f"{out / JOURNAL_FILE}: line 2", "not a finite number")
    assert not (out / "summary.json").exists()


# ----------------------------------------------------------------- cause 8: estimates that raised
@pytest.mark.parametrize("method", ["mc", "ce"])
def test_an_estimate_whose_episodes_raised_is_not_reliable_and_says_how_many(method):
    bound = Estimate(method, "reactive", 10, 10, 0, 0.0, (0.0, 0.28), upper_only=True, errors=10)
    assert not bound.reliable and bound.to_dict()["reliable"] is False
    assert "10 of 10 episodes raised" in bound.text() and "not reliable" in bound.text()
    some = Estimate(method, "reactive", 200, 100, 30, 0.3, (0.2, 0.4), ess=30.0, top_share=0.05, errors=3)
    assert not some.reliable and "3 of 200 episodes raised" in some.text()
    clean = Estimate(method, "reactive", 200, 100, 30, 0.3, (0.2, 0.4), ess=30.0, top_share=0.05)
    assert clean.reliable and clean.text() == "0.3 [0.2, 0.4]"


# ----------------------------------------------------------------- cause 9: one kind per directory
def _settings(directory: Path, **data: object) -> bytes:
    directory.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data).encode()
    (directory / "settings.json").write_bytes(text)
    return text


def test_the_kind_of_run_a_directory_holds(tmp_path):
    from cdf_mj.experiments.store import check_run_kind, run_kind

    assert run_kind(tmp_path / "absent") is None
    _settings(tmp_path / "exp", seeds=[0, 4], planners=["cdf"], scenario={}, cdf={}, scene="s.xml")
    _settings(tmp_path / "fal", kind="falsify")
    _settings(tmp_path / "est", kind="estimate")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "settings.json").write_text("{not json")
    assert [run_kind(tmp_path / d) for d in ("exp", "fal", "est", "bad")] == ["experiment", "falsify", "estimate",
                                                                             None]
    check_run_kind(tmp_path / "fal", "falsify")
    with pytest.raises(ValueError, match=r"holds another kind of run \(a falsify, by its settings.json\), not an "
                                         "experiment"):
        check_run_kind(tmp_path / "fal", "experiment")


def test_an_estimate_into_an_experiments_directory_is_refused_and_its_settings_kept(tmp_path):
    from cdf_mj.falsify.run import estimate
    from cdf_mj.falsify.space import load_space

    space = tmp_path / "one.toml"
    space.write_text(SPACE)
    out = tmp_path / "exp"
    before = _settings(out, seeds=[0, 4], planners=["reactive"], scenario={}, cdf={}, scene="s.xml", version="x")
    (out / "episodes.jsonl").write_text('{"seed": 0}\n')
    with pytest.raises(ValueError, match=r"holds another kind of run \(an experiment") as info:
        estimate(load_space(space), "reactive", 4, out, method="mc", workers=1)
    assert "\n" not in str(info.value) and str(out) in str(info.value)
    assert (out / "settings.json").read_bytes() == before and not (out / JOURNAL_FILE).exists()


def test_an_experiment_into_a_falsification_directory_is_refused_and_its_settings_kept(tmp_path, capsys):
    out = tmp_path / "fal"
    before = _settings(out, kind="falsify", planner="reactive")
    (out / JOURNAL_FILE).write_text(_line(1))
    status, stdout, err = run_cli(capsys, "experiment", "--episodes", "2", "--workers", "1",
                                  "--out", str(out), "--quiet")
    assert_one_line_error(status, stdout, err, str(out), "another kind of run (a falsify")
    assert (out / "settings.json").read_bytes() == before and not (out / "episodes.jsonl").exists()


def test_experiment_force_never_removes_a_falsifications_settings(tmp_path, capsys):
    out = tmp_path / "fal"
    before = _settings(out, kind="falsify", planner="reactive")
    (out / JOURNAL_FILE).write_text(_line(1))
    status, stdout, err = run_cli(capsys, "experiment", "--episodes", "2", "--workers", "1", "--force",
                                  "--out", str(out), "--quiet")
    assert_one_line_error(status, stdout, err, str(out), "another kind of run (a falsify")
    assert (out / "settings.json").read_bytes() == before and not (out / "episodes.jsonl").exists()


def test_key_of_is_what_the_lines_carry():
    assert json.loads(_line(4))["key"] == key_of("reactive", 4, (0.5,))
