"""The default view (cdf_mj.viz.camera.FollowCamera) and where overlays land in the image.

The size and framing checks project the cars' footprints with the camera MuJoCo sets up
for the frame (``mjv_updateScene``; no OpenGL needed). The pixel checks render real frames
offscreen (EGL or OSMesa) and are skipped, with the reason, only where no backend exists:
each draws one overlay into a frame and compares the pixels it changed with the projection
of the overlay's geometry, on the default scene and on a rotated, mirrored junction.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.sim.gl import Offscreen, RenderError, project_points
from cdf_mj.sim.scene import Scene
from cdf_mj.viz.camera import FollowCamera, follow_camera, lane_direction
from cdf_mj.viz.overlays import OVERLAY_COLORS, TICK_FRACTION, draw_belief, draw_braking, draw_particles
from cdf_mj.viz.replay import Particles, Replay, record_episode
from tests.junctions import build_junction, junction_scene

W, H = 640, 480
FPS = 30.0


@pytest.fixture(scope="module")
def rotated() -> Scene:
    """A junction rotated by 2 rad (the main road runs north-north-west), left-hand traffic."""
    return junction_scene(rotation=2.0, mirror=True, lane_width=3.4)



def _frames(scene: Scene, follow: FollowCamera, replay: Replay):
    """(t, poses, MjvScene) for every frame at FPS, the scene's camera set by the view."""
    scn = mujoco.MjvScene(scene.model, maxgeom=scene.model.ngeom + 10)
    opt, pert, cam = mujoco.MjvOption(), mujoco.MjvPerturb(), mujoco.MjvCamera()
    for t in np.arange(0.0, replay.end_time + 1e-9, 1.0 / FPS):
        poses = replay.pose_at(float(t))
        scene.set_pose(scene.ego, poses[0])
        scene.set_pose(scene.obstacle, poses[1])
        scene.sync()
        follow.at(float(t)).apply(cam)
        mujoco.mjv_updateScene(scene.model, scene.data, opt, pert, cam, mujoco.mjtCatBit.mjCAT_ALL, scn)
        yield float(t), poses, scn


def _ground(xy: np.ndarray, z: float = 0.0) -> np.ndarray:
    return np.column_stack([xy, np.full(len(xy), z)])


@pytest.mark.parametrize(("which", "preset"), [("default", {}), ("default", {"ego.start_spread": (-25.2, -24.0)}),
                                               ("rotated", {})])
def test_both_cars_at_least_40_px_and_in_view_in_every_frame(scene, rotated, which, preset) -> None:
    sc = scene if which == "default" else rotated
    config = ScenarioConfig().with_values(preset)
    replay = record_episode(3, "reactive", config, sc, label=False)
    layout = sc.layout()
    follow = FollowCamera(layout, replay.times, replay.poses, W, H, fovy=float(sc.model.vis.global_.fovy))
    previous = None
    n = 0
    for _, poses, scn in _frames(sc, follow, replay):
        for car, pose in ((layout.ego, poses[0]), (layout.obstacle, poses[1])):
            px = project_points(scn, _ground(car.footprint(pose)), W, H)  # corners, counter-clockwise
            length = min(np.hypot(*(px[0] - px[1])), np.hypot(*(px[2] - px[3])))
            assert length >= 40.0, f"a car is {length:.1f} px long"
            assert np.all((px >= 0) & (px <= [W, H])), f"a car leaves the view: {px.round()}"
        conflict = project_points(scn, _ground(np.asarray(layout.conflict)[None]), W, H)[0]
        if not preset:  # the far start of the second case may push the conflict zone out
            assert 0 <= conflict[0] <= W and 0 <= conflict[1] <= H
        # Smooth: between frames 1/30 s apart the view moves and zooms by little.
        ground = project_points(scn, _ground(np.array([[0.0, 0.0], [10.0, 0.0]])), W, H)
        scale = np.hypot(*(ground[1] - ground[0])) / 10.0  # [px/m]
        if previous is not None:
            assert abs(scale / previous[1] - 1.0) < 0.02
            assert np.hypot(*(ground[0] - previous[0])) < 6.0  # [px]
        previous = (ground[0], scale)
        n += 1
    assert n == len(np.arange(0.0, replay.end_time + 1e-9, 1.0 / FPS)) > 30


def test_the_ego_drives_left_to_right_on_any_junction(scene, rotated) -> None:
    for sc in (scene, rotated):
        layout = sc.layout()
        poses = np.stack([np.stack([layout.ego_start, layout.obstacle_start])] * 3)
        (view, *_) = follow_camera(layout, poses, W, H, fovy=float(sc.model.vis.global_.fovy))
        scn = mujoco.MjvScene(sc.model, maxgeom=sc.model.ngeom)
        cam = mujoco.MjvCamera()
        view.apply(cam)
        mujoco.mjv_updateScene(sc.model, sc.data, mujoco.MjvOption(), mujoco.MjvPerturb(), cam,
                               mujoco.mjtCatBit.mjCAT_ALL, scn)
        u = lane_direction(layout)
        a, b = project_points(scn, _ground(np.stack([layout.conflict, layout.conflict + 10 * u])), W, H)
        assert b[0] - a[0] > 9 * view.pixels_per_metre(H, float(sc.model.vis.global_.fovy))  # rightwards
        assert abs(b[1] - a[1]) < 1.0
        # The obstacle's side road is above the ego's lane, or below it for left-hand traffic.
        side = project_points(scn, _ground(np.asarray(layout.obstacle_start[:2])[None]), W, H)[0]
        assert (side[1] < a[1]) == (sc is scene)


def test_bad_input_is_one_line(scene) -> None:
    layout = scene.layout()
    with pytest.raises(ValueError, match=r"poses must be \(K, 2, 4\)"):
        FollowCamera(layout, [0.0, 0.1], np.zeros((3, 2, 4)), W, H)
    with pytest.raises(ValueError, match="must be > 0"):
        FollowCamera(layout, [0.0], np.zeros((1, 2, 4)), 0, H)


# ----------------------------------------------------------------- pixels (OpenGL)
def _changed(sc: Scene, view, draw) -> np.ndarray:
    """Pixels ``(P, 2)`` (column, row) that ``draw(scn)`` changes in the frame of ``view``."""
    with Offscreen(sc.model, W, H, max_geom=sc.model.ngeom + 50) as gl:
        gl.use_view(view)
        gl.update(sc.data)
        gl.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        gl.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        bare = gl.render().copy()
        draw(gl.scene)
        drawn = gl.render().copy()
    rows, cols = np.nonzero(np.abs(drawn.astype(int) - bare.astype(int)).sum(axis=2) > 30)
    return np.column_stack([cols, rows]).astype(float)


def _in_polygon(px: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Points ``(P, 2)`` inside the convex polygon ``(4, 2)`` (either winding)."""
    signs = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        signs.append((b[0] - a[0]) * (px[:, 1] - a[1]) - (b[1] - a[1]) * (px[:, 0] - a[0]))
    s = np.stack(signs)
    return np.all(s >= 0, axis=0) | np.all(s <= 0, axis=0)


@pytest.mark.parametrize("which", ["default", "rotated"])
def test_overlay_pixels_land_on_the_projected_geometry(backend, scene, rotated, which) -> None:
    sc = scene if which == "default" else rotated
    layout = sc.layout()
    sc.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)
    poses = np.stack([np.stack([layout.ego_start, layout.obstacle_start])] * 2)
    fovy = float(sc.model.vis.global_.fovy)
    follow = FollowCamera(layout, [0.0, 0.1], poses, W, H, fovy=fovy)
    view = follow.at(0.0)
    u = lane_direction(layout)
    # The brake stripe across the ego's lane, 12 m ahead of the ego's start.
    brake = np.array([*(layout.ego_start[:2] + 12.0 * u), math.atan2(u[1], u[0]), 10.0])
    far = np.array([1e3, 1e3, 0.0, 0.0])  # the beacon out of sight
    changed = _changed(sc, view, lambda scn: draw_braking(scn, layout.ego, layout.ego_lane, brake, far, 3.0))
    front = layout.ego.hull_offset[0] + layout.ego.hull_half[0]
    centre = brake[:2] + front * u
    n = np.array([-u[1], u[0]])
    half_w = float(min(layout.ego_lane.half))
    stripe = np.stack([centre + 0.35 * u + half_w * n, centre - 0.35 * u + half_w * n,
                       centre - 0.35 * u - half_w * n, centre + 0.35 * u - half_w * n])
    with Offscreen(sc.model, W, H) as gl:
        gl.use_view(view)
        gl.update(sc.data)
        poly = gl.project(_ground(stripe, 0.04))
    assert len(changed) > 20
    grown = poly + 2.0 * np.sign(poly - poly.mean(axis=0))  # 2 px of rasterisation
    assert np.mean(_in_polygon(changed, grown)) > 0.97
    span = np.ptp(changed, axis=0)
    assert max(span) < 2 * half_w * view.pixels_per_metre(H, fovy) + 6  # across the lane, not 300 m

    # The belief box at a pose beside the obstacle: its wire edges lie on the projected box.
    belief = np.array([*(layout.conflict - 8.0 * u), math.atan2(u[1], u[0]), 0.0])
    changed = _changed(sc, view, lambda scn: draw_belief(scn, layout.ego, belief))
    foot = layout.ego.footprint(belief)
    with Offscreen(sc.model, W, H) as gl:
        gl.use_view(view)
        gl.update(sc.data)
        top, bottom = gl.project(_ground(foot, layout.ego.hull_height)), gl.project(_ground(foot, 0.0))
    box = np.concatenate([top, bottom])
    lo, hi = box.min(axis=0) - 2, box.max(axis=0) + 2
    assert len(changed) > 40 and np.all((changed >= lo) & (changed <= hi))
    assert np.all(np.ptp(changed, axis=0) > 0.8 * (hi - lo - 4))  # the whole box is drawn

    # A particle tick: a line from its rear axle along its heading, sized for the view.
    heading = math.atan2(u[1], u[0]) + 0.6
    tick = Particles(np.array([layout.conflict], dtype=np.float32), np.array([0], dtype=np.uint8),
                     np.array([1.0], dtype=np.float32), np.array([heading], dtype=np.float32))
    changed = _changed(sc, view, lambda scn: draw_particles(scn, tick, 2.0, 10))
    with Offscreen(sc.model, W, H) as gl:
        gl.use_view(view)
        gl.update(sc.data)
        start, one = gl.project(_ground(np.stack([layout.conflict, layout.conflict + n]), 2.0))
        metres = TICK_FRACTION * H / np.hypot(*(one - start))  # [m] a fraction of the view
        end = gl.project(np.array([*(layout.conflict + metres * np.array([math.cos(heading),
                                                                          math.sin(heading)])), 2.0]))
    assert len(changed) > 10
    dist_start = np.hypot(*(changed - start).T)
    dist_end = np.hypot(*(changed - end).T)
    assert dist_start.min() < 3.0 and dist_end.min() < 3.0  # from the particle to the tip
    assert np.hypot(*(end - start)) == pytest.approx(TICK_FRACTION * H, rel=0.05)  # about 17 px
    # Every changed pixel is on the segment (within the 3 px line and its rasterisation).
    seg = end - start
    s_along = np.clip(((changed - start) @ seg) / (seg @ seg), 0.0, 1.0)
    off = np.hypot(*(changed - start - s_along[:, None] * seg).T)
    assert np.all(off < 3.0)
    assert OVERLAY_COLORS["isovist"][3] <= 0.15  # a light fill that leaves the road grey


def test_a_trace_renders_in_the_follow_view_and_refuses_a_frame_past_its_end(backend, tmp_path) -> None:
    """A user's monitor trace (mocap cars on a rotated junction of their own names)."""
    iio = pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
    from cdf_mj.viz.trace import render_trace
    from tests.test_monitor import OWN_NAMES, _wait_and_go

    xml = tmp_path / "junction.xml"
    xml.write_text(build_junction(names=OWN_NAMES, cars=False, rotation=2.0, camera=None).to_xml())
    _, _, monitor = _wait_and_go(OWN_NAMES, 0.5, "left", seed=0, rotation=2.0)
    trace = monitor.save_trace(tmp_path / "episode.jsonl")
    with pytest.raises(RenderError, match=r"^--frame 99: outside the episode, which runs from 0 s to "):
        render_trace(trace, xml, tmp_path / "late.png", frame_time=99.0)
    assert not (tmp_path / "late.png").exists()
    out = tmp_path / "frame.png"
    render_trace(trace, xml, out, frame_time=1.0)
    img = iio.imread(out)
    r, g, b = (img[..., i].astype(int) for i in range(3))
    panel = np.zeros(img.shape[:2], dtype=bool)
    panel[:180, :250] = True  # the posterior panel's corner, whose curves are coloured too
    red = (r > g + 80) & (r > b + 80) & ~panel
    blue = (b > r + 50) & (b > g + 30) & ~panel
    # Both boxes at least 40 px long: the follow view, not the 70 m top camera.
    for mask in (red, blue):
        rows, cols = np.nonzero(mask)
        assert len(rows) > 200 and max(np.ptp(rows), np.ptp(cols)) >= 40
