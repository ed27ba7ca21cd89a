"""The package's version, the one place it is written: ``cdf_mj.__version__`` re-exports
it, ``pyproject.toml`` reads it (``[tool.setuptools.dynamic]``), and every module that
stamps a file with it imports it from here (never from the package's facade, which sits
above every layer)."""

from __future__ import annotations

__all__ = ["__version__"]

__version__ = "0.3.0"
