"""What a sweep writes: the rows of its table (one per point and planner, and the
directories with failed episodes), as CSV and Markdown, and its figure; and the planner
comparison figures of an experiment's records (:func:`comparison_figures`). Figures need
matplotlib (the optional extra ``viz``; :class:`VizUnavailableError` without it). ::

    from cdf_mj.experiments.sweep_report import comparison_figures
    paths = comparison_figures(records, "docs/img/analysis")
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cdf_mj.analysis.metrics import PlannerMetrics, brier_over_time, prior_brier
from cdf_mj.analysis.tables import format_number, format_rate
from cdf_mj.experiments.store import write_atomic
from cdf_mj.experiments.sweep_spec import SweepSpec, _reads_cdf, _value_text
from cdf_mj.extras import require
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.records import RecordLike, completed, is_false_alarm, is_imminent, lead_time, record_field

__all__ = ["PointFailures", "VizUnavailableError", "comparison_figures"]


class VizUnavailableError(ImportError):
    """matplotlib is missing: the figures need the optional extra ``viz``."""


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
