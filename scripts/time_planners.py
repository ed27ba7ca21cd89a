#!/usr/bin/env python3
"""Planners timed against each other on the same seeds, in alternation, in one process.

Each round runs every planner on every seed (the order of the planners reversed on odd
rounds, so that neither is always first on a warm cache); the median CPU time per tick of
each planner is printed, with its ratio to the first planner and to ``constant`` (the
physics floor: the same world with no planner's work), measured in the same run::

    python scripts/time_planners.py --planner cdf,cdf-option --episodes 30 --rounds 3

Seeds from ``--seed`` (default 700000, a range no page uses). Bad input is one line
``time_planners: error: ...`` and exit status 2.
"""

from __future__ import annotations

import statistics
import sys
import time

from cdf_mj.analysis.pages import ScriptParser, fail
from cdf_mj.config import ScenarioConfig
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

PROG = "time_planners"


def main(argv: list[str] | None = None) -> int:
    parser = ScriptParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", default="cdf,cdf-option", help="planners, comma-separated (first: the base)")
    parser.add_argument("--seed", type=int, default=700000, help="first seed (default 700000)")
    parser.add_argument("--episodes", type=int, default=30, help="seeds per round (default 30)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds, alternating the order (default 3)")
    args = parser.parse_args(argv)
    planners = [p for p in args.planner.split(",") if p]
    unknown = [p for p in planners if p not in PLANNERS]
    if not planners or unknown:
        fail(PROG, f"unknown planner(s) {', '.join(unknown) or '(none given)'}: choose from {', '.join(PLANNERS)}")
    if args.seed < 0 or not 1 <= args.episodes <= 10_000 or not 1 <= args.rounds <= 100:
        fail(PROG, "--seed must be >= 0, --episodes in [1, 10000], --rounds in [1, 100]")
    names = [*planners, *(["constant"] if "constant" not in planners else [])]
    scene, config = Scene.load(), ScenarioConfig()
    for name in names:  # compile before timing
        run_episode(config, args.seed, name, scene, label=False)
    per_tick: dict[str, list[float]] = {name: [] for name in names}
    for rnd in range(args.rounds):
        order = names if rnd % 2 == 0 else names[::-1]
        for seed in range(args.seed, args.seed + args.episodes):
            for name in order:
                start = time.process_time()
                record = run_episode(config, seed, name, scene, label=False)
                ticks = max(int((record.safety or {}).get("ticks") or 1), 1)
                per_tick[name].append((time.process_time() - start) / ticks)
    median = {name: statistics.median(values) for name, values in per_tick.items()}
    base, floor = median[planners[0]], median["constant"]
    print(f"seeds {args.seed}-{args.seed + args.episodes - 1}, {args.rounds} rounds; median CPU time per tick:")
    for name in names:
        print(f"  {name:<16} {1e3 * median[name]:.3f} ms   x{median[name] / base:.2f} of {planners[0]}   "
              f"x{median[name] / floor:.2f} of the physics floor (constant)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
