"""``cdf-mj episode``: run one episode and print its record as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from cdf_mj.cli.args import _command, _non_negative_int, add_scenario_arguments, config_from_args, scene_from_args
from cdf_mj.experiments.store import json_default
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.scenario.episode import run_episode


def _print_json(obj: Any) -> None:
    # allow_nan=False: stdout is strict JSON or nothing (NaN is not JSON).
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=json_default) + "\n")


def _cmd_episode(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    scene = scene_from_args(args, config)
    record = run_episode(config, seed=args.seed, planner=args.planner, scene=scene,
                         label=args.label, trace=args.trace)
    _print_json(record.to_dict())
    return 0


def _add_episode(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "episode", compiles=True, summary="run one episode and print its record as JSON",
        description="Run one episode of the T-intersection scenario and print its record "
                    "as JSON on stdout. The same seed gives the same record.")
    p.add_argument("--seed", type=_non_negative_int, default=0,
                   help="episode seed, a non-negative integer (default: 0)")
    p.add_argument("--planner", choices=sorted(PLANNERS), default="reactive",
                   help="ego planner (default: reactive)")
    add_scenario_arguments(p)
    p.add_argument("--no-label", dest="label", action="store_false",
                   help="skip the counterfactual run that labels the episode Cutoff/Yield/Right")
    p.add_argument("--trace", action="store_true", help="include per-tick poses, modes and beliefs")
    p.set_defaults(func=_cmd_episode)
