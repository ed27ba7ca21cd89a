#!/usr/bin/env python3
"""Print the benchmark table of docs/PERFORMANCE.md: the targets, then every row, each
timed in repeats interleaved with the physics floor (least time, spread, x floor).

The same as ``cdf-mj bench``; see ``cdf-mj bench --help``::

    taskset -c 0 python scripts/bench.py               # single-core rows
    python scripts/bench.py --only-reproduce           # reproduction with 1 and 2 workers
"""

from __future__ import annotations

import sys

from cdf_mj.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
