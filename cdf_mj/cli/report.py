"""``cdf-mj report``: PNG figures and a Markdown page from an experiment directory."""

from __future__ import annotations

import argparse

from cdf_mj.cli.args import command, out_path, seed_value, shown
from cdf_mj.config import MAX_SEED
from cdf_mj.extras import install_hint


def _cmd_report(args: argparse.Namespace) -> int:
    from cdf_mj.viz.report import shown_path, write_report

    result = write_report(args.dir, out=args.out, seeds=args.seeds, planner=args.planner)
    skipped = f"; skipped {result.failed} failed episode(s)" if result.failed else ""
    if result.unreadable:
        skipped += f" and {result.unreadable} unreadable line(s)"
    print(f"wrote {shown_path(result.markdown)} and {len(result.figures)} figure(s): "
          f"{', '.join(p.name for p in result.figures.values())} from {result.records} records{skipped}")
    for name, why in result.omitted.items():
        print(f"  {name}: not drawn ({why})")
    return 0


def _seed_list(text: str) -> list[int]:
    try:
        seeds = [seed_value(v) for v in text.split(",") if v.strip()]
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected comma-separated seeds from 0 to {MAX_SEED}, got "
                                         f"{shown(text)}") from None
    if not seeds:
        raise argparse.ArgumentTypeError("expected at least one seed")
    return seeds


def add_report(subparsers: argparse._SubParsersAction) -> None:
    """The ``report`` command."""
    p = command(
        subparsers, "report", summary="figures (PNG) and a Markdown page from an experiment directory",
        description="Turn an experiment directory (settings.json, episodes.jsonl) into PNG "
                    "figures and report.md: confusion matrix beside the paper's, avoidance per "
                    "planner with 95 %% intervals, trajectories, posterior traces, braking lead "
                    "times. Failed episodes are skipped and counted. "
                    f"Needs matplotlib ({install_hint('viz')}).")
    p.add_argument("dir", metavar="DIR", help="experiment directory (cdf-mj experiment --out DIR)")
    p.add_argument("--out", type=out_path, default=None, help="output directory (default DIR)")
    p.add_argument("--seeds", type=_seed_list, default=None, metavar="SEED[,SEED...]",
                   help="comma-separated seeds for trajectories and posteriors (default: one per label)")
    p.add_argument("--planner", default=None, metavar="PLANNER",
                   help="planner whose trajectories are drawn (default cdf, else the first)")
    p.set_defaults(func=_cmd_report)
