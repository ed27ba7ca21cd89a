#!/usr/bin/env python3
"""The decision rules compared, every action counted: the default ``cdf`` (version 0.3's
anticipation, which slows on the prior, kept by the declared tuning objective) and
``cdf-option`` (the option rule, which waits for the belief), each other predictor with the
layered rule, the earlier rules, the naive-caution baselines and the reactive baseline, on
held-out seeds first, then on the scenario presets, then on the development seeds.

Runs (resumable, with :func:`~cdf_mj.experiments.experiment.run_experiment`, into
``OUT/PART``) and writes a Markdown page (default docs/DECISION_RESULTS.md):

- ``held-out``: the default scenario on seeds 400000-400999, a range no page used before
  (first used here: 100000+ had been looked at too often);
- one part per preset on seeds 401000-401199 (held out as well, first used here; ``stop-and-wait``, judged
  against the issue's targets, with every naive baseline and other predictor);
- ``development``: the default scenario on seeds 0-199, where the thresholds were chosen
  (scripts/tune_option.py and the earlier tuning scripts), labelled as such.

Every part runs ``constant`` on the same seeds: it is the reference of the time lost at the
fixed point and its collisions define the hard subset (the Cutoffs the ACC alone does not
avoid). For every planner: Cutoff recall, avoided (ours and the paper's formula), hard-brake
false alarms, collisions in Yield and Right episodes; every intervention per label (the share
of Yield and Right episodes with one beside the recall in Cutoff episodes), the time lost at
the fixed point, the peak deceleration and the hard subset
(:func:`cdf_mj.analysis.pareto.intervention_lines`); the safety margins over the Cutoff
episodes (:func:`cdf_mj.analysis.tables.margin_table`); ``cdf`` and ``cdf-option`` each
against every other planner (``cdf-option`` against ``cdf`` too: what the option rule buys
over the default and what it costs), seed by seed on collisions, non-Cutoff interventions,
hard brakes and time lost (exact McNemar and sign tests) with a Pareto verdict per pair
(:func:`cdf_mj.analysis.pareto.compare`); the issue's targets for both; and a Pareto figure
of the held-out part (:mod:`cdf_mj.viz.pareto`), with the CDF at each tuning point as a grey
dot (``option 0.5 s, 0.9``, ``go 0.1``) if ``--tuning`` names the tuning results::

    python scripts/decision.py --tuning results/tune_option        # all parts, the figure
    python scripts/decision.py --parts held-out --episodes 20 --out /tmp/d --doc /tmp/d.md

The figure goes to ``--figure`` (default ``img/decision/pareto.png`` beside the page: for the
default page docs/img/decision/pareto.png; '' for none; needs matplotlib). Bad input (an
unknown part or planner, a result directory of other settings, a tuning directory without
runs, ``--figure`` without matplotlib) is one line ``decision: error: ...`` and exit status 2,
before anything runs.
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

from cdf_mj.analysis.metrics import PlannerMetrics, planner_metrics
from cdf_mj.analysis.pages import ScriptParser, command_line, exit_status, fail, markdown_table, verdict, write_page
from cdf_mj.analysis.pareto import (
    DECIDERS,
    RULES_NOTE,
    compare,
    comparisons,
    cost_targets,
    intervention_lines,
    layered_label,
    pareto_lines,
    pareto_points,
    planner_item,
    tuning_points,
)
from cdf_mj.analysis.safety import safety_summary
from cdf_mj.analysis.tables import format_number, format_percent, format_rate, margin_table
from cdf_mj.config import CDFConfig, LayeredConfig, ScenarioConfig
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment
from cdf_mj.extras import install_hint
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.presets import load_preset, scenario_preset_names
from cdf_mj.records import completed, is_false_alarm, record_field

PROG = "decision"
REFERENCE = "constant"  # the reference of the time lost and of the hard subset, in every part
TODAY = "cdf"  # today's rule: the package's default, the reference of the post-encroachment target
#: The planners neither ``cdf`` nor ``cdf-option`` may be dominated by (issue 35): the naive
#: baselines and the other predictors with the layered rule.
CHALLENGERS = ("caution-waiting", "caution-moving", "caution-phantom", "imm-layered", "cv-layered")
PLANNERS_DEFAULT = ("cdf", "cdf-option", "cdf-risk", "cdf-threshold", "imm-layered", "cv-layered", "caution-waiting",
                    "caution-moving", "caution-phantom", "reactive", REFERENCE)
PRESET_PLANNERS = ("cdf", "cdf-option", "imm-layered", "caution-moving", "reactive", REFERENCE)
#: The parts judged against the issue's targets (the default world and stop-and-wait); their
#: planners include every challenger.
TARGET_PARTS = ("held-out", "development", "stop-and-wait")
TARGET_PLANNERS = ("cdf", "cdf-option", *CHALLENGERS, "reactive", REFERENCE)
HELD_OUT = 400000  # first seed of the held-out part; no page used this range before
PRESET_SEED0 = 401000  # first seed of each preset part; no page used this range before either
FIGURE = Path("img") / "decision" / "pareto.png"  # beside the page


@dataclass(frozen=True)
class Part:
    """One evaluation: a scenario on a range of seeds."""

    name: str
    title: str
    config: ScenarioConfig
    seeds: range
    planners: tuple[str, ...]
    held_out: bool


def _parts(episodes: int | None) -> dict[str, Part]:
    n_main, n_preset, n_dev = (episodes or 1000), (episodes or 200), (episodes or 200)
    parts = {"held-out": Part("held-out", "Default scenario, held-out seeds (first used here)", ScenarioConfig(),
                              range(HELD_OUT, HELD_OUT + n_main), PLANNERS_DEFAULT, True)}
    for name in scenario_preset_names():
        if name == "default":
            continue
        parts[name] = Part(name, f"Preset `{name}`, held-out seeds", load_preset(name),
                           range(PRESET_SEED0, PRESET_SEED0 + n_preset),
                           TARGET_PLANNERS if name in TARGET_PARTS else PRESET_PLANNERS, True)
    parts["development"] = Part("development", "Default scenario, development seeds (the thresholds were "
                                "chosen here)", ScenarioConfig(), range(0, n_dev), PLANNERS_DEFAULT, False)
    return parts


def planner_rows(metrics: dict[str, PlannerMetrics]) -> list[str]:
    """Markdown: one row per planner with the collision and hard-brake counts of the page."""
    header = ["planner", "Cutoff recall", "avoided (95 % CI)", "paper's formula",
              "hard-brake false alarms / episodes", "hard-brake false alarms / Yield episodes",
              "false discovery (of hard-braked)", "collisions Yield, Right", "time lost at the end [s]"]
    rows = [[m.planner, format_rate(m.recall), format_rate(m.avoided),
             f"{format_percent(m.paper_avoided)} ({m.imminent - m.collisions}/{m.imminent})" if m.imminent else "-",
             format_rate(m.false_alarms), format_rate(m.false_alarms_yield), format_rate(m.false_discovery),
             f"{m.collisions_yield}, {m.collisions_right}", format_number(m.time_lost)]
            for m in metrics.values()]
    return markdown_table(header, rows)


def _cutoff_safety(records: Sequence[dict[str, Any]], planner: str) -> dict[str, Any]:
    """:func:`safety_summary` of ``planner``'s Cutoff episodes, with the count of those it
    avoided without a hard brake (``no_brake``)."""
    cut = [r for r in records if record_field(r, "planner") == planner and record_field(r, "label") == "Cutoff"]
    return {**safety_summary(cut), "no_brake": sum(1 for r in cut if record_field(r, "brake_time") is None),
            "n": len(cut)}


def _labelled(name: str) -> str:
    """``name`` with its layered rule's anticipation, if it has one: ``imm-layered (option 0.5 s, 0.9)``."""
    label = layered_label(name)
    return f"{name} ({label})" if label else name


def issue_targets(records: Sequence[dict[str, Any]], metrics: dict[str, PlannerMetrics], planner: str) -> list[str]:
    """Issue 35's targets for ``planner``: what its actions cost, its margins over the Cutoffs
    (post-encroachment time beside today's rule, ``cdf``'s), and no challenger dominating it;
    each line with its figure and met or missed."""
    m = metrics[planner]
    s = _cutoff_safety(records, planner)
    ttc = s["min_ttc"]
    lines = [f"Issue 35's targets for `{planner}` (point estimates):", "", *cost_targets(m, REFERENCE),
             f"- least time to collision over the Cutoffs, median >= 1.3 s: "
             f"{format_number(ttc['median']) if ttc['n'] else '-'} s ({ttc['n']} episodes): "
             f"{verdict(ttc['median'] >= 1.3) if ttc['n'] else 'not measured'}"]
    pet = s["pet"]
    target = f"- post-encroachment time over the Cutoffs no worse than today's rule (`{TODAY}`): "
    if planner == TODAY:
        lines.append(target + (f"median {format_number(pet['median'])} s ({pet['n']} episodes): met (it is today's "
                               "rule)" if pet["n"] else "not measured"))
    elif TODAY in metrics:
        old = _cutoff_safety(records, TODAY)["pet"]
        measured = bool(pet["n"] and old["n"])
        shown = (f"median {format_number(pet['median'])} s vs `{TODAY}`'s {format_number(old['median'])} s"
                 if measured else "-")
        lines.append(target + f"{shown}: " + (verdict(pet["median"] >= old["median"] - 1e-9) if measured
                                              else "not measured"))
    judged = [compare(records, planner, other, REFERENCE) for other in CHALLENGERS if other in metrics]
    if judged:
        over = [v.second for v in judged if v.dominant == v.second]
        own = layered_label(planner)
        of = ", ".join(_labelled(v.second) for v in judged) + (f"; `{planner}` runs {own}" if own else "")
        found = f"dominated by {', '.join(over)}" if over else "none does"
        lines.append(f"- no naive baseline and no other predictor with the layered rule dominates `{planner}` (of "
                     f"{of}): {found}: {verdict(not over)}")
    return [*lines, ""]


def earlier_targets(records: Sequence[dict[str, Any]], metrics: dict[str, PlannerMetrics], planner: str) -> list[str]:
    """The earlier issues' targets for ``planner`` on the default scenario, judged on the point estimates."""
    cdf = metrics[planner]
    mine = [r for r in records if record_field(r, "planner") == planner]
    s, every = _cutoff_safety(records, planner), safety_summary(mine)
    fa = cdf.false_alarms
    ttc = s["ttc_at_brake"]
    ttc_ok = not ttc["n"] or (ttc["median"] >= 1.5 and ttc["min"] >= 1.0)
    ttc_text = ("no hard brake in any Cutoff episode" if not ttc["n"] else
                f"median {ttc['median']:.2f} s, least {ttc['min']:.2f} s over the {ttc['n']} Cutoff episodes "
                f"with a hard brake; {s['no_brake']} of {s['n']} needed none")
    switches = every["brake_switches"]
    rss = every["rss_ticks"]
    rss_ok = not rss["n"] or rss["value"] <= 0.01
    rss_text = "-" if not rss["n"] else f"{100 * (1 - rss['value']):.1f} % of {rss['n']} ticks"
    jerk, limit = every["peak_jerk_comfort"], LayeredConfig().comfort_jerk
    lines = [f"The earlier issues' targets for `{planner}` (point estimates):", "",
             f"- Cutoff recall 100 %: {format_rate(cdf.recall)}: {verdict(cdf.recall.k == cdf.recall.n)}",
             f"- avoided 100 %: {format_rate(cdf.avoided)}: {verdict(cdf.avoided.k == cdf.avoided.n)}",
             f"- hard-brake false alarms <= 1.0 % of episodes: {format_rate(fa)}: {verdict(fa.value <= 0.01)}",
             f"- TTC at the first hard brake >= 1.5 s median and >= 1.0 s least, or no hard brake needed: "
             f"{ttc_text}: {verdict(ttc_ok)}",
             f"- brake switches <= 2 per episode (median): "
             f"{format_number(switches['median'], 0) if switches['n'] else '-'}: "
             f"{verdict(not switches['n'] or switches['median'] <= 2)}",
             f"- following ticks at or beyond the RSS distance >= 99 %: {rss_text}: {verdict(rss_ok)}",
             f"- peak jerk outside hard braking within the rule's stated {limit:g} m/s³ (the world's process "
             f"noise on the acceleration adds its own): median {format_number(jerk['median'], 1)}, largest "
             f"{format_number(jerk['max'], 1)} m/s³: {verdict(not jerk['n'] or jerk['max'] <= limit)}"]
    if "cdf-threshold" in metrics:
        t = metrics["cdf-threshold"]
        lines.append(f"- time lost at the end no more than the paper's rule's: {format_number(cdf.time_lost)} s vs "
                     f"{format_number(t.time_lost)} s: {verdict(cdf.time_lost <= t.time_lost)}")
    if "reactive" in metrics:
        r = metrics["reactive"]
        lines.append(f"- collisions in Yield episodes no more than reactive's: {cdf.collisions_yield} vs "
                     f"{r.collisions_yield}: {verdict(cdf.collisions_yield <= r.collisions_yield)}")
    return [*lines, ""]


def false_alarm_brakes(records: Sequence[dict[str, Any]], planner: str) -> str:
    """How long ``planner`` braked in the episodes not labelled Cutoff in which it braked
    (all its brakes together, to their release or the end) and what they cost."""
    alarms = [r for r in records if record_field(r, "planner") == planner and is_false_alarm(r)]
    if not alarms:
        return ""

    def brakes(r: dict[str, Any]) -> list[list[float | None]]:
        info = r.get("planner_info") or {}
        return info.get("brakes") or [[r["brake_time"], None]]  # a held brake: to the end

    held = [sum((end if end is not None else r["end_time"]) - start for start, end in brakes(r)) for r in alarms]
    released = sum(1 for r in alarms if brakes(r)[-1][1] is not None)
    plural = "s" if len(alarms) != 1 else ""
    return (f"{planner}'s {len(alarms)} hard-brake false alarm{plural}: {released} released by the end; braked for "
            f"{min(held):.1f}-{max(held):.1f} s in all (median {statistics.median(held):.1f} s); time lost at the "
            f"end in those episodes {statistics.fmean(r['time_lost'] for r in alarms):.2f} s on average.")


def section(part: Part, records: Sequence[dict[str, Any]], failed: int) -> list[str]:
    """Markdown of one part."""
    good = completed(records)
    metrics = planner_metrics(good, reference=REFERENCE)
    seeds = sorted({record_field(r, "seed") for r in good})
    span = f"seeds {seeds[0]}-{seeds[-1]}" if seeds else "no seeds"
    if part.name == "held-out":
        span += " (a range first used here)"
    labels = {lab: sum(1 for r in good if record_field(r, "planner") == part.planners[0]
                       and record_field(r, "label") == lab) for lab in ("Cutoff", "Yield", "Right")}
    lines = [f"## {part.title}", "", f"{span}; labels {labels['Cutoff']} Cutoff, {labels['Yield']} Yield, "
             f"{labels['Right']} Right" + (f"; {failed} failed episode(s) left out" if failed else "") + ".", ""]
    if not metrics:
        return [*lines, "No completed episode.", ""]
    lines += ["Collisions and hard brakes:", "", *planner_rows(metrics), "",
              "Every intervention (per label; the time lost at the fixed point; the hard subset):", "",
              *intervention_lines(metrics, REFERENCE), "",
              "Safety margins over the Cutoff episodes (from the true poses, docs/SAFETY.md):", "",
              *margin_table(good, [p for p in metrics if p != REFERENCE]), ""]
    for first, others in comparisons(list(metrics), DECIDERS, REFERENCE):
        what = (" (the first pair: what the option rule buys over the default and what it costs)"
                if first == "cdf-option" and others[:1] == ["cdf"] else "")
        lines += [f"`{first}` against every other planner, seed by seed{what}:", "",
                  *pareto_lines(good, first, others, REFERENCE), ""]
    brakes = [f"- {line}" for p in (*DECIDERS, "cdf-risk", "cdf-threshold") if (line := false_alarm_brakes(good, p))]
    lines += [*brakes, ""] if brakes else []
    for planner in (p for p in DECIDERS if p in metrics):
        if part.name in TARGET_PARTS:
            lines += issue_targets(good, metrics, planner)
        if part.name in ("held-out", "development"):
            lines += earlier_targets(good, metrics, planner)
    return lines


def figure_section(records: Sequence[dict[str, Any]], path: Path | None, doc: Path, tuning: str | None) -> list[str]:
    """Draw the Pareto figure of the held-out part into ``path``; its Markdown (or why none)."""
    title = ["### The trade-off: every planner on the held-out seeds", ""]
    if path is None:
        return [*title, f"Not drawn: matplotlib is not installed ({install_hint('viz')}).", ""]
    from cdf_mj.viz.pareto import pareto_figure

    good = completed(records)
    seeds = sorted({record_field(r, "seed") for r in good})
    grey = tuning_points(tuning) if tuning else []
    rules = "; ".join(f"`{p}` runs {label}" for p in DECIDERS if (label := layered_label(p)))
    note = f"Seeds {seeds[0]}-{seeds[-1]} of the default scenario." + (
        f" Grey: the CDF at each tuning point of {tuning} (development seeds, default scenario; {rules})."
        if grey else "")
    try:
        drawn = pareto_figure(pareto_points(planner_metrics(good, reference=REFERENCE), REFERENCE), path, grey,
                              note=note.replace("`", ""))
    except ValueError as exc:
        return [*title, f"Not drawn: {exc}.", ""]
    rel = Path(os.path.relpath(drawn.path, doc.parent)).as_posix()
    skipped = f" Not drawn (no time lost measured): {', '.join(drawn.skipped)}." if drawn.skipped else ""
    return [*title, f"![Pareto figure: non-Cutoff interventions against non-Cutoff time lost]({rel})", "",
            "x: the share of the episodes not labelled Cutoff in which the planner intervened (bar: 95 % Wilson "
            "interval); y: its mean time lost in them at the fixed point against the same seed's `constant` ego "
            "[s]; marker area: its share of hard brakes in them; red ring and count: collisions with the obstacle "
            "(any label). Lower left is better; the default `cdf` and `cdf-option` (the option rule) have colours "
            f"of their own. {note}{skipped}", ""]


def markdown(sections: list[list[str]], planners: Sequence[str], small: bool) -> str:
    """The whole page, without its stamp (:func:`~cdf_mj.analysis.pages.write_page` adds it)."""
    lines = [
        "# Decision rules compared",
        "",
        "The rules and how the thresholds were chosen: [DECISION.md](DECISION.md). The planners (each line "
        "from its class's docstring):",
        "",
        *map(planner_item, planners),
        "",
        RULES_NOTE,
        "",
        "How to read the tables:",
        "",
        "- **Cutoff recall**: Cutoff episodes the planner predicted (it braked hard, or the layered rule",
        "  was slowing the ego when the obstacle entered its lane). **avoided**: Cutoff episodes without a",
        "  collision with the obstacle. **paper's formula**: (Cutoff episodes - collisions with the",
        "  obstacle of any label) / Cutoff episodes. **hard-brake false alarms**: braked hard (3 m/s² or",
        "  more for the layered rule; the full brake for the others) in an episode not labelled Cutoff, of",
        "  all episodes and of the Yield episodes. **false discovery**: of the episodes in which it braked",
        "  hard, those not labelled Cutoff. **time lost at the end**: the progress deficit at the end over",
        "  the nominal speed, mean over episodes without a collision (it charges following a slower car).",
        "- **Interventions**: episodes in which the planner held the ego below its own controller by more",
        "  than a tolerance on some tick, hard brake or not (the per-label table and its notes say how).",
        "  **time lost at the fixed point**: against the same seed's `constant` ego, which follows too.",
        "  **hard subset**: the Cutoffs on which `constant`'s ACC alone hit the obstacle.",
        "- 95 % Wilson intervals. The pair tables compare `cdf` and `cdf-option` with each other planner",
        "  seed by seed: exact McNemar tests on the seeds on which only one of the two collides (any label),",
        "  intervenes or brakes hard (not Cutoff), the sign test on the time lost, and a Pareto verdict.",
        "- '-' in a cell: nothing to measure there (no Cutoff episode for a recall, no hard brake for a",
        "  false discovery or a lead time, no episode of that label), never a failed count.",
        "",
    ]
    if small:
        lines += ["**Few seeds: a check that the evaluation runs, not a result.**", ""]
    for sec in sections:
        lines += sec
    return "\n".join(lines).rstrip() + "\n"


def _fail(message: str) -> NoReturn:
    fail(PROG, message)


def _figure_path(args: argparse.Namespace) -> Path | None:
    """Where the figure goes (None: not drawn, matplotlib missing and the default asked)."""
    if args.figure == "":
        return None
    if importlib.util.find_spec("matplotlib") is None:
        if args.figure is not None:
            _fail(f"--figure needs matplotlib ({install_hint('viz')}), or --figure '' for none")
        return None
    return Path(args.figure) if args.figure is not None else Path(args.doc).parent / FIGURE


def main(argv: Sequence[str] | None = None) -> int:
    """Run the evaluation; returns the exit status (1 if some episodes failed)."""
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default=None, help="comma-separated parts (default: held-out, every preset "
                                                 "but default, development)")
    p.add_argument("--episodes", type=int, default=None, help="seeds per part (default 1000 held out, 200 "
                                                              "per preset and development)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: the CPU count)")
    p.add_argument("--out", default="results/decision", help="result directory (default results/decision)")
    p.add_argument("--doc", default="docs/DECISION_RESULTS.md", help="Markdown page written")
    p.add_argument("--figure", default=None, help=f"the Pareto figure's PNG (default {FIGURE} beside the page; "
                                                  "'' for none)")
    p.add_argument("--tuning", default=None, help="tuning results (OUT of scripts/tune_option.py): the CDF at "
                                                  "each point of its 'default' scenario as grey dots on the figure")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    args = p.parse_args(argv)
    if (args.episodes is not None and args.episodes < 1) or (args.workers is not None and args.workers < 1):
        _fail("--episodes and --workers must be at least 1")
    parts = _parts(args.episodes)
    names = [n.strip() for n in args.parts.split(",") if n.strip()] if args.parts else list(parts)
    unknown = [n for n in names if n not in parts]
    if unknown or not names:
        _fail(f"unknown part(s) {', '.join(unknown) or '(none)'}: choose from {', '.join(parts)}")
    missing = sorted({q for n in names for q in parts[n].planners} - set(PLANNERS))
    if missing:
        _fail(f"planner(s) {', '.join(missing)} not registered")
    figure, doc = _figure_path(args), Path(args.doc)
    if args.tuning:
        try:  # read now: a wrong directory is refused before anything runs
            tuning_points(args.tuning)
        except (ValueError, OSError) as exc:
            _fail(f"--tuning: {exc}")
    sections, failed = [], 0
    for i, name in enumerate(names, start=1):
        part = parts[name]
        if not args.quiet:
            print(f"[{i}/{len(names)}] {name}: seeds {part.seeds.start}-{part.seeds.stop - 1}, "
                  f"{','.join(part.planners)}", file=sys.stderr)
        try:
            run = run_experiment(Path(args.out) / name, part.seeds, part.planners, part.config, CDFConfig(),
                                 progress=not args.quiet, workers=args.workers, resume=True)
        except SettingsMismatchError as exc:
            _fail(f"{exc} with --out, or remove {Path(args.out) / name}")
        except ValueError as exc:
            _fail(str(exc))
        failed += run.failed
        sections.append(section(part, run.records, run.failed))
        if name == "held-out" and args.figure != "":
            sections.append(figure_section(run.records, figure, doc, args.tuning))
    command = command_line("scripts/decision.py", [("--parts", args.parts), ("--episodes", args.episodes),
                                                   ("--tuning", args.tuning)])
    planners = list(dict.fromkeys(q for n in names for q in parts[n].planners))
    small = args.episodes is not None and args.episodes < 100
    write_page(doc, markdown(sections, planners, small), command)
    if not args.quiet:
        print(f"wrote {doc}; records in {args.out}/<part>/episodes.jsonl", file=sys.stderr)
    return exit_status(PROG, failed)


if __name__ == "__main__":
    sys.exit(main())
