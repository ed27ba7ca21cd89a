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
noise       process noise: ``noise_accel`` and ``noise_steer``    0.5 1 2 4
            times the factor (both cars; the CDF's filter noise
            follows, as ``process_noise_scale`` x the scenario's)
obs-noise   observation noise: ``obs_noise_pos``, ``_heading``,   0.5 1 2 4
            ``_speed`` times the factor
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
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cdf_mj.analysis.metrics import (
    PlannerMetrics,
    Rate,
    brier_over_time,
    decision_time,
    planner_metrics,
    prior_brier,
    tau_curve,
)
from cdf_mj.analysis.tables import format_number, format_rate
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.store import write_atomic
from cdf_mj.extras import require
from cdf_mj.planners.registry import PLANNERS, planner_spec
from cdf_mj.records import (
    FAILED,
    RecordLike,
    completed,
    is_false_alarm,
    is_imminent,
    lead_time,
    record_field,
)
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["SWEEPS", "PointFailures", "SweepResult", "SweepSpec", "VizUnavailableError", "comparison_figures",
           "run_sweep"]

class VizUnavailableError(ImportError):
    """matplotlib is missing: the figures need the optional extra ``viz``."""


def _reads_cdf(name: str) -> bool:
    """Whether planner ``name`` takes any of a run's CDF settings (its registry entry's
    ``shared``); an unregistered name reads none."""
    return name in PLANNERS and bool(planner_spec(name).shared)


def _scale_process(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    noise = config.noise
    return config.replace(noise=noise.replace(accel=noise.accel * k, steer=noise.steer * k)), cdf


def _scale_obs(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    seen = config.observation
    return config.replace(observation=seen.replace(pos=seen.pos * k, heading=seen.heading * k,
                                                   speed=seen.speed * k)), cdf


@dataclass(frozen=True)
class SweepSpec:
    """One sweep: the setting it changes, its default values and how a value is applied."""

    name: str
    label: str  # axis label, with unit
    values: tuple[float, ...]
    apply: Callable[[ScenarioConfig, CDFConfig, float], tuple[ScenarioConfig, CDFConfig]]
    cdf_only: bool  # only the CDF reads it: other planners run once, at the first point
    integer: bool = False
    log_x: bool = False

    def settings(self, value: float, config: ScenarioConfig, cdf: CDFConfig) -> tuple[ScenarioConfig, CDFConfig]:
        """The scenario and CDF settings of one point (ValueError out of range)."""
        if self.integer:
            if float(value) != int(value):
                raise ValueError(f"{self.name} values must be whole numbers, got {value!r}")
            value = int(value)
        return self.apply(config, cdf, value)


SWEEPS: dict[str, SweepSpec] = {s.name: s for s in (
    SweepSpec("beta", "beta, P(observe a visible ego) per 0.1 s tick", (0.01, 0.02, 0.05, 0.1, 0.2),
              lambda c, d, v: (c.with_values({"obstacle.beta": float(v)}), d), cdf_only=False, log_x=True),
    SweepSpec("particles", "particle count N", (100, 250, 500, 1000, 2000, 4000),
              lambda c, d, v: (c, d.replace(n_particles=int(v))), cdf_only=True, integer=True, log_x=True),
    SweepSpec("tau", "braking threshold tau on P(cutoff) (the paper's rule)",
              (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99),
              lambda c, d, v: (c, d.replace(tau=float(v), decision="threshold")), cdf_only=True),
    SweepSpec("risk", "risk rule: braking threshold on P(collision if deferred)", (0.05, 0.1, 0.2, 0.3, 0.5),
              lambda c, d, v: (c, d.replace(decision="risk", risk=d.risk.replace(brake=float(v),
                                                                                  release=float(v) / 2))),
              cdf_only=True, log_x=True),
    SweepSpec("noise", "process noise, factor on noise_accel and noise_steer", (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_process(c, d, float(v)), cdf_only=False, log_x=True),
    SweepSpec("obs-noise", "observation noise, factor on obs_noise_*", (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_obs(c, d, float(v)), cdf_only=False, log_x=True),
)}


@dataclass(frozen=True)
class PointFailures:
    """The failed episodes of one experiment directory of a sweep (a point, or the
    reference run listed at the first point)."""

    value: float  # the swept value the directory's rows are listed at
    directory: Path  # its episodes.jsonl holds each failed record's error and traceback
    failed: int  # failed episodes
    episodes: int  # all episodes of the directory
    error: str  # the first failed record's error, e.g. "MemoryError: ..."

    def __str__(self) -> str:
        return (f"{self.failed} of {self.episodes} episodes failed in {self.directory} "
                f"(first: {' '.join(self.error.split())})")


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


def _value_text(value: float) -> str:
    return f"{value:g}"


def _planners_in(point: Path) -> list[str] | None:
    """The planners of the results already in a point's directory (None if there are none)."""
    try:
        planners = json.loads((point / "settings.json").read_text(encoding="utf-8")).get("planners")
    except (OSError, ValueError, AttributeError):
        return None
    return list(planners) if isinstance(planners, list) else None


def _run_point(out: Path, seeds: Sequence[int], planners: Sequence[str], config: ScenarioConfig,
               cdf: CDFConfig, scene: str | Path, progress: bool,
               workers: int | None) -> tuple[list[RecordLike], float]:
    """One :func:`run_experiment` call, resumed where ``out`` holds the same settings (a
    finished point is reused, an interrupted one continues); returns all its records (the
    failed ones too) and its wall time [s]."""
    from cdf_mj.experiments.experiment import run_experiment

    result = run_experiment(out, seeds, list(planners), config, cdf, scene, progress,
                            workers=workers, resume=True)
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


@dataclass(frozen=True)
class _Point:
    """One planner's metrics at one value of the swept setting."""

    value: float
    metrics: PlannerMetrics
    failed: int  # the planner's failed episodes at this point (not in ``metrics``)
    wall: float  # [s] of the point's run_experiment calls

    def row(self, sweep: str) -> dict[str, Any]:
        return {"sweep": sweep, "value": self.value, **self.metrics.to_row(), "failed": self.failed,
                "point_wall_s": round(self.wall, 2)}


def run_sweep(name: str, out_dir: str | Path, seeds: Iterable[int], planners: Sequence[str] = ("cdf", "reactive"),
              values: Sequence[float] | None = None, config: ScenarioConfig | None = None,
              cdf: CDFConfig | None = None, scene: str | Path = DEFAULT_SCENE, workers: int | None = None,
              progress: bool = False, figure: bool = True) -> SweepResult:
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
        recs, wall = _run_point(point, seeds, names, cfg, cdf_v, scene, progress, workers)
        failures += _failures(value, point, recs)
        if i == 0 and references:  # unaffected by the swept CDF setting: run once, at the base
            ref, ref_wall = _run_point(out / name / "reference", seeds, references, config, cdf, scene,
                                       progress, workers)
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


# ----------------------------------------------------------------- output
_COLUMNS = ("sweep", "value", "planner", "episodes", "imminent", "collisions", "avoided", "avoided_lo",
            "avoided_hi", "avoided_k", "avoided_n", "false_alarms", "false_alarms_lo", "false_alarms_hi",
            "false_alarms_k", "false_alarms_n", "lead_time", "min_gap", "time_lost", "brier_left",
            "brier_seen", "failed", "point_wall_s")


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """``rows`` as CSV, whole or not at all (:func:`~cdf_mj.experiments.store.write_atomic`)."""
    text = io.StringIO(newline="")
    if rows:
        cols = [c for c in _COLUMNS if c in rows[0]] + [c for c in rows[0] if c not in _COLUMNS]
        w = csv.DictWriter(text, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols})
    write_atomic(path, text.getvalue())


def _markdown(spec: SweepSpec, table: list[_Point], extra: dict[str, Any], failures: Sequence[PointFailures]) -> str:
    lines = [f"Sweep `{spec.name}`: {spec.label}", "",
             ("| value | planner | imminent | collisions | avoided (95 % CI) | false alarms (95 % CI) "
             "| median lead [s] | median min gap [m] | mean time lost [s] | Brier P(left) | Brier P(seen) "
             "| failed | point wall time [s] |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in table:
        m = p.metrics
        cells = [_value_text(p.value), m.planner, str(m.imminent), str(m.collisions), format_rate(m.avoided),
                 format_rate(m.false_alarms), format_number(m.lead_time), format_number(m.min_gap),
                 format_number(m.time_lost), format_number(m.brier_left, 3), format_number(m.brier_seen, 3),
                 str(p.failed), format_number(p.wall, 1)]
        lines.append("| " + " | ".join(cells) + " |")
    others = sorted({_value_text(p.value) for p in table if not _reads_cdf(p.metrics.planner)})
    if spec.cdf_only and others:
        readers = sorted(n for n in PLANNERS if _reads_cdf(n))
        lines += ["", (f"Planners other than {', '.join(f'`{n}`' for n in readers)} do not read this "
                       f"setting: they ran once and are listed at {spec.name} = {', '.join(others)}.")]
    if failures:
        lines += ["", f"**{sum(f.failed for f in failures)} episodes failed** and are not in the metrics "
                      "(each failed record holds its error and traceback):"]
        lines += [f"- {spec.name} = {_value_text(f.value)}: {f}" for f in failures]
    if "agreement" in extra:
        a = extra["agreement"]
        lines += ["", (f"Brake times derived from the histories of the largest-tau run agree with the "
                      f"braking runs in {a['agree']}/{a['episodes']} CDF episodes (`tau_curve.csv` "
                      "holds the fine curve; its false alarms are exact up to the 5-decimal rounding of the stored "
                      "P(cutoff), its avoidance is not computed).")]
    return "\n".join(lines)


def _pyplot() -> Any:
    try:
        matplotlib = require("matplotlib", "viz", "the sweep figures")
    except ImportError as exc:
        raise VizUnavailableError(str(exc)) from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    """Lay out, write as PNG (110 dpi, parents created; whole or not at all) and close a
    figure; returns ``path``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    png = io.BytesIO()
    try:
        fig.savefig(png, format="png", dpi=110)
    finally:
        plt.close(fig)
    return write_atomic(path, png.getvalue())


def _figure(spec: SweepSpec, rows: list[dict[str, Any]], extra: dict[str, Any], path: Path) -> None:
    """Avoided and false alarms against the swept value (tau: the operating curve)."""
    plt = _pyplot()
    planners = list(dict.fromkeys(r["planner"] for r in rows))
    if spec.name == "tau":
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
        cdf_rows = sorted((r for r in rows if r["planner"] == "cdf"), key=lambda r: r["value"])
        ax.errorbar([100 * r["false_alarms"] for r in cdf_rows], [100 * r["avoided"] for r in cdf_rows],
                    yerr=[[100 * (r["avoided"] - r["avoided_lo"]) for r in cdf_rows],
                          [100 * (r["avoided_hi"] - r["avoided"]) for r in cdf_rows]],
                    fmt="o-", color="C0", capsize=2, label="cdf over tau (braking runs)")
        for k, r in enumerate(cdf_rows):
            ax.annotate(f"{_value_text(r['value'])}", (100 * r["false_alarms"], 100 * r["avoided"]),
                        textcoords="offset points", xytext=(3, 6 if k % 2 else -11), fontsize=7, color="C0")
        for j, p in enumerate(x for x in planners if x != "cdf"):
            r = next(r for r in rows if r["planner"] == p)
            ax.plot(100 * r["false_alarms"], 100 * r["avoided"], marker="s", ls="", color=f"C{j + 1}", label=p)
        ax.set_xlabel("false alarms [% of episodes]")
        ax.set_ylabel("imminent collisions avoided [% of Cutoff episodes]")
        ax.set_title("Operating curve (labels: tau)", fontsize=10)
        curve = extra.get("curve") or []
        if curve:
            taus = [c["tau"] for c in curve]
            bx.plot(taus, [100 * c["false_alarms"] for c in curve], color="C3",
                    label="false alarms, every 0.01 (from the histories)")
            bx.fill_between(taus, [100 * c["false_alarms_lo"] for c in curve],
                            [100 * c["false_alarms_hi"] for c in curve], color="C3", alpha=0.15, lw=0)
            bx.plot(taus, [100 * c["detected"] for c in curve], color="0.5", ls=":",
                    label="cut-offs braked for before lane entry (from the histories)")
        bx.plot([r["value"] for r in cdf_rows], [100 * r["false_alarms"] for r in cdf_rows], "o", color="C3",
                mfc="none", label="false alarms (braking runs)")
        bx.plot([r["value"] for r in cdf_rows], [100 * r["avoided"] for r in cdf_rows], "o-", color="C0",
                label="avoided (braking runs)")
        bx.set_xlabel("tau")
        bx.set_ylabel("[%]")
        bx.set_title("Against the threshold", fontsize=10)
        for a in (ax, bx):
            a.grid(alpha=0.3)
            a.legend(fontsize=7)
    else:
        fig, axes = plt.subplots(1, 3 if any(r["brier_left"] is not None for r in rows) else 2,
                                 figsize=(13, 4))
        series = [("avoided", "imminent collisions avoided [%]"), ("false_alarms", "false alarms [% of episodes]")]
        for ax, (key, title) in zip(axes, series, strict=False):  # a third axis: the Brier scores
            for j, p in enumerate(planners):
                rs = sorted((r for r in rows if r["planner"] == p), key=lambda r: r["value"])
                xs = [r["value"] for r in rs]
                ys = [100 * r[key] for r in rs]
                err = [[100 * (r[key] - r[f"{key}_lo"]) for r in rs], [100 * (r[f"{key}_hi"] - r[key]) for r in rs]]
                if len(rs) == 1 and spec.cdf_only:
                    ax.axhline(ys[0], color=f"C{j}", ls="--", lw=1, label=f"{p} (does not read it)")
                else:
                    ax.errorbar(xs, ys, yerr=err, fmt="o-", capsize=2, color=f"C{j}", label=p)
            ax.set_title(title, fontsize=10)
        if len(axes) == 3:
            ax = axes[2]
            for j, p in enumerate(planners):
                for key, style in (("brier_left", "o-"), ("brier_seen", "s--")):
                    rs = sorted((r for r in rows if r["planner"] == p and r[key] is not None),
                                key=lambda r: r["value"])
                    if len(rs) > 1:
                        ax.plot([r["value"] for r in rs], [r[key] for r in rs], style, color=f"C{j}",
                                label=f"{p} {'P(left)' if key == 'brier_left' else 'P(seen)'}")
            ax.set_title("Brier score over all ticks (lower is better)", fontsize=10)
        for ax in axes:
            ax.set_xlabel(spec.label, fontsize=8)
            if spec.log_x:
                ax.set_xscale("log")
                ax.minorticks_off()
            values = sorted({r["value"] for r in rows})
            ax.set_xticks(values)
            ax.set_xticklabels([_value_text(v) for v in values], fontsize=8)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"Sweep: {spec.name}", fontsize=11)
    _save(fig, path)


# ----------------------------------------------------------------- planner comparison figures
def comparison_figures(records: Iterable[RecordLike], out_dir: str | Path, p_left: float = 0.75) -> list[Path]:
    """Figures of an experiment's records (planners on the same seeds), written to ``out_dir``:

    ``brier_over_time.png``: Brier score of P(left) and P(seen) per tick time for every
    planner with such a history, beside the prior ``p_left`` held constant and the per-time
    base rate (in-sample); ``brake_times.png``: each planner's lead times in Cutoff
    episodes (:func:`~cdf_mj.records.lead_time`), and its false alarms
    (:func:`~cdf_mj.records.is_false_alarm`, of all episodes) by each time.
    """
    plt = _pyplot()
    recs = [r for r in completed(records) if record_field(r, "label") is not None]
    by_planner: dict[str, list[RecordLike]] = {}
    for r in recs:
        by_planner.setdefault(record_field(r, "planner"), []).append(r)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for ax, q, title in ((axes[0], "p_left", "P(left) against the true intent"),
                         (axes[1], "p_seen", "P(seen) against 'observed the ego on an earlier tick'")):
        ref = None
        for j, (p, mine) in enumerate(by_planner.items()):
            c = brier_over_time(mine, q)
            if not c.episodes:
                continue
            keep = c.counts >= max(10, 0.1 * c.episodes)
            ax.plot(c.times[keep], c.scores[keep], color=f"C{j}", label=f"{p} (all ticks {c.overall:.3f})")
            ref = ref or c
        if ref is not None:
            keep = ref.counts >= max(10, 0.1 * ref.episodes)
            if q == "p_left":
                ax.axhline(prior_brier(next(iter(by_planner.values())), p_left), color="0.5", ls=":",
                           label=f"prior {p_left:g}, held")
            else:
                ax.plot(ref.times[keep], ref.reference[keep], color="0.5", ls=":",
                        label="base rate per time (in-sample)")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("Brier score (lower is better)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "brier_over_time.png"))

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for j, (p, mine) in enumerate(by_planner.items()):
        leads = sorted(t for t in map(lead_time, mine) if t is not None)
        n_cut = sum(map(is_imminent, mine))
        if leads:
            axes[0].step(leads, np.arange(1, len(leads) + 1) / n_cut * 100, where="post", color=f"C{j}", label=p)
        alarms = sorted(record_field(r, "brake_time") for r in mine if is_false_alarm(r))
        share = np.arange(len(alarms) + 1) / len(mine) * 100
        axes[1].step([0.0, *alarms, 8.0], [*share, share[-1]], where="post", color=f"C{j}", label=p)
    axes[0].invert_xaxis()
    axes[0].set_xlabel("lead time: obstacle enters the ego lane minus brake [s]")
    axes[0].set_ylabel("Cutoff episodes braked with at least this lead [%]")
    axes[1].set_xlabel("time [s]")
    axes[1].set_ylabel("false alarms by then [% of all episodes]")
    axes[0].set_title("Lead time in Cutoff episodes", fontsize=10)
    axes[1].set_title("False alarms over time (braked in a Yield or Right episode)", fontsize=10)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "brake_times.png"))
    return paths
