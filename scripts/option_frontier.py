#!/usr/bin/env python3
"""The option rule's frontier: can any point of it be as safe as version 0.3's rule, which
slows on the prior, while intervening as rarely as issue 35 asks?

A measurement, not a tuning (nothing is chosen here). The question, written down before
it ran: on the development seeds 0-199 of the default scenario, ``stop-and-wait`` and the
four junction-crash families (``stress-looked-but-failed``, ``stress-misjudged-speed``,
``stress-distracted``, ``stress-creeper``: drivers written apart from the filter's model),
is there a point of the option rule (``LayeredConfig.anticipation = "option"``,
``option_time`` 1 s, its ``anticipate`` in {0.3, 0.5, 0.7, 0.9}, the escalation to the full
brake held at 0.9, the emergency layer's ``RiskConfig.brake`` in {0.3, 0.5}, each release
at half its threshold) with no collision in any of the six, non-Cutoff interventions at
most 10 % and hard brakes at most 1 % (issue 35's targets)? Beside it: ``cdf`` as shipped
(version 0.3's ``go 0.1``, which slows on the prior) and the naive-caution baselines
``caution-waiting`` and ``caution-moving``, the bar the belief must clear.

Each point is a :func:`cdf_mj.experiments.experiment.run_experiment` (with ``constant``,
the reference of the time lost) in ``OUT/SCENARIO/POINT`` (resumable). Prints a Markdown
page and, with ``--doc``, writes it with its figure::

    python scripts/option_frontier.py          # results/frontier, docs/FRONTIER.md (about 12 min on 2 cores)
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import dataclass
from pathlib import Path

from cdf_mj.analysis.metrics import PlannerMetrics, Rate, planner_metrics
from cdf_mj.analysis.pages import command_line, markdown_table, write_page
from cdf_mj.analysis.tables import format_rate
from cdf_mj.cli.args import episode_count, worker_count
from cdf_mj.config import CDFConfig, LayeredConfig, RiskConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.presets import load_preset

SCENARIOS = ("default", "stop-and-wait", "stress-looked-but-failed", "stress-misjudged-speed", "stress-distracted",
             "stress-creeper")
ANTICIPATE = (0.3, 0.5, 0.7, 0.9)
EMERGENCY = (0.3, 0.5)
ESCALATE = 0.9
OPTION_TIME = 1.0
BASELINES = ("caution-waiting", "caution-moving")


@dataclass(frozen=True)
class Point:
    """One planner of the frontier: the option rule at ``(anticipate, emergency)``, or a
    registered planner as shipped (``anticipate`` None)."""

    planner: str
    anticipate: float | None = None
    emergency: float | None = None

    @property
    def name(self) -> str:
        """Its row and directory name."""
        if self.anticipate is None:
            return self.planner
        return f"option-{self.anticipate:g}-emergency-{self.emergency:g}"

    def kwargs(self) -> dict:
        """Its :func:`run_experiment` arguments (besides the seeds and the scenario)."""
        if self.anticipate is None:
            return {"planners": (self.planner, "constant")}
        layers = LayeredConfig(anticipation="option", option_time=OPTION_TIME, anticipate=self.anticipate,
                               anticipate_release=self.anticipate / 2, escalate=ESCALATE)
        risk = RiskConfig(brake=self.emergency, release=self.emergency / 2)
        return {"planners": ("cdf", "constant"), "cdf": CDFConfig(layered=layers, risk=risk)}


POINTS = (*(Point("cdf", a, e) for e, a in itertools.product(EMERGENCY, ANTICIPATE)), Point("cdf"),
          *(Point(b) for b in BASELINES))


def _run(out: Path, scenario: str, point: Point, episodes: int, workers: int | None) -> PlannerMetrics:
    """The metrics of one point on one scenario (run, or resumed)."""
    kwargs = {**point.kwargs(), "config": load_preset(scenario), "workers": workers, "progress": False}
    path = out / scenario / point.name
    result = run_experiment(path, range(episodes), resume=True, **kwargs)  # a fresh directory starts
    return planner_metrics(result)[kwargs["planners"][0]]


@dataclass(frozen=True)
class Pooled:
    """A point's figures pooled over the scenarios."""

    collisions: int
    episodes: int
    interventions: Rate  # non-Cutoff episodes with an intervention
    hard: Rate  # non-Cutoff episodes with a hard brake
    time_lost: float  # [s] mean over the scenarios of the non-Cutoff time lost at the fixed point

    @property
    def meets(self) -> bool:
        """Issue 35's targets: no collision, interventions <= 10 %, hard brakes <= 1 %."""
        return self.collisions == 0 and self.interventions.value <= 0.10 and self.hard.value <= 0.01


def pooled(cells: dict[str, PlannerMetrics]) -> Pooled:
    """The figures of one point over the scenarios."""
    ms = list(cells.values())
    quiet = sum(m.episodes - m.imminent for m in ms)
    return Pooled(sum(m.collisions for m in ms), sum(m.episodes for m in ms),
                  Rate(sum(m.false_interventions.k for m in ms), quiet), Rate(sum(m.false_alarms.k for m in ms), quiet),
                  sum(m.time_lost_fixed for m in ms) / len(ms))


def _figure(path: Path, rows: dict[Point, Pooled]) -> None:
    """Non-Cutoff interventions against hard brakes, each point's collisions written beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    colours = {0.3: "tab:purple", 0.5: "tab:blue"}
    for k, (point, p) in enumerate(rows.items()):
        x, y = 100 * p.interventions.value, 100 * p.hard.value
        if point.anticipate is not None:
            colour, label = colours.get(point.emergency or 0.0, "tab:cyan"), f"{point.anticipate:g}"
        else:
            colour, label = ("tab:red" if point.planner == "cdf" else "tab:grey"), point.name
        ax.scatter([x], [y], c=colour, marker="o" if p.collisions == 0 else "X", s=60, zorder=3)
        ax.annotate(f"{label} ({p.collisions})", (x, y), textcoords="offset points", fontsize=7,
                    xytext=(6, 10 - 9 * (k % 3)))
    ax.add_patch(matplotlib.patches.Rectangle((0, 0), 10, 1, color="tab:green", alpha=0.15, zorder=1))
    for e, colour in colours.items():
        ax.scatter([], [], c=colour, marker="X", label=f"option rule, emergency {e:g} (label: anticipate)")
    ax.scatter([], [], c="tab:red", marker="X", label="cdf as shipped (go 0.1)")
    ax.scatter([], [], c="tab:grey", marker="X", label="naive caution")
    ax.legend(fontsize=7, loc="center right")
    ax.set_xlabel("non-Cutoff episodes with an intervention [%]")
    ax.set_ylabel("non-Cutoff episodes with a hard brake [%]")
    ax.set_title("(n): collisions over the six scenarios (X: at least one, o: none); green: issue 35's targets "
                 "(<= 10 %, <= 1 %)", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="option_frontier", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/frontier"), help="result directory")
    parser.add_argument("--episodes", type=episode_count, default=200, help="development seeds from 0 (default 200)")
    parser.add_argument("--workers", type=worker_count, default=None, help="worker processes (default: one per CPU)")
    parser.add_argument("--doc", default="docs/FRONTIER.md",
                        help="Markdown page written (default docs/FRONTIER.md; '' for none)")
    parser.add_argument("--figure", type=Path, default=None,
                        help="its figure (default img/frontier/frontier.png beside the page)")
    args = parser.parse_args(argv)
    cells: dict[Point, dict[str, PlannerMetrics]] = {pt: {} for pt in POINTS}
    for scenario, point in itertools.product(SCENARIOS, POINTS):
        print(f"{scenario}, {point.name}", file=sys.stderr, flush=True)
        try:
            cells[point][scenario] = _run(args.out, scenario, point, args.episodes, args.workers)
        except (ValueError, OSError) as exc:  # a directory of other settings, not a directory, ...
            parser.error(str(exc))
    rows = {pt: pooled(cells[pt]) for pt in POINTS}
    met = [pt.name for pt, p in rows.items() if p.meets and pt.anticipate is not None]
    lines = ["# The option rule's frontier on the development seeds", "",
             f"Seeds 0-{args.episodes - 1} (development) of {', '.join(f'`{s}`' for s in SCENARIOS)}. The question, "
             "declared in `scripts/option_frontier.py` before it ran: does any point of the option rule (`option_time` "
             f"{OPTION_TIME:g} s, the escalation to the full brake at {ESCALATE:g}) reach issue 35's targets on all "
             "six "
             "at once: no collision, non-Cutoff interventions <= 10 %, hard brakes <= 1 %? A measurement, nothing "
             "is chosen from it.", "",
             "**Answer: " + (f"yes, {', '.join(met)}.**" if met else "no point does.**"), "",
             "![frontier](img/frontier/frontier.png)", "",
             "Pooled over the six scenarios (95 % Wilson intervals; time lost: mean over the scenarios of the "
             "non-Cutoff time lost at the fixed point against the same seed's `constant` ego):", ""]
    header = ["planner", "collisions (of episodes)", "non-Cutoff interventions", "non-Cutoff hard brakes",
              "time lost [s]", "targets"]
    lines += markdown_table(header, [[pt.name, f"{p.collisions} ({p.episodes})", format_rate(p.interventions),
                                      format_rate(p.hard), f"{p.time_lost:.3f}", "met" if p.meets else "missed"]
                                     for pt, p in rows.items()])
    lines += ["", "Collisions per scenario:", ""]
    lines += markdown_table(["planner", *SCENARIOS],
                            [[pt.name, *(str(cells[pt][s].collisions) for s in SCENARIOS)] for pt in POINTS])
    lines += ["", "Non-Cutoff hard brakes per scenario (of the non-Cutoff episodes):", ""]
    lines += markdown_table(["planner", *SCENARIOS],
                            [[pt.name, *(f"{m.false_alarms.k}/{m.episodes - m.imminent}"
                                         for m in (cells[pt][s] for s in SCENARIOS))] for pt in POINTS])
    text = "\n".join(lines)
    print(text)
    if args.doc or args.figure:
        doc = Path(args.doc or "docs/FRONTIER.md")
        figure = args.figure or doc.parent / "img" / "frontier" / "frontier.png"
        _figure(figure, rows)
    if args.doc:
        command = command_line("scripts/option_frontier.py",
                               [("--episodes", args.episodes if args.episodes != 200 else None)])
        write_page(doc, text, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
