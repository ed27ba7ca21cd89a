"""cdf_mj.viz.overlays: geoms added to a real MjvScene (no OpenGL needed to build one)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from cdf_mj.sim.visibility import isovist
from cdf_mj.viz.overlays import (
    OVERLAY_COLORS,
    PARTICLE_COLORS,
    draw_belief,
    draw_braking,
    draw_isovist,
    draw_particles,
)


def _geoms(scn: mujoco.MjvScene) -> list:
    return [scn.geoms[i] for i in range(scn.ngeom)]


def test_particles_heaviest_first_coloured_by_intent_and_belief(scene) -> None:
    xy = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0], [9.0, 10.0]], dtype=np.float32)
    code = np.array([0, 1, 2, 3, 0], dtype=np.uint8)  # 2 * intent + seen
    snapshot = (xy, code, np.full(5, 0.2, dtype=np.float32))
    scn = mujoco.MjvScene(scene.model, maxgeom=10)
    draw_particles(scn, snapshot, z=2.0, limit=4)
    geoms = _geoms(scn)
    assert len(geoms) == 4  # the limit
    names = [("left", False), ("left", True), ("right", False), ("right", True)]
    for g, (x, y), name in zip(geoms, xy[:4], names, strict=True):
        np.testing.assert_allclose(g.pos, [x, y, 2.0], atol=1e-6)
        np.testing.assert_allclose(g.rgba, PARTICLE_COLORS[name], atol=1e-6)
        assert g.type == mujoco.mjtGeom.mjGEOM_BOX and g.category == mujoco.mjtCatBit.mjCAT_DECOR
    full = mujoco.MjvScene(scene.model, maxgeom=2)
    draw_particles(full, snapshot, z=2.0, limit=100)
    assert full.ngeom == 2  # a full scene takes what fits, quietly


def test_isovist_is_a_fan_reaching_every_corner(scene) -> None:
    layout = scene.layout()
    scene.reset(ego=layout.ego_start, obstacle=layout.obstacle_start)
    iso = isovist(scene, layout.obstacle.eye(layout.obstacle_start))
    corners = np.asarray(iso.polygon.simplify(0.1).exterior.coords)[:-1]
    scn = mujoco.MjvScene(scene.model, maxgeom=500)
    draw_isovist(scn, iso, z=0.05)
    geoms = _geoms(scn)
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
