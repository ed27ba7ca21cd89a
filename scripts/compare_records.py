#!/usr/bin/env python3
"""Compare two runs of the same experiment, seed by seed: do the tables still hold?

A change that alters the random draws (issue 16 compiled the filter: its draws are now
made particle by particle, only where they matter) changes individual records while the
model stays the same. This prints, for every planner the two runs share, its avoided
collisions, the paper's formula, its collisions and false alarms in each run with 95 %
Wilson intervals, and the seeds on which the two runs disagree with the exact McNemar
test on them; then how many labels differ (the labels come from the world, whose draws a
filter change must not touch)::

    python scripts/compare_records.py /tmp/rep_base /tmp/rep_new
    python scripts/compare_records.py before/episodes.jsonl after/episodes.jsonl --format markdown

Arguments are experiment directories or their ``episodes.jsonl``. Bad input (a missing or
damaged records file, runs without a seed and planner in common) is one line
``compare_records: error: ...`` and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cdf_mj.analysis.metrics import mcnemar_exact, paired_counts, planner_metrics
from cdf_mj.records import RECORDS_FILE, completed, read_records


def _load(path: str) -> list[dict[str, Any]]:
    p = Path(path)
    return completed(read_records(p / RECORDS_FILE if p.is_dir() else p).records)


def _rate(rate: Any) -> str:
    lo, hi = rate.interval
    return f"{100 * rate.value:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({rate.k}/{rate.n})"


def compare(before: list[dict[str, Any]], after: list[dict[str, Any]]) -> list[str]:
    """The comparison's lines (Markdown table and notes)."""
    keys_a = {(r["planner"], r["seed"]) for r in before}
    keys_b = {(r["planner"], r["seed"]) for r in after}
    common = keys_a & keys_b
    if not common:
        raise ValueError("the two runs have no (planner, seed) in common")
    planners = sorted({p for p, _ in common})
    tagged = [{**r, "planner": f"{r['planner']}@before"} for r in before if (r["planner"], r["seed"]) in common]
    tagged += [{**r, "planner": f"{r['planner']}@after"} for r in after if (r["planner"], r["seed"]) in common]
    metrics = planner_metrics(tagged)
    lines = [f"{len(common)} episodes in common ({', '.join(planners)}); before | after",
             "",
             "| planner | run | avoided | paper's formula | collisions | false alarms |",
             "|---|---|---|---|---|---|"]
    tests = []
    for planner in planners:
        for run in ("before", "after"):
            m = metrics.get(f"{planner}@{run}")
            if m is None:
                continue
            lines.append(f"| {planner} | {run} | {_rate(m.avoided)} | {100 * m.paper_avoided:.1f} % | "
                         f"{m.collisions} | {_rate(m.false_alarms)} |")
        pc = paired_counts(tagged, f"{planner}@before", f"{planner}@after")
        p_hit = mcnemar_exact(pc.hit_only_first, pc.hit_only_second)
        p_alarm = mcnemar_exact(pc.false_alarm_only_first, pc.false_alarm_only_second)
        tests.append(f"- {planner}: {pc.seeds} seeds; collisions only before {pc.hit_only_first}, only after "
                     f"{pc.hit_only_second} (exact McNemar p = {p_hit:.3g}); false alarms only before "
                     f"{pc.false_alarm_only_first}, only after {pc.false_alarm_only_second} (p = {p_alarm:.3g})")
    labels_a = {(r["planner"], r["seed"]): r.get("label") for r in before}
    differ = sum(labels_a[(r["planner"], r["seed"])] != r.get("label") for r in after
                 if (r["planner"], r["seed"]) in common)
    return [*lines, "", "Seed by seed:", "", *tests, "", f"Labels that differ: {differ} of {len(common)}."]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="compare_records", description=__doc__.split("\n\n")[0])
    parser.add_argument("before", help="experiment directory or episodes.jsonl of the first run")
    parser.add_argument("after", help="the same of the second run")
    args = parser.parse_args(argv)
    try:
        lines = compare(_load(args.before), _load(args.after))
    except (OSError, ValueError) as exc:
        print(f"compare_records: error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
