"""cdf_mj.viz.report: figures and a Markdown page from an experiment directory."""

from __future__ import annotations

import json
import os
import shutil
import sys

import numpy as np
import pytest

from cdf_mj.analysis.metrics import planner_metrics
from cdf_mj.analysis.tables import experiment_tables, format_rate
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene
from cdf_mj.viz.report import FIGURES, ReportError, load_experiment, scene_extent, trajectories_figure, write_report
from tests.cli_helpers import run_cli
from tests.junctions import build_junction

pytest.importorskip("matplotlib", reason="the viz extra (matplotlib) is not installed")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    """Seeds 0-3 (Right, Cutoff, Right, Yield) with cdf and reactive, plus a failed
    episode of seed 4, a record of a third planner and a line cut short by a kill (or still
    being written); the settings say seeds 0-4 and the three planners."""
    out = tmp_path_factory.mktemp("exp")
    run_experiment(out, range(4), ("cdf", "reactive"), ScenarioConfig(), CDFConfig(n_particles=300),
                   progress=False, workers=1, backend="serial")
    settings = json.loads((out / "settings.json").read_text())
    settings.update(seeds=[0, 5], planners=["cdf", "reactive", "baseline_x"])
    (out / "settings.json").write_text(json.dumps(settings))
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
    settings = json.loads((experiment / "settings.json").read_text())
    (d / "settings.json").write_text(json.dumps({**settings, "planners": ["plugin_only"]}))
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


def test_trajectory_axes_come_from_a_rotated_scene_and_the_legend_stays_outside(tmp_path) -> None:
    """A mirrored junction turned by 2.3 rad about (30, -12), written to a file: the axes hold
    every point of the re-simulated paths and the junction, at equal scale, and the legend
    box lies outside the axes box."""
    xml = tmp_path / "rotated.xml"
    xml.write_text(build_junction(rotation=2.3, mirror=True, center=(30.0, -12.0)).to_xml())
    cdf = CDFConfig(n_particles=200)
    run_experiment(tmp_path / "exp", range(4), ("cdf",), ScenarioConfig(), cdf, scene=xml,
                   progress=False, workers=1, backend="serial")
    seeds = [0, 1, 3]
    fig = trajectories_figure(load_experiment(tmp_path / "exp"), "cdf", seeds)
    ax = fig.axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    scene = Scene.load(xml)
    layout = scene.layout()
    points = [layout.conflict, layout.ego_start[:2], layout.obstacle_start[:2]]
    for seed in seeds:
        trace = run_episode(ScenarioConfig(), seed, CDFPlanner(cdf), scene, trace=True).trace
        points += list(np.asarray(trace["poses"])[:, :, :2].reshape(-1, 2))
    pts = np.array(points)
    assert pts[:, 0].min() > x0 and pts[:, 0].max() < x1
    assert pts[:, 1].min() > y0 and pts[:, 1].max() < y1
    assert pts[:, 1].max() - pts[:, 1].min() > 40  # the turned junction spans y, unlike the T's fixed 36 m
    fig.canvas.draw()
    box = ax.get_window_extent()
    assert (x1 - x0) / box.width == pytest.approx((y1 - y0) / box.height, rel=1e-3)  # equal aspect
    assert len(fig.legends) == 1 and ax.get_legend() is None
    legend = fig.legends[0].get_window_extent()
    assert not legend.overlaps(box), (legend, box)
    assert len(fig.legends[0].get_texts()) == 1 + 2 * len(seeds)  # routes, then ego and obstacle per seed


def test_scene_extent_cuts_long_routes_and_keeps_the_junction() -> None:
    layout = Scene.load().layout()
    x0, x1, y0, y1 = scene_extent(layout, margin=2.0)
    assert x0 < layout.ego_start[0] - 2.0 + 1e-9 and x1 < 60.0  # the 150 m route ends are cut
    assert y0 < layout.ego_lane.corners()[:, 1].min() and y1 > layout.obstacle_start[1]
    far = np.array([[80.0, -1.85]])  # a path that leaves the junction widens it
    assert scene_extent(layout, far, margin=2.0)[1] == pytest.approx(82.0)
    with pytest.raises(ValueError, match="finite"):
        scene_extent(layout, np.array([[np.nan, 0.0]]))


@pytest.mark.parametrize(("settings_change", "record_change", "named"), [
    (lambda s: [s], None, r"settings\.json: settings are a JSON object, got list"),
    (lambda s: {**s, "scenario": [1]}, None, "key 'scenario' must be an object"),
    (lambda s: {**s, "scenario": {**s["scenario"], "names": "abc"}}, None, "key 'scenario.names'"),
    (lambda s: {**s, "planners": 7}, None, "key 'planners' must be"),
    (lambda s: {**s, "scenario": {**s["scenario"], "dt": "fast"}}, None, "scenario settings this version"),
    (None, lambda r: r.pop("min_gap"), r"episodes\.jsonl:1 is not an episode record: field 'min_gap' is missing"),
    (None, lambda r: r.update(seed=None), r"episodes\.jsonl:1 .*field 'seed' must be an integer, got null"),
    (None, lambda r: r.update(planner=["cdf"]), r"episodes\.jsonl:1 .*field 'planner' must be a string"),
    (None, lambda r: r.update(planner_info="x"), r"episodes\.jsonl:1 .*field 'planner_info' must be an object"),
    (None, lambda r: r.update(seed=40), r"episodes\.jsonl:1 is not a record of this run: seed 40 is outside"),
])
def test_odd_json_is_one_line_naming_the_file_and_the_key(experiment, tmp_path, capsys, settings_change,
                                                          record_change, named) -> None:
    d = tmp_path / "odd"
    d.mkdir()
    settings = json.loads((experiment / "settings.json").read_text())
    lines = (experiment / "episodes.jsonl").read_text().splitlines()[:-1]  # whole lines
    if settings_change is not None:
        settings = settings_change(settings)
    if record_change is not None:
        first = json.loads(lines[0])
        record_change(first)
        lines[0] = json.dumps(first)
    (d / "settings.json").write_text(json.dumps(settings))
    (d / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ReportError, match=named):
        write_report(d, out=tmp_path / "page")
    assert main(["report", str(d)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cdf-mj: error: ") and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize(("history", "named"), [
    ([1, 2], "history' must be an object of per-tick lists"),
    ({"t": [0.0, "x"], "p_left": [1.0, 1.0]}, "history.t' must be a list of finite numbers"),
    ({"t": [0.0, 0.1], "p_left": [1.0]}, "history.p_left' must hold one probability in"),
    ({"t": [0.0], "p_cutoff": [1.5]}, "history.p_cutoff' must hold one probability in"),
])
def test_an_odd_posterior_history_is_refused_naming_its_line(experiment, tmp_path, history, named) -> None:
    d = tmp_path / "history"
    d.mkdir()
    shutil.copy(experiment / "settings.json", d)
    lines = (experiment / "episodes.jsonl").read_text().splitlines()[:-1]
    number = next(i for i, line in enumerate(lines) if json.loads(line)["planner"] == "cdf")
    rec = json.loads(lines[number])
    rec["planner_info"]["history"] = history
    lines[number] = json.dumps(rec)
    (d / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ReportError, match=rf"episodes\.jsonl:{number + 1} is not an episode record: "
                                          rf"field 'planner_info\.{named}"):
        write_report(d, out=tmp_path / "page")


def test_the_report_replaces_planted_symlinks_and_never_writes_their_targets(experiment, tmp_path) -> None:
    d = tmp_path / "planted"
    d.mkdir()
    for name in ("settings.json", "episodes.jsonl"):
        shutil.copy(experiment / name, d)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    for name in ("report.md", "confusion.png", ".report.md.tmp"):
        (d / name).symlink_to(victim)
    res = write_report(d, seeds=[1])
    assert victim.read_text() == "precious"
    assert not res.markdown.is_symlink() and res.markdown.read_text().startswith("# Experiment report")
    assert not (d / "confusion.png").is_symlink() and (d / "confusion.png").read_bytes()[:8] == PNG_MAGIC
    assert not [p for p in d.iterdir() if p.name.endswith(".tmp") and not p.is_symlink()]  # no temporary left


@pytest.mark.skipif(sys.platform in ("win32", "darwin"), reason="needs a file system that takes any bytes in a name")
def test_a_directory_whose_name_is_not_utf8_is_reported(experiment, tmp_path, capsys) -> None:
    """``experiment --out $'r\\xff'`` writes such a directory; its report shows the byte
    as ``\\xff`` on the page and in the one line printed (any terminal takes it)."""
    d = tmp_path / os.fsdecode(b"r\xff\x1b")  # not UTF-8, and an ESC
    d.mkdir()
    for name in ("settings.json", "episodes.jsonl"):
        shutil.copy(experiment / name, d)
    status, out, err = run_cli(capsys, "report", str(d), "--seeds", "1")
    assert status == 0, err
    shown = f"{os.fsencode(tmp_path).decode('utf-8', 'backslashreplace')}/r\\xff\\x1b"
    assert out.startswith(f"wrote {shown}/report.md and 5 figure(s)")
    out.encode("ascii")  # nothing a strict terminal refuses, no ESC
    page = (d / "report.md").read_text(encoding="utf-8")
    assert page.startswith(f"# Experiment report: {shown}\n")
