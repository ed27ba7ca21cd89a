"""``cdf-mj episode``: run one episode and print its record as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from cdf_mj.cli.args import (
    add_planner_option,
    add_run_arguments,
    command,
    config_from_args,
    scene_from_args,
    seed_value,
)
from cdf_mj.experiments.store import json_default
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


def add_episode(subparsers: argparse._SubParsersAction) -> None:
    """The ``episode`` command."""
    p = command(
        subparsers, "episode", compiles=True, summary="run one episode and print its record as JSON",
        description="Run one episode of the T-intersection scenario and print its record "
                    "as JSON on stdout. The same seed gives the same record.")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="episode seed, a non-negative integer (default: 0)")
    add_planner_option(p, "reactive", "ego planner (default: reactive)")
    add_run_arguments(p, pool=False, progress=False)
    p.add_argument("--no-label", dest="label", action="store_false",
                   help="skip the counterfactual run that labels the episode Cutoff/Yield/Right")
    p.add_argument("--trace", action="store_true", help="include per-tick poses, modes and beliefs")
    p.set_defaults(func=_cmd_episode)
