"""The one reader of what a user types for a :class:`~cdf_mj.config.ScenarioConfig` field.

A key and a value come from ``--set KEY=VALUE`` (the value parsed as JSON), from a preset
file's ``[scenario]`` tables or from a falsification space's ``[dims."KEY"]`` tables (TOML);
each reader hands them here, so that all three take and refuse the same things with the
same words:

* :func:`dotted_key`: a dotted key (``"obstacle.beta"``) as it is; a flat key of version 0.1
  (``"beta"``, :data:`~cdf_mj.config.FLAT_KEYS`) as its dotted key, with a
  :class:`~cdf_mj.config.FlatKeyWarning` (a DeprecationWarning) saying how the same source
  writes it now; any other key refused, naming the nearest valid one and all of them.
* :func:`coerce_value`: a value in its field's type: a number (an integer becomes a float;
  not true or false, not a string), an integer (not a float, not true or false), true or
  false, a string, or a ``(low, high)`` pair from an array of two numbers.
* :func:`apply_values`: a config with the values set, every range checked by the config
  itself (NaN, infinities and numbers too large for a float are out of every range).
* :func:`flat_key_notes`: the FlatKeyWarnings of a block handed, one line each, to a
  function (the command line prints them as ``cdf-mj: note: ...`` on stderr).

Every refusal is a :class:`UserValueError` of one line naming the key; the reader puts in
front where it was read (``"--set: "``, ``"preset FILE: [scenario] "``,
``'space FILE: [dims."KEY"]: '``). ::

    from cdf_mj.config.user_values import apply_values, read_value
    key, value = read_value("beta", 0.1, spell=lambda k: f"--set {k}")   # FlatKeyWarning
    config = apply_values(ScenarioConfig(), {key: value})                 # obstacle.beta = 0.1
"""

from __future__ import annotations

import contextlib
import difflib
import numbers
import os
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping
from typing import Any, TextIO

from cdf_mj.config.scenario import FLAT_KEYS, SCENARIO_KEYS, FlatKeyWarning, ScenarioConfig

__all__ = ["FlatKeyWarning", "UserValueError", "apply_values", "coerce_value", "dotted_key", "flat_key_notes",
           "read_value"]

_DEFAULT = ScenarioConfig()
_PACKAGE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "")  # cdf_mj/


class UserValueError(ValueError):
    """A key or a value a user gave that a ScenarioConfig cannot take: one line naming the
    key (dotted) and what it takes."""


def _as_is(key: str) -> str:
    return key


def _shown(value: Any) -> str:
    """``value`` for a message: ``true``/``false`` as all three inputs spell them, anything
    else as its repr, cut if long (a 400-digit number keeps its start and its length)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}...({len(text)} characters)"


def _stacklevel() -> int:
    """The ``stacklevel`` at which a warning issued by this function's caller names the
    first frame outside ``cdf_mj`` (the user's script or test), however deep the reader."""
    frame = sys._getframe(1)
    level = 1
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    return level


def dotted_key(key: str, spell: Callable[[str], str] = _as_is, where: str = "") -> str:
    """The dotted key of ``key``: a dotted key as it is, a flat key of version 0.1 mapped
    with a FlatKeyWarning ``"{where}{spell(key)} is now {spell(dotted)}"`` (``spell``: how
    the source writes a key, e.g. ``"--set beta"``; ``where``: which file). UserValueError
    for any other key, naming the nearest valid key (if one is near) and all of them."""
    if key in SCENARIO_KEYS:
        return key
    dotted = FLAT_KEYS.get(key)
    if dotted is not None:
        warnings.warn(f"{where}{spell(key)} is now {spell(dotted)}", FlatKeyWarning, stacklevel=_stacklevel())
        return dotted
    near = difflib.get_close_matches(key, SCENARIO_KEYS, n=1, cutoff=0.8)
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    raise UserValueError(f"unknown field {_shown(key)}{hint}; valid fields: {', '.join(SCENARIO_KEYS)}")


def _number(value: Any) -> Any:
    """A real number as a float (one too large for a float as it is: out of every range)."""
    try:
        return float(value)
    except OverflowError:
        return value


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def coerce_value(key: str, value: Any) -> Any:
    """``value`` (as JSON or TOML read it) in the type of the field ``key`` (dotted): a float
    for a number, an int, a bool, a str, or a tuple of two floats for a ``(low, high)``
    pair (from a list or a tuple). UserValueError naming the key and its type otherwise;
    ranges (NaN included) are the config's to check (:func:`apply_values`)."""
    default = _DEFAULT.get(key)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise UserValueError(f"{key} must be true or false, got {_shown(value)}")
        return value
    if isinstance(default, float):
        if not _is_number(value):
            raise UserValueError(f"{key} must be a number, got {_shown(value)}")
        return _number(value)
    if isinstance(default, int):
        if not isinstance(value, numbers.Integral) or isinstance(value, bool):
            raise UserValueError(f"{key} must be an integer, got {_shown(value)}")
        return int(value)
    if isinstance(default, tuple):
        if (not isinstance(value, (list, tuple)) or len(value) != len(default)
                or not all(_is_number(v) for v in value)):
            example = ", ".join(f"{float(v):g}" for v in default)
            raise UserValueError(f"{key} must be an array of {len(default)} numbers, e.g. [{example}], "
                                 f"got {_shown(value)}")
        return tuple(_number(v) for v in value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise UserValueError(f"{key} must be a string, got {_shown(value)}")
        return value
    raise UserValueError(f"{key} cannot be set here")  # no field of another type today


def read_value(key: str, value: Any, spell: Callable[[str], str] = _as_is, where: str = "") -> tuple[str, Any]:
    """``(dotted key, value in its field's type)`` of a key and a value a user gave:
    :func:`dotted_key` (``spell`` and ``where`` word its FlatKeyWarning), then
    :func:`coerce_value`. UserValueError (one line naming the key) for either."""
    dotted = dotted_key(key, spell, where)
    return dotted, coerce_value(dotted, value)


def apply_values(base: ScenarioConfig, values: Mapping[str, Any]) -> ScenarioConfig:
    """``base`` with ``values`` (dotted key -> value, as :func:`read_value` gives them) set,
    validated: UserValueError with the config's one-line message naming the field and
    its range (``"obstacle.beta=2.0 is out of range: must be in [0, 1]"``)."""
    try:
        return base.with_values(values)
    except ValueError as exc:
        raise UserValueError(" ".join(str(exc).split())) from None


_notes_depth = 0  # flat_key_notes blocks open (the outermost one shows the notes)


@contextlib.contextmanager
def flat_key_notes(show: Callable[[str], None]) -> Iterator[None]:
    """Within the block, each FlatKeyWarning is held and, once the block ends without an
    error, its message handed to ``show`` (an error leaves only its own line); other
    warnings go on at once as they would. Within another such block, the outer one shows
    them."""
    global _notes_depth
    if _notes_depth:
        yield
        return
    held: list[str] = []
    _notes_depth += 1
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", FlatKeyWarning)
            shown = warnings.showwarning

            def hold(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                     file: TextIO | None = None, line: str | None = None) -> None:
                if issubclass(category, FlatKeyWarning):
                    held.append(str(message))
                else:  # not ours: as if it had not been caught
                    shown(message, category, filename, lineno, file, line)

            warnings.showwarning = hold
            yield
    finally:
        _notes_depth -= 1
    for note in held:
        show(note)
