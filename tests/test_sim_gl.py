"""cdf_mj.sim.gl: the OpenGL backend chosen at run time, and MuJoCo's offscreen renderer.

The choice of backend is tested with ``_try_backend`` replaced (a machine has one set of
GL libraries); drawing needs a real backend (EGL or OSMesa) and is skipped, with the
reason, only when none can be created.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np
import pytest

from cdf_mj.sim import gl
from cdf_mj.sim.gl import Offscreen, RenderError, gl_backend


@pytest.fixture(scope="module")
def backend() -> str:
    """The OpenGL backend's name; skips the test when no backend can be created."""
    try:
        return gl_backend()[0]
    except RenderError as exc:
        pytest.skip(f"no OpenGL backend can be created here: {exc}")


# ----------------------------------------------------------------- choosing the backend
@pytest.mark.parametrize(("value", "fragment"), [("glx", "glfw:"), ("1", "glfw:"),
                                                ("disable", "turns MuJoCo's rendering off")])
def test_mujocos_own_spellings_of_mujoco_gl(monkeypatch, value, fragment) -> None:
    monkeypatch.setattr(gl, "_BACKEND", None)
    monkeypatch.setenv("MUJOCO_GL", value)
    monkeypatch.setattr(gl, "_try_backend", lambda name: (_ for _ in ()).throw(OSError("no display")))
    with pytest.raises(RenderError, match=fragment):  # glx and 1 mean GLFW to MuJoCo, not "unknown"
        gl_backend()


def test_no_gl_backend_names_the_fix(monkeypatch) -> None:
    monkeypatch.setattr(gl, "_BACKEND", None)
    monkeypatch.setenv("MUJOCO_GL", "nonesuch")
    with pytest.raises(RenderError) as info:
        gl_backend()
    msg = str(info.value)
    assert "\n" not in msg and "MUJOCO_GL" in msg and "apt-get install libegl1 libosmesa6" in msg
    assert "nonesuch: not a backend MuJoCo offers" in msg


def test_egl_first_then_osmesa(monkeypatch) -> None:
    tried = []

    def fake(name):
        tried.append(name)
        if name == "egl":
            raise OSError("libEGL.so.1: cannot open shared object file")
        return "OSMesaContext"

    monkeypatch.setattr(gl, "_BACKEND", None)
    monkeypatch.setattr(gl, "_try_backend", fake)
    monkeypatch.setenv("MUJOCO_GL", "")  # unset for gl_backend, and restored afterwards
    assert gl_backend() == ("osmesa", "OSMesaContext")
    assert tried == ["egl", "osmesa"]
    assert os.environ["MUJOCO_GL"] == "osmesa"  # for any later context in this process


def test_the_backend_is_kept_for_the_process(backend) -> None:
    assert gl_backend() is gl_backend() and gl_backend()[0] == backend


# ----------------------------------------------------------------- drawing
def test_offscreen_draws_the_model_from_its_camera(backend, scene) -> None:
    camera = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_CAMERA, "top")
    with Offscreen(scene.model, 96, 64) as renderer:
        renderer.use_camera(camera)
        renderer.update(scene.data)
        n_model = renderer.scene.ngeom
        first = renderer.render().copy()
        assert first.shape == (64, 96, 3) and first.dtype == np.uint8 and first.std() > 1
        assert n_model > 0 and np.array_equal(renderer.render(), first)  # the same scene, the same image
    renderer.close()  # idempotent


def test_a_frame_larger_than_the_models_buffer(backend, scene) -> None:
    """The offscreen buffer is enlarged for the render context, and the model left as it was."""
    vis = scene.model.vis.global_
    before = (vis.offwidth, vis.offheight, scene.model.vis.quality.offsamples)
    with Offscreen(scene.model, vis.offwidth + 64, 48, samples=4) as renderer:
        renderer.update(scene.data)
        assert renderer.render().shape == (48, before[0] + 64, 3)
    assert (vis.offwidth, vis.offheight, scene.model.vis.quality.offsamples) == before
