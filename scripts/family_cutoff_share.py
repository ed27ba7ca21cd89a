#!/usr/bin/env python3
"""Each obstacle driver family's share of Cutoff labels among left-turners, against the
``constant`` ego (it holds its speed) at the default start.

    python scripts/family_cutoff_share.py                          # seeds 0-199, every family
    python scripts/family_cutoff_share.py --seed 1000 --episodes 400 --family looked-but-failed,creeper
    python scripts/family_cutoff_share.py --set ego.speed=11.2     # another world, the same question

Every seed's obstacle turns left (``obstacle.p_left=1``); its label comes from the one
labelling rule (:func:`cdf_mj.scenario.episode.counterfactual`: Cutoff where the ego holding
its speed touches the obstacle before it is ``timing.label_distance`` past the conflict
point). Prints a Markdown table with 95 % Wilson intervals; docs/DRIVERS.md quotes it.
Bad input (an unknown family, a scene that cannot be loaded, a family whose extra is not
installed) is one line ``family_cutoff_share: error: ...`` and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import time

from cdf_mj.analysis.metrics import wilson_interval
from cdf_mj.analysis.pages import ScriptParser
from cdf_mj.cli import add_scenario_arguments, config_from_args
from cdf_mj.cli.args import CLIError, comma_list, episode_count, scene_from_args, seed_range, seed_value
from cdf_mj.config import DRIVER_FAMILIES
from cdf_mj.records import Label
from cdf_mj.scenario.episode import counterfactual

PROG = "family_cutoff_share"


def _family(text: str) -> str:
    if text not in DRIVER_FAMILIES:
        raise argparse.ArgumentTypeError(f"unknown family {text!r}: one of {', '.join(DRIVER_FAMILIES)}")
    return text


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seed", type=seed_value, default=0, help="first seed (default 0)")
    p.add_argument("--episodes", type=episode_count, default=200, help="seeds, from --seed on (default 200)")
    p.add_argument("--family", type=comma_list(_family, "families"),
                   default=[f for f in DRIVER_FAMILIES if f != "sumo"], metavar="F[,F...]",
                   help="obstacle.family values (default: every family but sumo, which needs its extra)")
    add_scenario_arguments(p)
    args = p.parse_args(argv)
    try:
        seeds = seed_range(args.seed, args.episodes)
        base = config_from_args(args)
        configs = {name: base.with_values({"obstacle.family": name, "obstacle.p_left": 1.0})
                   for name in args.family}
        scene = scene_from_args(args, base)
    except (CLIError, ValueError) as exc:  # SceneError and PresetError are ValueErrors: one line each
        p.error(str(exc))
    print(f"seeds {seeds.start}-{seeds.stop - 1}, every obstacle turning left, the constant ego\n")
    print("| family | Cutoff | share | 95 % interval | wall [s] |")
    print("|---|---:|---:|---|---:|")
    for name, config in configs.items():
        t0 = time.perf_counter()
        try:
            cut = sum(counterfactual(config, seed, scene)[0] == Label.CUTOFF.value for seed in seeds)
        except ImportError as exc:  # a family of an extra that is not installed (its hint names it)
            p.error(str(exc))
        lo, hi = wilson_interval(cut, len(seeds))
        print(f"| {name} | {cut}/{len(seeds)} | {cut / len(seeds):.0%} | {lo:.0%}-{hi:.0%} | "
              f"{time.perf_counter() - t0:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
