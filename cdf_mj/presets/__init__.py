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
``[scenario]`` (``stop_dwell = [1.0, 3.0]``), still reads, with a DeprecationWarning
naming the table and key to write instead.

On the command line: ``cdf-mj experiment --preset stop-and-wait`` (``--set`` is applied
after the preset); ``cdf-mj presets`` lists them. Every mistake in a file (not TOML, an
unknown key or field, a value of the wrong type or out of range) is a :class:`PresetError`
of one line naming the file and the field.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from cdf_mj.config import FLAT_KEYS, GROUPS, SCENARIO_KEYS, ScenarioConfig
from cdf_mj.inputs import PRESET_MAX_BYTES, parse_user_toml, read_user_text

__all__ = ["STRESS_PREFIX", "SUFFIX", "Preset", "PresetError", "load_preset", "preset_description", "preset_names",
           "read_preset", "scenario_preset_names"]

#: The suffix of a preset file.
SUFFIX = ".toml"
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
        base = base or ScenarioConfig()
        try:
            return base.with_values(self.scenario)
        except ValueError as exc:  # ScenarioConfig names the field and its range
            raise PresetError(f"preset {self.source}: [scenario] {exc}") from None

    def changes(self) -> dict[str, tuple[Any, Any]]:
        """Dotted key -> (default, preset value) for each field whose value differs from the
        default (a field set to its default is left out)."""
        default = ScenarioConfig()
        return {k: (default.get(k), v) for k, v in self.scenario.items() if default.get(k) != v}


def _packaged() -> dict[str, Any]:
    """Preset name -> its file in this package (a Traversable), sorted by name."""
    files = resources.files(__name__)
    found = {f.name[: -len(SUFFIX)]: f for f in files.iterdir() if f.name.endswith(SUFFIX) and f.is_file()}
    return dict(sorted(found.items()))


#: The prefix of the stress presets (scripts/stress.py runs them; docs/STRESS.md).
STRESS_PREFIX = "stress-"


def preset_names() -> list[str]:
    """The names of the presets shipped with the package, sorted."""
    return list(_packaged())


def scenario_preset_names() -> list[str]:
    """The shipped presets that vary the scenario's driver or ego (:func:`preset_names` but
    the stress presets, whose suite is scripts/stress.py)."""
    return [n for n in preset_names() if not n.startswith(STRESS_PREFIX)]


def _is_path(name_or_path: str | Path) -> bool:
    """A path (a ``.toml`` suffix, a directory part or a Path object) rather than a name."""
    if isinstance(name_or_path, Path):
        return True
    return name_or_path.endswith(SUFFIX) or "/" in name_or_path or "\\" in name_or_path


def _number(source: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PresetError(f"preset {source}: [scenario] {key} must be a number, got {value!r}")
    return float(value)


def _coerce(source: str, key: str, value: Any, default: Any) -> Any:
    """``value`` read from TOML in the type of the field's ``default``; PresetError if it
    cannot be (ranges are checked by ScenarioConfig)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise PresetError(f"preset {source}: [scenario] {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, float):
        return _number(source, key, value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise PresetError(f"preset {source}: [scenario] {key} must be an integer, got {value!r}")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list) or len(value) != len(default):
            example = ", ".join(f"{float(v):g}" for v in default)
            raise PresetError(f"preset {source}: [scenario] {key} must be an array of {len(default)} numbers, "
                              f"e.g. [{example}], got {value!r}")
        return tuple(_number(source, key, v) for v in value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise PresetError(f"preset {source}: [scenario] {key} must be a string, got {value!r}")
        return value
    raise PresetError(f"preset {source}: [scenario] {key} cannot be set in a preset")


def _dotted(table: dict[str, Any], source: str) -> dict[str, Any]:
    """The ``[scenario]`` table by dotted key: its group tables' fields, and the flat keys
    of version 0.1 (:data:`~cdf_mj.config.FLAT_KEYS`, with a DeprecationWarning). A key
    that is neither is kept as it is (and refused as unknown)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key in GROUPS and isinstance(value, dict):
            out.update({f"{key}.{field}": v for field, v in value.items()})
        elif key in FLAT_KEYS:
            group, _, field = FLAT_KEYS[key].partition(".")
            warnings.warn(f"preset {source}: [scenario] {key} is a flat key of version 0.1; write {field} in "
                          f"[scenario.{group}]", DeprecationWarning, stacklevel=4)
            out[FLAT_KEYS[key]] = value
        else:
            out[key] = value
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
    default = ScenarioConfig()
    scenario: dict[str, Any] = {}
    for key, value in _dotted(table, source).items():
        if key not in SCENARIO_KEYS:
            raise PresetError(f"preset {source}: [scenario] unknown field {key!r}; "
                              f"valid fields: {', '.join(SCENARIO_KEYS)}")
        scenario[key] = _coerce(source, key, value, default.get(key))
    preset = Preset(name=name, description=" ".join(description.split()), scenario=scenario, source=source)
    preset.config()  # ranges: PresetError naming the file and the field
    return preset


def read_preset(name_or_path: str | Path) -> Preset:
    """The :class:`Preset` of a shipped name (``"stop-and-wait"``) or of a TOML file of
    your own (a path: ends in ``.toml`` or has a directory part).

    PresetError (one line) for an unknown name (listing the shipped ones), a file that
    cannot be read, a file that is not TOML (with line and column), an unknown key or
    field (listing the valid ones), or a value of the wrong type or out of range.
    """
    if _is_path(name_or_path):
        path = Path(name_or_path)
        # a regular file (a FIFO or a device is refused unopened) of at most PRESET_MAX_BYTES
        text = read_user_text(path, "preset file", PRESET_MAX_BYTES, PresetError,
                              f"give a path to a .toml file or one of the names: {', '.join(preset_names())}")
        return _parse(text, path.stem, str(path))
    packaged = _packaged()
    if name_or_path not in packaged:
        raise PresetError(f"unknown preset {name_or_path!r}: choose from {', '.join(packaged)}, "
                          f"or give the path of a {SUFFIX} file")
    return _parse(packaged[name_or_path].read_text(encoding="utf-8"), name_or_path,
                  f"{name_or_path} (cdf_mj/presets/{name_or_path}{SUFFIX})")


def load_preset(name_or_path: str | Path) -> ScenarioConfig:
    """The validated ScenarioConfig of a preset (see :func:`read_preset`): the defaults
    with the preset's fields set. PresetError (a ValueError) naming the file and the field."""
    return read_preset(name_or_path).config()


def preset_description(name_or_path: str | Path) -> str:
    """The description of a preset: who the driver is and why it is a test (one line)."""
    return read_preset(name_or_path).description
