#!/usr/bin/env python3
"""docs/RESULTS.md: the paper's experiment in MuJoCo, remade from runs this script makes.

Runs (with :func:`~cdf_mj.experiments.experiment.run_experiment`, into ``OUT/PART``,
resumable: the same command continues an interrupted run, or only rewrites the page of a
finished one) and writes the page (default docs/RESULTS.md, stamped with this command and
the package version, :mod:`cdf_mj.analysis.pages`):

- ``development``: the default scenario on seeds 0-999 (the reproduction of the paper's
  experiment; the scenario was calibrated on these seeds);
- ``held-out``: the same on seeds 100000-100999, never used to choose anything.

Both run ``cdf`` (the CDF with the layered rule, the package's default: docs/DECISION.md),
``cdf-threshold`` (the CDF with the paper's rule) and ``reactive`` (the paper's baseline) on
the same seeds, and ``constant`` (the ego's own controller alone), the reference of the time
lost at the fixed point and of the hard subset, which the paper's tables leave out. A
*brake* is a hard brake (``LayeredConfig.hard_brake`` or more of deceleration for ``cdf``;
the full brake for the others): the hard-brake false alarms and lead times count those only;
every intervention, hard or not, is counted in a table of its own
(:func:`cdf_mj.analysis.pareto.intervention_lines`). The page has the paper's two tables
beside ours (the CDF's predictions against the labels; collisions, avoidance by our count
and by the paper's formula, hard-brake false alarms, lead time, gap, time lost; 95 % Wilson
intervals), every figure the paper reports set against our interval
(matched: the paper's figure inside it), where the differences come from (counted from
the records), and the figures of ``cdf-mj report`` for the development part (into
``--figures``, default docs/img/report; needs matplotlib). Every number on the page comes
from the records of these runs. ::

    python scripts/results.py                  # both parts and the figures
    python scripts/results.py --parts held-out --episodes 20 --out /tmp/r --doc /tmp/R.md --figures ''

Run time on 2 cores (2 workers), measured with cdf_mj 0.1.0 (episodes of 5-8 s): 100 seeds
of one part in 10 s, so about 1.5 minutes per part and 3-4 minutes for the page with its
figures; longer episodes cost in proportion. ``--episodes N`` runs N seeds per part,
``--parts`` some parts only.

Bad input (an unknown part, a result directory of other settings, figures without
matplotlib) is one line ``results: error: ...`` and exit status 2, before anything runs.
Exit status 1 if some episodes failed (their records hold the error; the page counts them).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from cdf_mj.analysis.metrics import PlannerMetrics, Rate, confusion_matrix, cutoff_recall, of_planner, planner_metrics
from cdf_mj.analysis.pages import ScriptParser, command_line, exit_status, fail, markdown_table, write_page
from cdf_mj.analysis.pareto import intervention_lines, planner_line
from cdf_mj.analysis.tables import PAPER_CONFUSION, PAPER_PLANNERS, format_number, format_percent, format_rate
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment
from cdf_mj.extras import install_hint
from cdf_mj.records import LABELS, completed, hit_obstacle, is_false_alarm, is_imminent, lead_time, record_field

PROG = "results"
SCRIPT = "scripts/results.py"
REFERENCE = "constant"  # the reference of the time lost at the fixed point and of the hard subset
PLANNERS = ("cdf", "cdf-threshold", "reactive", REFERENCE)
COMPARED = PLANNERS[:3]  # the planners of the paper's tables
CDF_PLANNERS = ("cdf", "cdf-threshold")
PAPER_EPISODES = sum(sum(row) for row in PAPER_CONFUSION.values())  # 1000


@dataclass(frozen=True)
class Part:
    """One run: the default scenario on a range of seeds."""

    name: str
    title: str
    seeds: range


def parts(episodes: int | None) -> dict[str, Part]:
    """The parts, with ``episodes`` seeds each (default 1000)."""
    n = episodes or 1000
    return {"development": Part("development", "development seeds", range(0, n)),
            "held-out": Part("held-out", "held-out seeds", range(100000, 100000 + n))}


def _span(part: Part) -> str:
    return f"{part.seeds.start}–{part.seeds.stop - 1}"


# ----------------------------------------------------------------- the paper's tables beside ours
def confusion_lines(records: Sequence[dict[str, Any]], planner: str) -> list[str]:
    """The planner's predictions against the labels, each cell ``ours | paper``, and its recall."""
    ours = confusion_matrix(records)
    rows = []
    for lab in LABELS:
        mine, paper = ours[str(lab)], PAPER_CONFUSION[lab]
        rows.append([str(lab), *(f"{o} \\| {p}" for o, p in zip(mine, paper, strict=True)),
                     f"{sum(mine)} \\| {sum(paper)}"])
    return [*markdown_table(["scenario \\ prediction", *map(str, LABELS), "total"], rows), "",
            f"Cutoff recall: {format_rate(cutoff_recall(records))} (paper 100 %).", ""]


def planner_lines(metrics: dict[str, PlannerMetrics]) -> list[str]:
    """The compared planners' collisions and braking, the paper's counts beside them."""
    header = ["planner", "collisions imminent", "collisions occurred", "avoided (95 % CI)",
              "(imminent - occurred) / imminent", "paper: imminent / occurred / formula",
              "hard-brake false alarms (95 % CI)", "hard-brake false alarms / Yield episodes",
              "collisions in Yield, Right", "median lead time [s]", "median min gap [m]",
              "mean time lost at the end, no collision [s]"]
    rows = []
    for m in (m for name, m in metrics.items() if name in COMPARED):
        paper_name = "cdf" if m.planner in CDF_PLANNERS else m.planner
        paper = "-"
        if paper_name in PAPER_PLANNERS:
            pi, po = PAPER_PLANNERS[paper_name]
            paper = f"{pi} / {po} / {format_percent((pi - po) / pi, 0)}"
        rows.append([m.planner, str(m.imminent), str(m.collisions), format_rate(m.avoided),
                     format_percent(m.paper_avoided), paper, format_rate(m.false_alarms),
                     format_rate(m.false_alarms_yield),
                     f"{m.collisions_yield}, {m.collisions_right}", format_number(m.lead_time),
                     format_number(m.min_gap), format_number(m.time_lost)])
    return markdown_table(header, rows)


def part_section(part: Part, records: Sequence[dict[str, Any]], failed: int, out: Path) -> list[str]:
    """Markdown of one part: labels, the CDF's predictions beside the paper's, the planners."""
    good = completed(records)
    first = of_planner(good, PLANNERS[0])
    labels = {lab: sum(1 for r in first if record_field(r, "label") == lab) for lab in LABELS}
    held = "never used to choose anything" if part.name == "held-out" else "the reproduction of the paper's run"
    lines = [f"## Seeds {_span(part)} ({part.title}: {held})", "",
             f"Records: `{out / part.name}/episodes.jsonl` ({len(good)} completed episodes"
             + (f"; {failed} failed, left out" if failed else "") + "). Labels: "
             + ", ".join(f"{lab} {labels[lab]}" for lab in LABELS)
             + f" of {len(first)} (paper: "
             + ", ".join(f"{lab} {sum(PAPER_CONFUSION[lab])}" for lab in LABELS) + f" of {PAPER_EPISODES}).", ""]
    if not good:
        return [*lines, "No completed episode.", ""]
    for planner in CDF_PLANNERS:
        mine = of_planner(good, planner)
        if mine:
            rule = "the layered rule" if planner == "cdf" else "the paper's rule"
            lines += [f"`{planner}` ({rule}): predictions, ours \\| paper", "", *confusion_lines(mine, planner)]
    metrics = planner_metrics(good, reference=REFERENCE)
    lines += ["Planners:", "", *planner_lines(metrics), "",
              f"Every intervention, `{REFERENCE}` the reference (per label; the time lost at the fixed point; the "
              "hard subset):", "", *intervention_lines(metrics, REFERENCE), ""]
    return lines


# ----------------------------------------------------------------- beside the paper
@dataclass(frozen=True)
class Figure:
    """One figure the paper reports and ours on each part."""

    quantity: str
    paper_k: int
    paper_n: int
    ours: dict[str, Rate]  # part name -> our rate

    @property
    def paper(self) -> float:
        return self.paper_k / self.paper_n

    def inside(self, part: str) -> bool:
        lo, hi = self.ours[part].interval
        return lo <= self.paper <= hi

    def matched(self) -> bool:
        return all(self.inside(p) for p in self.ours)


def _paper_formula(m: PlannerMetrics) -> Rate:
    """The paper's (imminent - occurred) / imminent as a rate (0 if more collided than were imminent)."""
    return Rate(max(0, m.imminent - m.collisions), m.imminent)


def paper_figures(by_part: dict[str, list[dict[str, Any]]]) -> list[Figure]:
    """Every figure of the paper's two tables that our records measure, per part."""
    figures: list[Figure] = []

    def add(quantity: str, paper: tuple[int, int], ours: dict[str, Rate | None]) -> None:
        kept = {p: r for p, r in ours.items() if r is not None and r.n}
        if kept:
            figures.append(Figure(quantity, paper[0], paper[1], kept))

    metrics = {p: planner_metrics(recs) for p, recs in by_part.items()}
    for lab in LABELS:
        shares = {}
        for p, recs in by_part.items():
            first = of_planner(recs, PLANNERS[0])
            shares[p] = Rate(sum(1 for r in first if record_field(r, "label") == lab), len(first))
        add(f"{lab} share of episodes", (sum(PAPER_CONFUSION[lab]), PAPER_EPISODES), dict(shares))
    cut, yld, right = LABELS
    for planner in CDF_PLANNERS:
        conf = {p: confusion_matrix(of_planner(recs, planner)) for p, recs in by_part.items()}

        def cell(row: str, col: int, c: dict[str, tuple[int, int, int]]) -> Rate:
            return Rate(c[row][col], sum(c[row]))

        paper = {str(lab): PAPER_CONFUSION[lab] for lab in LABELS}
        add(f"`{planner}`: Cutoff episodes predicted Cutoff (recall)", (paper[cut][0], sum(paper[cut])),
            {p: cell(cut, 0, c) for p, c in conf.items()})
        add(f"`{planner}`: Yield episodes predicted Cutoff", (paper[yld][0], sum(paper[yld])),
            {p: cell(yld, 0, c) for p, c in conf.items()})
        add(f"`{planner}`: Right episodes predicted Right", (paper[right][2], sum(paper[right])),
            {p: cell(right, 2, c) for p, c in conf.items()})
        add(f"`{planner}`: hard-brake false alarms, of all episodes", (paper[yld][0], PAPER_EPISODES),
            {p: m[planner].false_alarms if planner in m else None for p, m in metrics.items()})
    for planner in (*CDF_PLANNERS, "reactive"):
        pi, po = PAPER_PLANNERS["cdf" if planner in CDF_PLANNERS else planner]
        add(f"`{planner}`: avoided, the paper's formula", (pi - po, pi),
            {p: _paper_formula(m[planner]) if planner in m else None for p, m in metrics.items()})
    return figures


def _ours(fig: Figure, names: dict[str, str]) -> str:
    return "; ".join(f"{names[p]} {format_rate(r)}" for p, r in fig.ours.items())


def beside_paper_lines(figures: list[Figure], names: dict[str, str]) -> list[str]:
    """The comparison table and the lists of what matched and what did not."""
    parts_shown = list(dict.fromkeys(p for f in figures for p in f.ours))
    header = ["figure", "paper", *(f"ours, {names[p]} (95 % CI)" for p in parts_shown), "paper inside our interval"]
    rows = []
    for f in figures:
        cells = [format_rate(f.ours[p]) if p in f.ours else "-" for p in parts_shown]
        inside = ", ".join(("yes" if f.inside(p) else "**no**") for p in f.ours)
        rows.append([f.quantity, f"{format_percent(f.paper)} ({f.paper_k}/{f.paper_n})", *cells, inside])
    lines = [*markdown_table(header, rows), ""]
    matched = [f for f in figures if f.matched()]
    missed = [f for f in figures if not f.matched()]
    lines += ["### What matched the paper", "",
              "The paper's figure lies inside our 95 % interval on every seed range:", ""]
    lines += [f"- {f.quantity}: paper {format_percent(f.paper)}; ours {_ours(f, names)}." for f in matched] or [
        "- none."]
    lines += ["", "### What did not match", "", "The paper's figure lies outside our 95 % interval on at least one "
              "seed range:", ""]
    for f in missed:
        sides = sorted({"above" if f.ours[p].value > f.paper else "below" for p in f.ours if not f.inside(p)})
        lines.append(f"- {f.quantity}: paper {format_percent(f.paper)}; ours {_ours(f, names)} ({' and '.join(sides)} "
                     "the paper's).")
    if not missed:
        lines.append("- none.")
    return [*lines, ""]


# ----------------------------------------------------------------- where the differences come from
def _range(values: Sequence[float], unit: str = "s") -> str:
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.2f} {unit}"
    return f"median {statistics.median(values):.2f} {unit} ({min(values):.2f}–{max(values):.2f})"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _brakes(r: dict[str, Any]) -> list[list[float | None]]:
    info = record_field(r, "planner_info") or {}
    return info.get("brakes") or ([[record_field(r, "brake_time"), None]] if record_field(r, "brake_time") is not None
                                  else [])


def cause_lines(records: Sequence[dict[str, Any]], planner: str, part_name: str) -> list[str]:
    """Where ``planner``'s false alarms and collisions come from, counted from its records."""
    mine = of_planner(records, planner)
    lines: list[str] = []
    alarms = [r for r in mine if is_false_alarm(r)]
    if alarms:
        brake = [float(record_field(r, "brake_time")) for r in alarms]
        seen = [r for r in alarms if record_field(r, "first_seen_time") is not None]
        after = sum(1 for r in seen if record_field(r, "first_seen_time") >= record_field(r, "brake_time"))
        released = sum(1 for r in alarms if (b := _brakes(r)) and b[-1][1] is not None)
        calm = [float(record_field(r, "time_lost")) for r in mine
                if record_field(r, "brake_time") is None and not hit_obstacle(r)]
        lost = [float(record_field(r, "time_lost")) for r in alarms if not hit_obstacle(r)]
        lines.append(
            f"- `{planner}`, {part_name}: {_count(len(alarms), 'false alarm')}. It first braked hard at "
            f"{_range(brake)}; the obstacle first saw the ego at "
            f"{_range([float(record_field(r, 'first_seen_time')) for r in seen])} in {len(seen)} of them "
            f"({after} at or after the brake), never in {len(alarms) - len(seen)}. Released by the end: "
            f"{released}. Mean time lost in them {format_number(statistics.fmean(lost) if lost else None)} s, "
            f"against {format_number(statistics.fmean(calm) if calm else None)} s in episodes without a hard "
            "brake or a collision.")
    others = [r for r in mine if hit_obstacle(r) and not is_imminent(r)]
    if others:
        delays = [float(record_field(r, "collision_time")) - float(record_field(r, "brake_time")) for r in others
                  if record_field(r, "brake_time") is not None and record_field(r, "collision_time") is not None]
        unbraked = sum(1 for r in others if record_field(r, "brake_time") is None)
        seeds = ", ".join(f"{record_field(r, 'seed')} ({record_field(r, 'label')})" for r in others[:12])
        more = f" and {len(others) - 12} more" if len(others) > 12 else ""
        lines.append(
            f"- `{planner}`, {part_name}: {_count(len(others), 'collision')} in episodes not labelled Cutoff "
            f"(seeds {seeds}"
            f"{more}); {len(others) - unbraked} after a hard brake, from its first hard brake to contact "
            f"{_range(delays)}; "
            f"{unbraked} without one.")
    cut_hits = [r for r in mine if hit_obstacle(r) and is_imminent(r)]
    if cut_hits:
        leads = [t for t in map(lead_time, cut_hits) if t is not None]
        unbraked = sum(1 for r in cut_hits if record_field(r, "brake_time") is None)
        starts = [float(record_field(r, "ego_start_offset")) for r in cut_hits]
        lines.append(
            f"- `{planner}`, {part_name}: {_count(len(cut_hits), 'collision')} in Cutoff episodes: {unbraked} without "
            f"a hard brake, {len(cut_hits) - unbraked} braked too late (lead time {_range(leads)}); ego start offsets "
            f"{_range(starts, 'm')}.")
    return lines


def causes_section(by_part: dict[str, list[dict[str, Any]]], names: dict[str, str]) -> list[str]:
    lines = ["## Where the differences come from", "",
             "Counted from the same records. A *false alarm* is a hard brake in an episode not labelled Cutoff "
             f"(for `cdf`, a command of {CDFConfig().layered.hard_brake:g} m/s² or more of deceleration: its gentle "
             "slowing is not one); \"first saw\" is the obstacle driver's first observation of the ego "
             "(`first_seen_time`), after which it may yield; the paper's rule holds its brake, the layered rule "
             "releases it.", ""]
    body = [line for planner in COMPARED for p, recs in by_part.items()
            for line in cause_lines(recs, planner, names[p])]
    return [*lines, *(body or ["Nothing to explain: no false alarm and no collision."]), ""]


# ----------------------------------------------------------------- figures
def figure_lines(run_dir: Path, records: Sequence[dict[str, Any]], figures_dir: Path, doc: Path,
                 span: str) -> list[str]:
    """Draw ``cdf-mj report``'s figures of one part into ``figures_dir``; their Markdown."""
    from cdf_mj.viz.report import FIGURES, write_report

    cdf = sorted(of_planner(completed(records), "cdf"), key=lambda r: record_field(r, "seed"))
    seeds = []
    for lab in LABELS:  # the first seed of each label, a Cutoff the CDF braked hard in first
        cand = [r for r in cdf if record_field(r, "label") == lab]
        cand.sort(key=lambda r: (record_field(r, "brake_time") is None) == (lab == LABELS[0]))
        if cand:
            seeds.append(int(record_field(cand[0], "seed")))
    result = write_report(run_dir, figures_dir, seeds=seeds or None, planner="cdf" if cdf else None)
    lines = [f"## Figures (seeds {span})", "",
             f"Drawn by `cdf_mj.viz.report.write_report` (what `cdf-mj report {run_dir}` draws) from the records "
             f"of seeds {span}; the trajectories and posterior traces are of `cdf` on seeds "
             + ", ".join(f"{s} ({record_field(next(r for r in cdf if record_field(r, 'seed') == s), 'label')})"
                         for s in seeds) + f". `{REFERENCE}` is in the bar charts as the reference (the ego's ACC "
             "alone).", ""]
    for name, caption in FIGURES.items():
        if name in result.figures:
            rel = Path(os.path.relpath(result.figures[name], doc.parent)).as_posix()
            lines += [f"![{caption}]({rel})", "", f"*{name}*: {caption}.", ""]
        else:
            lines += [f"*{name}*: not drawn ({result.omitted.get(name, 'no data')}).", ""]
    return lines


# ----------------------------------------------------------------- the page
def markdown(sections: list[list[str]], beside: list[str], causes: list[str], figures: list[str],
             small: bool, out: Path) -> str:
    """The whole page (without its stamp)."""
    scenario, cdf = ScenarioConfig(), CDFConfig()
    lay = cdf.layered
    timing = ", ".join(f"{k} = {v}" for k, v in scenario.to_dict().get("timing", {}).items())
    lines = [
        "# Results: the paper's experiment in MuJoCo",
        "",
        *(["**Few seeds or some parts only: a check that the script runs, not a result.**", ""] if small else []),
        "The planners run on the same seeds (common random numbers: the same obstacle intent, observation",
        "draws, noise and ego start for each seed):",
        "",
        f"- `cdf`: {planner_line('cdf')}, the package's default, with {cdf.n_particles} particles: a graded "
        "command each tick, which slows the ego or brakes hard. Its *brake* is a command of "
        f"{lay.hard_brake:g} m/s² or more of deceleration;",
        f"- `cdf-threshold`: the same filter with the paper's rule: brake once P(cutoff) >= τ = {cdf.tau:g}, "
        "held to the end;",
        "- `reactive`: the paper's baseline, brakes once any part of the obstacle is inside the ego's lane;",
        f"- `{REFERENCE}`: {planner_line(REFERENCE)} The reference of the time lost at the fixed point and of the "
        "hard subset; the paper's tables leave it out.",
        "",
        "Labels come from a counterfactual run of each seed with the ego holding its speed (README, \"The",
        "scenario\"): Cutoff (it would hit the obstacle), Yield (a left-turner that does not cut it off),",
        "Right. The paper's tables are of its CDF, whose rule is that of `cdf-threshold`; its figures stand",
        "beside both CDF rows. A CDF predicts Cutoff if it braked (hard), or, for `cdf`, if it was slowing the",
        "ego when the obstacle entered the ego's lane; otherwise Yield or Right by its last P(left). Every rate",
        "has its 95 % Wilson interval.",
        "",
        f"Scenario: `ScenarioConfig()` (timing: {timing}); the CDF: `CDFConfig()`. The scenario was calibrated "
        "on seeds 0–999 for its label shares and the reactive baseline only ([PARAMETERS.md](PARAMETERS.md)); "
        "the CDF's parameters, the risk rule's threshold (the layered rule's emergency layer uses it) and the "
        "layered rule's thresholds were chosen on seeds 0–199 ([DECISION.md](DECISION.md) names the scripts); "
        "seeds 100000–100999 were never used to choose anything.",
        "",
        f"Each part is one `run_experiment` call into `{out}/<part>` (the records of `cdf-mj experiment "
        f"--planner {','.join(PLANNERS)}` on the same seeds). `cdf-mj experiment` prints the same "
        "tables (`cdf_mj.analysis.tables.experiment_tables`).",
        "",
    ]
    for sec in sections:
        lines += sec
    lines += [
        "Columns:",
        "",
        "- *collisions imminent*: episodes labelled Cutoff.",
        "- *collisions occurred*: episodes in which the ego touched the obstacle, whatever the label.",
        "- *avoided*: our figure: Cutoff episodes without such a contact, of all Cutoff episodes.",
        "- *(imminent − occurred) / imminent*: the paper's formula, beside ours for comparison with the paper:",
        "  since *occurred* counts every label, it also charges the collisions in episodes labelled Yield",
        "  (after a false alarm, for example), so it is at most our *avoided*.",
        "- *hard-brake false alarms*: episodes not labelled Cutoff in which the planner braked hard, of all",
        f"  episodes (and of the Yield episodes): for `cdf` a command of {lay.hard_brake:g} m/s² or more of",
        "  deceleration (its gentle slowing is not a brake, but an intervention: the next table counts those),",
        "  for the others their full brake.",
        "- *lead time*: from the first hard brake to the obstacle entering the ego lane, median over the Cutoff",
        "  episodes in which the planner braked hard (negative: braked after the entry).",
        "- *min gap*: the smallest distance between the two cars' hulls, median over all episodes.",
        "- *time lost at the end*: the ego's progress deficit at the end over its nominal speed, mean over",
        "  episodes without a collision (it charges following a slower car; the time lost at the fixed point",
        f"  against `{REFERENCE}` does not).",
        "- '-': nothing to measure (no hard brake for a lead time, no episode of that kind).",
        "",
        "Each is counted by one rule of `cdf_mj.records` (`is_imminent`, `hit_obstacle`, `avoided`,",
        "`is_false_alarm`, `lead_time`, `paper_avoided`) through `cdf_mj.analysis.metrics.planner_metrics`,",
        "the same in these tables, the figures of `cdf-mj report` and the sweeps.",
        "",
    ]
    if beside:
        lines += ["## Beside the paper", "", *beside]
    lines += causes + figures
    return "\n".join(lines).rstrip() + "\n"


def _fail(message: str) -> NoReturn:
    fail(PROG, message)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the parts and write the page; returns the exit status (1 if some episodes failed)."""
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default=None, help="comma-separated parts (default: development,held-out)")
    p.add_argument("--episodes", type=int, default=None, help="seeds per part (default 1000)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: the CPU count)")
    p.add_argument("--out", default="results/results", help="result directory (default results/results)")
    p.add_argument("--doc", default="docs/RESULTS.md", help="Markdown page written (default docs/RESULTS.md)")
    p.add_argument("--figures", default="docs/img/report",
                   help="where the figures go (default docs/img/report; '' for none)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    args = p.parse_args(argv)
    if (args.episodes is not None and args.episodes < 1) or (args.workers is not None and args.workers < 1):
        _fail("--episodes and --workers must be at least 1")
    all_parts = parts(args.episodes)
    names = [n.strip() for n in args.parts.split(",") if n.strip()] if args.parts is not None else list(all_parts)
    unknown = [n for n in names if n not in all_parts]
    if unknown or not names or len(set(names)) != len(names):
        _fail(f"unknown or repeated part(s) {', '.join(unknown) or ', '.join(names) or '(none)'}: choose from "
              f"{', '.join(all_parts)}")
    if args.figures and importlib.util.find_spec("matplotlib") is None:
        _fail(f"the figures need matplotlib ({install_hint('viz')}), or --figures '' for none")
    out, doc = Path(args.out), Path(args.doc)
    by_part: dict[str, list[dict[str, Any]]] = {}
    sections, failed = [], 0
    for i, name in enumerate(names, start=1):
        part = all_parts[name]
        if not args.quiet:
            print(f"[{i}/{len(names)}] {name}: seeds {_span(part)}, {','.join(PLANNERS)}", file=sys.stderr)
        try:
            run = run_experiment(out / name, part.seeds, PLANNERS, ScenarioConfig(), CDFConfig(),
                                 progress=not args.quiet, workers=args.workers, resume=True)
        except SettingsMismatchError as exc:
            _fail(f"{exc} with --out, or remove {out / name}")
        except ValueError as exc:
            _fail(str(exc))
        failed += run.failed
        by_part[name] = completed(run.records)
        sections.append(part_section(part, run.records, run.failed, out))
    labels = {n: f"seeds {_span(all_parts[n])}" for n in names}
    beside = beside_paper_lines(paper_figures(by_part), labels)
    causes = causes_section(by_part, labels)
    figures: list[str] = []
    if args.figures:
        shown = "development" if "development" in by_part else names[0]
        figures = figure_lines(out / shown, by_part[shown], Path(args.figures), doc, _span(all_parts[shown]))
    command = command_line(SCRIPT, [("--parts", args.parts), ("--episodes", args.episodes)])
    small = args.parts is not None or args.episodes is not None
    write_page(doc, markdown(sections, beside, causes, figures, small, out), command)
    if not args.quiet:
        print(f"wrote {doc}; records in {out}/<part>/episodes.jsonl", file=sys.stderr)
    return exit_status(PROG, failed)


if __name__ == "__main__":
    sys.exit(main())
