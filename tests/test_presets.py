"""Scenario presets: every shipped file loads, ``--preset`` on the command line (``--set``
after it, recorded in an experiment's settings), a file of version 0.1 (flat keys) still
reads, one-line errors for every broken file, and ``scripts/mismatch.py`` end to end."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, load_script, run_cli

from cdf_mj import cli
from cdf_mj.config import CDFConfig, FlatKeyWarning, ScenarioConfig
from cdf_mj.presets import (
    PresetError,
    load_preset,
    preset_description,
    preset_names,
    read_preset,
    scenario_preset_names,
)

REPO = Path(__file__).resolve().parent.parent
PRESET_DIR = REPO / "cdf_mj" / "presets"
SCRIPT = REPO / "scripts" / "mismatch.py"
#: The presets the issue asks for by name.
REQUIRED = {"paper", "default", "stop-and-wait", "slow-pull-out", "impatient", "fast-ego"}


def write(tmp_path: Path, text: str, name: str = "mine.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ----------------------------------------------------------------- the shipped presets
def test_the_names_are_the_files_of_the_package():
    assert preset_names() == sorted(p.stem for p in PRESET_DIR.glob("*.toml"))
    assert set(preset_names()) >= REQUIRED


@pytest.mark.parametrize("name", preset_names())
def test_every_shipped_preset_is_a_valid_config(name):
    config = load_preset(name)
    assert isinstance(config, ScenarioConfig)
    preset = read_preset(name)
    assert preset.config() == config
    assert len(preset_description(name)) > 40  # who the driver is and why it is a test
    if name == "default":
        assert config == ScenarioConfig() and preset.changes() == {}
    elif name != "paper":  # a preset that changed nothing would test nothing (paper pins today's values)
        assert preset.changes(), f"preset {name} changes no field from the defaults"
        for key, (default, value) in preset.changes().items():
            assert config.get(key) == value != default


def test_the_paper_preset_leaves_the_stop_line_at_once_and_others_wait():
    """The paper's driver pins no dwell and no second look, whatever the defaults become."""
    paper = read_preset("paper").scenario
    assert paper["obstacle.stop_dwell"] == (0.0, 0.0) and paper["obstacle.departure_look"] == 0.0
    default, waiting = ScenarioConfig().obstacle.stop_dwell, load_preset("stop-and-wait").obstacle.stop_dwell
    assert sum(waiting) > sum(default) and waiting[1] >= 2.0


def test_the_fast_ego_reaches_the_conflict_point_when_the_default_ego_does():
    """The start spread moves back with the speed: the same arrival times, in seconds."""
    default, fast = ScenarioConfig(), load_preset("fast-ego")
    to_conflict = 43.3  # [m] from site ego_start to site conflict (models/xml/intersection.xml)
    for d, f in zip(default.ego.start_spread, fast.ego.start_spread, strict=True):
        assert (to_conflict - f) / fast.ego.speed == pytest.approx((to_conflict - d) / default.ego.speed, abs=0.02)


# ----------------------------------------------------------------- the command line
def test_presets_lists_every_preset_and_shows_one(capsys):
    status, out, _ = run_cli(capsys, "presets")
    assert status == 0
    assert [line.split()[0] for line in out.splitlines()[:len(preset_names())]] == preset_names()
    status, out, _ = run_cli(capsys, "presets", "slow-pull-out")
    assert status == 0
    assert "obstacle.accel = 1.2  (default 2.5)" in out
    assert "slow-pull-out.toml" in out


def test_set_applies_after_the_preset_whatever_the_order():
    parser = cli.build_parser()
    for argv in (["episode", "--preset", "slow-pull-out", "--set", "obstacle.accel=2.0"],
                 ["episode", "--set", "obstacle.accel=2.0", "--preset", "slow-pull-out"]):
        config = cli.config_from_args(parser.parse_args(argv))
        assert config.obstacle.accel == 2.0  # --set wins
        assert config.obstacle.turn_speed == load_preset("slow-pull-out").obstacle.turn_speed  # the preset's
    assert cli.config_from_args(parser.parse_args(["episode"])) == ScenarioConfig()


@pytest.mark.parametrize("command", ["episode", "experiment", "reproduce", "sweep beta", "bench"])
def test_every_scenario_command_takes_a_preset(command):
    args = cli.build_parser().parse_args([*command.split(), "--preset", "fast-ego"])
    assert cli.config_from_args(args) == load_preset("fast-ego")


def test_a_users_own_file_is_a_preset(tmp_path, capsys):
    path = write(tmp_path, 'description = "A bold driver of my own."\n[scenario.obstacle]\ncritical_gap = 2\n'
                           '[scenario.ego]\nstart_spread = [-2, 2]\n')
    config = load_preset(path)
    assert config.obstacle.critical_gap == 2.0 and isinstance(config.obstacle.critical_gap, float)
    assert config.ego.start_spread == (-2.0, 2.0)
    args = cli.build_parser().parse_args(["episode", "--preset", str(path)])
    assert cli.config_from_args(args) == config
    status, out, _ = run_cli(capsys, "presets", str(path))
    assert status == 0 and "obstacle.critical_gap = 2.0  (default 5.0)" in out


def test_a_flat_file_of_version_0_1_still_reads_with_a_note(tmp_path):
    """The flat keys of version 0.1 directly in [scenario]: the same config, and a
    DeprecationWarning naming the table and key to write instead."""
    flat = write(tmp_path, 'description = "A bold driver of version 0.1."\n[scenario]\ncritical_gap = 2\n'
                           'obstacle_accel = 1.5\nego_start_spread = [-2, 2]\n', "flat.toml")
    nested = write(tmp_path, 'description = "A bold driver of version 0.1."\n[scenario.obstacle]\n'
                             'critical_gap = 2\naccel = 1.5\n[scenario.ego]\nstart_spread = [-2, 2]\n', "nested.toml")
    with pytest.warns(FlatKeyWarning, match="is now") as got:  # a DeprecationWarning
        old = read_preset(flat)
    assert [str(w.message) for w in got] == [
        f"preset {flat}: [scenario] critical_gap is now [scenario.obstacle] critical_gap",
        f"preset {flat}: [scenario] obstacle_accel is now [scenario.obstacle] accel",
        f"preset {flat}: [scenario] ego_start_spread is now [scenario.ego] start_spread"]
    assert {w.filename for w in got} == {__file__}  # the caller's line, however deep the reader
    assert old.scenario == read_preset(nested).scenario
    assert old.config() == load_preset(nested) == ScenarioConfig().with_values(
        {"obstacle.critical_gap": 2.0, "obstacle.accel": 1.5, "ego.start_spread": (-2.0, 2.0)})


def test_an_unknown_name_lists_the_shipped_ones(capsys):
    status, out, err = run_cli(capsys, "episode", "--preset", "stop-and-go")
    assert_one_line_error(status, out, err, "unknown preset 'stop-and-go'", *preset_names())
    with pytest.raises(PresetError, match=f"choose from {preset_names()[0]}"):
        load_preset("stop-and-go")


@pytest.mark.parametrize(("text", "needles"), [
    ('description = "x x"\n[scenario.obstacle]\nbeta = 0.1\ncritcal_gap = 3\n',
     ["unknown field 'obstacle.critcal_gap'", "valid fields: timing.dt", "obstacle.critical_gap"]),
    ('description = "x x"\n[scenario]\ncritcal_gap = 3\n', ["unknown field 'critcal_gap'"]),
    ('description = "x x"\n[scenario.obstacle]\ncritcal_gap = 3\n',
     ["unknown field 'obstacle.critcal_gap' (did you mean 'obstacle.critical_gap'?)"]),
    ('description = "x x"\n[scenario.sensing]\nlatency = true\n', ["sensing.latency must be an integer, got true"]),
    ('description = "x x"\n[scenario.timing]\nduration = ' + "9" * 400 + "\n",
     ["timing.duration=99999", "(400 characters) is out of range"]),
    ('description = "x x"\n[scenario.obstacle]\nbeta = 2.0\n', ["[scenario]", "obstacle.beta=2.0", "in [0, 1]"]),
    ('description = "x x"\n[scenario.obstacle]\nbeta = "high"\n', ["obstacle.beta must be a number", "'high'"]),
    ('description = "x x"\n[scenario.ego]\nstart_spread = [1, 2, 3]\n',
     ["ego.start_spread must be an array of 2 numbers"]),
    ('description = "x x"\n[scenario]\nbeta = 0.1\n[cdf]\ntau = 0.5\n',
     ["unknown key 'cdf'", "CDF always keeps its own defaults"]),
    ('[scenario]\nbeta = 0.1\n', ["needs description"]),
    ('description = "x x"\n[scenario\nbeta = 0.1\n', ["not valid TOML", "line 2"]),
    ('description = "x x"\nscenario = 3\n', ["'scenario' must be a table"]),
])
def test_a_broken_file_is_one_line_naming_file_and_field(tmp_path, capsys, text, needles):
    path = write(tmp_path, text)
    for argv in (["episode", "--no-label", "--preset", str(path)],
                 ["experiment", "--episodes", "1", "--out", str(tmp_path / "run"), "--preset", str(path)],
                 ["presets", str(path)]):
        status, out, err = run_cli(capsys, *argv)
        assert_one_line_error(status, out, err, str(path), *needles)
    assert not (tmp_path / "run" / "episodes.jsonl").exists()  # nothing ran


def test_a_missing_or_unreadable_file(tmp_path, capsys):
    status, out, err = run_cli(capsys, "episode", "--preset", str(tmp_path / "none.toml"))
    assert_one_line_error(status, out, err, "none.toml does not exist", "fast-ego")
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    status, out, err = run_cli(capsys, "episode", "--preset", str(binary))
    assert_one_line_error(status, out, err, "bin.toml cannot be read")


def test_the_experiment_records_the_presets_config_and_refuses_another(tmp_path, capsys):
    out_dir = tmp_path / "run"
    common = ["experiment", "--episodes", "1", "--seed", "3", "--planner", "reactive", "--workers", "1",
              "--quiet", "--out", str(out_dir)]
    status, _, err = run_cli(capsys, *common, "--preset", "slow-pull-out")
    assert status == 0, err
    settings = json.loads((out_dir / "settings.json").read_text())
    assert settings["scenario"] == json.loads(json.dumps(load_preset("slow-pull-out").to_dict()))
    status, out, err = run_cli(capsys, *common, "--preset", "fast-ego")
    assert_one_line_error(status, out, err, "other settings", "scenario.ego.speed", "scenario.obstacle.accel")
    status, out, _ = run_cli(capsys, *common, "--preset", "slow-pull-out")  # the same preset: resumed
    assert status == 0 and "already in" in out


# ----------------------------------------------------------------- scripts/mismatch.py
def _script():
    return load_script(SCRIPT, "mismatch_script")


def test_mismatch_refuses_a_broken_preset_before_running(tmp_path):
    proc = subprocess.run([sys.executable, str(SCRIPT), "--preset", "default,nope", "--out", str(tmp_path / "r"),
                           "--doc", str(tmp_path / "M.md")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith("mismatch: error: unknown preset 'nope'")
    assert not (tmp_path / "r").exists() and not (tmp_path / "M.md").exists()


def test_mismatch_runs_every_preset_end_to_end(tmp_path):
    out, doc = tmp_path / "results", tmp_path / "MISMATCH.md"
    argv = [sys.executable, str(SCRIPT), "--episodes", "2", "--seed", "1000", "--workers", "1", "--quiet",
            "--out", str(out), "--doc", str(doc)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = doc.read_text()
    names = scenario_preset_names()  # the stress presets have their own suite (scripts/stress.py)
    assert not (out / "stress-merge-brakes").exists()
    for name in names:
        lines = (out / name / "episodes.jsonl").read_text().splitlines()
        records = [json.loads(line) for line in lines]
        assert sorted((r["seed"], r["planner"]) for r in records) == sorted(
            (s, p) for s in (1000, 1001) for p in ("cdf", "reactive", "cv", "imm"))
        settings = json.loads((out / name / "settings.json").read_text())
        assert settings["scenario"] == json.loads(json.dumps(load_preset(name).to_dict()))
        assert settings["cdf"] == json.loads(json.dumps(CDFConfig().to_dict()))  # the filter's defaults
        section = text.split(f"## `{name}`\n", 1)[1].split("\n## ", 1)[0]
        assert read_preset(name).description in section
        for planner in ("cdf", "reactive", "cv", "imm"):
            assert f"\n| {planner} | " in section
        for baseline in ("reactive", "cv", "imm"):
            assert f"\n| cdf / {baseline} | 2 | " in section
        assert "**Targets (CDF on its defaults):**" in section
    summary = text.split("## Summary", 1)[1].split("\n## ", 1)[0]
    assert [line.split("|")[1].strip() for line in summary.splitlines() if line.startswith("| `")] == \
        [f"`{n}`" for n in names]
    again = subprocess.run(argv, capture_output=True, text=True, timeout=300)  # resumed: nothing runs
    assert again.returncode == 0, again.stderr[-3000:]
    assert doc.read_text() == text
