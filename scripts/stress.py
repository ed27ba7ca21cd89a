#!/usr/bin/env python3
"""The stress suite: every planner on every stress preset, with the safety margins.

For each stress preset of :mod:`cdf_mj.presets` (``stress-*``: the obstacle slowing,
braking or stopping after the merge, with today's ego and with the paper's; each driver
family written apart from the filter's model; noise on the measured obstacle, measurement
and brake latency, dropped measurements; one combination) and the default world for
reference, run the planners on the same held-out seeds with
:func:`~cdf_mj.experiments.experiment.run_experiment` into ``OUT/PRESET`` (resumable: the
same command continues a killed run), then write a Markdown page (default docs/STRESS.md):

- a stamp line (the command and the package version), an overview written from the
  numbers: which planner collides where, and where ``cdf`` differs from another planner;
- per preset: collisions with the obstacle (any label), Cutoff avoided (ours and the
  paper's formula), false alarms (braked in an episode not labelled Cutoff), with 95 %
  Wilson intervals; the safety margins of :mod:`cdf_mj.analysis.safety` over the Cutoff
  episodes (docs/SAFETY.md defines each); exact McNemar tests of ``cdf`` against every
  other planner, seed by seed, on collisions and on false alarms;
- the issue's targets for ``cdf`` on the presets that have one, met or missed::

    python scripts/stress.py                                      # everything (long)
    python scripts/stress.py --episodes 4 --preset stress-merge-brakes --doc /tmp/s.md

Seeds: from 100000 by default. No parameter was chosen there (the CDF's and the risk
rule's on seeds 0-199, docs/PARAMETERS.md and docs/DECISION.md), and the issue that asked
for this suite measured its first table on seeds 100000-100099, which these include.
200 seeds per preset: a Wilson interval at most about +-7 points wide on a share of all
episodes, and some 80 Cutoff episodes per preset for the margins.

The CDF runs with ``CDFConfig()`` everywhere: nothing of a stress (the world's driver
family, the noise, the latency) is passed to any planner, except in the ``*-told`` presets,
which tell every planner the ego's own sensing figures (``sensing.told``: the latency and the
noise, as a real ego knows its own hardware). Results are as measured: a
failure here is a finding, not an error. Progress goes to stderr. Bad input (an unknown
or broken preset, an unknown planner, a count out of range, a result directory of other
settings) is one line ``stress: error: ...`` and exit status 2, before anything runs.
The flags are ``cdf-mj``'s (``--seed``, ``--planner``; ``--preset`` a comma-separated list
here); the old ``--seed0``, ``--planners``, ``--presets`` and ``--parts`` still work, with a
note on stderr once the page is written.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cdf_mj.analysis.metrics import Rate, mcnemar_exact, of_planner, paired_counts, planner_metrics
from cdf_mj.analysis.pages import ScriptParser, command_line, markdown_table, verdict, write_page
from cdf_mj.analysis.safety import SafetyParams
from cdf_mj.analysis.tables import format_number, format_rate, margin_table
from cdf_mj.cli.args import CLIError, add_option, notes
from cdf_mj.cli.args import episode_count as _episodes
from cdf_mj.cli.args import out_path as _out_path
from cdf_mj.cli.args import planner_list as _planner_list
from cdf_mj.cli.args import seed_range as _seed_range
from cdf_mj.cli.args import seed_value as _non_negative_int
from cdf_mj.cli.args import worker_count as _workers
from cdf_mj.config import CDFConfig
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment
from cdf_mj.presets import STRESS_PREFIX, Preset, preset_names, read_preset
from cdf_mj.records import RecordLike, completed, hit_obstacle, is_imminent, record_field

PROG = "stress"
PLANNERS_DEFAULT = ("cdf", "cdf-risk", "cdf-threshold", "imm-layered", "reactive")
#: The issue's targets for ``cdf`` on the stress presets: no collision where the merged car
#: brakes or stops; at most 1 % collisions under noise and latency the rule is told; for the
#: driver families written apart from the filter's model, the paper's formula >= 99 % and
#: false alarms <= 3 %.
NO_COLLISION = ("stress-merge-brakes", "stress-merge-stops")
TOLD = ("stress-noise-told", "stress-latency-2-told", "stress-brake-latency-2-told")
FAMILIES = ("stress-gap-acceptance", "stress-rolling-stop", "stress-aggressive", "stress-off-route")
REFERENCE = "default"  # the preset of the default world, run first for reference
SEED0, EPISODES = 100000, 200  # held out; see the module docstring
SIGNIFICANT = 0.05  # McNemar p below which the overview names a difference


def default_presets() -> list[str]:
    """The reference world, then every shipped stress preset (sorted)."""
    return [REFERENCE, *(n for n in preset_names() if n.startswith(STRESS_PREFIX))]


@dataclass(frozen=True)
class PresetRun:
    """The completed records of one preset's run."""

    preset: Preset
    records: list[RecordLike]  # completed episodes only
    failed: int  # failed episodes, left out


def _collisions(records: Sequence[RecordLike]) -> Rate:
    """Episodes with a collision with the obstacle, any label, of all."""
    return Rate(sum(map(hit_obstacle, records)), len(records))


def _value(v: Any) -> str:
    return f"[{', '.join(f'{x:g}' for x in v)}]" if isinstance(v, tuple) else f"{v:g}" if isinstance(v, float) \
        else str(v).lower() if isinstance(v, bool) else str(v)


def outcome_table(records: Sequence[RecordLike], planners: Sequence[str]) -> list[str]:
    """Markdown: per planner, collisions, avoided, false alarms (Wilson intervals), time lost."""
    metrics = planner_metrics(records)
    rows = []
    for name in planners:
        m = metrics.get(name)
        if m is None:
            continue
        paper = "-" if not m.imminent else f"{100 * m.paper_avoided:.1f} % ({m.imminent - m.collisions}/{m.imminent})"
        rows.append([name, str(m.episodes), format_rate(_collisions(of_planner(records, name))), format_rate(m.avoided),
                     paper, format_rate(m.false_alarms), format_number(m.time_lost)])
    return markdown_table(["planner", "episodes", "collisions with the obstacle, any label (95 % CI)",
                   "Cutoff avoided (95 % CI)", "paper's formula", "false alarms: braked, not Cutoff (95 % CI)",
                   "time lost [s]"], rows)


def paired_table(records: Sequence[RecordLike], planners: Sequence[str]) -> list[str]:
    """Markdown: ``cdf`` against each other planner seed by seed (exact McNemar tests on
    collisions of any label and on false alarms)."""
    ran = {record_field(r, "planner") for r in records}
    others = [p for p in planners if p != "cdf" and p in ran]
    if "cdf" not in ran or not others:
        return ["No pair to compare (`cdf` and another planner are needed)."]
    rows = []
    for other in others:
        c = paired_counts(records, "cdf", other)
        rows.append([f"cdf / {other}", str(c.seeds), str(c.hit_only_first), str(c.hit_only_second),
                     f"{mcnemar_exact(c.hit_only_first, c.hit_only_second):.3g}", str(c.false_alarm_only_first),
                     str(c.false_alarm_only_second),
                     f"{mcnemar_exact(c.false_alarm_only_first, c.false_alarm_only_second):.3g}"])
    return markdown_table(["pair", "seeds", "collision only cdf", "only the other", "McNemar p", "false alarm only cdf",
                           "only the other", "McNemar p"], rows)


def preset_section(run: PresetRun, planners: Sequence[str]) -> list[str]:
    """Markdown of one preset: what it stresses and sets, then the three tables."""
    p = run.preset
    title = f"## `{p.name}`" + (" (reference: the default world)" if p.name == REFERENCE else "")
    sets = "; ".join(f"`{k}` = {_value(v)}" for k, v in p.scenario.items())
    lines = [title, "", p.description, "", f"Sets: {sets}." if sets else "Sets nothing: `ScenarioConfig()`.", ""]
    if not run.records:
        return [*lines, "No completed episode" + (f" ({run.failed} failed)." if run.failed else "."), ""]
    seeds = sorted({record_field(r, "seed") for r in run.records})
    first = record_field(run.records[0], "planner")
    labels = Counter(str(record_field(r, "label")) for r in of_planner(run.records, first))
    failed = f"; {run.failed} failed episode(s) left out" if run.failed else ""
    lines += [f"Seeds {seeds[0]}-{seeds[-1]}; labels " + ", ".join(f"{n} {lab}" for lab, n in sorted(labels.items()))
              + f"{failed}.", "", "Outcomes:", "", *outcome_table(run.records, planners), "",
              "Margins over the Cutoff episodes:", "", *margin_table(run.records, planners), "",
              "`cdf` against the others, seed by seed:", "", *paired_table(run.records, planners), ""]
    return lines


def targets(runs: Sequence[PresetRun]) -> list[str]:
    """Markdown: the issue's targets for ``cdf`` (:data:`NO_COLLISION`, :data:`TOLD`,
    :data:`FAMILIES`) on the presets of this page, judged on the point estimates."""
    lines = []
    for run in runs:
        m = planner_metrics(run.records).get("cdf")
        name = run.preset.name
        if m is None:
            continue
        hits = _collisions(of_planner(run.records, "cdf"))
        if name in NO_COLLISION:
            lines.append(f"- `{name}`: no collision: {format_rate(hits)}: {verdict(hits.k == 0)}")
        elif name in TOLD:
            lines.append(f"- `{name}`: collisions <= 1 %: {format_rate(hits)}: {verdict(hits.value <= 0.01)}")
        elif name in FAMILIES:
            paper = m.paper_avoided
            shown = "-" if not m.imminent else f"{100 * paper:.1f} % ({m.imminent - m.collisions}/{m.imminent})"
            ok = (not m.imminent or paper >= 0.99) and m.false_alarms.value <= 0.03
            lines.append(f"- `{name}`: paper's formula >= 99 %: {shown}; false alarms <= 3 %: "
                         f"{format_rate(m.false_alarms)}: {verdict(ok)}")
    if not lines:
        return []
    return ["## Targets for `cdf`", "", "The issue's targets on the stress presets (point estimates):", "",
            *lines, ""]


def overview(runs: Sequence[PresetRun], planners: Sequence[str]) -> list[str]:
    """Markdown: collisions per preset and planner, where each planner collides, and the
    presets on which ``cdf`` differs from another planner (McNemar p < SIGNIFICANT)."""
    rows = []
    for run in runs:
        first = of_planner(run.records, planners[0])
        cells = [format_rate(_collisions(of_planner(run.records, p))) for p in planners]
        rows.append([f"`{run.preset.name}`", str(sum(map(is_imminent, first))), *cells])
    lines = ["## Overview", "", "Collisions with the obstacle (any label), of all episodes:", "",
             *markdown_table(["preset", "Cutoff episodes", *planners], rows), ""]
    for p in planners:
        hits = sorted(((_collisions(of_planner(r.records, p)), r.preset.name) for r in runs),
                      key=lambda item: (-item[0].value if item[0].n else 0.0, item[1]))
        some = [f"`{name}` {rate.k}/{rate.n}" for rate, name in hits if rate.k]
        none = [f"`{name}`" for rate, name in hits if not rate.k and rate.n]
        text = f"collides on {len(some)} of {len(runs)} presets" + (f", most first: {', '.join(some)}" if some
                                                                     else "")
        lines.append(f"- **{p}** {text}" + (f"; never on {', '.join(none)}." if none else "."))
    lines.append("")
    if "cdf" in planners and len(planners) > 1:
        found = []
        for run in runs:
            for other in (q for q in planners if q != "cdf"):
                c = paired_counts(run.records, "cdf", other)
                for what, a, b in (("collides", c.hit_only_first, c.hit_only_second),
                                   ("false-alarms", c.false_alarm_only_first, c.false_alarm_only_second)):
                    pv = mcnemar_exact(a, b)
                    if pv < SIGNIFICANT:
                        found.append(f"- `{run.preset.name}`: cdf {what} {'more' if a > b else 'less'} than {other} "
                                     f"(only cdf on {a} seeds, only {other} on {b}; McNemar p = {pv:.3g}).")
        lines += [f"Where `cdf` differs from another planner at McNemar p < {SIGNIFICANT:g} (collisions of any "
                  "label, false alarms; not corrected for the many tests):", ""]
        lines += found or ["- nowhere."]
        lines.append("")
    return lines


def stress_markdown(runs: Sequence[PresetRun], planners: Sequence[str]) -> str:
    """The whole page but its stamp (:func:`cdf_mj.analysis.pages.write_page` adds it): the
    overview, how to read it, one section a preset."""
    seeds = max((len({record_field(r, "seed") for r in run.records}) for run in runs), default=0)
    few = [f"**{seeds} seeds per preset: a check that the suite runs, not a result (the intervals are too "
           "wide for any conclusion).**", ""] if seeds < 100 else []
    critical = SafetyParams().ttc_critical
    lines = [
        "# Stress suite: the planners outside the filter's own world",
        "",
        *few,
        f"Planners {', '.join(f'`{p}`' for p in planners)} on the same seeds of every preset (common random",
        "numbers); each preset (`cdf-mj presets NAME`, files `cdf_mj/presets/stress-*.toml`) sets only what it",
        "stresses, and no planner is told of it (the CDF keeps `CDFConfig()`), except the `*-told` presets,",
        "which tell every planner the ego's own sensing figures (its latency and noise). `cdf` decides with",
        "the layered rule, `cdf-risk` with version 0.2's risk rule, `cdf-threshold` with the paper's, and",
        "`imm-layered` is the intent-only IMM with the layered rule (docs/DECISION.md). Results as measured.",
        "",
        *overview(runs, planners),
        *targets(runs),
        "## How to read the tables",
        "",
        "- **collisions**: episodes in which the ego touched the obstacle, whatever the label.",
        "- **Cutoff avoided**: Cutoff episodes (the constant-speed run of the seed hits the obstacle) without",
        "  a collision with the obstacle; **paper's formula**: (Cutoff episodes - collisions of any label) /",
        "  Cutoff episodes.",
        "- **false alarms**: episodes not labelled Cutoff in which the planner braked hard (a graded",
        "  command of `LayeredConfig.hard_brake`, 3 m/s², or more; the others' full brake), of all episodes.",
        "- **time lost**: the ego's progress deficit at the end, mean over the episodes without a collision.",
        "- The margins are over the Cutoff episodes, from the true poses (docs/SAFETY.md gives every",
        "  formula); (n) counts the episodes in which a margin happened: the Cutoff episodes the planner",
        "  avoided **without a hard brake** (slowing only); **TTC at the first hard brake** (median",
        f"  [least]) and the share of those onsets with TTC < {critical:g} s; **minimum TTC** with the",
        "  obstacle in the lane; **minimum headway** (gap / ego speed) with it ahead in the lane; **minimum",
        "  gap** between the collision boxes; **following ticks under the RSS distance**, pooled over the",
        "  episodes, and the episodes with any; **brake switches** (hard braking on or off); **peak",
        "  deceleration** (median [largest]); **peak jerk outside hard braking**, the comfort jerk (median",
        "  [largest]; it includes the world's process noise on the acceleration, 0.3 m/s² a tick).",
        "- 95 % Wilson intervals. The paired tables count the seeds on which only one of the two planners",
        "  collides (any label) or false-alarms; McNemar p is the exact two-sided binomial test on those",
        "  discordant seeds.",
        "",
    ]
    sections = [line for run in runs for line in preset_section(run, planners)]
    return "\n".join([*lines, *sections]).rstrip() + "\n"


def _preset_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated presets, got {text!r}")
    return names


def _command(args: argparse.Namespace, names: Sequence[str]) -> str:
    """The command line that makes this page (options that change it, when not the default)."""
    given = (("--preset", ",".join(names), ",".join(default_presets())), ("--episodes", args.episodes, EPISODES),
             ("--seed", args.seed, SEED0), ("--planner", ",".join(args.planner), ",".join(PLANNERS_DEFAULT)))
    return command_line("scripts/stress.py", [(flag, v) for flag, v, default in given if v != default])


def main(argv: Sequence[str] | None = None) -> int:
    """Run the suite and write the page; returns the exit status (1 if some episodes failed)."""
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_option(p, "--preset", old=("--presets", "--parts"), type=_preset_list, default=None, metavar="P[,P...]",
               help=f"comma-separated presets or .toml files (default: {REFERENCE} and every stress-* preset)")
    p.add_argument("--episodes", type=_episodes, default=EPISODES, help=f"seeds per preset (default {EPISODES})")
    add_option(p, "--seed", old=("--seed0",), type=_non_negative_int, default=SEED0,
               help=f"first seed (default {SEED0}: held out)")
    add_option(p, "--planner", old=("--planners",), type=_planner_list, default=list(PLANNERS_DEFAULT),
               metavar="P[,P...]", help=f"comma-separated planners (default {','.join(PLANNERS_DEFAULT)}); cdf is "
                                        "compared with each of the others")
    p.add_argument("--workers", type=_workers, default=None, help="worker processes (default: the CPU count)")
    p.add_argument("--out", type=_out_path, default="results/stress",
                   help="result directory, one folder per preset (default results/stress)")
    p.add_argument("--doc", type=_out_path, default="docs/STRESS.md", help="Markdown page written "
                                                                           "(default docs/STRESS.md)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    try:
        args = p.parse_args(argv)
        seeds = _seed_range(args.seed, args.episodes)
    except CLIError as exc:
        p.error(str(exc))
    if len(set(args.planner)) != len(args.planner):
        p.error(f"--planner names a planner twice: {','.join(args.planner)}")
    doc = Path(args.doc)
    if doc.is_dir():
        p.error(f"--doc {doc} is a directory; give the path of the Markdown page to write")
    names = args.preset if args.preset is not None else default_presets()
    try:  # every preset is read and checked before anything runs
        presets = [read_preset(n) for n in names]
    except ValueError as exc:
        p.error(str(exc))
    twice = sorted(n for n, k in Counter(q.name for q in presets).items() if k > 1)
    if twice:
        p.error(f"--preset names {twice[0]!r} twice (results go in OUT/<name>)")
    runs = []
    for i, preset in enumerate(presets, start=1):
        if not args.quiet:
            print(f"[{i}/{len(presets)}] {preset.name}: seeds {seeds[0]}-{seeds[-1]}, {','.join(args.planner)}",
                  file=sys.stderr)
        out = Path(args.out) / preset.name
        try:
            run = run_experiment(out, seeds, args.planner, preset.config(), CDFConfig(), progress=not args.quiet,
                                 workers=args.workers, resume=True)
        except SettingsMismatchError as exc:
            p.error(f"{exc} with --out, or remove {out} to run preset {preset.name} again")
        except ValueError as exc:
            p.error(str(exc))
        runs.append(PresetRun(preset, completed(run.records), run.failed))
    write_page(doc, stress_markdown(runs, args.planner), _command(args, names))
    if not args.quiet:
        print(f"wrote {doc}; records in {args.out}/<preset>/episodes.jsonl", file=sys.stderr)
    failed = {run.preset.name: run.failed for run in runs if run.failed}
    for name, n in failed.items():  # the page says so too; the records hold the error and traceback
        print(f"{PROG}: {name}: {n} episode(s) failed; see {Path(args.out) / name}/episodes.jsonl", file=sys.stderr)
    for text in notes(args):  # old spellings, once the page is written (an error stays one line)
        print(f"{PROG}: note: {text}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
