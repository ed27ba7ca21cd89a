"""cdf_mj.viz.overlays: geoms added to a real MjvScene (no OpenGL needed to build one)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from cdf_mj.model.geometry import OrientedBox
from cdf_mj.sim.visibility import isovist
from cdf_mj.viz.overlays import (
    OVERLAY_COLORS,
    PARTICLE_COLORS,
    TICK_FRACTION,
    draw_belief,
    draw_braking,
    draw_isovist,
    draw_particles,
    lane_half_width,
    view_height_at,
)
from cdf_mj.viz.replay import Particles


def _geoms(scn: mujoco.MjvScene) -> list:
    return [scn.geoms[i] for i in range(scn.ngeom)]


def _top_view(scene, height: float = 40.0) -> mujoco.MjvScene:
    """A scene of the model seen from ``height`` [m] straight above the origin."""
    scn = mujoco.MjvScene(scene.model, maxgeom=200)
    cam = mujoco.MjvCamera()
    cam.type, cam.distance, cam.elevation, cam.azimuth = mujoco.mjtCamera.mjCAMERA_FREE, height, -90.0, 90.0
    cam.lookat[:] = 0.0
    mujoco.mjv_updateScene(scene.model, scene.data, mujoco.MjvOption(), mujoco.MjvPerturb(), cam,
                           mujoco.mjtCatBit.mjCAT_ALL, scn)
    scn.ngeom = 0  # only what is drawn below
    return scn


def test_particles_are_heading_ticks_heaviest_first_coloured_by_intent_and_belief(scene) -> None:
    xy = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0], [9.0, 10.0]], dtype=np.float32)
    code = np.array([0, 1, 2, 3, 0], dtype=np.uint8)  # 2 * intent + seen
    heading = np.array([0.0, math.pi / 2, -math.pi / 2, math.pi, 1.0], dtype=np.float32)
    snapshot = Particles(xy, code, np.full(5, 0.2, dtype=np.float32), heading)
    scn = _top_view(scene)
    draw_particles(scn, snapshot, z=2.0, limit=4)
    geoms = _geoms(scn)
    assert len(geoms) == 4  # the limit
    length = TICK_FRACTION * view_height_at(scn, [4.0, 5.0, 2.0])
    assert 1.0 < length < 3.0  # [m] 3.5 % of a 33 m tall view
    names = [("left", False), ("left", True), ("right", False), ("right", True)]
    for g, (x, y), th, name in zip(geoms, xy[:4], heading[:4], names, strict=True):
        assert g.type == mujoco.mjtGeom.mjGEOM_LINE and g.category == mujoco.mjtCatBit.mjCAT_DECOR
        np.testing.assert_allclose(g.rgba, PARTICLE_COLORS[name], atol=1e-6)
        # A line from the particle along its heading (the geom's z axis), one tick long.
        axis = np.asarray(g.mat).reshape(3, 3)[:, 2]
        np.testing.assert_allclose(g.pos, [x, y, 2.0], atol=1e-5)  # it starts at the particle
        np.testing.assert_allclose(axis, [math.cos(th), math.sin(th), 0.0], atol=1e-6)
        assert g.size[2] == pytest.approx(length, rel=0.02)
    fixed = _top_view(scene)
    draw_particles(fixed, snapshot, z=2.0, limit=1, length=0.5)
    assert _geoms(fixed)[0].size[2] == pytest.approx(0.5)
    full = mujoco.MjvScene(scene.model, maxgeom=2)
    with pytest.raises(ValueError, match=r"no camera yet: call mujoco\.mjv_updateScene"):
        draw_particles(full, snapshot, z=2.0, limit=100)  # no view to size the ticks for
    draw_particles(full, snapshot, z=2.0, limit=100, length=1.0)
    assert full.ngeom == 2  # a full scene takes what fits, quietly
    squares = mujoco.MjvScene(scene.model, maxgeom=10)
    draw_particles(squares, snapshot[:3], z=2.0, limit=2)  # no headings: squares, as before
    assert [g.type for g in _geoms(squares)] == [mujoco.mjtGeom.mjGEOM_BOX] * 2


def test_isovist_is_a_fan_reaching_every_corner(scene) -> None:
    layout = scene.layout()
    scene.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)
    iso = isovist(scene, layout.obstacle.eye(layout.obstacle_start))
    corners = np.asarray(iso.polygon.simplify(0.1).exterior.coords)[:-1]
    scn = mujoco.MjvScene(scene.model, maxgeom=500)
    draw_isovist(scn, iso, z=0.05)
    fill = [g for g in _geoms(scn) if g.type == mujoco.mjtGeom.mjGEOM_TRIANGLE]
    outline = [g for g in _geoms(scn) if g.type == mujoco.mjtGeom.mjGEOM_LINE]
    assert len(fill) + len(outline) == scn.ngeom and len(outline) == len(corners)
    for g in outline:  # the boundary, just above the fill
        np.testing.assert_allclose(g.rgba, OVERLAY_COLORS["isovist_edge"], atol=1e-6)
        assert g.pos[2] == pytest.approx(0.07)
        axis = np.asarray(g.mat).reshape(3, 3)[:, 2]
        ends = np.stack([g.pos[:2], g.pos[:2] + g.size[2] * axis[:2]])
        assert np.hypot(*(ends[:, None, :] - corners[None]).transpose(2, 0, 1)).min(axis=1).max() < 1e-4
    bare = mujoco.MjvScene(scene.model, maxgeom=500)
    draw_isovist(bare, iso, z=0.05, outline=False)
    assert bare.ngeom == len(fill)
    geoms = fill
    assert 3 <= len(geoms) <= len(corners)  # far fewer triangles than the 360 rays
    reached = []
    for g in geoms:
        assert g.type == mujoco.mjtGeom.mjGEOM_TRIANGLE and g.pos[2] == pytest.approx(0.05)
        np.testing.assert_allclose(g.rgba, OVERLAY_COLORS["isovist"], atol=1e-6)
        np.testing.assert_allclose(g.pos[:2], iso.origin[:2])
        mat = np.asarray(g.mat).reshape(3, 3)
        reached.append(g.pos[:2] + g.size[0] * mat[:2, 0])  # the triangle's first far corner
    dist = np.hypot(*(np.asarray(reached)[:, None, :] - corners[None]).transpose(2, 0, 1))
    assert np.all(dist.min(axis=1) < 1e-4)  # every triangle ends on the isovist's boundary


def test_belief_box_is_the_ego_hull_at_the_believed_pose(scene) -> None:
    ego = scene.layout().ego
    pose = np.array([10.0, -3.0, math.pi / 2, 5.0])
    scn = mujoco.MjvScene(scene.model, maxgeom=4)
    draw_belief(scn, ego, pose)
    (g,) = _geoms(scn)
    centre = ego.footprint(pose).mean(axis=0)
    np.testing.assert_allclose(g.pos, [*centre, ego.hull_height / 2], atol=1e-6)
    np.testing.assert_allclose(g.size, [*ego.hull_half, ego.hull_height / 2], atol=1e-6)
    assert g.type == mujoco.mjtGeom.mjGEOM_LINEBOX


def test_braking_stripe_at_the_front_and_a_beacon_over_the_ego(scene) -> None:
    layout = scene.layout()
    ego = layout.ego
    brake_pose = np.array([0.0, 0.0, 0.0, 10.0])
    now = np.array([6.0, 0.0, 0.0, 4.0])
    scn = mujoco.MjvScene(scene.model, maxgeom=4)
    draw_braking(scn, ego, float(layout.ego_lane.half[1]), brake_pose, now, z=3.0)
    stripe, beacon = _geoms(scn)
    assert stripe.pos[0] == pytest.approx(ego.hull_offset[0] + ego.hull_half[0])
    assert stripe.size[1] == pytest.approx(layout.ego_lane.half[1])  # across the whole lane
    np.testing.assert_allclose(beacon.pos, [6.0 + ego.hull_offset[0], 0.0, 3.0], atol=1e-6)
    for g in (stripe, beacon):
        np.testing.assert_allclose(g.rgba, OVERLAY_COLORS["brake"], atol=1e-6)


@pytest.mark.parametrize("lane", [OrientedBox(np.array([5.0, 0.0]), 0.0, np.array([1.85, 150.0])),
                                  OrientedBox(np.array([5.0, 0.0]), math.pi / 2, np.array([150.0, 1.85])),
                                  OrientedBox(np.array([5.0, 0.0]), -math.pi / 2, np.array([150.0, 1.85]))])
def test_braking_stripe_spans_a_north_south_lane_whichever_axis_the_box_runs_along(scene, lane) -> None:
    """A lane box along its local y (a user's north-south road) used to give a 300 m stripe."""
    ego = scene.layout().ego
    brake_pose = np.array([5.6, -20.0, math.pi / 2, 10.0])  # driving north, 0.6 m right of centre
    assert lane_half_width(lane, brake_pose[2]) == pytest.approx(1.85)
    scn = mujoco.MjvScene(scene.model, maxgeom=4)
    draw_braking(scn, ego, lane, brake_pose, brake_pose, z=3.0)
    stripe, _ = _geoms(scn)
    assert stripe.size[1] == pytest.approx(1.85)  # across the lane, not along it
    front = ego.hull_offset[0] + ego.hull_half[0]
    np.testing.assert_allclose(stripe.pos[:2], [5.0, -20.0 + front], atol=1e-9)  # on the lane's centre
    across = np.asarray(stripe.mat).reshape(3, 3)[:2, 1]  # the stripe's long (local y) axis
    assert abs(across[0]) == pytest.approx(1.0)  # east-west, across a northbound lane
