"""The rules that read one record (a dict of the records file, or an
:class:`~cdf_mj.records.schema.EpisodeRecord`): what counts as imminent, avoided, braked, a
(hard-brake) false alarm, an intervention, the lead time and the prediction, so that a rate means the same wherever it
is printed or drawn (the table is in :mod:`cdf_mj.records`)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

from cdf_mj.records.schema import FAILED, Label, RecordLike

__all__ = ["avoided", "braked", "completed", "hit_obstacle", "intervened", "is_false_alarm", "is_false_intervention",
           "is_imminent", "lead_time", "paper_avoided", "pass_time", "prediction", "record_field"]

def completed(records: Iterable[RecordLike]) -> list[RecordLike]:
    """The records of episodes that ran to the end (``"status": "failed"`` left out)."""
    return [r for r in records if not (isinstance(r, Mapping) and r.get("status") == FAILED)]


def record_field(rec: RecordLike, name: str) -> Any:
    """Field ``name`` of a record given as a dict or as an :class:`EpisodeRecord`
    (KeyError or AttributeError if it has none)."""
    return rec[name] if isinstance(rec, Mapping) else getattr(rec, name)


def is_imminent(rec: RecordLike) -> bool:
    """The episode is labelled Cutoff: the constant-speed run of its seed hits the obstacle
    (the paper's "collision imminent")."""
    return bool(record_field(rec, "label") == Label.CUTOFF)


def hit_obstacle(rec: RecordLike) -> bool:
    """The ego touched the obstacle in this episode, whatever its label (the paper's
    "collision occurred")."""
    return bool(record_field(rec, "collision_with") == "obstacle")


def avoided(rec: RecordLike) -> bool:
    """An imminent collision was avoided: a Cutoff episode in which the ego did not touch
    the obstacle. False in every episode not labelled Cutoff."""
    return is_imminent(rec) and not hit_obstacle(rec)


def braked(rec: RecordLike) -> bool:
    """The planner decided to brake (``brake_time`` is set)."""
    return record_field(rec, "brake_time") is not None


def is_false_alarm(rec: RecordLike) -> bool:
    """The planner braked in a labelled episode that is not a Cutoff (Yield or Right): a
    hard-brake false alarm (slowing is not counted here; see :func:`is_false_intervention`)."""
    label = record_field(rec, "label")
    return label is not None and label != Label.CUTOFF and braked(rec)


def _intervention(rec: RecordLike) -> Mapping[str, Any] | None:
    """The record's ``intervention`` (None in a record written before it was kept)."""
    return rec.get("intervention") if isinstance(rec, Mapping) else getattr(rec, "intervention", None)


def intervened(rec: RecordLike) -> bool | None:
    """The planner held the ego below its own controller (speed hold, car following) by
    more than the record's tolerance on at least one tick, hard brake or not; None for a
    record without ``intervention``."""
    info = _intervention(rec)
    return None if info is None else info["ticks"] > 0


def is_false_intervention(rec: RecordLike) -> bool | None:
    """The planner intervened (:func:`intervened`) in a labelled episode that is not a
    Cutoff (Yield or Right); None for a record without ``intervention``."""
    did = intervened(rec)
    if did is None:
        return None
    label = record_field(rec, "label")
    return label is not None and label != Label.CUTOFF and did


def pass_time(rec: RecordLike) -> float | None:
    """[s] when the ego's rear axle got ``timing.label_distance`` past the conflict point
    (extrapolated at the nominal speed where it never did: a lower bound); None for a
    record without ``intervention``."""
    info = _intervention(rec)
    return None if info is None else float(info["pass_time"])


def lead_time(rec: RecordLike) -> float | None:
    """[s] how long before the obstacle entered the ego lane the planner decided to brake,
    ``entered_lane_time - brake_time`` (negative: braked after the entry), in a Cutoff
    episode with both times; None otherwise."""
    entered = record_field(rec, "entered_lane_time")
    if not (is_imminent(rec) and braked(rec) and entered is not None):
        return None
    return float(entered - record_field(rec, "brake_time"))


def prediction(rec: RecordLike) -> str | None:
    """The planner's predicted label: its own (``planner_info["prediction"]``, the CDF's),
    else ``Cutoff`` for a planner that braked; None for one that did neither."""
    own = (record_field(rec, "planner_info") or {}).get("prediction")
    if own is not None:
        return str(own)
    return Label.CUTOFF.value if braked(rec) else None


def paper_avoided(imminent: int, occurred: int) -> float:
    """The paper's share of imminent collisions avoided, ``(imminent - occurred) / imminent``,
    from the episodes labelled Cutoff (:func:`is_imminent`) and those with a collision with
    the obstacle (:func:`hit_obstacle`), of any label: unlike :func:`avoided`, it also
    charges a collision in a Yield episode (caused by braking there). NaN without imminent
    collisions."""
    return (imminent - occurred) / imminent if imminent else math.nan
