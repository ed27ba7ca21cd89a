#!/usr/bin/env python3
"""The decision rules compared: each predictor with the paper's threshold rule, with version
0.2's risk rule and with the layered rule, on held-out seeds first, then on the scenario
presets, then on the development seeds.

Runs (resumable, with :func:`~cdf_mj.experiments.experiment.run_experiment`, into
``OUT/PART``) and writes a Markdown page (default docs/DECISION_RESULTS.md):

- ``held-out``: the default scenario on seeds 100000-100999 (never used for tuning);
- one part per preset on seeds 1000-1199 (held out as well);
- ``development``: the default scenario on seeds 0-199, where the risk rule's threshold
  (scripts/tune_risk.py) and the layered rule's anticipation threshold per predictor
  (scripts/tune_layers.py) were chosen, labelled as such.

For every planner: Cutoff recall (predicted Cutoff in Cutoff episodes: braked, or for the
layered rule slowed for the obstacle as it entered the lane), avoided (ours and the
paper's formula, where a collision of any label counts), false alarms (hard braking) per
episode and per Yield episode, the false-discovery rate of its hard brakes, collisions in
Yield and Right episodes, time lost; the safety margins over the Cutoff episodes
(:func:`cdf_mj.analysis.tables.margin_table`); then ``cdf`` against every other planner
seed by seed (exact McNemar tests on collisions of any label and on false alarms), and
the issue's targets::

    python scripts/decision.py                          # all parts (about 25 min on 2 cores)
    python scripts/decision.py --parts held-out --episodes 20 --out /tmp/d --doc /tmp/d.md

Bad input (an unknown part or planner, a result directory of other settings) is one line
``decision: error: ...`` and exit status 2, before anything runs.
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from cdf_mj.analysis.metrics import PlannerMetrics, mcnemar_exact, paired_counts, planner_metrics
from cdf_mj.analysis.pages import ScriptParser, exit_status, fail, markdown_table, verdict, write_page
from cdf_mj.analysis.safety import safety_summary
from cdf_mj.analysis.tables import format_number, format_percent, format_rate, margin_table
from cdf_mj.config import CDFConfig, LayeredConfig, ScenarioConfig
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.presets import load_preset, scenario_preset_names
from cdf_mj.records import completed, is_false_alarm, record_field

PROG = "decision"
PLANNERS_DEFAULT = ("cdf", "cdf-risk", "cdf-threshold", "imm-layered", "imm-risk", "imm", "cv-layered", "reactive")
PRESET_PLANNERS = ("cdf", "cdf-risk", "cdf-threshold", "imm-layered", "reactive")
#: The predictor the CDF is judged against under the same (layered) rule.
SAME_RULE = "imm-layered"


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
    parts = {"held-out": Part("held-out", "Default scenario, held-out seeds", ScenarioConfig(),
                              range(100000, 100000 + n_main), PLANNERS_DEFAULT, True)}
    for name in scenario_preset_names():
        if name == "default":
            continue
        parts[name] = Part(name, f"Preset `{name}`, held-out seeds", load_preset(name),
                           range(1000, 1000 + n_preset), PRESET_PLANNERS, True)
    parts["development"] = Part("development", "Default scenario, development seeds (the threshold was "
                                "chosen here)", ScenarioConfig(), range(0, n_dev), PLANNERS_DEFAULT, False)
    return parts


def planner_rows(metrics: dict[str, PlannerMetrics]) -> list[str]:
    """Markdown: one row per planner with the counts of the module docstring."""
    header = ["planner", "Cutoff recall", "avoided (95 % CI)", "paper's formula", "false alarms / episodes",
              "false alarms / Yield episodes", "false discovery (of braked)", "collisions Yield, Right",
              "time lost [s]"]
    rows = [[m.planner, format_rate(m.recall), format_rate(m.avoided),
             f"{format_percent(m.paper_avoided)} ({m.imminent - m.collisions}/{m.imminent})",
             format_rate(m.false_alarms), format_rate(m.false_alarms_yield), format_rate(m.false_discovery),
             f"{m.collisions_yield}, {m.collisions_right}", format_number(m.time_lost)]
            for m in metrics.values()]
    return markdown_table(header, rows)


def paired_rows(records: Sequence[dict[str, Any]], first: str, others: Sequence[str]) -> list[str]:
    """Markdown: ``first`` against each of ``others`` seed by seed (exact McNemar tests)."""
    rows = []
    for other in others:
        c = paired_counts(records, first, other)
        rows.append([f"{first} / {other}", str(c.seeds), str(c.hit_only_first), str(c.hit_only_second),
                     f"{mcnemar_exact(c.hit_only_first, c.hit_only_second):.3g}", str(c.false_alarm_only_first),
                     str(c.false_alarm_only_second),
                     f"{mcnemar_exact(c.false_alarm_only_first, c.false_alarm_only_second):.3g}"])
    return markdown_table(["pair", "seeds", f"collision only {first}", "only the other", "McNemar p",
                           f"false alarm only {first}", "only the other", "McNemar p"], rows)


def _cutoff_safety(records: Sequence[dict[str, Any]], planner: str) -> dict[str, Any]:
    """:func:`safety_summary` of ``planner``'s Cutoff episodes, with the count of those it
    avoided without a hard brake (``no_brake``)."""
    cut = [r for r in records if record_field(r, "planner") == planner and record_field(r, "label") == "Cutoff"]
    return {**safety_summary(cut), "no_brake": sum(1 for r in cut if record_field(r, "brake_time") is None),
            "n": len(cut)}


def targets(records: Sequence[dict[str, Any]], metrics: dict[str, PlannerMetrics]) -> list[str]:
    """The issue's targets for ``cdf`` on the default scenario, judged on the point estimates."""
    cdf = metrics.get("cdf")
    if cdf is None:
        return []
    mine = [r for r in records if record_field(r, "planner") == "cdf"]
    s, every = _cutoff_safety(records, "cdf"), safety_summary(mine)
    lines = ["Targets (default scenario, point estimates):", ""]
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
    lines += [f"- Cutoff recall 100 %: {format_rate(cdf.recall)}: {verdict(cdf.recall.k == cdf.recall.n)}",
              f"- avoided 100 %: {format_rate(cdf.avoided)}: {verdict(cdf.avoided.k == cdf.avoided.n)}",
              f"- avoided, paper's formula, >= 99.5 %: {format_percent(cdf.paper_avoided)}: "
              f"{verdict(cdf.paper_avoided >= 0.995)}",
              f"- false alarms (hard braking) <= 1.0 % of episodes: {format_rate(fa)}: {verdict(fa.value <= 0.01)}",
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
        lines.append(f"- time lost no more than the paper's rule's: {format_number(cdf.time_lost)} s vs "
                     f"{format_number(t.time_lost)} s: {verdict(cdf.time_lost <= t.time_lost)}")
    if "reactive" in metrics:
        r = metrics["reactive"]
        lines.append(f"- collisions in Yield episodes no more than reactive's: {cdf.collisions_yield} vs "
                     f"{r.collisions_yield}: {verdict(cdf.collisions_yield <= r.collisions_yield)}")
    return [*lines, ""]


def _compare(a: int, b: int) -> str:
    return "fewer" if a < b else "as many" if a == b else "more"


def beats(records: Sequence[dict[str, Any]], metrics: dict[str, PlannerMetrics], other: str) -> str:
    """``cdf`` against ``other`` on collisions (the paper's count) and false alarms."""
    if "cdf" not in metrics or other not in metrics:
        return ""
    c = paired_counts(records, "cdf", other)
    hits, other_hits = metrics["cdf"].collisions, metrics[other].collisions
    alarms, other_alarms = metrics["cdf"].false_alarms.k, metrics[other].false_alarms.k
    p_hit = mcnemar_exact(c.hit_only_first, c.hit_only_second)
    p_fa = mcnemar_exact(c.false_alarm_only_first, c.false_alarm_only_second)
    both = hits < other_hits and alarms < other_alarms
    neither_worse = hits <= other_hits and alarms <= other_alarms
    verdict = ("better on both" if both else "no worse on either, better on one" if neither_worse
               and (hits, alarms) != (other_hits, other_alarms) else "the same" if neither_worse
               else "worse on at least one")
    return (f"cdf against {other} (the same layered rule, another predictor): collisions {hits} vs {other_hits} "
            f"({_compare(hits, other_hits)}; McNemar p = {p_hit:.3g}), false alarms {alarms} vs {other_alarms} "
            f"({_compare(alarms, other_alarms)}; p = {p_fa:.3g}): {verdict}.")


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
    return (f"{planner}'s {len(alarms)} false alarm{plural}: {released} released by the end; braked for "
            f"{min(held):.1f}-{max(held):.1f} s in all (median {statistics.median(held):.1f} s); time lost in "
            f"those episodes {statistics.fmean(r['time_lost'] for r in alarms):.2f} s on average.")


def section(part: Part, records: Sequence[dict[str, Any]], failed: int) -> list[str]:
    """Markdown of one part."""
    good = completed(records)
    metrics = planner_metrics(good)
    seeds = sorted({record_field(r, "seed") for r in good})
    span = f"seeds {seeds[0]}-{seeds[-1]}" if seeds else "no seeds"
    labels = {lab: sum(1 for r in good if record_field(r, "planner") == part.planners[0]
                       and record_field(r, "label") == lab) for lab in ("Cutoff", "Yield", "Right")}
    lines = [f"## {part.title}", "", f"{span}; labels {labels['Cutoff']} Cutoff, {labels['Yield']} Yield, "
             f"{labels['Right']} Right" + (f"; {failed} failed episode(s) left out" if failed else "") + ".", ""]
    if not metrics:
        return [*lines, "No completed episode.", ""]
    lines += [*planner_rows(metrics), "", "Safety margins over the Cutoff episodes (from the true poses, "
              "docs/SAFETY.md):", "", *margin_table(good, list(metrics)), ""]
    if "cdf" in metrics:
        lines += [*paired_rows(good, "cdf", [p for p in metrics if p != "cdf"]), ""]
        verdict = beats(good, metrics, SAME_RULE)
        if verdict:
            lines += [verdict, ""]
        lines += [f"- {line}" for p in ("cdf", "cdf-risk", "cdf-threshold") if (line := false_alarm_brakes(good, p))]
        lines.append("")
    if part.name in ("held-out", "development"):
        lines += targets(good, metrics)
    return lines


def markdown(sections: list[list[str]], small: bool) -> str:
    """The whole page, without its stamp (:func:`~cdf_mj.analysis.pages.write_page` adds it)."""
    lines = [
        "# Decision rules compared",
        "",
        "The rules and how the threshold was chosen: [DECISION.md](DECISION.md).",
        "",
        "- `cdf`: the CDF filter with the layered rule (anticipate, emergency, follow: a graded command);",
        "  `cdf-risk`: the same filter with version 0.2's risk rule (the full brake at the last safe",
        "  moment, released); `cdf-threshold`: with the paper's rule (brake once P(cutoff) >= tau, held);",
        "  `imm-layered`, `cv-layered`: the intent-only IMM and the constant-velocity predictors with the",
        "  layered rule (each predictor's anticipation threshold chosen by one rule on seeds 0-199);",
        "  `imm-risk`: the IMM with the risk rule; `imm`: the IMM with its own threshold rule; `reactive`:",
        "  brakes once the obstacle is in the ego's lane.",
        "- **Cutoff recall**: Cutoff episodes the planner predicted (it braked hard, or the layered rule",
        "  was slowing the ego when the obstacle entered its lane). **avoided**: Cutoff episodes without a",
        "  collision with the obstacle. **paper's formula**: (Cutoff episodes - collisions with the",
        "  obstacle of any label) / Cutoff episodes. **false alarms**: braked hard (3 m/s² or more for the",
        "  layered rule; the full brake for the others) in an episode not labelled Cutoff, of all episodes",
        "  and of the Yield episodes. **false discovery**: of the episodes in which it braked hard, those",
        "  not labelled Cutoff. **time lost**: mean over episodes without a collision.",
        "- 95 % Wilson intervals; paired tables count the seeds on which only one planner collides (any",
        "  label) or false-alarms, with the exact two-sided McNemar test on those discordant seeds.",
        "",
    ]
    if small:
        lines += ["**Few seeds: a check that the evaluation runs, not a result.**", ""]
    for sec in sections:
        lines += sec
    return "\n".join(lines).rstrip() + "\n"


def _fail(message: str) -> NoReturn:
    fail(PROG, message)


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
    command = "python scripts/decision.py" + "".join(
        f" {flag} {shlex.quote(str(v))}" for flag, v in (("--parts", args.parts), ("--episodes", args.episodes))
        if v is not None)
    doc = write_page(args.doc, markdown(sections, small=args.episodes is not None and args.episodes < 100), command)
    if not args.quiet:
        print(f"wrote {doc}; records in {args.out}/<part>/episodes.jsonl", file=sys.stderr)
    return exit_status(PROG, failed)


if __name__ == "__main__":
    sys.exit(main())
