"""``cdf-mj bench``: the timing table of docs/PERFORMANCE.md (physics, filter stages,
planners, startup, reproduction scaling)."""

from __future__ import annotations

import argparse

from cdf_mj.cli.args import (
    _comma_list,
    _command,
    _episodes,
    _particles,
    _shown,
    _workers,
    add_scenario_arguments,
    config_from_args,
)


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value <= 600.0):  # a timing run of 10 minutes at most
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, at most 600, got "
                                         f"{_shown(text)}")
    return value


def _cmd_bench(args: argparse.Namespace) -> int:
    from cdf_mj.experiments.bench import (
        bench_core,
        bench_env,
        bench_filter,
        bench_planners,
        bench_reproduction,
        bench_startup,
        format_rows,
        physics_floor,
    )

    sizes = tuple(args.particles)
    config = config_from_args(args)
    where = {"scene": args.scene, "config": config}
    floor = physics_floor(**where)  # every row's x floor, from this run
    rows = [] if args.only_reproduce else [*bench_core(args.episodes, floor=floor, **where),
                                           *bench_filter(sizes, **where),
                                           *bench_planners(args.episodes, **where),
                                           *bench_env(args.env_seconds, **where),
                                           *bench_startup()]
    if args.reproduce or args.only_reproduce:
        rows += bench_reproduction(args.reproduce_episodes, tuple(args.workers), progress=not args.quiet,
                                   **where)
    print(format_rows(rows, floor))
    return 0


def _add_bench(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "bench", compiles=True,
        summary="timing table: physics, filter stages, planners, startup, reproduction scaling",
        description="Print the benchmark table of docs/PERFORMANCE.md: medians from one run "
                    "(pin to one core with taskset -c 0 for the single-core rows), each beside its "
                    "ratio to the physics floor of the same run (x floor), and the startup of fresh "
                    "processes (Numba compiling or loading its cache, a cold cdf-mj episode).")
    p.add_argument("--episodes", type=_episodes, default=30,
                   help="episodes timed per planner (default 30)")
    p.add_argument("--particles", type=_comma_list(_particles, "positive integers"), default=[250, 1000, 10000],
                   help="filter sizes N to time, each 1 to 10^6, at most 100 of them (default 250,1000,10000)")
    p.add_argument("--env-seconds", type=_positive_seconds, default=1.0,
                   help="seconds of each of the 3 timed runs of the Gymnasium env per setting (default 1)")
    p.add_argument("--reproduce", action="store_true",
                   help="also time the paper's reproduction with each --workers count (minutes)")
    p.add_argument("--only-reproduce", action="store_true", help="only the reproduction rows")
    p.add_argument("--reproduce-episodes", type=_episodes, default=1000,
                   help="seeds in the timed reproduction (default 1000)")
    p.add_argument("--workers", type=_comma_list(_workers, "positive integers"), default=[1, 2],
                   help="worker counts for the reproduction (default 1,2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scenario_arguments(p)
    p.set_defaults(func=_cmd_bench)
