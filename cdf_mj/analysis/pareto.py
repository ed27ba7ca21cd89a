"""Planners set against one another on what each of their actions costs (issue 35): one
planner against another seed by seed on four criteria, the Pareto verdict of the pair, the
points of the Pareto figure (:mod:`cdf_mj.viz.pareto`), the table of every intervention per
label, one line on what each registered planner is, and which pairs the pages compare
(:data:`DECIDERS` against every other planner, :func:`comparisons`).

The four criteria, each the smaller the better, on the seeds both planners ran (common
random numbers: the same obstacle, noise and ego start for a seed):

==============================  ============================================================
collisions                      episodes of any label in which the ego touched the obstacle
                                (:func:`~cdf_mj.records.hit_obstacle`)
non-Cutoff interventions        episodes not labelled Cutoff in which the planner held the
                                ego below its own controller (:func:`~cdf_mj.records.intervened`)
non-Cutoff hard brakes          episodes not labelled Cutoff in which it braked hard
                                (:func:`~cdf_mj.records.is_false_alarm`)
non-Cutoff time lost [s]        mean over the episodes not labelled Cutoff, on the seeds on
                                which neither planner nor the reference (``constant``) ego
                                collided, of the time lost at the fixed point against the
                                reference (:func:`~cdf_mj.records.pass_time`)
==============================  ============================================================

The counts are compared with the exact McNemar test on the discordant seeds (one planner
has it, the other not); the time lost with the exact sign test (the same binomial test) on
the seeds on which the two pass times differ, and two means within :data:`TIME_TIE` are a
tie. A difference that its test does not find significant at :data:`SIGNIFICANCE` is a tie
too (one seed of difference is chance, not a gain). X *dominates* Y when X is at least as
good on all four and better on one, so judged. ::

    from cdf_mj.analysis.pareto import compare, pareto_lines
    print(compare(records, "caution-moving", "cdf").text())
    print("\\n".join(pareto_lines(records, "cdf", ["caution-moving", "imm-layered"])))
"""

from __future__ import annotations

import math
import re
import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cdf_mj.analysis.metrics import PlannerMetrics, Rate, mcnemar_exact, planner_metrics
from cdf_mj.analysis.pages import markdown_table, verdict
from cdf_mj.analysis.tables import (
    format_number,
    format_percent,
    format_rate,
    intervention_table,
)
from cdf_mj.config import LayeredConfig
from cdf_mj.planners.decision import LayeredRule
from cdf_mj.planners.registry import LazyPlanner, make_planner, planner_spec
from cdf_mj.records import (
    RecordLike,
    completed,
    hit_obstacle,
    intervened,
    is_false_alarm,
    is_imminent,
    load_records,
    pass_time,
    read_settings,
    record_field,
)

__all__ = ["CDF_LINE", "CRITERIA", "DECIDERS", "RULES_NOTE", "SIGNIFICANCE", "TIME_TIE", "Criterion",
           "PairVerdict", "ParetoPoint", "compare", "comparisons", "cost_targets", "intervention_lines",
           "layered_label", "pareto_lines", "pareto_points", "planner_item", "planner_line", "rule_label",
           "tuning_points"]

#: The criteria of :func:`compare`, in the order they are printed.
CRITERIA = ("collisions", "non-Cutoff interventions", "non-Cutoff hard brakes", "non-Cutoff time lost [s]")
#: [s] Two means of time lost closer than this are a tie (the pages print two decimals).
TIME_TIE = 0.01
#: The level at which a McNemar or sign test's p-value is called significant.
SIGNIFICANCE = 0.05
#: [s] Two pass times of a seed closer than this are the same (for the sign test).
_SEED_TIE = 1e-6
#: The planners the pages set against every other one (issue 35): the package's default CDF
#: and the CDF with the option rule, which waits for the belief.
DECIDERS = ("cdf", "cdf-option")


def rule_label(layers: LayeredConfig | Mapping[str, Any]) -> str:
    """A layered rule's anticipation in a few words: ``"option 0.5 s, 0.9"`` (the option rule:
    its option time and threshold) or ``"go 0.1"`` (version 0.3's anticipation: its
    threshold). ``layers`` is the config or a stored run's ``cdf.layered`` settings; settings
    without ``anticipation`` predate the option rule and read as ``go``. KeyError without
    ``anticipate``."""
    fields = layers.to_dict() if isinstance(layers, LayeredConfig) else layers
    if fields.get("anticipation", "go") == "option":
        return f"option {fields['option_time']:g} s, {fields['anticipate']:g}"
    return f"{fields.get('anticipation', 'go')} {fields['anticipate']:g}"


def layered_label(name: str) -> str | None:
    """:func:`rule_label` of the layered rule the registered planner ``name`` decides by with
    its defaults, None if it decides by another rule (the naive-caution rules, which do not
    read the anticipation, included). ValueError for an unknown planner."""
    rule = getattr(make_planner(name), "rule", None)
    return rule_label(rule.layers) if type(rule) is LayeredRule else None


def _cdf_line(layers: LayeredConfig) -> str:
    """How the pages describe ``cdf`` with the package's default layered rule ``layers``."""
    if layers.anticipation != "go":
        return f"the CDF with the layered rule, anticipation {rule_label(layers)} (docs/DECISION.md)"
    return (f"the CDF with the layered rule and version 0.3's anticipation ({rule_label(layers)}: slow at the "
            f"comfortable brake once a collision going on has probability {layers.anticipate:g}), kept as the "
            "default by the declared tuning objective (scripts/tune_option.py, fewest collisions first); the prior "
            "alone can reach that risk, so it slows on the prior before the belief has any evidence "
            "(docs/DECISION.md), and `cdf-option` is the rule that waits for the belief")


#: How the pages describe ``cdf`` (:func:`planner_line`), from the package's default rule.
CDF_LINE = _cdf_line(LayeredConfig())
#: What the pages say of the two rules of :data:`DECIDERS`, one Markdown paragraph.
RULES_NOTE = ("Two rules of the CDF are compared. The default `cdf` keeps version 0.3's anticipation: the "
              "declared tuning objective (scripts/tune_option.py, its output in [TUNING.md](TUNING.md): fewest "
              "collisions first, then non-Cutoff interventions, hard brakes and time lost) kept it, and it slows on "
              "the prior, before the belief has any evidence. `cdf-option` is the option rule, the one that waits "
              "for the belief: it slows only once going on a little longer would leave a collision that the "
              "comfortable brake could no longer avoid. Each is set against every other planner and judged against "
              "the issues' targets, and `cdf-option` against `cdf`: what the option rule buys over the default and "
              "what it costs.")


@dataclass(frozen=True)
class Criterion:
    """Two planners on one criterion: their values and the discordant seeds."""

    name: str  # one of CRITERIA
    first: float  # the first planner's count, or its mean time lost [s] (NaN: not measured)
    second: float
    only_first: int  # seeds on which only the first has it (counts), or it lost more (time)
    only_second: int
    seeds: int  # the seeds compared
    tie: float = 0.0  # differences of ``first - second`` within this are a tie

    @property
    def p(self) -> float:
        """Exact two-sided McNemar (counts) or sign test (time) p-value on the discordant seeds."""
        return mcnemar_exact(self.only_first, self.only_second)

    @property
    def better(self) -> str | None:
        """``"first"`` or ``"second"`` (the smaller value), ``"tie"`` (within ``tie``, or a
        difference its test does not find significant at :data:`SIGNIFICANCE`), or None if
        not measured."""
        if math.isnan(self.first) or math.isnan(self.second):
            return None
        diff = self.first - self.second
        if abs(diff) <= self.tie + 1e-12 or self.p >= SIGNIFICANCE:
            return "tie"
        return "first" if diff < 0 else "second"

    def shown(self, value: float) -> str:
        """One value as the pages print it."""
        return format_number(value) if self.tie else str(int(value))

    def test_text(self) -> str:
        """``McNemar p = 0.031, significant at 0.05`` (or the sign test's) for a difference."""
        test = "sign test" if self.tie else "McNemar"
        word = "significant" if self.p < SIGNIFICANCE else "not significant"
        return f"{test} p = {self.p:.3g}, {word} at {SIGNIFICANCE:g}"


@dataclass(frozen=True)
class PairVerdict:
    """Two planners compared on :data:`CRITERIA` (:func:`compare`)."""

    first: str
    second: str
    seeds: int  # labelled seeds both ran
    criteria: tuple[Criterion, ...]

    @property
    def dominant(self) -> str | None:
        """The planner at least as good on every criterion and better on one; None if neither
        is (or a criterion could not be measured)."""
        sides = [c.better for c in self.criteria]
        if None in sides:
            return None
        for side, name in (("first", self.first), ("second", self.second)):
            other = "second" if side == "first" else "first"
            if side in sides and other not in sides:
                return name
        return None

    def text(self) -> str:
        """The verdict in one sentence, with the values and tests of each criterion that differs."""
        def said(c: Criterion) -> str:
            unit = " s" if c.tie else ""
            return (f"{c.name.removesuffix(' [s]')} ({c.shown(c.first)}{unit} vs {c.shown(c.second)}{unit}, "
                    f"{c.test_text()})")

        missing = [c.name for c in self.criteria if c.better is None]
        if missing:
            return (f"not judged: {', '.join(missing)} not measured ({self.seeds} seeds; interventions need "
                    "records with `intervention`, the time lost also the same seeds' `constant` episodes)")
        wins = {side: [said(c) for c in self.criteria if c.better == side] for side in ("first", "second")}
        if self.dominant is not None:
            loser = self.second if self.dominant == self.first else self.first
            side = "first" if self.dominant == self.first else "second"
            return (f"**{self.dominant} dominates {loser}**: at least as good on all four, better on "
                    + "; ".join(wins[side]) + ".")
        if not wins["first"]:
            return "tied on all four: no dominance."
        return (f"no dominance: {self.first} better on {'; '.join(wins['first'])}; {self.second} better on "
                f"{'; '.join(wins['second'])}.")


def _by_seed(records: Iterable[RecordLike], planner: str) -> dict[int, RecordLike]:
    return {int(record_field(r, "seed")): r for r in completed(records)
            if record_field(r, "planner") == planner and record_field(r, "label") is not None}


def _count(name: str, pairs: Sequence[tuple[RecordLike, RecordLike]],
           rule: Callable[[RecordLike], bool | None]) -> Criterion:
    """A count criterion over ``pairs`` (first, second) on which ``rule`` is known for both;
    not measured (NaN) where it is known for none (records written before ``intervention``)."""
    known = [(bool(x), bool(y)) for x, y in ((rule(a), rule(b)) for a, b in pairs) if x is not None and y is not None]
    if pairs and not known:
        return Criterion(name, math.nan, math.nan, 0, 0, 0)
    return Criterion(name, float(sum(x for x, _ in known)), float(sum(y for _, y in known)),
                     sum(1 for x, y in known if x and not y), sum(1 for x, y in known if y and not x), len(known))


def _time_lost(pairs: Sequence[tuple[RecordLike, RecordLike]], reference: Mapping[int, RecordLike]) -> Criterion:
    """Mean time lost at the fixed point against ``reference``, on the non-Cutoff seeds on
    which none of the three collided; discordant seeds by the pass times."""
    lost: list[tuple[float, float]] = []
    for a, b in pairs:
        ref = reference.get(int(record_field(a, "seed")))
        trio = (a, b, ref) if ref is not None else ()
        times = [pass_time(r) for r in trio]
        if (not trio or is_imminent(a) or any(t is None for t in times)
                or any(record_field(r, "collision") for r in trio)):
            continue
        ta, tb, tr = (float(t) for t in times)  # type: ignore[arg-type]
        lost.append((ta - tr, tb - tr))
    mean = (lambda i: statistics.fmean(x[i] for x in lost)) if lost else (lambda i: math.nan)
    return Criterion(CRITERIA[3], mean(0), mean(1), sum(1 for x, y in lost if x > y + _SEED_TIE),
                     sum(1 for x, y in lost if y > x + _SEED_TIE), len(lost), tie=TIME_TIE)


def compare(records: Iterable[RecordLike], first: str, second: str, reference: str = "constant") -> PairVerdict:
    """``first`` against ``second`` on :data:`CRITERIA`, seed by seed on the labelled seeds
    both completed; the time lost against ``reference``'s records of the same seeds."""
    records = list(records)
    a, b = _by_seed(records, first), _by_seed(records, second)
    pairs = [(a[s], b[s]) for s in sorted(a.keys() & b.keys())]
    others = [(x, y) for x, y in pairs if not is_imminent(x)]
    criteria = (_count(CRITERIA[0], pairs, hit_obstacle), _count(CRITERIA[1], others, intervened),
                _count(CRITERIA[2], others, is_false_alarm),
                _time_lost(others, _by_seed(records, reference)))
    return PairVerdict(first, second, len(pairs), criteria)


def pareto_lines(records: Iterable[RecordLike], first: str, others: Sequence[str],
                 reference: str = "constant") -> list[str]:
    """Markdown: ``first`` against each of ``others`` that ran (:func:`compare`), a table of
    the four criteria with their tests, then one verdict line per pair."""
    records = list(records)
    ran = {record_field(r, "planner") for r in records}
    verdicts = [compare(records, first, other, reference) for other in others if other in ran and other != first]
    if first not in ran or not verdicts:
        return [f"No pair to compare (`{first}` and another planner are needed)."]
    rows = []
    for v in verdicts:
        cells = [f"{c.shown(c.first)} / {c.shown(c.second)} ({c.only_first} / {c.only_second}; "
                 f"p = {c.p:.3g})" if c.better is not None else "-" for c in v.criteria]
        rows.append([f"{first} / {v.second}", str(v.seeds), *cells,
                     v.dominant or ("not judged" if any(c.better is None for c in v.criteria) else "none")])
    header = ["pair", "seeds", *(f"{name}: first / second (discordant seeds; p)" for name in CRITERIA), "dominates"]
    return [*markdown_table(header, rows), "",
            f"Each cell: the first planner's value / the second's, then the seeds on which only the first / only "
            f"the second has it (for the time lost: loses more), and the exact two-sided p-value on those seeds "
            f"(McNemar; the sign test for the time lost). Collisions of any label; the rest over the episodes not "
            f"labelled Cutoff; time lost at the fixed point against `{reference}`, on the seeds on which neither "
            f"planner nor `{reference}` collided; means within {TIME_TIE:g} s are a tie. A planner dominates when "
            "it is at least as good on all four and better on one; p < "
            f"{SIGNIFICANCE:g} is called significant ('-': not measured).", "",
            *(f"- {v.first} / {v.second}: {v.text()}" for v in verdicts)]


def comparisons(planners: Sequence[str], firsts: Sequence[str] = DECIDERS,
                reference: str = "constant") -> list[tuple[str, list[str]]]:
    """Each of ``firsts`` in ``planners``, in order, with the planners it is set against:
    every other one but ``reference``, the earlier of ``firsts`` first and the later left out
    (a pair of two of ``firsts`` is compared once, the later first: for :data:`DECIDERS`,
    ``cdf-option / cdf`` says what the option rule buys over the default and what it costs)."""
    mine = [f for f in dict.fromkeys(firsts) if f in planners]
    rest = [p for p in planners if p not in mine and p != reference]
    return [(f, [*mine[:i], *rest]) for i, f in enumerate(mine)]


# ----------------------------------------------------------------- the Pareto figure's points
@dataclass(frozen=True)
class ParetoPoint:
    """One planner (or one tuning point) on the axes of the Pareto figure."""

    name: str
    interventions: Rate  # episodes not labelled Cutoff with an intervention, of them
    time_lost: float  # [s] mean non-Cutoff time lost at the fixed point vs the reference (NaN: none)
    hard_brakes: Rate  # episodes not labelled Cutoff with a hard brake, of them
    collisions: int  # episodes of any label with a collision with the obstacle

    @classmethod
    def of(cls, m: PlannerMetrics, name: str | None = None) -> ParetoPoint:
        """The point of one planner's metrics."""
        return cls(name or m.planner, m.false_interventions, m.time_lost_fixed,
                   Rate(m.false_alarms.k, m.episodes - m.imminent), m.collisions)


def pareto_points(metrics: Mapping[str, PlannerMetrics], reference: str = "constant") -> list[ParetoPoint]:
    """The points of every planner in ``metrics`` but ``reference`` (it is the origin of
    the time lost and intervenes never)."""
    return [ParetoPoint.of(m) for name, m in metrics.items() if name != reference]


def tuning_points(directory: str | Path, scenario: str = "default", planner: str = "cdf") -> list[ParetoPoint]:
    """``planner``'s point at each tuning run ``DIRECTORY/SCENARIO/*`` (the
    :func:`~cdf_mj.experiments.experiment.run_experiment` directories that
    scripts/tune_option.py writes), named by its rule (:func:`rule_label` of the run's
    ``cdf.layered`` settings: ``option 0.5 s, 0.9``, ``go 0.1``; the folder's name for a run
    without them); runs without ``planner`` records are skipped. ValueError if
    ``DIRECTORY/SCENARIO`` is not a folder or holds no run."""
    root = Path(directory) / scenario
    if not root.is_dir():
        raise ValueError(f"tuning directory {directory}: no folder {scenario!r} in it (expected "
                         f"{directory}/{scenario}/<option_time>-<anticipate> or go-<anticipate>)")
    points = []
    for run in sorted(p for p in root.iterdir() if (p / "settings.json").is_file()):
        layered = (read_settings(run / "settings.json").get("cdf") or {}).get("layered") or {}
        name = rule_label(layered) if "anticipate" in layered else run.name
        m = planner_metrics(load_records(run)).get(planner)
        if m is not None:
            points.append(ParetoPoint.of(m, name))
    if not points:
        raise ValueError(f"tuning directory {root}: no run with {planner!r} records")
    return points


# ----------------------------------------------------------------- tables and words
def intervention_lines(metrics: Mapping[str, PlannerMetrics], reference: str = "constant") -> list[str]:
    """:func:`~cdf_mj.analysis.tables.intervention_table` in Markdown, as the pages' lines."""
    return intervention_table(metrics.values(), "markdown", reference).split("\n")


_ROLE = re.compile(r":[a-z]+:`~?([^`<]+?)(?:\s*<[^>]+>)?`")


def planner_line(name: str) -> str:
    """One line on what the registered planner ``name`` is: :data:`CDF_LINE` for ``cdf``,
    otherwise the first sentence of its class's docstring as plain Markdown (Sphinx roles
    become code spans of their last name). ValueError for an unknown planner."""
    if name == "cdf":
        return CDF_LINE
    target = planner_spec(name).target
    doc = (target.resolve() if isinstance(target, LazyPlanner) else target).__doc__ or ""
    text = " ".join(doc.strip().split("\n\n", 1)[0].split())
    text = _ROLE.sub(lambda m: f"`{m[1].split('.')[-1]}`", text).replace("``", "`")
    text = re.sub(rf"^`{re.escape(name)}`:\s*", "", text)
    return _first_sentence(text) or "(no docstring)"


def planner_item(name: str) -> str:
    """Markdown list item on the registered planner ``name``: its :func:`planner_line` and, if
    it decides by the layered rule, that rule's anticipation (:func:`layered_label`)."""
    label = layered_label(name)
    return f"- `{name}`: {planner_line(name)}" + (f" Layered rule: {label}." if label else "")


def _first_sentence(text: str) -> str:
    """``text`` up to its first full stop outside brackets that a capital letter follows."""
    depth = 0
    for i, char in enumerate(text):
        depth += (char in "([") - (char in ")]")
        if char == "." and depth == 0 and text[i + 1:i + 2] == " " and text[i + 2:i + 3].isupper():
            return text[:i + 1]
    return text


def _judged(ok: bool, measured: bool) -> str:
    return verdict(ok) if measured else "not measured"


def cost_targets(m: PlannerMetrics, reference: str = "constant") -> list[str]:
    """Markdown bullets: issue 35's targets on one planner's counts, judged on the point
    estimates: no collision with the obstacle, avoided by the paper's formula >= 99.5 %,
    interventions in <= 10 % of the episodes not labelled Cutoff, hard brakes in <= 1 % of
    them, a mean time lost there <= 0.05 s (at the fixed point, against ``reference``)."""
    others = m.episodes - m.imminent
    hard, iv, lost = Rate(m.false_alarms.k, others), m.false_interventions, m.time_lost_fixed
    formula = (f"{format_percent(m.paper_avoided)} ({m.imminent - m.collisions}/{m.imminent})" if m.imminent
               else "no Cutoff episode")
    return [f"- no collision with the obstacle, any label: {m.collisions} of {m.episodes}: {verdict(not m.collisions)}",
            f"- avoided, paper's formula, >= 99.5 %: {formula}: "
            f"{_judged(m.paper_avoided >= 0.995, m.imminent > 0)}",
            f"- interventions in <= 10 % of the episodes not labelled Cutoff: {format_rate(iv)}: "
            f"{_judged(iv.value <= 0.10, iv.n > 0)}",
            f"- hard brakes in <= 1 % of them: {format_rate(hard)}: {_judged(hard.value <= 0.01, hard.n > 0)}",
            f"- mean time lost in them <= 0.05 s (at the fixed point, vs `{reference}`): {format_number(lost, 3)} s"
            + (f" over {m.time_lost_fixed_seeds} seeds" if m.time_lost_fixed_seeds else
               f" (no same-seed `{reference}` episode)") + f": {_judged(lost <= 0.05, not math.isnan(lost))}"]
