#!/usr/bin/env python3
"""Print the benchmark table (medians from one run) for docs/PERFORMANCE.md.

    python scripts/bench.py [--episodes 60]
"""

from __future__ import annotations

import argparse
import sys

from cdf_mj.bench import bench_core, format_rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=60, help="episodes timed per planner")
    args = p.parse_args(argv)
    print(format_rows(bench_core(args.episodes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
