"""``cdf-mj bench``: the timing table of docs/PERFORMANCE.md (physics, filter stages,
planners, startup, reproduction scaling), every row timed in interleaved repeats against
the physics floor sampled between them, and the targets first.

``--particles N`` and ``--workers N`` mean what they mean elsewhere, one number (the
filter rows' size, the timed reproduction's workers); the scaling tables run over the
lists ``--scale-particles`` and ``--scale-workers``. A list given to ``--particles`` or
``--workers``, as earlier releases took it, still works, with a note."""

from __future__ import annotations

import argparse

from cdf_mj.cli.args import (
    CLIError,
    add_note,
    add_run_arguments,
    comma_list,
    command,
    config_from_args,
    episode_count,
    int_in,
    particle_count,
    shown,
    worker_count,
)

_repeats = int_in(1, 1000, "run time: every row runs that many times over")
_particle_counts = comma_list(particle_count, "positive integers")
_worker_counts = comma_list(worker_count, "positive integers")
#: The scaling lists' defaults.
SCALE_PARTICLES = (250, 1000, 10000)
SCALE_WORKERS = (1, 2)


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value <= 600.0):  # a timing run of 10 minutes at most
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, at most 600, got "
                                         f"{shown(text)}")
    return value


def _scale(args: argparse.Namespace, one: str, scale: str, default: tuple[int, ...]) -> tuple[int, ...]:
    """The list to time of ``--ONE N`` (one number; a list, as earlier releases took it,
    with a note) or ``--SCALE N1,N2,...`` (``one``, ``scale``: the namespace's names)."""
    given, listed = getattr(args, one), getattr(args, scale)
    flag, scale_flag = f"--{one}", f"--scale-{one}"
    if given is not None and listed is not None:
        raise CLIError(f"{flag}: not used with {scale_flag}; give one number with {flag} or a list with {scale_flag}")
    if given is not None and len(given) > 1:
        add_note(args, f"bench {flag} with a list is now {scale_flag} (the old spelling still works)")
    return tuple(given or listed or default)


def _cmd_bench(args: argparse.Namespace) -> int:
    from cdf_mj.experiments.bench import (
        DEFAULT_CLOCK,
        FloorProbe,
        bench_core,
        bench_env,
        bench_filter,
        bench_planners,
        bench_reproduction,
        bench_startup,
        format_rows,
    )
    from cdf_mj.falsify.throughput import bench_falsification

    sizes = _scale(args, "particles", "scale_particles", SCALE_PARTICLES)
    workers = _scale(args, "workers", "scale_workers", SCALE_WORKERS)
    config = config_from_args(args)
    where = {"scene": args.scene, "config": config}
    reps = args.repeats
    # The floor samples between every row's repeats, on the chosen clock.
    probe = FloorProbe(**where, clock=args.clock or DEFAULT_CLOCK)
    rows = [] if args.only_reproduce else [*bench_core(args.episodes, probe=probe, repeats=reps, **where),
                                           *bench_filter(sizes, 3 * reps, probe=probe, **where),
                                           *bench_planners(args.episodes, probe=probe, repeats=reps, **where),
                                           *bench_env(args.env_seconds, reps, probe=probe, **where),
                                           *bench_startup(probe=probe)]
    if args.reproduce or args.only_reproduce:
        rows += bench_reproduction(args.reproduce_episodes, workers, progress=not args.quiet,
                                   probe=probe, **where)
        rows.append(bench_falsification(args.falsify_episodes, probe=probe, **where))
    print(format_rows(rows, probe.floor()))
    return 0


def add_bench(subparsers: argparse._SubParsersAction) -> None:
    """The ``bench`` command."""
    p = command(
        subparsers, "bench", compiles=True,
        summary="timing table: physics, filter stages, planners, startup, reproduction scaling",
        description="Print the benchmark table of docs/PERFORMANCE.md, the targets first: every row timed in "
                    "repeats interleaved with floor samples (20 mj_step, one planner tick of physics), "
                    "reported as its least time, the median and spread, and its ratio to the least floor "
                    "sample taken between its repeats (x floor); under the table, a check that the floor "
                    "stayed under the physics-tick row. Times are CPU seconds of this process unless "
                    "--clock wall. Pin to one core with taskset -c 0 for the "
                    "single-core rows; the startup rows time fresh processes (Numba compiling or loading "
                    "its cache, a cold cdf-mj episode).")
    p.add_argument("--episodes", type=episode_count, default=10,
                   help="seeds of each episode row, timed --repeats times over (default 10)")
    p.add_argument("--repeats", type=_repeats, default=3,
                   help="interleaved repeats of a row: passes over the seeds of an episode row, runs of "
                        "--env-seconds of an env row; 3 x that many replays of a filter row, 100 x that "
                        "many calls of a physics or sight-line row (default 3)")
    p.add_argument("--clock", choices=("cpu", "wall"), default=None,
                   help="time with the CPU time of this process (the default where it ticks in microseconds or "
                        "finer: on a shared core, a row longer than a scheduler slice would otherwise count other "
                        "processes' turns) or wall time; the reproduction and cold-start rows are wall times "
                        "either way")
    p.add_argument("--particles", type=_particle_counts, default=None,
                   help="the CDF's particle count N: time the filter rows at this one size, 1 to 10^6 (several: "
                        "--scale-particles)")
    p.add_argument("--scale-particles", type=_particle_counts, default=None, metavar="N1,N2,...",
                   help="filter sizes N to time, each 1 to 10^6, at most 100 of them (default "
                        f"{','.join(map(str, SCALE_PARTICLES))})")
    p.add_argument("--env-seconds", type=_positive_seconds, default=1.0,
                   help="seconds of each of the --repeats timed runs of the Gymnasium env per setting "
                        "(default 1)")
    p.add_argument("--reproduce", action="store_true",
                   help="also time the paper's reproduction on --workers, or on each --scale-workers count, "
                        "and a falsification's Monte Carlo estimate on 2 workers (minutes)")
    p.add_argument("--only-reproduce", action="store_true",
                   help="only the reproduction rows (and the falsification throughput's)")
    p.add_argument("--reproduce-episodes", type=episode_count, default=1000,
                   help="seeds in the timed reproduction (default 1000)")
    p.add_argument("--falsify-episodes", type=episode_count, default=400,
                   help="episodes of the timed falsification estimate (with --reproduce; default 400)")
    p.add_argument("--workers", type=_worker_counts, default=None,
                   help="worker processes of the timed reproduction, 1 to 1024 (several: --scale-workers)")
    p.add_argument("--scale-workers", type=_worker_counts, default=None, metavar="N1,N2,...",
                   help="worker counts of the reproduction's scaling rows, each 1 to 1024, at most 100 of them "
                        f"(default {','.join(map(str, SCALE_WORKERS))})")
    add_run_arguments(p, pool=False)
    p.set_defaults(func=_cmd_bench)
