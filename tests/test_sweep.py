"""Sweeps: a tiny sweep writes its table (CSV, Markdown) and figure; tau from histories."""

from __future__ import annotations

import csv
import sys

import pytest

from cdf_mj.analysis.metrics import planner_metrics, tau_curve
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.sweep import SWEEPS, comparison_figures, run_sweep
from cdf_mj.extras import install_hint
from cdf_mj.planners.base import as_config
from cdf_mj.planners.registry import PLANNERS, PlannerSpec
from cdf_mj.planners.simple import ReactivePlanner
from cdf_mj.records import load_records


def test_tiny_beta_sweep_writes_table_and_figure(tmp_path):
    res = run_sweep("beta", tmp_path, seeds=range(2), planners=("reactive", "cv"), values=(0.05, 0.2),
                    workers=1)
    with open(res.csv_path, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["value"], r["planner"]) for r in rows] == [("0.05", "reactive"), ("0.05", "cv"),
                                                          ("0.2", "reactive"), ("0.2", "cv")]
    assert all(r["episodes"] == "2" for r in rows)
    # Every row is the metrics of its point's records.
    for value in ("0.05", "0.2"):
        metrics = planner_metrics(load_records(tmp_path / "beta" / value))
        for r in (r for r in rows if r["value"] == value):
            m = metrics[r["planner"]]
            assert (int(r["imminent"]), int(r["collisions"]), int(r["avoided_k"]), int(r["false_alarms_k"])) == \
                (m.imminent, m.collisions, m.avoided.k, m.false_alarms.k)
    assert "| 0.2 | cv |" in res.markdown_path.read_text(encoding="utf-8")
    assert res.figure_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Each point is an experiment directory of its own; a second call reuses them.
    assert (tmp_path / "beta" / "0.05" / "episodes.jsonl").is_file()
    again = run_sweep("beta", tmp_path, seeds=range(2), planners=("reactive", "cv"), values=(0.05, 0.2),
                      workers=1, figure=False)
    assert [r["avoided_k"] for r in again.rows] == [r["avoided_k"] for r in res.rows]


def test_tau_sweep_reads_the_fine_curve_from_the_histories(tmp_path):
    res = run_sweep("tau", tmp_path, seeds=range(1, 4), planners=("cdf", "reactive"), values=(0.5, 0.95),
                    workers=1)
    # The reference planner runs once; the CDF at every tau.
    assert sorted((r["value"], r["planner"]) for r in res.rows) == [(0.5, "cdf"), (0.95, "cdf"),
                                                                   (0.95, "reactive")]
    agreement = res.extra["agreement"]
    assert agreement["episodes"] == 6 and agreement["agree"] == 6
    curve = res.extra["curve"]
    assert curve[-1]["tau"] == pytest.approx(0.95)
    fa = [c["false_alarms"] for c in curve]
    assert fa == sorted(fa, reverse=True)  # a higher threshold never brakes more often
    assert (tmp_path / "tau_curve.csv").is_file() and res.figure_path.is_file()
    assert tau_curve([], tau_max=0.5)[0]["episodes"] == 0
    # At a threshold that was run, the curve's false alarms are those of the braking run.
    at_half = planner_metrics(load_records(tmp_path / "tau" / "0.5"))["cdf"]
    assert next(c for c in curve if c["tau"] == 0.5)["false_alarms_k"] == at_half.false_alarms.k


def test_comparison_figures_are_written(tmp_path):
    from cdf_mj.experiments.experiment import run_experiment

    result = run_experiment(tmp_path / "run", range(4), ("cdf", "reactive"), cdf=CDFConfig(n_particles=300),
                            progress=False, workers=1)
    paths = comparison_figures(result.records, tmp_path / "figures")
    assert [p.name for p in paths] == ["brier_over_time.png", "brake_times.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in paths)


def test_sweep_refuses_bad_requests(tmp_path):
    with pytest.raises(ValueError, match="unknown sweep"):
        run_sweep("gamma", tmp_path, seeds=range(1))
    with pytest.raises(ValueError, match="include the planner 'cdf'"):
        run_sweep("particles", tmp_path, seeds=range(1), planners=("reactive",))
    with pytest.raises(ValueError, match="whole numbers"):
        run_sweep("particles", tmp_path, seeds=range(1), values=(10.5,))
    with pytest.raises(ValueError, match="beta"):
        run_sweep("beta", tmp_path, seeds=range(1), values=(1.5,))
    assert set(SWEEPS) == {"beta", "particles", "tau", "risk", "noise", "obs-noise"}


def test_cli_sweep(tmp_path, capsys, monkeypatch):
    argv = ["sweep", "noise", "--values", "1,2", "--episodes", "1", "--planner", "reactive",
            "--workers", "1", "--quiet", "--out", str(tmp_path)]
    assert main(argv) == 0
    assert "Sweep `noise`" in capsys.readouterr().out
    assert (tmp_path / "noise.png").is_file()
    # Without matplotlib: the tables are written, then one line naming the extra.
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main([*argv[:-1], str(tmp_path / "novis")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and install_hint("viz") in err[0]
    assert (tmp_path / "novis" / "noise.csv").is_file()
    assert main(["sweep", "noise", "--values", "x"]) == 2
    assert main(["sweep", "noise", "beta", "--values", "1"]) == 2


def test_points_are_reused_when_the_value_list_changes(tmp_path):
    kwargs = {"seeds": range(2), "planners": ("cdf", "reactive"), "workers": 1, "figure": False}
    run_sweep("tau", tmp_path, values=(0.9, 0.5), **kwargs)
    kept = (tmp_path / "tau" / "0.9" / "episodes.jsonl").read_bytes()
    result = run_sweep("tau", tmp_path, values=(0.95, 0.9), **kwargs)  # 0.9 is no longer first
    assert (tmp_path / "tau" / "0.9" / "episodes.jsonl").read_bytes() == kept
    assert {(r["value"], r["planner"]) for r in result.rows} == {(0.9, "cdf"), (0.95, "cdf"), (0.95, "reactive")}


def test_a_sweep_directory_of_the_earlier_layout_is_reused(tmp_path):
    """Earlier versions ran every planner in the first point's directory: still reused."""
    from cdf_mj.experiments.experiment import run_experiment

    run_experiment(tmp_path / "tau" / "0.9", range(2), ["cdf", "reactive"], cdf=SWEEPS["tau"].settings(
        0.9, ScenarioConfig(), CDFConfig())[1], progress=False, workers=1)
    kept = (tmp_path / "tau" / "0.9" / "episodes.jsonl").read_bytes()
    result = run_sweep("tau", tmp_path, values=(0.9, 0.5), seeds=range(2), planners=("cdf", "reactive"),
                       workers=1, figure=False)
    assert (tmp_path / "tau" / "0.9" / "episodes.jsonl").read_bytes() == kept
    assert not (tmp_path / "tau" / "reference").exists()
    assert {(r["value"], r["planner"]) for r in result.rows} == {(0.9, "cdf"), (0.5, "cdf"), (0.9, "reactive")}


class _BreaksAboveHalfTau(ReactivePlanner):
    """The reactive planner, except that it raises where the run's tau is above 0.5 (a user's
    buggy planner that takes the run's CDF settings: registered with ``shared=("cdf",)``)."""

    def __init__(self, cdf=None):
        super().__init__()
        self.tau = as_config(cdf, CDFConfig, "cdf").tau

    def reset(self, context, rng):
        if self.tau > 0.5:
            raise RuntimeError(f"planner broke at tau {self.tau}")
        super().reset(context, rng)


def test_failed_episodes_are_counted_per_point_and_never_hidden(tmp_path, monkeypatch, capsys):
    """A point whose episodes all fail keeps its row (episodes 0, failed 2), the Markdown
    names it, its directory and the error, and the command exits 1 (issue 15, item 1)."""
    monkeypatch.setitem(PLANNERS, "fragile", PlannerSpec("fragile", _BreaksAboveHalfTau, shared=("cdf",)))
    res = run_sweep("tau", tmp_path, seeds=range(2), planners=("fragile", "cdf"), values=(0.5, 0.9), workers=1)
    rows = {(r["value"], r["planner"]): r for r in res.rows}
    assert set(rows) == {(0.5, "fragile"), (0.5, "cdf"), (0.9, "fragile"), (0.9, "cdf")}
    assert (rows[0.9, "fragile"]["episodes"], rows[0.9, "fragile"]["failed"]) == (0, 2)
    assert (rows[0.5, "fragile"]["episodes"], rows[0.5, "fragile"]["failed"]) == (2, 0)
    assert (rows[0.9, "cdf"]["episodes"], rows[0.9, "cdf"]["failed"]) == (2, 0)
    assert res.failed == 2 and [(f.value, f.failed, f.episodes) for f in res.failures] == [(0.9, 2, 4)]
    assert res.failures[0].directory == tmp_path / "tau" / "0.9"
    assert "RuntimeError: planner broke at tau 0.9" in res.failures[0].error
    with open(res.csv_path, encoding="utf-8") as fh:
        csv_rows = [r for r in csv.DictReader(fh) if r["planner"] == "fragile"]
    assert [(r["value"], r["episodes"], r["failed"]) for r in csv_rows] == [("0.5", "2", "0"), ("0.9", "0", "2")]
    md = res.markdown_path.read_text(encoding="utf-8")
    assert "| 0.9 | fragile | 0 |" in md and "**2 episodes failed**" in md and str(tmp_path / "tau" / "0.9") in md
    assert res.figure_path.is_file()  # a point without completed episodes is drawn as a gap

    argv = ["sweep", "tau", "--values", "0.5,0.9", "--episodes", "2", "--planner", "fragile,cdf",
            "--workers", "1", "--quiet", "--no-figure", "--out", str(tmp_path)]
    assert main(argv) == 1  # EXIT_FAILED_EPISODES, as `experiment`
    err = capsys.readouterr().err
    assert "tau = 0.9: 2 of 4 episodes failed" in err and "planner broke" in err and "Traceback" not in err
    assert main([*argv[:3], "0.5", *argv[4:]]) == 0  # the point without failures alone: success


_FULL_DISK_SWEEP = """
import resource, signal, sys
from cdf_mj.experiments.sweep import run_sweep

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
try:
    run_sweep("beta", sys.argv[1], seeds=range(2), planners=("cv",), values=(0.05, 0.2), workers=1)
except OSError as exc:
    print(exc.errno)
    sys.exit(3)
"""


@pytest.mark.skipif(sys.platform == "win32", reason="needs POSIX resource limits")
def test_a_full_disk_leaves_the_earlier_figure_whole(tmp_path):
    """The figure (> 20 kB) meets a full disk: an OSError, the earlier PNG untouched, no
    partial or temporary file (issue 15, item 2)."""
    import subprocess

    run_sweep("beta", tmp_path, seeds=range(2), planners=("cv",), values=(0.05, 0.2), workers=1)
    before = (tmp_path / "beta.png").read_bytes()
    assert len(before) > 20_000
    run = subprocess.run([sys.executable, "-c", _FULL_DISK_SWEEP, str(tmp_path)], capture_output=True,
                         text=True, timeout=120, check=False)
    assert run.returncode == 3, run.stderr
    assert (tmp_path / "beta.png").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@pytest.mark.parametrize("name", ["noise", "obs-noise"])
def test_the_noise_sweeps_scale_the_filters_own_model_with_the_world(name):
    """Since the filter keeps its own noise model (it reads nothing of the world's), the
    noise sweeps scale both: they ask how the noise level matters, as before."""
    config, cdf = SWEEPS[name].settings(2.0, ScenarioConfig(), CDFConfig())
    world = config.noise if name == "noise" else config.observation
    own = cdf.process_noise if name == "noise" else cdf.prior.observation
    base = ScenarioConfig().noise if name == "noise" else ScenarioConfig().observation
    assert world == own == base.replace(**{k: 2 * v for k, v in base.to_dict().items()})
