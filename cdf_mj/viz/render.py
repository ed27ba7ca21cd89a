"""Offscreen video of an episode, with what the CDF sees and believes drawn in.

``render_episode`` runs one episode (the ``cdf`` planner's filter snapshotted at every
tick), then replays it at a constant frame rate in simulated time: frame ``i`` shows the
scene at ``t = i / fps`` seconds, so no frame is dropped or repeated. ::

    from cdf_mj.viz.render import render_episode
    result = render_episode("episode.mp4", seed=7, planner="cdf", camera="top")
    result.n_frames, result.frames_per_second

Every request is checked (camera, output path, resolution, frame rate, packages, GL)
before any simulation: :class:`RenderError` with one line saying what to change. The
jobs of a render, each in its own module:

* :mod:`cdf_mj.viz.replay`: the episode re-simulated with the per-tick data a video
  needs, the cars' poses interpolated between ticks;
* :mod:`cdf_mj.sim.gl`: the OpenGL backend (``MUJOCO_GL``, else EGL, then OSMesa) and
  MuJoCo's offscreen renderer; :class:`RenderError` and :func:`gl_backend` come from there;
* :mod:`cdf_mj.viz.overlays`: the isovist, particles, belief box and braking drawn into
  the 3D scene;
* :mod:`cdf_mj.viz.panel`: the posterior panel over the top-left corner;
* :mod:`cdf_mj.viz.encoding`: the MP4, GIF or PNG, written all or nothing.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.extras import require
from cdf_mj.planners import make_planner
from cdf_mj.records import EpisodeRecord
from cdf_mj.sim.gl import Offscreen, RenderError, gl_backend
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.visibility import isovist
from cdf_mj.viz.encoding import FORMATS, FrameWriter, check_writable
from cdf_mj.viz.overlays import draw_belief, draw_braking, draw_isovist, draw_particles
from cdf_mj.viz.panel import Panel
from cdf_mj.viz.replay import Replay, record_episode

__all__ = [
    "MAX_RESOLUTION",
    "MIN_RESOLUTION",
    "RenderError",
    "RenderRequest",
    "RenderResult",
    "check_request",
    "frame_times",
    "gl_backend",
    "render_episode",
]

#: Largest width or height [px]; the model's offscreen buffer is enlarged up to this.
MAX_RESOLUTION = 4096
#: Smallest frame side [px] the overlays and the panel are laid out for.
MIN_RESOLUTION = 32
_GIF_FPS = (10, 20, 25, 50)  # GIF delays are whole hundredths of a second
_FEATURE = "cdf-mj render"  # what the user asked for, in a missing-package message


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


def check_request(out: str | Path, model: mujoco.MjModel, camera: str = "top", width: int = 640,
                  height: int = 480, fps: float | None = None,
                  frame_time: float | None = None) -> RenderRequest:
    """Validate a render request without simulating anything (the arguments are those of
    :func:`render_episode`, ``model`` the scene's). Returns the checked request (format,
    camera id, frame rate).

    Raises:
        RenderError: the first problem, in one line naming the option to change.
        ImportError: the ``viz`` extra is missing.
    """
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
    try:  # the temporary file the writer starts with: permissions alone miss read-only
        check_writable(out)  # and virtual file systems, and root
    except OSError as exc:
        raise RenderError(f"--out {out}: not writable ({exc.strerror or type(exc).__name__})") from None
    require("imageio", "viz", _FEATURE)
    require("PIL", "viz", _FEATURE)
    if fmt == "mp4":
        require("imageio_ffmpeg", "viz", _FEATURE)
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

    def __init__(self, replay: Replay, scene: Scene, gl: Offscreen, planner: str,
                 max_particles: int, shadows: bool, overlays: bool = True) -> None:
        self.replay, self.scene, self.gl = replay, scene, gl
        self.layout = scene.layout()
        self.overlays = overlays
        self.max_particles = max_particles
        self.panel = Panel(replay, gl.width, gl.height, planner)
        self.shadows = shadows
        self.z_particles = max(self.layout.obstacle.hull_height, self.layout.ego.hull_height) + 0.4
        rec = replay.record
        self.brake_pose = replay.pose_at(rec.brake_time)[0] if rec.brake_time is not None else None

    def frame(self, t: float) -> np.ndarray:
        """The image ``(height, width, 3)`` uint8 at time ``t`` [s]."""
        rep, sc, gl, lay = self.replay, self.scene, self.gl, self.layout
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
        draw_isovist(scn, isovist(sc, lay.obstacle.eye(poses[1])))
        k = rep.tick(t)
        if k < len(rep.seen) and rep.seen[k]:
            draw_belief(scn, lay.ego, rep.belief[k])
        if rep.particles is not None and k < len(rep.particles):
            draw_particles(scn, rep.particles[k], self.z_particles, self.max_particles)
        if self.brake_pose is not None and rep.braking(t):
            draw_braking(scn, lay.ego, float(lay.ego_lane.half[1]), self.brake_pose, poses[0],
                         self.z_particles + 0.6)
        img = gl.render().copy()
        return self.panel.draw(img, t)


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
        seed, planner, config, cdf: the episode (as :func:`cdf_mj.scenario.episode.run_episode`;
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

    The file appears only once complete (:class:`cdf_mj.viz.encoding.FrameWriter`): a
    failure leaves ``out`` as it was.

    Raises:
        RenderError: bad input or no OpenGL, before any simulation.
        ImportError: the ``viz`` extra is missing, before any simulation.
        EncodingError: the file could not be written (an OSError naming ``out``).
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
    with FrameWriter(req.out, req.fps) as writer, \
            Offscreen(scene.model, req.width, req.height,
                      max_geom=scene.model.ngeom + 400 + max_particles + 16,
                      samples=4 if antialias else 0) as gl:
        gl.use_camera(req.camera_id)
        painter = _Painter(replay, scene, gl, replay.record.planner, max_particles, shadows,
                           overlays)
        for t in times:
            writer.append(painter.frame(float(t)))
    t2 = time.perf_counter()
    return RenderResult(path=req.out, n_frames=len(times), frames_per_second=req.fps,
                        duration=float(times[-1]), render_seconds=t2 - t1, simulate_seconds=t1 - t0,
                        backend=backend, record=replay.record, label=replay.label)
