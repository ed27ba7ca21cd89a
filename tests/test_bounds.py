"""Every number bounded, every geometry checked at load (issue 15 items 5, 6, 8, 11).

Configurations refuse any value that is not finite or beyond its physical bound; the CLI
refuses every count and size beyond its documented bound before any work; a scene whose
timestep is 0 or NaN, or whose geometry holds a non-finite number, is refused at load,
before an experiment writes anything; a FIFO in a scene is refused before MuJoCo opens it;
MuJoCo's warnings go to the logger ``cdf_mj.mujoco``, not stdout and MUJOCO_LOG.TXT. Real
files, real MuJoCo, the CLI run in-process or as a subprocess with a timeout.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.config import (
    MAX_DURATION,
    MAX_EPISODES,
    MAX_PARTICLES,
    MAX_SEED,
    CDFConfig,
    DriverPrior,
    Ego,
    Observation,
    ObstacleDriver,
    ProcessNoise,
    Pursuit,
    ScenarioConfig,
    SceneNames,
    Timing,
)
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.checks import MUJOCO_LOGGER, SceneError
from cdf_mj.sim.scene import Scene

HUGE_INT = int("9" * 400)  # a 400-digit integer: too large for a float

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------ configurations
def _number_fields(cls: type) -> list[tuple[str, object]]:
    """Every float field and every pair of floats of a config class, with its default."""
    out = []
    for f in dataclasses.fields(cls):
        default = getattr(cls(), f.name)
        if isinstance(default, float) or (isinstance(default, tuple) and default
                                          and all(isinstance(v, float) for v in default)):
            out.append((f.name, default))
    return out


@pytest.mark.parametrize("cls", [Timing, Ego, ObstacleDriver, Observation, Pursuit, ProcessNoise, CDFConfig,
                                 DriverPrior])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e300, -1e300, HUGE_INT, "1", None],
                         ids=["nan", "inf", "-inf", "1e300", "-1e300", "400-digits", "str", "None"])
def test_every_number_of_every_config_is_finite_and_bounded(cls, bad):
    fields = _number_fields(cls)
    assert len(fields) >= 2  # the test reaches the fields it means to
    for name, default in fields:
        value = tuple(bad for _ in default) if isinstance(default, tuple) else bad
        with pytest.raises(ValueError, match=rf"\b{name}=") as err:
            cls(**{name: value})
        assert len(str(err.value)) < 300  # a 400-digit value is cut in the message


def test_scenario_bounds_are_the_documented_ones():
    with pytest.raises(ValueError, match=r"ego\.start_spread=.*-200 <= low <= high <= 200"):
        ScenarioConfig(ego=Ego(start_spread=(-1e300, 1e300)))
    with pytest.raises(ValueError, match=r"ego\.start_spread"):
        ScenarioConfig().with_values({"ego.start_spread": (-201.0, 0.0)})
    Ego(start_spread=(-200.0, 200.0))  # the bound itself is allowed
    Timing(duration=MAX_DURATION)
    with pytest.raises(ValueError, match=r"timing\.duration=.*600"):
        ScenarioConfig(timing={"duration": MAX_DURATION + 1})


@pytest.mark.parametrize("names", ["abc", 7, ("ego_",), {"no_such_field": "x"}])
def test_scenario_names_must_be_scene_names(names):
    with pytest.raises(ValueError, match=r"names"):
        ScenarioConfig(names=names)


def test_scenario_names_from_json_become_scene_names():
    config = ScenarioConfig(names={"route_ego": "av_path"})
    assert config.names == SceneNames(route_ego="av_path")


@pytest.mark.parametrize("n", [0, MAX_PARTICLES + 1, 10**20, 1.5, True, "100"])
def test_particle_count_is_a_bounded_integer(n):
    with pytest.raises(ValueError, match=r"n_particles=.*\[1, 1e\+06\]"):
        CDFConfig(n_particles=n)
    assert CDFConfig(n_particles=MAX_PARTICLES).n_particles == MAX_PARTICLES


# ------------------------------------------------------------------ command line
@pytest.mark.parametrize(("argv", "needle"), [
    (["experiment", "--particles", "99999999999999999999"], "--particles"),
    (["experiment", "--episodes", "1000000000000"], "--episodes"),
    (["experiment", "--workers", "100000"], "--workers"),
    (["experiment", "--seed", str(MAX_SEED + 1)], "--seed"),
    (["experiment", "--seed", str(MAX_SEED), "--episodes", "2"], "beyond the largest seed"),
    (["episode", "--seed", "9" * 5000], "--seed"),
    (["episode", "--set", f"timing.duration={HUGE_INT}"], "timing.duration"),
    (["episode", "--set", "ego.start_spread=[-1e300, 1e300]"], "ego.start_spread"),
    (["sweep", "particles", "--values", "100,1e400"], "--values"),
    (["sweep", "beta", "--values", "nan"], "--values"),
    (["bench", "--particles", "100000000"], "--particles"),
    (["bench", "--workers", "1,99999"], "--workers"),
    (["bench", "--env-seconds", "1e300"], "--env-seconds"),
    (["render", "--out", "x.png", "--width", "99999999999"], "--width"),
    (["render", "--out", "x.png", "--fps", "nan"], "--fps"),
    (["report", "somewhere", "--seeds", "1,-2"], "--seeds"),
])
def test_every_count_and_size_is_refused_up_front(capsys, tmp_path, argv, needle):
    argv = [*argv, "--out", str(tmp_path / "out")] if argv[0] in ("experiment", "sweep") else argv
    assert_one_line_error(*run_cli(capsys, *argv), needle)
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_the_bounds_are_in_the_help(capsys):
    status, out, _ = run_cli(capsys, "experiment", "--help")
    assert status == 0
    assert "10^6" in out and "10^7" in out
    assert MAX_EPISODES == 10**7


def test_an_os_error_on_a_path_with_a_newline_is_one_line(capsys, tmp_path):
    blocker = tmp_path / "a\nfile"
    blocker.write_text("not a directory")
    status, out, err = run_cli(capsys, "experiment", "--episodes", "1", "--planner", "reactive",
                               "--workers", "1", "--quiet", "--out", str(blocker / "out"))
    assert_one_line_error(status, out, err)
    assert "a\\nfile" in err  # the newline shown escaped, the path still named


# ------------------------------------------------------------------ scenes
def _scene_copy(tmp_path: Path) -> Path:
    """A copy of models/xml to edit; returns its scene.xml."""
    shutil.copytree(MODELS_DIR, tmp_path / "models")  # not "xml": python -m puts the cwd on sys.path
    return tmp_path / "models" / "scene.xml"


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


@pytest.mark.parametrize("timestep", ["0", "nan", "-0.005", "inf"])
def test_a_timestep_that_is_not_positive_and_finite_is_refused_at_load(tmp_path, timestep):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', f'timestep="{timestep}"')
    with pytest.raises(SceneError, match=r"<option timestep=.*must be a finite number of seconds > 0"):
        Scene.load(scene)


def test_an_experiment_refuses_a_zero_timestep_before_writing(capsys, tmp_path):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', 'timestep="0"')
    out = tmp_path / "out"
    status, stdout, err = run_cli(capsys, "experiment", "--scene", str(scene), "--episodes", "2",
                                  "--planner", "reactive", "--workers", "1", "--quiet", "--out", str(out))
    assert_one_line_error(status, stdout, err, "timestep")
    assert not (out / "episodes.jsonl").exists()


@pytest.mark.parametrize("where", ["pos", "size"])
def test_a_building_with_a_non_finite_number_is_named_at_load(tmp_path, where):
    scene = _scene_copy(tmp_path)
    inter = scene.parent / "intersection.xml"
    text = inter.read_text()
    start = text.index('<geom name="building')
    name = text[start:].split('"')[1]
    end = text.index("/>", start)
    geom = text[start:end]
    attr = f' {where}="'
    i = geom.index(attr) + len(attr)
    edited = geom[:i] + "nan " + geom[i:].split(" ", 1)[1]
    inter.write_text(text[:start] + edited + text[end:])
    with pytest.raises(SceneError, match=rf"'{name}'") as err:  # MuJoCo refuses a NaN size itself
        Scene.load(scene)
    assert "nan" in str(err.value).lower() or "not a finite number" in str(err.value)


def test_a_building_far_beyond_the_junction_is_refused(tmp_path):
    spec = mujoco.MjSpec.from_file(str(MODELS_DIR / "scene.xml"))
    building = next(g for g in spec.geoms if g.name.startswith("building"))
    building.pos = [1e300, 0.0, 1.0]
    with pytest.raises(SceneError, match=rf"'{building.name}'"):
        Scene.from_model(spec.compile(), drive=False)


# ------------------------------------------------------------------ FIFOs
needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes on this system")


def _cli(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cdf_mj", *argv], cwd=cwd, capture_output=True,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})


@needs_fifo
def test_a_scene_that_includes_a_fifo_is_refused_without_hanging(tmp_path):
    scene = _scene_copy(tmp_path)
    os.mkfifo(scene.parent / "pipe.xml")
    _edit(scene, '<include file="intersection.xml"/>',
          '<include file="intersection.xml"/>\n  <include file="pipe.xml"/>')
    done = _cli("episode", "--scene", str(scene), cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "FIFO" in lines[0] and "pipe.xml" in lines[0], done.stderr
    assert done.stdout == ""


@needs_fifo
def test_a_scene_or_names_file_that_is_a_fifo_is_refused(tmp_path):
    os.mkfifo(tmp_path / "scene.xml")
    with pytest.raises(SceneError, match=r"is a FIFO \(named pipe\), not a regular file"):
        Scene.load(tmp_path / "scene.xml")
    os.mkfifo(tmp_path / "names.json")
    done = _cli("episode", "--names", str(tmp_path / "names.json"), cwd=tmp_path)
    assert done.returncode == 2 and "FIFO" in done.stderr and len(done.stderr.splitlines()) == 1


def test_a_scene_that_is_a_directory_is_named_so(tmp_path):
    (tmp_path / "scene.xml").mkdir()
    with pytest.raises(SceneError, match=r"is a directory, not a regular file"):
        Scene.load(tmp_path / "scene.xml")


# ------------------------------------------------------------------ MuJoCo's warnings
def test_mujoco_warnings_go_to_the_logger_not_stdout_or_a_log_file(tmp_path, monkeypatch, capfd, caplog):
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>")
    data = mujoco.MjData(model)
    data.qvel[0] = math.nan
    with caplog.at_level(logging.WARNING, logger=MUJOCO_LOGGER.name):
        mujoco.mj_step(model, data)
    assert any("MuJoCo: Nan, Inf or huge value" in r.getMessage() for r in caplog.records), caplog.text
    out, err = capfd.readouterr()
    assert "WARNING" not in out and "WARNING" not in err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_no_mujoco_warning_line_precedes_the_error(tmp_path):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', 'timestep="nan"')  # MuJoCo warns: "XML contains a 'NaN'"
    done = _cli("episode", "--scene", str(scene), cwd=tmp_path)
    assert done.returncode == 2
    assert done.stdout == ""
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "timestep" in done.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_a_full_disk_names_the_output_path(capsys, tmp_path, monkeypatch):
    import errno

    from cdf_mj.experiments import experiment

    def full_disk(*args, **kwargs):  # what a write() on a full disk raises: no file named
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(experiment, "run_experiment", full_disk)
    out = tmp_path / "out\ndir"
    status, stdout, err = run_cli(capsys, "experiment", "--episodes", "1", "--quiet", "--out", str(out))
    assert_one_line_error(status, stdout, err, "out\\ndir (writing)", "No space left on device")
