"""cdf_mj.viz.report: figures and a Markdown page from an experiment directory."""

from __future__ import annotations

import json
import shutil

import pytest

from cdf_mj.analysis.metrics import planner_metrics
from cdf_mj.analysis.tables import experiment_tables, format_rate
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.viz.report import FIGURES, ReportError, load_experiment, write_report

pytest.importorskip("matplotlib", reason="the viz extra (matplotlib) is not installed")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    """Seeds 0-3 (Right, Cutoff, Right, Yield) with cdf and reactive, plus a failed
    episode, a record of another planner and a line cut short by a kill (or still being written)."""
    out = tmp_path_factory.mktemp("exp")
    run_experiment(out, range(4), ("cdf", "reactive"), ScenarioConfig(), CDFConfig(n_particles=300),
                   progress=False, workers=1, backend="serial")
    lines = (out / "episodes.jsonl").read_text().splitlines()
    other = json.loads(next(line for line in lines if json.loads(line)["planner"] == "reactive"))
    other["planner"] = "baseline_x"
    failed = {"seed": 4, "planner": "cdf", "status": "failed", "error": "ValueError: boom",
              "traceback": "Traceback (most recent call last): ..."}
    with open(out / "episodes.jsonl", "a", encoding="utf-8") as fh:
        fh.write(json.dumps(other) + "\n" + json.dumps(failed) + "\n" + '{"seed": 5, "plan')
    return out


def test_report_writes_every_figure_it_lists(experiment, tmp_path) -> None:
    res = write_report(experiment, out=tmp_path / "rep")
    assert set(res.figures) == set(FIGURES) and not res.omitted
    page = res.markdown.read_text()
    for name, path in res.figures.items():
        assert path.parent == tmp_path / "rep"
        assert path.read_bytes()[:8] == PNG_MAGIC and path.stat().st_size > 5000
        assert f"![{name}]({path.name})" in page
    assert (res.records, res.failed, res.unreadable) == (9, 1, 1)
    assert "1 failed episode(s)" in page and "a half-written last line" in page
    assert "baseline_x" in page  # other planners are reported like the paper's two
    assert "re-simulated" not in page  # the trajectories' re-runs match the stored records


def test_load_experiment_skips_failed_and_orders_planners(experiment) -> None:
    exp = load_experiment(experiment)
    assert exp.planners == ["cdf", "reactive", "baseline_x"]
    assert all(r.get("status") != "failed" for r in exp.records)


def test_figures_without_data_are_omitted_with_a_reason(experiment, tmp_path) -> None:
    d = tmp_path / "reactive_only"
    d.mkdir()
    shutil.copy(experiment / "settings.json", d)
    lines = [line for line in (experiment / "episodes.jsonl").read_text().splitlines()
             if '"planner": "reactive"' in line]
    (d / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    res = write_report(d)
    assert {"confusion", "posterior"} <= set(res.omitted)
    assert all(p.is_file() for p in res.figures.values())
    assert "not drawn (no CDF records" in res.markdown.read_text()


def test_bad_directories_are_refused(tmp_path, experiment) -> None:
    with pytest.raises(ReportError, match=r"settings\.json is missing"):
        write_report(tmp_path)
    d = tmp_path / "failed_only"
    d.mkdir()
    shutil.copy(experiment / "settings.json", d)
    (d / "episodes.jsonl").write_text(json.dumps({"seed": 0, "planner": "cdf", "status": "failed"}) + "\n")
    with pytest.raises(ReportError, match="no completed episode"):
        write_report(d)
    with pytest.raises(ReportError, match="seed"):
        write_report(experiment, out=tmp_path / "x", seeds=[999])


def test_a_damaged_record_is_refused_naming_its_line_and_field(tmp_path, experiment) -> None:
    d = tmp_path / "damaged"
    d.mkdir()
    shutil.copy(experiment / "settings.json", d)
    lines = (experiment / "episodes.jsonl").read_text().splitlines()
    second = json.loads(lines[1])
    del second["collision_with"]
    (d / "episodes.jsonl").write_text("\n".join([lines[0], json.dumps(second), *lines[2:]]) + "\n")
    with pytest.raises(ReportError, match=r"episodes\.jsonl:2 is not an episode record: field 'collision_with' is"):
        write_report(d)


def test_cli_report(experiment, tmp_path, capsys) -> None:
    status = main(["report", str(experiment), "--out", str(tmp_path / "cli"), "--seeds", "1"])
    out = capsys.readouterr().out
    assert status == 0
    assert "5 figure(s)" in out and "skipped 1 failed episode(s)" in out
    assert main(["report", str(tmp_path / "none")]) == 2
    assert capsys.readouterr().err.startswith("cdf-mj: error: ")


def test_unregistered_planner_is_reported_without_trajectories(experiment, tmp_path) -> None:
    d = tmp_path / "plugin"
    d.mkdir()
    shutil.copy(experiment / "settings.json", d)
    lines = [line.replace('"planner": "reactive"', '"planner": "plugin_only"')
             for line in (experiment / "episodes.jsonl").read_text().splitlines()
             if '"planner": "reactive"' in line]
    (d / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    res = write_report(d)
    assert "not registered" in res.omitted["trajectories"]
    assert {"avoidance", "lead_times"} <= set(res.figures)


def test_the_page_holds_the_tables_of_the_metrics(experiment, tmp_path) -> None:
    exp = load_experiment(experiment)
    page = write_report(experiment, out=tmp_path / "page").markdown.read_text()
    assert experiment_tables(exp.records, fmt="markdown") in page
    metrics = planner_metrics(exp.records)
    assert list(metrics) == exp.planners
    for m in metrics.values():
        assert f"| {m.planner} | {m.imminent} | {m.collisions} | {format_rate(m.avoided)} |" in page
    assert metrics["cdf"].avoided.n == 1  # seed 1 is the one Cutoff
