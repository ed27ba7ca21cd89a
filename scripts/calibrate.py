#!/usr/bin/env python3
"""Scenario calibration check: label shares and reactive avoidance for a seed range.

    python scripts/calibrate.py --seeds 0:1000
    python scripts/calibrate.py --seeds 100000:100500 --planner reactive --set obstacle.beta=0.1

Prints a Markdown table with 95 % Wilson intervals beside the paper's figures.
"""

from __future__ import annotations

import argparse
import sys
import time

from cdf_mj.analysis.metrics import scenario_summary
from cdf_mj.analysis.tables import format_scenario_summary
from cdf_mj.cli import add_scenario_arguments, config_from_args
from cdf_mj.experiments.experiment import run_many


def _seed_range(text: str) -> range:
    try:
        lo, hi = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START:STOP, got {text!r}") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"expected 0 <= START < STOP, got {text!r}")
    return range(lo, hi)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=_seed_range, default=range(0, 1000), help="START:STOP (default 0:1000)")
    p.add_argument("--planner", default="reactive")
    add_scenario_arguments(p)
    args = p.parse_args(argv)
    try:
        config = config_from_args(args)
    except ValueError as exc:
        p.error(str(exc))
    t0 = time.perf_counter()
    records = run_many(args.seeds, args.planner, config, args.scene)
    wall = time.perf_counter() - t0
    print(f"seeds {args.seeds.start}:{args.seeds.stop}, planner {args.planner}, {wall:.1f} s\n")
    print(format_scenario_summary(scenario_summary(records), args.planner))
    return 0


if __name__ == "__main__":
    sys.exit(main())
