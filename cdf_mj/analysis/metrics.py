"""Rates with confidence intervals and the metrics of a set of episode records: label
shares, each planner's outcomes, the CDF's predictions, seed-by-seed comparisons, the
braking threshold's operating curve and the Brier scores of the filters' probabilities.

No action is free: besides hard brakes (:func:`~cdf_mj.records.is_false_alarm`), every
intervention is counted (:func:`~cdf_mj.records.intervened`: the planner held the ego below
its own controller by more than a tolerance), with its peak deceleration, and the time lost
is measured at a fixed point (the ego passing ``timing.label_distance`` beyond the conflict
point) against the same seed's ``constant`` ego, which follows a slower car too. The Cutoff
seeds on which that ego's ACC alone hit the obstacle are the hard subset.

Every count applies a rule of :mod:`cdf_mj.records` (:func:`~cdf_mj.records.avoided`,
:func:`~cdf_mj.records.is_false_alarm`, :func:`~cdf_mj.records.lead_time`, ...); the
tables (:mod:`cdf_mj.analysis.tables`), the report's figures and the sweeps print and draw
these metrics, so a rate means the same everywhere. Records may be dicts (lines of a
records file) or :class:`~cdf_mj.records.EpisodeRecord` objects; failed records
(``"status": "failed"``) and unlabelled ones are left out where a label is needed.

Every rate is reported with its 95 % Wilson score interval, which stays inside [0, 1]
and behaves at small counts and at 0 % or 100 % (where the normal approximation fails).

The Brier score of a probability forecast p of an event with truth y in {0, 1} is the
mean of (p - y)^2: 0 is perfect, a constant 0.5 scores 0.25. :func:`brier_over_time`
scores a filter's per-tick history (``planner_info["history"]``) against the truth of the
episode: ``p_left`` against the obstacle's true intent, ``p_seen`` against whether the
obstacle had observed the ego on an earlier tick (from the record's ``first_seen_time``).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from cdf_mj.records import (
    LABELS,
    EpisodeRecord,
    Label,
    RecordLike,
    avoided,
    braked,
    completed,
    hit_obstacle,
    intervened,
    is_false_alarm,
    is_imminent,
    lead_time,
    paper_avoided,
    pass_time,
    prediction,
    record_field,
)

__all__ = [
    "FILTER_QUANTITIES",
    "BrierCurve",
    "PairedCounts",
    "PlannerMetrics",
    "Rate",
    "brier_over_time",
    "brier_score",
    "confusion_matrix",
    "cutoff_recall",
    "decision_time",
    "mcnemar_exact",
    "of_planner",
    "paired_counts",
    "planner_metrics",
    "prior_brier",
    "scenario_summary",
    "tau_curve",
    "wilson_interval",
]


def wilson_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval for ``k`` successes in ``n`` trials (default 95 %)."""
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return (lo, hi)


@dataclass(frozen=True)
class Rate:
    """``k`` of ``n``, with its 95 % Wilson interval."""

    k: int
    n: int

    @property
    def value(self) -> float:
        """The rate k / n (NaN when n = 0)."""
        return self.k / self.n if self.n else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        """95 % Wilson interval."""
        return wilson_interval(self.k, self.n)

    def __str__(self) -> str:
        lo, hi = self.interval
        return f"{100 * self.value:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({self.k}/{self.n})"

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view."""
        lo, hi = self.interval
        return {"k": self.k, "n": self.n, "value": self.value, "ci95": [lo, hi]}


_R = TypeVar("_R", bound=RecordLike)


def of_planner(records: Iterable[_R], planner: str) -> list[_R]:
    """The records of ``planner`` (its ``planner`` field), in their order."""
    return [r for r in records if record_field(r, "planner") == planner]


def _labelled(records: Iterable[RecordLike]) -> list[RecordLike]:
    """The completed records that carry a scenario label."""
    return [r for r in completed(records) if record_field(r, "label") is not None]


def scenario_summary(records: Iterable[RecordLike]) -> dict[str, Rate]:
    """Label shares and collision avoidance of episode records.

    Returns ``Cutoff``, ``Yield``, ``Right``: shares of all labelled episodes, and
    ``avoided``: Cutoff episodes without a collision with the obstacle
    (:func:`~cdf_mj.records.avoided`), of all Cutoff episodes.
    """
    recs = _labelled(records)
    counts = Counter(record_field(r, "label") for r in recs)
    out = {str(lab): Rate(counts.get(lab, 0), len(recs)) for lab in LABELS}
    out["avoided"] = Rate(sum(map(avoided, recs)), sum(map(is_imminent, recs)))
    return out


def confusion_matrix(records: Iterable[RecordLike]) -> dict[str, tuple[int, int, int]]:
    """Scenario label -> counts of predicted ``Cutoff``, ``Yield``, ``Right``
    (:func:`~cdf_mj.records.prediction`), over the labelled records given (those without a
    prediction are in no column)."""
    recs = _labelled(records)
    pairs = Counter((record_field(r, "label"), prediction(r)) for r in recs)
    return {str(a): (pairs[(a, LABELS[0])], pairs[(a, LABELS[1])], pairs[(a, LABELS[2])]) for a in LABELS}


def cutoff_recall(records: Iterable[RecordLike]) -> Rate:
    """Cutoff episodes predicted ``Cutoff`` (:func:`~cdf_mj.records.prediction`), of all
    Cutoff episodes."""
    cut = [r for r in _labelled(records) if is_imminent(r)]
    return Rate(sum(1 for r in cut if prediction(r) == Label.CUTOFF), len(cut))


# ----------------------------------------------------------------- planners and filters
#: The probabilities a filter's history may hold that have a truth in the record.
FILTER_QUANTITIES = ("p_left", "p_seen")


def brier_score(probs: Sequence[float] | np.ndarray, truths: Sequence[float] | np.ndarray) -> float:
    """Mean of ``(p - y)^2`` over paired forecasts ``p`` in [0, 1] and outcomes ``y`` in {0, 1}."""
    p = np.asarray(probs, dtype=float)
    y = np.asarray(truths, dtype=float)
    if p.shape != y.shape or p.size == 0:
        raise ValueError(f"need as many forecasts as outcomes, at least one; got {p.shape} and {y.shape}")
    if not np.all((p >= 0) & (p <= 1)):
        raise ValueError("forecasts must be probabilities in [0, 1]")
    if not np.all((y == 0) | (y == 1)):
        raise ValueError("outcomes must be 0 or 1")
    return float(np.mean((p - y) ** 2))


def _truth(rec: RecordLike, quantity: str, times: np.ndarray) -> np.ndarray:
    """Per-tick truth of ``quantity`` in one episode (see :func:`brier_over_time`)."""
    if quantity == "p_left":
        return np.full(len(times), 1.0 if record_field(rec, "intent") == "left" else 0.0)
    seen = record_field(rec, "first_seen_time")
    if seen is None:
        return np.zeros(len(times))
    return np.asarray(np.asarray(times) > seen + 1e-6, dtype=float)


@dataclass(frozen=True)
class BrierCurve:
    """Brier score of one filter quantity over many episodes, overall and per tick time."""

    quantity: str  # "p_left" or "p_seen"
    overall: float  # mean over every (episode, tick) pair; NaN without data
    episodes: int  # episodes with a history of this quantity
    ticks: int  # (episode, tick) pairs scored
    times: np.ndarray  # (T,) tick times [s]
    scores: np.ndarray  # (T,) Brier score over the episodes still running at that time
    counts: np.ndarray  # (T,) episodes still running at that time
    reference: np.ndarray  # (T,) Brier score of the base rate at that time (in-sample)

    @property
    def reference_overall(self) -> float:
        """Brier score of the per-time base rate over all ticks: the best forecast that
        uses the time alone, fitted on these same episodes (a floor for time-only forecasts)."""
        n = self.counts.sum()
        return float((self.reference * self.counts).sum() / n) if n else math.nan


def _history(rec: RecordLike) -> Mapping[str, Any]:
    """The per-tick history a filter planner keeps in ``planner_info`` (empty if none)."""
    return (record_field(rec, "planner_info") or {}).get("history") or {}


def brier_over_time(records: Iterable[RecordLike], quantity: str = "p_left") -> BrierCurve:
    """Brier score of a filter's per-tick probability ``quantity`` against the truth.

    Truth: for ``p_left``, the obstacle's intent was left; for ``p_seen``, the obstacle had
    observed the ego on a tick before this one (``first_seen_time < t``). A planner
    decides at tick t on the pose measured at the start of the tick, before the obstacle
    looks on that tick, so no filter can know of a look at t: ``p_seen`` at t is the
    probability of an observation on the ticks 0 ... t - dt. Records without a history of
    ``quantity`` in ``planner_info`` (non-filter planners, failed episodes) are skipped.
    """
    if quantity not in FILTER_QUANTITIES:
        raise ValueError(f"unknown filter quantity {quantity!r}: choose one of {', '.join(FILTER_QUANTITIES)}")
    by_time: dict[float, list[tuple[float, float]]] = {}
    episodes = 0
    for rec in completed(records):
        hist = _history(rec)
        if not hist.get(quantity):
            continue
        episodes += 1
        times = np.round(np.asarray(hist["t"], dtype=float), 6)
        probs = np.asarray(hist[quantity], dtype=float)
        for t, p, y in zip(times, probs, _truth(rec, quantity, times), strict=True):
            by_time.setdefault(float(t), []).append((float(p), float(y)))
    times = np.array(sorted(by_time))
    scores, counts, reference = [], [], []
    total, n = 0.0, 0
    for t in times:
        pairs = np.array(by_time[float(t)])
        sq = (pairs[:, 0] - pairs[:, 1]) ** 2
        scores.append(float(sq.mean()))
        counts.append(len(pairs))
        base = pairs[:, 1].mean()
        reference.append(float(np.mean((base - pairs[:, 1]) ** 2)))
        total += float(sq.sum())
        n += len(pairs)
    return BrierCurve(quantity=quantity, overall=total / n if n else math.nan, episodes=episodes,
                      ticks=n, times=times, scores=np.array(scores), counts=np.array(counts, dtype=int),
                      reference=np.array(reference))


def prior_brier(records: Iterable[RecordLike], p_left: float = 0.75) -> float:
    """Brier score of the prior ``p_left`` held constant as a forecast of the obstacle's
    intent being left, over the completed records (a reference for P(left)); NaN if none."""
    y = np.array([record_field(r, "intent") == "left" for r in completed(records)], dtype=float)
    return float(np.mean((p_left - y) ** 2)) if y.size else math.nan


@dataclass(frozen=True)
class PlannerMetrics:
    """One planner's outcomes over many labelled episodes, each counted by a rule of
    :mod:`cdf_mj.records`."""

    planner: str
    episodes: int
    imminent: int  # episodes labelled Cutoff (is_imminent)
    collisions: int  # episodes in which the ego touched the obstacle, any label (hit_obstacle)
    avoided: Rate  # Cutoff episodes without a collision with the obstacle (avoided), of the Cutoff ones
    false_alarms: Rate  # episodes not labelled Cutoff in which the planner braked hard (is_false_alarm), of all
    lead_time: float  # [s] median lead_time over braking Cutoff episodes (NaN if none)
    min_gap: float  # [m] median of the smallest gap between the cars, over all episodes
    time_lost: float  # [s] mean over episodes without a collision (NaN if none)
    brier_left: float | None  # Brier score of P(left) over all ticks (filters only)
    brier_seen: float | None  # Brier score of P(seen) over all ticks (filters that model belief)
    # The counts of the decision rule's report (docs/DECISION.md), each by a rule of records:
    recall: Rate = Rate(0, 0)  # Cutoff episodes it predicted (braked; or a graded rule slowed for), of them
    false_alarms_yield: Rate = Rate(0, 0)  # Yield episodes in which it braked, of the Yield ones
    false_discovery: Rate = Rate(0, 0)  # episodes not labelled Cutoff, of those in which it braked
    collisions_yield: int = 0  # Yield episodes with a collision with the obstacle
    collisions_right: int = 0  # Right episodes with a collision with the obstacle
    # Every intervention (records.intervened: held below its own controller by more than the
    # tolerance, hard brake or not), over the records that carry ``intervention``:
    interventions: dict[str, Rate] = field(default_factory=dict)  # label -> episodes with one, of that label's
    false_interventions: Rate = Rate(0, 0)  # episodes not labelled Cutoff with one, of those
    intervention_recall: Rate = Rate(0, 0)  # Cutoff episodes with one, of those
    peak_decel: float = math.nan  # [m/s^2] median peak deceleration over the non-Cutoff episodes with one
    # [s] mean over episodes not labelled Cutoff of pass_time minus the same seed's reference
    # (``constant``) record's: the time lost at the fixed point (timing.label_distance past the
    # conflict point), so that following a slower car, which the reference ego does too, is
    # not charged. Pairs in which either ego collided are left out; NaN without a pair.
    time_lost_fixed: float = math.nan
    time_lost_fixed_seeds: int = 0  # the seeds (pairs) it is the mean of
    time_lost_fixed_by_label: dict[str, float] = field(default_factory=dict)  # label -> the same per label
    # The hard subset: Cutoff seeds on which the reference (``constant``) ego, its ACC alone,
    # hit the obstacle; and those of them it avoided.
    hard_cutoffs: int = 0
    hard_avoided: Rate = Rate(0, 0)
    without_intervention: int = 0  # its records without ``intervention`` (written before it was kept)

    @property
    def paper_avoided(self) -> float:
        """The paper's count, ``(imminent - collisions) / imminent``
        (:func:`cdf_mj.records.paper_avoided`)."""
        return paper_avoided(self.imminent, self.collisions)

    def to_row(self) -> dict[str, float | int | str | None]:
        """Flat, JSON- and CSV-ready view (rates as fractions with their 95 % interval)."""
        row: dict[str, float | int | str | None] = {"planner": self.planner, "episodes": self.episodes,
                                                    "imminent": self.imminent, "collisions": self.collisions}
        rates = {name: getattr(self, name) for name in ("avoided", "false_alarms", "recall", "false_alarms_yield",
                                                        "false_discovery", "false_interventions",
                                                        "intervention_recall", "hard_avoided")}
        rates |= {f"interventions_{lab}": rate for lab, rate in self.interventions.items()}
        for name, rate in rates.items():
            lo, hi = rate.interval
            row.update({name: rate.value, f"{name}_lo": lo, f"{name}_hi": hi, f"{name}_k": rate.k,
                        f"{name}_n": rate.n})
        row.update({"lead_time": self.lead_time, "min_gap": self.min_gap, "time_lost": self.time_lost,
                    "brier_left": self.brier_left, "brier_seen": self.brier_seen,
                    "collisions_yield": self.collisions_yield, "collisions_right": self.collisions_right,
                    "peak_decel": self.peak_decel, "time_lost_fixed": self.time_lost_fixed,
                    "time_lost_fixed_seeds": self.time_lost_fixed_seeds, "hard_cutoffs": self.hard_cutoffs,
                    "without_intervention": self.without_intervention})
        row.update({f"time_lost_fixed_{lab}": value for lab, value in self.time_lost_fixed_by_label.items()})
        return row


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else math.nan


def _mean(values: list[float]) -> float:
    return float(statistics.fmean(values)) if values else math.nan


def _intervention_metrics(recs: list[RecordLike], by_label: Mapping[str, list[RecordLike]],
                          reference: Mapping[int, RecordLike]) -> dict[str, Any]:
    """The intervention fields of one planner's :class:`PlannerMetrics` from its labelled
    records ``recs`` (``by_label``) and the reference planner's records by seed."""
    have = {lab: [r for r in by_label[lab] if intervened(r) is not None] for lab in LABELS}
    others = have[Label.YIELD] + have[Label.RIGHT]
    lost: dict[str, list[float]] = {lab: [] for lab in LABELS}
    for lab in LABELS:
        for r in have[lab]:
            ref = reference.get(record_field(r, "seed"))
            if ref is not None and pass_time(ref) is not None and not (
                    record_field(r, "collision") or record_field(ref, "collision")):
                lost[lab].append(pass_time(r) - pass_time(ref))  # type: ignore[operator]
    lost_others = lost[Label.YIELD] + lost[Label.RIGHT]
    hard = [r for r in by_label[Label.CUTOFF] if (ref := reference.get(record_field(r, "seed"))) is not None
            and is_imminent(ref) and hit_obstacle(ref)]
    def rate(recs: list[RecordLike]) -> Rate:
        return Rate(sum(1 for r in recs if intervened(r)), len(recs))

    return {"interventions": {str(lab): rate(have[lab]) for lab in LABELS},
            "false_interventions": rate(others), "intervention_recall": rate(have[Label.CUTOFF]),
            "peak_decel": _median([record_field(r, "intervention")["peak_decel"] for r in others if intervened(r)]),
            "time_lost_fixed": _mean(lost_others), "time_lost_fixed_seeds": len(lost_others),
            "time_lost_fixed_by_label": {str(lab): _mean(lost[lab]) for lab in LABELS},
            "hard_cutoffs": len(hard), "hard_avoided": Rate(sum(map(avoided, hard)), len(hard)),
            "without_intervention": len(recs) - sum(map(len, have.values()))}


def planner_metrics(records: Iterable[RecordLike], reference: str = "constant") -> dict[str, PlannerMetrics]:
    """:class:`PlannerMetrics` per planner name, in order of first appearance; failed
    episodes (``"status": "failed"``) and unlabelled ones are left out. ``reference`` names
    the planner whose records, seed by seed, time lost at the fixed point is measured
    against and whose collisions make the hard subset (none of its records: NaN and 0)."""
    by_planner: dict[str, list[RecordLike]] = {}
    for rec in _labelled(records):
        by_planner.setdefault(record_field(rec, "planner"), []).append(rec)
    ref = {record_field(r, "seed"): r for r in by_planner.get(reference, ())}
    out: dict[str, PlannerMetrics] = {}
    for name, recs in by_planner.items():
        by_label: dict[str, list[RecordLike]] = {lab: [] for lab in LABELS}
        for r in recs:
            by_label[record_field(r, "label")].append(r)
        leads = [t for t in map(lead_time, recs) if t is not None]
        intact = [record_field(r, "time_lost") for r in recs if not record_field(r, "collision")]
        brier = {}
        for q in FILTER_QUANTITIES:
            curve = brier_over_time(recs, q)
            brier[q] = curve.overall if curve.episodes else None
        out[name] = PlannerMetrics(
            planner=name, episodes=len(recs), imminent=sum(map(is_imminent, recs)),
            collisions=sum(map(hit_obstacle, recs)),
            avoided=Rate(sum(map(avoided, recs)), sum(map(is_imminent, recs))),
            false_alarms=Rate(sum(map(is_false_alarm, recs)), len(recs)),
            lead_time=_median(leads), min_gap=_median([record_field(r, "min_gap") for r in recs]),
            time_lost=_mean(intact),
            brier_left=brier["p_left"], brier_seen=brier["p_seen"],
            recall=cutoff_recall(recs),
            false_alarms_yield=Rate(sum(map(is_false_alarm, by_label[Label.YIELD])), len(by_label[Label.YIELD])),
            false_discovery=Rate(sum(map(is_false_alarm, recs)), sum(map(braked, recs))),
            collisions_yield=sum(map(hit_obstacle, by_label[Label.YIELD])),
            collisions_right=sum(map(hit_obstacle, by_label[Label.RIGHT])),
            **_intervention_metrics(recs, by_label, ref))
    return out


@dataclass(frozen=True)
class PairedCounts:
    """Two planners compared seed by seed (common random numbers), on the seeds both ran."""

    first: str
    second: str
    seeds: int  # labelled seeds both planners ran
    collides_only_first: int  # Cutoff episodes in which only the first hits the obstacle
    collides_only_second: int
    false_alarm_only_first: int  # episodes not labelled Cutoff in which only the first brakes
    false_alarm_only_second: int
    false_alarm_both: int
    hit_only_first: int = 0  # episodes of any label in which only the first hits the obstacle
    hit_only_second: int = 0  # (the paper's count of collisions)
    # Episodes not labelled Cutoff, both records carrying ``intervention``, in which only the
    # first, only the second, or both intervene (records.intervened; for McNemar's test).
    intervene_only_first: int = 0
    intervene_only_second: int = 0
    intervene_both: int = 0


def paired_counts(records: Iterable[RecordLike], first: str, second: str) -> PairedCounts:
    """:class:`PairedCounts` of planners ``first`` and ``second`` (collisions by
    :func:`~cdf_mj.records.hit_obstacle`, false alarms by
    :func:`~cdf_mj.records.is_false_alarm`, interventions by
    :func:`~cdf_mj.records.intervened`)."""
    by_key = {(record_field(r, "planner"), record_field(r, "seed")): r for r in _labelled(records)}
    seeds = sorted({s for p, s in by_key if p == first} & {s for p, s in by_key if p == second})
    counts = [0] * 10
    for seed in seeds:
        a, b = by_key[(first, seed)], by_key[(second, seed)]
        counts[5] += hit_obstacle(a) and not hit_obstacle(b)
        counts[6] += hit_obstacle(b) and not hit_obstacle(a)
        if is_imminent(a):
            hit_a, hit_b = hit_obstacle(a), hit_obstacle(b)
            counts[0] += hit_a and not hit_b
            counts[1] += hit_b and not hit_a
        else:
            alarm_a, alarm_b = is_false_alarm(a), is_false_alarm(b)
            counts[2] += alarm_a and not alarm_b
            counts[3] += alarm_b and not alarm_a
            counts[4] += alarm_a and alarm_b
            did_a, did_b = intervened(a), intervened(b)
            if did_a is not None and did_b is not None:
                counts[7] += did_a and not did_b
                counts[8] += did_b and not did_a
                counts[9] += did_a and did_b
    return PairedCounts(first, second, len(seeds), *counts)


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value for ``b`` and ``c`` discordant pairs (for example
    :class:`PairedCounts`' ``collides_only_first`` and ``collides_only_second``): the
    binomial test of ``min(b, c)`` successes in ``b + c`` trials at 1/2; 1.0 without
    discordant pairs. ValueError for a negative count."""
    if b < 0 or c < 0:
        raise ValueError(f"mcnemar_exact: counts must be >= 0, got {b} and {c}")
    n = b + c
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(b, c) + 1)) / 2**n
    return min(1.0, 2 * tail)


# ----------------------------------------------------------------- the braking threshold
def decision_time(rec: RecordLike, tau: float) -> float | None:
    """[s] the first tick of a filter's history at which ``P(cutoff) >= tau``: where a run
    with braking threshold ``tau`` brakes, for every ``tau`` up to the one the record was
    run with (before the ego brakes the history does not depend on the threshold: same
    seed, same random streams). None if it never reaches ``tau``."""
    hist = _history(rec)
    for t, p in zip(hist.get("t", ()), hist.get("p_cutoff", ()), strict=True):
        if p >= tau:
            return float(t)
    return None


def _with_brake_time(rec: RecordLike, brake_time: float | None) -> RecordLike:
    """The record as it would read had the planner braked at ``brake_time``."""
    if isinstance(rec, EpisodeRecord):
        return dataclasses.replace(rec, brake_time=brake_time)
    return {**rec, "brake_time": brake_time}


def tau_curve(records: Iterable[RecordLike], tau_max: float, step: float = 0.01) -> list[dict[str, Any]]:
    """False alarms and detections of the CDF for thresholds ``step, 2 step, ..., tau_max``,
    read from the P(cutoff) histories of CDF records run at ``tau_max``
    (:func:`decision_time`: exact up to ``tau_max``). Each record is judged as if the CDF
    had braked at that decision time: a false alarm by
    :func:`~cdf_mj.records.is_false_alarm`, of all episodes; a detection is a Cutoff
    episode braked for before the obstacle entered the ego lane (positive
    :func:`~cdf_mj.records.lead_time`, or no entry), of the Cutoff episodes. Collisions are
    not derived. Rates carry their 95 % Wilson interval."""
    recs = [r for r in _labelled(records) if record_field(r, "planner") == "cdf"]
    n_cut = sum(map(is_imminent, recs))
    out = []
    for tau in np.arange(step, tau_max + 1e-9, step):
        tau = round(float(tau), 6)
        fa = det = 0
        times = []
        for r in recs:
            d = decision_time(r, tau)
            at_tau = _with_brake_time(r, d)
            fa += is_false_alarm(at_tau)
            lead = lead_time(at_tau)
            if d is not None and is_imminent(r) and (lead is None or lead > 0):
                det += 1
                times.append(d)
        far, detr = Rate(fa, len(recs)), Rate(det, n_cut)
        out.append({"tau": tau, "false_alarms": far.value, "false_alarms_lo": far.interval[0],
                    "false_alarms_hi": far.interval[1], "false_alarms_k": fa, "episodes": len(recs),
                    "detected": detr.value, "detected_k": det, "cutoffs": n_cut,
                    "median_decision_time": float(np.median(times)) if times else math.nan})
    return out
