"""cdf_mj.extras: every optional extra is named, and installed, the same way everywhere."""

from __future__ import annotations

import importlib.metadata
import json
import re
from pathlib import Path

import pytest

from cdf_mj.extras import EXTRAS, WHEEL, install_hint, require

REPO = Path(__file__).resolve().parent.parent


def test_the_extras_are_those_of_the_installed_distribution():
    provided = set(importlib.metadata.metadata("cdf-mj").get_all("Provides-Extra") or [])
    assert provided - {"all", "test"} == set(EXTRAS)


def test_install_hint_works_for_a_checkout_and_for_a_wheel():
    hint = install_hint("viz")
    assert "\n" not in hint
    assert "pip install -e '.[viz]'" in hint  # editable, from the checkout's root
    assert f"pip install '{WHEEL}[viz]'" in hint
    assert "cdf-mj[viz]" not in hint  # the package is not on PyPI: that would find nothing


def test_install_hint_refuses_an_unknown_extra():
    with pytest.raises(ValueError, match="unknown extra 'nosuch': choose from gym, ray, viz"):
        install_hint("nosuch")


def test_require_returns_the_module():
    assert require("json.decoder", "viz", "a test") is importlib.import_module("json.decoder")


def test_a_missing_module_is_one_line_naming_feature_and_extra():
    with pytest.raises(ImportError) as info:
        require("cdf_mj_no_such_module.sub", "viz", "cdf-mj render")
    message = str(info.value)
    assert message == f"cdf-mj render needs cdf_mj_no_such_module: {install_hint('viz')}"
    assert isinstance(info.value.__cause__, ModuleNotFoundError)  # the original, for --debug


def test_require_refuses_an_unknown_extra_even_when_the_module_exists():
    with pytest.raises(ValueError, match="unknown extra"):
        require("json", "nosuch", "a test")


def test_no_module_spells_an_install_command_of_its_own():
    """Hints come from install_hint only, so that they cannot drift apart."""
    spelled = [f"{path.relative_to(REPO)}:{n}" for path in sorted((REPO / "cdf_mj").rglob("*.py"))
               if path.name != "extras.py"
               for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
               if re.search(r"pip install", line)]
    assert spelled == [], json.dumps(spelled)
