"""A small experiment: records persisted, tables consistent with the records, bad input refused."""

from __future__ import annotations

import json

import pytest

from cdf_mj.analysis.tables import experiment_tables
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig
from cdf_mj.experiments.experiment import ResultsExistError, run_experiment
from cdf_mj.records import LABELS, Label, load_records

SEEDS = range(0, 12)
SMALL = CDFConfig(n_particles=300)


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    records = run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False)
    return out, records


def test_every_episode_and_planner_is_persisted(small_run):
    out, records = small_run
    on_disk = load_records(out)  # in the order the seeds finished
    assert sorted(on_disk, key=lambda r: (r["seed"], r["planner"] != "cdf")) == records.records
    assert len(on_disk) == 2 * len(SEEDS)
    assert {(r["seed"], r["planner"]) for r in on_disk} == {(s, p) for s in SEEDS for p in ("cdf", "reactive")}
    settings = json.loads((out / "settings.json").read_text())
    assert settings["seeds"] == [0, 12] and settings["cdf"]["n_particles"] == 300


def test_planners_share_labels_and_tables_match_records(small_run):
    _, records = small_run
    by_seed: dict[int, set] = {}
    for r in records:
        by_seed.setdefault(r["seed"], set()).add(r["label"])
    assert all(len(labels) == 1 for labels in by_seed.values())  # common random numbers

    table = experiment_tables(records, fmt="markdown")
    cdf = [r for r in records if r["planner"] == "cdf"]
    for lab in LABELS:
        row = [sum(1 for r in cdf if r["label"] == lab and r["planner_info"]["prediction"] == p) for p in LABELS]
        assert sum(row) == sum(1 for r in cdf if r["label"] == lab)
        assert f"| {lab} | {row[0]} \\| " in table
    n_cut = sum(1 for r in cdf if r["label"] == Label.CUTOFF)
    reactive_hits = sum(1 for r in records if r["planner"] == "reactive" and r["collision_with"] == "obstacle")
    assert f"| reactive | {n_cut} | {reactive_hits} |" in table
    assert "417 / 9 / 98 %" in table and "404 / 213 / 47 %" in table  # the paper beside ours


def test_other_settings_in_the_same_directory_are_refused(small_run):
    out, _ = small_run
    with pytest.raises(ValueError,
                       match=r"other settings \(differing: cdf.n_particles, planner_args.cdf, planners\)") as info:
        run_experiment(out, SEEDS, ("reactive",), progress=False)
    assert not isinstance(info.value, ResultsExistError)
    # The same settings without resume: its own error, in neutral terms.
    with pytest.raises(ResultsExistError, match=f"^{out} already holds results of this experiment$"):
        run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False)


def test_bad_experiment_input_is_refused_before_work(tmp_path, capsys):
    assert main(["experiment", "--episodes", "2", "--planner", "cdf,psychic", "--out", str(tmp_path / "a")]) == 2
    assert "psychic" in capsys.readouterr().err
    assert main(["experiment", "--episodes", "2", "--tau", "1.5", "--out", str(tmp_path / "b")]) == 2
    assert "tau" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    with pytest.raises(ValueError, match="contiguous"):
        run_experiment(tmp_path / "c", [0, 2, 5], ("reactive",), progress=False)


def test_cli_experiment_prints_both_tables(tmp_path, capsys):
    assert main(["experiment", "--episodes", "3", "--seed", "40", "--planner", "reactive,constant",
                 "--out", str(tmp_path / "r"), "--quiet"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "Collisions with the obstacle" in lines and "Braking" in lines and "Every intervention" in lines
    assert sum(line.startswith("reactive ") for line in lines) == 3  # one row in each table
    assert sum(line.startswith("constant ") for line in lines) == 3
    tables = lines[lines.index("Collisions with the obstacle"):]
    assert max(map(len, tables)) <= 100
    assert len(load_records(tmp_path / "r")) == 6
