"""The stress suite (scripts/stress.py) and its presets: the presets load and set only what
they stress, whatever the defaults; the script writes its page (stamp, tables, McNemar
lines) on a tiny run and refuses bad input in one line, writing nothing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import load_script

import cdf_mj
from cdf_mj.analysis.pages import Stamp, read_stamp
from cdf_mj.config import ScenarioConfig
from cdf_mj.presets import load_preset, preset_names, read_preset

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "stress.py"
stress = load_script(SCRIPT, "stress_script")

STRESS = [n for n in preset_names() if n.startswith("stress-")]
SENSING_NOISE = {"sensing.pos", "sensing.heading", "sensing.speed"}
AFTER_MERGE = {"after_merge.behaviour", "after_merge.decel", "after_merge.slow_to", "after_merge.brake",
               "after_merge.at"}
#: Preset -> the keys it may set (its kind) and the values it must set.
KINDS: dict[str, tuple[set[str], dict[str, object]]] = {
    "stress-merge-slows": (AFTER_MERGE, {"after_merge.behaviour": "slow", "after_merge.decel": (2.0, 2.0)}),
    "stress-merge-brakes": (AFTER_MERGE, {"after_merge.behaviour": "brake", "after_merge.brake": (4.0, 4.0)}),
    "stress-merge-stops": (AFTER_MERGE, {"after_merge.behaviour": "stop"}),
    "stress-merge-slows-paper-ego": (AFTER_MERGE | {"ego.follow"},
                                     {"after_merge.behaviour": "slow", "ego.follow": False}),
    "stress-merge-brakes-paper-ego": (AFTER_MERGE | {"ego.follow"},
                                      {"after_merge.behaviour": "brake", "ego.follow": False}),
    "stress-gap-acceptance": ({"obstacle.family"}, {"obstacle.family": "gap-acceptance"}),
    "stress-rolling-stop": ({"obstacle.family"}, {"obstacle.family": "rolling-stop"}),
    "stress-aggressive": ({"obstacle.family"}, {"obstacle.family": "aggressive"}),
    "stress-off-route": ({"obstacle.family"}, {"obstacle.family": "off-route"}),
    "stress-looked-but-failed": ({"obstacle.family"}, {"obstacle.family": "looked-but-failed"}),
    "stress-misjudged-speed": ({"obstacle.family"}, {"obstacle.family": "misjudged-speed"}),
    "stress-distracted": ({"obstacle.family"}, {"obstacle.family": "distracted"}),
    "stress-creeper": ({"obstacle.family"}, {"obstacle.family": "creeper"}),
    "stress-sumo": ({"obstacle.family"}, {"obstacle.family": "sumo"}),
    "stress-occluded": ({"sensing.occluded"}, {"sensing.occluded": True}),
    "stress-occluded-rolling-stop": ({"obstacle.family", "sensing.occluded"},
                                     {"obstacle.family": "rolling-stop", "sensing.occluded": True}),
    "stress-noise": (SENSING_NOISE, {"sensing.pos": 0.3, "sensing.heading": 0.05, "sensing.speed": 0.3}),
    "stress-noise-2x": (SENSING_NOISE, {"sensing.pos": 0.6, "sensing.heading": 0.1, "sensing.speed": 0.6}),
    "stress-brake-latency-1": ({"sensing.brake_latency"}, {"sensing.brake_latency": 1}),
    "stress-brake-latency-2": ({"sensing.brake_latency"}, {"sensing.brake_latency": 2}),
    "stress-latency-2": ({"sensing.latency"}, {"sensing.latency": 2}),
    "stress-dropout": ({"sensing.dropout"}, {"sensing.dropout": 0.2}),
    "stress-noise-told": (SENSING_NOISE | {"sensing.told"}, {"sensing.pos": 0.3, "sensing.told": True}),
    "stress-latency-2-told": ({"sensing.latency", "sensing.told"}, {"sensing.latency": 2, "sensing.told": True}),
    "stress-brake-latency-2-told": ({"sensing.brake_latency", "sensing.told"},
                                    {"sensing.brake_latency": 2, "sensing.told": True}),
    "stress-combined": ({"obstacle.family", "sensing.brake_latency"} | AFTER_MERGE | SENSING_NOISE,
                        {"obstacle.family": "aggressive", "after_merge.behaviour": "brake",
                         "sensing.pos": 0.3, "sensing.brake_latency": 1}),
}
#: The defaults the episodes are about to get (until the encounter is resolved): a preset
#: must mean the same on them.
RESOLVED = {"timing.end_distance": 60.0, "timing.until_clear": True, "timing.duration": 15.0, "ego.follow": True,
            "after_merge.follows": True}


def test_the_stress_presets_are_the_issues_list():
    assert sorted(STRESS) == sorted(KINDS)
    assert stress.default_presets() == ["default", *STRESS]


def test_a_preset_whose_extra_is_missing_is_left_out_with_a_note(monkeypatch, capsys):
    monkeypatch.setitem(stress.NEEDS_EXTRA, "stress-noise", "no-such-extra")
    monkeypatch.setitem(stress.EXTRAS, "no-such-extra", ("cdf_mj_no_such_module",))
    assert "stress-noise" not in stress.default_presets()
    assert "stress: note: stress-noise left out: install the no-such-extra extra" in capsys.readouterr().err


def test_the_issue_36_targets_name_each_family_and_the_occluded_ego():
    assert set(stress.CUTOFF_FAMILIES) | set(stress.OCCLUDED) <= set(STRESS)
    assert stress.PHANTOM in stress.PLANNERS_DEFAULT


def test_the_default_planners_set_both_cdf_rules_against_every_naive_baseline_and_predictor():
    assert {"cdf", "cdf-option", "caution-waiting", "caution-moving", "caution-phantom", "imm-layered",
            "cv-layered", "constant"} <= set(stress.PLANNERS_DEFAULT)


@pytest.mark.parametrize("name", sorted(KINDS))
def test_a_stress_preset_sets_only_keys_of_its_kind(name):
    preset = read_preset(name)
    allowed, required = KINDS[name]
    assert set(preset.scenario) <= allowed, set(preset.scenario) - allowed
    for key, value in required.items():
        assert preset.scenario[key] == value, key
    assert preset.description.startswith("Stress: ") and len(preset.description) > 80
    config = load_preset(name)
    assert {k for k in preset.scenario if config.get(k) != ScenarioConfig().get(k)}  # it changes something
    base = ScenarioConfig().with_values(RESOLVED)
    resolved = preset.config(base)  # on the coming defaults: the preset's keys, the rest as the base
    for key in ("timing.end_distance", "timing.until_clear", "timing.duration", "after_merge.follows",
                *(k for k in RESOLVED if k not in preset.scenario)):
        assert resolved.get(key) == base.get(key), key
    for key, value in preset.scenario.items():
        assert resolved.get(key) == value


def test_the_suite_writes_its_page_and_resumes(tmp_path, capsys):
    out, doc = tmp_path / "results", tmp_path / "STRESS.md"
    presets, planners = ["stress-merge-brakes", "stress-noise"], ["cdf", "cdf-option", "reactive"]
    argv = ["--episodes", "2", "--preset", ",".join(presets), "--planner", ",".join(planners), "--workers", "1",
            "--quiet", "--out", str(out), "--doc", str(doc)]
    assert stress.main(argv) == 0
    assert capsys.readouterr().err == ""  # the current spellings: no note
    text = doc.read_text()
    command = f"python scripts/stress.py --preset {','.join(presets)} --episodes 2 --planner {','.join(planners)}"
    assert read_stamp(text) == Stamp(command, cdf_mj.__version__)
    assert f"Generated by `{command}` with cdf_mj {cdf_mj.__version__}" in text
    overview = text.split("## Overview\n", 1)[1].split("\n## ", 1)[0]
    for name in presets:
        assert f"\n| `{name}` | " in overview
    for planner in planners:
        assert f"- **{planner}** collides on " in overview
    assert "Where `cdf` differs from another planner at McNemar p < 0.05" in overview
    assert "Where `cdf-option` differs from another planner at McNemar p < 0.05" in overview
    assert "| preset | dominate `cdf-option` | `cdf-option` dominates | neither |" in overview
    targets = text.split("## Targets for `cdf` and `cdf-option`\n", 1)[1].split("\n## ", 1)[0]
    for first in ("cdf", "cdf-option"):  # stress-merge-brakes: no collision, for each rule
        mine = targets.split(f"### `{first}`\n", 1)[1].split("\n### ", 1)[0]
        assert "- `stress-merge-brakes`: no collision: " in mine
    for name in presets:
        records = [json.loads(line) for line in (out / name / "episodes.jsonl").read_text().splitlines()]
        assert sorted((r["seed"], r["planner"]) for r in records) == sorted(
            (s, p) for s in (stress.SEED0, stress.SEED0 + 1) for p in (*planners, "constant"))  # the reference runs too
        settings = json.loads((out / name / "settings.json").read_text())
        assert settings["scenario"] == json.loads(json.dumps(load_preset(name).to_dict()))
        section = text.split(f"## `{name}`\n", 1)[1].split("\n## ", 1)[0]
        assert read_preset(name).description in section
        assert "| planner | episodes | collisions with the obstacle, any label (95 % CI) |" in section
        assert "TTC at the first hard brake [s], median [min] (n)" in section or "No Cutoff episode" in section
        for planner in planners:
            assert f"\n| {planner} | 2 | " in section
        assert "| pair | seeds | collisions: first / second (discordant seeds; p) |" in section
        assert "\n| cdf / reactive | 2 | " in section and "\n- cdf / reactive: " in section  # row and verdict
        assert "\n| cdf-option / cdf | 2 | " in section and "\n| cdf-option / reactive | 2 | " in section
        assert "\n| cdf / cdf-option |" not in section  # the pair once, the option rule first
        assert "interventions, Yield (95 % CI)" in section and "Hard subset: " in section
        assert "\n| constant | 2 | " in section  # the reference's outcomes
    assert "\n| `stress-merge-brakes` | " in text.split("Pareto verdicts against `cdf`", 1)[1]
    assert stress.main(argv) == 0  # resumed: nothing runs again, the same page
    assert doc.read_text() == text
    capsys.readouterr()
    # The old spellings do the same (the page names the new ones), with a note each once it is written.
    old = ["--episodes", "2", "--presets", ",".join(presets), "--planners", ",".join(planners),
           "--seed0", str(stress.SEED0), "--workers", "1", "--quiet", "--out", str(out), "--doc", str(doc)]
    assert stress.main(old) == 0
    assert doc.read_text() == text
    assert capsys.readouterr().err.splitlines() == [
        "stress: note: --presets is now --preset (the old spelling still works)",
        "stress: note: --planners is now --planner (the old spelling still works)",
        "stress: note: --seed0 is now --seed (the old spelling still works)"]


@pytest.mark.parametrize(("argv", "needle"), [
    (["--preset", "stress-nope"], "unknown preset 'stress-nope'"),
    (["--presets", "stress-nope"], "unknown preset 'stress-nope'"),  # an old spelling: no note on an error
    (["--planner", "cdf,warp"], "warp"),
    (["--planner", "cdf,cdf"], "names a planner twice"),
    (["--episodes", "0"], "--episodes"),
    (["--episodes", "100000000"], "--episodes"),
    (["--episodes", "two"], "--episodes"),
    (["--seed", "-1"], "--seed"),
    (["--seed0", "-1"], "--seed0"),
    (["--seed", str(2**53 - 1), "--episodes", "2"], "beyond the largest seed"),
    (["--seed", "1", "--seed0", "2"], "--seed: not used with --seed0, its old spelling"),
    (["--planners", "cdf", "--planner", "reactive"], "--planner: not used with --planners"),
    (["--workers", "0"], "--workers"),
    (["--out", ""], "--out"),
    (["--frobnicate"], "unrecognized arguments"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, argv, needle):
    out, doc = tmp_path / "r", tmp_path / "S.md"
    with pytest.raises(SystemExit) as exc:
        stress.main(["--out", str(out), "--doc", str(doc), *argv])
    assert exc.value.code == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == "" and len(lines) == 1, captured.err
    assert lines[0].startswith("stress: error: ") and needle in lines[0], lines[0]
    assert not out.exists() and not doc.exists()
