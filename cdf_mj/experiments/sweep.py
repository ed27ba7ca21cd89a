"""Sweeps: how the planners' outcomes depend on one setting, through the experiment runner.

==========  ====================================================  =========================
sweep       what changes                                          default values
==========  ====================================================  =========================
beta        ``ScenarioConfig.beta``, P(observe a visible ego)     0.01 0.02 0.05 0.1 0.2
            per tick (the CDF is told the true beta)
particles   ``CDFConfig.n_particles`` N                           100 250 500 1000 2000 4000
tau         ``CDFConfig.tau``, the threshold of the paper's rule  0.5 0.6 0.7 0.8 0.85 0.9
            (the CDF runs with ``decision = "threshold"``)        0.95 0.99
risk        ``CDFConfig.risk.brake``, the risk rule's braking     0.05 0.1 0.2 0.3 0.5
            threshold (``release`` at half of it)
noise       process noise: ``noise.accel`` and ``noise.steer``    0.5 1 2 4
            times the factor (both cars; the CDF filter's own
            ``CDFConfig.process_noise`` follows)
obs-noise   observation noise: ``observation.pos``, ``.heading``, 0.5 1 2 4
            ``.speed`` times the factor (the filter's own
            ``DriverPrior.observation`` follows)
==========  ====================================================  =========================

Every point is one :func:`cdf_mj.experiments.experiment.run_experiment` call in its own directory
``OUT/<sweep>/<value>/`` (so a point that finished is reused by a later call with the same
settings, and an interrupted one resumes), on the same seeds for every point (common
random numbers). Settings that only the CDF reads (``particles``, ``tau``, ``risk``) run the
planners that do not read the CDF's settings (all but ``cdf``, ``cdf-threshold``,
``imm-risk`` and ``cv-risk``) once, as references, in ``OUT/<sweep>/reference/`` (reported at the first point),
so that a point's directory holds the same settings whatever the other values are. Each
sweep writes ``OUT/<sweep>.csv``, ``OUT/<sweep>.md`` (the metrics of
:func:`cdf_mj.analysis.metrics.planner_metrics` per point and planner) and
``OUT/<sweep>.png`` (matplotlib, the optional extra ``viz``).

An episode that fails (raises; its record holds the error) is left out of the metrics but
never out of the table: every point and planner keeps its row, with the column ``failed``
counting its failed episodes (a point whose episodes all failed has ``episodes`` 0), and
:attr:`SweepResult.failures` names each point with failures, its directory and the first
error. ``cdf-mj sweep`` then exits with status 1.

The ``tau`` sweep also writes ``OUT/tau_curve.csv``, the false alarms and detections for
a fine grid of thresholds (:func:`cdf_mj.analysis.metrics.tau_curve`), read from the
filter's P(cutoff) history of the run at the largest tau: before it brakes, the filter's
history is the same whatever the threshold (same seed, same random streams, the ego not
yet braking), so the first tick at which P(cutoff) >= tau is exactly where a run at that
tau would brake, for every tau up to the largest. Collisions are not read this way:
avoidance comes from the braking runs only, and the sweep reports how many derived brake
times agree with those runs. ::

    from cdf_mj.experiments.sweep import run_sweep
    result = run_sweep("beta", "results/sweeps", seeds=range(200), planners=("cdf", "reactive"))
    print(result.markdown)

The sweeps themselves are :mod:`cdf_mj.experiments.sweep_spec`; their tables and figures, and
the planner comparison figures, :mod:`cdf_mj.experiments.sweep_report`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cdf_mj.analysis.metrics import PlannerMetrics, Rate, decision_time, planner_metrics, tau_curve
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.store import write_atomic
from cdf_mj.experiments.sweep_report import (
    PointFailures,
    VizUnavailableError,
    _figure,
    _markdown,
    _Point,
    _write_csv,
    comparison_figures,
)
from cdf_mj.experiments.sweep_spec import SWEEPS, SweepSpec, _reads_cdf, _value_text
from cdf_mj.records import FAILED, RecordLike, completed, record_field
from cdf_mj.sim.scene import DEFAULT_SCENE

if TYPE_CHECKING:
    from cdf_mj.experiments.runner import Backend

__all__ = ["SWEEPS", "PointFailures", "SweepResult", "SweepSpec", "VizUnavailableError", "comparison_figures",
           "run_sweep"]


@dataclass
class SweepResult:
    """What :func:`run_sweep` wrote: one row per point and planner, and the file paths."""

    name: str
    rows: list[dict[str, Any]]  # PlannerMetrics.to_row() with "sweep", "value", "failed" and "point_wall_s"
    csv_path: Path
    markdown_path: Path
    figure_path: Path | None
    markdown: str
    extra: dict[str, Any] = field(default_factory=dict)  # tau: the fine curve and the agreement check
    failures: list[PointFailures] = field(default_factory=list)  # directories with failed episodes

    @property
    def failed(self) -> int:
        """Failed episodes over the whole sweep (0: every episode ran)."""
        return sum(f.failed for f in self.failures)


def _planners_in(point: Path) -> list[str] | None:
    """The planners of the results already in a point's directory (None if there are none)."""
    try:
        planners = json.loads((point / "settings.json").read_text(encoding="utf-8")).get("planners")
    except (OSError, ValueError, AttributeError):
        return None
    return list(planners) if isinstance(planners, list) else None


def _run_point(out: Path, seeds: Sequence[int], planners: Sequence[str], config: ScenarioConfig,
               cdf: CDFConfig, scene: str | Path, progress: bool, workers: int | None,
               backend: Backend = "process", address: str | None = None) -> tuple[list[RecordLike], float]:
    """One :func:`run_experiment` call, resumed where ``out`` holds the same settings (a
    finished point is reused, an interrupted one continues); returns all its records (the
    failed ones too) and its wall time [s]."""
    from cdf_mj.experiments.experiment import run_experiment

    result = run_experiment(out, seeds, list(planners), config, cdf, scene, progress,
                            workers=workers, backend=backend, address=address, resume=True)
    return list(result.records), result.wall_time


def _failures(value: float, directory: Path, records: Sequence[RecordLike]) -> list[PointFailures]:
    """The failed episodes of one directory's records (an empty list if none failed)."""
    failed = [r for r in records if record_field(r, "status") == FAILED]
    if not failed:
        return []
    return [PointFailures(value, directory, len(failed), len(records), str(record_field(failed[0], "error")))]


def _metrics(records: Sequence[RecordLike], planners: Sequence[str]) -> list[tuple[PlannerMetrics, int]]:
    """Each planner's metrics over its completed records with its count of failed episodes,
    for every planner named in ``planners`` that has records (one whose episodes all failed
    included, with ``episodes`` 0)."""
    metrics = planner_metrics(records)
    failed: dict[str, int] = {}
    for r in records:
        failed[record_field(r, "planner")] = failed.get(record_field(r, "planner"), 0) + \
            (record_field(r, "status") == FAILED)
    nan = float("nan")
    return [(metrics.get(p) or PlannerMetrics(p, 0, 0, 0, Rate(0, 0), Rate(0, 0), nan, nan, nan, None, None),
             failed[p]) for p in planners if p in failed]


def run_sweep(name: str, out_dir: str | Path, seeds: Iterable[int], planners: Sequence[str] = ("cdf", "reactive"),
              values: Sequence[float] | None = None, config: ScenarioConfig | None = None,
              cdf: CDFConfig | None = None, scene: str | Path = DEFAULT_SCENE, workers: int | None = None,
              progress: bool = False, figure: bool = True, backend: Backend = "process",
              address: str | None = None) -> SweepResult:
    """Run one sweep (see the module docstring) and write its table and figure.

    Args:
        name: a key of :data:`SWEEPS`.
        out_dir: result directory; points go to ``out_dir/<name>/<value>/``.
        seeds: a contiguous range of seeds, the same for every point.
        planners: registered planner names (``cdf`` must be among them for ``particles``
            and ``tau``).
        values: the values to sweep (default: the spec's).
        config, cdf: the settings every point starts from.
        scene: MJCF scene file.
        workers: worker processes per point (default: the runner's, the CPU count).
        progress: progress bars on stderr.
        figure: also draw ``out_dir/<name>.png`` (needs matplotlib: :class:`VizUnavailableError`).
        backend, address: where each point's episodes run (as :func:`run_experiment`'s).
    """
    if name not in SWEEPS:
        raise ValueError(f"unknown sweep {name!r}: choose one of {', '.join(SWEEPS)}")
    spec = SWEEPS[name]
    planners = list(dict.fromkeys(planners))
    if not planners:
        raise ValueError("a sweep needs at least one planner")
    if spec.cdf_only and "cdf" not in planners:
        raise ValueError(f"sweep {name} changes a CDF setting: include the planner 'cdf'")
    values = tuple(spec.values if values is None else values)
    if not values:
        raise ValueError(f"sweep {name}: no values")
    if len(set(values)) != len(values):
        raise ValueError(f"sweep {name}: repeated values {list(values)}")
    config, cdf = config or ScenarioConfig(), cdf or CDFConfig()
    points = [(v, *spec.settings(v, config, cdf)) for v in values]  # all validated before any run
    seeds = list(seeds)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if spec.name == "tau":  # the largest tau first: its histories give the fine curve
        points.sort(key=lambda p: -p[0])

    table: list[_Point] = []
    failures: list[PointFailures] = []
    records_by_value: dict[float, list[RecordLike]] = {}
    # Planners that read the CDF's settings run at every point; the others, for a setting
    # only those read, run once as references.
    varied = [p for p in planners if _reads_cdf(p)] if spec.cdf_only else planners
    references = [p for p in planners if p not in varied]
    for i, (value, cfg, cdf_v) in enumerate(points):
        point = out / name / _value_text(value)
        names = varied
        if i == 0 and references and _planners_in(point) == list(planners):
            names, references = planners, []  # an earlier version's layout: every planner here
        recs, wall = _run_point(point, seeds, names, cfg, cdf_v, scene, progress, workers, backend, address)
        failures += _failures(value, point, recs)
        if i == 0 and references:  # unaffected by the swept CDF setting: run once, at the base
            ref, ref_wall = _run_point(out / name / "reference", seeds, references, config, cdf, scene,
                                       progress, workers, backend, address)
            failures += _failures(value, out / name / "reference", ref)
            recs, wall = recs + ref, wall + ref_wall
        records_by_value[value] = completed(recs)
        table += [_Point(value, m, k, wall) for m, k in _metrics(recs, planners)]
    table.sort(key=lambda p: (p.value, planners.index(p.metrics.planner) if p.metrics.planner in planners else 99))
    rows = [p.row(name) for p in table]

    extra: dict[str, Any] = {}
    if spec.name == "tau":
        top = max(records_by_value)
        curve = tau_curve(records_by_value[top], tau_max=top)
        extra["curve"] = curve
        extra["agreement"] = _tau_agreement(records_by_value, top)
        _write_csv(out / "tau_curve.csv", curve)

    md = _markdown(spec, table, extra, failures)
    csv_path, md_path = out / f"{name}.csv", out / f"{name}.md"
    _write_csv(csv_path, rows)
    write_atomic(md_path, md + "\n")
    fig_path = None
    if figure:
        fig_path = out / f"{name}.png"
        _figure(spec, rows, extra, fig_path)
    return SweepResult(name=name, rows=rows, csv_path=csv_path, markdown_path=md_path,
                       figure_path=fig_path, markdown=md, extra=extra, failures=failures)


def _tau_agreement(records_by_value: dict[float, list[RecordLike]], top: float) -> dict[str, int]:
    """How many brake times of the braking runs (the top run's own included) the top run's
    histories predict (:func:`~cdf_mj.analysis.metrics.decision_time`). The history stores
    P(cutoff) rounded to 5 decimals, so a value within 5e-6 of a threshold may be read on
    the other side of it."""
    def cdf_runs(recs: list[RecordLike]) -> list[RecordLike]:
        return [r for r in recs if record_field(r, "planner") == "cdf"]

    base = {record_field(r, "seed"): r for r in cdf_runs(records_by_value[top])}
    same = total = 0
    for tau, recs in records_by_value.items():
        for r in cdf_runs(recs):
            if record_field(r, "seed") in base:
                total += 1
                same += decision_time(base[record_field(r, "seed")], tau) == record_field(r, "brake_time")
    return {"episodes": total, "agree": same}
