#!/usr/bin/env python3
"""Each obstacle driver family's share of Cutoff labels among left-turners, against the
``constant`` ego (it holds its speed) at the default start.

    python scripts/family_cutoff_share.py                          # seeds 0:200, every family
    python scripts/family_cutoff_share.py --seeds 1000:1400 --families looked-but-failed creeper
    python scripts/family_cutoff_share.py --set ego.speed=11.2     # another world, the same question

Every seed's obstacle turns left (``obstacle.p_left=1``); its label comes from the one
labelling rule (:func:`cdf_mj.scenario.episode.counterfactual`: Cutoff where the ego holding
its speed touches the obstacle before it is ``timing.label_distance`` past the conflict
point). Prints a Markdown table with 95 % Wilson intervals; docs/DRIVERS.md quotes it.
"""

from __future__ import annotations

import argparse
import sys
import time

from cdf_mj.analysis.metrics import wilson_interval
from cdf_mj.cli import add_scenario_arguments, config_from_args
from cdf_mj.records import Label
from cdf_mj.scenario.drivers import FAMILIES
from cdf_mj.scenario.episode import counterfactual
from cdf_mj.sim.scene import Scene


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
    p.add_argument("--seeds", type=_seed_range, default=range(0, 200), help="START:STOP (default 0:200)")
    p.add_argument("--families", nargs="+", default=["model", *FAMILIES], metavar="NAME",
                   help="obstacle.family values (default: model and every family of cdf_mj.scenario.drivers)")
    add_scenario_arguments(p)
    args = p.parse_args(argv)
    try:
        base = config_from_args(args)
        configs = {name: base.with_values({"obstacle.family": name, "obstacle.p_left": 1.0})
                   for name in args.families}
    except ValueError as exc:
        p.error(str(exc))
    scene = Scene.load(args.scene, names=base.names)
    seeds = args.seeds
    print(f"seeds {seeds.start}:{seeds.stop}, every obstacle turning left, the constant ego\n")
    print("| family | Cutoff | share | 95 % interval | wall [s] |")
    print("|---|---:|---:|---|---:|")
    for name, config in configs.items():
        t0 = time.perf_counter()
        cut = sum(counterfactual(config, seed, scene)[0] == Label.CUTOFF.value for seed in seeds)
        lo, hi = wilson_interval(cut, len(seeds))
        print(f"| {name} | {cut}/{len(seeds)} | {cut / len(seeds):.0%} | {lo:.0%}-{hi:.0%} | "
              f"{time.perf_counter() - t0:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
