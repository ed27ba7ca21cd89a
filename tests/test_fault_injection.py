"""Fault injection on the experiment store: runs killed at random moments and resumed, every
kind of damaged records line, a scene changed between a kill and the resume, and symlinks
planted in the results directory. Nothing may be lost, mixed or counted twice."""

from __future__ import annotations

import json
import random
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from cdf_mj.cli import main
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment, scene_files
from cdf_mj.records import load_records
from cdf_mj.sim.assets import MODELS_DIR

PLANNERS = ("constant", "reactive")
SEEDS = range(0, 12)
ARGS = ["--episodes", str(len(SEEDS)), "--planner", ",".join(PLANNERS), "--workers", "1", "--quiet"]


def _key(rec: dict) -> tuple[int, str]:
    return rec["seed"], rec["planner"]


@pytest.fixture(scope="module")
def clean_dir(tmp_path_factory) -> Path:
    """The results directory of an uninterrupted serial run with the command's settings."""
    out = tmp_path_factory.mktemp("clean")
    assert main(["experiment", "--out", str(out), *ARGS]) == 0
    return out


@pytest.fixture(scope="module")
def clean(clean_dir) -> list[dict]:
    """The records of the uninterrupted run, sorted."""
    return sorted(load_records(clean_dir), key=_key)


@pytest.fixture
def finished(tmp_path, clean_dir) -> Path:
    """A copy of the finished results directory, to damage."""
    return Path(shutil.copytree(clean_dir, tmp_path / "finished"))


def test_runs_killed_at_random_moments_resume_to_the_clean_records(tmp_path, clean):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "cdf_mj.cli", "experiment", "--out", str(out), *ARGS]
    rng = random.Random(2024)  # the kill times, not anything measured
    kills = 0
    for _ in range(4):
        # Kill once the file holds a random number of lines, after a random delay more:
        # between two seeds, or while one is being written.
        at = rng.randrange(1, 2 * len(SEEDS) - 4)
        proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while _lines(out / "episodes.jsonl") < at and proc.poll() is None:
            assert time.monotonic() < deadline, "the experiment wrote nothing in 60 s"
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.05))
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait()
    assert kills >= 2, "the runs finished before they were killed: the test proves nothing"
    assert _lines(out / "episodes.jsonl") < 2 * len(SEEDS)
    assert main(["experiment", "--out", str(out), *ARGS]) == 0
    records = load_records(out)
    counts = Counter(_key(r) for r in records)
    assert set(counts) == {(s, p) for s in SEEDS for p in PLANNERS} and max(counts.values()) == 1
    assert sorted(records, key=_key) == clean


def _lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def _damage(path: Path, kind: str) -> int:
    """Damage the records file in one way; the number of the line that is damaged."""
    lines = path.read_text().splitlines()
    rec = json.loads(lines[3])
    number = 4
    if kind == "not json":
        lines[3] = lines[3][:-5]
    elif kind == "duplicate":
        lines.append(lines[1])
        number = len(lines)
    elif kind == "failed duplicate":
        lines.append(json.dumps({"seed": rec["seed"], "planner": rec["planner"], "status": "failed"}))
        number = len(lines)
    elif kind == "seed outside":
        lines[3] = json.dumps({**rec, "seed": SEEDS.stop + 5})
    elif kind == "other planner":
        lines[3] = json.dumps({**rec, "planner": "cdf"})
    elif kind == "missing field":
        del rec["min_gap"]
        lines[3] = json.dumps(rec)
    else:  # a field of the wrong kind, given as the JSON text
        field, text = kind.split("=", 1)
        lines[3] = json.dumps(rec).replace(f'"{field}": {json.dumps(rec[field])}', f'"{field}": {text}', 1)
        assert lines[3] != json.dumps(rec)
    path.write_text("\n".join(lines) + "\n")
    return number


@pytest.mark.parametrize("kind", ["not json", "duplicate", "failed duplicate", "seed outside", "other planner",
                                  "missing field", "seed=1.7", "seed=true", "seed=null", "seed=1e400",
                                  'seed="3"', "seed=-1", 'planner=["reactive"]', 'brake_time="soon"',
                                  "min_gap=NaN", "time_lost=Infinity", 'planner_info="x"', "label=7"])
def test_a_damaged_line_of_any_kind_is_one_error_naming_it_and_nothing_runs(finished, capsys, kind):
    path = finished / "episodes.jsonl"
    number = _damage(path, kind)
    before = path.read_bytes()
    assert main(["experiment", "--out", str(finished), *ARGS]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"cdf-mj: error: {path}:{number} is not ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert path.read_bytes() == before  # nothing appended, nothing cut


def test_a_half_written_last_line_is_dropped_and_the_run_completes(finished, clean):
    path = finished / "episodes.jsonl"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-3]) + "\n" + lines[-3][:25])  # killed while writing
    assert main(["experiment", "--out", str(finished), *ARGS]) == 0
    assert sorted(load_records(finished), key=_key) == clean


def _scene_copy(where: Path) -> Path:
    where.mkdir()
    for name in ("scene.xml", "intersection.xml", "car.xml"):
        shutil.copy(MODELS_DIR / name, where / name)
    return where / "scene.xml"


@pytest.mark.parametrize("changed", ["scene.xml", "intersection.xml", "car.xml"])
def test_resuming_with_a_changed_scene_is_refused_by_name(tmp_path, changed):
    scene = _scene_copy(tmp_path / "models")
    out = tmp_path / "run"
    run_experiment(out, range(2), PLANNERS, scene=scene, progress=False, workers=1)
    files = scene_files(scene)
    assert sorted(Path(p).name for p in files) == ["car.xml", "intersection.xml", "scene.xml"]
    stored = json.loads((out / "settings.json").read_text())
    assert stored["scene_files"] == files and stored["version"]
    # The same world: resumes (nothing left to run).
    assert run_experiment(out, range(2), PLANNERS, scene=scene, progress=False, workers=1, resume=True).ran == 0
    target = tmp_path / "models" / changed
    target.write_text(target.read_text() + "<!-- edited between a kill and the resume -->\n")
    before = (out / "episodes.jsonl").read_bytes()
    with pytest.raises(SettingsMismatchError, match=rf"^the scene \S*{changed} changed since the run in "):
        run_experiment(out, range(2), PLANNERS, scene=scene, progress=False, workers=1, resume=True)
    assert (out / "episodes.jsonl").read_bytes() == before


def test_resuming_results_of_another_version_is_refused(finished):
    settings = json.loads((finished / "settings.json").read_text())
    (finished / "settings.json").write_text(json.dumps({**settings, "version": "0.0.1"}))
    with pytest.raises(SettingsMismatchError, match=r"holds results of cdf_mj 0\.0\.1, and this is "):
        run_experiment(finished, SEEDS, PLANNERS, progress=False, workers=1, resume=True)


def test_planted_symlinks_are_never_written_through(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "run"
    out.mkdir()
    (out / "settings.json.tmp").symlink_to(victim)
    (out / "settings.json").symlink_to(victim)
    run_experiment(out, range(2), PLANNERS, progress=False, workers=1)
    assert victim.read_text() == "precious"
    assert not (out / "settings.json").is_symlink() and json.loads((out / "settings.json").read_text())["seeds"]
    assert sorted(p.name for p in out.iterdir()) == ["episodes.jsonl", "settings.json", "settings.json.tmp"]

    other = tmp_path / "linked"
    other.mkdir()
    (other / "episodes.jsonl").symlink_to(tmp_path / "elsewhere.jsonl")  # a link to a file not there yet
    with pytest.raises(ValueError, match=r"episodes\.jsonl is a symbolic link"):
        run_experiment(other, range(2), PLANNERS, progress=False, workers=1)
    assert not (tmp_path / "elsewhere.jsonl").exists()
