#!/usr/bin/env python3
"""Choose the risk rule's braking threshold on the development seeds, by a rule fixed in advance.

The rule (docs/DECISION.md, written before any other seed was run): on seeds 0-199 of
the default scenario and of the presets in which the other driver's belief matters
(``stop-and-wait``, ``slow-pull-out``, ``fast-ego``), run the CDF with
``RiskConfig.brake`` in {0.05, 0.1, 0.2, 0.3, 0.5} (``release`` at half of it; latency
0.1 s, horizon 5 s and box margin 0.3 m fixed beforehand) and choose

1. the largest worst-scenario share of Cutoff episodes avoided, counted the paper's way
   ((imminent - collisions of any label) / imminent);
2. among those, the fewest false alarms per episode, averaged over the scenarios;
3. among those, the larger threshold.

Each point is a :func:`cdf_mj.experiments.sweep.run_sweep` point in ``OUT/SCENARIO/risk/VALUE``
(resumable). Prints a Markdown table and the choice::

    python scripts/tune_risk.py --out results/tune_risk
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cdf_mj.experiments.sweep import run_sweep
from cdf_mj.presets import load_preset
from cdf_mj.records import paper_avoided

SCENARIOS = ("default", "stop-and-wait", "slow-pull-out", "fast-ego")
VALUES = (0.05, 0.1, 0.2, 0.3, 0.5)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tune_risk", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/tune_risk"), help="result directory")
    parser.add_argument("--episodes", type=int, default=200, help="development seeds from 0 (default 200)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: one per CPU)")
    args = parser.parse_args(argv)
    table: dict[float, dict[str, tuple[float, float, str]]] = {v: {} for v in VALUES}
    for name in SCENARIOS:
        result = run_sweep("risk", args.out / name, range(args.episodes), planners=("cdf",), values=VALUES,
                           config=load_preset(name), workers=args.workers, figure=False)
        for row in result.rows:
            avoided = paper_avoided(int(row["imminent"]), int(row["collisions"]))
            cell = (f"{avoided:.1%} ({row['imminent'] - row['collisions']}/{row['imminent']}), "
                    f"FA {row['false_alarms_k']}/{row['false_alarms_n']}")
            table[float(row["value"])][name] = (avoided, float(row["false_alarms"]), cell)
    print("| brake | " + " | ".join(SCENARIOS) + " |")
    print("|---|" + "---|" * len(SCENARIOS))
    for v in VALUES:
        print(f"| {v:g} | " + " | ".join(table[v][s][2] for s in SCENARIOS) + " |")

    def key(v: float) -> tuple[float, float, float]:
        cells = table[v].values()
        return (min(c[0] for c in cells), -sum(c[1] for c in cells) / len(cells), v)

    best = max(VALUES, key=key)
    print(f"\nchosen: brake = {best:g}, release = {best / 2:g} (worst-scenario avoided {key(best)[0]:.1%}, "
          f"mean false alarms {-key(best)[1]:.1%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
