"""Vectorised line of sight (cdf_mj.model.occlusion) against MuJoCo rays and shapely."""

from __future__ import annotations

import statistics
import time

import mujoco
import numpy as np
import pytest
import shapely

from cdf_mj.model.geometry import box_corners
from cdf_mj.model.occlusion import Occluders, ego_visible, segments_hit_rectangle, sight_targets
from cdf_mj.sim import visibility
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene, SceneError

EGO_WEST = np.array([-30.0, -1.85, 0.0, 13.4])
DEEP = np.array([-1.85, 16.0, -np.pi / 2, 0.0])  # far back in the side road


@pytest.fixture(scope="module")
def occ(scene) -> Occluders:
    return scene.layout().occluders


def _seen(scene, obstacle_poses, ego_pose) -> np.ndarray:
    """:func:`ego_visible` with the scene layout's buildings and cars."""
    layout = scene.layout()
    return ego_visible(layout.occluders, layout.ego, layout.obstacle, obstacle_poses, ego_pose)


def _random_cases(rng, n):
    obstacle = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(4, 30, n),
                                -np.pi / 2 + rng.uniform(-0.5, 0.5, n), rng.uniform(0, 5, n)])
    ego = np.column_stack([rng.uniform(-80, 40, n), np.full(n, -1.85), np.zeros(n),
                           rng.uniform(5, 15, n)])
    return obstacle, ego


def _mujoco_answers(scene, obstacle, ego):
    out = np.empty(len(obstacle), dtype=bool)
    for i, (o, e) in enumerate(zip(obstacle, ego, strict=True)):
        scene.reset(ego=e, obstacle=o)
        scene.sync()
        out[i] = visibility.ego_visible(scene)
    return out


def test_reads_the_buildings(scene, occ):
    assert set(occ.names) == {"building_nw", "building_ne", "building_sw", "building_se"}
    i = occ.names.index("building_nw")
    np.testing.assert_allclose(occ.center[i], [-23.25, 18.75])
    np.testing.assert_allclose(occ.half[i], [16.75, 11.25])
    assert occ.heading[i] == pytest.approx(0.0, abs=1e-12)
    assert (occ.bottom[i], occ.top[i]) == pytest.approx((0.0, 12.0))
    assert np.all(occ.top > scene.layout().obstacle.eye_offset[2])  # all occlude at eye height


def test_agrees_with_mujoco_rays(scene, occ):
    """300 random obstacle poses in and around the side road, ego on the main road:
    the vectorised answer (per-particle ego poses, and one call per case with a shared
    ego pose) equals mj_multiRay's."""
    rng = np.random.default_rng(12345)
    obstacle, ego = _random_cases(rng, 300)
    expected = _mujoco_answers(scene, obstacle, ego)
    batch = _seen(scene, obstacle, ego)  # (N, 4) ego poses: per-particle targets
    single = np.array([_seen(scene, o, e)[0] for o, e in zip(obstacle, ego, strict=True)])
    assert batch.shape == (300,) and batch.dtype == bool
    assert 0.1 < expected.mean() < 0.9  # both outcomes well represented
    assert np.mean(batch == expected) >= 0.99
    assert np.array_equal(batch, single)


def test_occluded_and_clear_cases(scene, occ):
    assert not _seen(scene, DEEP, EGO_WEST)[0]
    assert _seen(scene, scene.layout().obstacle_start, EGO_WEST)[0]
    # Same answers as MuJoCo.
    assert list(_mujoco_answers(scene, np.stack([DEEP, scene.layout().obstacle_start]),
                                np.stack([EGO_WEST, EGO_WEST]))) == [False, True]


def test_shapes_and_broadcasting(scene, occ):
    rng = np.random.default_rng(1)
    obstacle, _ = _random_cases(rng, 1000)
    shared = _seen(scene, obstacle, EGO_WEST)
    assert shared.shape == (1000,) and shared.dtype == bool
    assert shared.any() and not shared.all()
    # Shared targets (K, 2) == the same targets per eye (N, K, 2); (K, 3) accepted.
    eyes = scene.layout().obstacle.eye(obstacle)
    targets = sight_targets(scene.layout().ego, EGO_WEST)
    corners = scene.layout().ego.footprint(EGO_WEST)
    np.testing.assert_array_equal(targets, np.vstack([corners, corners.mean(axis=0)]))
    assert np.array_equal(occ.visible(eyes, targets), shared)
    assert np.array_equal(occ.visible(eyes, np.broadcast_to(targets, (1000, 5, 2))), shared)
    assert np.array_equal(occ.visible(eyes, np.column_stack([targets, np.ones(5)])), shared)
    # (N, 2) eyes: all boxes count; the same here, as every building is taller than the eye.
    assert np.array_equal(occ.visible(eyes[:, :2], targets), shared)
    # N = 1, one target point, and a single pose.
    one = _seen(scene, obstacle[:1], EGO_WEST)
    assert one.shape == (1,) and one[0] == shared[0]
    assert _seen(scene, obstacle[0], EGO_WEST).shape == (1,)
    assert occ.visible(eyes[:1], targets[:1]).shape == (1,)
    # Degenerate sizes.
    assert occ.visible(eyes[:0], targets).shape == (0,)
    assert not occ.visible(eyes, targets[:0]).any()
    with pytest.raises(ValueError, match="eyes"):
        occ.visible(eyes[:, :1], targets)
    with pytest.raises(ValueError, match="targets"):
        occ.visible(eyes, np.zeros((999, 5, 2)))
    with pytest.raises(ValueError, match="targets"):
        occ.visible(eyes, np.zeros(2))


def test_segment_rectangle_primitive_matches_shapely():
    """A rotated rectangle against random segments, many of them crossing or ending
    inside it: the separating-axis test agrees with shapely (touching = meeting)."""
    rng = np.random.default_rng(7)
    center, heading, half = np.array([1.5, -2.0]), 0.6, np.array([3.0, 1.2])
    rect = shapely.Polygon(box_corners(center, heading, half))
    p0 = rng.uniform(-8, 10, (4000, 2))
    p1 = rng.uniform(-8, 10, (4000, 2))
    p1[:500] = p0[:500] + rng.normal(0, 0.5, (500, 2))  # short segments
    hit = segments_hit_rectangle(p0, p1, center, heading, half)
    lines = shapely.linestrings(np.stack([p0, p1], axis=1))
    assert np.array_equal(hit, shapely.intersects(lines, rect))
    assert 0.2 < hit.mean() < 0.8
    # The same rectangle as an Occluders box, eyes = p0, one target each = p1.
    occ = Occluders(names=("r",), center=center[None], heading=[heading], half=half[None],
                    bottom=[0.0], top=[5.0])
    assert np.array_equal(occ.visible(p0, p1[:, None, :]), ~hit)
    # Shared targets: several points, seen if any is.
    targets = rng.uniform(-8, 10, (3, 2))
    per_point = np.stack([segments_hit_rectangle(p0, t, center, heading, half) for t in targets])
    assert np.array_equal(occ.visible(p0, targets), (~per_point).any(axis=0))


def test_heights_no_boxes_and_culling():
    wall = Occluders(names=("low", "high"), center=[[0.0, 0.0], [0.0, 10.0]], heading=[0.0, 0.0],
                     half=[[1.0, 5.0], [1.0, 1.0]], bottom=[0.0, 3.0], top=[1.0, 6.0])
    eyes = np.array([[-5.0, 0.0, 1.2], [-5.0, 0.0, 0.5], [-5.0, 10.0, 4.0], [-5.0, 10.0, 1.2]])
    targets = np.array([[5.0, 0.0], [5.0, 1.0]])
    per_eye = np.array([[[5.0, 0.0]], [[5.0, 0.0]], [[5.0, 10.0]], [[5.0, 10.0]]])
    # The low wall is below an eye at 1.2 m, the high box spans only 3-6 m.
    expected = np.array([True, False, True, True])
    expected_per_eye = np.array([True, False, False, True])
    assert np.array_equal(wall.visible(eyes[:1], targets), expected[:1])  # one height
    assert np.array_equal(wall.visible(eyes, targets), expected)  # mixed heights
    assert np.array_equal(wall.visible(eyes, per_eye), expected_per_eye)
    assert not wall.visible(eyes[:, :2], per_eye[:, :, :]).any()  # no heights: all block
    assert not wall.visible(eyes[:1, :2], targets).any()
    none = Occluders(names=(), center=np.zeros((0, 2)), heading=[], half=np.zeros((0, 2)),
                     bottom=[], top=[])
    assert none.visible(eyes, targets).all()
    # Boxes every point lies beyond on one side are culled: the answer is unchanged.
    far = Occluders(names=("far",), center=[[0.0, 100.0]], heading=[0.3], half=[[5.0, 5.0]],
                    bottom=[0.0], top=[10.0])
    assert far.visible(eyes, targets).all()
    with pytest.raises(ValueError, match="names"):
        Occluders(names=("a", "b"), center=[[0.0, 0.0]], heading=[0.0], half=[[1.0, 1.0]],
                  bottom=[0.0], top=[1.0])


def _spec_scene(edit) -> Scene:
    spec = mujoco.MjSpec.from_file(str(DEFAULT_SCENE))
    edit(spec)
    return Scene(spec.compile(), source="<edited scene>")


def test_rotated_building_in_a_body_agrees_with_mujoco():
    """A box rotated 45 degrees inside a moved body, in the side road north of the
    junction: the layout places it from geom_xpos/xmat and the answers match rays."""
    def add(spec):
        body = spec.worldbody.add_body(name="block", pos=[0.0, 40.0, 0.0],
                                       quat=[np.cos(np.pi / 8), 0.0, 0.0, np.sin(np.pi / 8)])
        body.add_geom(name="building_rot", type=mujoco.mjtGeom.mjGEOM_BOX, size=[3.0, 1.0, 5.0],
                      pos=[1.0, 0.0, 5.0], group=1)
    scene = _spec_scene(add)
    occ = scene.layout().occluders
    i = occ.names.index("building_rot")
    np.testing.assert_allclose(occ.center[i], [np.sqrt(0.5), 40.0 + np.sqrt(0.5)], atol=1e-9)
    assert occ.heading[i] == pytest.approx(np.pi / 4)
    assert (occ.bottom[i], occ.top[i]) == pytest.approx((0.0, 10.0))
    rng = np.random.default_rng(3)
    n = 150
    obstacle = np.column_stack([rng.uniform(-6, 6, n), rng.uniform(46, 60, n),
                                -np.pi / 2 + rng.uniform(-0.4, 0.4, n), np.zeros(n)])
    ego = np.column_stack([rng.uniform(-6, 3, n), rng.uniform(31, 35, n),
                           rng.uniform(-0.3, 0.3, n), np.zeros(n)])
    expected = _mujoco_answers(scene, obstacle, ego)
    got = _seen(scene, obstacle, ego)
    assert 0.1 < expected.mean() < 0.9
    assert np.mean(got == expected) >= 0.99


@pytest.mark.parametrize(("edit", "match"), [
    (lambda s: setattr(s.geom("building_nw"), "type", mujoco.mjtGeom.mjGEOM_CYLINDER),
     "boxes: 'building_nw' is a cylinder"),
    (lambda s: setattr(s.geom("building_ne"), "quat", [np.cos(0.1), np.sin(0.1), 0.0, 0.0]),
     "upright.*building_ne"),
])
def test_rejects_buildings_that_are_not_upright_boxes(edit, match):
    """Such a shape has no rectangular footprint: the scene refuses it when it is built."""
    with pytest.raises(SceneError, match=match):
        _spec_scene(edit)


def test_fast_enough_for_the_filter(scene, occ):
    """N = 1000: a loose bound that only a per-particle Python loop would break
    (visible() measured ~55 us on the 2-core dev machine)."""
    rng = np.random.default_rng(0)
    obstacle, _ = _random_cases(rng, 1000)
    eyes = scene.layout().obstacle.eye(obstacle)
    targets = sight_targets(scene.layout().ego, EGO_WEST)
    times = []
    for _ in range(30):
        t0 = time.perf_counter()
        occ.visible(eyes, targets)
        times.append(time.perf_counter() - t0)
    assert statistics.median(times) < 2e-3
