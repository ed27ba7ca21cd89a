"""Offscreen video of an episode, with what the CDF sees and believes drawn in.

``render_episode`` runs one episode (the ``cdf`` planner's filter snapshotted at every
tick), then replays it at a constant frame rate in simulated time: frame ``i`` shows the
scene at ``t = i / fps`` seconds, so no frame is dropped or repeated. ::

    from cdf_mj.viz.render import render_compare, render_episode
    result = render_episode("episode.mp4", seed=1, planner="cdf")   # the follow view
    result = render_episode("side.mp4", seed=1, layout="side")       # charts beside the view
    both = render_compare("compare.mp4", seed=1, planners=("cdf", "imm", "reactive"))
    result.n_frames, result.frames_per_second

Layouts (``layout``): ``"overlay"`` (default) draws the posterior panel
(:class:`cdf_mj.viz.panel.Panel`) over the top-left of the 3D view, the frame is
``width`` x ``height``; ``"side"`` puts :class:`cdf_mj.viz.panel.SidePanel` (time series
with axes, units and legends in words) beside the view, the frame is ``width +
side_width(height)`` x ``height`` (1000 x 480 at the defaults). In both, the planner's
command beside the ego's own controller's acceleration, the ticks in which the planner
intervened shaded, is charted over the view's bottom-left
(:class:`cdf_mj.viz.command_chart.CommandChart`). :func:`render_compare`
draws the same seed under several planners as tiles side by side, one per planner, each
labelled with its planner and brake time, at the same frame times; an episode that ends
earlier holds its last frame.

Every request is checked (camera, output path, resolution, frame rate, packages, GL)
before any simulation: :class:`RenderError` with one line saying what to change. The
jobs of a render, each in its own module:

* :mod:`cdf_mj.viz.replay`: the episode re-simulated with the per-tick data a video
  needs, the cars' poses interpolated between ticks;
* :mod:`cdf_mj.sim.gl`: the OpenGL backend (``MUJOCO_GL``, else EGL, then OSMesa) and
  MuJoCo's offscreen renderer; :class:`RenderError` and :func:`gl_backend` come from there;
* :mod:`cdf_mj.viz.overlays`: the isovist, particles, belief box and braking drawn into
  the 3D scene;
* :mod:`cdf_mj.viz.camera`: the default view that follows both cars;
* :mod:`cdf_mj.viz.panel`: the posterior panel over the top-left corner, or beside it;
* :mod:`cdf_mj.viz.encoding`: the MP4, GIF or PNG, written all or nothing.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.extras import require
from cdf_mj.planners import make_planner
from cdf_mj.records import EpisodeRecord
from cdf_mj.records.files import name_max
from cdf_mj.sim.gl import Offscreen, RenderError, gl_backend
from cdf_mj.sim.scene import Scene
from cdf_mj.sim.visibility import isovist
from cdf_mj.viz.camera import FollowCamera
from cdf_mj.viz.encoding import FORMATS, FrameWriter, check_writable
from cdf_mj.viz.overlays import draw_belief, draw_braking, draw_isovist, draw_particles
from cdf_mj.viz.panel import SIDE_MIN_HEIGHT, Panel, SidePanel, _font, side_width
from cdf_mj.viz.replay import Replay, check_frame_time, record_episode

__all__ = [
    "DEFAULT_SEED",
    "LAYOUTS",
    "MAX_FRAMES",
    "MAX_RESOLUTION",
    "MIN_RESOLUTION",
    "CompareResult",
    "RenderError",
    "RenderRequest",
    "RenderResult",
    "check_request",
    "frame_times",
    "gl_backend",
    "parse_planners",
    "render_compare",
    "render_episode",
    "tile_caption",
]

#: Largest width or height [px]; the model's offscreen buffer is enlarged up to this.
MAX_RESOLUTION = 4096
#: Smallest frame side [px] the overlays and the panel are laid out for.
MIN_RESOLUTION = 32
#: Most frames one render draws: :data:`cdf_mj.config.MAX_DURATION` (600 s) at 60 fps,
#: about ten minutes of drawing at 60 frames/s. Counted from the span and the frame rate
#: before any frame time is made (:func:`frame_times`).
MAX_FRAMES = 36_001
#: The seed rendered by default: the smallest whose default episode is a cut-off the CDF
#: brakes for (brake decision 0.9 s, lane entry 2.0 s), so the default video shows a decision.
DEFAULT_SEED = 1
#: How the posterior is laid out: over the 3D view's top-left, or as charts beside it.
LAYOUTS = ("overlay", "side")
_GIF_FPS = (10, 20, 25, 50)  # GIF delays are whole hundredths of a second
_FEATURE = "cdf-mj render"  # what the user asked for, in a missing-package message


# ----------------------------------------------------------------- checking a request
@dataclass(frozen=True)
class RenderRequest:
    """A checked request: output path and format, camera id (-1: the follow view), size
    of the 3D view [px], frame rate [frames per simulated second], the time [s] of a single
    frame (PNG only) and the layout (:data:`LAYOUTS`)."""

    out: Path
    fmt: str
    camera_id: int
    width: int
    height: int
    fps: float
    frame_time: float | None
    layout: str = "overlay"

    @property
    def frame_width(self) -> int:
        """Width [px] of one tile of the output: the view, and the side panel with ``side``."""
        return self.width + (side_width(self.height) if self.layout == "side" else 0)


def check_request(out: str | Path, model: mujoco.MjModel, camera: str | None = "top", width: int = 640,
                  height: int = 480, fps: float | None = None,
                  frame_time: float | None = None, layout: str = "overlay") -> RenderRequest:
    """Validate a render request without simulating anything (the arguments are those of
    :func:`render_episode`, ``model`` the scene's; ``camera=None`` is the follow view).
    Returns the checked request (format, camera id, frame rate).

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
    if layout not in LAYOUTS:
        raise RenderError(f"--layout {layout!r}: choose one of {', '.join(LAYOUTS)}")
    names = [model.camera(i).name for i in range(model.ncam)]
    if camera is not None and camera not in names:
        raise RenderError(f"unknown camera {camera!r}: choose one of {', '.join(names) or '(none in this scene)'} "
                          "(or leave --camera out for the view that follows both cars)")
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
    if layout == "side" and height < SIDE_MIN_HEIGHT:
        raise RenderError(f"--height {height}: --layout side needs at least {SIDE_MIN_HEIGHT} px "
                          "for its charts; use a larger --height or --layout overlay")
    if fps is None:
        fps = 25.0 if fmt == "gif" else 30.0
    if isinstance(fps, bool) or not math.isfinite(fps) or not 1.0 <= fps <= 240.0:
        raise RenderError(f"--fps {fps}: must be between 1 and 240 frames per simulated second")
    if fmt == "gif" and fps not in _GIF_FPS:
        raise RenderError(f"--fps {fps:g}: GIF frame delays are whole hundredths of a second; "
                          f"choose {', '.join(map(str, _GIF_FPS))} for a constant rate")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise RenderError(f"--out {out}: directory {parent} does not exist")
    if len(os.fsencode(out.name)) > name_max(parent):
        raise RenderError(f"--out {out}: the name is {len(os.fsencode(out.name))} bytes, longer than "
                          f"the {name_max(parent)} its file system takes; choose a shorter name")
    if out.is_dir():
        raise RenderError(f"--out {out}: is a directory")
    try:  # the temporary file the writer starts with: permissions alone miss read-only
        check_writable(out)  # and virtual file systems, and root
    except OSError as exc:
        raise RenderError(f"--out {out}: not writable ({exc.strerror or type(exc).__name__})") from None
    require("imageio", "viz", _FEATURE)
    require("PIL", "viz", _FEATURE)
    if fmt in ("mp4", "gif"):  # both streamed to ffmpeg
        require("imageio_ffmpeg", "viz", _FEATURE)
    cam_id = -1 if camera is None else names.index(camera)
    return RenderRequest(out, fmt, cam_id, int(width), int(height), float(fps), frame_time, layout)


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
    #: temporary files of killed renders to ``path`` removed before writing (FrameWriter)
    stale_removed: tuple[Path, ...] = ()


@dataclass(frozen=True)
class CompareResult:
    """What :func:`render_compare` wrote: one tile per planner, in the order asked."""

    path: Path
    n_frames: int
    frames_per_second: float  # [frames per simulated second]
    duration: float  # [s] simulated time covered (the longest episode), 0 for one frame
    render_seconds: float  # [s] wall time of drawing and encoding the frames
    simulate_seconds: float  # [s] wall time of running the episodes
    backend: str  # OpenGL backend
    records: tuple[EpisodeRecord, ...]  # one per tile, left to right
    label: str | None  # the seed's scenario label (the same for every planner)
    tile_width: int  # [px] each tile's width; the frame is len(records) tiles wide
    tile_height: int  # [px]
    #: temporary files of killed renders to ``path`` removed before writing (FrameWriter)
    stale_removed: tuple[Path, ...] = ()


def frame_times(end_time: float, fps: float, what: str = "the episode") -> np.ndarray:
    """Frame times ``i / fps`` [s] from 0 up to ``end_time`` (both ends included when on
    the grid): one frame per ``1 / fps`` of simulated time. RenderError naming ``--fps``
    and ``what`` (whose span ``end_time`` is) for more than :data:`MAX_FRAMES` frames,
    counted before any is made."""
    n = math.floor(end_time * fps + 1e-6) + 1 if math.isfinite(end_time * fps) else math.inf
    if not n <= MAX_FRAMES:
        most = math.floor((MAX_FRAMES - 1) / end_time) if end_time > 0 else MAX_FRAMES
        raise RenderError(f"--fps {fps:g}: {end_time:g} s of {what} at {fps:g} fps is {n} frames, more "
                          f"than the {MAX_FRAMES} a render draws; lower --fps (at most {most} here) or "
                          f"shorten {what}")
    return np.arange(n) / fps


class _Painter:
    """Draws the replay at any time: scene state, camera, overlays, panel (over the view,
    or beside it with the ``side`` layout)."""

    def __init__(self, replay: Replay, scene: Scene, gl: Offscreen, planner: str,
                 max_particles: int, shadows: bool, overlays: bool = True,
                 layout: str = "overlay", follow: bool = True, caption: bool = False) -> None:
        self.replay, self.scene, self.gl = replay, scene, gl
        self.layout = scene.layout()
        self.overlays = overlays
        self.max_particles = max_particles
        self.side = layout == "side"
        self.panel = Panel(replay, gl.width, gl.height, planner,
                           bottom=_caption_height(gl.height) if caption else 0)
        self.side_panel = (SidePanel(replay, side_width(gl.height), gl.height, planner)
                           if self.side else None)
        self.follow = (FollowCamera(self.layout, replay.times, replay.poses, gl.width, gl.height,
                                    fovy=float(scene.model.vis.global_.fovy)) if follow else None)
        self.shadows = shadows
        self.z_particles = max(self.layout.obstacle.hull_height, self.layout.ego.hull_height) + 0.4
        rec = replay.record
        self.brake_pose = replay.pose_at(rec.brake_time)[0] if rec.brake_time is not None else None

    @property
    def width(self) -> int:
        """Width [px] of the images :meth:`frame` returns."""
        return self.gl.width + (self.side_panel.w if self.side_panel is not None else 0)

    def frame(self, t: float) -> np.ndarray:
        """The image ``(height, width, 3)`` uint8 at time ``t`` [s]."""
        rep, sc, gl, lay = self.replay, self.scene, self.gl, self.layout
        poses = rep.pose_at(t)
        sc.set_pose(sc.ego, poses[0])
        sc.set_pose(sc.obstacle, poses[1])
        sc.sync()
        mujoco.mj_camlight(sc.model, sc.data)
        if self.follow is not None:
            gl.use_view(self.follow.at(t))
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
            draw_braking(scn, lay.ego, lay.ego_lane, self.brake_pose, poses[0], self.z_particles + 0.6)
        img = gl.render().copy()
        if self.side_panel is not None:  # the command chart stays over the view
            return np.concatenate([self.panel.draw_chart(img, t), self.side_panel.draw(t)], axis=1)
        return self.panel.draw(img, t)


def _prepare(out: str | Path, config: ScenarioConfig | None, scene: Scene | str | Path | None,
             planners: tuple[str, ...], camera: str | None, width: int, height: int,
             fps: float | None, frame_time: float | None, layout: str,
             max_particles: int) -> tuple[ScenarioConfig, Scene, RenderRequest, str]:
    """Everything checked before any simulation: the config, the loaded scene, the request
    and the OpenGL backend's name."""
    config = config or ScenarioConfig()
    if not isinstance(scene, Scene):
        scene = Scene.load(scene, names=config.names) if scene is not None else Scene.load(names=config.names)
    for name in planners:
        make_planner(name)  # unknown planner: refused before work
    req = check_request(out, scene.model, camera, width, height, fps, frame_time, layout)
    if isinstance(max_particles, bool) or not isinstance(max_particles, int) or max_particles < 0:
        raise RenderError(f"max_particles={max_particles!r}: must be an integer >= 0")
    backend, _ = gl_backend()
    return config, scene, req, backend


def _times(req: RenderRequest, end_time: float) -> np.ndarray:
    """The frame times [s]: every ``1 / fps`` up to ``end_time``, or the one frame of
    ``--frame`` (RenderError past ``end_time``)."""
    if req.frame_time is not None:
        return np.array([check_frame_time(req.frame_time, end_time)])
    return frame_times(end_time, req.fps)


def _offscreen(scene: Scene, req: RenderRequest, max_particles: int, antialias: bool) -> Offscreen:
    """The renderer of the 3D view, looking through the requested camera."""
    gl = Offscreen(scene.model, req.width, req.height,
                   max_geom=scene.model.ngeom + 400 + max_particles + 16,
                   samples=4 if antialias else 0)
    if req.camera_id >= 0:
        gl.use_camera(req.camera_id)
    return gl


def render_episode(out: str | Path, seed: int = DEFAULT_SEED, planner: str = "cdf", *,
                   config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                   scene: Scene | str | Path | None = None, camera: str | None = None,
                   width: int = 640, height: int = 480, fps: float | None = None,
                   frame_time: float | None = None, layout: str = "overlay",
                   max_particles: int = 100, shadows: bool = False, antialias: bool = False,
                   overlays: bool = True) -> RenderResult:
    """Render one episode to ``out`` (``.mp4``, ``.gif``, or ``.png`` with ``frame_time``).

    Args:
        out: output file; its suffix chooses the format.
        seed, planner, config, cdf: the episode (as :func:`cdf_mj.scenario.episode.run_episode`;
            ``cdf`` sets the filter of the ``cdf`` planner). The default seed,
            :data:`DEFAULT_SEED`, is a cut-off the CDF brakes for.
        scene: a loaded scene or an MJCF path (default ``models/xml/scene.xml``).
        camera: ``None`` (default) for the view that follows both cars and the conflict
            zone (:class:`cdf_mj.viz.camera.FollowCamera`), or a camera of the model, e.g.
            ``top``, ``ego_chase`` or ``obstacle_chase``.
        width, height: size of the 3D view [px], even for MP4, at most
            :data:`MAX_RESOLUTION` (the model's offscreen buffer is enlarged when needed).
        fps: frames per simulated second (default 30 for MP4, 25 for GIF).
        frame_time: for ``.png``, the simulated time of the one frame [s], from 0 to the
            episode's end (:class:`RenderError` past it, naming the end time).
        layout: ``"overlay"`` (the panel over the view's top-left) or ``"side"`` (charts
            beside the view: the frame is ``width + side_width(height)`` px wide and
            ``height`` at least :data:`cdf_mj.viz.panel.SIDE_MIN_HEIGHT`).
        max_particles: most distinct particles drawn per frame (heaviest first).
        shadows: draw shadows (about 4x slower on a software renderer).
        antialias: 4x multisampling (about 2x slower on a software renderer).
        overlays: draw the isovist, particles, belief, braking and the panel (``False``:
            the bare scene, in either layout).

    The file appears only once complete (:class:`cdf_mj.viz.encoding.FrameWriter`): a
    failure leaves ``out`` as it was.

    Raises:
        RenderError: bad input or no OpenGL, before any simulation; a ``frame_time`` past
            the episode's end, after simulating and before drawing.
        ImportError: the ``viz`` extra is missing, before any simulation.
        EncodingError: the file could not be written (an OSError naming ``out``).
    """
    config, scene, req, backend = _prepare(out, config, scene, (planner,), camera, width, height,
                                           fps, frame_time, layout, max_particles)
    t0 = time.perf_counter()
    replay = record_episode(seed, planner, config, scene, cdf)
    t1 = time.perf_counter()
    times = _times(req, replay.end_time)
    with FrameWriter(req.out, req.fps) as writer, _offscreen(scene, req, max_particles, antialias) as gl:
        painter = _Painter(replay, scene, gl, replay.record.planner, max_particles, shadows,
                           overlays, req.layout, follow=req.camera_id < 0)
        for t in times:
            writer.append(painter.frame(float(t)))
    t2 = time.perf_counter()
    return RenderResult(path=req.out, n_frames=len(times), frames_per_second=req.fps,
                        duration=float(times[-1]), render_seconds=t2 - t1, simulate_seconds=t1 - t0,
                        backend=backend, record=replay.record, label=replay.label,
                        stale_removed=writer.stale_removed)


def tile_caption(record: EpisodeRecord) -> str:
    """The words under a compare tile: planner, brake decision [s] and any collision."""
    brake = f"brakes at {record.brake_time:.2f} s" if record.brake_time is not None else "never brakes"
    hit = f", hits the {record.collision_with or 'obstacle'}" if record.collision else ""
    return f"{record.planner}: {brake}{hit}"


def _caption_px(height: int) -> int:
    """Text height [px] of a compare tile's caption, for a tile ``height`` px high."""
    return max(8, min(20, round(height / 24)))


def _caption_height(height: int) -> int:
    """Rows [px] of a compare tile's caption strip, for a tile ``height`` px high."""
    return round(_caption_px(height) * 1.5)


def _caption(img: np.ndarray, text: str) -> np.ndarray:
    """``img`` with ``text`` on a dark strip along its bottom-left (in place); returns it."""
    from PIL import Image, ImageDraw

    h, w = img.shape[:2]
    px, strip = _caption_px(h), _caption_height(h)
    font = _font(px)
    tw = min(w, round(font.getlength(text)) + 2 * px)
    img[h - strip:, :tw] = (0.25 * img[h - strip:, :tw]).astype(np.uint8)
    pil = Image.fromarray(img)
    ImageDraw.Draw(pil).text((px // 2 + 2, h - strip // 2), text, fill=(255, 255, 255), font=font, anchor="lm")
    img[...] = np.asarray(pil)
    return img


def parse_planners(text: str) -> tuple[str, ...]:
    """``"cdf,imm,reactive"`` -> ``("cdf", "imm", "reactive")``; RenderError for fewer than
    two, a repeated or an unknown name (naming it and the choices)."""
    from cdf_mj.planners import PLANNERS

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    for n in names:
        if n not in PLANNERS:
            raise RenderError(f"--planner: unknown planner {n!r}; choose from {', '.join(sorted(PLANNERS))}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise RenderError(f"--planner: planner {repeated[0]!r} given twice; name each once")
    if not 2 <= len(names) <= 6:
        raise RenderError(f"--planner {text!r}: give 2 to 6 planners separated by commas, e.g. cdf,imm,reactive")
    return names


def render_compare(out: str | Path, seed: int = DEFAULT_SEED,
                   planners: str | tuple[str, ...] = ("cdf", "imm", "reactive"), *,
                   config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                   scene: Scene | str | Path | None = None, camera: str | None = None,
                   width: int = 640, height: int = 480, fps: float | None = None,
                   frame_time: float | None = None, layout: str = "overlay",
                   max_particles: int = 100, shadows: bool = False,
                   antialias: bool = False) -> CompareResult:
    """Render the same seed under several planners into one video, tiles side by side.

    Each tile is what :func:`render_episode` draws for that planner (``width`` x
    ``height`` [px], plus the side panel with ``layout="side"``), with a caption at its
    bottom-left naming the planner, its brake time and any collision
    (:func:`tile_caption`). Every tile is drawn at the same simulated times, up to the
    longest episode's end; a tile whose episode ended earlier holds its last frame. The
    arguments are those of :func:`render_episode`; ``planners`` is 2 to 6 distinct names
    (or one string ``"cdf,imm,reactive"``).

    Raises:
        RenderError: bad input or no OpenGL, before any simulation; a ``frame_time`` past
            the longest episode's end, before drawing.
        ImportError: the ``viz`` extra is missing, before any simulation.
    """
    names = parse_planners(planners if isinstance(planners, str) else ",".join(planners))
    config, scene, req, backend = _prepare(out, config, scene, names, camera, width, height,
                                           fps, frame_time, layout, max_particles)
    t0 = time.perf_counter()
    replays = [record_episode(seed, name, config, scene, cdf, label=i == 0) for i, name in enumerate(names)]
    for r in replays[1:]:  # the label is the seed's (the ego at constant speed): run once
        r.label = replays[0].label
    t1 = time.perf_counter()
    end = max(r.end_time for r in replays)
    times = _times(req, end)
    with FrameWriter(req.out, req.fps) as writer, _offscreen(scene, req, max_particles, antialias) as gl:
        painters = [_Painter(r, scene, gl, name, max_particles, shadows, True, req.layout,
                             follow=req.camera_id < 0, caption=True)
                    for r, name in zip(replays, names, strict=True)]
        captions = [tile_caption(r.record) for r in replays]
        for t in times:
            tiles = [_caption(p.frame(min(float(t), p.replay.end_time)), c)
                     for p, c in zip(painters, captions, strict=True)]
            writer.append(np.concatenate(tiles, axis=1))
    t2 = time.perf_counter()
    return CompareResult(path=req.out, n_frames=len(times), frames_per_second=req.fps,
                         duration=float(times[-1]), render_seconds=t2 - t1, simulate_seconds=t1 - t0,
                         backend=backend, records=tuple(r.record for r in replays),
                         label=replays[0].label, tile_width=req.frame_width, tile_height=req.height,
                         stale_removed=writer.stale_removed)
