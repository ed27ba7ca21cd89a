"""The schema of an episode record: :class:`EpisodeRecord` and its fields' types, the
scenario :class:`Label`, and :func:`check_record`, which every reader of a records file
applies to each line (the parts of ``planner_info`` that the metrics read included)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields
from enum import Enum
from typing import Any, TypeAlias, Union, get_args, get_origin, get_type_hints

__all__ = ["FAILED", "INTERVENTION_KEYS", "LABELS", "OK", "EpisodeRecord", "Label", "Labels", "RecordLike",
           "check_record"]

#: The ``status`` of a stored record: the episode ran to its end, or raised.
OK, FAILED = "ok", "failed"


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
    min_gap: float  # [m] smallest distance between the two cars' hulls (0 only when they touch)
    brake_time: float | None  # the planner's decision to brake
    time_lost: float  # [s] the ego's progress deficit at the end, over its nominal speed
    end_time: float  # [s]
    counterfactual_collision: bool | None  # the constant-speed run hit the obstacle
    planner_info: dict[str, Any] = field(default_factory=dict)
    # Safety and comfort margins of the episode (cdf_mj.analysis.safety.SafetyMetrics, docs/SAFETY.md).
    safety: dict[str, Any] | None = None
    # The world's options drawn for it: the obstacle's driver family and parameters, its
    # behaviour after merging, the ego's sensing (what was dropped).
    world: dict[str, Any] | None = None
    # Every intervention of the planner, not only hard brakes (:data:`INTERVENTION_KEYS`);
    # None in records written before it was kept.
    intervention: dict[str, Any] | None = None
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


#: A record as the rules of :mod:`cdf_mj.records.counting` take it: a dict (a line of the file)
#: or an EpisodeRecord.
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
_KINDS = {int: "an integer", float: "a finite number", str: "a string", bool: "true or false", dict: "an object"}
_CHOICES: dict[str, tuple[str, ...]] = {"intent": ("left", "right"), "label": tuple(lab.value for lab in LABELS),
                                        "collision_with": ("obstacle", "building")}


def _check_field(name: str, value: object) -> None:
    """ValueError unless ``value`` is of field ``name``'s type and among its choices."""
    base, optional = _SCHEMA[name]
    if value is None and optional:
        return
    if base is float:  # a finite number: NaN, Infinity and 1e400 (inf) are not times or gaps
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    elif base is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = isinstance(value, base)
    if not ok:
        shown = "null" if value is None else f"{type(value).__name__} {value!r}"[:60]
        raise ValueError(f"field {name!r} must be {_KINDS[base]}{' or null' if optional else ''}, got {shown}")
    if name == "seed" and isinstance(value, int) and value < 0:
        raise ValueError(f"field 'seed' must be a non-negative integer, got {value}")
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
        if data["seed"] < 0:
            raise ValueError(f"field 'seed' must be a non-negative integer, got {data['seed']}")
        return
    EpisodeRecord.from_dict(data)
    _check_planner_info(data.get("planner_info") or {})
    if data.get("intervention") is not None:
        _check_intervention(data["intervention"])


#: The keys of a record's ``intervention`` and what each holds. A tick is intervening when
#: the planner's command as it acts is below the ego's own acceleration (speed hold and car
#: following) by more than ``tolerance`` (cdf_mj.scenario.ego_agent.intervention_tolerance_of).
INTERVENTION_KEYS: dict[str, str] = {
    "tolerance": "[m/s^2] the tolerance of an intervening tick",
    "first": "[s] the first intervening tick, null if none",
    "ticks": "how many ticks intervened",
    "time": "[s] their duration (ticks x timing.dt)",
    "peak_decel": "[m/s^2] the most deceleration applied on an intervening tick (0 if none)",
    "pass_time": "[s] when the ego's rear axle got timing.label_distance past the conflict point; "
                 "extrapolated at the nominal speed from the end when it did not (a lower bound)",
    "passed": "whether it got there (pass_time measured, not extrapolated)",
}


def _check_intervention(value: object) -> None:
    """ValueError naming the key unless ``value`` is a record's ``intervention``: an object
    of :data:`INTERVENTION_KEYS`, times and decelerations finite and >= 0, ``ticks`` a
    non-negative integer, ``passed`` true or false, ``first`` null exactly when ``ticks`` is 0."""
    if not isinstance(value, Mapping):
        raise ValueError(f"field 'intervention' must be an object or null, got {type(value).__name__}")
    for key in INTERVENTION_KEYS:
        if key not in value:
            raise ValueError(f"field 'intervention.{key}' is missing")
        v = value[key]
        if key == "passed":
            ok = isinstance(v, bool)
        elif key == "ticks":
            ok = isinstance(v, int) and not isinstance(v, bool) and v >= 0
        else:
            ok = (v is None and key == "first") or (
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0)
        if not ok:
            kind = {"passed": "true or false", "ticks": "a non-negative integer",
                    "first": "a finite time >= 0 or null"}.get(key, "a finite number >= 0")
            raise ValueError(f"field 'intervention.{key}' must be {kind}, got {v!r}"[:120])
    if (value["first"] is None) != (value["ticks"] == 0):
        raise ValueError(f"field 'intervention.first' is {value['first']!r} with {value['ticks']} intervening "
                         "ticks: it is null exactly when there are none")


#: The per-tick probabilities of a filter's history that the metrics read.
_HISTORY_PROBABILITIES = ("p_left", "p_seen", "p_cutoff")


def _check_planner_info(info: Mapping[str, Any]) -> None:
    """ValueError unless the parts of ``planner_info`` the rules read are of their kind:
    ``prediction`` a label or null; ``history`` an object of per-tick lists, with ``t``
    [s] and the probabilities of :data:`_HISTORY_PROBABILITIES` finite numbers, one per
    tick (probabilities in [0, 1])."""
    own = info.get("prediction")
    if own is not None and own not in _CHOICES["label"]:
        raise ValueError(f"field 'planner_info.prediction' must be one of "
                         f"{', '.join(map(repr, _CHOICES['label']))} or null, got {own!r}"[:160])
    if "history" not in info or info["history"] is None:
        return
    history = info["history"]
    if not isinstance(history, Mapping) or not all(isinstance(v, list) for v in history.values()):
        raise ValueError("field 'planner_info.history' must be an object of per-tick lists")
    ticks = history.get("t")
    for key in ("t", *_HISTORY_PROBABILITIES):
        values = history.get(key)
        if values is None and key != "t":
            continue
        if not (isinstance(values, list) and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)):
            raise ValueError(f"field 'planner_info.history.{key}' must be a list of finite numbers")
        if key != "t" and (len(values) != len(ticks or ()) or not all(0.0 <= v <= 1.0 for v in values)):
            raise ValueError(f"field 'planner_info.history.{key}' must hold one probability in [0, 1] "
                             "for each time of 't'")
