"""Episode records: the schema, the labels, the records file, and the rules that read a record.

One episode gives one :class:`EpisodeRecord`; experiments store one JSON object per line in
``episodes.jsonl`` (:data:`RECORDS_FILE`). Every part of the package that reads records
(the experiment runner's store, the tables, the report, the sweeps) reads the file with
:func:`read_records` and judges a record with the rules below, so that a rate means the
same wherever it is printed or drawn. ::

    from cdf_mj.records import avoided, is_imminent, load_records
    records = load_records("results/reproduce")        # dicts, one per line
    cutoffs = [r for r in records if is_imminent(r)]
    share = sum(map(avoided, cutoffs)) / len(cutoffs)

The rules take a record as a dict (a line of the file, or :meth:`EpisodeRecord.to_dict`)
or as an :class:`EpisodeRecord`:

====================  ========================================================================
:func:`is_imminent`   the episode is labelled Cutoff (the paper's "collision imminent")
:func:`hit_obstacle`  the ego touched the obstacle, whatever the label (the paper's "collision
                      occurred")
:func:`avoided`       a Cutoff episode without a collision with the obstacle
:func:`braked`        the planner decided to brake
:func:`is_false_alarm` a labelled episode not labelled Cutoff in which the planner braked
:func:`lead_time`     [s] obstacle enters the ego lane - brake decision, in a braking Cutoff
                      episode
:func:`prediction`    the planner's predicted label
:func:`paper_avoided` the paper's count, (imminent - occurred) / imminent
====================  ========================================================================
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields
from enum import Enum
from pathlib import Path
from typing import Any, TypeAlias, Union, get_args, get_origin, get_type_hints

__all__ = ["FAILED", "LABELS", "OK", "RECORDS_FILE", "EpisodeRecord", "Label", "Labels", "RecordLike",
           "RecordsFile", "avoided", "braked", "check_record", "completed", "hit_obstacle", "is_false_alarm",
           "is_imminent", "lead_time", "load_records", "paper_avoided", "prediction", "read_records",
           "record_field"]

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
        """JSON-serialisable dict (NumPy values in ``planner_info`` or ``trace`` aside)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> EpisodeRecord:
        """The record ``data`` holds: a dict of :meth:`to_dict`, or a completed line of a
        records file (its ``"status": "ok"`` is accepted and not kept).

        Every field is checked: present (``planner_info`` and ``trace`` may be left out),
        of its type (a number may be written as an integer), and ``intent``, ``label`` and
        ``collision_with`` one of their values. ValueError naming the first field that
        fails, or an unknown one; ``from_dict(rec.to_dict()) == rec``.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"an episode record is a JSON object, got {type(data).__name__}")
        status = data.get("status", OK)
        if status != OK:
            raise ValueError(f"field 'status' is {status!r}: only a completed episode ({OK!r}) has a record")
        unknown = sorted(set(data) - set(_SCHEMA) - {"status"})
        if unknown:
            raise ValueError(f"unknown field {unknown[0]!r}")
        values = {}
        for f in fields(cls):
            if f.name in data:
                _check_field(f.name, data[f.name])
                values[f.name] = data[f.name]
            elif f.default is MISSING and f.default_factory is MISSING:
                raise ValueError(f"field {f.name!r} is missing")
        return cls(**values)


#: A record as the rules below take it: a dict (a line of the file) or an EpisodeRecord.
RecordLike: TypeAlias = Mapping[str, Any] | EpisodeRecord


def _schema() -> dict[str, tuple[type, bool]]:
    """Field name -> (JSON type, may be None), from the annotations of EpisodeRecord."""
    out = {}
    for name, hint in get_type_hints(EpisodeRecord).items():
        args = get_args(hint) if get_origin(hint) in (Union, type(int | None)) else (hint,)
        base = next(a for a in args if a is not type(None))
        out[name] = (get_origin(base) or base, type(None) in args)
    return out


_SCHEMA = _schema()
_KINDS = {int: "an integer", float: "a number", str: "a string", bool: "true or false", dict: "an object"}
_CHOICES: dict[str, tuple[str, ...]] = {"intent": ("left", "right"), "label": tuple(lab.value for lab in LABELS),
                                        "collision_with": ("obstacle", "building")}


def _check_field(name: str, value: object) -> None:
    """ValueError unless ``value`` is of field ``name``'s type and among its choices."""
    base, optional = _SCHEMA[name]
    if value is None and optional:
        return
    if base is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif base is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = isinstance(value, base)
    if not ok:
        shown = "null" if value is None else f"{type(value).__name__} {value!r}"[:60]
        raise ValueError(f"field {name!r} must be {_KINDS[base]}{' or null' if optional else ''}, got {shown}")
    if name in _CHOICES and value not in _CHOICES[name]:
        raise ValueError(f"field {name!r} must be one of {', '.join(map(repr, _CHOICES[name]))}, got {value!r}")


def check_record(data: object) -> None:
    """ValueError (naming the field) unless ``data`` is a record of a records file: a
    completed episode (:meth:`EpisodeRecord.from_dict`) or a failed one, whose ``seed``
    is an integer and ``planner`` a string (``error`` and ``traceback`` strings if present)."""
    if not isinstance(data, Mapping):
        raise ValueError(f"an episode record is a JSON object, got {type(data).__name__}")
    if data.get("status") == FAILED:
        for name, kind in (("seed", int), ("planner", str), ("error", str), ("traceback", str)):
            value = data.get(name)
            if (value is None and name in ("error", "traceback")) or (
                    isinstance(value, kind) and not isinstance(value, bool)):
                continue
            raise ValueError(f"field {name!r} of a failed record must be {_KINDS[kind]}, got {value!r}"[:120])
        return
    EpisodeRecord.from_dict(data)


# ----------------------------------------------------------------- the records file
@dataclass(frozen=True)
class RecordsFile:
    """What :func:`read_records` found in a records file."""

    path: Path
    records: list[dict[str, Any]]  # every complete line, in file order (failed records included)
    complete_bytes: int  # length of the complete lines; a half-written last line may follow
    size: int  # [bytes] of the file

    @property
    def partial(self) -> bool:
        """The file ends in a half-written line (a run killed, or still writing), left out."""
        return self.complete_bytes < self.size


def read_records(path: str | Path) -> RecordsFile:
    """Read a records file (one JSON object a line), checking every record (:func:`check_record`).

    Everything after the last newline is a line cut short by a killed run (or one still
    being written): it is left out, and reported by :attr:`RecordsFile.partial`. Blank
    lines are skipped. Any other line that is not a record is a ValueError naming the file
    and the line number. The file is not changed.
    """
    path = Path(path)
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    records: list[dict[str, Any]] = []
    for number, line in enumerate(data[:end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            check_record(rec)
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError included
            reason = f"not JSON ({exc.msg})" if isinstance(exc, json.JSONDecodeError) else str(exc)
            raise ValueError(f"{path}:{number} is not an episode record: {reason}") from None
        records.append(rec)
    return RecordsFile(path, records, end, len(data))


def load_records(out_dir: str | Path) -> list[dict[str, Any]]:
    """The records of an experiment directory (its ``episodes.jsonl``, read by
    :func:`read_records`), failed ones included: one dict a line, in file order."""
    return read_records(Path(out_dir) / RECORDS_FILE).records


def completed(records: Iterable[RecordLike]) -> list[RecordLike]:
    """The records of episodes that ran to the end (``"status": "failed"`` left out)."""
    return [r for r in records if not (isinstance(r, Mapping) and r.get("status") == FAILED)]


# ----------------------------------------------------------------- rules of one record
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
    """The planner braked in a labelled episode that is not a Cutoff (Yield or Right)."""
    label = record_field(rec, "label")
    return label is not None and label != Label.CUTOFF and braked(rec)


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
