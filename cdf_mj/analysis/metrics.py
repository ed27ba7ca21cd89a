"""Rates with confidence intervals, the scenario summary of a set of episode records, the
per-planner metrics and the Brier scores of the filters' probabilities.

Every rate is reported with its 95 % Wilson score interval, which stays inside [0, 1]
and behaves at small counts and at 0 % or 100 % (where the normal approximation fails).

The Brier score of a probability forecast p of an event with truth y in {0, 1} is the
mean of (p - y)^2: 0 is perfect, a constant 0.5 scores 0.25. :func:`brier_over_time`
scores a filter's per-tick history (``planner_info["history"]``) against the truth of the
episode: ``p_left`` against the obstacle's true intent, ``p_seen`` against whether the
obstacle had observed the ego on an earlier tick (from the record's ``first_seen_time``).
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from cdf_mj.records import Labels

__all__ = [
    "FILTER_QUANTITIES",
    "BrierCurve",
    "PlannerMetrics",
    "Rate",
    "brier_over_time",
    "brier_score",
    "filter_table",
    "format_scenario_summary",
    "paired_table",
    "planner_metrics",
    "planner_table",
    "scenario_summary",
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

    def to_dict(self) -> dict:
        """JSON-serialisable view."""
        lo, hi = self.interval
        return {"k": self.k, "n": self.n, "value": self.value, "ci95": [lo, hi]}


def _get(rec: object, key: str):
    return rec[key] if isinstance(rec, Mapping) else getattr(rec, key)


def scenario_summary(records: Iterable[object]) -> dict[str, Rate]:
    """Label shares and collision avoidance of episode records (objects or dicts).

    Returns ``Cutoff``, ``Yield``, ``Right`` shares of all labelled episodes, and
    ``avoided``: among Cutoff episodes, the share in which the planner did not collide
    with the obstacle.
    """
    recs = [r for r in records if _get(r, "label") is not None]
    n = len(recs)
    counts = Counter(_get(r, "label") for r in recs)
    cutoffs = [r for r in recs if _get(r, "label") == Labels.CUTOFF]
    avoided = sum(_get(r, "collision_with") != "obstacle" for r in cutoffs)
    out = {lab: Rate(counts.get(lab, 0), n) for lab in (Labels.CUTOFF, Labels.YIELD, Labels.RIGHT)}
    out["avoided"] = Rate(avoided, len(cutoffs))
    return out


def format_scenario_summary(summary: dict[str, Rate], planner: str) -> str:
    """A Markdown table of :func:`scenario_summary` beside the paper's figures."""
    paper = {Labels.CUTOFF: "41.7 %", Labels.YIELD: "34.7 %", Labels.RIGHT: "23.6 %",
             "avoided": "47 % (reactive), 98 % (CDF)"}
    rows = ["| quantity | ours (95 % CI) | paper |", "|---|---|---|"]
    for key in (Labels.CUTOFF, Labels.YIELD, Labels.RIGHT):
        rows.append(f"| {key} share | {summary[key]} | {paper[key]} |")
    rows.append(f"| imminent collisions avoided ({planner}) | {summary['avoided']} | {paper['avoided']} |")
    return "\n".join(rows)


# ----------------------------------------------------------------- planners and filters
#: The probabilities a filter's history may hold that have a truth in the record.
FILTER_QUANTITIES = ("p_left", "p_seen")


def _usable(records: Iterable[object]) -> list[object]:
    """Records of episodes that ran to the end (records with ``"status": "failed"`` left out)."""
    return [r for r in records if not (isinstance(r, Mapping) and r.get("status") == "failed")]


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


def _truth(rec: object, quantity: str, times: np.ndarray) -> np.ndarray:
    """Per-tick truth of ``quantity`` in one episode (see :func:`brier_over_time`)."""
    if quantity == "p_left":
        return np.full(len(times), 1.0 if _get(rec, "intent") == "left" else 0.0)
    if quantity == "p_seen":
        seen = _get(rec, "first_seen_time")
        if seen is None:
            return np.zeros(len(times))
        return (np.asarray(times) > seen + 1e-6).astype(float)
    raise ValueError(f"unknown filter quantity {quantity!r}: choose one of {', '.join(FILTER_QUANTITIES)}")


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


def brier_over_time(records: Iterable[object], quantity: str = "p_left") -> BrierCurve:
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
    for rec in _usable(records):
        hist = (_get(rec, "planner_info") or {}).get("history") or {}
        if quantity not in hist or not hist[quantity]:
            continue
        episodes += 1
        times = np.round(np.asarray(hist["t"], dtype=float), 6)
        probs = np.asarray(hist[quantity], dtype=float)
        for t, p, y in zip(times, probs, _truth(rec, quantity, times)):
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


@dataclass(frozen=True)
class PlannerMetrics:
    """One planner's outcomes over many labelled episodes (definitions as in the paper's
    planner table of :func:`cdf_mj.experiment.experiment_tables`)."""

    planner: str
    episodes: int
    imminent: int  # episodes labelled Cutoff
    collisions: int  # episodes in which the ego touched the obstacle, any label
    avoided: Rate  # Cutoff episodes without contact with the obstacle
    false_alarms: Rate  # episodes not labelled Cutoff in which the planner braked, of all
    lead_time: float  # [s] median of (obstacle enters the ego lane - brake) over braking Cutoff episodes
    min_gap: float  # [m] median of the smallest gap between the cars, over all episodes
    time_lost: float  # [s] mean over episodes without a collision
    brier_left: float | None  # Brier score of P(left) over all ticks (filters only)
    brier_seen: float | None  # Brier score of P(seen) over all ticks (filters that model belief)

    def to_row(self) -> dict[str, float | int | str | None]:
        """Flat, JSON- and CSV-ready view (rates as fractions with their 95 % interval)."""
        row: dict[str, float | int | str | None] = {"planner": self.planner, "episodes": self.episodes,
                                                    "imminent": self.imminent, "collisions": self.collisions}
        for name in ("avoided", "false_alarms"):
            rate: Rate = getattr(self, name)
            lo, hi = rate.interval
            row.update({name: rate.value, f"{name}_lo": lo, f"{name}_hi": hi, f"{name}_k": rate.k,
                        f"{name}_n": rate.n})
        row.update({"lead_time": self.lead_time, "min_gap": self.min_gap, "time_lost": self.time_lost,
                    "brier_left": self.brier_left, "brier_seen": self.brier_seen})
        return row


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else math.nan


def planner_metrics(records: Iterable[object]) -> dict[str, PlannerMetrics]:
    """:class:`PlannerMetrics` per planner name, in order of first appearance; failed
    episodes (``"status": "failed"``) and unlabelled ones are left out."""
    by_planner: dict[str, list[object]] = {}
    for rec in _usable(records):
        if _get(rec, "label") is not None:
            by_planner.setdefault(_get(rec, "planner"), []).append(rec)
    out: dict[str, PlannerMetrics] = {}
    for name, recs in by_planner.items():
        cut = [r for r in recs if _get(r, "label") == Labels.CUTOFF]
        leads = [_get(r, "entered_lane_time") - _get(r, "brake_time") for r in cut
                 if _get(r, "brake_time") is not None and _get(r, "entered_lane_time") is not None]
        intact = [_get(r, "time_lost") for r in recs if not _get(r, "collision")]
        brier = {}
        for q in FILTER_QUANTITIES:
            curve = brier_over_time(recs, q)
            brier[q] = curve.overall if curve.episodes else None
        out[name] = PlannerMetrics(
            planner=name, episodes=len(recs), imminent=len(cut),
            collisions=sum(1 for r in recs if _get(r, "collision_with") == "obstacle"),
            avoided=Rate(sum(1 for r in cut if _get(r, "collision_with") != "obstacle"), len(cut)),
            false_alarms=Rate(sum(1 for r in recs if _get(r, "label") != Labels.CUTOFF
                                  and _get(r, "brake_time") is not None), len(recs)),
            lead_time=_median(leads), min_gap=_median([_get(r, "min_gap") for r in recs]),
            time_lost=float(statistics.fmean(intact)) if intact else math.nan,
            brier_left=brier["p_left"], brier_seen=brier["p_seen"])
    return out


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def planner_table(records: Iterable[object]) -> str:
    """Markdown: every planner's avoided collisions, false alarms, lead time, gap, time lost
    and, for the filters, the Brier scores of P(left) and P(seen) over all ticks."""
    rows = [("| planner | episodes | imminent | collisions | avoided (95 % CI) | false alarms (95 % CI) "
            "| median lead time [s] | median min gap [m] | mean time lost, no collision [s] "
            "| Brier P(left) | Brier P(seen) |"),
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in planner_metrics(records).values():
        rows.append(f"| {m.planner} | {m.episodes} | {m.imminent} | {m.collisions} | {m.avoided} "
                    f"| {m.false_alarms} | {_fmt(m.lead_time)} | {_fmt(m.min_gap)} | {_fmt(m.time_lost)} "
                    f"| {_fmt(m.brier_left, 3)} | {_fmt(m.brier_seen, 3)} |")
    return "\n".join(rows)


def paired_table(records: Iterable[object], pairs: Sequence[tuple[str, str]]) -> str:
    """Markdown: two planners compared seed by seed (common random numbers), on the seeds
    both ran: Cutoff episodes in which only the first or only the second collides with the
    obstacle, and episodes not labelled Cutoff in which only the first, only the second,
    or both brake (false alarms)."""
    by_key = {(_get(r, "planner"), _get(r, "seed")): r for r in _usable(records)
              if _get(r, "label") is not None}
    rows = ["| pair | collides only with the first | only with the second "
            "| false alarm only with the first | only with the second | both |",
            "|---|---|---|---|---|---|"]
    for first, second in pairs:
        seeds = sorted({seed for planner, seed in by_key if planner == first}
                       & {seed for planner, seed in by_key if planner == second})
        counts = [0] * 5
        for seed in seeds:
            a, b = by_key[(first, seed)], by_key[(second, seed)]
            if _get(a, "label") == Labels.CUTOFF:
                hit_a = _get(a, "collision_with") == "obstacle"
                hit_b = _get(b, "collision_with") == "obstacle"
                counts[0] += hit_a and not hit_b
                counts[1] += hit_b and not hit_a
            else:
                alarm_a, alarm_b = _get(a, "brake_time") is not None, _get(b, "brake_time") is not None
                counts[2] += alarm_a and not alarm_b
                counts[3] += alarm_b and not alarm_a
                counts[4] += alarm_a and alarm_b
        rows.append(f"| {first} / {second} | " + " | ".join(str(c) for c in counts) + " |")
    return "\n".join(rows)


def _cells_at(times: np.ndarray, values: np.ndarray, at: Sequence[float]) -> str:
    """Markdown cells of ``values`` at the tick times ``at`` ("-" where no tick is there)."""
    cells = []
    for t in at:
        k = np.flatnonzero(np.isclose(times, t))
        cells.append(_fmt(float(values[k[0]]), 3) if k.size else "-")
    return " | ".join(cells)


def filter_table(records: Iterable[object], times: Sequence[float] = (0.5, 1.0, 1.5, 2.0),
                 p_left: float = 0.75) -> str:
    """Markdown: Brier scores of each filter's P(left) and P(seen), over all ticks and at
    the given tick ``times`` [s], beside two references: the prior ``p_left`` held
    constant, and the per-time base rate fitted on these episodes (in-sample)."""
    recs = _usable(records)
    planners = list(dict.fromkeys(_get(r, "planner") for r in recs))
    head = " | ".join(f"t = {t:g} s" for t in times)
    rows = [f"| planner | quantity | episodes | ticks | all ticks | {head} |",
            "|---|---|---|---|---|" + "---|" * len(times)]
    for name in planners:
        mine = [r for r in recs if _get(r, "planner") == name]
        for q in FILTER_QUANTITIES:
            c = brier_over_time(mine, q)
            if not c.episodes:
                continue
            rows.append(f"| {name} | {q} | {c.episodes} | {c.ticks} | {_fmt(c.overall, 3)} "
                        f"| {_cells_at(c.times, c.scores, times)} |")
    if planners:
        first = [r for r in recs if _get(r, "planner") == planners[0]]
        y = np.array([1.0 if _get(r, "intent") == "left" else 0.0 for r in first])
        prior = float(np.mean((p_left - y) ** 2))
        rows.append(f"| prior P(left) = {p_left:g}, held | p_left | {len(first)} | - | {_fmt(prior, 3)} | "
                    + " | ".join(_fmt(prior, 3) for _ in times) + " |")
    for q in FILTER_QUANTITIES:
        for name in planners:  # the episodes and ticks of the first filter with this history
            c = brier_over_time([r for r in recs if _get(r, "planner") == name], q)
            if not c.episodes:
                continue
            rows.append(f"| base rate per time (in-sample, {name}'s ticks) | {q} | {c.episodes} | {c.ticks} "
                        f"| {_fmt(c.reference_overall, 3)} | {_cells_at(c.times, c.reference, times)} |")
            break
    return "\n".join(rows)
