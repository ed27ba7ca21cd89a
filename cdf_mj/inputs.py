"""The one input layer: every file and text value that a user hands ``cdf_mj`` is read and
parsed here, with the same bounds everywhere.

* :func:`read_regular` / :func:`read_text`: regular files only (a FIFO, a device, a
  directory or a socket is refused by name, checked with ``stat`` before anything opens
  it), and a size bound checked before reading and again while reading (a file that grows
  under the reader, or one like ``/proc/...`` whose size ``stat`` does not tell).
* :func:`parse_json` / :func:`parse_toml`: a nesting-depth bound checked before the parser
  recurses, so a value ``[[[[...`` 5000 deep is one line, never a RecursionError.
* :func:`printable`: control characters escaped before text from a file reaches a
  terminal (an ESC in a preset's description cannot recolour or clear the screen).
* :func:`is_path` / :func:`read_named`: the one rule by which a user's word names a file
  of theirs or one shipped with the package (a preset, a falsification space), and the
  reading of either.

Every refusal is an :class:`InputError` (a ValueError) of one line naming the input (the
caller's ``what``, e.g. ``"preset file"``, and the path) and the bound. Errors of the
operating system (a missing file, no permission) and of the parsers (the line and column
of a syntax error) pass through unchanged, so that each caller words them as before. ::

    from cdf_mj.inputs import PRESET_MAX_BYTES, parse_toml, read_text
    data = parse_toml(read_text(path, "preset file", PRESET_MAX_BYTES), f"preset file {path}")

This module imports nothing of ``cdf_mj``: it is the lowest layer, under config, records
and the presets.
"""

from __future__ import annotations

import json
import os
import re
import stat
import sys
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

if sys.version_info >= (3, 11):
    from importlib.resources.abc import Traversable

    import tomllib
else:  # Python 3.10: the same parser from PyPI (a dependency there)
    from importlib.abc import Traversable

    import tomli as tomllib

__all__ = [
    "MAX_DEPTH",
    "NAMES_MAX_BYTES",
    "PRESET_MAX_BYTES",
    "RECORDS_MAX_BYTES",
    "SETTINGS_MAX_BYTES",
    "TOML_SUFFIX",
    "TRACE_MAX_BYTES",
    "InputError",
    "NamedText",
    "NotRegularFileError",
    "TOMLDecodeError",
    "check_depth",
    "check_regular",
    "is_path",
    "kind_of",
    "packaged_files",
    "parse_json",
    "parse_toml",
    "parse_user_toml",
    "printable",
    "read_named",
    "read_regular",
    "read_text",
    "read_user_text",
]

_KiB, _MiB, _GiB = 2**10, 2**20, 2**30

# ------------------------------------------------------------------------ the bounds
#: Levels of nesting (arrays and objects/tables, the outermost one included) that a JSON
#: or TOML input may hold. The deepest the package writes is 4 (a settings file's
#: ``scenario.obstacle.stop_dwell`` pair); 64 leaves room for any hand-written file, and
#: keeps the parsers (tomllib spends about 3 Python frames a level) and every function
#: that walks a parsed value far below Python's default limit of 1000 frames.
MAX_DEPTH = 64
#: [bytes] a preset file (``--preset``, ``cdf-mj presets FILE``): a description and a few
#: fields, well under 4 kB; 1 MiB is generous and reads in a millisecond.
PRESET_MAX_BYTES = 1 * _MiB
#: [bytes] a names file (``--names``): at most a dozen element names, under 1 kB.
NAMES_MAX_BYTES = 1 * _MiB
#: [bytes] a monitor trace (``render --trace``): about 400 bytes a tick, so an episode of
#: 600 s at 0.1 s (6000 ticks) is about 2.5 MB; 64 MiB holds 150 000 ticks (over 4 hours
#: at 10 Hz) and parses in well under 1 GB.
TRACE_MAX_BYTES = 64 * _MiB
#: [bytes] an experiment's ``settings.json``: two configs and the scene's file hashes,
#: a few kB.
SETTINGS_MAX_BYTES = 16 * _MiB
#: [bytes] an experiment's ``episodes.jsonl``: a run may hold 10^7 episodes
#: (``cdf_mj.config.MAX_EPISODES``) of 1 to 3 kB each, so up to about 30 GB is a real run.
RECORDS_MAX_BYTES = 32 * _GiB

#: What :func:`parse_toml` raises for a document that is not TOML (with line and column).
TOMLDecodeError = tomllib.TOMLDecodeError

_CHUNK = 1 * _MiB  # [bytes] read at a time, so that a growing file is caught within 1 MiB


class InputError(ValueError):
    """An input refused by this layer: one line naming it (the caller's ``what`` and path)
    and the bound it breaks."""


class NotRegularFileError(InputError):
    """A path that is not a regular file; ``kind`` says what it is (``"a FIFO (named
    pipe)"``, ``"a directory"``, ...)."""

    def __init__(self, message: str, kind: str) -> None:
        super().__init__(message)
        self.kind = kind


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``"a directory"``, ``"a FIFO (named
    pipe)"``, ``"a character device"``, ...; ``"a regular file"``)."""
    for test, word in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device")):
        if test(mode):
            return word
    return "not a regular file"


def _refuse_unless_regular(path: str | Path, what: str, mode: int) -> None:
    if not stat.S_ISREG(mode):
        kind = kind_of(mode)
        raise NotRegularFileError(f"{what} {path} is {kind}, not a regular file", kind)


def _size(n: int) -> str:
    """``n`` bytes in words: ``"1 MiB"``, ``"300 bytes"``."""
    for unit, name in ((_GiB, "GiB"), (_MiB, "MiB"), (_KiB, "KiB")):
        if n >= unit and n % unit == 0:
            return f"{n // unit} {name}"
    return f"{n} bytes"


def check_regular(path: str | Path, what: str) -> os.stat_result:
    """The ``stat`` of ``path`` (links followed); NotRegularFileError, naming ``what`` and
    the path and saying what it is, unless it is a regular file. Nothing is opened, so a
    FIFO or a device cannot block or flood. OSError (FileNotFoundError, ...) as ``os.stat``
    raises it."""
    st = os.stat(path)
    _refuse_unless_regular(path, what, st.st_mode)
    return st


def read_regular(path: str | Path, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them.

    Checked before it is opened (:func:`check_regular`: a FIFO, a device, a directory or a
    socket is a NotRegularFileError naming ``what`` and the path; a link is followed), its
    size checked against ``max_bytes`` before reading, and again while reading (a file
    that grows, or whose size ``stat`` does not tell): InputError naming the bound. It is
    opened non-blocking, so a FIFO put in its place after the check cannot hang the reader
    either. OSError (a missing file, no permission) passes through as ``open`` raises it.
    """
    st = check_regular(path, what)
    if st.st_size > max_bytes:
        raise InputError(f"{what} {path} is {st.st_size} bytes, larger than the bound of {_size(max_bytes)}")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0) | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(path, flags)
    try:
        _refuse_unless_regular(path, what, os.fstat(fd).st_mode)  # replaced since the check
        chunks: list[bytes] = []
        total = 0
        while True:
            chunk = os.read(fd, min(_CHUNK, max_bytes + 1 - total))
            if not chunk:
                return b"".join(chunks)
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise InputError(f"{what} {path} grew past the bound of {_size(max_bytes)} while being read")
    finally:
        os.close(fd)


def read_text(path: str | Path, what: str, max_bytes: int) -> str:
    """:func:`read_regular`, decoded as UTF-8 (UnicodeDecodeError, a ValueError, if it is
    not UTF-8 text)."""
    return read_regular(path, what, max_bytes).decode("utf-8")


def read_user_text(path: str | Path, what: str, max_bytes: int, error: type[ValueError], choices: str) -> str:
    """:func:`read_text` of a file a user named (a preset, a space), every failure an
    ``error`` of one line naming ``what`` and the path: a missing file (``choices`` says
    what to give instead), one that cannot be read (the system's reason), one that is not
    UTF-8, or a refusal of :func:`read_regular`."""
    try:
        return read_text(path, what, max_bytes)
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist; {choices}") from None
    except (OSError, UnicodeDecodeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__
        raise error(f"{what} {path} cannot be read ({why})") from None
    except InputError as exc:
        raise error(str(exc)) from None


# ------------------------------------------------------------------------ names or paths
#: The suffix of the package's TOML inputs (presets, falsification spaces).
TOML_SUFFIX = ".toml"


def is_path(name_or_path: str | os.PathLike[str], suffix: str = TOML_SUFFIX) -> bool:
    """Whether ``name_or_path`` names a file of the user's rather than one shipped by name:
    a path object, a text ending in ``suffix``, or one with a directory part (``/`` or
    ``\\``, a path as Windows writes it)."""
    if not isinstance(name_or_path, str):
        return True
    return name_or_path.endswith(suffix) or "/" in name_or_path or "\\" in name_or_path


def packaged_files(package: str, folder: str = "", suffix: str = TOML_SUFFIX) -> dict[str, Traversable]:
    """Name (the file's stem) -> file, for each ``suffix`` file of ``package`` (a dotted
    name: ``"cdf_mj.presets"``) or of its sub-folder ``folder``, sorted by name."""
    files = resources.files(package)
    if folder:
        files = files / folder
    found = {f.name[: -len(suffix)]: f for f in files.iterdir() if f.name.endswith(suffix) and f.is_file()}
    return dict(sorted(found.items()))


class NamedText(NamedTuple):
    """The text of a file named by a user (:func:`read_named`)."""

    name: str  # the file's stem: "stop-and-wait"
    source: str  # how messages name it: the user's path, or "NAME (cdf_mj/presets/NAME.toml)"
    text: str
    path: Path | None  # the user's file; None for one of the package's


def read_named(name_or_path: str | os.PathLike[str], what: str, package: str, error: type[ValueError], *,
               folder: str = "", max_bytes: int = PRESET_MAX_BYTES, suffix: str = TOML_SUFFIX) -> NamedText:
    """The text of a user's file (a path: :func:`is_path`) or of the file of that name
    shipped in ``package`` (its ``folder``: :func:`packaged_files`).

    ``error`` (one line) for an unknown name (listing the shipped ones) and for a file of
    the user's that is missing, cannot be read, is not UTF-8 or breaks a bound of
    :func:`read_user_text` (``what`` names it: ``"preset"`` gives ``"preset file PATH"``).
    """
    files = packaged_files(package, folder, suffix)
    if is_path(name_or_path, suffix):
        path = Path(name_or_path)
        text = read_user_text(path, f"{what} file", max_bytes, error,
                              f"give the path of a {suffix} file or one of the names: {', '.join(files)}")
        return NamedText(path.stem, str(path), text, path)
    name = str(name_or_path)
    if name not in files:
        raise error(f"unknown {what} {name!r}: choose from {', '.join(files)}, or give the path of a {suffix} file")
    where = "/".join([*package.split("."), *([folder] if folder else []), name + suffix])
    return NamedText(name, f"{name} ({where})", files[name].read_text(encoding="utf-8"), None)


# ------------------------------------------------------------------------ nesting
# The tokens that matter for nesting: strings and comments (whose brackets do not count)
# and brackets. Every string pattern matches wherever its quote opens (an unclosed string
# runs to the end of its line or of the text), so that the scan is one linear pass.
_JSON_TOKENS = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*(?:"|\\?\Z)|[\[\]{}]', re.DOTALL)
_BASIC = r'"[^"\\\n]*(?:\\[^\n][^"\\\n]*)*'  # a basic string, without its closing quote
_LITERAL = r"'[^'\n]*"  # a literal string, without its closing quote
_KEY_PART = rf"""(?:[A-Za-z0-9_-]+|{_BASIC}"|{_LITERAL}')"""
_KEY_PARTS = re.compile(_KEY_PART)
# TOML also nests tables by dotted keys (``a.b.c = 1``, ``[a.b.c]``): a run of key parts
# joined by dots is one token whose parts are counted (a float such as 1.5 counts 2:
# harmless). A run starts only where no bare key character precedes it.
_TOML_TOKENS = re.compile(
    r'"""(?:[^\\"]|\\.|""?(?!"))*(?:"{3,5}|\\?\Z)'  # multi-line basic string
    r"|'''(?:[^']|''?(?!'))*(?:'{3,5}|\Z)"  # multi-line literal string
    rf"|(?P<key>(?<![A-Za-z0-9_-]){_KEY_PART}(?:[ \t]*\.[ \t]*{_KEY_PART})+)"  # dotted key
    rf"""|{_BASIC}(?:"|\\?(?=\n)|\\?\Z)|{_LITERAL}(?:'|(?=\n)|\Z)|#[^\n]*|[\[\]{{}}]""", re.DOTALL)


def _too_deep(what: str, max_depth: int) -> InputError:
    return InputError(f"{what} is nested deeper than {max_depth} levels (arrays and objects or tables)")


def check_depth(text: str, what: str, max_depth: int = MAX_DEPTH, syntax: str = "json") -> None:
    """InputError ``"WHAT is nested deeper than N levels"`` if the brackets and braces of
    ``text`` (JSON, or TOML with ``syntax="toml"``), outside strings and comments, open
    more than ``max_depth`` levels at once. One pass over ``text``, no recursion; a text
    with no more than ``max_depth`` brackets in all is passed without a scan."""
    toml = syntax == "toml"
    if text.count("[") + text.count("{") <= max_depth and not (toml and text.count(".") >= max_depth):
        return
    depth = 0
    for match in (_TOML_TOKENS if toml else _JSON_TOKENS).finditer(text):
        token = match.group()
        if match.lastgroup == "key" and len(_KEY_PARTS.findall(token)) > max_depth:
            raise _too_deep(what, max_depth)
        if token in "[{":
            depth += 1
            if depth > max_depth:
                raise _too_deep(what, max_depth)
        elif token in "]}":
            depth = max(depth - 1, 0)


def _check_value_depth(value: Any, what: str, max_depth: int) -> None:
    """InputError if the parsed ``value`` holds lists and dicts more than ``max_depth``
    levels deep (walked with a stack, not recursion): TOML's dotted keys (``a.b.c = 1``)
    nest tables without any bracket."""
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else None
        if children is None:
            continue
        if depth > max_depth:
            raise _too_deep(what, max_depth)
        stack.extend((child, depth + 1) for child in children)


def parse_json(text: str | bytes, what: str, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(text)`` after :func:`check_depth`: InputError naming ``what`` for a value
    nested deeper than ``max_depth`` levels, never a RecursionError. json.JSONDecodeError
    (with line and column) and UnicodeDecodeError (bytes not UTF-8) pass through."""
    if isinstance(text, bytes):  # as json.loads decodes bytes
        text = text.decode(json.detect_encoding(text), "surrogatepass")
    check_depth(text, what, max_depth)
    try:
        return json.loads(text)
    except RecursionError:  # a nesting the scan missed: still one line
        raise _too_deep(what, max_depth) from None


def parse_toml(text: str, what: str, max_depth: int = MAX_DEPTH) -> dict[str, Any]:
    """``tomllib.loads(text)`` after :func:`check_depth` (arrays and inline tables), with the
    tables that dotted keys and headers nest checked after it: InputError naming ``what``
    for a document nested deeper than ``max_depth`` levels (the document's own table is
    the first), never a RecursionError. tomllib.TOMLDecodeError passes through."""
    check_depth(text, what, max_depth, syntax="toml")
    try:
        data = tomllib.loads(text)
    except RecursionError:  # a nesting the scan missed: still one line
        raise _too_deep(what, max_depth) from None
    _check_value_depth(data, what, max_depth)
    return data


def parse_user_toml(text: str, what: str, error: type[ValueError]) -> dict[str, Any]:
    """:func:`parse_toml` of a file a user wrote (a preset, a space), every failure an
    ``error`` of one line: ``"{what}: not valid TOML: ..."`` with the parser's line and
    column, or the nesting bound's refusal."""
    try:
        return parse_toml(text, what)
    except TOMLDecodeError as exc:
        raise error(f"{what}: not valid TOML: {' '.join(str(exc).split())}") from None
    except InputError as exc:
        raise error(str(exc)) from None


# ------------------------------------------------------------------------ output
def _escapes(keep: str) -> dict[int, str]:
    """Code point -> its escape for every control character (C0, DEL, C1) and the
    bidirectional overrides and isolates, but those in ``keep``."""
    points = [*range(0x20), *range(0x7F, 0xA0), *range(0x202A, 0x202F), *range(0x2066, 0x206A)]
    return {p: (f"\\x{p:02x}" if p < 0x100 else f"\\u{p:04x}") for p in points if chr(p) not in keep}


_TABLES: dict[str, dict[int, str]] = {}


def printable(text: str, keep: str = "") -> str:
    """``text`` with every control character (C0 such as NUL and ESC, DEL, C1) and every
    bidirectional override written as its escape (``\\x1b``, ``\\x00``, ``\\u202e``), so
    that text read from a file prints as what it is and cannot drive the terminal;
    characters in ``keep`` (e.g. ``"\\n\\t"``) are left as they are."""
    table = _TABLES.get(keep)
    if table is None:
        table = _TABLES[keep] = _escapes(keep)
    return text.translate(table)
