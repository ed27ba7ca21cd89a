#!/usr/bin/env python3
"""Choose each predictor's anticipation threshold for the layered rule on the development
seeds, by one rule fixed in advance and applied to each predictor alike.

The rule (docs/DECISION.md, written before any other seed was run): on seeds 0-199 of the
default scenario and of the presets in which the other driver's belief matters
(``stop-and-wait``, ``slow-pull-out``, ``fast-ego``), run ``cdf``, ``imm-layered`` and
``cv-layered`` with ``LayeredConfig.anticipate`` in {0.1, 0.2, 0.35, 0.5}
(``anticipate_release`` at half of it; every other layer parameter, and the emergency
layer's thresholds of ``RiskConfig``, fixed beforehand) and choose, for each predictor,

1. the largest worst-scenario share of Cutoff episodes avoided, counted the paper's way
   ((imminent - collisions of any label) / imminent);
2. among those, the fewest false alarms (hard brakes in episodes not labelled Cutoff)
   per episode, averaged over the scenarios;
3. among those, the least time lost per episode, averaged over the scenarios;
4. among those, the larger threshold.

Each point is a :func:`cdf_mj.experiments.experiment.run_experiment` in
``OUT/SCENARIO/VALUE`` (resumable). Prints a Markdown table per predictor and the choices::

    python scripts/tune_layers.py --out results/tune_layers
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cdf_mj.analysis.metrics import planner_metrics
from cdf_mj.config import CDFConfig, LayeredConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.presets import load_preset

SCENARIOS = ("default", "stop-and-wait", "slow-pull-out", "fast-ego")
VALUES = (0.1, 0.2, 0.35, 0.5)
PLANNERS = ("cdf", "imm-layered", "cv-layered")


def _point(out: Path, scenario: str, value: float, episodes: int, workers: int | None) -> dict:
    """The metrics per planner of one scenario at one threshold (run, or resumed)."""
    layers = LayeredConfig(anticipate=value, anticipate_release=value / 2)
    kwargs = {"planners": PLANNERS, "config": load_preset(scenario), "cdf": CDFConfig(layered=layers),
                  "planner_args": {p: {"layered": layers} for p in PLANNERS if p != "cdf"},
                  "workers": workers, "progress": False}
    path = out / scenario / f"{value:g}"
    result = run_experiment(path, range(episodes), resume=True, **kwargs)  # a fresh directory starts
    return planner_metrics(result)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tune_layers", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/tune_layers"), help="result directory")
    parser.add_argument("--episodes", type=int, default=200, help="development seeds from 0 (default 200)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: one per CPU)")
    args = parser.parse_args(argv)
    cells: dict[str, dict[float, dict[str, tuple[float, float, float, str]]]] = {
        p: {v: {} for v in VALUES} for p in PLANNERS}
    for scenario in SCENARIOS:
        for value in VALUES:
            print(f"{scenario}, anticipate = {value:g}", file=sys.stderr, flush=True)
            for planner, m in _point(args.out, scenario, value, args.episodes, args.workers).items():
                fa = m.false_alarms
                text = (f"{m.paper_avoided:.1%} ({m.imminent - m.collisions}/{m.imminent}), FA {fa.k}/{fa.n}, "
                        f"lost {m.time_lost:.2f} s")
                cells[planner][value][scenario] = (m.paper_avoided, fa.value, m.time_lost, text)
    for planner in PLANNERS:
        table = cells[planner]

        def key(v: float, table: dict = table) -> tuple[float, float, float, float]:
            c = table[v].values()
            n = len(c)
            return (min(x[0] for x in c), -sum(x[1] for x in c) / n, -sum(x[2] for x in c) / n, v)

        best = max(VALUES, key=key)
        print(f"\n### {planner}\n\n| anticipate | " + " | ".join(SCENARIOS) + " |")
        print("|---|" + "---|" * len(SCENARIOS))
        for v in VALUES:
            print(f"| {v:g} | " + " | ".join(table[v][s][3] for s in SCENARIOS) + " |")
        k = key(best)
        print(f"\nchosen for {planner}: anticipate = {best:g}, anticipate_release = {best / 2:g} (worst-scenario "
              f"avoided {k[0]:.1%}, mean false alarms {-k[1]:.1%}, mean time lost {-k[2]:.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
