#!/usr/bin/env python3
"""Where a planner's tick goes, function by function, in whole episodes (wall time).

Wraps the functions of one tick (the world's step and physics, the planner's observe and
command, the CDF filter's stages, the layered rule's rolls and follow layer) with a timer
each, runs episodes of a planner (no counterfactual) and prints each function's time per
tick, inclusive of what it calls (nested rows overlap)::

    taskset -c 1 python scripts/tick_breakdown.py cdf            # 20 episodes, seeds 2000-2019
    python scripts/tick_breakdown.py imm-layered --episodes 10
    python scripts/tick_breakdown.py cdf --particles 250         # the CDF with another particle count

The timers add about half a microsecond a call; cProfile's shares are in
``scripts/profile_filter.py --planner PLANNER``. Bad arguments are one line
``tick_breakdown: error: ...`` and exit status 2.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

from cdf_mj.cli.args import particle_count
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.registry import PLANNERS, make_planner
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

# (module, class, method): what one tick calls, outermost first.
_TIMED = (("cdf_mj.scenario.world", "World", "step"), ("cdf_mj.sim.scene", "Scene", "step"),
          ("cdf_mj.scenario.ego_agent", "EgoAgent", "act"),
          ("cdf_mj.scenario.obstacle_agent", "ObstacleAgent", "act"),
          ("cdf_mj.planners.base", "DecidingPlanner", "command"), ("cdf_mj.planners.cdf", "CDFPlanner", "observe"),
          ("cdf_mj.inference.particle_filter", "ParticleFilter", "predict"),
          ("cdf_mj.inference.particle_filter", "ParticleFilter", "weigh"),
          ("cdf_mj.inference.particle_filter", "ParticleFilter", "posterior"),
          ("cdf_mj.inference.particle_filter", "ParticleFilter", "resample"),
          ("cdf_mj.inference.particle_filter", "ParticleFilter", "futures"),
          ("cdf_mj.planners.decision", "LayeredRule", "command"),
          ("cdf_mj.planners.decision", "LayeredRule", "layers_of"),
          ("cdf_mj.planners.decision", "LayeredRule", "_follow"),
          ("cdf_mj.planners.decision", "RiskRule", "assess"))


def _wrap(totals: dict[str, float], module: str, owner: str, name: str) -> None:
    cls = getattr(importlib.import_module(module), owner)
    fn: Callable[..., Any] = cls.__dict__[name]
    key = f"{owner}.{name}"

    @functools.wraps(fn)
    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[key] += time.perf_counter() - t0

    setattr(cls, name, timed)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="tick_breakdown", description=__doc__.split("\n\n")[0])
    parser.add_argument("planner", help="a registered planner, e.g. cdf")
    parser.add_argument("--episodes", type=int, default=20, help="episodes timed, seeds 2000 on (default 20)")
    parser.add_argument("--particles", type=particle_count, default=None,
                        help="a CDF planner's particle count (default its own)")
    args = parser.parse_args(argv)
    if args.planner not in PLANNERS:
        parser.error(f"unknown planner {args.planner!r}; one of {', '.join(sorted(PLANNERS))}")
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")

    def planner() -> Any:
        made = make_planner(args.planner)
        if args.particles is None:
            return made
        if not isinstance(made, CDFPlanner):
            parser.error(f"--particles: {args.planner!r} is not a CDF planner")
        return type(made)(made.cdf.replace(n_particles=args.particles))  # each CDF planner keeps its rule

    totals: dict[str, float] = defaultdict(float)
    for where in _TIMED:
        _wrap(totals, *where)
    scene = Scene.load()
    run_episode(None, 1999, planner(), scene, label=False)  # warm-up (and compiling)
    totals.clear()
    ticks, t0 = 0, time.perf_counter()
    for i in range(args.episodes):
        record = run_episode(None, 2000 + i, planner(), scene, label=False)
        ticks += max(round(record.end_time / 0.1), 1)
    wall = time.perf_counter() - t0
    print(f"{args.planner}: {1e6 * wall / ticks:.0f} µs a tick over {ticks} ticks of {args.episodes} episodes\n")
    print("| function (inclusive) | µs a tick |\n|---|---|")
    for key, sec in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"| {key} | {1e6 * sec / ticks:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
