"""``cdf-mj sweep``: run the planners over a range of one setting; a table (CSV, Markdown)
and a figure per sweep."""

from __future__ import annotations

import argparse
import sys

from cdf_mj.cli.args import (
    EXIT_FAILED_EPISODES,
    MAX_LIST_ITEMS,
    PROG,
    CLIError,
    add_cdf_arguments,
    add_option,
    add_planner_option,
    add_run_arguments,
    cdf_from_args,
    comma_list,
    command,
    config_from_args,
    episode_count,
    out_path,
    pool_from_args,
    seed_range,
    seed_value,
    shown,
)
from cdf_mj.extras import install_hint

#: Most points of one sweep (each an experiment on every seed): the CLI's list bound.
MAX_SWEEP_VALUES = MAX_LIST_ITEMS


def _finite(text: str) -> float:
    """One swept value: a finite number (its range is the swept setting's, checked by its
    configuration)."""
    value = float(text)  # ValueError: not a number
    if not abs(value) < float("inf"):  # inf, nan; also a 400-digit number
        raise argparse.ArgumentTypeError(f"must be a finite number, got {shown(text)}")
    return value


#: ``--values``: comma-separated finite numbers, 1 to :data:`MAX_SWEEP_VALUES` of them.
_value_list = comma_list(_finite, "numbers")


def _cmd_sweep(args: argparse.Namespace) -> int:
    from cdf_mj.experiments.sweep import VizUnavailableError, run_sweep

    config = config_from_args(args)
    cdf = cdf_from_args(args, args.planners)
    seeds = seed_range(args.seed, args.episodes)
    pool = pool_from_args(args)
    if args.values is not None and len(args.sweeps) > 1:
        raise CLIError("--values applies to one sweep at a time; name a single sweep")
    if cdf.adaptive is not None and "particles" in args.sweeps:
        from cdf_mj.experiments.sweep_spec import SWEEPS

        low = min(args.values if args.values is not None else SWEEPS["particles"].values)
        if low < cdf.adaptive.n_min:
            raise CLIError(f"--adaptive-particles {cdf.adaptive.n_min} is more than the particle count {low:g} the "
                           "sweep of particles reaches (it sweeps the most the adaptive count may reach)")
    failed = []
    for name in args.sweeps:
        try:
            result = run_sweep(name, args.out, seeds, planners=args.planners, values=args.values, config=config,
                               cdf=cdf, scene=args.scene, progress=not args.quiet, figure=not args.no_figure,
                               **pool)
        except VizUnavailableError as exc:
            raise CLIError(f"{exc} (the tables are written; --no-figure skips the figure)") from None
        print(result.markdown + "\n")
        figure = f", {result.figure_path}" if result.figure_path else ""
        print(f"wrote {result.csv_path}, {result.markdown_path}{figure}\n")
        failed += [f"{name} = {f.value:g}: {f}" for f in result.failures]
    for line in failed:  # as `experiment` does: the run goes on, the status says it
        print(f"{PROG}: {line}", file=sys.stderr)
    if failed:
        print(f"{PROG}: the failed episodes are left out of the tables; their records hold the error and "
              "traceback (\"status\": \"failed\")", file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def add_sweep(subparsers: argparse._SubParsersAction) -> None:
    """The ``sweep`` command."""
    from cdf_mj.experiments.sweep import SWEEPS

    p = command(
        subparsers, "sweep", compiles=True,
        summary="run the planners over a range of one setting; table (CSV, Markdown) and figure",
        description="Sweep one setting (beta, particle count, threshold tau, noise levels) over "
                    "values, each point an experiment on the same seeds; write OUT/<sweep>.csv, "
                    "OUT/<sweep>.md and OUT/<sweep>.png. Finished points are reused. The figure "
                    f"needs matplotlib ({install_hint('viz')}).")
    p.add_argument("sweeps", nargs="+", choices=sorted(SWEEPS), metavar="SWEEP",
                   help=f"one or more of: {', '.join(SWEEPS)}")
    p.add_argument("--values", type=_value_list, default=None,
                   help="comma-separated values (one sweep only; default: the sweep's own)")
    p.add_argument("--episodes", type=episode_count, default=200, help="seeds per point, 1 to 10^7 (default 200)")
    add_option(p, "--seed", old=("--seed0",), type=seed_value, default=0,
               help="first seed: every point runs seeds --seed to --seed + --episodes - 1 (default 0)")
    add_planner_option(p, ["cdf", "reactive"], "comma-separated planners (default cdf,reactive)", several=True,
                       old=("--planners",))
    p.add_argument("--out", type=out_path, default="results/sweeps", help="output directory (default results/sweeps)")
    add_cdf_arguments(p, swept=True)
    p.add_argument("--no-figure", action="store_true", help="tables only (no matplotlib needed)")
    add_run_arguments(p)
    p.set_defaults(func=_cmd_sweep)
