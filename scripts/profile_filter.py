#!/usr/bin/env python3
"""Where a particle-filter tick (or an episode) spends its time: cProfile shares.

Replays the measured poses of seed 1 (constant planner, a Cutoff) through
``ParticleFilter.predict`` / ``update`` and the risk rule's assessment of the filter's
futures (the benchmark's ticks), under cProfile, and prints
each stage's and each hot helper's share of the whole (cumulative time, so nested rows
overlap their parents), with its calls per tick. The figures of docs/PERFORMANCE.md
("Where the time goes") come from::

    taskset -c 0 python scripts/profile_filter.py --particles 1000 --replays 20

and ``--planner cdf`` profiles whole episodes of a planner instead (50 seeds, no
counterfactual) and prints the share of ``mj_step`` and of the functions with the most
time of their own (the old spelling ``--episode cdf`` still works, with a note)::

    taskset -c 0 python scripts/profile_filter.py --planner cdf

cProfile adds its own overhead to every Python call, so shares, not absolute times, are
what to read.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys

import numpy as np

from cdf_mj.cli.args import CLIError, add_option, notes
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.decision import RiskRule
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

# (module file, function) rows to report, in the order of a tick. The compiled kernels
# (kernels.py, conflict.py) show as one call each: cProfile cannot see inside them.
PF = "particle_filter.py"
ROWS = [
    (PF, "predict"), ("kernels.py", "predict"), (PF, "set_ego"),
    (PF, "update"), (PF, "weigh"), ("kernels.py", "weigh"), (PF, "posterior"), ("kernels.py", "posterior"),
    (PF, "resample"), ("kernels.py", "resample"),
    ("decision.py", "assess"), (PF, "futures"), ("kernels.py", "left_futures"), ("decision.py", "plans"),
    ("conflict.py", "ego_plans"), ("conflict.py", "collision_masses"),
]


PROG = "profile_filter"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, default=1000, help="N (default 1000)")
    parser.add_argument("--replays", type=int, default=20, help="replays of the episode (default 20)")
    add_option(parser, "--planner", old=("--episode",), metavar="PLANNER", default=None,
               help="profile 50 whole episodes of this planner instead")
    try:
        args = parser.parse_args(argv)
    except CLIError as exc:  # a flag and its old spelling together
        parser.error(str(exc))
    if args.particles < 1 or args.replays < 1:
        parser.error("--particles and --replays must be positive")
    status = _episodes(args.planner) if args.planner is not None else _ticks(args.particles, args.replays)
    for text in notes(args):  # old spellings, once the profile is printed
        print(f"{PROG}: note: {text}", file=sys.stderr)
    return status


def _ticks(particles: int, replays: int) -> int:
    """Profile the filter's ticks (``replays`` replays of seed 1 at ``particles``) and print the shares."""
    scene, cfg = Scene.load(), ScenarioConfig()
    poses = np.array(run_episode(cfg, 1, "constant", scene, trace=True).trace["poses"])
    pf = ParticleFilter.from_layout(scene.layout(), CDFConfig(n_particles=particles), np.random.default_rng(0),
                                    cfg.timing.dt)

    rule = RiskRule(CDFConfig().risk)
    rule.reset(PlannerContext.of(scene.layout(), cfg))

    def replay() -> None:
        for _ in range(replays):
            pf.reset(poses[0])
            for k in range(1, len(poses)):
                pf.predict(poses[k - 1])
                pf.update(poses[k])
                rule.assess(poses[k][0], pf.futures(rule.react_ticks))  # the cdf planner's decision

    replay()  # warm-up
    profiler = cProfile.Profile()
    profiler.enable()
    replay()
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # {(file, line, name): (cc, ncalls, tottime, cumtime, callers)}
    ticks = replays * (len(poses) - 1)
    cum: dict[tuple[str, str], tuple[int, float]] = {}
    for (path, _line, name), (_cc, ncalls, _tt, ct, _callers) in stats.items():
        key = (path.rsplit("/", 1)[-1], name)
        calls, total = cum.get(key, (0, 0.0))
        cum[key] = (calls + ncalls, total + ct)
    tick = cum[(PF, "predict")][1] + cum[(PF, "update")][1] + cum[("decision.py", "assess")][1]
    print(f"N = {particles}, {ticks} ticks; shares of predict + update + the risk rule's assessment "
          "(cumulative, nested rows overlap their parents)\n")
    print("| function | share of a tick | calls per tick |\n|---|---|---|")
    for key in ROWS:
        calls, total = cum.get(key, (0, 0.0))
        print(f"| {key[1]} ({key[0]}) | {100 * total / tick:.0f} % | {calls / ticks:.1f} |")
    return 0


def _episodes(planner: str, seeds: range = range(2000, 2050)) -> int:
    scene, cfg = Scene.load(), ScenarioConfig()
    run_episode(cfg, 1999, planner, scene, label=False)  # warm-up
    profiler = cProfile.Profile()
    profiler.enable()
    for seed in seeds:
        run_episode(cfg, seed, planner, scene, label=False)
    profiler.disable()
    stats = pstats.Stats(profiler)
    total = stats.total_tt
    own = sorted(((tt, name, path.rsplit("/", 1)[-1]) for (path, _l, name), (_cc, _nc, tt, _ct, _c)
                  in stats.stats.items()), reverse=True)
    print(f"{len(seeds)} episodes of {planner}; shares of the time of their own (tottime)\n")
    print("| function | share |\n|---|---|")
    for tt, name, where in own[:12]:
        print(f"| {name} ({where}) | {100 * tt / total:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
