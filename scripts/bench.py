#!/usr/bin/env python3
"""Print the benchmark table (medians from one run) for docs/PERFORMANCE.md.

    python scripts/bench.py [--episodes 60] [--filter]
"""

from __future__ import annotations

import argparse
import sys

from cdf_mj.bench import bench_core, bench_filter, format_rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=60, help="episodes timed per planner")
    p.add_argument("--filter", action="store_true",
                   help="also time the particle filter stage by stage and a CDF episode")
    args = p.parse_args(argv)
    rows = bench_core(args.episodes)
    if args.filter:
        rows += bench_filter()
    print(format_rows(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
