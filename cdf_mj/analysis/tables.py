"""Tables of episode records beside the paper's figures, as plain text for a terminal or as
Markdown for the docs.

:func:`experiment_tables` prints the paper's two tables beside ours (the one that
``cdf-mj experiment`` prints); :func:`planner_table`, :func:`paired_table`,
:func:`filter_table` and :func:`format_scenario_summary` are the Markdown tables of
docs/ANALYSIS.md and of the calibration. Every page's planner table counts every
intervention, not only hard brakes: a page script adds :data:`INTERVENTION_COLUMNS`
(:func:`intervention_cells`) to its rows and prints :func:`intervention_notes` under them,
or prints :func:`intervention_table`. Every number comes from
:mod:`cdf_mj.analysis.metrics`, so the tables, the report's figures and the sweeps agree. ::

    from cdf_mj.analysis.tables import experiment_tables
    from cdf_mj.records import load_records
    print(experiment_tables(load_records("results/reproduce")))                    # text
    print(experiment_tables(load_records("results/reproduce"), fmt="markdown"))    # docs
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Collection, Iterable, Sequence
from typing import Literal

import numpy as np

from cdf_mj.analysis.metrics import (
    FILTER_QUANTITIES,
    PlannerMetrics,
    Rate,
    brier_over_time,
    confusion_matrix,
    cutoff_recall,
    paired_counts,
    planner_metrics,
    prior_brier,
)
from cdf_mj.analysis.pages import markdown_table
from cdf_mj.analysis.safety import SafetyParams, safety_summary
from cdf_mj.planners.base import INTERVENTION_SHARE
from cdf_mj.records import LABELS, Label, RecordLike, completed, is_imminent, paper_avoided, record_field

__all__ = ["INTERVENTION_COLUMNS", "PAPER_CONFUSION", "PAPER_PLANNERS", "TableFormat", "experiment_tables",
           "filter_table", "format_number", "format_percent", "format_rate", "format_scenario_summary",
           "intervention_cells", "intervention_notes", "intervention_table", "margin_table", "paired_table",
           "planner_table"]

#: The paper's Figure "Simulation results using the CDF", 1000 episodes: scenario label ->
#: episodes predicted Cutoff, Yield, Right.
PAPER_CONFUSION: dict[str, tuple[int, int, int]] = {
    Label.CUTOFF: (417, 0, 0), Label.YIELD: (13, 334, 0), Label.RIGHT: (0, 0, 236)}
#: The paper's planner comparison: planner -> (collisions imminent, collisions occurred).
PAPER_PLANNERS: dict[str, tuple[int, int]] = {"cdf": (417, 9), "reactive": (404, 213)}

#: ``text``: aligned columns for a terminal (at most 100 characters wide with the usual
#: planner names); ``markdown``: pipe tables for the docs.
TableFormat = Literal["text", "markdown"]
_FORMATS = ("text", "markdown")


def format_number(value: float | None, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals; ``-`` for None or NaN."""
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def format_rate(rate: Rate) -> str:
    """``p % [lo, hi] (k/n)`` with the 95 % Wilson interval; ``-`` for a rate of nothing (n = 0)."""
    return str(rate) if rate.n else "-"


def format_percent(share: float, digits: int = 1) -> str:
    """``share`` (a fraction) in per cent; ``-`` for NaN."""
    return "-" if math.isnan(share) else f"{100 * share:.{digits}f} %"


def _paper_share(imminent: int, occurred: int) -> str:
    """The paper's avoided share of its own counts, as it rounds it."""
    return format_percent(paper_avoided(imminent, occurred), 0)


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], fmt: TableFormat,
           right: Collection[int] = ()) -> str:
    """Markdown pipe table, or text columns two spaces apart under a dashed rule (the
    columns numbered in ``right`` right-aligned)."""
    if fmt == "markdown":
        return "\n".join(markdown_table(header, rows))
    widths = [max(map(len, column)) for column in zip(header, *rows, strict=True)]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def _check_format(fmt: str) -> None:
    if fmt not in _FORMATS:
        raise ValueError(f"unknown table format {fmt!r}: choose one of {', '.join(_FORMATS)}")


# ----------------------------------------------------------------- every intervention
#: The columns every page's planner table gains (:func:`intervention_cells`), after its
#: false alarms, which are hard brakes only (:func:`intervention_notes` says so).
INTERVENTION_COLUMNS = ("interventions, not Cutoff (95 % CI)",
                        "time lost at the fixed point vs constant, not Cutoff [s] (seeds)",
                        "median peak deceleration, intervening, not Cutoff [m/s²]")


def intervention_cells(m: PlannerMetrics) -> list[str]:
    """The cells of :data:`INTERVENTION_COLUMNS` for one planner (``-`` where its records
    carry no ``intervention``, or no same-seed ``constant`` record is there)."""
    lost = f"{format_number(m.time_lost_fixed)} ({m.time_lost_fixed_seeds})" if m.time_lost_fixed_seeds else "-"
    return [format_rate(m.false_interventions), lost, format_number(m.peak_decel)]


def intervention_notes(metrics: Iterable[PlannerMetrics], reference: str = "constant") -> list[str]:
    """Lines to print under a planner table with :data:`INTERVENTION_COLUMNS`: what they
    count, that "false alarms" are hard brakes, the hard subset (Cutoff seeds on which the
    ``reference`` ego's ACC alone hit the obstacle) and each planner's share of it avoided,
    and what is missing (records without ``intervention``, no ``reference`` records)."""
    metrics = list(metrics)
    lines = ["Interventions: episodes in which the planner's command held the ego below its own controller "
             f"(speed hold and car following) by more than {100 * INTERVENTION_SHARE:g} % of the car's full brake "
             "on some tick, hard brake "
             "or not. False alarms count hard brakes only (the hard-brake false alarms). Time lost at the fixed "
             f"point: when the ego passes timing.label_distance beyond the conflict point, minus when the same "
             f"seed's `{reference}` ego (which follows too) does, pairs without a collision (an ego that never "
             "got there is extrapolated at its nominal speed: a lower bound)."]
    hard = next((m.hard_cutoffs for m in metrics if m.planner == reference), 0)
    if any(m.planner == reference for m in metrics):
        avoided = ", ".join(f"{m.planner} {m.hard_avoided.k}/{m.hard_avoided.n}" for m in metrics)
        lines.append(f"Hard subset: {hard} Cutoff seed(s) on which `{reference}`'s ACC alone hit the obstacle"
                     + (f"; avoided: {avoided}." if hard else "."))
    else:
        lines.append(f"No `{reference}` episodes in these records: no time lost at the fixed point and no hard "
                     "subset ('-').")
    missing = [f"{m.planner} {m.without_intervention}" for m in metrics if m.without_intervention]
    if missing:
        lines.append(f"Records without `intervention` (written before it was kept): {', '.join(missing)}; the "
                     "intervention columns count the others ('-' where none).")
    return lines


def intervention_table(metrics: Iterable[PlannerMetrics], fmt: TableFormat = "markdown",
                       reference: str = "constant") -> str:
    """Every planner's interventions: in Markdown, the hard-brake false alarms,
    :data:`INTERVENTION_COLUMNS`, the share in Yield and in Right episodes beside the recall in
    Cutoff episodes and the hard subset avoided, then :func:`intervention_notes` and what a
    ``-`` means; as text, :data:`INTERVENTION_COLUMNS` within 100 columns and the notes."""
    _check_format(fmt)
    metrics = list(metrics)
    if fmt == "text":
        header = ["planner", "interventions, not Cutoff", "time lost [s] (seeds)", "peak decel [m/s²]"]
        rows = [[m.planner, *intervention_cells(m)] for m in metrics]
        return "\n".join([_table(header, rows, "text", right=(2, 3)),
                          "time lost: at the fixed point, vs constant; peak decel: median over intervening, "
                          "not Cutoff.",
                          *(textwrap.fill(line, 100) for line in intervention_notes(metrics, reference))])
    others = [lab for lab in LABELS if lab != Label.CUTOFF]
    header = ["planner", "hard-brake false alarms, of all episodes (95 % CI)", *INTERVENTION_COLUMNS,
              *(f"interventions, {lab} (95 % CI)" for lab in others),
              "interventions in Cutoff: recall (95 % CI)", f"hard subset avoided (Cutoffs `{reference}` hits)"]
    rows = [[m.planner, format_rate(m.false_alarms), *intervention_cells(m),
             *(format_rate(m.interventions.get(str(lab), Rate(0, 0))) for lab in others),
             format_rate(m.intervention_recall), format_rate(m.hard_avoided)] for m in metrics]
    notes = [*intervention_notes(metrics, reference),
             f"'-' in a cell: nothing to measure there (no episode of that label or subset, no intervention for a "
             f"peak deceleration, or no same-seed `{reference}` episode for the time lost). `{reference}` is the "
             "reference: it never intervenes, and its time lost is 0 by definition."]
    return "\n".join([*markdown_table(header, rows), *(part for note in notes for part in ("", note))])


# ----------------------------------------------------------------- the experiment
def _confusion_part(cdf: list[RecordLike], fmt: TableFormat) -> list[str]:
    """The CDF's confusion matrix beside the paper's, and its Cutoff recall."""
    ours = confusion_matrix(cdf)
    sep = " \\| " if fmt == "markdown" else " / "
    rows = []
    for lab in LABELS:
        row, paper = ours[lab], PAPER_CONFUSION[lab]
        cells = [f"{o}{sep}{p}" for o, p in zip(row, paper, strict=True)]
        rows.append([str(lab), *cells, f"{sum(row)}{sep}{sum(paper)}"])
    title = (f"CDF predictions ({len(cdf)} episodes): ours | paper" if fmt == "markdown"
             else f"CDF predictions ({len(cdf)} episodes); each cell: ours / paper")
    header = ["scenario \\ prediction", *map(str, LABELS), "total"]
    return [title, "", _table(header, rows, fmt), "",
            f"Cutoff recall: {cutoff_recall(cdf)} (paper 100 %)", ""]


def _planners_markdown(metrics: Sequence[PlannerMetrics]) -> list[str]:
    """The Markdown tables of every planner, as docs/RESULTS.md shows them: collisions and
    hard brakes, then every intervention (:func:`intervention_table`)."""
    header = ["planner", "collisions imminent", "collisions occurred", "avoided (95 % CI)",
              "(imminent - occurred) / imminent", "paper: imminent / occurred / avoided",
              "hard-brake false alarms (95 % CI)", "median lead time [s]", "median min gap [m]",
              "mean time lost, no collision [s]"]
    rows = []
    for m in metrics:
        paper = "-"
        if m.planner in PAPER_PLANNERS:
            pi, po = PAPER_PLANNERS[m.planner]
            paper = f"{pi} / {po} / {_paper_share(pi, po)}"
        rows.append([m.planner, str(m.imminent), str(m.collisions), format_rate(m.avoided),
                     format_percent(m.paper_avoided), paper, format_rate(m.false_alarms),
                     format_number(m.lead_time), format_number(m.min_gap), format_number(m.time_lost)])
    return [_table(header, rows, "markdown"), "", "Every intervention:", "", intervention_table(metrics)]


def _planners_text(metrics: Sequence[PlannerMetrics]) -> list[str]:
    """Two narrower tables, collisions and braking, each with its definitions under it."""
    collisions = [[m.planner, str(m.imminent), str(m.collisions), format_rate(m.avoided),
                   format_percent(m.paper_avoided)] for m in metrics]
    collisions += [[f"paper: {name}", str(pi), str(po), "-", _paper_share(pi, po)]
                   for name, (pi, po) in PAPER_PLANNERS.items() if any(m.planner == name for m in metrics)]
    braking = [[m.planner, format_rate(m.false_alarms), format_number(m.lead_time), format_number(m.min_gap),
                format_number(m.time_lost)] for m in metrics]
    return [
        "Collisions with the obstacle",
        _table(["planner", "imminent", "occurred", "avoided (95 % CI)", "paper's formula"], collisions,
               "text", right=(1, 2, 4)),
        "imminent: episodes labelled Cutoff. occurred: any episode with a collision with the obstacle.",
        "avoided: Cutoff episodes without a collision with the obstacle / Cutoff episodes.",
        "paper's formula: (imminent - occurred) / imminent, so a collision in a Yield episode counts too.",
        "",
        "Braking",
        _table(["planner", "hard-brake false alarms (95 % CI)", "lead time [s]", "min gap [m]", "time lost [s]"],
               braking, "text", right=(2, 3, 4)),
        "hard-brake false alarms: episodes not labelled Cutoff in which it braked hard / all episodes.",
        "lead time: median of (obstacle enters the ego lane - brake) over braking Cutoff episodes.",
        "min gap: median smallest distance between the cars; time lost: at the end, vs the nominal speed,",
        "mean over the episodes without collision.",
        "",
        "Every intervention",
        intervention_table(metrics, "text"),
        "",
        "Definitions, and how the paper counts: docs/RESULTS.md.",
    ]


def experiment_tables(records: Iterable[RecordLike], fmt: TableFormat = "text") -> str:
    """The paper's two tables beside ours: the CDF's predictions against the scenario
    labels (if the records hold CDF episodes), and every planner's collisions (imminent,
    occurred, avoided, and the paper's formula), braking (hard-brake false alarms, lead
    time, gap, time lost) and every intervention (:func:`intervention_table`), with 95 %
    Wilson intervals.

    ``fmt="text"`` prints aligned columns that fit 100 characters, the planner comparison
    split in three tables with the definition of each figure under them; ``fmt="markdown"``
    gives the pipe tables of docs/RESULTS.md. Failed episodes are left out and counted in
    a last line.
    """
    _check_format(fmt)
    records = list(records)
    good = completed(records)
    metrics = list(planner_metrics(good).values())
    cdf = [r for r in good if record_field(r, "planner") == "cdf"]
    lines = _confusion_part(cdf, fmt) if cdf else []
    lines += _planners_markdown(metrics) if fmt == "markdown" else _planners_text(metrics)
    failed = len(records) - len(good)
    if failed:
        lines += ["", f"{failed} failed episode(s) left out of these tables "
                      "(their records hold the error and traceback)."]
    return "\n".join(lines)


# ----------------------------------------------------------------- analysis tables (Markdown)
def format_scenario_summary(summary: dict[str, Rate], planner: str) -> str:
    """Markdown: a :func:`~cdf_mj.analysis.metrics.scenario_summary` beside the paper's
    label shares and avoided rates (:data:`PAPER_CONFUSION`, :data:`PAPER_PLANNERS`)."""
    episodes = sum(sum(row) for row in PAPER_CONFUSION.values())
    paper_avoid = ", ".join(f"{_paper_share(*counts)} ({name})" for name, counts in PAPER_PLANNERS.items())
    rows = [[f"{lab} share", str(summary[lab]), f"{100 * sum(PAPER_CONFUSION[lab]) / episodes:.1f} %"]
            for lab in LABELS]
    rows.append([f"imminent collisions avoided ({planner})", str(summary["avoided"]), paper_avoid])
    return _table(["quantity", "ours (95 % CI)", "paper"], rows, "markdown")


def planner_table(records: Iterable[RecordLike]) -> str:
    """Markdown: every planner's avoided collisions, hard-brake false alarms, interventions
    (:data:`INTERVENTION_COLUMNS`), lead time, gap, time lost and, for the filters, the Brier
    scores of P(left) and P(seen) over all ticks; then :func:`intervention_notes`."""
    header = ["planner", "episodes", "imminent", "collisions", "avoided (95 % CI)",
              "hard-brake false alarms (95 % CI)", *INTERVENTION_COLUMNS, "median lead time [s]",
              "median min gap [m]", "mean time lost at the end, no collision [s]", "Brier P(left)", "Brier P(seen)"]
    metrics = list(planner_metrics(records).values())
    rows = [[m.planner, str(m.episodes), str(m.imminent), str(m.collisions), format_rate(m.avoided),
             format_rate(m.false_alarms), *intervention_cells(m), format_number(m.lead_time),
             format_number(m.min_gap), format_number(m.time_lost), format_number(m.brier_left, 3),
             format_number(m.brier_seen, 3)]
            for m in metrics]
    return "\n".join([_table(header, rows, "markdown"), "", *intervention_notes(metrics)])


def paired_table(records: Iterable[RecordLike], pairs: Sequence[tuple[str, str]]) -> str:
    """Markdown: two planners compared seed by seed (common random numbers), on the seeds
    both ran (:func:`~cdf_mj.analysis.metrics.paired_counts`): Cutoff episodes in which
    only the first or only the second collides with the obstacle, and episodes not
    labelled Cutoff in which only the first, only the second, or both brake hard (false
    alarms), and in which only the first or only the second intervenes."""
    records = list(records)
    header = ["pair", "collides only with the first", "only with the second",
              "hard-brake false alarm only with the first", "only with the second", "both",
              "intervenes, not Cutoff, only with the first", "only with the second"]
    rows = []
    for first, second in pairs:
        c = paired_counts(records, first, second)
        rows.append([f"{first} / {second}", *map(str, (c.collides_only_first, c.collides_only_second,
                                                       c.false_alarm_only_first, c.false_alarm_only_second,
                                                       c.false_alarm_both, c.intervene_only_first,
                                                       c.intervene_only_second))])
    return _table(header, rows, "markdown")


def _cells_at(times: np.ndarray, values: np.ndarray, at: Sequence[float]) -> list[str]:
    """Cells of ``values`` at the tick times ``at`` ("-" where no tick is there)."""
    cells = []
    for t in at:
        k = np.flatnonzero(np.isclose(times, t))
        cells.append(format_number(float(values[k[0]]), 3) if k.size else "-")
    return cells


def filter_table(records: Iterable[RecordLike], times: Sequence[float] = (0.5, 1.0, 1.5, 2.0),
                 p_left: float = 0.75) -> str:
    """Markdown: Brier scores of each filter's P(left) and P(seen), over all ticks and at
    the given tick ``times`` [s], beside two references: the prior ``p_left`` held
    constant, and the per-time base rate fitted on these episodes (in-sample)."""
    recs = completed(records)
    planners = list(dict.fromkeys(record_field(r, "planner") for r in recs))
    mine = {name: [r for r in recs if record_field(r, "planner") == name] for name in planners}
    header = ["planner", "quantity", "episodes", "ticks", "all ticks", *(f"t = {t:g} s" for t in times)]
    rows = []
    for name in planners:
        for q in FILTER_QUANTITIES:
            c = brier_over_time(mine[name], q)
            if c.episodes:
                rows.append([name, q, str(c.episodes), str(c.ticks), format_number(c.overall, 3),
                             *_cells_at(c.times, c.scores, times)])
    if planners:
        first = mine[planners[0]]
        prior = format_number(prior_brier(first, p_left), 3)
        rows.append([f"prior P(left) = {p_left:g}, held", "p_left", str(len(first)), "-", prior,
                     *(prior for _ in times)])
    for q in FILTER_QUANTITIES:
        for name in planners:  # the episodes and ticks of the first filter with this history
            c = brier_over_time(mine[name], q)
            if c.episodes:
                rows.append([f"base rate per time (in-sample, {name}'s ticks)", q, str(c.episodes), str(c.ticks),
                             format_number(c.reference_overall, 3), *_cells_at(c.times, c.reference, times)])
                break
    return _table(header, rows, "markdown")


def _stat(entry: dict[str, object], extreme: str | None = None, digits: int = 2) -> str:
    """A :func:`~cdf_mj.analysis.safety.safety_summary` entry: its median, ``[min]`` or
    ``[max]`` if asked, and in how many episodes it happened; ``-`` if in none."""
    if not entry["n"]:
        return "-"
    text = format_number(entry["median"], digits)  # type: ignore[arg-type]
    if extreme:
        text += f" [{format_number(entry[extreme], digits)}]"  # type: ignore[arg-type]
    return f"{text} ({entry['n']})"


def margin_table(records: Iterable[RecordLike], planners: Sequence[str]) -> list[str]:
    """Markdown lines: per planner, the safety margins over its Cutoff episodes (records
    that carry ``safety``, docs/SAFETY.md): how many needed no hard brake, the time to
    collision at the first hard brake (median [least]) and the share of those onsets
    below ``SafetyParams.ttc_critical``, the least TTC, headway and gap, the following
    ticks under the RSS distance, brake switches, peak deceleration and the comfort jerk.
    ``["No Cutoff episode: no margins."]`` when there is none."""
    critical = SafetyParams().ttc_critical
    done = completed(records)
    rows = []
    for name in planners:
        cutoffs = [r for r in done if record_field(r, "planner") == name and is_imminent(r)]
        if not cutoffs:
            continue
        s = safety_summary(cutoffs)
        rss = s["rss_ticks"]
        rss_text = "-" if not rss["n"] else (f"{100 * rss['value']:.1f} % of {rss['n']} ticks; "
                                             f"{s['rss_episodes']['k']}/{s['rss_episodes']['n']} episodes")
        no_brake = sum(1 for r in cutoffs if record_field(r, "brake_time") is None)
        rows.append([name, str(s["episodes"]), str(no_brake), _stat(s["ttc_at_brake"], "min"),
                     format_rate(Rate(s["late_brake"]["k"], s["late_brake"]["n"])), _stat(s["min_ttc"]),
                     _stat(s["min_headway"]), _stat(s["min_gap"]), rss_text, _stat(s["brake_switches"], digits=0),
                     _stat(s["peak_decel"], "max"), _stat(s["peak_jerk_comfort"], "max", digits=1)])
    if not rows:
        return ["No Cutoff episode: no margins."]
    return _table(["planner", "Cutoff episodes", "of them without a hard brake",
                   "TTC at the first hard brake [s], median [min] (n)",
                   f"onsets with TTC < {critical:g} s (95 % CI)", "minimum TTC [s], median (n)",
                   "minimum headway [s], median (n)", "minimum gap [m], median (n)",
                   "following ticks under the RSS distance", "brake switches, median (n)",
                   "peak deceleration [m/s²], median [max] (n)",
                   "peak jerk outside hard braking [m/s³], median [max] (n)"], rows, "markdown").split("\n")
