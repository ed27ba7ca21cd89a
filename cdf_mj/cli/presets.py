"""``cdf-mj presets``: list the scenario presets that ``--preset`` takes, or show one.
Text read from a preset file (its name, description and path) is printed with its control
characters escaped (:func:`cdf_mj.inputs.printable`): an ESC or a NUL in a description
cannot drive the terminal."""

from __future__ import annotations

import argparse
import json

from cdf_mj.cli.args import PROG, command
from cdf_mj.inputs import printable
from cdf_mj.presets import preset_names, read_preset


def _cmd_presets(args: argparse.Namespace) -> int:
    if args.name is None:
        names = preset_names()
        width = max(map(len, names))
        for name in names:
            print(printable(f"{name:<{width}}  {read_preset(name).summary}"))
        print(f"\n'{PROG} presets NAME' shows the settings of one; "
              f"'{PROG} experiment --preset NAME' runs it.")
        return 0
    preset = read_preset(args.name)  # PresetError: one line
    preset.config()  # values in range
    print(printable(f"{preset.name}: {preset.description}"))
    print(printable(f"source: {preset.source}"))
    changes = preset.changes()
    if not changes:
        print("the default ScenarioConfig: no field changed")
    for key, (default, value) in changes.items():
        print(printable(f"  {key} = {json.dumps(value)}  (default {json.dumps(default)})"))
    return 0


def add_presets(subparsers: argparse._SubParsersAction) -> None:
    """The ``presets`` command."""
    p = command(
        subparsers, "presets", summary="list the scenario presets (--preset NAME), or show one",
        description="List the named scenario presets that --preset takes, each a driver (or "
                    "ego) that differs from the defaults in one trait; with NAME (or a .toml "
                    "file of your own), print the ScenarioConfig fields it changes. The CDF "
                    "keeps its own defaults under every preset.")
    p.add_argument("name", nargs="?", default=None, metavar="NAME",
                   help="a preset name or the path of a .toml preset file")
    p.set_defaults(func=_cmd_presets)
