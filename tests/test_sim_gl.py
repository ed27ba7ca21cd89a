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
from cdf_mj.sim.gl import Offscreen, RenderError, gl_backend, project_points


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


@pytest.mark.parametrize("orthographic", [False, True])
def test_projected_points_are_where_the_pixels_are(backend, scene, orthographic) -> None:
    """A small emissive marker drawn at a known point lands on project_points' pixel."""
    cam = mujoco.MjvCamera()
    cam.type, cam.distance, cam.azimuth, cam.elevation = mujoco.mjtCamera.mjCAMERA_FREE, 45.0, 150.0, -60.0
    cam.lookat[:] = (-5.0, 2.0, 0.0)
    cam.orthographic = orthographic

    class View:
        def apply(self, camera):
            for name in ("type", "distance", "azimuth", "elevation", "orthographic"):
                setattr(camera, name, getattr(cam, name))
            camera.lookat[:] = cam.lookat

    point = np.array([-12.0, -1.85, 1.0])
    with Offscreen(scene.model, 160, 120, max_geom=scene.model.ngeom + 4) as gl:
        gl.use_view(View())
        gl.update(scene.data)
        bare = gl.render().copy()
        g = gl.scene.geoms[gl.scene.ngeom]
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.array([0.4, 0, 0]), point, np.eye(3).ravel(),
                            np.array([0, 1, 0, 1], dtype=np.float32))
        gl.scene.ngeom += 1
        marked = gl.render().copy()
        expected = gl.project(point)
    rows, cols = np.nonzero(np.abs(marked.astype(int) - bare.astype(int)).sum(axis=2) > 30)
    assert len(rows) > 0
    np.testing.assert_allclose([cols.mean() + 0.5, rows.mean() + 0.5], expected, atol=1.0)
    glcam = gl.scene.camera[0]
    behind = np.asarray(glcam.pos) - 5.0 * np.asarray(glcam.forward)
    assert np.all(np.isnan(project_points(gl.scene, behind, 160, 120))) != orthographic  # NaN behind
