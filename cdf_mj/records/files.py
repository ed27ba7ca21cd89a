"""The files of an experiment directory: the records file (``episodes.jsonl``, one JSON
record a line, read and checked by :func:`read_records`), the settings file
(``settings.json``, :func:`read_settings`), writes that survive a crash
(:func:`write_atomic`, :func:`fsync_directory`), and the checks every output goes through
(:func:`check_output_target`: only a regular file is ever replaced; :func:`open_no_follow`:
an appended file is never reached through a link)."""

from __future__ import annotations

import dataclasses
import enum
import errno
import json
import os
import stat
import tempfile
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cdf_mj.inputs import (
    RECORDS_MAX_BYTES,
    SETTINGS_MAX_BYTES,
    InputError,
    NotRegularFileError,
    kind_of,
    parse_json,
    read_regular,
)
from cdf_mj.records.schema import check_record

__all__ = ["RECORDS_FILE", "SETTINGS_FILE", "OutputTargetError", "RecordsFile", "check_output_target",
           "check_settings", "fsync_directory", "jsonable", "load_records", "open_no_follow", "read_records",
           "read_settings", "write_atomic"]

def jsonable(value: Any) -> Any:
    """Configurations (dataclasses, tuples, NumPy values, enums) as plain JSON values: what
    settings files, traces and a stored run's planner arguments hold."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, enum.Enum):
        return jsonable(value.value)
    return value


#: The name of the records file in an experiment directory.
RECORDS_FILE = "episodes.jsonl"


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
    data = _read_regular(path, "records file", RECORDS_MAX_BYTES)
    end = data.rfind(b"\n") + 1
    records: list[dict[str, Any]] = []
    seen: dict[tuple[int, str], int] = {}
    known = None if planners is None else tuple(planners)
    for number, line in enumerate(data[:end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = parse_json(line, f"{path}:{number}")
            check_record(rec)
        except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError and InputError included
            reason = (f"not JSON ({exc.msg})" if isinstance(exc, json.JSONDecodeError) else
                      "not JSON (nested too deeply)" if isinstance(exc, InputError) else
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


def _read_regular(path: Path, what: str, max_bytes: int) -> bytes:
    """The bytes of ``path`` (:func:`cdf_mj.inputs.read_regular`); ValueError naming it
    unless it is a regular file of at most ``max_bytes``, so that a FIFO or a device never
    blocks or floods the reader."""
    try:
        return read_regular(path, what, max_bytes)
    except NotRegularFileError as exc:
        raise ValueError(f"{path} is not a regular file ({exc.kind}): move it away or choose another "
                         "directory") from None


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
    data = _read_regular(path, "settings file", SETTINGS_MAX_BYTES)
    try:
        data = parse_json(data, f"settings file {path}")
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc.msg})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not JSON (not UTF-8 text)") from None
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


class OutputTargetError(ValueError):
    """An output path where something other than a regular file is (a FIFO, a device, a
    socket, a directory): one line naming the path and what is there; nothing was written."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind


def check_output_target(path: str | Path, what: str = "output") -> None:
    """Nothing unless ``path`` is absent, a regular file or a symbolic link (an output
    replaces the link itself, never what it points to): else :class:`OutputTargetError`
    naming ``what``, the path and what is there (``"a FIFO (named pipe)"``, ``"a character
    device"``, ``"a directory"``, ``"a socket"``), so that an output never replaces a device
    or a pipe. Checked with ``lstat``; nothing is opened."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError:
        return  # not reachable (a missing directory, no permission): the write itself says why
    if stat.S_ISREG(mode) or stat.S_ISLNK(mode):
        return
    kind = kind_of(mode)
    raise OutputTargetError(f"{what} {path} is {kind}: an output replaces only a regular file; move it away "
                            "or choose another path", kind)


def open_no_follow(path: str | Path, flags: int, what: str = "file") -> int:
    """``os.open(path, flags)`` (mode ``0o666`` less the umask for a new file) that never
    follows a symbolic link at ``path`` nor opens anything but a regular file: ValueError
    naming ``what`` and the path for a link, a FIFO, a device, a socket or a directory
    (opened non-blocking, so a FIFO cannot hang it; the descriptor is left blocking)."""
    try:
        fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
                     | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError(f"{path} is a symbolic link: the {what} must be a regular file, "
                             "move the link away or choose another directory") from None
        if exc.errno in (errno.EISDIR, errno.ENXIO):  # a directory; a FIFO with no reader
            with suppress(OSError):
                raise ValueError(f"{path} is {kind_of(os.lstat(path).st_mode)}, not a regular file: the "
                                 f"{what} must be one; move it away or choose another directory") from None
        raise
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise ValueError(f"{path} is {kind_of(mode)}, not a regular file: the {what} must be one; move it "
                         "away or choose another directory")
    os.set_blocking(fd, True)
    return fd


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` whole or not at all, never through a link,
    never over anything but a regular file.

    Something at ``path`` other than a regular file or a symlink (a FIFO, a device, a
    socket, a directory) is refused before anything is written, and again just before the
    rename (:func:`check_output_target`). The bytes go to a new temporary file beside
    ``path`` (created exclusively, so a file or a symlink planted under any name is never
    written through), are ``fsync``-ed, and the file is renamed over ``path``: a symlink at
    ``path`` is replaced, its target untouched. The directory is ``fsync``-ed after the
    rename. On any error the temporary file is removed and ``path`` is as it was. Returns
    ``path``.
    """
    path = Path(path)
    check_output_target(path)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path, reserve=len(".12345678.tmp")) + ".",
                               suffix=".tmp", dir=path.parent)  # mkstemp adds 8 characters
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        check_output_target(path)  # made in the meantime: still never renamed over
        os.replace(tmp, path)
    except BaseException:
        with suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_directory(path.parent)
    return path


#: [bytes] the longest file name where the file system cannot say (``PC_NAME_MAX``).
_NAME_MAX = 255


def name_max(directory: str | Path) -> int:
    """[bytes] the longest file name the file system of ``directory`` takes
    (``os.pathconf(directory, "PC_NAME_MAX")``; 255 where it cannot be asked)."""
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):  # missing, no such setting, or Windows
        return _NAME_MAX


def temp_prefix(path: Path, reserve: int) -> str:
    """The start of the name of a temporary file beside ``path``: ``"." + path.name``, cut
    short (whole characters, counted as the bytes the OS stores) so that ``reserve`` more
    bytes still fit :func:`name_max` of ``path``'s directory, however long ``path``'s name.
    The cut is the same for every temporary file of ``path``."""
    room = name_max(path.parent) - reserve
    name = "." + path.name
    while len(os.fsencode(name)) > room and len(name) > 2:
        name = name[:-1]
    return name


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def load_records(out_dir: str | Path) -> list[dict[str, Any]]:
    """The records of an experiment directory (its ``episodes.jsonl``, read by
    :func:`read_records`), failed ones included: one dict a line, in file order."""
    return read_records(Path(out_dir) / RECORDS_FILE).records
