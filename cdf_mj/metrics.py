"""Rates with confidence intervals, and the scenario summary of a set of episode records.

Every rate is reported with its 95 % Wilson score interval, which stays inside [0, 1]
and behaves at small counts and at 0 % or 100 % (where the normal approximation fails).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Iterable, Mapping

from cdf_mj.episode import Labels

__all__ = ["Rate", "wilson_interval", "scenario_summary", "format_scenario_summary"]


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
