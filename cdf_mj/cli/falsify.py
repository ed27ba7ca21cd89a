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
    add_note,
    add_option,
    add_planner_option,
    add_run_arguments,
    command,
    episode_count,
    int_in,
    out_path,
    parse_overrides,
    planner_list,
    pool_from_args,
    seed_value,
)
from cdf_mj.config.user_values import UserValueError, apply_values, flat_key_notes
from cdf_mj.presets import read_preset
from cdf_mj.sim.checks import read_names
from cdf_mj.sim.scene import DEFAULT_SCENE

if TYPE_CHECKING:
    from cdf_mj.falsify.search import Generation
    from cdf_mj.falsify.space import SearchSpace

_popsize = int_in(2, 10_000, "candidates per generation")
_clusters = int_in(1, 1000, "clusters minimised and written")


def _space(args: argparse.Namespace) -> SearchSpace:
    """The space of ``--space``, its base world changed by ``--preset``, ``--names`` and
    ``--set`` in that order (each dimension's ends checked against the new base)."""
    from cdf_mj.falsify.space import Range, load_space

    given: list[str] = []
    with flat_key_notes(lambda note: add_note(args, note)):  # as config_from_args reads them
        space = load_space(args.space)  # SpaceError: one line, exit 2
        base = space.base
        searched = {d.key for d in space.dims}
        if args.preset is not None:  # its fields over the space's own preset (PresetError: one line)
            chosen = read_preset(args.preset)
            base, given = chosen.config(base), ["--preset", args.preset]
            for key in sorted(searched & set(chosen.scenario)):
                add_note(args, f"--preset {args.preset} sets {key}, a dimension of the space: each episode's "
                               "point sets it; the preset's value is only what a minimised "
                               "counterexample falls back to")
        if args.names is not None:  # a scene of your own with its own names (SceneError: one line)
            base = base.replace(names=read_names(args.names))
        if args.overrides:
            values = parse_overrides(args.overrides)
            clash = sorted(searched & set(values))
            if clash:  # a value the search would overwrite in every episode
                raise CLIError(f"--set {clash[0]}: a dimension of the space {space.name!r} (the search sets "
                               "it); give it in the space's preset or drop it from the space")
            try:
                base = apply_values(base, values)
            except UserValueError as exc:  # the config names the field and its range
                raise CLIError(f"--set: {exc}") from None
            given += [w for item in args.overrides for w in ("--set", item)]
    for d in space.dims if base is not space.base else ():
        for x in (d.low, d.high) if isinstance(d, Range) else range(len(d.values)):
            value = d.value(float(x))
            try:
                base.with_values({d.key: value})
            except ValueError as exc:
                raise CLIError(f"--preset/--set: the space's dimension {d.key} = {value!r} gives a world the "
                               f"scenario refuses: {exc}") from None
    preset = f"{space.preset} with {shlex.join(given)}" if given else space.preset
    return dataclasses.replace(space, base=base, preset=preset)


def _scene_args(args: argparse.Namespace) -> str:
    """``--scene``/``--names`` for the replay commands of the counterexamples (shell-quoted)."""
    words = ([] if args.scene == DEFAULT_SCENE else ["--scene", str(args.scene)]) + (
        [] if args.names is None else ["--names", str(args.names)])
    return shlex.join(words)


def _estimated_rate(path: str | None, space: SearchSpace, planner: str) -> float | None:
    """P(failure) of an ``estimate`` run (its directory or its estimate.json) of the same
    space, planner and failure, for the first failure's comparison with Monte Carlo; one
    line (CLIError) for a file that cannot be read, of another run, or without a rate in
    (0, 1]."""
    if path is None:
        return None
    from pathlib import Path

    from cdf_mj.inputs import SETTINGS_MAX_BYTES, InputError, parse_json, read_text

    file = Path(path) / "estimate.json" if Path(path).is_dir() else Path(path)
    try:
        data = parse_json(read_text(file, "estimate file", SETTINGS_MAX_BYTES), f"estimate file {file}")
    except (InputError, ValueError, OSError) as exc:
        raise CLIError(f"--estimate {file}: {exc}") from None
    if not isinstance(data, dict):
        raise CLIError(f"--estimate: {file} is not an estimate (a JSON object with its 'p')")
    for key, want in (("space", space.name), ("planner", planner), ("failure", space.failure.text)):
        if data.get(key) != want:
            raise CLIError(f"--estimate: {file} is an estimate of {key} {data.get(key)!r}, this search's is "
                           f"{want!r}: give an estimate of the same space, planner and failure")
    p = data.get("p")
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not 1e-12 <= p <= 1.0:
        raise CLIError(f"--estimate: {file} holds no failure probability in [1e-12, 1] (its 'p' is {p!r}): give the "
                       "directory of a finished `cdf-mj estimate` that saw failures")
    return float(p)


def _cmd_falsify(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cdf_mj.falsify.run import falsify

    pool = pool_from_args(args)
    space = _space(args)
    rate = _estimated_rate(args.estimate, space, args.planner)
    with tqdm(total=args.episodes, unit="ep", desc=f"falsify {args.planner}", disable=args.quiet) as bar:
        def generation(g: Generation) -> None:
            bar.update(g.episodes - bar.n)
            bar.set_postfix(best=f"{g.best_so_far:.3g}", failures=g.failures_so_far)

        def counterexamples(failures: int) -> None:
            if failures and not args.quiet:
                bar.write(f"{failures} failures: clustering, minimising and replaying them")

        result = falsify(space, args.planner, args.episodes, args.out, compare=args.compare or (), seed=args.seed,
                         popsize=args.popsize, objective=args.objective, scene=args.scene,
                         max_clusters=args.max_clusters,
                         figure=not args.no_figure, on_generation=generation, on_search_done=counterexamples,
                         scene_args=_scene_args(args), **pool)
    s = result.search
    first = f"first after {s.first_failure} episodes" if s.first_failure else "none within the budget"
    if rate is not None:
        first += f" (Monte Carlo expects one in {1 / rate:.0f} at the estimated rate {rate:.3g})"
    print(f"{len(s.failures)} failures of {args.planner} ({space.failure.text}) in {len(s.evaluations)} episodes; "
          f"{first}; {len(result.counterexamples)} counterexamples")
    for i, c in enumerate(result.counterexamples, 1):
        traits = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in c.changed.items())
        print(f"  {i}. {len(c.members)} failures, log-likelihood {c.likeliest:.1f}: {traits or 'the base world'} "
              f"(seed {c.seed}): {c.path}")
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

    pool = pool_from_args(args)
    space = _space(args)
    n = args.episodes
    if args.method != "mc" and n < MIN_CE_BUDGET:  # before a directory is made
        raise CLIError(f"--method {args.method} needs --episodes {MIN_CE_BUDGET} or more (an adaptive stage of 50 "
                       "and a "
                       f"last stage), got {n}; use --method mc below that")
    if args.stage is not None and args.method == "mc":
        raise CLIError("--stage is for --method ce or mixture (their adaptive stages); Monte Carlo has none")
    if args.stage is not None and args.stage > n - n // 5:
        raise CLIError(f"--stage {args.stage} leaves no adaptive stage before the last fifth of --episodes "
                       f"{n}: give at most {n - n // 5}")
    with tqdm(total=n, unit="ep", desc=f"estimate {args.planner} ({args.method})",
              disable=args.quiet) as bar:
        result = estimate(space, args.planner, n, args.out, method=args.method, seed=args.seed,
                          stage=args.stage, scene=args.scene, on_episode=bar.update, **pool)
    how = {"ce": "cross-entropy importance sampling", "mixture": "cross-entropy importance sampling with a "
           "mixture of failure modes", "mc": "Monte Carlo"}[result.method]
    ess = f"; effective sample size {result.ess:.1f}" if result.ess is not None else ""
    print(f"P({space.failure.text}) per encounter of {args.planner} on space {space.name}: {result.text()} "
          f"(95 %; {how}, {result.episodes} episodes, {result.failures} failures in the last {result.n}{ess})")
    if result.p > 0:
        print(f"at this rate plain Monte Carlo expects its first failure after {1 / result.p:.0f} episodes")
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
    add_planner_option(p, "cdf", "the planner under test (default cdf)")
    add_option(p, "--episodes", old=("--budget",), type=episode_count, default=budget,
               help=f"the run's budget of episodes, 1 to 10^7 (default {budget})")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="the run's seed: the same seed and settings give the same run (default 0)")
    p.add_argument("--out", type=out_path, default=out,
                   help=f"output directory; the same command on it goes on where a run stopped (default {out})")
    add_run_arguments(p, preset_help="a scenario preset (cdf-mj presets lists them) or a .toml file whose "
                                     "fields apply over the space's own preset, the world the space varies; "
                                     "--set applies after it")


def add_falsify(subparsers: argparse._SubParsersAction) -> None:
    """The ``falsify`` command."""
    p = command(
        subparsers, "falsify", compiles=True,
        summary="search a space of worlds for a planner's failures; counterexamples as presets",
        description="Search a declared space of worlds (driver family and traits, after-merge behaviour, the "
                    "ego's start, speed and sensing, ...) for episodes in which the planner fails, by CMA-ES "
                    "on a continuous robustness from the space's nominal (its first generation is a nominal "
                    "sample); cluster and minimise the failures, list them likeliest first, replay them on the "
                    "--compare planners, and write OUT/report.md, OUT/summary.json, OUT/progress.png and "
                    "OUT/counterexamples/NN-seed-S.toml (replay: cdf-mj episode --preset FILE --seed S). "
                    "Killed, the same command goes on.")
    _common(p, "results/falsify", 2000)
    p.add_argument("--compare", type=planner_list, default=None, metavar="PLANNER[,PLANNER...]",
                   help="comma-separated planners to replay the counterexamples on, beside --planner")
    p.add_argument("--popsize", type=_popsize, default=None,
                   help="the first generation's candidates (default CMA-ES's 4 + 3 ln d; doubled at each restart)")
    p.add_argument("--objective", choices=("robustness", "likely"), default="robustness",
                   help="robustness: find failures (default); likely: then the likeliest failures under the "
                        "space's nominal (every counterexample carries its log-likelihood either way)")
    p.add_argument("--estimate", default=None, metavar="DIR|FILE",
                   help="a `cdf-mj estimate` run of the same space and planner: the first failure is printed "
                        "beside the episodes plain Monte Carlo expects at its rate")
    p.add_argument("--max-clusters", type=_clusters, default=12,
                   help="clusters of failures minimised and written (the largest are kept; they are listed "
                        "likeliest first; default 12)")
    p.add_argument("--no-figure", action="store_true", help="no progress figure (no matplotlib needed)")
    p.set_defaults(func=_cmd_falsify)


def add_estimate(subparsers: argparse._SubParsersAction) -> None:
    """The ``estimate`` command."""
    p = command(
        subparsers, "estimate", compiles=True,
        summary="a planner's probability of failure per encounter, with its interval",
        description="Estimate P(failure) per encounter under a space's nominal distribution: cross-entropy "
                    "importance sampling (--method ce: adaptive stages, then a defensive mixture; a 95 % "
                    "interval and the effective sample size) or plain Monte Carlo (--method mc: Wilson "
                    "interval). Writes OUT/estimate.json; killed, the same command goes on.")
    _common(p, "results/estimate", 4000)
    p.add_argument("--method", choices=("ce", "mixture", "mc"), default="ce",
                   help="ce: cross-entropy importance sampling (default); mixture: the same with a mixture "
                        "proposal, one component per failure mode (for a planner that fails in several ways); "
                        "mc: plain Monte Carlo")
    p.add_argument("--stage", type=int_in(10, 10**6, "episodes per adaptive stage"), default=None,
                   help="ce, mixture: episodes per adaptive stage (default a fifth of --episodes)")
    p.set_defaults(func=_cmd_estimate)
