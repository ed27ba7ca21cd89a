"""The varied test junctions of tests/junctions.py: each loads as a Scene, its layout is the
default's moved by the junction's placement, and episodes run on it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from junctions import Placement, build_junction, junction_scene, start_poses

from cdf_mj.config import ScenarioConfig, SceneNames
from cdf_mj.model.layout import Layout
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

OWN_NAMES = SceneNames(ego_prefix="av/", obstacle_prefix="other/", ego_start="av_home",
                       obstacle_start="other_home", stop_line="stop", ego_lane="av_lane",
                       conflict="crossing", commit="no_return", route_ego="av_path",
                       route_left="cross_path", route_right="away_path", building_prefix="house")

VARIANTS = {
    "rotated": {"rotation": 0.7},
    "rotated_far": {"rotation": -2.6, "center": (120.0, -35.0)},
    "mirrored": {"mirror": True},
    "mirrored_rotated": {"mirror": True, "rotation": 2.2},
    "own_names": {"names": OWN_NAMES, "rotation": 1.0},
    "no_buildings": {"buildings": False, "mirror": True},
}


def _placement(kw: dict) -> Placement:
    return Placement(kw.get("rotation", 0.0), kw.get("mirror", False), kw.get("center", (0.0, 0.0)))


def _assert_moved(layout: Layout, ref: Layout, place: Placement, atol: float = 1e-9) -> None:
    """``layout`` is ``ref`` moved by ``place`` (points, poses, boxes, routes), within ``atol`` [m]."""
    for name in ("conflict", "commit"):
        np.testing.assert_allclose(getattr(layout, name), place.point(getattr(ref, name)), atol=atol)
    for name in ("ego_start", "obstacle_start"):
        got, want = getattr(layout, name), place.pose(getattr(ref, name))
        np.testing.assert_allclose(got[:2], want[:2], atol=atol)
        assert math.remainder(got[2] - want[2], 2 * math.pi) == pytest.approx(0.0, abs=atol)
    for name in ("route_ego", "route_left", "route_right"):
        np.testing.assert_allclose(getattr(layout, name).points, place.point(getattr(ref, name).points),
                                   atol=atol)
    for name in ("ego_lane", "stop_line"):
        box, rbox = getattr(layout, name), getattr(ref, name)
        np.testing.assert_allclose(box.center, place.point(rbox.center), atol=atol)
        np.testing.assert_allclose(box.half, rbox.half, atol=1e-12)
        np.testing.assert_allclose(np.sort(box.corners(), axis=0),
                                   np.sort(place.point(rbox.corners()), axis=0), atol=atol)


def test_the_default_junction_is_models_xml(scene: Scene):
    """Unmoved, 3.7 m lanes: the layout of models/xml/scene.xml (the same junction, built in
    Python), buildings included."""
    ref, got = scene.layout(), junction_scene().layout()
    _assert_moved(got, ref, Placement(), atol=1e-3)  # the XML rounds arc waypoints to 1 mm
    np.testing.assert_allclose(got.occluders.center, ref.occluders.center, atol=1e-9)
    np.testing.assert_allclose(got.occluders.half, ref.occluders.half, atol=1e-9)
    np.testing.assert_allclose(got.occluders.top, ref.occluders.top, atol=1e-9)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_each_variant_is_the_default_moved(variant: str):
    kw = VARIANTS[variant]
    names = kw.get("names", SceneNames())
    moved = junction_scene(**kw)
    ref = junction_scene().layout()
    layout, place = moved.layout(), _placement(kw)
    _assert_moved(layout, ref, place)
    # What the drivers measure does not change: route lengths, where the conflict and
    # commit points lie on the routes, the cars' dimensions.
    for name in ("route_ego", "route_left", "route_right"):
        assert getattr(layout, name).length == pytest.approx(getattr(ref, name).length, abs=1e-9)
    for route in ("route_ego", "route_left"):
        s, lat = getattr(layout, route).project(layout.conflict)
        s0, lat0 = getattr(ref, route).project(ref.conflict)
        assert float(s) == pytest.approx(float(s0), abs=1e-9)
        assert abs(float(lat)) == pytest.approx(abs(float(lat0)), abs=1e-9)
    assert layout.ego.wheelbase == ref.ego.wheelbase
    assert len(layout.occluders.names) == (4 if kw.get("buildings", True) else 0)
    assert all(n.startswith(names.building_prefix) for n in layout.occluders.names)
    # The cars stand at their start poses, as add_car put them.
    mujoco_poses = moved.poses()
    np.testing.assert_allclose(mujoco_poses[:, :2], [layout.ego_start[:2], layout.obstacle_start[:2]],
                               atol=1e-9)


@pytest.mark.parametrize("mirror", [False, True])
def test_route_left_crosses_the_ego_lane_whatever_the_traffic_side(mirror: bool):
    """Mirrored (left-hand traffic) the crossing turn bends right in the world, yet the route
    named route_left is still the one that ends in the ego's lane in the ego's direction."""
    layout = junction_scene(mirror=mirror, rotation=0.4).layout()
    left, right = layout.route_left.points, layout.route_right.points
    assert layout.ego_lane.contains(left[-2:]).all()
    assert not layout.ego_lane.contains(right).any()
    d0, d1 = left[1] - left[0], left[-1] - left[-2]
    turn = math.atan2(d0[0] * d1[1] - d0[1] * d1[0], d0 @ d1)  # > 0: a left turn in the world
    assert turn == pytest.approx(-math.pi / 2 if mirror else math.pi / 2, abs=1e-6)
    ego_dir = layout.route_ego.points[-1] - layout.route_ego.points[0]
    assert d1 @ ego_dir > 0  # into the ego's lane in the ego's direction


def test_lane_width_moves_the_lanes_and_keeps_the_rules():
    for w in (3.2, 4.2):
        layout = junction_scene(lane_width=w).layout()
        assert layout.ego_lane.half[1] == pytest.approx(w / 2)
        assert layout.ego_start[1] == pytest.approx(-w / 2)
        # front bumper (3.65 m ahead of the rear axle) on the stop line, 1 m before the road
        assert layout.obstacle_start[1] - 3.65 == pytest.approx(w + 1.0)
        assert layout.stop_line.center[1] - layout.stop_line.half[1] == pytest.approx(w + 1.0)
    with pytest.raises(ValueError, match="do not fit"):
        build_junction(lane_width=2.0, left_radius=12.0)


def test_start_poses_match_the_scene():
    kw = {"rotation": -1.2, "mirror": True, "lane_width": 3.4, "center": (5.0, 7.0)}
    layout = junction_scene(**kw).layout()
    ego, obstacle = start_poses(**kw)
    np.testing.assert_allclose(ego, layout.ego_start, atol=1e-7)
    np.testing.assert_allclose(obstacle, layout.obstacle_start, atol=1e-7)


def test_episodes_run_the_same_on_a_moved_junction():
    """Moving the junction moves the episode: the same seeds give the same intents, labels
    and braking on the default and on a mirrored, rotated copy with other names."""
    cfg = ScenarioConfig()
    base = junction_scene()
    moved = junction_scene(mirror=True, rotation=2.2, names=OWN_NAMES)
    for seed in range(4):
        a = run_episode(cfg, seed=seed, planner="reactive", scene=base)
        b = run_episode(cfg, seed=seed, planner="reactive", scene=moved)
        assert (a.intent, a.label, a.collision) == (b.intent, b.label, b.collision)
        assert (a.brake_time is None) == (b.brake_time is None)
        if a.brake_time is not None:
            assert b.brake_time == pytest.approx(a.brake_time, abs=0.11)
