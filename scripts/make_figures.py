#!/usr/bin/env python3
"""Regenerate every figure under ``docs/img`` with the commands the docs print.

One command remakes the pictures of README.md, docs/RESULTS.md, docs/ANALYSIS.md, docs/DECISION.md
and docs/FALSIFY.md::

    python scripts/make_figures.py                        # everything, a few minutes on 2 cores
    python scripts/make_figures.py --only report,gif      # some groups
    python scripts/make_figures.py --dry-run              # print the commands, run nothing

Each group runs ``cdf-mj`` commands (printed as ``$ cdf-mj ...`` before they run, in this
process through :func:`cdf_mj.cli.main`), so a figure is always the one its documented
command makes:

============  ============================================================================
group         writes (under ``--docs``, default ``docs/img``)
============  ============================================================================
``report``    ``report/*.png`` and ``report/report.md``: ``cdf-mj experiment`` (cdf and
              reactive, ``--episodes`` seeds from 0) then ``cdf-mj report``
``analysis``  ``analysis/{dev,heldout}/{brake_times,brier_over_time}.png``: the four
              planners on ``--analysis-episodes`` seeds from 0 (dev) and from 100000
              (held out), then :func:`cdf_mj.experiments.sweep.comparison_figures`
``sweeps``    ``analysis/{tau,beta,noise,obs-noise,particles}.png``: ``cdf-mj sweep`` on
              ``--sweep-episodes`` seeds per point
``frame``     ``frame.png``: seed 1, the CDF, the default view at 3.0 s, 480 x 360
``gif``       ``episode.gif``: the first 4 s of seed 1 with the CDF, 320 x 240 at 10
              frames/s (the README's top picture)
``decision``  ``decision/{anticipate,emergency,follow}.png``: one picture per layer of the
              layered rule (docs/DECISION.md), ``python scripts/decision_figures.py``; and
              ``decision/option_{waits,right,brakes,rss}.png``, one per behaviour of the option
              rule, ``python scripts/option_figures.py``
``pareto``    ``decision/pareto.png``: every planner's trade-off on the held-out seeds,
              ``python scripts/decision.py --tuning results/tune_option`` (which remakes
              docs/DECISION_RESULTS.md with it: about half an hour on 2 cores)
``frontier``  ``frontier/frontier.png``: the option rule's thresholds against issue 35's
              targets, ``python scripts/option_frontier.py`` (which remakes
              docs/FRONTIER.md with it: about 12 minutes on 2 cores, seconds after)
``falsify``   ``falsify/progress.png``: the falsification page's searches,
              ``python scripts/falsify.py`` (which remakes docs/FALSIFY.md with it: about 45
              minutes on 2 cores the first time, seconds from its results after)
============  ============================================================================

Experiment directories go under ``--results`` (default ``results/figures``) and are
reused: the same command again only redraws (``cdf-mj experiment`` resumes; finished
sweep points are kept). After a change to the simulation, the filter or a planner, run
with ``--fresh`` so that no record of the old code is drawn. The docs' tables come from
the larger runs their pages describe; the seed counts here are smaller where a figure
needs many episodes, and each figure's caption in the docs says which.

Bad input is one line ``make_figures: error: ...`` and exit status 2; a command that fails
stops the script with its exit status.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

PROG = "make_figures"
# The renderer's last.
GROUPS = ("report", "analysis", "sweeps", "decision", "pareto", "frontier", "falsify", "frame", "gif")
DECISION_PICTURES = ("anticipate", "emergency", "follow")  # scripts/decision_figures.py's
OPTION_PICTURES = ("option_waits", "option_right", "option_brakes", "option_rss")  # scripts/option_figures.py's
ANALYSIS_PLANNERS = "cdf,reactive,cv,imm"
ANALYSIS_SEED0 = {"dev": 0, "heldout": 100000}  # docs/ANALYSIS.md: seeds 0-999 and 100000-100999
SWEEPS = ("tau", "beta", "noise", "obs-noise")  # all four planners; particles: the CDF only


class CommandFailed(RuntimeError):
    """A ``cdf-mj`` command returned a non-zero exit status."""

    def __init__(self, argv: Sequence[str], status: int, program: str = "cdf-mj") -> None:
        super().__init__(f"`{program} {shlex.join(argv)}` exited with status {status}")
        self.status = status


@dataclass(frozen=True)
class Options:
    """The parsed command line."""

    docs: Path
    results: Path
    episodes: int
    analysis_episodes: int
    sweep_episodes: int
    workers: int | None
    fresh: bool
    dry_run: bool


def cdf_mj(argv: list[str], opts: Options) -> None:
    """Print ``$ cdf-mj ARGV`` and run it in this process; :class:`CommandFailed` on a
    non-zero exit status."""
    print(f"$ cdf-mj {shlex.join(argv)}", flush=True)
    if opts.dry_run:
        return
    from cdf_mj.cli import main

    status = main(argv)
    if status:
        raise CommandFailed(argv, status)


def _workers(opts: Options) -> list[str]:
    return [] if opts.workers is None else ["--workers", str(opts.workers)]


def _experiment(out: Path, episodes: int, seed0: int, planners: str, opts: Options) -> None:
    cdf_mj(["experiment", "--episodes", str(episodes), "--seed", str(seed0), "--planner", planners,
            "--out", str(out), "--quiet", *_workers(opts), *(["--force"] if opts.fresh else [])], opts)


def make_report(opts: Options) -> None:
    """docs/img/report: the figures of ``cdf-mj report`` for seeds 0..episodes-1."""
    out = opts.results / f"report{opts.episodes}"
    _experiment(out, opts.episodes, 0, "cdf,reactive", opts)
    cdf_mj(["report", str(out), "--out", str(opts.docs / "report")], opts)


def make_analysis(opts: Options) -> None:
    """docs/img/analysis/{dev,heldout}: brake times and Brier scores of the four planners."""
    for kind, seed0 in ANALYSIS_SEED0.items():
        out = opts.results / "analysis" / kind
        _experiment(out, opts.analysis_episodes, seed0, ANALYSIS_PLANNERS, opts)
        target = opts.docs / "analysis" / kind
        print(f">>> comparison_figures(load_records({str(out)!r}), {str(target)!r})", flush=True)
        if not opts.dry_run:
            from cdf_mj.experiments.sweep import comparison_figures
            from cdf_mj.records import load_records

            comparison_figures(load_records(out), target)


def make_sweeps(opts: Options) -> None:
    """docs/img/analysis/<sweep>.png: each sweep's figure, copied from its output directory."""
    out = opts.results / f"sweeps{opts.sweep_episodes}"
    if opts.fresh and not opts.dry_run and out.exists():
        shutil.rmtree(out)
    common = ["--episodes", str(opts.sweep_episodes), "--out", str(out), "--quiet", *_workers(opts)]
    cdf_mj(["sweep", *SWEEPS, "--planner", ANALYSIS_PLANNERS, *common], opts)
    cdf_mj(["sweep", "particles", "--planner", "cdf", *common], opts)
    for name in (*SWEEPS, "particles"):
        src, dst = out / f"{name}.png", opts.docs / "analysis" / f"{name}.png"
        print(f">>> copy {src} -> {dst}", flush=True)
        if not opts.dry_run:
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dst)


def python_script(argv: Sequence[str], writes: str, opts: Options) -> None:
    """Run ``python scripts/NAME.py ARGS`` (``argv``) as its own process, printed first with
    what it ``writes``; CommandFailed with its exit status if it fails."""
    print(f"$ python {shlex.join(argv)}  # {writes}", flush=True)
    if opts.dry_run:
        return
    script = Path(__file__).resolve().with_name(Path(argv[0]).name)
    status = subprocess.run([sys.executable, str(script), *argv[1:]], check=False).returncode
    if status:
        raise CommandFailed(list(argv), status, program="python")


def make_decision(opts: Options) -> None:
    """docs/img/decision: one picture per layer of the layered rule (scripts/decision_figures.py)
    and one per behaviour of the option rule (scripts/option_figures.py)."""
    out = opts.docs / "decision"
    python_script(["scripts/decision_figures.py", "--out", str(out)],
                  ", ".join(str(out / f"{n}.png") for n in DECISION_PICTURES), opts)
    python_script(["scripts/option_figures.py", "--out", str(out)],
                  ", ".join(str(out / f"{n}.png") for n in OPTION_PICTURES), opts)


def make_pareto(opts: Options) -> None:
    """docs/img/decision/pareto.png: written by the decision page's script, which remakes
    docs/DECISION_RESULTS.md from the same runs (with the tuning points of
    results/tune_option where scripts/tune_option.py has run)."""
    figure = opts.docs / "decision" / "pareto.png"
    python_script(["scripts/decision.py", "--figure", str(figure), "--tuning", "results/tune_option",
                   *_workers(opts)], f"{figure} and docs/DECISION_RESULTS.md", opts)


def make_frontier(opts: Options) -> None:
    """docs/img/frontier/frontier.png: written by the frontier page's script, which remakes
    docs/FRONTIER.md from the same runs."""
    figure = opts.docs / "frontier" / "frontier.png"
    python_script(["scripts/option_frontier.py", "--figure", str(figure), *_workers(opts)],
                  f"{figure} and docs/FRONTIER.md", opts)


def make_falsify(opts: Options) -> None:
    """docs/img/falsify/progress.png: written by the falsification page's script, which
    remakes docs/FALSIFY.md from the same runs."""
    figure = opts.docs / "falsify" / "progress.png"
    python_script(["scripts/falsify.py", "--figure", str(figure), "--quiet", *_workers(opts)],
                  f"{figure} and docs/FALSIFY.md", opts)


def make_frame(opts: Options) -> None:
    """docs/img/frame.png: one rendered frame (needs an OpenGL backend: EGL or OSMesa)."""
    cdf_mj(["render", "--seed", "1", "--planner", "cdf", "--frame", "3.0", "--width", "480",
            "--height", "360", "--out", str(opts.docs / "frame.png")], opts)


def make_gif(opts: Options) -> None:
    """docs/img/episode.gif: the README's top picture, a few hundred KB."""
    cdf_mj(["render", "--seed", "1", "--planner", "cdf", "--set", "timing.duration=4.0", "--width", "320",
            "--height", "240", "--fps", "10", "--out", str(opts.docs / "episode.gif")], opts)


MAKERS: dict[str, Callable[[Options], None]] = {
    "report": make_report, "analysis": make_analysis, "sweeps": make_sweeps, "decision": make_decision,
    "pareto": make_pareto, "frontier": make_frontier,
    "falsify": make_falsify, "frame": make_frame, "gif": make_gif,
}


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The command line (see the module docstring)."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0] if __doc__ else None,
                                epilog="groups: " + ", ".join(GROUPS))
    p.add_argument("--only", default=",".join(GROUPS),
                   help=f"comma-separated groups to make, in this order: {', '.join(GROUPS)} (default all)")
    p.add_argument("--docs", type=Path, default=Path("docs/img"), help="where figures go (default docs/img)")
    p.add_argument("--results", type=Path, default=Path("results/figures"),
                   help="where experiment directories go (default results/figures)")
    p.add_argument("--episodes", type=_positive, default=200,
                   help="seeds of the report's experiment, from 0 (default 200)")
    p.add_argument("--analysis-episodes", type=_positive, default=100,
                   help="seeds of each dev / held-out run of the four planners (default 100)")
    p.add_argument("--sweep-episodes", type=_positive, default=40, help="seeds per sweep point (default 40)")
    p.add_argument("--workers", type=_positive, default=None,
                   help="worker processes per experiment (default: the CPU count)")
    p.add_argument("--fresh", action="store_true",
                   help="run every experiment again instead of reusing its records")
    p.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the script with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    groups = [g.strip() for g in args.only.split(",") if g.strip()]
    unknown = [g for g in groups if g not in MAKERS]
    if unknown or not groups:
        print(f"{PROG}: error: unknown group(s) {', '.join(unknown) or '(none given)'} in --only: "
              f"choose from {', '.join(GROUPS)}", file=sys.stderr)
        return 2
    opts = Options(args.docs, args.results, args.episodes, args.analysis_episodes, args.sweep_episodes,
                   args.workers, args.fresh, args.dry_run)
    for group in GROUPS:  # always this order: the renderer's pictures last
        if group in groups:
            print(f"# {group}", flush=True)
            try:
                MAKERS[group](opts)
            except CommandFailed as exc:
                print(f"{PROG}: error: {exc}", file=sys.stderr)
                return exc.status
    return 0


if __name__ == "__main__":
    sys.exit(main())
