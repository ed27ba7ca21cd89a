"""``--names FILE``: a JSON or TOML file of SceneNames fields on every command that reads a
scene; a bad file is one line naming the file (and the position or the key)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from junctions import build_junction

from cdf_mj.cli import main
from cdf_mj.config import ScenarioConfig, SceneNames
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.checks import SceneError, read_names
from cdf_mj.sim.scene import Scene

OWN = {"ego_prefix": "av/", "obstacle_prefix": "other/", "route_left": "cross_path",
       "route_right": "away_path", "conflict": "crossing", "building_prefix": "house"}
OWN_TOML = "\n".join(f'{k} = "{v}"' for k, v in OWN.items()) + "\n"


@pytest.fixture(scope="module")
def own_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A junction with our own names, rotated and mirrored, saved as an MJCF file."""
    path = tmp_path_factory.mktemp("own") / "junction.xml"
    path.write_text(build_junction(names=SceneNames(**OWN), rotation=0.8, mirror=True).to_xml())
    return path


@pytest.mark.parametrize(("suffix", "text"), [(".json", json.dumps(OWN)), (".toml", OWN_TOML)])
def test_read_names_from_json_and_toml(tmp_path: Path, suffix: str, text: str):
    path = tmp_path / f"names{suffix}"
    path.write_text(text)
    names = read_names(path)
    assert names == SceneNames(**OWN)
    assert names.route_ego == SceneNames().route_ego  # not given: the default


def test_episode_with_a_names_file(own_scene: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    names = tmp_path / "names.toml"
    names.write_text(OWN_TOML)
    assert main(["episode", "--scene", str(own_scene), "--names", str(names), "--seed", "1",
                 "--planner", "reactive"]) == 0
    rec = json.loads(capsys.readouterr().out)
    want = run_episode(ScenarioConfig(names=SceneNames(**OWN)), seed=1, planner="reactive",
                       scene=Scene.load(own_scene, SceneNames(**OWN)))
    assert rec["label"] == want.label and rec["ego_start_offset"] == want.ego_start_offset
    # without the file the scene's names are not found: one line naming them
    assert main(["episode", "--scene", str(own_scene), "--seed", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "lacks" in err and "body 'route_obstacle_left'" in err


@pytest.mark.parametrize("command", [
    ["experiment", "--episodes", "1", "--planner", "constant", "--quiet", "--workers", "1"],
    ["sweep", "beta", "--values", "0.05", "--episodes", "1", "--planner", "constant", "--quiet",
     "--workers", "1", "--no-figure"],
    ["bench", "--only-reproduce", "--reproduce-episodes", "1", "--workers", "1", "--quiet"],
    ["falsify", "--planner", "reactive", "--episodes", "8", "--popsize", "4", "--workers", "1", "--quiet",
     "--no-figure"],
    ["estimate", "--planner", "reactive", "--method", "mc", "--episodes", "4", "--workers", "1", "--quiet"],
])
def test_other_commands_take_a_names_file(command: list[str], own_scene: Path, tmp_path: Path):
    names = tmp_path / "names.json"
    names.write_text(json.dumps(OWN))
    out = ["--out", str(tmp_path / "out")] if command[0] in ("experiment", "sweep", "falsify", "estimate") else []
    assert main([*command, "--scene", str(own_scene), "--names", str(names), *out]) == 0


@pytest.mark.parametrize(("name", "text", "fragments"), [
    ("n.json", '{"ego_prefix": "av/",\n "route_ego" "x"}', ["not valid JSON at line 2, column 14"]),
    ("n.toml", 'ego_prefix = "av/"\nroute_ego = \n', ["not valid TOML", "line 2"]),
    ("n.json", '{"route_lef": "x"}', ["unknown key 'route_lef'", "valid keys: ego_prefix,", "route_left"]),
    ("n.json", '{"ego_prefix": 3}', ["ego_prefix must be a string", "got 3"]),
    ("n.json", '["ego_prefix"]', ["expected an object of SceneNames fields", "got a list"]),
    ("n.json", '{"ego_prefix": "car_", "obstacle_prefix": "car_"}', ["different prefixes"]),
    ("n.yaml", "ego_prefix: av/", ["expected a .json or .toml file"]),
])
def test_a_bad_names_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str,
                                      text: str, fragments: list[str]):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(SceneError) as err:
        read_names(path)
    assert str(err.value).startswith(f"names file {path}")
    assert main(["episode", "--names", str(path)]) == 2
    line = capsys.readouterr().err
    assert line.count("\n") == 1 and line.startswith("cdf-mj: error: names file ")
    for fragment in fragments:
        assert fragment in line, fragment


def test_a_missing_names_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    assert main(["episode", "--names", str(tmp_path / "none.json")]) == 2
    assert "none.json does not exist" in capsys.readouterr().err
