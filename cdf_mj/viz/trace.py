"""Draw a user's own episode from a monitor trace (``cdf-mj render --trace FILE``).

A trace (:meth:`cdf_mj.scenario.monitor.CDFMonitor.save_trace`) holds, per 0.1 s tick,
both cars' rear-axle poses, the CDF posterior and the brake decision, and in its header
the scene names and both cars' :class:`~cdf_mj.model.vehicle.CarGeometry`. This module
draws the scene's junction (the MJCF file the user's simulation ran on, its moving bodies
hidden) with both cars' collision boxes at the traced poses (red ego, blue obstacle,
interpolated between ticks), the braking stripe, and the posterior panel of
``cdf-mj render`` (:mod:`cdf_mj.viz.panel`); a trace of a planner without a posterior
(``CDFMonitor(planner="imm-layered")``) gets its rule's risk there, or none. ::

    from cdf_mj.viz.trace import render_trace
    render_trace("episode.jsonl", "my_junction.xml", "episode.mp4")
    render_trace("episode.jsonl", "my_junction.xml", "frame.png", frame_time=1.5)

The default view is :class:`cdf_mj.viz.camera.FollowCamera`: straight down, the ego
driving left to right, framing both cars and the conflict zone and zooming as they
converge. ``camera="top"`` (or any camera of the scene) looks through that camera instead;
a scene without a ``top`` camera gets one 70 m above the conflict point, looking down
(x to the right, y up in the image).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.monitor import MonitorTrace, read_trace
from cdf_mj.sim.checks import SceneError, check_regular_files
from cdf_mj.sim.gl import Offscreen, gl_backend
from cdf_mj.sim.scene import read_layout
from cdf_mj.viz.camera import FollowCamera
from cdf_mj.viz.encoding import FrameWriter
from cdf_mj.viz.overlays import draw_braking
from cdf_mj.viz.panel import Panel
from cdf_mj.viz.render import check_request, frame_times
from cdf_mj.viz.replay import Replay, check_frame_time

__all__ = ["CAR_COLORS", "TraceRenderResult", "render_trace"]

#: RGBA of the traced cars' boxes.
CAR_COLORS = {"ego": (0.85, 0.1, 0.1, 1.0), "obstacle": (0.1, 0.3, 0.85, 1.0)}
_TOP = "top"  # the camera used when the scene has one of this name


@dataclass(frozen=True)
class TraceRenderResult:
    """What :func:`render_trace` wrote."""

    path: Path
    n_frames: int
    frames_per_second: float  # [frames per simulated second]
    duration: float  # [s] simulated time covered from the trace's first tick, 0 for one frame
    render_seconds: float  # [s] wall time of drawing and encoding
    backend: str  # OpenGL backend
    brake_time: float | None  # [s] the monitor's brake decision, None if it never braked
    #: temporary files of killed renders to ``path`` removed before writing (FrameWriter)
    stale_removed: tuple[Path, ...] = ()


@dataclass(frozen=True)
class _TraceRecord:
    """The fields of a record that the panel and the replay read."""

    seed: str
    brake_time: float | None
    trace: dict[str, list[Any]]  # "brake" per tick; "command", "own", "intervening" where kept


class _TracePanel(Panel):
    """The posterior panel with the trace's file name in its head line."""

    def __init__(self, replay: Replay, width: int, height: int, head: str) -> None:
        self.head = head
        super().__init__(replay, width, height, "monitor")

    def _background(self, head: str) -> np.ndarray:
        return super()._background(self.head)


def _scene_model(scene: str | Path, names: SceneNames) -> tuple[mujoco.MjModel, int]:
    """The scene compiled for drawing: a ``top`` camera added when it has none (over the
    conflict point), and the geoms of every moving body made invisible. Returns the
    model and the camera's id."""
    path = Path(scene)
    if not path.is_file():
        raise SceneError(f"--scene {path}: file not found")
    check_regular_files(path)  # a FIFO among its includes would block MuJoCo
    try:
        spec = mujoco.MjSpec.from_file(str(path))
        if spec.camera(_TOP) is None:
            model = spec.compile()
            data = mujoco.MjData(model)
            mujoco.mj_kinematics(model, data)
            site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, names.conflict)
            cx, cy = data.site_xpos[site, :2] if site >= 0 else (0.0, 0.0)
            spec.worldbody.add_camera(name=_TOP, pos=[cx, cy, 70.0], fovy=60.0)
        model = spec.compile()
    except ValueError as exc:
        raise SceneError(f"cannot load scene {path}: {' '.join(str(exc).split())}") from None
    moving = np.array([model.body_weldid[b] != 0 or model.body_mocapid[b] >= 0
                       for b in range(model.nbody)])
    hide = moving[model.geom_bodyid]
    model.geom_rgba[hide, 3] = 0.0
    model.geom_matid[hide] = -1
    return model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, _TOP)


def _add_box(scn: mujoco.MjvScene, car: CarGeometry, pose: np.ndarray, rgba: tuple[float, ...]) -> None:
    """A car's collision box at pose ``[x, y, yaw, v]`` as a decor geom (nothing when full)."""
    if scn.ngeom >= scn.maxgeom:
        return
    c, s = math.cos(pose[2]), math.sin(pose[2])
    ox, oy = car.hull_offset
    half_z = 0.5 * car.hull_height
    pos = np.array([pose[0] + c * ox - s * oy, pose[1] + s * ox + c * oy, half_z])
    mat = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_BOX.value, np.array([*car.hull_half, half_z]), pos,
                        mat.ravel(), np.asarray(rgba, dtype=np.float32))
    g.category = mujoco.mjtCatBit.mjCAT_DECOR.value
    scn.ngeom += 1


def _replay(trace: MonitorTrace) -> Replay:
    """The trace as a :class:`Replay` for the panel and the pose interpolation."""
    times = np.append(trace.times, trace.times[-1])  # the last tick is the end
    poses = np.concatenate([trace.poses, trace.poses[-1:]])
    rows: dict[str, list[Any]] = {"brake": trace.brake.tolist()}
    if np.isfinite(trace.own).all():  # a trace that counts every intervention: its command chart
        rows.update(command=trace.command.tolist(), own=trace.own.tolist(), intervening=trace.intervening.tolist())
    record = cast(EpisodeRecord, _TraceRecord(seed=trace.path.name, brake_time=trace.brake_time, trace=rows))
    k = len(trace.times)
    # A planner without a posterior: its rule's risk alone where it has one, else no panel
    # of probabilities ("no filter").
    shown = [key for key in ("p_left", "p_seen", "p_cutoff", "risk") if key in trace.posterior]
    tau: float | None = trace.threshold if math.isfinite(trace.threshold) else None
    return Replay(record=record, label=None, times=times, poses=poses, seen=np.zeros(k, dtype=bool),
                  belief=np.zeros((k, 4)), particles=None,
                  posterior={key: trace.posterior[key] for key in ("t", *shown)} if shown else None,
                  tau=tau if shown else None)


def render_trace(trace: str | Path, scene: str | Path, out: str | Path, *,
                 names: SceneNames | None = None, width: int = 640, height: int = 480,
                 fps: float | None = None, frame_time: float | None = None,
                 camera: str | None = None) -> TraceRenderResult:
    """Render a monitor trace over its scene to ``out`` (``.mp4``, ``.gif``, or ``.png``
    with ``frame_time`` [s] from the trace's first tick, at most the trace's span).

    ``names`` picks the junction's elements in ``scene`` (default: the names in the
    trace's header); ``camera`` a camera of the scene (default ``None``: the follow view,
    :class:`~cdf_mj.viz.camera.FollowCamera`). Raises TraceError (``file:line``) for a
    damaged trace, SceneError for a scene that cannot be read, RenderError for a bad
    request (a ``frame_time`` past the trace's end included) or no OpenGL, all before
    drawing; the file appears only once complete.
    """
    tr = read_trace(trace)
    names = names or tr.names
    model, _ = _scene_model(scene, names)
    layout = read_layout(model, names, ego=tr.ego, obstacle=tr.obstacle, source=str(scene))
    req = check_request(out, model, camera or _TOP, width, height, fps, frame_time)
    t0 = float(tr.times[0])
    end = float(tr.times[-1]) - t0
    rel = (frame_times(end, req.fps, "the trace") if req.frame_time is None
           else np.array([check_frame_time(req.frame_time, end)]))
    backend, _ = gl_backend()
    replay = _replay(tr)
    follow = None if camera is not None else FollowCamera(
        layout, tr.times, tr.poses, req.width, req.height, fovy=float(model.vis.global_.fovy))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    brake_time = tr.brake_time
    brake_pose = replay.pose_at(brake_time)[0] if brake_time is not None else None
    z = max(tr.ego.hull_height, tr.obstacle.hull_height) + 1.0
    start = time.perf_counter()
    with FrameWriter(req.out, req.fps) as writer, \
            Offscreen(model, req.width, req.height, max_geom=model.ngeom + 64) as gl:
        gl.use_camera(req.camera_id)
        panel = _TracePanel(replay, gl.width, gl.height,
                            f"trace {tr.path.name}  {'monitor' if tr.planner == 'cdf' else tr.planner}")
        for rt in rel:
            t = t0 + float(rt)
            poses = replay.pose_at(t)
            if follow is not None:
                gl.use_view(follow.at(t))
            gl.update(data)
            scn = gl.scene
            scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            _add_box(scn, tr.ego, poses[0], CAR_COLORS["ego"])
            _add_box(scn, tr.obstacle, poses[1], CAR_COLORS["obstacle"])
            if brake_pose is not None and replay.braking(t):
                draw_braking(scn, tr.ego, layout.ego_lane, brake_pose, poses[0], z)
            writer.append(panel.draw(gl.render().copy(), t))
    return TraceRenderResult(path=req.out, n_frames=len(rel), frames_per_second=req.fps,
                             duration=float(rel[-1]), render_seconds=time.perf_counter() - start,
                             backend=backend, brake_time=brake_time, stale_removed=writer.stale_removed)
