"""Figures and a Markdown page from an experiment directory: ``cdf-mj report DIR``.

Reads ``DIR/settings.json`` and ``DIR/episodes.jsonl`` (as written by
``cdf-mj experiment --out DIR``) and writes, into ``DIR`` or ``out``:

====================  ======================================================================
``confusion.png``     the CDF's confusion matrix (scenario label x prediction) beside the paper's
``avoidance.png``     per planner: imminent collisions avoided and false alarms, 95 % Wilson
                      intervals
``trajectories.png``  top-down paths of both cars for a few seeds over the road layout of the
                      run's scene, axes from the scene's extent (:func:`scene_extent`)
``posterior.png``     P(left), P(seen), P(cutoff) over time for the same seeds (CDF)
``lead_times.png``    distribution of braking lead times, entered_lane_time - brake_time [s]
``report.md``         the tables of :func:`cdf_mj.analysis.tables.experiment_tables`, every figure
====================  ======================================================================

Legends lie outside the axes (beside, above or below), never over the data.

A figure whose data are absent (no CDF records, no braking before a lane entry) is left
out and the page says why. The records file is read with
:func:`cdf_mj.records.read_records` and the settings with :func:`cdf_mj.records.read_settings`,
before any work: a damaged line or key is one error naming it; failed episodes
(``"status": "failed"``) and a half-written last line (a run still writing) are skipped
and counted. Every rate and count comes from :mod:`cdf_mj.analysis.metrics`, as in the
tables. Planners other than ``cdf`` and ``reactive`` are shown like them. The
trajectories are re-simulated from the stored settings (``trace=True``); the posterior
traces come from the stored records. Figures use matplotlib's Agg canvas directly, so no
global backend is changed. The directory is read by :mod:`cdf_mj.viz.report_data` and the
figures are drawn by :mod:`cdf_mj.viz.report_figures`; this module writes the page. ::

    from cdf_mj.viz.report import write_report
    result = write_report("results/experiment")
    result.markdown, result.figures
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cdf_mj.analysis.tables import experiment_tables
from cdf_mj.inputs import printable
from cdf_mj.records import write_atomic
from cdf_mj.records.files import check_output_target
from cdf_mj.viz.report_data import Experiment, ReportError, load_experiment
from cdf_mj.viz.report_figures import (
    FIGURES,
    _avoidance,
    _confusion,
    _figure,
    _lead_times,
    _pick_seeds,
    _posterior,
    _trajectories,
    scene_extent,
    trajectories_figure,
)

__all__ = ["FIGURES", "Experiment", "ReportError", "ReportResult", "load_experiment", "scene_extent",
           "shown_path", "trajectories_figure", "write_report"]


@dataclass(frozen=True)
class ReportResult:
    """What :func:`write_report` wrote."""

    markdown: Path
    figures: dict[str, Path]  # name -> PNG, only those written
    omitted: dict[str, str]  # name -> why the figure was left out
    records: int  # completed records used
    failed: int  # failed records skipped
    unreadable: int  # 1 if a half-written last line was skipped, else 0


def shown_path(path: str | Path) -> str:
    """``path`` as text that any page or terminal takes: bytes of the name that are not
    UTF-8 and control characters written as escapes (the byte 0xFF as ``\\xff``, a newline
    as ``\\n``), the rest as it is."""
    return printable(os.fsencode(path).decode("utf-8", "backslashreplace"))


def write_report(path: str | Path, out: str | Path | None = None, seeds: Sequence[int] | None = None,
                 planner: str | None = None) -> ReportResult:
    """Write the figures of :data:`FIGURES` and ``report.md`` for an experiment directory.

    Args:
        path: the experiment directory (``settings.json``, ``episodes.jsonl``).
        out: where to write (default ``path``); created if missing.
        seeds: seeds for the trajectory and posterior figures (default: one per label).
        planner: planner whose trajectories are drawn (default ``cdf`` if present, else the
            first planner of the experiment).

    Raises:
        ReportError: not an experiment directory, nothing completed, unknown planner,
            missing matplotlib.
    """
    exp = load_experiment(path)
    out = Path(out) if out is not None else exp.path
    _figure(1, 1)  # matplotlib missing: refused before any work
    if planner is None:
        planner = "cdf" if "cdf" in exp.planners else exp.planners[0]
    elif planner not in exp.planners:
        raise ReportError(f"planner {planner!r} has no records in {exp.path}: "
                          f"choose one of {', '.join(exp.planners)}")
    known = {int(r["seed"]) for r in exp.by_planner(planner)}
    if seeds is not None:
        missing = [s for s in seeds if s not in known]
        if missing:
            raise ReportError(f"seed(s) {', '.join(map(str, missing))} have no completed {planner} "
                              f"record in {exp.path}")
        seeds = list(seeds)
    else:
        seeds = _pick_seeds(exp, planner)
    out.mkdir(parents=True, exist_ok=True)
    for name in (*(f"{figure}.png" for figure in FIGURES), "report.md"):
        check_output_target(out / name)  # a FIFO or a device there: refused before any figure is drawn

    notes: list[str] = []
    made: dict[str, Path | str] = {
        "confusion": _confusion(exp, out / "confusion.png"),
        "avoidance": _avoidance(exp, out / "avoidance.png"),
        "trajectories": _trajectories(exp, planner, seeds, out / "trajectories.png", notes),
        "posterior": _posterior(exp, seeds, out / "posterior.png"),
        "lead_times": _lead_times(exp, out / "lead_times.png"),
    }
    figures = {k: v for k, v in made.items() if isinstance(v, Path)}
    omitted = {k: v for k, v in made.items() if isinstance(v, str)}

    s = exp.settings
    span = s.get("seeds", [])
    lines = [f"# Experiment report: {shown_path(exp.path)}", "",
             f"{len(exp.records)} completed episode records, planners {', '.join(exp.planners)}"
             + (f", seeds {span[0]}-{span[1] - 1}" if len(span) == 2 else "") + "."]
    skipped = []
    if exp.failed:
        skipped.append(f"{exp.failed} failed episode(s) (`\"status\": \"failed\"`)")
    if exp.unreadable:
        skipped.append("a half-written last line")
    lines.append(f"Skipped: {', '.join(skipped)}." if skipped else "Skipped: none.")
    lines += ["", "## Tables", "", experiment_tables(exp.records, fmt="markdown"), "", "## Figures", ""]
    for name, caption in FIGURES.items():
        if name in figures:
            lines += [f"**{name}**: {caption}.", "", f"![{name}]({figures[name].name})", ""]
        else:
            lines += [f"**{name}**: not drawn ({omitted[name]}).", ""]
    if "trajectories" in figures:
        lines += [f"Trajectory and posterior seeds ({planner}): {', '.join(map(str, seeds))}.", ""]
    lines += notes
    markdown = out / "report.md"
    write_atomic(markdown, "\n".join(lines).rstrip() + "\n")  # a planted symlink is replaced, never followed
    return ReportResult(markdown=markdown, figures=figures, omitted=omitted, records=len(exp.records),
                        failed=exp.failed, unreadable=exp.unreadable)
