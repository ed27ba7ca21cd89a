"""The Pareto figure of docs/DECISION_RESULTS.md (issue 35): every planner on what its
caution costs where no cut-off comes, with its collisions marked.

One point per planner (:class:`~cdf_mj.analysis.pareto.ParetoPoint`): x is the share of the
episodes not labelled Cutoff in which it intervened [%], with its 95 % Wilson interval as
an error bar; y is its mean time lost in those episodes at the fixed point against the
same seed's ``constant`` ego [s]; the marker's area grows with its share of hard brakes in
those episodes; a planner that collided with the obstacle (any label) gets a red ring and
its count. ``cdf`` and ``cdf-option`` (the default CDF and its option rule) have colours of
their own. Tuning points (:func:`~cdf_mj.analysis.pareto.tuning_points`) are small grey dots
labelled by their rule (``option 0.5 s, 0.9``: option time and threshold; ``go 0.1``:
version 0.3's anticipation and its threshold), so the trade-off a rule and threshold make is
seen beside the planners. The lower left corner is best. ::

    from cdf_mj.analysis.metrics import planner_metrics
    from cdf_mj.analysis.pareto import pareto_points
    from cdf_mj.viz.pareto import pareto_figure
    pareto_figure(pareto_points(planner_metrics(records)), "docs/img/decision/pareto.png")

Needs matplotlib (the ``viz`` extra); ImportError in one line without it.
"""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cdf_mj.analysis.pareto import ParetoPoint
from cdf_mj.extras import require
from cdf_mj.records import write_atomic

__all__ = ["ParetoFigure", "pareto_figure"]

_AREA = (30.0, 12.0)  # marker area [pt^2] at no hard brake, and added per per cent of hard brakes
_SIZES = (0.0, 5.0, 20.0)  # [%] hard-brake shares shown in the size legend
_LINEAR = 1.0  # [s] above this largest time lost the y axis is logarithmic beyond a tenth of it
_NOTE_WIDTH = 150  # characters a line of the note under the axes holds (7 pt on the 9 in figure)
#: Colour of a planner by the start of its name (the first match; grey otherwise).
_FAMILIES = (("cdf-option", "tab:cyan"), ("cdf", "tab:blue"), ("caution-", "tab:orange"), ("imm", "tab:green"),
             ("cv", "tab:olive"), ("reactive", "tab:purple"))


@dataclass(frozen=True)
class ParetoFigure:
    """What :func:`pareto_figure` drew."""

    path: Path
    drawn: list[str]  # planners placed on the axes
    ringed: list[str]  # of them, those with a collision (red ring and count)
    skipped: list[str] = field(default_factory=list)  # planners without a time lost (named on the figure)
    tuning: int = 0  # tuning points drawn


def _colour(name: str) -> str:
    return next((c for start, c in _FAMILIES if name.startswith(start)), "tab:gray")


def _area(point: ParetoPoint) -> float:
    share = point.hard_brakes.value if point.hard_brakes.n else 0.0
    return _AREA[0] + _AREA[1] * 100 * share


def _placed(points: Sequence[ParetoPoint]) -> tuple[list[ParetoPoint], list[str]]:
    """The points with both coordinates, and the names of those without."""
    ok = [p for p in points if p.interventions.n and not math.isnan(p.time_lost)]
    return ok, [p.name for p in points if p not in ok]


def pareto_figure(points: Sequence[ParetoPoint], path: str | Path, tuning: Sequence[ParetoPoint] = (),
                  title: str = "Every planner where no cut-off comes", note: str = "") -> ParetoFigure:
    """Draw ``points`` (and the grey ``tuning`` points) into the PNG ``path`` (parents
    created; written whole or not at all); ``note`` is printed under the axes (the seeds,
    where the tuning points come from). ValueError if no point has both coordinates."""
    drawn, skipped = _placed(points)
    shown_tuning, _ = _placed(tuning)
    if not drawn:
        raise ValueError("pareto_figure: no planner has both a non-Cutoff intervention share and a time lost "
                         "(are the same seeds' `constant` episodes there?)")
    canvas = require("matplotlib.backends.backend_agg", "viz", "the Pareto figure").FigureCanvasAgg
    figure = require("matplotlib.figure", "viz", "the Pareto figure").Figure
    fig = figure(figsize=(9.0, 5.6), dpi=100, layout="constrained")
    canvas(fig)
    ax = fig.add_subplot()
    labels: list[tuple[float, float, str, float, str, bool]] = []  # x, y, text, font size, colour, optional
    for t in shown_tuning:
        xy = (100 * t.interventions.value, t.time_lost)
        ax.scatter(*xy, s=10, color="0.6", edgecolors="red" if t.collisions else "none", zorder=1)
        labels.append((*xy, t.name + (f" ({t.collisions} coll.)" if t.collisions else ""), 6, "0.45", True))
    ringed = []
    groups: dict[tuple[float, float], list[ParetoPoint]] = {}
    for p in drawn:
        x, (lo, hi) = 100 * p.interventions.value, p.interventions.interval
        colour = _colour(p.name)
        ax.errorbar([x], [p.time_lost], xerr=[[x - 100 * lo], [100 * hi - x]], fmt="none", ecolor=colour,
                    elinewidth=0.8, alpha=0.6, zorder=2)
        ax.scatter([x], [p.time_lost], s=_area(p), color=colour, alpha=0.8, edgecolors="k", linewidths=0.4,
                   zorder=3)
        if p.collisions:
            ringed.append(p.name)
            ax.scatter([x], [p.time_lost], s=_area(p) + 140, facecolors="none", edgecolors="red", linewidths=1.6,
                       zorder=4)
        groups.setdefault((round(x, 2), round(p.time_lost, 3)), []).append(p)
    for (x, y), same in groups.items():  # planners on one spot share a label
        text = ", ".join(p.name + (f" ({p.collisions} coll.)" if p.collisions else "") for p in same)
        labels.insert(0, (x, y, text, 8, "red" if any(p.collisions for p in same) else "k", False))
    _legend(ax, bool(shown_tuning))
    ax.set_xlabel("episodes not labelled Cutoff with an intervention [%] (bar: 95 % Wilson interval)")
    ylabel = "mean time lost there at the fixed point vs constant [s]"
    if max(p.time_lost for p in [*drawn, *shown_tuning]) > _LINEAR:
        ax.set_yscale("symlog", linthresh=_LINEAR / 10)
        ylabel += f"\n(linear to {_LINEAR / 10:g} s, logarithmic above)"
        ax.yaxis.set_major_formatter(lambda value, _: f"{value:g}")
    ax.set_ylabel(ylabel)
    lo, hi = ax.get_xlim()
    ax.set_xlim(min(-2.0, lo), hi + 0.12 * (hi - lo))  # room for the names
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.set_title(title, fontsize=10)
    said = [note] if note else []
    if skipped:
        said.append(f"not drawn (no time lost measured): {', '.join(skipped)}")
    lines = [part for text in said for part in textwrap.wrap(text, _NOTE_WIDTH)]
    if lines:
        fig.text(0.01, 0.0, "\n".join(lines), fontsize=7, va="bottom", ha="left", color="0.3")
        fig.get_layout_engine().set(rect=(0, 0.03 * len(lines), 1, 1 - 0.03 * len(lines)))
    _place_labels(fig, ax, labels)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, buf.getvalue())
    return ParetoFigure(out, [p.name for p in drawn], ringed, skipped, len(shown_tuning))


def _overlaps(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _place_labels(fig: Any, ax: Any, labels: Sequence[tuple[float, float, str, float, str, bool]]) -> None:
    """Annotate each point beside it where no earlier label is (the first free of a few
    places around it, text sizes estimated); an optional label with no free place is left
    out, any other goes to its first place."""
    fig.draw_without_rendering()  # the layout, so that data map to their final pixels
    scale = fig.dpi / 72  # pixels per point
    taken: list[tuple[float, ...]] = []  # the boxes placed [px]
    for x, y, text, size, colour, optional in labels:
        px, py = ax.transData.transform((x, y))
        width, height = 0.55 * size * len(text), 1.2 * size  # [pt]
        places = [(6, 3), (6, -3 - height), (6, 3 + height), (6, -3 - 2 * height), (-6 - width, 3),
                  (-6 - width, -3 - height), (6, 3 + 2 * height), (6, -3 - 3 * height)]
        boxes = [(px + dx * scale, py + dy * scale, px + (dx + width) * scale, py + (dy + height) * scale)
                 for dx, dy in places]
        free = next((k for k, box in enumerate(boxes) if not any(_overlaps(box, t) for t in taken)), None)
        if free is None and optional:
            continue
        k = free or 0
        taken.append(boxes[k])
        ax.annotate(text, (x, y), xytext=places[k], textcoords="offset points", fontsize=size, color=colour,
                    va="bottom", annotation_clip=False, in_layout=False)


def _legend(ax: Any, tuning: bool) -> None:
    """The legend: marker sizes by hard-brake share, the red ring, the grey tuning dots."""
    handles = [ax.scatter([], [], s=_AREA[0] + _AREA[1] * share, color="0.7", edgecolors="k", linewidths=0.4,
                          label=f"{share:g} % hard brakes,\nnot Cutoff") for share in _SIZES]
    handles.append(ax.scatter([], [], s=_AREA[0] + 140, facecolors="none", edgecolors="red", linewidths=1.6,
                              label="collided with the\nother car (count)"))
    if tuning:
        handles.append(ax.scatter([], [], s=10, color="0.6",
                                  label="the CDF at a tuning point\n(rule, option time,\nthreshold)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, labelspacing=1.3,
              borderpad=0.9)
