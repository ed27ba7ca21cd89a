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
import os
import stat
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from contextlib import suppress
from dataclasses import MISSING, asdict, dataclass, field, fields
from enum import Enum
from pathlib import Path
from typing import Any, TypeAlias, Union, get_args, get_origin, get_type_hints

__all__ = ["FAILED", "LABELS", "OK", "RECORDS_FILE", "SETTINGS_FILE", "EpisodeRecord", "Label", "Labels",
           "RecordLike", "RecordsFile", "avoided", "braked", "check_record", "check_settings", "completed",
           "fsync_directory", "hit_obstacle", "is_false_alarm", "is_imminent", "lead_time", "load_records",
           "paper_avoided", "prediction", "read_records", "read_settings", "record_field", "write_atomic"]

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


def read_records(path: str | Path, seeds: range | None = None,
                 planners: Sequence[str] | None = None) -> RecordsFile:
    """Read a records file (one JSON object a line), checking every record before any is used.

    Every line must be a record (:func:`check_record`: each field of its type, ``seed`` a
    non-negative integer, times finite numbers or null, ...), no ``(seed, planner)`` may
    appear twice, and where the run's ``seeds`` (a range) and ``planners`` are given, every
    record must be of one of them. Everything after the last newline is a line cut short
    by a killed run (or one still being written): it is left out, and reported by
    :attr:`RecordsFile.partial`. Blank lines are skipped. Any other line that fails is a
    ValueError naming the file, the line number and the reason; a path that is not a
    regular file (a directory, a FIFO) is a ValueError too. The file is not changed.
    """
    path = Path(path)
    data = _read_regular(path)
    end = data.rfind(b"\n") + 1
    records: list[dict[str, Any]] = []
    seen: dict[tuple[int, str], int] = {}
    known = None if planners is None else tuple(planners)
    for number, line in enumerate(data[:end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            check_record(rec)
        except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError included
            reason = (f"not JSON ({exc.msg})" if isinstance(exc, json.JSONDecodeError) else
                      "not JSON (nested too deeply)" if isinstance(exc, RecursionError) else
                      "not JSON (not UTF-8 text)" if isinstance(exc, UnicodeDecodeError) else str(exc))
            raise ValueError(f"{path}:{number} is not an episode record: {reason}") from None
        key = (rec["seed"], rec["planner"])
        problem = None
        if seeds is not None and rec["seed"] not in seeds:
            problem = f"seed {rec['seed']} is outside the run's seeds {seeds.start}-{seeds.stop - 1}"
        elif known is not None and rec["planner"] not in known:
            problem = f"planner {rec['planner']!r} is not one of the run's planners ({', '.join(known)})"
        elif key in seen:
            problem = f"seed {key[0]} of planner {key[1]!r} is recorded twice (first on line {seen[key]})"
        if problem is not None:
            raise ValueError(f"{path}:{number} is not a record of this run: {' '.join(problem.split())[:200]}")
        seen[key] = number
        records.append(rec)
    return RecordsFile(path, records, end, len(data))


def _read_regular(path: Path) -> bytes:
    """The bytes of ``path``; ValueError (naming it) unless it is a regular file, so that
    a FIFO or a device never blocks the reader."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path} is not a regular file: move it away or choose another directory")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            return fh.read()
    finally:
        os.close(fd)


#: The name of the settings file beside the records file in an experiment directory.
SETTINGS_FILE = "settings.json"


def check_settings(data: object, path: str | Path = SETTINGS_FILE) -> dict[str, Any]:
    """``data`` (a parsed ``settings.json``), checked: a JSON object whose ``seeds`` is a
    pair ``[first, stop)`` of non-negative integers, ``planners`` a non-empty list of
    distinct names, ``scenario`` and ``cdf`` objects (``scenario.names`` an object if
    given), ``scene`` a path string, and ``scene_files`` (path -> SHA-256) and ``version``
    strings where present. ValueError naming ``path`` and the first key that fails."""
    def bad(key: str, want: str, value: object) -> ValueError:
        shown = "null" if value is None else f"{type(value).__name__} {value!r}"
        return ValueError(" ".join(f"{path}: key {key!r} must be {want}, got {shown}"[:240].split()))

    if not isinstance(data, dict):
        raise ValueError(f"{path}: settings are a JSON object, got {type(data).__name__}")
    seeds = data.get("seeds")
    if not (isinstance(seeds, list) and len(seeds) == 2
            and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
            and seeds[0] <= seeds[1]):
        raise bad("seeds", "a pair [first, stop) of non-negative integers", seeds)
    planners = data.get("planners")
    if not (isinstance(planners, list) and planners and all(isinstance(p, str) for p in planners)
            and len(set(planners)) == len(planners)):
        raise bad("planners", "a non-empty list of distinct planner names", planners)
    for key in ("scenario", "cdf"):
        if not isinstance(data.get(key), dict):
            raise bad(key, "an object", data.get(key))
    names = data["scenario"].get("names")
    if names is not None and not isinstance(names, dict):
        raise bad("scenario.names", "an object of scene element names", names)
    if not isinstance(data.get("scene"), str):
        raise bad("scene", "the path of the scene file", data.get("scene"))
    files = data.get("scene_files", {})
    if not (isinstance(files, dict) and all(isinstance(v, str) for v in files.values())):
        raise bad("scene_files", "an object of file -> SHA-256", files)
    if not isinstance(data.get("version", ""), str):
        raise bad("version", "a version string", data.get("version"))
    return data


def read_settings(path: str | Path) -> dict[str, Any]:
    """The settings file at ``path``, read and checked (:func:`check_settings`). ValueError
    naming the file if it is not a regular file, not JSON, or fails the check."""
    path = Path(path)
    try:
        data = json.loads(_read_regular(path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg})") from None
    except (UnicodeDecodeError, RecursionError):
        raise ValueError(f"{path}: not JSON (not UTF-8 text, or nested too deeply)") from None
    return check_settings(data, path)


def fsync_directory(directory: str | Path) -> None:
    """``fsync`` a directory, so that a rename or a new file in it survives a power loss
    (nothing where directories cannot be opened, on Windows)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems cannot sync a directory; the rename itself stands
    finally:
        os.close(fd)


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` whole or not at all, never through a link.

    The bytes go to a new temporary file beside ``path`` (created exclusively, so a file or
    a symlink planted under any name is never written through), are ``fsync``-ed, and the
    file is renamed over ``path``: a symlink at ``path`` is replaced, its target untouched.
    The directory is ``fsync``-ed after the rename. On any error the temporary file is
    removed and ``path`` is as it was. Returns ``path``.
    """
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_directory(path.parent)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
