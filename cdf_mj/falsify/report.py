"""What a falsification shows a person: the search's progress as a figure (least
robustness per generation against episodes spent, one line per run) and its failures as
Markdown (``report.md`` of a run; ``scripts/falsify.py`` builds docs/FALSIFY.md from the
same pieces)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from cdf_mj.extras import require

if TYPE_CHECKING:
    from cdf_mj.falsify.counterexamples import Counterexample
    from cdf_mj.falsify.evaluate import Evaluation
    from cdf_mj.falsify.search import SearchResult
    from cdf_mj.falsify.space import SearchSpace

__all__ = ["FalsifyOutcome", "counterexample_table", "falsify_markdown", "progress_figure"]


class FalsifyOutcome(Protocol):
    """What :func:`falsify_markdown` reads of a finished run: a
    :class:`cdf_mj.falsify.run.FalsifyResult` (which this module does not import: the run
    imports its report, not the other way round)."""

    @property
    def space(self) -> SearchSpace: ...  # the space searched
    @property
    def search(self) -> SearchResult: ...  # the search's evaluations and generations
    @property
    def counterexamples(self) -> Sequence[Counterexample]: ...  # minimised, one per cluster
    @property
    def errors(self) -> Sequence[Evaluation]: ...  # every episode of the run that raised

_UNIT = {"gap": "m", "ttc": "s", "headway": "s"}


def progress_figure(runs: Mapping[str, Sequence[SearchResult]], path: str | Path, margin: str) -> Path:
    """Least robustness so far against episodes, one line per search (a planner's runs in
    one colour), a dot at each run's first failure; PNG at ``path``."""
    matplotlib = require("matplotlib", "viz", "the falsification's progress figure")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=120)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (planner, results) in enumerate(runs.items()):
        colour = colours[i % len(colours)]
        for j, res in enumerate(results):
            xs = [g.episodes for g in res.generations]
            ys = [max(g.best_so_far, 0.0) for g in res.generations]
            ax.step(xs, ys, where="post", color=colour, alpha=0.85, lw=1.4, label=planner if j == 0 else None)
            if res.first_failure is not None:
                ax.plot([res.first_failure], [0.0], "o", color=colour, ms=5)
    ax.set_xscale("log")  # the search's early generations, where the failures come, as wide as its end
    ax.set_xlabel("episodes of the search (log scale)")
    ax.set_ylabel(f"least robustness so far [{_UNIT[margin]}] ({margin}; 0 = failure)")
    ax.set_ylim(bottom=-0.05)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Falsification progress (dots: first failure of a run)", fontsize=10)
    fig.tight_layout()
    import io

    from cdf_mj.records import write_atomic

    path = Path(path)
    png = io.BytesIO()  # then written whole or not at all, never through a link nor into a FIFO
    fig.savefig(png, format=path.suffix.lstrip(".").lower() or "png")
    plt.close(fig)
    return write_atomic(path, png.getvalue())


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def counterexample_table(found: Sequence[Counterexample], compare: Sequence[str]) -> list[str]:
    """Markdown rows: one per counterexample, its traits, the contact and the other planners."""
    head = ("| # | failures | traits away from the base world | seed | label "
            "| speeds at contact (ego / obstacle) [m/s] | log-likelihood (likeliest of the cluster) "
            "| probability of its choices |")
    rule = "|---|---|---|---|---|---|---|---|"
    for p in compare:
        head += f" {p} |"
        rule += "---|"
    lines = [head, rule]
    for i, c in enumerate(found, 1):
        traits = "; ".join(f"`{k}` = {_fmt(v)}" for k, v in c.changed.items()) or "(none)"
        speeds = [max(c.contact[k], 0.0) + 0.0 for k in ("ego_speed", "obstacle_speed")] if c.contact else []
        contact = f"{speeds[0]:.1f} / {speeds[1]:.1f}" if speeds else "no touch"  # + 0.0: no "-0.0"
        row = (f"| {i} | {len(c.members)} | {traits} | {c.seed} | {c.summary.get('label')} | {contact} "
               f"| {c.log_likelihood:.1f} ({c.likeliest:.1f}) | {c.choice_mass:.2g} |")
        for p in compare:
            failed, replayed = c.others_members.get(p, (0, 0))
            got = c.others.get(p)
            mark = "raised" if got is None else "fails" if got else "passes"
            row += f" {mark}; {failed}/{replayed} of the cluster |"
        lines.append(row)
    return lines


def falsify_markdown(result: FalsifyOutcome, figure: str | None) -> str:
    """``report.md`` of one run (``figure``: the progress figure's file name beside it, or None)."""
    s, space = result.search, result.space
    compare = sorted({p for c in result.counterexamples for p in c.others})
    first = f"after {s.first_failure} episodes" if s.first_failure else "none"
    lines = [f"# Falsification of `{s.planner}` on space `{space.name}`", "",
             f"Failure: {space.failure.text}. Space: {len(space.dims)} dimensions over preset `{space.preset}` "
             f"({space.source}).", "",
             f"- episodes: {len(s.evaluations)}; failures found: {len(s.failures)}; first failure: {first}",
             f"- least robustness: {min((e.robustness for e in s.evaluations), default=float('nan')):.3g}",
             f"- restarts: {max((g.restart for g in s.generations), default=0)}; generations: {len(s.generations)}"]
    if result.errors:
        lines.append(f"- **{len(result.errors)} episodes raised** (counted as no failure; search, minimisation "
                     f"and replays): first error: {result.errors[0].error}")
    if figure:
        lines += ["", f"![progress]({figure})"]
    lines += ["", "## Counterexamples", ""]
    if result.counterexamples:
        lines += [f"Clusters of failures with the same choices, each minimised (options put back to the base "
                  f"world's while the seed still fails), likeliest first: by the nominal log-likelihood of the "
                  f"cluster's likeliest failure, then the nominal probability of its choices (an upper bound on "
                  f"the cluster's probability mass). Replay one with "
                  f"`cdf-mj episode --preset FILE --seed SEED --planner {s.planner}`.", ""]
        lines += counterexample_table(result.counterexamples, compare)
        lines += ["", "Files: " + ", ".join(f"`{Path(c.path).name}`" for c in result.counterexamples if c.path)]
    else:
        lines.append("No failure within the budget.")
    return "\n".join(lines) + "\n"
