"""Shared fixtures: one compiled scene per test session (loading is the slow part)."""

from __future__ import annotations

import pytest

from cdf_mj.sim.scene import Scene


@pytest.fixture(scope="session")
def scene() -> Scene:
    """The default scene, models/xml/scene.xml. Tests reset it before use."""
    return Scene.load()


@pytest.fixture(scope="session")
def backend() -> str:
    """The OpenGL backend's name (``egl``, ``osmesa``, ``glfw``); skips the test, with the
    reason, where no backend can be created here."""
    from cdf_mj.sim.gl import RenderError, gl_backend

    try:
        return gl_backend()[0]
    except RenderError as exc:
        pytest.skip(f"no OpenGL backend can be created here: {exc}")
