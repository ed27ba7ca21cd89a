"""One command-line vocabulary (issue 34): the same idea has the same flag on every command,
the spellings of earlier releases still work with a one-line note, ``--help`` shows the new
ones only, and no command module imports a private name of another module."""

from __future__ import annotations

import argparse
import ast
import json
import socket
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj import cli
from cdf_mj.cli.args import add_option, notes

REPO = Path(__file__).resolve().parent.parent

#: The least command line of each command (its required arguments).
BARE = {"reproduce": ["reproduce"], "episode": ["episode"], "experiment": ["experiment"], "presets": ["presets"],
        "sweep": ["sweep", "beta"], "render": ["render", "--out", "x.mp4"], "report": ["report", "dir"],
        "falsify": ["falsify"], "estimate": ["estimate"], "bench": ["bench"]}
RUNS_EPISODES = ("reproduce", "episode", "experiment", "sweep", "render", "falsify", "estimate", "bench")
RUNS_MANY = ("reproduce", "experiment", "sweep", "falsify", "estimate")

#: flag -> (its words on a command line, what it reads as, the commands that take it).
VOCABULARY: dict[str, tuple[list[str], object, tuple[str, ...]]] = {
    "--seed": (["7"], 7, ("reproduce", "episode", "experiment", "sweep", "render", "falsify", "estimate")),
    "--episodes": (["3"], 3, ("reproduce", "experiment", "sweep", "falsify", "estimate", "bench")),
    "--planner": (["reactive"], "reactive", ("reproduce", "episode", "experiment", "sweep", "render", "falsify",
                                             "estimate", "report")),
    "--workers": (["2"], 2, (*RUNS_MANY, "bench")),
    "--backend": (["ray"], "ray", RUNS_MANY),
    "--address": (["h:1"], "h:1", RUNS_MANY),
    "--quiet": ([], True, (*RUNS_MANY, "bench")),
    "--scene": (["s.xml"], "s.xml", RUNS_EPISODES),
    "--names": (["n.json"], "n.json", RUNS_EPISODES),
    "--preset": (["cautious"], "cautious", RUNS_EPISODES),
    "--set": (["obstacle.beta=0.1"], ["obstacle.beta=0.1"], RUNS_EPISODES),
    "--out": (["o"], "o", ("reproduce", "experiment", "sweep", "render", "report", "falsify", "estimate")),
}
#: Where a flag keeps its value: a list of planners, bench's --workers (one number or a list).
LISTS = {("--planner", "render"): "planner", **{("--planner", c): "planners" for c in ("reproduce", "experiment",
                                                                                       "sweep")}}


def _options(command: str) -> set[str]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {flag for action in sub.choices[command]._actions for flag in action.option_strings}


#: (command, old argv, new argv): every old spelling and what it now reads.
OLD_SPELLINGS = [
    ("experiment", ["--seed0", "4"], ["--seed", "4"]),
    ("reproduce", ["--seed0", "4"], ["--seed", "4"]),
    ("sweep", ["--seed0", "4"], ["--seed", "4"]),
    ("experiment", ["--planners", "cdf,imm"], ["--planner", "cdf,imm"]),
    ("reproduce", ["--planners", "cdf,imm"], ["--planner", "cdf,imm"]),
    ("sweep", ["--planners", "cdf,imm"], ["--planner", "cdf,imm"]),
    ("render", ["--compare", "cdf,imm"], ["--planner", "cdf,imm"]),
    ("falsify", ["--budget", "50"], ["--episodes", "50"]),
    ("estimate", ["--budget", "50"], ["--episodes", "50"]),
]


def _parse(argv: list[str]) -> argparse.Namespace:
    return cli.build_parser().parse_args(argv)


def _plain(args: argparse.Namespace) -> dict[str, object]:
    """The namespace without the record of how it was spelled."""
    return {k: v for k, v in vars(args).items() if not k.startswith("cli_") and k not in ("func",)}


@pytest.mark.parametrize("flag", VOCABULARY)
def test_every_command_that_has_an_idea_takes_it_by_the_same_flag(flag):
    words, value, commands = VOCABULARY[flag]
    for command in BARE:
        assert (flag in _options(command)) == (command in commands), (command, flag)
        if command not in commands:
            continue
        args = _parse([*BARE[command], flag, *words])
        if (flag, command) in LISTS:
            assert getattr(args, LISTS[flag, command]) == [value], command
        elif (flag, command) == ("--workers", "bench"):
            assert args.workers == [value]
        else:
            assert getattr(args, {"--set": "overrides"}.get(flag, flag[2:])) == value, command


@pytest.mark.parametrize(("command", "old", "new"), OLD_SPELLINGS, ids=lambda v: " ".join(v) if isinstance(v, list)
                         else v)
def test_an_old_spelling_reads_as_the_new_one_and_leaves_a_note(command, old, new):
    before, after = _parse([*BARE[command], *old]), _parse([*BARE[command], *new])
    assert _plain(before) == _plain(after)
    assert notes(before) == [f"{old[0]} is now {new[0]} (the old spelling still works)"]
    assert notes(after) == []


@pytest.mark.parametrize(("command", "old", "new"), OLD_SPELLINGS[:1] + OLD_SPELLINGS[3:4] + OLD_SPELLINGS[6:8])
def test_an_old_and_a_new_spelling_together_are_refused(command, old, new):
    with pytest.raises(ValueError, match=f"{new[0]}: not used with {old[0]}, its old spelling"):
        _parse([*BARE[command], *new, *old])


def test_the_same_spelling_twice_is_the_last_as_argparse_reads_it():
    assert _parse(["falsify", "--budget", "20", "--budget", "30"]).episodes == 30


def test_the_note_comes_once_the_command_has_run_and_the_records_are_the_same(capsys, tmp_path):
    common = ["experiment", "--episodes", "1", "--workers", "1", "--quiet", "--set", "timing.duration=1.0"]
    status, old, err = run_cli(capsys, *common, "--seed0", "3", "--planners", "constant", "--out", str(tmp_path / "a"))
    assert status == 0 and err.splitlines() == [
        "cdf-mj: note: --seed0 is now --seed (the old spelling still works)",
        "cdf-mj: note: --planners is now --planner (the old spelling still works)"]
    status, new, err = run_cli(capsys, *common, "--seed", "3", "--planner", "constant", "--out", str(tmp_path / "b"))
    assert status == 0 and err == ""
    assert old.split("\n\n", 1)[1] == new.split("\n\n", 1)[1]  # the same tables
    records = [json.loads((tmp_path / d / "episodes.jsonl").read_text()) for d in "ab"]
    assert records[0]["seed"] == 3 and records[0] == records[1]


def test_a_bad_command_line_in_old_spellings_stays_one_error_line(capsys, tmp_path):
    out = tmp_path / "x"
    assert_one_line_error(*run_cli(capsys, "experiment", "--seed0", str(2**53 - 1), "--episodes", "2",
                                   "--planners", "constant", "--out", str(out)), "beyond the largest seed")
    assert_one_line_error(*run_cli(capsys, "experiment", "--seed0", "-1"), "--seed0", "non-negative")
    assert not out.exists()


@pytest.mark.parametrize("command", BARE)
def test_help_shows_one_vocabulary(capsys, command):
    status, out, _ = run_cli(capsys, BARE[command][0], "--help")
    assert status == 0
    words = set(out.replace(",", " ").replace("[", " ").replace("]", " ").split())
    for old in ("--seed0", "--planners", "--budget"):
        assert old not in words, (command, old)
    assert ("--compare" in words) == (command == "falsify"), command  # falsify's: the replays' planners


def test_the_run_options_read_alike_on_every_command():
    """One adder: the same help for --workers, --backend, --address, --scene, --names, --set and
    --quiet wherever they are (bench's --workers times its own pool; falsify's --preset
    applies over the space's preset)."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps: dict[str, set[str]] = {}
    for name, p in sub.choices.items():
        for action in p._actions:
            for flag in action.option_strings:
                if flag in VOCABULARY and flag not in ("--seed", "--episodes", "--planner", "--out", "--preset") \
                        and not (name == "bench" and flag == "--workers"):
                    helps.setdefault(flag, set()).add(str(action.help))
    assert set(helps) == {"--workers", "--backend", "--address", "--quiet", "--scene", "--names", "--set"}
    assert all(len(h) == 1 for h in helps.values()), helps


def test_bench_takes_one_number_and_the_scaling_lists_by_their_own_names():
    args = _parse(["bench", "--particles", "500", "--workers", "3"])
    assert (args.particles, args.workers, notes(args)) == ([500], [3], [])
    args = _parse(["bench", "--scale-particles", "250,1000", "--scale-workers", "1,2,4"])
    assert (args.scale_particles, args.scale_workers) == ([250, 1000], [1, 2, 4])


def test_bench_with_a_list_as_earlier_releases_took_it_works_with_a_note(capsys, monkeypatch):
    import cdf_mj.experiments.bench as bench
    import cdf_mj.falsify.throughput as throughput

    seen = {}
    monkeypatch.setattr(bench, "bench_reproduction", lambda episodes, workers, **kw: seen.setdefault("w", workers)
                        and [])
    monkeypatch.setattr(throughput, "bench_falsification", lambda episodes, **kw: seen.setdefault("f", episodes))
    monkeypatch.setattr(bench, "format_rows", lambda rows, floor: "table")
    monkeypatch.setattr(bench, "FloorProbe", lambda **kw: type("P", (), {"floor": lambda self: None})())
    status, out, err = run_cli(capsys, "bench", "--only-reproduce", "--workers", "1,2", "--quiet")
    assert status == 0 and seen["w"] == (1, 2) and seen["f"] == 400 and out == "table\n"
    assert err.splitlines() == ["cdf-mj: note: bench --workers with a list is now --scale-workers (the old "
                                "spelling still works)"]
    assert_one_line_error(*run_cli(capsys, "bench", "--workers", "2", "--scale-workers", "1,2"),
                          "--workers: not used with --scale-workers")


def test_add_option_keeps_an_old_spelling_out_of_the_help():
    parser = argparse.ArgumentParser(prog="x")
    add_option(parser, "--new", old=("--old",), type=int, default=1, help="the new one")
    assert "--old" not in parser.format_help() and "--new" in parser.format_help()
    args = parser.parse_args(["--old", "2"])
    assert args.new == 2 and notes(args) == ["--old is now --new (the old spelling still works)"]
    assert parser.parse_args([]).new == 1


def test_falsify_and_estimate_apply_preset_and_set_over_the_spaces_base(capsys, tmp_path):
    out = tmp_path / "est"
    argv = ["estimate", "--method", "mc", "--planner", "constant", "--episodes", "2", "--workers", "1", "--quiet",
            "--preset", "slow-pull-out", "--set", "clear_distance=12.0", "--set", "timing.duration=1.0"]
    status, _, err = run_cli(capsys, *argv, "--out", str(out))
    assert status == 0 and "--set obstacle.clear_distance" in err, err  # read as --set reads it
    base = json.loads((out / "settings.json").read_text())["space_spec"]["base"]
    assert base["obstacle"]["clear_distance"] == 12.0 and base["timing"]["duration"] == 1.0
    assert base["obstacle"]["accel"] == 1.2  # the preset's driver pulls out slowly (a dimension: with a note)
    # the same directory with another base world is another run: refused
    assert_one_line_error(*run_cli(capsys, *argv[:-4], "--out", str(out)), "space")
    assert_one_line_error(*run_cli(capsys, "falsify", "--set", "obstacle.beta=7", "--out", str(tmp_path / "f")),
                          "obstacle.beta")
    assert not (tmp_path / "f").exists()


def test_a_set_on_a_dimension_of_the_space_is_refused_and_a_preset_on_one_is_told(capsys, tmp_path):
    """The search sets its dimensions in every episode: a --set of one would be ignored
    silently, so it is refused; a preset that sets one keeps its other fields, with a note."""
    assert_one_line_error(*run_cli(capsys, "estimate", "--method", "mc", "--episodes", "2", "--set", "ego.speed=10",
                                   "--out", str(tmp_path / "e")), "--set ego.speed", "a dimension of the space")
    assert not (tmp_path / "e").exists()
    status, _, err = run_cli(capsys, "estimate", "--method", "mc", "--planner", "constant", "--episodes", "2",
                             "--workers", "1", "--quiet", "--preset", "fast-ego", "--set", "timing.duration=1.0",
                             "--out", str(tmp_path / "p"))
    assert status == 0 and "--preset fast-ego sets ego.speed, a dimension of the space" in err, err


def test_a_flat_key_in_a_file_is_a_note_through_the_installed_script(tmp_path):
    """Through the console script (where Python would show a DeprecationWarning raised in
    ``__main__``) a flat key of version 0.1 in a preset file is one note, on every command."""
    import shutil
    import subprocess
    import sys

    flat = tmp_path / "flat.toml"
    flat.write_text('description = "a file of version 0.1"\n[scenario]\nbeta = 0.2\n')
    script = shutil.which("cdf-mj") or str(Path(sys.executable).with_name("cdf-mj"))
    done = subprocess.run([script, "presets", str(flat)], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0 and "obstacle.beta = 0.2" in done.stdout
    assert done.stderr.splitlines() == [f"cdf-mj: note: preset {flat}: [scenario] beta is now [scenario.obstacle] beta"]


def test_sweep_runs_on_the_backend_it_is_given(capsys, tmp_path):
    """``sweep --backend ray --address`` reaches the runner: a cluster that is not there is one line."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    pytest.importorskip("ray")
    assert_one_line_error(*run_cli(capsys, "sweep", "beta", "--values", "0.05", "--episodes", "1", "--planner",
                                   "constant", "--no-figure", "--quiet", "--backend", "ray", "--address", address,
                                   "--out", str(tmp_path)), f"no Ray cluster answers at {address}")
    assert_one_line_error(*run_cli(capsys, "sweep", "beta", "--address", address, "--out", str(tmp_path)),
                          "--address", "--backend ray")


def _private_imports(path: Path, modules: str) -> list[str]:
    """``from MODULE import _name`` lines of ``path`` whose module starts with ``modules``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [f"{path.name}:{node.lineno}: {node.module}.{a.name}" for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(modules)
            for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]


def test_no_command_module_or_script_imports_a_private_cli_name():
    found = [hit for path in sorted((REPO / "cdf_mj" / "cli").glob("*.py")) for hit in _private_imports(path, "cdf_mj")]
    found += [hit for path in sorted((REPO / "scripts").glob("*.py")) for hit in _private_imports(path, "cdf_mj.cli")]
    assert found == []
