"""Files a scene reads, checked before anything opens them: the MJCF file and every file it
names must be regular files (:func:`check_regular_files`: a FIFO or a device cannot hang
the load), and a names file (``cdf-mj ... --names FILE``, JSON or TOML) is read into
:class:`~cdf_mj.config.SceneNames` (:func:`read_names`). Both refuse with a one-line
:class:`~cdf_mj.sim.errors.SceneError`. ::

    from cdf_mj.sim.files import read_names
    names = read_names("my_names.toml")
"""

from __future__ import annotations

import dataclasses
import json
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from cdf_mj.config import SceneNames
from cdf_mj.inputs import (
    NAMES_MAX_BYTES,
    InputError,
    TOMLDecodeError,
    check_regular,
    kind_of,
    parse_json,
    parse_toml,
    read_text,
)
from cdf_mj.sim.errors import SceneError

__all__ = ["check_regular_files", "read_names"]


def _regular(path: Path, what: str) -> None:
    """SceneError unless ``path`` (followed if a link) is a regular file; nothing is opened,
    so a FIFO or device cannot block."""
    try:
        check_regular(path, what)  # the input layer: stat only
    except FileNotFoundError:
        raise SceneError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise SceneError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    except InputError as exc:
        raise SceneError(str(exc)) from None


def check_regular_files(path: str | Path) -> None:
    """SceneError, one line naming the file, unless the MJCF file ``path`` and every file it
    names (``<include file=...>`` recursively, meshes, textures, height fields, models of
    ``<attach>``) that exists is a regular file. Runs before MuJoCo opens any of them, so a
    FIFO or a device in a scene cannot hang or flood the load. Files that do not exist or
    that are not valid XML are left to MuJoCo, whose error names them."""
    path = Path(path)
    _regular(path, "scene file")
    root_dir = path.parent
    seen: set[Path] = set()
    todo = [path]
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        try:
            tree = ET.parse(current)
        except (ET.ParseError, OSError, ValueError):
            continue  # MuJoCo reports a malformed file with its line
        dirs = {root_dir, current.parent}
        for compiler in tree.iter("compiler"):
            for attr in ("meshdir", "texturedir", "assetdir"):
                if compiler.get(attr):
                    dirs.add(root_dir / compiler.get(attr, ""))
        for element in tree.iter():
            name = element.get("file")
            if not name:
                continue
            for base in sorted(dirs):
                candidate = base / name
                try:
                    mode = os.stat(candidate).st_mode
                except (OSError, ValueError):
                    continue
                if not stat.S_ISREG(mode):
                    raise SceneError(f"scene {path}: <{element.tag} file=\"{name}\"> is "
                                     f"{candidate}, {kind_of(mode)}, not a regular file; MuJoCo "
                                     "would block or fail reading it")
                if element.tag == "include":
                    todo.append(candidate)


# ---------------------------------------------------------------------- a names file
def read_names(path: str | Path) -> SceneNames:
    """The :class:`SceneNames` of a JSON (``.json``) or TOML (``.toml``) file holding one
    object (table) whose keys are SceneNames fields and whose values are strings; fields
    not given keep their defaults. SceneError, one line naming the file, for a file that
    cannot be read, malformed JSON or TOML (with its line and column), an unknown key (with
    the valid ones), a value that is not a string, or names SceneNames refuses.
    """
    path = Path(path)
    fields = [f.name for f in dataclasses.fields(SceneNames)]
    kind = path.suffix.lower()
    if kind not in (".json", ".toml"):
        raise SceneError(f"names file {path}: expected a .json or .toml file, got {path.suffix or 'no suffix'!r}")
    data: Any
    try:  # the input layer: a regular file of at most NAMES_MAX_BYTES, nested at most MAX_DEPTH
        text = read_text(path, "names file", NAMES_MAX_BYTES)
        data = (parse_json if kind == ".json" else parse_toml)(text, f"names file {path}")
    except FileNotFoundError:
        raise SceneError(f"names file {path} does not exist") from None
    except InputError as exc:
        raise SceneError(str(exc)) from None
    except json.JSONDecodeError as exc:
        raise SceneError(f"names file {path}: not valid JSON at line {exc.lineno}, column "
                         f"{exc.colno}: {exc.msg}") from None
    except TOMLDecodeError as exc:
        raise SceneError(f"names file {path}: not valid TOML: {' '.join(str(exc).split())}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"names file {path} cannot be read: {exc}") from None
    if not isinstance(data, dict):
        raise SceneError(f"names file {path}: expected an object of SceneNames fields, e.g. "
                         f'{{"route_ego": "my_path"}}, got a {type(data).__name__}')
    for key, value in data.items():
        if key not in fields:
            raise SceneError(f"names file {path}: unknown key {key!r}; valid keys: {', '.join(fields)}")
        if not isinstance(value, str):
            raise SceneError(f"names file {path}: {key} must be a string (an element name), got {value!r}")
    try:
        return SceneNames(**data)
    except ValueError as exc:
        raise SceneError(f"names file {path}: {exc}") from None
