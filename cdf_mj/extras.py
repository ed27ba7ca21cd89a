"""The optional extras of cdf_mj and the one way every message names them.

Each optional feature lives in an extra of ``pyproject.toml`` (``gym``, ``ray``, ``sumo``, ``viz``).
Code that needs one imports it through :func:`require`, which fails with one line naming
the extra and the command that installs it, the same in every module::

    from cdf_mj.extras import require

    plt = require("matplotlib.pyplot", "viz", "cdf-mj report")

The package is not on PyPI, so ``pip install 'cdf-mj[viz]'`` would not find it: the hint
says how to add an extra to a checkout (an editable install) and to a wheel.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from cdf_mj._version import __version__

__all__ = ["EXTRAS", "WHEEL", "install_hint", "require"]

#: Each extra -> the top-level modules it installs (their import names).
EXTRAS: dict[str, tuple[str, ...]] = {
    "gym": ("gymnasium",),
    "ray": ("ray",),
    "viz": ("matplotlib", "imageio", "imageio_ffmpeg", "PIL"),
    "sumo": ("libsumo", "sumolib", "sumo"),
}

#: The file name of this version's wheel (``pip wheel .`` in a checkout writes it).
WHEEL = f"cdf_mj-{__version__}-py3-none-any.whl"


def install_hint(extra: str) -> str:
    """How to install ``extra``, one line valid for a checkout and for a wheel, e.g.
    ``install the viz extra: pip install -e '.[viz]' in a checkout, or
    pip install 'cdf_mj-0.3.0-py3-none-any.whl[viz]'``. ValueError for an unknown extra."""
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}: choose from {', '.join(EXTRAS)}")
    return f"install the {extra} extra: pip install -e '.[{extra}]' in a checkout, or pip install '{WHEEL}[{extra}]'"


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module`` (dotted name), which ``extra`` installs, for ``feature`` (what
    the user asked for, e.g. ``"cdf-mj render"``).

    Raises:
        ImportError: the module cannot be imported; one line, e.g. ``cdf-mj render needs
            imageio: install the viz extra: pip install -e '.[viz]' in a checkout, ...``.
            The original error is its ``__cause__``.
        ValueError: ``extra`` is not one of :data:`EXTRAS`.
    """
    hint = install_hint(extra)
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"{feature} needs {module.partition('.')[0]}: {hint}", name=exc.name) from exc
