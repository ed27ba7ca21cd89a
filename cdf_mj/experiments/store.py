"""Where an experiment's records live: an append-only records file, and the lock on its directory.

:class:`RecordStore` appends one JSON line per episode as soon as a seed finishes, flushed
and ``fsync``-ed, so a run killed at any moment (``SIGKILL`` included) loses at most the
seeds that were still running. :meth:`RecordStore.open` reads what an earlier run left
(with :func:`cdf_mj.records.read_records`), cutting off a half-written last line, so that
the run can resume without duplicating or missing an episode. :func:`locked` keeps two
runs out of one directory at once, :func:`check_run_kind` two kinds of run out of it for
ever (an ``estimate`` never replaces an experiment's ``settings.json``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np

from cdf_mj.inputs import SETTINGS_MAX_BYTES, parse_json, read_regular
from cdf_mj.records import FAILED, RECORDS_FILE, SETTINGS_FILE, fsync_directory, read_records, write_atomic
from cdf_mj.records.files import open_no_follow

__all__ = ["RUN_KINDS", "RecordStore", "check_run_kind", "fsync_directory", "json_default", "locked", "run_kind",
           "write_atomic"]

#: The commands that write a ``settings.json`` into their ``--out`` directory (an
#: experiment's has no ``kind`` key; the others say theirs).
RUN_KINDS = ("experiment", "falsify", "estimate")


def json_default(obj: object) -> object:
    """NumPy values in records (planner summaries, traces) as plain JSON; TypeError otherwise.
    For ``json.dumps(..., default=json_default)``."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _open_no_follow(path: Path, flags: int) -> int:
    """``os.open`` that refuses a symlink or a non-regular file at ``path`` (ValueError naming
    it): :func:`cdf_mj.records.files.open_no_follow` of the records file."""
    return open_no_follow(path, flags, "records file")


def run_kind(directory: str | Path) -> str | None:
    """The kind of run (:data:`RUN_KINDS`) ``directory`` holds: its ``settings.json``'s
    ``kind`` (``falsify``, ``estimate``), ``experiment`` for settings without one or for an
    experiment's non-empty records file beside them; None for none, or for settings that
    cannot be read (each command's own checks word those)."""
    directory = Path(directory)
    try:
        data = parse_json(read_regular(directory / SETTINGS_FILE, "settings file", SETTINGS_MAX_BYTES),
                          f"settings file {directory / SETTINGS_FILE}")
    except FileNotFoundError:
        data = None
    except (OSError, ValueError):  # damaged, unreadable, not a regular file
        return None
    if isinstance(data, dict) and "kind" in data:
        kind = data["kind"]
        return kind if isinstance(kind, str) and kind in RUN_KINDS else None
    if isinstance(data, dict) and "seeds" in data and "planners" in data:
        return "experiment"
    try:
        return "experiment" if (directory / RECORDS_FILE).stat().st_size > 0 else None
    except OSError:
        return None


def check_run_kind(directory: str | Path, kind: str) -> None:
    """ValueError (one line naming ``directory`` and both kinds) if ``directory`` holds a
    run of another kind than ``kind`` (:func:`run_kind`): every command that writes a
    ``settings.json`` calls it first, so that none replaces another's settings."""
    have = run_kind(directory)
    if have is not None and have != kind:
        raise ValueError(f"{directory} holds another kind of run ({_article(have)} {have}, by its {SETTINGS_FILE}), "
                         f"not {_article(kind)} {kind}: a directory holds one kind of run; choose another directory")


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


@contextmanager
def locked(directory: str | Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``directory`` (which must exist) for the block, so
    that a second run into the same directory is refused (ValueError, at once) instead
    of writing the same episodes twice. The lock goes when the block ends or every
    process holding it has exited, however it ended. No lock where ``fcntl`` does not
    exist (Windows)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ValueError(f"{directory} is in use by another run: wait for it to finish, "
                             "or choose another directory") from None
        yield
    finally:
        os.close(fd)


class RecordStore:
    """Append-only JSON lines of episode records: every seed is flushed and ``fsync``-ed.

    Use :meth:`open`; the store is a context manager that closes the file.
    """

    def __init__(self, path: Path, records: list[dict[str, Any]], fh: IO[str]) -> None:
        self.path = path
        self.records = records  # everything on disk, in file order
        self._fh = fh

    @classmethod
    def open(cls, path: str | Path, drop_failed: bool = False, seeds: range | None = None,
             planners: Sequence[str] | None = None) -> RecordStore:
        """Open ``path`` for appending, reading the records already there.

        Every line is checked before any work (:func:`cdf_mj.records.read_records`): a
        line that is not a record, a ``(seed, planner)`` recorded twice, or, where the run's
        ``seeds`` (a range) and ``planners`` are given, a record of another seed or planner
        is a ValueError naming the file and the line. A last line cut short by a killed
        run is dropped (truncated from the file). With ``drop_failed``, failed records are
        removed from the file (rewritten atomically) so that their episodes run again. A
        symlink or a non-regular file at ``path`` is refused (ValueError), never written
        through. Writers of one file must not overlap: hold :func:`locked` on its directory.
        """
        path = Path(path)
        fd = _open_no_follow(path, os.O_RDWR | os.O_APPEND | os.O_CREAT)
        try:
            try:
                found = read_records(path, seeds=seeds, planners=planners)
            except ValueError as exc:
                raise ValueError(f"{exc}; the file is damaged: move it away or choose another directory") from None
            records = found.records
            if found.partial:
                os.ftruncate(fd, found.complete_bytes)
                os.fsync(fd)
            if drop_failed and any(r.get("status") == FAILED for r in records):
                records = [r for r in records if r.get("status") != FAILED]
                write_atomic(path, "".join(json.dumps(r, allow_nan=False) + "\n" for r in records))
                os.close(fd)
                fd = _open_no_follow(path, os.O_RDWR | os.O_APPEND)
            os.set_blocking(fd, True)
            fh = os.fdopen(fd, "a", encoding="utf-8")
        except BaseException:
            with suppress(OSError):
                os.close(fd)
            raise
        return cls(path, records, fh)

    def done(self) -> set[tuple[int, str]]:
        """``(seed, planner)`` pairs already recorded (failed ones included)."""
        return {(r["seed"], r["planner"]) for r in self.records}

    def append(self, records: Iterable[dict[str, Any]]) -> None:
        """Write records as one block, then flush and fsync (one seed per call).

        NumPy values are written as plain JSON (:func:`json_default`); a record JSON cannot
        hold (a NaN, an object) is stored as a failed record of its seed and planner
        instead, so that one planner's odd summary never stops the run."""
        kept, lines = [], []
        for rec in records:
            try:
                line = json.dumps(rec, allow_nan=False, default=json_default)
            except (TypeError, ValueError) as exc:
                rec = {"seed": rec.get("seed"), "planner": rec.get("planner"), "status": FAILED,
                       "error": f"the record is not JSON-serialisable: {exc}", "traceback": ""}
                line = json.dumps(rec)
            kept.append(rec)
            lines.append(line + "\n")
        if not lines:
            return
        self._fh.write("".join(lines))
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records.extend(kept)

    def close(self) -> None:
        """Close the file."""
        self._fh.close()

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
