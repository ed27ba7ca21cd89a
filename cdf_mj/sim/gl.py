"""Offscreen OpenGL for MuJoCo: the backend chosen at run time, and a renderer in it.

``MUJOCO_GL`` chooses the backend when the user sets it; otherwise EGL, then OSMesa, are
tried (``MUJOCO_GL`` is then set to the one that works, for any later context). The
backend is chosen here, not at ``import mujoco`` (the package imports MuJoCo before it
knows it will render), so the frames come from MuJoCo's own renderer (``mjr_render``, as
in ``mujoco.Renderer``) in a context of the chosen backend. ::

    from cdf_mj.sim.gl import Offscreen

    with Offscreen(scene.model, 640, 480) as gl:
        gl.use_camera(camera_id)
        gl.update(scene.data)
        rgb = gl.render().copy()

Both ``cdf-mj render`` (:mod:`cdf_mj.viz.render`) and the Gymnasium environment's
``render()`` draw through :class:`Offscreen`. Imports MuJoCo and NumPy only.
"""

from __future__ import annotations

import importlib
import os
import warnings
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

if TYPE_CHECKING:
    from typing_extensions import Self

__all__ = ["Offscreen", "RenderError", "gl_backend", "project_points"]


class RenderError(ValueError):
    """A render request that cannot be carried out: bad input, no OpenGL, missing packages.
    The message is one line that says what to change."""


# MuJoCo's own spellings of MUJOCO_GL (as its Python package reads the variable): these
# mean its default window-system backend, GLFW; these turn rendering off.
_GL_ALIASES = {"glx": "glfw", "wgl": "glfw", "enable": "glfw", "enabled": "glfw", "on": "glfw",
               "true": "glfw", "1": "glfw"}
_GL_OFF = ("disable", "disabled", "off", "false", "0")
_BACKENDS = ("egl", "osmesa", "glfw", "cgl")  # the mujoco.<name> modules with a GLContext

_BACKEND: tuple[str, Any] | None = None  # the backend chosen for this process


def _try_backend(name: str) -> Any:
    """The GLContext class of backend ``name`` after creating and freeing a tiny context;
    whatever the backend raises when it cannot make one."""
    had_platform = "PYOPENGL_PLATFORM" in os.environ
    try:
        module = importlib.import_module(f"mujoco.{name}")
        ctx = module.GLContext(16, 16)
        try:
            ctx.make_current()
            # Some backends (glfw without a display) "make" a context that cannot render:
            # only a MuJoCo render context proves it.
            con = mujoco.MjrContext(mujoco.MjModel.from_xml_string("<mujoco/>"),
                                    mujoco.mjtFontScale.mjFONTSCALE_100.value)
            con.free()
        finally:
            ctx.free()
        return module.GLContext
    except BaseException:
        # mujoco.egl / mujoco.osmesa set PYOPENGL_PLATFORM on import; undo it so that the
        # next backend can be tried.
        if not had_platform:
            os.environ.pop("PYOPENGL_PLATFORM", None)
        raise


def gl_backend() -> tuple[str, Any]:
    """The OpenGL backend for offscreen rendering: ``(name, GLContext class)``.

    ``MUJOCO_GL`` when the user has set it, else ``egl`` then ``osmesa``; the first one
    that can create a context is kept for the process. :class:`RenderError` if none can,
    naming what to install or set.
    """
    global _BACKEND
    if _BACKEND is not None:
        return _BACKEND
    requested = os.environ.get("MUJOCO_GL", "").strip().lower()
    if requested in _GL_OFF:
        raise RenderError(f"MUJOCO_GL={requested} turns MuJoCo's rendering off: unset it, or set "
                          "it to a backend that works here (egl, osmesa or glfw)")
    candidates = [_GL_ALIASES.get(requested, requested)] if requested else ["egl", "osmesa"]
    errors = []
    for name in candidates:
        if name not in _BACKENDS:
            errors.append(f"{name}: not a backend MuJoCo offers on this system")
            continue
        try:
            with warnings.catch_warnings():  # glfw warns on stderr when there is no display
                warnings.simplefilter("ignore")
                cls = _try_backend(name)
        except Exception as exc:  # any failure means "not this backend"
            errors.append(f"{name}: {' '.join(str(exc).split()) or type(exc).__name__}")
            continue
        if not requested:
            os.environ["MUJOCO_GL"] = name
        _BACKEND = (name, cls)
        return _BACKEND
    raise RenderError(
        f"no OpenGL backend for offscreen rendering ({'; '.join(errors)}); install EGL or "
        "OSMesa (Debian/Ubuntu: apt-get install libegl1 libosmesa6) and PyOpenGL, or set "
        "MUJOCO_GL to a backend that works here (egl, osmesa or glfw)")


def project_points(scene: mujoco.MjvScene, points: np.ndarray, width: int,
                   height: int) -> np.ndarray:
    """Pixel coordinates ``(..., 2)`` (column, row from the top-left corner, [px]) of world
    points ``(..., 3)`` [m] as :meth:`Offscreen.render` draws them: the projection of
    ``scene``'s camera (set by ``mjv_updateScene``) into a ``width`` x ``height`` image, as
    ``mjr_render`` sets it up (perspective or orthographic). Points behind the camera give
    NaN."""
    cam = mujoco.mjv_averageCamera(scene.camera[0], scene.camera[1])
    pos, fwd, up = (np.asarray(a, dtype=float) for a in (cam.pos, cam.forward, cam.up))
    right = np.cross(fwd, up)
    d = np.asarray(points, dtype=float) - pos
    x, y, depth = d @ right, d @ up, d @ fwd
    near, top, bottom = cam.frustum_near, cam.frustum_top, cam.frustum_bottom
    half_w = cam.frustum_width or 0.5 * width / height * (top - bottom)
    if not cam.orthographic:
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = np.where(depth > 0, x * near / depth, np.nan), np.where(depth > 0, y * near / depth, np.nan)
    col = (x - (cam.frustum_center - half_w)) / (2.0 * half_w) * width
    row = (top - y) / (top - bottom) * height
    return np.stack([col, row], axis=-1)


class Offscreen:
    """MuJoCo's OpenGL renderer in an offscreen context of the backend :func:`gl_backend`
    chooses: the calls of ``mujoco.Renderer``. Use with ``with`` (or call :meth:`close`).

    Args:
        model: the model to draw; its offscreen buffer is enlarged to ``width`` x
            ``height`` for this context only (the model is given back as it was).
        width, height: image size [px].
        max_geom: capacity of :attr:`scene` [geoms]: the model's plus any drawn on top.
        samples: multisampling (MSAA) samples per pixel; 0 for none.

    Raises:
        RenderError: no OpenGL backend can create a context.
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int, max_geom: int = 4000,
                 samples: int = 0) -> None:
        _, context_cls = gl_backend()
        self.model, self.width, self.height = model, width, height
        self._gl: Any = context_cls(width, height)
        self._gl.make_current()
        # The buffer size and multisampling are read when the context is made: set them
        # for it (larger buffer if asked; 4x MSAA halves the frame rate on llvmpipe),
        # then give the model back as it was.
        vis, quality = model.vis.global_, model.vis.quality
        saved = (vis.offwidth, vis.offheight, quality.offsamples)
        vis.offwidth, vis.offheight = max(vis.offwidth, width), max(vis.offheight, height)
        quality.offsamples = samples
        try:
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        finally:
            vis.offwidth, vis.offheight, quality.offsamples = saved
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        #: The geoms :meth:`render` draws: the model's (:meth:`update`) plus any added after.
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        self.option = mujoco.MjvOption()
        self.camera = mujoco.MjvCamera()
        self._perturb = mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), dtype=np.uint8)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Free the MuJoCo and GL contexts (idempotent)."""
        if self._gl is not None:
            self._gl.make_current()
            self._con.free()
            self._gl.free()
            self._gl = None

    def use_camera(self, camera_id: int) -> None:
        """Look through the model's fixed camera ``camera_id``."""
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.camera.fixedcamid = camera_id

    def use_view(self, view: Any) -> None:
        """Look through a free camera: ``view.apply(camera)`` (such as
        :class:`cdf_mj.viz.camera.CameraView`), for the next :meth:`update`."""
        view.apply(self.camera)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(..., 2)`` (column, row) of world points ``(..., 3)`` [m] in
        the image :meth:`render` draws after the last :meth:`update`
        (:func:`project_points`)."""
        return project_points(self.scene, points, self.width, self.height)

    def update(self, data: mujoco.MjData) -> None:
        """The model's geoms at ``data``'s positions into :attr:`scene` (replacing all)."""
        mujoco.mjv_updateScene(self.model, data, self.option, self._perturb, self.camera,
                               mujoco.mjtCatBit.mjCAT_ALL.value, self.scene)

    def render(self) -> np.ndarray:
        """:attr:`scene` as an RGB image ``(height, width, 3)`` uint8, top row first (a
        view of an internal buffer: copy it to keep it)."""
        self._gl.make_current()  # another renderer (another env) may have taken the thread
        mujoco.mjr_render(self._rect, self.scene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        return self._rgb[::-1]
