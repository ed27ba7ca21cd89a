#!/usr/bin/env python3
"""Choose each predictor's option rule (``LayeredConfig.anticipation = "option"``) on the
development seeds, by an objective declared before it ran and applied to each predictor alike.

The objective (issue 35; docs/DECISION.md; written down before any point was run): on seeds
0-199 of the default scenario and of the presets in which the other driver's belief matters
(``stop-and-wait``, ``slow-pull-out``, ``fast-ego``), run ``cdf``, ``imm-layered`` and
``cv-layered`` (and ``constant``, the reference of the time lost) with
``LayeredConfig.anticipate`` in {0.3, 0.5, 0.7, 0.9} (``anticipate_release`` at half of it)
and ``option_time`` in {0.5, 1.0} s, and, as candidates too, version 0.3's anticipation
(``anticipation = "go"``) at 0.1 and 0.35, every other parameter fixed beforehand, and
choose for each predictor, in this order:

1. the fewest collisions with the obstacle, summed over the scenarios (0 is the aim);
2. the fewest interventions in episodes not labelled Cutoff (mean share over the
   scenarios: ticks on which the planner held the ego more than 10 % of its full brake
   below its own controller, :func:`cdf_mj.records.intervened`);
3. the fewest hard brakes in those episodes (mean share);
4. the least time lost in those episodes at the fixed point, against the same seed's
   ``constant`` ego (mean over the scenarios);
5. the smaller threshold, then the longer option time (the more cautious).

Each point is a :func:`cdf_mj.experiments.experiment.run_experiment` in
``OUT/SCENARIO/T-THRESHOLD`` (``go-THRESHOLD`` for version 0.3's rule; resumable). Prints
a Markdown table per predictor and the choices; ``--doc`` writes them to a page::

    python scripts/tune_option.py                 # results/tune_option, docs/TUNING.md
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

from cdf_mj.analysis.metrics import PlannerMetrics, planner_metrics
from cdf_mj.analysis.pages import command_line, write_page
from cdf_mj.cli.args import episode_count, worker_count
from cdf_mj.config import CDFConfig, LayeredConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.presets import load_preset

SCENARIOS = ("default", "stop-and-wait", "slow-pull-out", "fast-ego")
THRESHOLDS = (0.3, 0.5, 0.7, 0.9)
OPTION_TIMES = (0.5, 1.0)
PLANNERS = ("cdf", "imm-layered", "cv-layered")
GO_THRESHOLDS = (0.1, 0.35)
#: The candidates: ``(option_time, anticipate)``, an option_time of None for version 0.3's rule.
POINTS: tuple[tuple[float | None, float], ...] = (*itertools.product(OPTION_TIMES, THRESHOLDS),
                                                  *((None, v) for v in GO_THRESHOLDS))


def layers_of(point: tuple[float | None, float]) -> LayeredConfig:
    """The layered rule of one candidate ``(option_time, anticipate)``."""
    option_time, value = point
    if option_time is None:
        return LayeredConfig(anticipation="go", anticipate=value, anticipate_release=value / 2)
    return LayeredConfig(anticipation="option", option_time=option_time, anticipate=value,
                         anticipate_release=value / 2)


def name_of(point: tuple[float | None, float]) -> str:
    """A candidate's name: ``T-THRESHOLD`` (its directory) or ``go-THRESHOLD``."""
    return f"{'go' if point[0] is None else format(point[0], 'g')}-{point[1]:g}"


def _point(out: Path, scenario: str, point: tuple[float | None, float], episodes: int,
           workers: int | None) -> dict[str, PlannerMetrics]:
    """The metrics per planner of one scenario at one grid point (run, or resumed)."""
    layers = layers_of(point)
    kwargs = {"planners": (*PLANNERS, "constant"), "config": load_preset(scenario),
              "cdf": CDFConfig(layered=layers),
              "planner_args": {p: {"layered": layers} for p in PLANNERS if p != "cdf"},
              "workers": workers, "progress": False}
    path = out / scenario / name_of(point)
    result = run_experiment(path, range(episodes), resume=True, **kwargs)  # a fresh directory starts
    return planner_metrics(result)


def _key(cells: dict[str, PlannerMetrics], point: tuple[float | None, float]) -> tuple[float, ...]:
    """The declared objective, smaller is better."""
    ms = list(cells.values())
    n = len(ms)
    return (sum(m.collisions for m in ms), sum(m.false_interventions.value for m in ms) / n,
            sum(m.false_alarms.k / max(m.episodes - m.imminent, 1) for m in ms) / n,
            sum(m.time_lost_fixed for m in ms) / n, point[1], -(point[0] if point[0] is not None else math.inf))


def _cell(m: PlannerMetrics) -> str:
    iv = m.false_interventions
    hard = m.false_alarms.k
    return f"{m.collisions} coll., {iv.k}/{iv.n} interv., {hard} hard, {m.time_lost_fixed:.3f} s"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tune_option", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/tune_option"), help="result directory")
    parser.add_argument("--episodes", type=episode_count, default=200, help="development seeds from 0 (default 200)")
    parser.add_argument("--workers", type=worker_count, default=None, help="worker processes (default: one per CPU)")
    parser.add_argument("--doc", default="docs/TUNING.md",
                        help="Markdown page written (default docs/TUNING.md; '' for none)")
    args = parser.parse_args(argv)
    cells: dict[str, dict[tuple[float | None, float], dict[str, PlannerMetrics]]] = {
        p: {pt: {} for pt in POINTS} for p in PLANNERS}
    for scenario in SCENARIOS:
        for point in POINTS:
            print(f"{scenario}, {name_of(point)}", file=sys.stderr, flush=True)
            try:
                got = _point(args.out, scenario, point, args.episodes, args.workers)
            except (ValueError, OSError) as exc:  # a directory of other settings, not a directory, ...
                parser.error(str(exc))
            for planner, m in got.items():
                if planner in PLANNERS:
                    cells[planner][point][scenario] = m
    lines = ["# The layered rule's anticipation, chosen on the development seeds", "",
             f"Seeds 0-{args.episodes - 1} of {', '.join(SCENARIOS)}; the objective, declared before the run, "
             "is in `scripts/tune_option.py` and [DECISION.md](DECISION.md). Each cell: collisions with the "
             "obstacle, non-Cutoff episodes with an intervention, non-Cutoff hard brakes, mean non-Cutoff time "
             "lost at the fixed point against `constant` [s].", ""]
    for planner in PLANNERS:
        table = cells[planner]
        best = min(POINTS, key=lambda pt, t=table: _key(t[pt], pt))
        lines += [f"## {planner}", "", "| rule (option_time-anticipate) | " + " | ".join(SCENARIOS) + " |",
                  "|---|" + "---|" * len(SCENARIOS)]
        lines += [f"| {name_of(pt)} | " + " | ".join(_cell(table[pt][s]) for s in SCENARIOS) + " |"
                  for pt in POINTS]
        k = _key(table[best], best)
        lines += ["", f"Chosen for {planner}: {name_of(best)} (anticipate_release = {best[1] / 2:g}; {k[0]} "
                      f"collisions, mean non-Cutoff interventions "
                      f"{k[1]:.1%}, hard brakes {k[2]:.1%}, time lost {k[3]:.3f} s).", ""]
    text = "\n".join(lines)
    print(text)
    if args.doc:
        command = command_line("scripts/tune_option.py", [("--episodes", args.episodes if args.episodes != 200
                                                           else None)])
        write_page(args.doc, text, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
