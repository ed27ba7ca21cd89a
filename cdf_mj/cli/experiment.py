"""``cdf-mj experiment`` and ``cdf-mj reproduce``: run planners on the same seeds into a
result directory and print the paper's tables beside ours.

Both take the same options; ``reproduce`` is ``experiment`` with the paper's 1000 seeds.
The same command again continues an interrupted run (``--resume``, needed before, is
accepted and does nothing more), ``--force`` starts over.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cdf_mj.cli.args import (
    EXIT_FAILED_EPISODES,
    PROG,
    CLIError,
    add_cdf_arguments,
    add_format_argument,
    add_option,
    add_planner_option,
    add_run_arguments,
    cdf_from_args,
    command,
    config_from_args,
    episode_count,
    out_path,
    pool_from_args,
    seed_range,
    seed_value,
)
from cdf_mj.experiments.store import check_run_kind, locked
from cdf_mj.records import RECORDS_FILE

#: The one line that ``--resume`` prints on stderr (the option of earlier releases, now a no-op).
RESUME_NOTE = "--resume is no longer needed: the same command continues an interrupted run"

#: What an experiment directory holds of its run; ``--force`` removes these and nothing else.
RUN_FILES = (RECORDS_FILE, "settings.json")


def _cmd_experiment(args: argparse.Namespace) -> int:
    from cdf_mj.analysis.tables import experiment_tables
    from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment

    config = config_from_args(args)
    cdf = cdf_from_args(args, args.planners)
    seeds = seed_range(args.seed, args.episodes)
    if args.retry_failed and args.force:
        raise CLIError("--force starts over, so --retry-failed has nothing to retry: give one of them")
    pool = pool_from_args(args)
    if args.resume:  # a script written when continuing needed --resume: it gets what it asked for
        print(f"{PROG}: {RESUME_NOTE}", file=sys.stderr)
    if args.force:
        _remove_run(Path(args.out))
    try:  # resume: the same command again continues a run, or shows its tables if it is complete
        result = run_experiment(args.out, seeds, args.planners, config, cdf, args.scene,
                                progress=not args.quiet, resume=True, retry_failed=args.retry_failed, **pool)
    except SettingsMismatchError as exc:
        raise CLIError(f"{exc}, or give --force to replace them") from None
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; the finished episodes are saved in {args.out}/episodes.jsonl: "
              f"run the same command again to continue", file=sys.stderr)
        return 130
    what = f"{args.episodes} episodes from seed {args.seed}, planners {','.join(args.planners)}"
    if result.ran:
        resumed = f", {result.resumed} already on disk" if result.resumed else ""
        print(f"{what}: {result.ran} run in {result.wall_time:.1f} s on {result.workers} worker(s) "
              f"({result.backend}){resumed}; peak memory per worker {result.peak_worker_rss_mb:.0f} MiB; "
              f"records in {args.out}/episodes.jsonl\n")
    else:
        print(f"{what}: all {result.resumed} records were already in {args.out}/episodes.jsonl "
              f"(--force runs them again)\n")
    print(experiment_tables(result.records, fmt=args.format))
    if result.failed:
        print(f"{PROG}: {result.failed} of {len(result)} episodes failed; their records in "
              f"{args.out}/episodes.jsonl hold the error and traceback (\"status\": \"failed\")",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _remove_run(out: Path) -> None:
    """Remove the records and settings of the run in ``out`` (:data:`RUN_FILES`), under the
    directory's lock so that a run still using it is not pulled from under it; never those
    of another kind of run (a falsification's settings.json: ValueError naming it)."""
    if not out.is_dir():
        return
    with locked(out):
        check_run_kind(out, "experiment")
        for name in RUN_FILES:
            (out / name).unlink(missing_ok=True)


def _add_experiment_arguments(p: argparse.ArgumentParser, episodes: int, out: str) -> None:
    p.add_argument("--episodes", type=episode_count, default=episodes,
                   help=f"number of seeds, 1 to 10^7 (default {episodes})")
    add_option(p, "--seed", old=("--seed0",), type=seed_value, default=0,
               help="first seed: the run's seeds are --seed to --seed + --episodes - 1 (default 0)")
    add_planner_option(p, ["cdf", "reactive"], "comma-separated planners run on the same seeds (default "
                       "cdf,reactive)", several=True, old=("--planners",))
    p.add_argument("--out", type=out_path, default=out, help=f"result directory (default {out})")
    add_cdf_arguments(p)
    p.add_argument("--force", action="store_true",
                   help="start over: remove the records and settings of the run in --out (no other file)")
    p.add_argument("--resume", action="store_true",
                   help="no longer needed, accepted for earlier scripts: the same command continues an "
                        "interrupted run")
    p.add_argument("--retry-failed", action="store_true",
                   help="run the episodes of the run in --out that failed again")
    add_format_argument(p)
    add_run_arguments(p)
    p.set_defaults(func=_cmd_experiment)


def add_experiment(subparsers: argparse._SubParsersAction) -> None:
    """The ``experiment`` command."""
    p = command(
        subparsers, "experiment", compiles=True,
        summary="run planners on the same seeds; print the paper's tables beside ours",
        description="Run each planner on the same seeds, write one JSON line per episode and "
                    "planner to OUT/episodes.jsonl, and print the paper's two tables beside ours. "
                    "The same command again continues an interrupted run, or only prints the "
                    "tables of a finished one; other settings in the same OUT are refused.")
    _add_experiment_arguments(p, episodes=100, out="results/experiment")


def add_reproduce(subparsers: argparse._SubParsersAction) -> None:
    """The ``reproduce`` command: ``experiment`` with the paper's 1000 seeds."""
    p = command(
        subparsers, "reproduce", compiles=True, summary="the paper's experiment: 1000 episodes, CDF and reactive",
        description="The paper's experiment with the default settings: seeds 0-999, the CDF "
                    "(with its risk rule; --planner cdf-threshold,reactive for the paper's rule) "
                    "and the reactive planner on the same seeds, both tables. The same command "
                    "again continues an interrupted run, or only prints the tables of a finished one.")
    _add_experiment_arguments(p, episodes=1000, out="results/reproduce")
