#!/usr/bin/env python3
"""docs/ANALYSIS.md: the CDF against the alternatives it argues against, remade from runs
this script makes.

Runs (with :func:`~cdf_mj.experiments.experiment.run_experiment` and
:func:`~cdf_mj.experiments.sweep.run_sweep`, into ``OUT/PART``, resumable: the same
command continues an interrupted run, or only rewrites the page of a finished one) and
writes the page (default docs/ANALYSIS.md, stamped with this command and the package
version, :mod:`cdf_mj.analysis.pages`). Parts:

==================  ====================================================================
``development``     the seven planners (cdf, cdf-threshold, imm-layered, imm, cv-layered,
                    cv, reactive) on seeds 0-999: metrics, the CDF against each planner seed
                    by seed (exact McNemar tests), Brier scores, hard-brake times by the
                    ego's start offset, and figures
``held-out``        the same on seeds 100000-100999 (never used to choose anything)
``baseline-grid``   the grid on which the ``cv`` and ``imm`` parameters were chosen, run
                    again on seeds 0-199 with the same rule
``harder``          a faster ego meeting a slower turning obstacle, seeds 0-199, and the
                    IMM with longer horizons
``sweep-tau``,      the sweeps of :mod:`cdf_mj.experiments.sweep` on seeds 0-199 (their
``sweep-risk``,     figures, but risk's, go to ``--figures``); ``sweep-risk`` sweeps
                    version 0.2's risk rule (``cdf`` runs with it there)
``sweep-beta``,
``sweep-noise``,
``sweep-obs-noise``,
``sweep-particles``
==================  ====================================================================

::

    python scripts/analysis.py                    # every part (about 22 min on 2 cores, below)
    python scripts/analysis.py --parts development,held-out
    python scripts/analysis.py --parts development --episodes 5 --out /tmp/a --doc /tmp/A.md --figures ''

Run time on 2 cores (2 workers), measured with cdf_mj 0.1.0 (episodes of 5-8 s) on a few
seeds per part and extrapolated: development and held-out about 3 min each (40 seeds of
development: 8 s); baseline-grid 3.5 min (23 runs of 200 seeds); harder 1 min; the sweeps
about 11 min together (beta, noise and obs-noise the longest); about 22 minutes in all.
Longer episodes cost in proportion. ``--episodes N`` runs N seeds per part instead;
``--parts`` some parts only (the page then shows only those).

``cdf``, ``imm-layered`` and ``cv-layered`` decide with the layered rule (a graded command:
slow gently, brake hard only in an emergency or behind a car too close, release); for them
a *brake* (false alarms, lead and brake times) is a command of ``LayeredConfig.hard_brake``
or more of deceleration, and Cutoff recall counts the Cutoff episodes they predicted
(braked hard, or were slowing the ego when the obstacle entered its lane).

Bad input (an unknown part, a result directory of other settings, figures without
matplotlib) is one line ``analysis: error: ...`` and exit status 2, before anything runs.
Exit status 1 if some episodes failed (their records hold the error; the tables leave them
out and count them).
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import math
import os
import shutil
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from cdf_mj.analysis.metrics import PlannerMetrics, Rate, mcnemar_exact, of_planner, paired_counts, planner_metrics
from cdf_mj.analysis.pages import ScriptParser, command_line, exit_status, fail, markdown_table, write_page
from cdf_mj.analysis.tables import filter_table, format_number, format_percent, format_rate, planner_table
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment
from cdf_mj.experiments.sweep import SWEEPS, SweepResult, run_sweep
from cdf_mj.extras import install_hint
from cdf_mj.planners.cv import CVConfig
from cdf_mj.planners.imm import IMMConfig
from cdf_mj.planners.registry import bind_planner, make_planner, planner_spec
from cdf_mj.records import LABELS, braked, completed, is_imminent, record_field

PROG = "analysis"
SCRIPT = "scripts/analysis.py"
PLANNERS = ("cdf", "cdf-threshold", "imm-layered", "imm", "cv-layered", "cv", "reactive")
HARDER_PLANNERS = ("cdf", "cdf-threshold", "imm-layered", "imm", "cv", "reactive")
#: The planners with ``cdf``'s own (layered) rule: against them the comparison isolates the prediction.
SAME_RULE = ("imm-layered", "cv-layered")
HARDER = {"ego.speed": 17.9, "ego.start_spread": (-22.0, -6.0), "obstacle.turn_speed": 4.0}
HARDER_IMM_HORIZONS = (2.0, 2.5, 3.0)  # [s]
#: Planners of each sweep (a sweep of a CDF setting runs the others once, as references). The
#: risk sweep is of version 0.2's risk rule: ``cdf`` runs with it there (``decision = "risk"``),
#: beside the other predictors with that rule.
SWEEP_PLANNERS: dict[str, tuple[str, ...]] = {
    "tau": ("cdf", "imm", "cv", "reactive"),
    "risk": ("cdf", "imm-risk", "cv-risk", "imm", "reactive"),
    "beta": HARDER_PLANNERS,
    "noise": HARDER_PLANNERS,
    "obs-noise": HARDER_PLANNERS,
    "particles": ("cdf",),
}
#: Sweeps whose figure the page shows (docs/img/analysis/<name>.png, also made by
#: scripts/make_figures.py --only sweeps); the others are tables only.
FIGURED_SWEEPS = ("tau", "beta", "noise", "obs-noise", "particles")
#: The grids on which the baselines' parameters were chosen (seeds 0-199): (horizon [s], margin [m]).
CV_GRID = (*((h, 0.3) for h in (0.5, 1.0, 1.5, 2.0, 2.5)), *((h, m) for m in (0.0, 0.15) for h in (1.0, 1.5, 2.0)))
#: (horizon [s], threshold), at IMMConfig's margin.
IMM_GRID = tuple((h, th) for h in (1.0, 1.5, 2.0) for th in (0.6, 0.8, 0.9, 0.95))
FIGURE_DIRS = {"development": "dev", "held-out": "heldout"}  # as scripts/make_figures.py names them


@dataclass(frozen=True)
class Options:
    """What every part needs to run."""

    out: Path
    doc: Path
    figures: Path | None
    workers: int | None
    progress: bool


@dataclass(frozen=True)
class Part:
    """One part of the page: its seeds and the function that runs it and returns its Markdown."""

    name: str
    seeds: range
    make: Callable[[Part, Options], Made]


@dataclass(frozen=True)
class Made:
    """What a part made: its Markdown, its failed episodes and, for a comparison, its completed records."""

    lines: list[str]
    failed: int
    records: list[dict[str, Any]] | None = None


# ----------------------------------------------------------------- helpers
def _span(seeds: range) -> str:
    return f"{seeds.start}–{seeds.stop - 1}"


def _p(b: int, c: int) -> str:
    return f"{mcnemar_exact(b, c):.3g}"


def _experiment(part: Part, opts: Options, planners: Sequence[str], sub: str = "",
                config: ScenarioConfig | None = None,
                planner_args: dict[str, dict[str, Any]] | None = None) -> tuple[list[dict[str, Any]], int]:
    """One resumable run_experiment call into OUT/PART[/SUB]: (all records, failed)."""
    directory = opts.out / part.name / sub if sub else opts.out / part.name
    try:
        run = run_experiment(directory, part.seeds, planners, config or ScenarioConfig(), CDFConfig(),
                             progress=opts.progress, workers=opts.workers, resume=True, planner_args=planner_args)
    except SettingsMismatchError as exc:
        _fail(f"{exc} with --out, or remove {directory}")
    except ValueError as exc:
        _fail(str(exc))
    return run.records, run.failed


def _labels_line(records: Sequence[dict[str, Any]], planner: str) -> str:
    mine = of_planner(records, planner)
    counts = {lab: sum(1 for r in mine if record_field(r, "label") == lab) for lab in LABELS}
    return ", ".join(f"{lab} {counts[lab]}" for lab in LABELS) + f" of {len(mine)}"


def _failed_note(failed: int) -> str:
    return f" {failed} failed episode(s) are left out of the tables (their records hold the error)." if failed else ""


# ----------------------------------------------------------------- the planners compared
def braking_lines(metrics: dict[str, PlannerMetrics], records: Sequence[dict[str, Any]]) -> list[str]:
    """Recall (predicted Cutoffs), false alarms among Yield episodes, false discovery (of the
    episodes with a hard brake), collisions by label, released hard brakes."""
    rows = []
    for m in metrics.values():
        mine = [r for r in of_planner(records, m.planner) if braked(r)]
        released = sum(1 for r in mine if (record_field(r, "planner_info") or {}).get("release_time") is not None)
        rows.append([m.planner, format_rate(m.recall), format_rate(m.false_alarms_yield),
                     format_rate(m.false_discovery), f"{m.collisions_yield}, {m.collisions_right}",
                     f"{format_percent(m.paper_avoided)} ({max(0, m.imminent - m.collisions)}/{m.imminent})",
                     f"{released}/{len(mine)}"])
    return markdown_table(["planner", "Cutoff recall (predicted Cutoff)", "false alarms / Yield episodes",
                           "false discovery (of braked hard)", "collisions in Yield, Right", "paper's formula",
                           "brake released (of braked hard)"], rows)


def paired_lines(records: Sequence[dict[str, Any]], others: Sequence[str]) -> list[str]:
    """``cdf`` against each of ``others`` seed by seed, with exact McNemar tests."""
    rows = []
    for other in others:
        c = paired_counts(records, "cdf", other)
        rows.append([f"cdf / {other}", str(c.seeds), str(c.collides_only_first), str(c.collides_only_second),
                     _p(c.collides_only_first, c.collides_only_second), str(c.hit_only_first),
                     str(c.hit_only_second), _p(c.hit_only_first, c.hit_only_second),
                     str(c.false_alarm_only_first), str(c.false_alarm_only_second), str(c.false_alarm_both),
                     _p(c.false_alarm_only_first, c.false_alarm_only_second)])
    return markdown_table(["pair", "seeds", "Cutoff: collides only cdf", "only the other", "McNemar p",
                           "any label: collides only cdf", "only the other", "McNemar p", "false alarm only cdf",
                           "only the other", "both", "McNemar p"], rows)


def offset_lines(records: Sequence[dict[str, Any]], planners: Sequence[str]) -> list[str]:
    """Median first hard-brake time of braking Cutoff episodes by the ego's start offset, four equal bins."""
    lo, hi = (float(v) for v in ScenarioConfig().to_dict()["ego"]["start_spread"])
    edges = [lo + (hi - lo) * k / 4 for k in range(5)]
    header = ["planner", *(f"[{a:g}, {b:g}{']' if k == 3 else ')'} m" for k, (a, b) in
                           enumerate(itertools.pairwise(edges)))]
    rows = []
    for planner in planners:
        cut = [r for r in of_planner(records, planner) if is_imminent(r) and braked(r)]
        if not cut:
            continue
        cells = []
        for k, (a, b) in enumerate(itertools.pairwise(edges)):
            times = [float(record_field(r, "brake_time")) for r in cut
                     if a <= float(record_field(r, "ego_start_offset")) < b
                     or (k == 3 and float(record_field(r, "ego_start_offset")) == b)]
            cells.append(f"{statistics.median(times):.2f} ({len(times)})" if times else "-")
        rows.append([planner, *cells])
    return markdown_table(header, rows) if rows else ["No Cutoff episode with a hard brake."]


def _verdict(hits: int, other_hits: int, alarms: int, other_alarms: int) -> str:
    if hits < other_hits and alarms < other_alarms:
        return "fewer collisions and fewer false alarms"
    if hits <= other_hits and alarms <= other_alarms:
        return "the same" if (hits, alarms) == (other_hits, other_alarms) else "no worse on either, better on one"
    if hits >= other_hits and alarms >= other_alarms:
        return "no better on either, worse on at least one"
    return "better on one, worse on the other"


def in_short(by_part: dict[str, tuple[range, list[dict[str, Any]]]]) -> list[str]:
    """One line per planner: cdf against it on each seed range (collisions of any label and
    false alarms, with McNemar p on the discordant seeds); those with cdf's own rule
    (:data:`SAME_RULE`) are marked as the same rule with another predictor."""
    lines = []
    for other in PLANNERS[1:]:
        pieces = []
        for seeds, recs in by_part.values():
            m = planner_metrics(recs)
            if "cdf" not in m or other not in m:
                continue
            c = paired_counts(recs, "cdf", other)
            hits, other_hits = m["cdf"].collisions, m[other].collisions
            alarms, other_alarms = m["cdf"].false_alarms.k, m[other].false_alarms.k
            pieces.append(f"seeds {_span(seeds)}: collisions {hits} vs {other_hits} "
                          f"(p = {_p(c.hit_only_first, c.hit_only_second)}), false alarms {alarms} vs {other_alarms} "
                          f"(p = {_p(c.false_alarm_only_first, c.false_alarm_only_second)}): "
                          f"{_verdict(hits, other_hits, alarms, other_alarms)}")
        if pieces:
            same = f" ({_rule_of(other)})" if other in SAME_RULE else ""
            lines.append(f"- `cdf` against `{other}`{same}: " + "; ".join(pieces) + ".")
    return lines


def _rule_of(planner: str) -> str:
    """How ``planner``'s layered rule stands to ``cdf``'s: the same rule with another
    predictor, or the layered rule with another anticipation too (the objective of
    scripts/tune_option.py chose each predictor's)."""
    ours = CDFConfig().layered
    theirs = getattr(make_planner(planner).rule, "layers", None)
    if theirs is None or (theirs.anticipation, theirs.anticipate) == (ours.anticipation, ours.anticipate):
        return "the same layered rule, another predictor"
    return (f"the layered rule with another predictor and its own anticipation: {theirs.anticipation} "
            f"{theirs.anticipate:g} against `cdf`'s {ours.anticipation} {ours.anticipate:g}")


def make_comparison(part: Part, opts: Options) -> Made:
    """development or held-out: the seven planners compared."""
    records, failed = _experiment(part, opts, PLANNERS)
    good = completed(records)
    held = "never used to choose anything" if part.name == "held-out" else "development seeds"
    lines = [f"## The planners on seeds {_span(part.seeds)} ({held})", "",
             f"Records: `{opts.out / part.name}/episodes.jsonl`. Labels: {_labels_line(good, PLANNERS[0])}."
             + _failed_note(failed), ""]
    if not good:
        return Made([*lines, "No completed episode.", ""], failed, good)
    metrics = planner_metrics(good)
    lines += [planner_table(good), "",
              "Cutoff recall counts the Cutoff episodes a planner predicted (it braked; with the layered rule, it "
              "braked hard or was slowing the ego when the obstacle entered its lane); false alarms, false "
              "discovery and released brakes count hard brakes only:", "", *braking_lines(metrics, good), "",
              "Paired on the same seeds (common random numbers); McNemar p is the exact two-sided test on the "
              "discordant seeds:", "", *paired_lines(good, [p for p in PLANNERS[1:] if p in metrics]), "",
              "### Brier scores of the filters", "", filter_table(good, p_left=CDFConfig().prior.p_left), "",
              "### When each planner brakes, by the ego's start offset", "",
              "Median time [s] of the first hard brake (episodes) over the Cutoff episodes in which the planner "
              "braked hard, by the ego's start offset (metres ahead of its nominal start); a layered rule's "
              "gentle slowing is not counted:", "", *offset_lines(good, PLANNERS[:-1]), ""]
    if opts.figures is not None:
        from cdf_mj.experiments.sweep import comparison_figures

        paths = comparison_figures(good, opts.figures / FIGURE_DIRS[part.name])
        for path in paths:
            rel = Path(os.path.relpath(path, opts.doc.parent)).as_posix()
            lines += [f"![{path.stem} on seeds {_span(part.seeds)}]({rel})", ""]
        lines += [f"*Drawn by `cdf_mj.experiments.sweep.comparison_figures` from these records (seeds "
                  f"{_span(part.seeds)}).*", ""]
    return Made(lines, failed, good)


# ----------------------------------------------------------------- the baselines' parameters
@dataclass(frozen=True)
class GridPoint:
    planner: str
    horizon: float
    margin: float
    threshold: float | None
    metrics: PlannerMetrics

    @property
    def score(self) -> float:
        """avoided share - false-alarm share (of all episodes); -inf without Cutoff episodes."""
        value = self.metrics.avoided.value - self.metrics.false_alarms.value
        return -math.inf if math.isnan(value) else value

    def key(self) -> tuple[float, float]:
        lead = self.metrics.lead_time
        return (self.score, -math.inf if math.isnan(lead) else lead)


def make_grid(part: Part, opts: Options) -> Made:
    """The grid the baselines' parameters were chosen on, run again with the same rule."""
    points: list[GridPoint] = []
    failed = 0
    margin = IMMConfig().margin
    for h, m in CV_GRID:
        recs, f = _experiment(part, opts, ["cv"], f"cv-h{h:g}-m{m:g}",
                              planner_args={"cv": {"params": CVConfig(horizon=h, margin=m)}})
        failed += f
        points += [GridPoint("cv", h, m, None, pm) for pm in planner_metrics(completed(recs)).values()]
    for h, th in IMM_GRID:
        recs, f = _experiment(part, opts, ["imm"], f"imm-h{h:g}-t{th:g}",
                              planner_args={"imm": {"params": IMMConfig(horizon=h, threshold=th)}})
        failed += f
        points += [GridPoint("imm", h, margin, th, pm) for pm in planner_metrics(completed(recs)).values()]
    cv, imm = CVConfig(), IMMConfig()
    defaults = {"cv": (cv.horizon, cv.margin, None), "imm": (imm.horizon, imm.margin, imm.threshold)}
    best = {name: max((p for p in points if p.planner == name), key=GridPoint.key, default=None)
            for name in ("cv", "imm")}
    rows = []
    for p in points:
        mark = "**" if p is best[p.planner] else ""
        default = " (default)" if (p.horizon, p.margin, p.threshold) == defaults[p.planner] else ""
        rows.append([f"{mark}{p.planner}{default}{mark}", f"{p.horizon:g}", f"{p.margin:g}",
                     "-" if p.threshold is None else f"{p.threshold:g}", format_rate(p.metrics.avoided),
                     format_rate(p.metrics.false_alarms), format_number(p.metrics.lead_time),
                     f"{mark}{format_number(p.score, 3)}{mark}"])
    lines = [
        "## How the baseline parameters were chosen",
        "",
        "On seeds 0–199 only, before any other run of the baselines, by one rule fixed in advance: the largest",
        "*avoided share − false-alarm share* (false alarms as a share of all episodes), ties broken by the",
        "longer median lead time. The IMM's noise levels were set from how closely a route-following car keeps",
        "to its route in a few traces, not tuned.",
        "",
        f"*History (cdf_mj 0.1.0, episodes of 8 s ending 20 m past the conflict point):* the rule chose `cv` "
        f"with horizon {cv.horizon:g} s and margin {cv.margin:g} m, and `imm` with horizon {imm.horizon:g} s and "
        f"threshold {imm.threshold:g} (margin {imm.margin:g} m); these are still the defaults (`CVConfig()`, "
        "`IMMConfig()`), and every table on this page uses them. `cv-layered` and `imm-layered` keep these "
        "predictors' settings but decide by the layered rule, whose anticipation threshold was chosen for each "
        "predictor on seeds 0–199 by another rule (`scripts/tune_layers.py`), not on this grid.",
        "",
        f"The same grid run again on this code, seeds {_span(part.seeds)} (records under "
        f"`{opts.out / part.name}/`); bold: the rule's pick today." + _failed_note(failed),
        "",
        *markdown_table(["planner", "horizon [s]", "margin [m]", "threshold", "avoided", "false alarms",
                         "median lead [s]", "avoided − false alarms"], rows),
        "",
    ]
    for name, p in best.items():
        if p is None:
            continue
        same = (p.horizon, p.margin, p.threshold) == defaults[name]
        lines.append(f"- `{name}`: the rule picks horizon {p.horizon:g} s, margin {p.margin:g} m"
                     + ("" if p.threshold is None else f", threshold {p.threshold:g}")
                     + (": the default." if same else ": **not the default**; the tables keep the default."))
    return Made([*lines, ""], failed)


# ----------------------------------------------------------------- the harder variant
def make_harder(part: Part, opts: Options) -> Made:
    """A faster ego meeting a slower turning obstacle; the IMM with longer horizons."""
    config = ScenarioConfig().with_values(HARDER)
    records, failed = _experiment(part, opts, HARDER_PLANNERS, "planners", config)
    rows: list[tuple[str, PlannerMetrics]] = [(m.planner, m) for m in planner_metrics(completed(records)).values()]
    for h in HARDER_IMM_HORIZONS:
        recs, f = _experiment(part, opts, ["imm"], f"imm-h{h:g}", config,
                              planner_args={"imm": {"params": IMMConfig(horizon=h)}})
        failed += f
        rows += [(f"imm, horizon {h:g} s", m) for m in planner_metrics(completed(recs)).values()]
    changes = ", ".join(f"`{k}` = {v}" for k, v in HARDER.items())
    lines = [
        "## A harder variant (exploratory)",
        "",
        f"Seeds {_span(part.seeds)}, every planner parameter as chosen for the default scenario, the scenario "
        f"changed in {changes}: a faster ego, started further back to arrive at about the same time, meets a "
        "slower turning obstacle, so the ego must brake while the conflict is further away. The IMM rows with "
        "longer horizons are tuned on the seeds they are reported on: read them as a direction. One seed range, "
        f"no held-out check. Records under `{opts.out / part.name}/`." + _failed_note(failed),
        "",
        *markdown_table(["planner", "avoided (95 % CI)", "paper's formula", "false alarms (95 % CI)",
                         "median lead [s]", "mean time lost [s]"],
                        [[name, format_rate(m.avoided), format_percent(m.paper_avoided), format_rate(m.false_alarms),
                          format_number(m.lead_time), format_number(m.time_lost)] for name, m in rows]),
        "",
    ]
    return Made(lines, failed)


# ----------------------------------------------------------------- sweeps
SWEEP_TEXT = {
    "tau": "The paper's rule at each threshold τ: `cdf` runs with `decision = \"threshold\"`. The fine "
           "false-alarm curve (every 0.01 of τ, in the figure) is read from the P(cutoff) histories of the run "
           "at the largest τ: before the ego brakes, the filter's history does not depend on τ, so the first tick "
           "with P(cutoff) ≥ τ is where a run at τ brakes; the line under the table counts how often that agrees "
           "with the braking runs. Avoidance comes from the braking runs only.",
    "risk": "Version 0.2's risk rule (the full brake at the last safe moment, released when the risk falls; "
            "`cdf-risk`, `imm-risk` and `cv-risk` elsewhere): its braking threshold (release at half of it), for "
            "every predictor with that rule. Here `cdf` runs with `decision = \"risk\"`, not its default layered "
            "rule; `imm` and `reactive` are references.",
    "beta": "β, the probability per tick that the obstacle's driver observes a visible ego: only the world's "
            "changes; every planner keeps its own settings (the CDF's prior on β is the range "
            f"{list(CDFConfig().prior.beta)}). A larger β means more obstacles see the ego and yield.",
    "noise": "Both cars' process noise times the factor; the CDF filter's own model of it follows.",
    "obs-noise": "The obstacle driver's observation noise of the ego times the factor; the CDF filter's model "
                 "of it follows.",
    "particles": "The CDF's particle count N.",
}


def sweep_lines(result: SweepResult, planners: Sequence[str]) -> list[str]:
    """The sweep's table (without wall times: a resumed run would show its own) and its notes."""
    rows = []
    for r in result.rows:
        avoided = Rate(int(r["avoided_k"]), int(r["avoided_n"]))
        alarms = Rate(int(r["false_alarms_k"]), int(r["false_alarms_n"]))
        rows.append([f"{r['value']:g}", str(r["planner"]), str(r["imminent"]), str(r["collisions"]),
                     format_rate(avoided), format_rate(alarms), format_number(r["lead_time"]),
                     format_number(r["min_gap"]), format_number(r["time_lost"]),
                     format_number(r["brier_left"], 3), format_number(r["brier_seen"], 3), str(r["failed"])])
    lines = markdown_table(["value", "planner", "imminent", "collisions", "avoided (95 % CI)",
                            "false alarms (95 % CI)", "median lead [s]", "median min gap [m]", "mean time lost [s]",
                            "Brier P(left)", "Brier P(seen)", "failed"], rows)
    spec = SWEEPS[result.name]
    notes = []
    if spec.cdf_only:
        refs = [p for p in planners if not planner_spec(p).shared]
        if refs:
            notes.append(f"{', '.join(f'`{p}`' for p in refs)} do not read this setting: they ran once, listed at "
                         f"the first value.")
    if "agreement" in result.extra:
        a = result.extra["agreement"]
        notes.append(f"Brake times derived from the histories of the largest-τ run agree with the braking runs in "
                     f"{a['agree']}/{a['episodes']} CDF episodes.")
    if result.failures:
        notes.append(f"{result.failed} episodes failed and are left out: "
                     + "; ".join(str(f) for f in result.failures) + ".")
    return [*lines, "", *notes, *([""] if notes else [])]


def make_sweep(part: Part, opts: Options) -> Made:
    """One sweep of :mod:`cdf_mj.experiments.sweep` on the part's seeds."""
    name = part.name.removeprefix("sweep-")
    planners = SWEEP_PLANNERS[name]
    try:
        result = run_sweep(name, opts.out / "sweeps", part.seeds, planners, workers=opts.workers,
                           progress=opts.progress, figure=opts.figures is not None)
    except SettingsMismatchError as exc:
        _fail(f"{exc} with --out, or remove {opts.out / 'sweeps' / name}")
    except ValueError as exc:
        _fail(str(exc))
    spec = SWEEPS[name]
    lines = [f"### {name}: {spec.label}", "", SWEEP_TEXT[name], "",
             f"Values {', '.join(f'{v:g}' for v in spec.values)}; planners {', '.join(planners)}; seeds "
             f"{_span(part.seeds)} at every point (records under `{opts.out / 'sweeps' / name}/`).", "",
             *sweep_lines(result, planners)]
    if opts.figures is not None and result.figure_path is not None and name in FIGURED_SWEEPS:
        target = opts.figures / f"{name}.png"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(result.figure_path, target)
        lines += [f"![{name} sweep]({Path(os.path.relpath(target, opts.doc.parent)).as_posix()})", ""]
    return Made(lines, result.failed)


# ----------------------------------------------------------------- the page
def all_parts(episodes: int | None) -> dict[str, Part]:
    """Every part, with ``episodes`` seeds each (default 1000 for the comparisons, 200 for the rest)."""
    n_main, n_small = episodes or 1000, episodes or 200
    parts = {"development": Part("development", range(0, n_main), make_comparison),
             "held-out": Part("held-out", range(100000, 100000 + n_main), make_comparison),
             "baseline-grid": Part("baseline-grid", range(0, n_small), make_grid),
             "harder": Part("harder", range(0, n_small), make_harder)}
    for name in SWEEP_PLANNERS:
        parts[f"sweep-{name}"] = Part(f"sweep-{name}", range(0, n_small), make_sweep)
    return parts


def _anticipation(name: str) -> str:
    """Planner ``name``'s anticipation threshold as a run builds it (its layered rule's
    ``LayeredConfig.anticipate``); ``-`` for a planner without the layered rule."""
    layers = getattr(getattr(bind_planner(name, CDFConfig())(), "rule", None), "layers", None)
    return "-" if layers is None else f"{layers.anticipate:g}"


def introduction(small: bool) -> list[str]:
    """The page's head: what is compared, each planner's knowledge and rule (parameters read
    from their configs)."""
    cdf, cv, imm = CDFConfig(), CVConfig(), IMMConfig()
    lay, risk = cdf.layered, cdf.risk
    grown = f" (the obstacle's grown by {cv.margin:g} m)" if cv.margin else ""
    return [
        "# Analysis: the CDF against the alternatives it argues against",
        "",
        *(["**Few seeds or some parts only: a check that the script runs, not a result.**", ""] if small else []),
        "The paper compares its Cognitive Driving Framework (CDF) with one reactive planner and concludes that",
        "modelling the other driver's *belief* is what makes early braking possible. Here the CDF meets the",
        "alternatives its introduction names, each predictor with its own rule and with the CDF's layered rule,",
        "on the same seeds (common random numbers: the same obstacle, intent, observation draws, noise and ego",
        "start for every planner on a seed). `cdf` against `imm-layered` and `cv-layered` is the layered rule",
        "with another predictor; where the declared objective of scripts/tune_option.py chose another",
        f"anticipation for a predictor (`imm-layered`: {_rule_of('imm-layered')}), the comparison is of",
        "prediction and anticipation together, and the line below says so.",
        "",
        "The layered rule ([DECISION.md](DECISION.md)) gives a graded command each tick, read from one roll of "
        "the predictor's hypotheses against the ego's plans: it slows the ego gently (at "
        f"{lay.comfort_brake:g} m/s²) once the probability of a collision if the ego goes on reaches its "
        f"anticipation threshold and slowing is the less risky (until it falls below {lay.anticipate_release:g}); "
        "it brakes fully only in an emergency (the probability of a collision that deferring the full brake by "
        f"one tick and {risk.latency + lay.emergency_margin:g} s would leave unavoidable reaches {risk.brake:g}, "
        f"released below {risk.release:g}) or behind a car in its lane closer than the RSS safe distance (further "
        f"back it follows it at a {lay.time_gap:g} s time gap); a hard brake is held at least {lay.dwell:g} s. "
        f"For these planners a *brake* is a command of {lay.hard_brake:g} m/s² or more of deceleration: their "
        "gentle slowing is neither a brake nor a false alarm.",
        "",
        *markdown_table(["planner", "what it knows", "brakes (or slows) when"], [
            ["`reactive`", "the obstacle's footprint", "any part of the obstacle is inside the ego lane (the paper's "
             "baseline)"],
            ["`cv`", "both measured poses", "the straight-line, constant-speed extrapolations of both cars put their "
             f"collision boxes{grown} in contact within {cv.horizon:g} s"],
            ["`cv-layered`", "as `cv`", "the layered rule on the constant-velocity prediction (anticipation "
             f"threshold {_anticipation('cv-layered')}, chosen for this predictor on seeds 0–199)"],
            ["`imm`", "both measured poses, the two routes", "P(conflict) = Σ over intents P(intent) · [that "
             f"intent's predicted path meets the ego within {imm.horizon:g} s] reaches {imm.threshold:g}; intent "
             "from filterpy's `IMMEstimator`, no belief"],
            ["`imm-layered`", "as `imm`", "the layered rule on the IMM's intents (anticipation threshold "
             f"{_anticipation('imm-layered')}, chosen for this predictor on seeds 0–199)"],
            ["`cdf-threshold`", "both measured poses, the routes, the obstacle driver's model with its belief",
             f"P(cutoff) from the particle filter ({cdf.n_particles} particles) reaches τ = {cdf.tau:g}, held "
             "(the paper's rule)"],
            ["`cdf`", "as `cdf-threshold`", "the layered rule on the particle filter's hypotheses (anticipation "
             f"threshold {_anticipation('cdf')}, chosen on seeds 0–199; the emergency layer's {risk.brake:g} is the "
             "risk rule's threshold, chosen on the same seeds)"],
        ]),
        "",
        "`imm` runs one Kalman filter per intent, each tracking the obstacle's progress along its own route "
        "(state: arc length, speed, acceleration; constant-acceleration model; the measured pose is compared "
        "with the route's point and tangent, an extended Kalman update), mixed by filterpy's `IMMEstimator` "
        f"with a Markov matrix whose switch probability is {imm.switch_prob:g} per tick and the prior "
        f"P(left) = {imm.p_left:g}. It predicts each intent's path along its route at constant acceleration, "
        f"speed kept within [0, {imm.max_speed:g} m/s], and the ego holding its speed. It has no notion of "
        "whether the obstacle has seen the ego: a yielding obstacle is visible to it only through its "
        "deceleration. Code: `cdf_mj/planners/cv.py`, `cdf_mj/planners/imm.py`; parameters `CVConfig`, `IMMConfig`.",
        "",
        "Definitions as in [RESULTS.md](RESULTS.md): *avoided* is among the Cutoff episodes (the constant-speed "
        "run of the seed hits the obstacle); a *false alarm* is a (hard) brake in an episode not labelled Cutoff, "
        "as a share of all episodes; *lead time* is from the first (hard) brake to the obstacle entering the ego "
        "lane, over the Cutoff episodes with one (negative: braked after the entry); *Cutoff recall* counts the "
        "Cutoff episodes predicted Cutoff (braked, or with the layered rule slowing the ego when the obstacle "
        "entered its lane); *time lost* is over episodes without a collision. "
        "The truth of P(left) is the episode's intent; the truth of P(seen) at tick t is \"the obstacle observed "
        "the ego on an earlier tick\" (a planner decides on the pose measured at the start of the tick, before "
        "the obstacle looks on that tick). The Brier tables' references are not filters: the prior held "
        "constant, and the per-time base rate fitted on the same episodes (in-sample, a little flattering to "
        "itself). Every rate has its 95 % Wilson interval.",
        "",
    ]


def markdown(sections: dict[str, list[str]], summary: list[str], small: bool, out: Path) -> str:
    """The whole page (without its stamp)."""
    lines = introduction(small)
    if summary:
        lines += ["## In short", "", "Counted from the comparison parts below (collisions: episodes of any label "
                  "with a collision with the obstacle; McNemar p on the seeds where only one of the two "
                  "collides, or false-alarms):", "", *summary, ""]
    for name in ("baseline-grid", "development", "held-out", "harder"):
        lines += sections.get(name, [])
    sweeps = [name for name in sections if name.startswith("sweep-")]
    if sweeps:
        lines += ["## Sweeps", "",
                  "Each point is one `run_experiment` call on the same seeds (common random numbers), on the seeds "
                  "where the CDF's parameters and the baselines' were chosen: these curves show sensitivity, not "
                  "held-out performance. A setting that only the filter planners read runs the other planners once, "
                  f"as references. Each sweep also writes `{out}/sweeps/<sweep>.csv` and `.md`.", ""]
        for name in sweeps:
            lines += sections[name]
    lines += ["## Reproducing", "", f"`{command_line(SCRIPT)}` runs every part (resumable) and writes this page "
              "and its figures; `--parts` and `--episodes` run less (the script's docstring gives the run times)."]
    return "\n".join(lines).rstrip() + "\n"


def _fail(message: str) -> NoReturn:
    fail(PROG, message)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the parts and write the page; returns the exit status (1 if some episodes failed)."""
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--parts", default=None, help="comma-separated parts (default: all)")
    p.add_argument("--episodes", type=int, default=None,
                   help="seeds per part (default 1000 for development and held-out, 200 for the others)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: the CPU count)")
    p.add_argument("--out", default="results/analysis", help="result directory (default results/analysis)")
    p.add_argument("--doc", default="docs/ANALYSIS.md", help="Markdown page written (default docs/ANALYSIS.md)")
    p.add_argument("--figures", default="docs/img/analysis",
                   help="where the figures go (default docs/img/analysis; '' for none)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    args = p.parse_args(argv)
    if (args.episodes is not None and args.episodes < 1) or (args.workers is not None and args.workers < 1):
        _fail("--episodes and --workers must be at least 1")
    parts = all_parts(args.episodes)
    names = [n.strip() for n in args.parts.split(",") if n.strip()] if args.parts is not None else list(parts)
    unknown = [n for n in names if n not in parts]
    if unknown or not names or len(set(names)) != len(names):
        _fail(f"unknown or repeated part(s) {', '.join(unknown) or ', '.join(names) or '(none)'}: choose from "
              f"{', '.join(parts)}")
    if args.figures and importlib.util.find_spec("matplotlib") is None:
        _fail(f"the figures need matplotlib ({install_hint('viz')}), or --figures '' for none")
    opts = Options(Path(args.out), Path(args.doc), Path(args.figures) if args.figures else None, args.workers,
                   not args.quiet)
    sections: dict[str, list[str]] = {}
    compared: dict[str, tuple[range, list[dict[str, Any]]]] = {}
    failed = 0
    for i, name in enumerate(names, start=1):
        part = parts[name]
        if not args.quiet:
            print(f"[{i}/{len(names)}] {name}: seeds {_span(part.seeds)}", file=sys.stderr)
        made = part.make(part, opts)
        sections[name] = made.lines
        failed += made.failed
        if made.records is not None:
            compared[name] = (part.seeds, made.records)
    command = command_line(SCRIPT, [("--parts", args.parts), ("--episodes", args.episodes)])
    small = args.parts is not None or args.episodes is not None
    write_page(opts.doc, markdown(sections, in_short(compared), small, opts.out), command)
    if not args.quiet:
        print(f"wrote {opts.doc}; records in {opts.out}/<part>/", file=sys.stderr)
    return exit_status(PROG, failed)


if __name__ == "__main__":
    sys.exit(main())
