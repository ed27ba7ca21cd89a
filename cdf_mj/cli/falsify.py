"""``cdf-mj falsify``: search a space of worlds for a planner's failures; ``cdf-mj
estimate``: its probability of failure per encounter (importance sampling or Monte Carlo)."""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
from typing import TYPE_CHECKING

from cdf_mj.cli.args import (
    EXIT_FAILED_EPISODES,
    PROG,
    CLIError,
    _command,
    _episodes,
    _int_in,
    _non_negative_int,
    _out_path,
    _planner_list,
    _workers,
)
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.sim.checks import read_names

if TYPE_CHECKING:
    from cdf_mj.falsify.search import Generation
    from cdf_mj.falsify.space import SearchSpace
from cdf_mj.sim.scene import DEFAULT_SCENE

_popsize = _int_in(2, 10_000, "candidates per generation")
_clusters = _int_in(1, 1000, "clusters minimised and written")


def _space(args: argparse.Namespace) -> SearchSpace:
    from cdf_mj.falsify.space import load_space

    if args.address is not None and args.backend != "ray":
        raise CLIError("--address is the address of a Ray cluster: it needs --backend ray")
    space = load_space(args.space)  # SpaceError: one line, exit 2
    if args.names is not None:  # a scene of your own with its own names (SceneError: one line)
        space = dataclasses.replace(space, base=space.base.replace(names=read_names(args.names)))
    return space


def _scene_args(args: argparse.Namespace) -> str:
    """``--scene``/``--names`` for the replay commands of the counterexamples (shell-quoted)."""
    words = ([] if args.scene == DEFAULT_SCENE else ["--scene", str(args.scene)]) + (
        [] if args.names is None else ["--names", str(args.names)])
    return shlex.join(words)


def _cmd_falsify(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cdf_mj.falsify.run import falsify

    space = _space(args)
    with tqdm(total=args.budget, unit="ep", desc=f"falsify {args.planner}", disable=args.quiet) as bar:
        def generation(g: Generation) -> None:
            bar.update(g.episodes - bar.n)
            bar.set_postfix(best=f"{g.best_so_far:.3g}", failures=g.failures_so_far)

        def counterexamples(failures: int) -> None:
            if failures and not args.quiet:
                bar.write(f"{failures} failures: clustering, minimising and replaying them")

        result = falsify(space, args.planner, args.budget, args.out, compare=args.compare or (), seed=args.seed,
                         popsize=args.popsize, scene=args.scene, backend=args.backend, workers=args.workers,
                         address=args.address, max_clusters=args.max_clusters, figure=not args.no_figure,
                         on_generation=generation, on_search_done=counterexamples, scene_args=_scene_args(args))
    s = result.search
    first = f"first after {s.first_failure} episodes" if s.first_failure else "none within the budget"
    print(f"{len(s.failures)} failures of {args.planner} ({space.failure.text}) in {len(s.evaluations)} episodes; "
          f"{first}; {len(result.counterexamples)} counterexamples")
    for i, c in enumerate(result.counterexamples, 1):
        traits = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in c.changed.items())
        print(f"  {i}. {len(c.members)} failures: {traits or 'the base world'} (seed {c.seed}): {c.path}")
    print(f"wrote {result.out / 'report.md'}, {result.out / 'summary.json'}")
    if result.errors:
        print(f"{PROG}: {len(result.errors)} episodes raised (counted as no failure; in the search, the "
              f"minimisation or the replays): {result.errors[0].error}; see {result.out / 'summary.json'}",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _cmd_estimate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cdf_mj.falsify.estimate import MIN_CE_BUDGET
    from cdf_mj.falsify.run import estimate

    space = _space(args)
    if args.method == "ce" and args.budget < MIN_CE_BUDGET:  # before a directory is made
        raise CLIError(f"--method ce needs --budget {MIN_CE_BUDGET} or more (an adaptive stage of 50 and a last "
                       f"stage), got {args.budget}; use --method mc below that")
    if args.stage is not None and args.method == "mc":
        raise CLIError("--stage is for --method ce (its adaptive stages); Monte Carlo has none")
    if args.stage is not None and args.stage > args.budget - args.budget // 5:
        raise CLIError(f"--stage {args.stage} leaves no adaptive stage before the last fifth of --budget "
                       f"{args.budget}: give at most {args.budget - args.budget // 5}")
    with tqdm(total=args.budget, unit="ep", desc=f"estimate {args.planner} ({args.method})",
              disable=args.quiet) as bar:
        result = estimate(space, args.planner, args.budget, args.out, method=args.method, seed=args.seed,
                          stage=args.stage, scene=args.scene, backend=args.backend, workers=args.workers,
                          address=args.address, on_episode=bar.update)
    how = "cross-entropy importance sampling" if result.method == "ce" else "Monte Carlo"
    ess = f"; effective sample size {result.ess:.1f}" if result.ess is not None else ""
    print(f"P({space.failure.text}) per encounter of {args.planner} on space {space.name}: {result.text()} "
          f"(95 %; {how}, {result.episodes} episodes, {result.failures} failures in the last {result.n}{ess})")
    print(f"wrote {args.out}/estimate.json")
    if result.errors:
        print(f"{PROG}: {result.errors} episodes raised (counted as no failure); see {args.out}/evaluations.jsonl",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _common(p: argparse.ArgumentParser, out: str, budget: int) -> None:
    from cdf_mj.falsify.space import space_names

    p.add_argument("--space", default="default", metavar="NAME|FILE",
                   help=f"the space: a shipped name ({', '.join(space_names())}) or a .toml file of your own "
                        "(docs/FALSIFICATION.md says the format) (default: default)")
    p.add_argument("--planner", choices=sorted(PLANNERS), default="cdf", help="the planner under test (default cdf)")
    p.add_argument("--budget", type=_episodes, default=budget, help=f"episodes, 1 to 10^7 (default {budget})")
    p.add_argument("--seed", type=_non_negative_int, default=0,
                   help="the run's seed: the same seed and settings give the same run (default 0)")
    p.add_argument("--out", type=_out_path, default=out,
                   help=f"output directory; the same command on it goes on where a run stopped (default {out})")
    p.add_argument("--scene", metavar="PATH", default=DEFAULT_SCENE, help="MJCF scene file (default scene.xml)")
    p.add_argument("--names", metavar="FILE", default=None,
                   help="the scene's element names: a .json or .toml object of SceneNames fields (docs/SCENES.md)")
    p.add_argument("--workers", type=_workers, default=None,
                   help="worker processes (default: the CPU count; 1 runs in this process)")
    p.add_argument("--backend", choices=("process", "ray"), default="process",
                   help="where episodes run: a process pool (default) or Ray")
    p.add_argument("--address", default=None, help="with --backend ray: an existing Ray cluster's address")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_falsify(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "falsify", compiles=True,
        summary="search a space of worlds for a planner's failures; counterexamples as presets",
        description="Search a declared space of worlds (driver family and traits, after-merge behaviour, the "
                    "ego's start, speed and sensing, ...) for episodes in which the planner fails, by CMA-ES "
                    "on a continuous robustness; cluster and minimise the failures, replay them on the "
                    "--compare planners, and write OUT/report.md, OUT/summary.json, OUT/progress.png and "
                    "OUT/counterexamples/NN-seed-S.toml (replay: cdf-mj episode --preset FILE --seed S). "
                    "Killed, the same command goes on.")
    _common(p, "results/falsify", 2000)
    p.add_argument("--compare", type=_planner_list, default=None,
                   help="comma-separated planners to replay the counterexamples on")
    p.add_argument("--popsize", type=_popsize, default=None,
                   help="the first generation's candidates (default CMA-ES's 4 + 3 ln d; doubled at each restart)")
    p.add_argument("--max-clusters", type=_clusters, default=12,
                   help="clusters of failures minimised and written (largest first; default 12)")
    p.add_argument("--no-figure", action="store_true", help="no progress figure (no matplotlib needed)")
    p.set_defaults(func=_cmd_falsify)


def _add_estimate(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "estimate", compiles=True,
        summary="a planner's probability of failure per encounter, with its interval",
        description="Estimate P(failure) per encounter under a space's nominal distribution: cross-entropy "
                    "importance sampling (--method ce: adaptive stages, then a defensive mixture; a 95 % "
                    "interval and the effective sample size) or plain Monte Carlo (--method mc: Wilson "
                    "interval). Writes OUT/estimate.json; killed, the same command goes on.")
    _common(p, "results/estimate", 4000)
    p.add_argument("--method", choices=("ce", "mc"), default="ce",
                   help="ce: cross-entropy importance sampling (default); mc: plain Monte Carlo")
    p.add_argument("--stage", type=_int_in(10, 10**6, "episodes per adaptive stage"), default=None,
                   help="ce: episodes per adaptive stage (default a fifth of the budget)")
    p.set_defaults(func=_cmd_estimate)
