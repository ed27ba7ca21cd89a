"""The linters of pyproject.toml pass: ruff on the code, the tests and the scripts; mypy
on the package (strict on cdf_mj.model, cdf_mj.inference and cdf_mj.planners).

Both come with the ``test`` extra; a test is skipped, with the reason, where its tool is
not installed. Slow (mypy takes tens of seconds without its cache).
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent


def _lint(tool: str, *args: str) -> None:
    if importlib.util.find_spec(tool) is None:
        pytest.skip(f"{tool} is not installed (it comes with the test extra: pip install -e '.[test]')")
    proc = subprocess.run([sys.executable, "-m", tool, *args], cwd=REPO, capture_output=True, text=True,
                          timeout=600, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f"{tool} {' '.join(args)}:\n{proc.stdout}\n{proc.stderr}"


def test_ruff():
    _lint("ruff", "check", "cdf_mj", "tests", "scripts")


def test_mypy():
    _lint("mypy")  # the files and the settings are in pyproject.toml
