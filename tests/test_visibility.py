"""Line of sight with MuJoCo rays: buildings and cars occlude, the isovist polygon agrees."""

from __future__ import annotations

import numpy as np
import shapely

from cdf_mj.sim.visibility import ego_visible, isovist

EGO_WEST = np.array([-30.0, -1.85, 0.0, 13.4])  # on the main road, west of the junction


def _place(scene, ego, obstacle):
    scene.reset(ego=ego, obstacle=obstacle)
    scene.sync()


def _place_at_start(scene) -> np.ndarray:
    """Ego at EGO_WEST, obstacle on its start site; returns the obstacle driver's eye (3,) [m]."""
    layout = scene.layout()
    _place(scene, EGO_WEST, layout.obstacle_start)
    return layout.obstacle.eye(layout.obstacle_start)


def test_building_blocks_the_sight_line(scene):
    """From deep in the side road the north-west building hides the ego; from the stop
    line the driver sees it."""
    deep = np.array([-1.85, 16.0, -np.pi / 2, 0.0])
    _place(scene, EGO_WEST, deep)
    assert not ego_visible(scene)
    eye = scene.layout().obstacle.eye(deep)
    iso = isovist(scene, eye)
    ego_centre = scene.layout().ego.footprint(EGO_WEST).mean(axis=0)
    assert not iso.polygon.contains(shapely.Point(ego_centre))
    # The blocked ray hits the building.
    bearing = np.arctan2(ego_centre[1] - eye[1], ego_centre[0] - eye[0]) % (2 * np.pi)
    k = int(np.rint(bearing / (2 * np.pi / len(iso.angles)))) % len(iso.angles)
    assert scene.model.geom(int(iso.geomid[k])).name == "building_nw"

    eye = _place_at_start(scene)
    assert ego_visible(scene)
    iso = isovist(scene, eye)
    bearing = np.arctan2(ego_centre[1] - eye[1], ego_centre[0] - eye[0]) % (2 * np.pi)
    k = int(np.rint(bearing / (2 * np.pi / len(iso.angles)))) % len(iso.angles)
    assert scene.model.body_rootid[scene.model.geom_bodyid[iso.geomid[k]]] == scene.ego.body


def test_the_ego_itself_stops_rays(scene):
    """Rays end on the ego's hull: the isovist is shadowed behind it."""
    eye = _place_at_start(scene)
    iso = isovist(scene, eye, n_rays=720)
    hits = scene.model.body_rootid[scene.model.geom_bodyid[iso.geomid[iso.geomid >= 0]]]
    assert np.any(hits == scene.ego.body)
    centre = scene.layout().ego.footprint(EGO_WEST).mean(axis=0)
    behind = centre + 5.0 * (centre - eye[:2]) / 30.0
    assert not iso.contains(behind[None])[0]


def test_bearing_lookup_agrees_with_polygon(scene):
    iso = isovist(scene, _place_at_start(scene), n_rays=720)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-60, -30], [60, 40], size=(2000, 2))
    fast = iso.contains(pts)
    exact = shapely.contains_xy(iso.polygon, pts[:, 0], pts[:, 1])
    assert np.mean(fast == exact) > 0.98  # they differ only within half a ray of an edge


def test_looking_car_does_not_occlude_itself(scene):
    iso = isovist(scene, _place_at_start(scene))
    hit_roots = scene.model.body_rootid[scene.model.geom_bodyid[iso.geomid[iso.geomid >= 0]]]
    assert not np.any(hit_roots == scene.obstacle.body)
    assert np.all(iso.distances > 0.5)
