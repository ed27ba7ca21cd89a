"""Where an experiment's records live: an append-only records file, and the lock on its directory.

:class:`RecordStore` appends one JSON line per episode as soon as a seed finishes, flushed
and ``fsync``-ed, so a run killed at any moment (``SIGKILL`` included) loses at most the
seeds that were still running. :meth:`RecordStore.open` reads what an earlier run left
(with :func:`cdf_mj.records.read_records`), cutting off a half-written last line, so that
the run can resume without duplicating or missing an episode. :func:`locked` keeps two
runs out of one directory.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np

from cdf_mj.records import FAILED, read_records

__all__ = ["RecordStore", "json_default", "locked"]


def json_default(obj: object) -> object:
    """NumPy values in records (planner summaries, traces) as plain JSON; TypeError otherwise.
    For ``json.dumps(..., default=json_default)``."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


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
    def open(cls, path: str | Path, drop_failed: bool = False) -> RecordStore:
        """Open ``path`` for appending, reading the records already there.

        A last line cut short by a killed run is dropped (truncated from the file); any
        other line that is not a record is a ValueError naming its line number
        (:func:`cdf_mj.records.read_records`). With ``drop_failed``, failed records are
        removed from the file (rewritten atomically) so that their episodes run again.
        Writers of one file must not overlap: hold :func:`locked` on its directory.
        """
        path = Path(path)
        records: list[dict[str, Any]] = []
        if path.exists():
            try:
                found = read_records(path)
            except ValueError as exc:
                raise ValueError(f"{exc}; the file is damaged: move it away or choose another directory") from None
            records = found.records
            if found.partial:
                with open(path, "r+b") as cut:
                    cut.truncate(found.complete_bytes)
                    cut.flush()
                    os.fsync(cut.fileno())
        if drop_failed and any(r.get("status") == FAILED for r in records):
            records = [r for r in records if r.get("status") != FAILED]
            tmp = path.with_name(path.name + ".tmp")
            with open(tmp, "w", encoding="utf-8") as out:
                out.write("".join(json.dumps(r, allow_nan=False) + "\n" for r in records))
                out.flush()
                os.fsync(out.fileno())
            os.replace(tmp, path)
        fh = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed by close() / __exit__
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
