"""The ``cdf-mj`` command line: JSON on success, one line and exit status 2 on bad input;
experiments that can be run again; the list of commands."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj import cli
from cdf_mj.extras import install_hint
from cdf_mj.records import EpisodeRecord

REPO = Path(__file__).resolve().parent.parent
RECORD_KEYS = {f.name for f in dataclasses.fields(EpisodeRecord)}


def test_episode_prints_record_as_json(capsys):
    status, out, err = run_cli(capsys, "episode", "--seed", "3", "--planner", "constant")
    assert status == 0, err
    record = json.loads(out)
    assert set(record) == RECORD_KEYS
    assert record["seed"] == 3
    assert record["planner"] == "constant"
    assert record["label"] in {"Cutoff", "Yield", "Right"}
    assert record["trace"] is None


def test_same_seed_same_json(capsys):
    argv = ("episode", "--seed", "5", "--planner", "reactive")
    first = run_cli(capsys, *argv)
    second = run_cli(capsys, *argv)
    assert first[0] == 0
    assert first == second


def test_flags_and_overrides_reach_the_episode(capsys):
    status, out, err = run_cli(capsys, "episode", "--seed", "2", "--no-label", "--trace",
                               "--set", "ego.start_spread=[1.5, 1.5]", "--set", "obstacle.beta=0")
    assert status == 0, err
    record = json.loads(out)
    assert record["label"] is None
    assert record["ego_start_offset"] == pytest.approx(1.5)  # a zero-width spread
    assert record["first_seen_time"] is None  # beta = 0: never observes the ego
    assert len(record["trace"]["t"]) > 0


def test_unknown_planner_lists_choices(capsys):
    assert_one_line_error(*run_cli(capsys, "episode", "--planner", "nosuch"),
                          "nosuch", "constant", "reactive")


def test_negative_seed(capsys):
    assert_one_line_error(*run_cli(capsys, "episode", "--seed", "-1"), "--seed", "non-negative")


def test_out_of_range_parameter_names_it_and_its_range(capsys):
    assert_one_line_error(*run_cli(capsys, "episode", "--set", "obstacle.beta=1.5"), "obstacle.beta", "[0, 1]")


def test_a_flat_key_of_version_0_1_still_works_with_a_note(capsys):
    """``--set beta=...`` as scripts of version 0.1 wrote it: the same episode, and one line
    on stderr naming the dotted key."""
    argv = ["episode", "--seed", "2", "--no-label", "--planner", "constant"]
    status, old, err = run_cli(capsys, *argv, "--set", "beta=0", "--set", "ego_start_spread=[1.5, 1.5]")
    assert status == 0 and err.splitlines() == ["cdf-mj: note: --set beta is now --set obstacle.beta",
                                                "cdf-mj: note: --set ego_start_spread is now --set ego.start_spread"]
    status, new, err = run_cli(capsys, *argv, "--set", "obstacle.beta=0", "--set", "ego.start_spread=[1.5, 1.5]")
    assert status == 0 and err == "" and new == old


@pytest.mark.parametrize(("assignment", "needle"), [
    ("nosuch=1", "nosuch"),
    ("obstacle.beta=abc", "obstacle.beta"),
    ("ego.start_spread=[1,2,3]", "ego.start_spread"),
    ("obstacle.beta", "key=value"),
])
def test_bad_override(capsys, assignment, needle):
    assert_one_line_error(*run_cli(capsys, "episode", "--set", assignment), needle)


def test_missing_scene_file(capsys):
    assert_one_line_error(*run_cli(capsys, "episode", "--scene", "/nonexistent.xml"),
                          "/nonexistent.xml")


def test_scene_without_cars(capsys):
    """A scene that compiles but lacks the cars (SceneError) is bad input too."""
    scene = REPO / "models" / "xml" / "intersection.xml"
    assert_one_line_error(*run_cli(capsys, "episode", "--scene", str(scene)), "ego_chassis")


def test_no_command_lists_every_command_on_one_line(capsys):
    status, out, err = run_cli(capsys)
    assert status == 0 and err == ""
    commands = [line.split()[0] for line in out.split("commands:\n")[1].split("\n\n")[0].splitlines()]
    assert commands == ["reproduce", "episode", "experiment", "presets", "sweep", "render", "report", "falsify",
                        "estimate", "bench"]
    assert "cdf-mj COMMAND --help" in out
    # the same list with --debug alone: a flag is not a command
    assert run_cli(capsys, "--debug")[1] == out


def test_unknown_command(capsys):
    assert_one_line_error(*run_cli(capsys, "nosuch"), "nosuch", "reproduce")


def test_version(capsys):
    status, out, _ = run_cli(capsys, "--version")
    assert status == 0
    assert out.strip() == f"cdf-mj {cli.__version__}"


def test_module_entry_point_runs_in_a_subprocess():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    proc = subprocess.run(
        [sys.executable, "-m", "cdf_mj", "episode", "--seed", "1", "--planner", "reactive"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    record = json.loads(proc.stdout)
    assert record["seed"] == 1
    assert record["planner"] == "reactive"


def _unwrapped(text: str) -> str:
    """``text`` without whitespace: argparse wraps help lines, also at hyphens."""
    return "".join(text.split())


def test_help_of_an_optional_feature_names_its_extra(capsys):
    for command, extra in (("render", "viz"), ("report", "viz"), ("sweep", "viz"), ("experiment", "ray")):
        status, out, _ = run_cli(capsys, command, "--help")
        assert status == 0
        assert _unwrapped(install_hint(extra)) in _unwrapped(out), command


# ----------------------------------------------------------------- experiments run again
SMALL_RUN = ("--episodes", "2", "--planner", "reactive", "--workers", "1", "--quiet")


def test_an_experiment_run_again_prints_its_stored_tables(capsys, tmp_path):
    out = tmp_path / "run"
    status, first, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))
    assert status == 0, err
    records = (out / "episodes.jsonl").read_bytes()
    status, again, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))
    assert status == 0, err
    assert f"all 2 records were already in {out}/episodes.jsonl" in again
    assert again.split("\n\n", 1)[1] == first.split("\n\n", 1)[1]  # the same tables
    assert (out / "episodes.jsonl").read_bytes() == records  # nothing ran, nothing written


def test_an_unfinished_experiment_is_finished_by_the_same_command(capsys, tmp_path):
    out = tmp_path / "run"
    assert run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))[0] == 0
    lines = (out / "episodes.jsonl").read_text().splitlines(keepends=True)
    (out / "episodes.jsonl").write_text(lines[0])  # as if killed after the first seed
    status, text, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))
    assert status == 0, err
    assert "1 run in" in text and "1 already on disk" in text
    assert sorted((out / "episodes.jsonl").read_text().splitlines(keepends=True)) == sorted(lines)


def test_other_settings_are_refused_with_the_keys_that_differ(capsys, tmp_path):
    out = tmp_path / "run"
    assert run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))[0] == 0
    before = (out / "episodes.jsonl").read_bytes()
    assert_one_line_error(*run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out), "--set",
                                   "obstacle.beta=0.1"), "other settings", "scenario.obstacle.beta", "--force")
    assert "resume=" not in capsys.readouterr().err
    assert (out / "episodes.jsonl").read_bytes() == before


def test_force_starts_over_and_removes_only_that_runs_files(capsys, tmp_path):
    out = tmp_path / "run"
    assert run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))[0] == 0
    (out / "report.md").write_text("a file of the user's\n")
    status, text, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out), "--force",
                                "--set", "obstacle.beta=0.1")
    assert status == 0, err
    assert "2 run in" in text and "already on disk" not in text
    settings = json.loads((out / "settings.json").read_text())
    assert settings["scenario"]["obstacle"]["beta"] == 0.1
    assert len((out / "episodes.jsonl").read_text().splitlines()) == 2
    assert (out / "report.md").read_text() == "a file of the user's\n"


@pytest.mark.parametrize("command", ["experiment", "reproduce"])
def test_resume_of_earlier_releases_is_accepted_with_a_one_line_note(capsys, tmp_path, command):
    """``--resume`` (needed once to continue a run) does nothing more than the same command
    without it, and says so in one line on stderr; stdout and the records are unchanged."""
    out = tmp_path / "run"
    assert run_cli(capsys, command, *SMALL_RUN, "--out", str(out))[0] == 0
    lines = (out / "episodes.jsonl").read_text().splitlines(keepends=True)
    (out / "episodes.jsonl").write_text(lines[0])  # as if killed after the first seed
    status, text, err = run_cli(capsys, command, *SMALL_RUN, "--out", str(out), "--resume", "--retry-failed")
    assert status == 0, err
    assert err.splitlines() == ["cdf-mj: --resume is no longer needed: the same command continues an "
                                "interrupted run"]
    assert "1 run in" in text and "1 already on disk" in text
    assert sorted((out / "episodes.jsonl").read_text().splitlines(keepends=True)) == sorted(lines)


def test_force_and_retry_failed_together_are_refused(capsys, tmp_path):
    assert_one_line_error(*run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(tmp_path), "--force",
                                   "--retry-failed"), "--force", "--retry-failed")
    assert list(tmp_path.iterdir()) == []


def test_parse_overrides_types_values_like_the_config():
    assert cli.parse_overrides(["obstacle.beta=0", "ego.start_spread=[-4, 4]", "obstacle.beta=0.1"]) == {
        "obstacle.beta": 0.1, "ego.start_spread": (-4.0, 4.0)}
    with pytest.raises(ValueError, match="names"):
        cli.parse_overrides(["names=x"])  # the nested SceneNames is not a --set field


@pytest.mark.parametrize("command", [["experiment"], ["reproduce"], ["sweep", "tau"],
                                     ["render", "--out", "x.mp4"]])
def test_every_command_that_runs_the_cdf_takes_the_same_cdf_settings(command):
    args = cli.build_parser().parse_args([*command, "--particles", "300", "--tau", "0.6", "--cutoff-rule", "paper"])
    cdf = cli.cdf_from_args(args)
    assert (cdf.n_particles, cdf.tau, cdf.cutoff_rule) == (300, 0.6, "paper")


def test_tables_print_as_text_by_default_and_as_markdown_on_request(capsys, tmp_path):
    out = tmp_path / "run"
    status, text, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out))
    assert status == 0, err
    status, markdown, err = run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out), "--format", "markdown")
    assert status == 0, err
    assert "|---" in markdown and "|---" not in text
    assert "reactive" in text and "reactive" in markdown
    assert_one_line_error(*run_cli(capsys, "experiment", *SMALL_RUN, "--out", str(out), "--format", "html"),
                          "--format", "text", "markdown")


def test_the_first_run_after_an_install_says_it_compiles(tmp_path):
    """With an empty Numba cache a simulating command says, on stderr, that it compiles the
    kernels (seconds of silence would look like a hang); once they are cached, it says
    nothing; stdout stays the record's JSON either way."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    command = [sys.executable, "-m", "cdf_mj", "episode", "--seed", "0", "--planner", "constant",
               "--set", "timing.duration=0.5"]
    first, again = (subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
                    for _ in range(2))
    assert first.returncode == 0 and again.returncode == 0, first.stderr + again.stderr
    assert "compiling the simulation's kernels" in first.stderr and str(tmp_path / "numba") in first.stderr
    assert "compiling" not in again.stderr
    assert json.loads(first.stdout) == json.loads(again.stdout)
