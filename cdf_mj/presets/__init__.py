"""Named scenario presets: the world's driver varied, one TOML file per preset.

A preset is a :class:`~cdf_mj.config.ScenarioConfig` with some fields changed from the
defaults, kept in a file of this package (``cdf_mj/presets/NAME.toml``) with a line or two
on who the driver is and why it is a test. Presets change the world only: the CDF keeps
its own :class:`~cdf_mj.config.CDFConfig` defaults, so running the planners on every
preset is a model-mismatch evaluation (``scripts/mismatch.py``, docs/MISMATCH.md). ::

    from cdf_mj.presets import load_preset, preset_names
    preset_names()                               # ['default', 'fast-ego', ...]
    config = load_preset("stop-and-wait")        # a validated ScenarioConfig
    config = load_preset("my_driver.toml")       # a file of your own, same format

A preset file holds ``description`` (a string) and a ``[scenario]`` table of
ScenarioConfig fields, one table per group (``[scenario.obstacle]``, ``[scenario.ego]``,
...: :data:`cdf_mj.config.SCENARIO_KEYS`), in the fields' units (pairs as two-element
arrays)::

    description = "A driver who waits 1-3 s at the stop line before it goes."

    [scenario.obstacle]
    stop_dwell = [1.0, 3.0]   # [s]

A file of version 0.1, with the flat keys of :data:`cdf_mj.config.FLAT_KEYS` directly in
``[scenario]`` (``stop_dwell = [1.0, 3.0]``), still reads, with a
:class:`~cdf_mj.config.FlatKeyWarning` (a DeprecationWarning) naming the table and key to
write instead; the command line shows it as a one-line note. Keys and values are read as
``--set`` and space files read them (:mod:`cdf_mj.config.user_values`).

On the command line: ``cdf-mj experiment --preset stop-and-wait`` (``--set`` is applied
after the preset); ``cdf-mj presets`` lists them. Every mistake in a file (not TOML, an
unknown key or field, a value of the wrong type or out of range) is a :class:`PresetError`
of one line naming the file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cdf_mj.config import GROUPS, ScenarioConfig
from cdf_mj.config.user_values import UserValueError, apply_values, read_value
from cdf_mj.inputs import PRESET_MAX_BYTES, TOML_SUFFIX, packaged_files, parse_user_toml, read_named

__all__ = ["STRESS_PREFIX", "SUFFIX", "Preset", "PresetError", "load_preset", "preset_description", "preset_names",
           "read_preset", "scenario_preset_names"]

#: The suffix of a preset file.
SUFFIX = TOML_SUFFIX
_KEYS = ("description", "scenario")


class PresetError(ValueError):
    """A preset that cannot be found or read; the message is one line naming the file
    (or the unknown name) and what to change."""


@dataclass(frozen=True)
class Preset:
    """One preset as read from its file: the fields it changes, not yet a config."""

    name: str  # file stem: "stop-and-wait"
    description: str  # who this driver is and why it is a test
    scenario: dict[str, Any]  # dotted ScenarioConfig key ("obstacle.accel") -> value (pairs as tuples)
    source: str  # where it was read from: the package's file or a user's path

    @property
    def summary(self) -> str:
        """The first sentence of the description (for one-line listings)."""
        head, sep, _ = self.description.partition(". ")
        return head + "." if sep else self.description

    def config(self, base: ScenarioConfig | None = None) -> ScenarioConfig:
        """``base`` (default: the defaults) with this preset's fields set; PresetError
        naming the file and the field if a value is out of range."""
        try:
            return apply_values(base or ScenarioConfig(), self.scenario)
        except UserValueError as exc:  # ScenarioConfig names the field and its range
            raise PresetError(f"preset {self.source}: [scenario] {exc}") from None

    def changes(self) -> dict[str, tuple[Any, Any]]:
        """Dotted key -> (default, preset value) for each field whose value differs from the
        default (a field set to its default is left out)."""
        default = ScenarioConfig()
        return {k: (default.get(k), v) for k, v in self.scenario.items() if default.get(k) != v}


#: The prefix of the stress presets (scripts/stress.py runs them; docs/STRESS.md).
STRESS_PREFIX = "stress-"


def preset_names() -> list[str]:
    """The names of the presets shipped with the package, sorted."""
    return list(packaged_files(__name__, suffix=SUFFIX))


def scenario_preset_names() -> list[str]:
    """The shipped presets that vary the scenario's driver or ego (:func:`preset_names` but
    the stress presets, whose suite is scripts/stress.py)."""
    return [n for n in preset_names() if not n.startswith(STRESS_PREFIX)]


def _spell(key: str) -> str:
    """How a preset file writes ``key``: ``"[scenario.obstacle] beta"``, or ``"[scenario] beta"``
    for a flat key of version 0.1."""
    group, dot, field = key.partition(".")
    return f"[scenario.{group}] {field}" if dot else f"[scenario] {key}"


def _entries(table: dict[str, Any]) -> list[tuple[str, Any]]:
    """The ``[scenario]`` table as (key, value): its group tables' fields by dotted key, any
    other key (a flat key of version 0.1, or one to refuse) as it is."""
    out: list[tuple[str, Any]] = []
    for key, value in table.items():
        if key in GROUPS and isinstance(value, dict):
            out += [(f"{key}.{field}", v) for field, v in value.items()]
        else:
            out.append((key, value))
    return out


def _parse(text: str, name: str, source: str) -> Preset:
    """The preset in the TOML ``text`` read from ``source``."""
    data = parse_user_toml(text, f"preset {source}", PresetError)  # nested at most MAX_DEPTH levels
    unknown = sorted(set(data) - set(_KEYS))
    if unknown:
        raise PresetError(f"preset {source}: unknown key {unknown[0]!r}; a preset holds only 'description' "
                          "and a [scenario] table (the CDF always keeps its own defaults)")
    description = data.get("description")
    if not isinstance(description, str) or not description.strip():
        raise PresetError(f"preset {source}: needs description = \"...\" (who this driver is and why it is a test)")
    table = data.get("scenario", {})
    if not isinstance(table, dict):
        raise PresetError(f"preset {source}: 'scenario' must be a table ([scenario]), got {table!r}")
    scenario: dict[str, Any] = {}
    for key, value in _entries(table):
        try:  # the reader of --set and space files too: the same types, flat keys and words
            dotted, coerced = read_value(key, value, _spell, f"preset {source}: ")
        except UserValueError as exc:
            raise PresetError(f"preset {source}: [scenario] {exc}") from None
        scenario[dotted] = coerced
    preset = Preset(name=name, description=" ".join(description.split()), scenario=scenario, source=source)
    preset.config()  # ranges: PresetError naming the file and the field
    return preset


def read_preset(name_or_path: str | Path) -> Preset:
    """The :class:`Preset` of a shipped name (``"stop-and-wait"``) or of a TOML file of
    your own (a path: ends in ``.toml`` or has a directory part, :func:`cdf_mj.inputs.is_path`).

    PresetError (one line) for an unknown name (listing the shipped ones), a file that
    cannot be read, a file that is not TOML (with line and column), an unknown key or
    field (listing the valid ones), or a value of the wrong type or out of range.
    """
    # a user's file: a regular file (a FIFO or a device is refused unopened) of at most PRESET_MAX_BYTES
    named = read_named(name_or_path, "preset", __name__, PresetError, max_bytes=PRESET_MAX_BYTES, suffix=SUFFIX)
    return _parse(named.text, named.name, named.source)


def load_preset(name_or_path: str | Path) -> ScenarioConfig:
    """The validated ScenarioConfig of a preset (see :func:`read_preset`): the defaults
    with the preset's fields set. PresetError (a ValueError) naming the file and the field."""
    return read_preset(name_or_path).config()


def preset_description(name_or_path: str | Path) -> str:
    """The description of a preset: who the driver is and why it is a test (one line)."""
    return read_preset(name_or_path).description
