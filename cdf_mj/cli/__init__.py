"""The ``cdf-mj`` command line.

::

    cdf-mj                                                 # the commands, one line each
    cdf-mj episode --seed 7 --planner reactive            # one episode, record as JSON
    cdf-mj episode --seed 7 --set obstacle.beta=0.1 --set ego.start_spread='[-4, 4]'
    python -m cdf_mj episode --seed 7                      # the same without the script

Bad input (unknown planner, negative seed, out-of-range parameter, unreadable scene,
a simulation that diverges) ends with one line ``cdf-mj: error: ...`` on stderr and exit
status 2; ``--debug`` shows the traceback instead. Every count and size has an upper bound
(``cdf_mj.config.MAX_*``: 10^6 particles, 10^7 episodes, 1024 workers, seeds below 2^53),
checked before any work; control characters in a message (a path with a newline) are
escaped, so the error stays one line. A run in which episodes failed
(``experiment``, ``reproduce``, ``sweep``) exits with status 1. With stderr closed
(``2>&-``) commands run as usual and only their messages are lost; with stdout closed
(``>&-``) nothing runs (status 2), as what they print would be lost.

One idea has one flag on every command (``--seed``, ``--episodes``, ``--planner``,
``--workers``, ...): the table is in :mod:`cdf_mj.cli.args`. The spellings of earlier
releases (``--seed0``, ``--planners``, ``--budget``, ``render --compare``) still work and
say so in one line on stderr.

The package's modules: ``app`` (:func:`main`, the parser, errors to one line), ``args``
(what the commands share: :class:`CLIError`, the vocabulary and its old spellings, bounded
argument types, the run options and the CDF's options), and one module per command
(``episode``, ``experiment`` with ``reproduce``, ``sweep``, ``render``, ``report``,
``falsify`` with ``estimate``, ``bench``, ``presets``). A command module imports public
names of ``args`` only. Nothing else in ``cdf_mj`` imports this package (tests/test_layers.py).

Adding a subcommand: write ``cdf_mj/cli/<name>.py`` with ``add_<name>(subparsers)``, which
builds its parser with ``args.command`` (use :func:`add_run_arguments` for ``--scene``,
``--set``, ``--workers``, ...; the flags of the table for its other ideas) and sets
``func`` to a function ``(args) -> int``; append it to ``app._SUBCOMMANDS``. Raise
:class:`CLIError` (or any ``ValueError``) for bad input; logic lives in the package, not
here. Scripts that take ``--set`` too can call :func:`parse_overrides`.
"""

from __future__ import annotations

import os
import sys

try:  # MuJoCo loads the OpenGL backend named by MUJOCO_GL as it is imported
    import mujoco  # noqa: F401
except (ImportError, AttributeError, RuntimeError) as _exc:
    if not os.environ.get("MUJOCO_GL"):
        raise
    print(f"cdf-mj: error: MuJoCo cannot load the OpenGL backend MUJOCO_GL={os.environ['MUJOCO_GL']} "
          f"({' '.join(str(_exc).split()) or type(_exc).__name__}); unset MUJOCO_GL (cdf-mj render "
          "then tries EGL, then OSMesa) or set it to one installed here", file=sys.stderr)
    raise SystemExit(2) from None

from cdf_mj._version import __version__
from cdf_mj.cli.app import build_parser, main
from cdf_mj.cli.args import (
    EXIT_FAILED_EPISODES,
    EXIT_USAGE,
    PROG,
    SETTABLE,
    CLIError,
    add_cdf_arguments,
    add_format_argument,
    add_run_arguments,
    add_scenario_arguments,
    cdf_from_args,
    config_from_args,
    parse_overrides,
    pool_from_args,
    scene_from_args,
)
from cdf_mj.cli.experiment import RUN_FILES
from cdf_mj.cli.sweep import MAX_SWEEP_VALUES

__all__ = ["EXIT_FAILED_EPISODES", "EXIT_USAGE", "MAX_SWEEP_VALUES", "PROG", "RUN_FILES", "SETTABLE", "CLIError",
           "__version__", "add_cdf_arguments", "add_format_argument", "add_run_arguments", "add_scenario_arguments",
           "build_parser", "cdf_from_args", "config_from_args", "main", "parse_overrides", "pool_from_args",
           "scene_from_args"]
