"""Episode records: the schema, the labels, and the file they are stored in.

One episode gives one :class:`EpisodeRecord`; experiments store one JSON object per line
(``episodes.jsonl``). Every part of the package that reads records (the runner, the
tables, the report, the sweeps) reads them through this module. ::

    from cdf_mj.records import Label, load_records
    records = load_records("results/reproduce")       # list of dicts, one per line
    cutoffs = [r for r in records if r["label"] == Label.CUTOFF]
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

__all__ = ["EpisodeRecord", "Label", "Labels", "LABELS", "OK", "FAILED", "RECORDS_FILE",
           "completed", "load_records"]

#: The ``status`` of a stored record: the episode ran to its end, or raised.
OK, FAILED = "ok", "failed"

#: The name of the records file in an experiment directory.
RECORDS_FILE = "episodes.jsonl"


class Label(str, Enum):
    """Scenario label of an episode, from the counterfactual run of its seed in which the
    ego holds its speed. Members compare equal to their strings (``Label.CUTOFF ==
    "Cutoff"``), which is how records store them."""

    CUTOFF = "Cutoff"  # intent left, and the constant-speed run hits the obstacle
    YIELD = "Yield"  # intent left, no such collision
    RIGHT = "Right"  # intent right

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


#: The labels in table order.
LABELS: tuple[Label, ...] = (Label.CUTOFF, Label.YIELD, Label.RIGHT)

#: Earlier name of :class:`Label`, kept for users' scripts.
Labels = Label


@dataclass
class EpisodeRecord:
    """What happened in one episode. Times are seconds from the start, ``None`` if never.

    ``label`` is the scenario label (:class:`Label`) from the counterfactual run of the
    same seed with the ego holding its speed: ``Right`` (intent right), ``Cutoff`` (intent
    left and that run collides with the obstacle) or ``Yield`` (intent left, no such
    collision).
    """

    seed: int
    planner: str
    intent: str  # "left" | "right"
    label: str | None  # Cutoff | Yield | Right (None if labelling was not asked for)
    ego_start_offset: float  # [m] along the ego route from site ego_start
    first_seen_time: float | None  # obstacle's first observation of the ego
    yielded: bool  # the obstacle held back for the ego (waited at the stop line or braked)
    entered_lane_time: float | None  # first tick with any part of the obstacle in the ego lane
    collision: bool  # the ego touched the obstacle or a building
    collision_with: str | None  # "obstacle" | "building"
    collision_time: float | None
    min_gap: float  # [m] smallest distance between the two hulls (0 at contact)
    brake_time: float | None  # the planner's decision to brake
    time_lost: float  # [s] the ego's progress deficit at the end, over its nominal speed
    end_time: float  # [s]
    counterfactual_collision: bool | None  # the constant-speed run hit the obstacle
    planner_info: dict[str, Any] = field(default_factory=dict)
    trace: dict[str, Any] | None = None  # per-tick arrays when asked for

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict."""
        return asdict(self)


def completed(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records of episodes that ran to the end (failed ones left out)."""
    return [r for r in records if r.get("status") != FAILED]


def load_records(out_dir: str | Path) -> list[dict[str, Any]]:
    """The records of an experiment directory (its ``episodes.jsonl``), one dict a line."""
    path = Path(out_dir) / RECORDS_FILE
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
