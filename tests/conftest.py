"""Shared fixtures: one compiled scene per test session (loading is the slow part)."""

from __future__ import annotations

import pytest

from cdf_mj.sim.scene import Scene


@pytest.fixture(scope="session")
def scene() -> Scene:
    """The default scene, models/xml/scene.xml. Tests reset it before use."""
    return Scene.load()
