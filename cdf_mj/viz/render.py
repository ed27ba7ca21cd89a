"""Offscreen video of an episode, with what the CDF sees and believes drawn in.

``render_episode`` runs one episode (the ``cdf`` planner's filter snapshotted at every
tick), then replays it at a constant frame rate in simulated time: frame ``i`` shows the
scene at ``t = i / fps`` seconds, the cars' poses interpolated between the 0.1 s ticks
of the episode trace (positions and speed linearly, headings along the shorter arc),
so no frame is dropped or repeated. The filter's state shown is that of the last tick
at or before ``t``. ::

    from cdf_mj.viz.render import render_episode
    result = render_episode("episode.mp4", seed=7, planner="cdf", camera="top")
    result.n_frames, result.frames_per_second

Drawn into the 3D scene (``mjvScene`` user geoms), world frame:

* the obstacle driver's isovist (360 MuJoCo rays from its eye), a translucent yellow fan
  on the road;
* the filter's particles (obstacle rear-axle positions, the most frequent
  ``max_particles`` distinct ones) above the roof line, coloured by intent and belief:
  :data:`PARTICLE_COLORS`;
* where the obstacle believes the ego is, once it has seen it: a yellow wire box;
* the braking moment: a red stripe across the ego's lane where the ego decided to brake,
  and a red beacon over the ego while it brakes.

Over the top-left corner of the image (NumPy, no per-frame matplotlib): time, seed,
planner and label; P(left), P(seen) and P(cutoff) as bars (``tau`` marked) and as a
running plot over the episode, with the braking time; a legend of the particle colours.

OpenGL: ``MUJOCO_GL`` chooses the backend when the user sets it; otherwise EGL, then
OSMesa, are tried (``MUJOCO_GL`` is then set to the one that works, for any later
context). The backend is chosen here, not at ``import mujoco`` (the package imports
MuJoCo before it knows it will render), so the frames come from MuJoCo's own renderer
(``mjr_render``, as in ``mujoco.Renderer``) in a context of the chosen backend.
Every request is checked (camera, output path, resolution, frame rate, packages, GL)
before any simulation: :class:`RenderError` with one line saying what to change.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.scenario.episode import episode_label, run_episode
from cdf_mj.records import EpisodeRecord
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.planners.base import CDFPlanner, Planner, make_planner
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.visibility import isovist

if TYPE_CHECKING:
    from typing_extensions import Self

__all__ = [
    "FORMATS",
    "MAX_RESOLUTION",
    "OVERLAY_COLORS",
    "PARTICLE_COLORS",
    "VIZ_HINT",
    "RenderError",
    "RenderRequest",
    "RenderResult",
    "Replay",
    "check_request",
    "frame_times",
    "gl_backend",
    "record_episode",
    "render_episode",
]

#: Output formats by file suffix.
FORMATS = {".mp4": "mp4", ".gif": "gif", ".png": "png"}
#: Largest width or height [px]; the model's offscreen buffer is enlarged up to this.
MAX_RESOLUTION = 4096
#: Smallest frame side [px] the overlays and the panel are laid out for.
MIN_RESOLUTION = 32
#: The fix for a missing optional dependency.
VIZ_HINT = "pip install 'cdf-mj[viz]'"
#: RGBA of the particles by (intent, has seen the ego).
PARTICLE_COLORS = {
    ("left", False): (1.0, 0.1, 1.0, 1.0),   # magenta: a left-turner that has not seen the ego
    ("left", True): (0.55, 0.3, 1.0, 1.0),   # violet: a left-turner that has seen it
    ("right", False): (0.1, 0.9, 0.1, 1.0),  # green: a right-turner that has not seen the ego
    ("right", True): (0.6, 1.0, 0.6, 1.0),   # pale green: a right-turner that has seen it
}
#: RGBA of the other overlays (3D geoms and the panel's curves).
OVERLAY_COLORS = {
    "isovist": (1.0, 0.9, 0.15, 0.25),
    "belief": (1.0, 0.9, 0.15, 1.0),
    "brake": (1.0, 0.05, 0.05, 1.0),
    "p_left": (1.0, 0.1, 1.0, 1.0),
    "p_seen": (1.0, 0.9, 0.15, 1.0),
    "p_cutoff": (1.0, 0.35, 0.1, 1.0),
    "p_conflict": (1.0, 0.35, 0.1, 1.0),  # the imm baseline's braking quantity, as P(cutoff)
}
#: Probabilities a planner's ``history`` may hold, in panel order, with their labels.
_PANEL_KEYS = {"p_left": "P(left)", "p_seen": "P(seen)", "p_cutoff": "P(cutoff)", "p_conflict": "P(conflict)"}
_INTENT_NAMES = ("left", "right")  # cdf_mj.driver.Intent order
_GIF_FPS = (10, 20, 25, 50)  # GIF delays are whole hundredths of a second


class RenderError(ValueError):
    """A render request that cannot be carried out: bad input, no OpenGL, missing packages.
    The message is one line that says what to change."""


# ----------------------------------------------------------------- OpenGL backend
_BACKEND: tuple[str, Any] | None = None


def _try_backend(name: str) -> Any:
    """The GLContext class of backend ``name`` after creating and freeing a tiny context."""
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


# MuJoCo's own spellings of MUJOCO_GL (mujoco/rendering/classic/gl_context.py): these mean
# its default window-system backend, GLFW; these turn rendering off.
_GL_ALIASES = {"glx": "glfw", "wgl": "glfw", "enable": "glfw", "enabled": "glfw", "on": "glfw",
               "true": "glfw", "1": "glfw"}
_GL_OFF = ("disable", "disabled", "off", "false", "0")


def gl_backend() -> tuple[str, Any]:
    """The OpenGL backend for offscreen rendering: ``(name, GLContext class)``.

    ``MUJOCO_GL`` when the user has set it, else ``egl`` then ``osmesa``; the first one
    that can create a context is kept for the process. :class:`RenderError` if none can.
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
        if name not in ("egl", "osmesa", "glfw", "cgl"):
            errors.append(f"{name}: not a backend MuJoCo offers on this system")
            continue
        try:
            with warnings.catch_warnings():  # glfw warns on stderr when there is no display
                warnings.simplefilter("ignore")
                cls = _try_backend(name)
        except Exception as exc:  # noqa: BLE001 - any failure means "not this backend"
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


class _Offscreen:
    """MuJoCo's OpenGL renderer in an offscreen context: the calls of ``mujoco.Renderer``
    with a backend chosen at run time. Use with ``with``."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int, max_geom: int = 4000,
                 samples: int = 0) -> None:
        _, context_cls = gl_backend()
        self.model, self.width, self.height = model, width, height
        self._gl = context_cls(width, height)
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

    def update(self, data: mujoco.MjData) -> None:
        """The model's geoms at ``data``'s positions into :attr:`scene`."""
        mujoco.mjv_updateScene(self.model, data, self.option, self._perturb, self.camera,
                               mujoco.mjtCatBit.mjCAT_ALL.value, self.scene)

    def render(self) -> np.ndarray:
        """The scene as an RGB image ``(height, width, 3)`` uint8, top row first (a view
        of an internal buffer: copy it to keep it)."""
        self._gl.make_current()  # another renderer (another env) may have taken the thread
        mujoco.mjr_render(self._rect, self.scene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        return self._rgb[::-1]


# ----------------------------------------------------------------- recording an episode
class _RecordingFilter(ParticleFilter):
    """The CDF's particle filter, keeping each tick's weighted particles before it predicts."""

    snapshots: list[tuple[np.ndarray, np.ndarray, np.ndarray]]

    def predict(self, system_pose: np.ndarray | None = None) -> None:
        self.snapshots.append(_distinct_particles(self.pose[:, :2], self.intent, self.has_belief,
                                                  self.weights))
        super().predict(system_pose)


class _RecordingCDFPlanner(CDFPlanner):
    """The ``cdf`` planner with a :class:`_RecordingFilter`: the same decisions, the same
    random draws, plus a particle snapshot per tick."""

    def reset(self, scene, config: ScenarioConfig, rng: np.random.Generator) -> None:
        super().reset(scene, config, rng)
        # Building a filter draws nothing from rng: the recorded run is the plain run.
        self.filter = _RecordingFilter.from_scene(scene, config, self.cdf, rng)
        self.filter.snapshots = []


def _distinct_particles(xy: np.ndarray, intent: np.ndarray, seen: np.ndarray,
                        weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct (position to 1 cm, intent, seen) particles, heaviest first: positions
    ``(M, 2)`` float32 [m], codes ``(M,)`` (``2 * intent + seen``), weights ``(M,)``."""
    code = (2 * np.asarray(intent) + np.asarray(seen)).astype(np.int64)
    key = np.column_stack([np.round(xy * 100.0).astype(np.int64), code])
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    mass = np.bincount(inverse.ravel(), weights=weights, minlength=len(uniq))
    order = np.argsort(-mass, kind="stable")
    uniq, mass = uniq[order], mass[order]
    return (uniq[:, :2] / 100.0).astype(np.float32), uniq[:, 2].astype(np.uint8), mass.astype(np.float32)


@dataclass
class Replay:
    """One recorded episode, ready to be drawn at any time ``t`` in ``[0, end_time]`` [s].

    ``times`` are the tick times plus the end time, ``poses`` the system pose
    ``(ego, obstacle) x [x m, y m, theta rad, v m/s]`` at each (world frame).
    """

    record: EpisodeRecord
    label: str | None
    times: np.ndarray  # (K + 1,) [s]
    poses: np.ndarray  # (K + 1, 2, 4)
    seen: np.ndarray  # (K,) the obstacle has seen the ego, per tick
    belief: np.ndarray  # (K, 4) the obstacle's belief of the ego's pose, per tick
    particles: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None  # per tick, CDF only
    # t and the probabilities the planner keeps per tick (CDF: p_left, p_seen, p_cutoff;
    # imm: p_left, p_conflict); None for a planner without any
    posterior: dict[str, np.ndarray] | None
    tau: float | None  # the threshold of the last of them at which the planner brakes

    @property
    def end_time(self) -> float:
        """When the episode ended [s]."""
        return float(self.times[-1])

    def tick(self, t: float) -> int:
        """Index of the last tick at or before ``t``."""
        k = int(np.searchsorted(self.times[:-1], t + 1e-9, side="right")) - 1
        return min(max(k, 0), len(self.times) - 2)

    def pose_at(self, t: float) -> np.ndarray:
        """System pose ``(2, 4)`` at time ``t``, interpolated between ticks."""
        k = min(int(np.searchsorted(self.times, t, side="right")) - 1, len(self.times) - 2)
        k = max(k, 0)
        t0, t1 = self.times[k], self.times[k + 1]
        a = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        p0, p1 = self.poses[k], self.poses[k + 1]
        out = p0 + a * (p1 - p0)
        dth = np.remainder(p1[:, 2] - p0[:, 2] + math.pi, 2 * math.pi) - math.pi
        out[:, 2] = p0[:, 2] + a * dth
        return out

    def braking(self, t: float) -> bool:
        """Whether the ego's planner has decided to brake by time ``t``."""
        bt = self.record.brake_time
        return bt is not None and t + 1e-9 >= bt


def record_episode(seed: int, planner: str | Planner = "cdf", config: ScenarioConfig | None = None,
                   scene: Scene | None = None, cdf: CDFConfig | None = None,
                   label: bool = True) -> Replay:
    """Run one episode with its trace (and, for ``cdf``, the filter's particles per tick).

    The record is the one :func:`cdf_mj.episode.run_episode` gives for the same seed and
    planner. ``label`` runs the constant-speed counterfactual for the scenario label.
    """
    config = config or ScenarioConfig()
    scene = scene or Scene.load(names=config.names)
    if planner == "cdf":
        plan: Planner = _RecordingCDFPlanner(cdf)
    else:
        plan = make_planner(planner)
    record = run_episode(config, seed, plan, scene, label=False, trace=True)
    final = scene.poses()  # the scene holds the state at end_time
    trace = record.trace or {}
    times = np.append(np.asarray(trace["t"], dtype=float), record.end_time)
    poses = np.concatenate([np.asarray(trace["poses"], dtype=float).reshape(-1, 2, 4), final[None]])
    lab = episode_label(config, seed, scene) if label else None
    particles = posterior = tau = None
    if isinstance(plan, _RecordingCDFPlanner):
        particles = plan.filter.snapshots
        tau = plan.cdf.tau
    else:  # a baseline with a probability history (imm): its own threshold
        tau = getattr(getattr(plan, "params", None), "threshold", None)
    h = getattr(plan, "history", None)
    if isinstance(h, dict) and "t" in h and any(k in h for k in _PANEL_KEYS):
        posterior = {k: np.asarray(h[k], dtype=float) for k in ("t", *_PANEL_KEYS) if k in h}
    else:
        tau = None
    return Replay(record=record, label=lab, times=times, poses=poses,
                  seen=np.asarray(trace["seen"], dtype=bool),
                  belief=np.asarray(trace["belief"], dtype=float).reshape(-1, 4),
                  particles=particles, posterior=posterior, tau=tau)


# ----------------------------------------------------------------- 3D overlays
def _add_geom(scn: mujoco.MjvScene, gtype: int, size: Sequence[float], pos: Sequence[float],
              mat: np.ndarray, rgba: Sequence[float], emission: float = 0.0) -> None:
    if scn.ngeom >= scn.maxgeom:
        return
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(g, gtype, np.asarray(size, dtype=float), np.asarray(pos, dtype=float),
                        mat.ravel(), np.asarray(rgba, dtype=np.float32))
    g.emission = emission
    g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
    scn.ngeom += 1


def _yaw_mat(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


_EYE3 = np.eye(3)
_TRI = mujoco.mjtGeom.mjGEOM_TRIANGLE.value
_BOX = mujoco.mjtGeom.mjGEOM_BOX.value
_LINEBOX = mujoco.mjtGeom.mjGEOM_LINEBOX.value
_CYL = mujoco.mjtGeom.mjGEOM_CYLINDER.value


def _draw_isovist(scn: mujoco.MjvScene, origin: np.ndarray, boundary: np.ndarray, z: float) -> None:
    """The isovist as a fan of triangles from the eye (it is star-shaped from there):
    ``boundary`` ``(M, 2)`` are its corners in angular order, world frame [m]."""
    rgba = np.asarray(OVERLAY_COLORS["isovist"], dtype=np.float32)
    size = np.zeros(3)
    pos = np.array([origin[0], origin[1], z])
    mat = np.zeros((3, 3))
    mat[2, 2] = 1.0
    d = boundary - np.asarray(origin[:2])
    dist = np.hypot(d[:, 0], d[:, 1])
    keep = dist > 1e-6
    d, dist = d[keep], dist[keep]
    u = d / dist[:, None]
    n = len(d)
    for i in range(n):
        j = (i + 1) % n
        if scn.ngeom >= scn.maxgeom:
            return
        # Triangle (0,0,0)-(size0,0,0)-(0,size1,0) in the geom frame: x towards corner i,
        # y towards corner j (a sheared frame: MuJoCo draws it as given).
        mat[0, 0], mat[1, 0], mat[0, 1], mat[1, 1] = u[i, 0], u[i, 1], u[j, 0], u[j, 1]
        size[0], size[1] = dist[i], dist[j]
        g = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(g, _TRI, size, pos, mat.ravel(), rgba)
        g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
        scn.ngeom += 1


def _draw_particles(scn: mujoco.MjvScene, snapshot: tuple[np.ndarray, np.ndarray, np.ndarray],
                    z: float, limit: int, half: float = 0.3) -> None:
    xy, code, _ = snapshot
    colors = [np.asarray(PARTICLE_COLORS[(_INTENT_NAMES[c // 2], bool(c % 2))], dtype=np.float32)
              for c in range(4)]
    size = np.array([half, half, 0.05])
    for i in range(min(limit, len(xy))):
        _add_geom(scn, _BOX, size, (xy[i, 0], xy[i, 1], z), _EYE3, colors[code[i]], emission=0.8)


# ----------------------------------------------------------------- the 2D panel
def _font(px: int) -> Any:
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _rgb(name: str) -> np.ndarray:
    return (np.asarray(OVERLAY_COLORS[name][:3]) * 255).astype(np.uint8)


class _Panel:
    """Probabilities, their history and a legend, drawn over the top-left of each frame."""

    ALPHA = 0.82

    def __init__(self, replay: Replay, width: int, height: int, planner: str) -> None:
        from PIL import Image, ImageDraw

        self._Image, self._ImageDraw = Image, ImageDraw
        self.replay = replay
        self.w = max(48, round(0.38 * width))
        self.h = max(32, round(0.36 * height))
        self.w, self.h = min(self.w, width), min(self.h, height)
        self.font = _font(max(7, round(self.h / 13)))
        # Rows: 0 head, 1 time and braking, 2-4 bars, 5-7 running plot, 8 legend.
        line = self.h / 9.0
        self.rows = [round(line * (i + 0.5)) for i in range(9)]  # text centres
        self.label_w = round(0.34 * self.w)
        self.bar_x0, self.bar_x1 = self.label_w, round(0.82 * self.w)
        self.bar_h = max(2, round(line * 0.6))
        self.plot = (round(0.04 * self.w), round(line * 5.1), round(0.96 * self.w),
                     round(line * 7.9))  # x0, y0, x1, y1
        self.keys = tuple(k for k in _PANEL_KEYS if replay.posterior is not None and k in replay.posterior)
        head = f"seed {replay.record.seed}  {planner}  label {replay.label or '-'}"
        self.base = self._background(head)
        self.curves = self._curves()

    def _text(self, img: np.ndarray, items: list[tuple[int, int, str, tuple[int, int, int]]]) -> np.ndarray:
        pil = self._Image.fromarray(img)
        draw = self._ImageDraw.Draw(pil)
        for x, y, text, color in items:
            draw.text((x, y), text, fill=color, font=self.font, anchor="lm")
        return np.array(pil)

    def _background(self, head: str) -> np.ndarray:
        img = np.full((self.h, self.w, 3), 20, dtype=np.uint8)
        pad = max(2, self.w // 60)
        items = [(pad, self.rows[0], head, (235, 235, 235))]
        if self.replay.posterior is not None:
            for i, k in enumerate(self.keys):
                items.append((pad, self.rows[2 + i], _PANEL_KEYS[k], tuple(int(v) for v in _rgb(k))))
        else:
            items.append((pad, self.rows[2], "no filter: planner without a posterior", (200, 200, 200)))
        # Legend of particle colours on the last row.
        x = pad
        step = (self.w - 2 * pad) / 4
        sw = max(2, self.bar_h)
        y = self.rows[8]
        for (intent, seen), rgba in PARTICLE_COLORS.items():
            img[y - sw // 2:y - sw // 2 + sw, int(x):int(x) + sw] = (np.asarray(rgba[:3]) * 255).astype(np.uint8)
            items.append((int(x) + sw + 2, y, intent[0].upper() + ("s" if seen else ""), (220, 220, 220)))
            x += step
        img = self._text(img, items)
        x0, y0, x1, y1 = self.plot
        img[y0:y1 + 1, x0] = 90
        img[y1, x0:x1 + 1] = 90
        return img

    def _curves(self) -> np.ndarray | None:
        """All three curves over the whole episode, drawn once; frames reveal columns."""
        post = self.replay.posterior
        if post is None:
            return None
        x0, _y0, x1, _y1 = self.plot
        img = self.base.copy()
        tx = self._x(post["t"])
        if self.replay.tau is not None:
            ty = self._y(self.replay.tau)
            img[ty, x0:x1 + 1:3] = _rgb(self.keys[-1]) // 2
        for k in self.keys:
            ys = self._y(post[k])
            col = _rgb(k)
            for i in range(len(tx)):
                xa, xb = tx[i], tx[i + 1] if i + 1 < len(tx) else tx[i]
                ya, yb = ys[i], ys[i + 1] if i + 1 < len(ys) else ys[i]
                n = max(abs(xb - xa), abs(yb - ya), 1) + 1
                xs = np.rint(np.linspace(xa, xb, n)).astype(int)
                yy = np.rint(np.linspace(ya, yb, n)).astype(int)
                img[yy, xs] = col
        return img

    def _x(self, t: np.ndarray | float) -> np.ndarray:
        x0, _, x1, _ = self.plot
        end = max(self.replay.end_time, 1e-6)
        return np.rint(x0 + 1 + np.asarray(t) / end * (x1 - x0 - 1)).astype(int)

    def _y(self, p: np.ndarray | float) -> np.ndarray:
        _, y0, _, y1 = self.plot
        return np.rint(y1 - 1 - np.clip(np.asarray(p), 0.0, 1.0) * (y1 - y0 - 2)).astype(int)

    def draw(self, frame: np.ndarray, t: float) -> np.ndarray:
        """The panel at time ``t`` blended into ``frame`` (in place); returns ``frame``."""
        rep = self.replay
        img = self.base.copy()
        x0, y0, _x1, y1 = self.plot
        cx = int(self._x(t))
        if self.curves is not None:
            img[y0:y1, x0:cx + 1] = self.curves[y0:y1, x0:cx + 1]
        img[y0:y1, cx] = 160  # cursor
        pad = max(2, self.w // 60)
        items = [(pad, self.rows[1], f"t {t:5.2f} s", (235, 235, 235))]
        if rep.braking(t):
            bx = int(self._x(rep.record.brake_time))
            img[y0:y1, bx] = _rgb("brake")
            bw = round(0.34 * self.w)
            img[self.rows[1] - self.bar_h:self.rows[1] + self.bar_h, self.w - bw - pad:self.w - pad] = _rgb("brake")
            items.append((self.w - bw, self.rows[1], "BRAKE", (255, 255, 255)))
        if rep.posterior is not None:
            k = rep.tick(t)
            span = self.bar_x1 - self.bar_x0
            for i, key in enumerate(self.keys):
                p = float(rep.posterior[key][min(k, len(rep.posterior[key]) - 1)])
                yc = self.rows[2 + i]
                ya, yb = yc - self.bar_h // 2, yc - self.bar_h // 2 + self.bar_h
                img[ya:yb, self.bar_x0:self.bar_x1] = 55
                img[ya:yb, self.bar_x0:self.bar_x0 + round(p * span)] = _rgb(key)
                if key == self.keys[-1] and rep.tau is not None:  # the braking quantity
                    tx = self.bar_x0 + round(rep.tau * span)
                    img[ya - 1:yb + 1, min(tx, self.w - 1)] = 255
                items.append((self.bar_x1 + pad, yc, f"{p:.2f}", (235, 235, 235)))
        img = self._text(img, items)
        region = frame[:self.h, :self.w]
        region[...] = (self.ALPHA * img + (1.0 - self.ALPHA) * region).astype(np.uint8)
        return frame


# ----------------------------------------------------------------- checking a request
@dataclass(frozen=True)
class RenderRequest:
    """A checked request: output path and format, camera id, size [px], frame rate
    [frames per simulated second], and the time [s] of a single frame (PNG only)."""

    out: Path
    fmt: str
    camera_id: int
    width: int
    height: int
    fps: float
    frame_time: float | None


def _require(module: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError:
        raise RenderError(f"rendering needs the package {module.split('.')[0]!r}: {VIZ_HINT}") from None


def check_request(out: str | Path, model: mujoco.MjModel, camera: str = "top", width: int = 640,
                  height: int = 480, fps: float | None = None,
                  frame_time: float | None = None) -> RenderRequest:
    """Validate a render request without simulating anything; :class:`RenderError` names
    the first problem. Returns the checked request (format, camera id, frame rate)."""
    out = Path(out)
    fmt = FORMATS.get(out.suffix.lower())
    if fmt is None:
        raise RenderError(f"--out {out}: unknown format {out.suffix or '(no suffix)'!r}; "
                          f"use {', '.join(FORMATS)}")
    if fmt == "png" and frame_time is None:
        raise RenderError(f"--out {out}: a .png is one frame; give its time with --frame T (seconds)")
    if fmt != "png" and frame_time is not None:
        raise RenderError(f"--frame renders one image: use an --out ending in .png, not {out.suffix}")
    if frame_time is not None and not (math.isfinite(frame_time) and frame_time >= 0):
        raise RenderError(f"--frame {frame_time}: must be a time >= 0 [s]")
    names = [model.camera(i).name for i in range(model.ncam)]
    if camera not in names:
        raise RenderError(f"unknown camera {camera!r}: choose one of {', '.join(names) or '(none in this scene)'}")
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise RenderError(f"--{name} {v!r}: must be a positive integer [px]")
        if v < MIN_RESOLUTION:
            raise RenderError(f"--{name} {v}: below the smallest frame this draws ({MIN_RESOLUTION} px)")
        if v % 2 and fmt == "mp4":
            raise RenderError(f"--{name} {v}: must be even for MP4 (its yuv420p needs even sizes; "
                              f"try {v + 1})")
        if v > MAX_RESOLUTION:
            raise RenderError(f"--{name} {v}: above the largest offscreen buffer this renders "
                              f"({MAX_RESOLUTION} px)")
    if fps is None:
        fps = 25.0 if fmt == "gif" else 30.0
    if isinstance(fps, bool) or not math.isfinite(fps) or not 1.0 <= fps <= 240.0:
        raise RenderError(f"--fps {fps}: must be between 1 and 240 frames per simulated second")
    if fmt == "gif" and fps not in _GIF_FPS:
        raise RenderError(f"--fps {fps:g}: GIF frame delays are whole hundredths of a second; "
                          f"choose {', '.join(map(str, _GIF_FPS))} for a constant rate")
    parent = out.parent if str(out.parent) else Path(".")
    if out.is_dir():
        raise RenderError(f"--out {out}: is a directory")
    if not parent.is_dir():
        raise RenderError(f"--out {out}: directory {parent} does not exist")
    existed = out.exists()
    try:  # really open it: permissions alone miss read-only and virtual file systems
        with open(out, "ab"):
            pass
    except OSError as exc:
        raise RenderError(f"--out {out}: not writable ({exc.strerror or type(exc).__name__})") from None
    finally:
        if not existed and out.exists():
            out.unlink()
    _require("imageio")
    _require("PIL")
    if fmt == "mp4":
        _require("imageio_ffmpeg")
    return RenderRequest(out, fmt, names.index(camera), int(width), int(height), float(fps), frame_time)


# ----------------------------------------------------------------- rendering
@dataclass(frozen=True)
class RenderResult:
    """What :func:`render_episode` wrote."""

    path: Path
    n_frames: int
    frames_per_second: float  # [frames per simulated second]
    duration: float  # [s] simulated time covered, 0 for one frame
    render_seconds: float  # [s] wall time of drawing and encoding the frames
    simulate_seconds: float  # [s] wall time of running the episode
    backend: str  # OpenGL backend
    record: EpisodeRecord
    label: str | None


def frame_times(end_time: float, fps: float) -> np.ndarray:
    """Frame times ``i / fps`` [s] from 0 up to ``end_time`` (both ends included when on
    the grid): one frame per ``1 / fps`` of simulated time."""
    n = math.floor(end_time * fps + 1e-6) + 1
    return np.arange(n) / fps


class _Painter:
    """Draws the replay at any time: scene state, overlays, panel."""

    def __init__(self, replay: Replay, scene: Scene, gl: _Offscreen, planner: str,
                 max_particles: int, shadows: bool, overlays: bool = True) -> None:
        self.replay, self.scene, self.gl = replay, scene, gl
        self.overlays = overlays
        self.max_particles = max_particles
        self.panel = _Panel(replay, gl.width, gl.height, planner)
        self.shadows = shadows
        self.z_particles = max(scene.obstacle.hull_height, scene.ego.hull_height) + 0.4
        rec = replay.record
        self.brake_pose = replay.pose_at(rec.brake_time)[0] if rec.brake_time is not None else None

    def frame(self, t: float) -> np.ndarray:
        rep, sc, gl = self.replay, self.scene, self.gl
        poses = rep.pose_at(t)
        sc.set_pose(sc.ego, poses[0])
        sc.set_pose(sc.obstacle, poses[1])
        sc.sync()
        mujoco.mj_camlight(sc.model, sc.data)
        gl.update(sc.data)
        flags = gl.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        scn = gl.scene
        if not self.overlays:
            return gl.render().copy()
        iso = isovist(sc, sc.obstacle.eye(poses[1]))
        # Straight building faces need few corners: 360 rays become about 40 triangles.
        ring = np.asarray(iso.polygon.simplify(0.1).exterior.coords)[:-1]
        _draw_isovist(scn, iso.origin, ring, z=0.05)
        k = rep.tick(t)
        if k < len(rep.seen) and rep.seen[k]:
            b = rep.belief[k]
            c, s = math.cos(b[2]), math.sin(b[2])
            ox, oy = sc.ego.hull_offset
            centre = (b[0] + c * ox - s * oy, b[1] + s * ox + c * oy, sc.ego.hull_height / 2)
            _add_geom(scn, _LINEBOX, (*sc.ego.hull_half, sc.ego.hull_height / 2), centre,
                      _yaw_mat(b[2]), OVERLAY_COLORS["belief"], emission=1.0)
        if rep.particles is not None and k < len(rep.particles):
            _draw_particles(scn, rep.particles[k], self.z_particles, self.max_particles)
        if self.brake_pose is not None and rep.braking(t):
            self._draw_brake(scn, poses[0])
        img = gl.render().copy()
        return self.panel.draw(img, t)

    def _draw_brake(self, scn: mujoco.MjvScene, ego: np.ndarray) -> None:
        sc = self.scene
        bp = self.brake_pose
        c, s = math.cos(bp[2]), math.sin(bp[2])
        front = sc.ego.hull_offset[0] + sc.ego.hull_half[0]
        lane_half = float(sc.ego_lane.half[1])
        _add_geom(scn, _BOX, (0.35, lane_half, 0.02), (bp[0] + c * front, bp[1] + s * front, 0.04),
                  _yaw_mat(bp[2]), OVERLAY_COLORS["brake"], emission=1.0)
        ce, se = math.cos(ego[2]), math.sin(ego[2])
        cx, cy = ego[0] + ce * sc.ego.hull_offset[0], ego[1] + se * sc.ego.hull_offset[0]
        _add_geom(scn, _CYL, (0.45, 0.6, 0.0), (cx, cy, self.z_particles + 0.6), _EYE3,
                  OVERLAY_COLORS["brake"], emission=1.0)


def _writer(req: RenderRequest) -> tuple[Callable[[np.ndarray], None], Callable[[], None]]:
    """``(append(frame), close())`` for the request's format."""
    iio = _require("imageio.v2")
    if req.fmt == "mp4":
        w = iio.get_writer(req.out, format="FFMPEG", mode="I", fps=req.fps, codec="libx264",
                           pixelformat="yuv420p", macro_block_size=2, quality=7,
                           ffmpeg_log_level="error", output_params=["-preset", "veryfast"])
        return w.append_data, w.close
    frames: list[np.ndarray] = []

    def close() -> None:
        v3 = _require("imageio.v3")
        if req.fmt == "png":
            v3.imwrite(req.out, frames[0])
        else:
            v3.imwrite(req.out, np.stack(frames), plugin="pillow", duration=round(1000.0 / req.fps),
                       loop=0)

    return frames.append, close


def render_episode(out: str | Path, seed: int = 7, planner: str = "cdf", *,
                   config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                   scene: Scene | str | Path | None = None, camera: str = "top",
                   width: int = 640, height: int = 480, fps: float | None = None,
                   frame_time: float | None = None, max_particles: int = 100,
                   shadows: bool = False, antialias: bool = False,
                   overlays: bool = True) -> RenderResult:
    """Render one episode to ``out`` (``.mp4``, ``.gif``, or ``.png`` with ``frame_time``).

    Args:
        out: output file; its suffix chooses the format.
        seed, planner, config, cdf: the episode (as :func:`cdf_mj.episode.run_episode`;
            ``cdf`` sets the filter of the ``cdf`` planner).
        scene: a loaded scene or an MJCF path (default ``models/xml/scene.xml``).
        camera: a camera of the model: ``top``, ``ego_chase`` or ``obstacle_chase``.
        width, height: image size [px], even, at most :data:`MAX_RESOLUTION` (the model's
            offscreen buffer is enlarged when needed).
        fps: frames per simulated second (default 30 for MP4, 25 for GIF).
        frame_time: for ``.png``, the simulated time of the one frame [s] (clipped to the
            episode's end).
        max_particles: most distinct particles drawn per frame (heaviest first).
        shadows: draw shadows (about 4x slower on a software renderer).
        antialias: 4x multisampling (about 2x slower on a software renderer).
        overlays: draw the isovist, particles, belief, braking and the panel (``False``:
            the bare scene).

    Raises:
        RenderError: bad input, missing packages or no OpenGL, before any simulation.
    """
    config = config or ScenarioConfig()
    if not isinstance(scene, Scene):
        scene = Scene.load(scene, names=config.names) if scene is not None else Scene.load(names=config.names)
    make_planner(planner)  # unknown planner: refused before work
    req = check_request(out, scene.model, camera, width, height, fps, frame_time)
    if not isinstance(max_particles, int) or max_particles < 0:
        raise RenderError(f"max_particles={max_particles!r}: must be an integer >= 0")
    backend, _ = gl_backend()

    t0 = time.perf_counter()
    replay = record_episode(seed, planner, config, scene, cdf)
    t1 = time.perf_counter()
    if req.frame_time is not None:
        times = np.array([min(req.frame_time, replay.end_time)])
    else:
        times = frame_times(replay.end_time, req.fps)
    append, close = _writer(req)
    done = False
    try:
        with _Offscreen(scene.model, req.width, req.height,
                        max_geom=scene.model.ngeom + 400 + max_particles + 16,
                        samples=4 if antialias else 0) as gl:
            gl.use_camera(req.camera_id)
            painter = _Painter(replay, scene, gl, replay.record.planner, max_particles, shadows,
                               overlays)
            for t in times:
                append(painter.frame(float(t)))
        done = True
    finally:
        if done:
            close()
        else:  # no half-written file behind a failure
            with contextlib.suppress(Exception):  # the first error is the one to report
                close()
            req.out.unlink(missing_ok=True)
    t2 = time.perf_counter()
    return RenderResult(path=req.out, n_frames=len(times), frames_per_second=req.fps,
                        duration=float(times[-1]), render_seconds=t2 - t1, simulate_seconds=t1 - t0,
                        backend=backend, record=replay.record, label=replay.label)
