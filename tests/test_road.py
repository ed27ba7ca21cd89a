"""The road's words (cdf_mj/model/road.py) on hand-placed cars on the real junction: in the
lane by a corner or by overlap, ahead by the rear axle, the box centre or the boxes' extent
along the route, the heading a car is followed within, the gap, the IDM's two forms (bit for
bit the formulas they replaced), the RSS distance against the paper's formula, and car
following.

The scene's ego lane is the box y in [-3.7, 0] m along x (heading east, centre line
y = -1.85 m); our car's box reaches 3.65 m ahead of its rear axle and 0.95 m behind it,
0.9 m to each side.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from cdf_mj.config import Ego
from cdf_mj.model import road
from cdf_mj.model.road import (
    FOLLOW_HEADING,
    ahead,
    car_gap,
    follow_accel,
    heading_within,
    idm,
    in_lane,
    in_lane_ahead,
    route_arc,
    rss_distance,
)
from cdf_mj.model.vehicle import CarGeometry

LANE_Y = -1.85  # [m] the ego lane's centre line
FRONT, REAR, HALF_WIDTH = 1.35 + 2.3, 2.3 - 1.35, 0.9  # [m] our car's box from its rear axle


@pytest.fixture(scope="module")
def layout(scene):
    return scene.layout()


def _box(layout, pose):
    """Our car's collision box at a rear-axle pose ``[x, y, theta]``."""
    return layout.obstacle.footprint_one(*(float(v) for v in pose[:3]))


# ------------------------------------------------------------------------------ in the lane
def test_a_car_half_in_the_lane_is_in_it_both_ways(layout):
    box = _box(layout, [10.0, 0.0, 0.0])  # astride the centre line: y in [-0.9, 0.9]
    assert in_lane(layout, box, by="corner") and in_lane(layout, box, by="overlap")
    assert in_lane(layout, box)  # the boxes meeting is the one definition


def test_a_car_touching_the_lane_edge_is_in_it_both_ways_and_a_hair_off_in_neither(layout):
    touching = _box(layout, [10.0, HALF_WIDTH, 0.0])  # its right side on the lane's edge, y = 0
    assert min(y for _, y in touching) == 0.0
    assert in_lane(layout, touching, by="corner") and in_lane(layout, touching, by="overlap")
    off = _box(layout, [10.0, HALF_WIDTH + 1e-9, 0.0])
    assert not in_lane(layout, off, by="corner") and not in_lane(layout, off, by="overlap")


def test_a_crossing_car_longer_than_the_lane_is_wide_is_in_it_only_by_overlap(layout):
    # Heading south, its box centred on the centre line: it spans y in [-4.15, 0.45], past
    # both edges of the 3.7 m lane, with no corner inside it.
    box = _box(layout, [5.0, LANE_Y + 1.35, -math.pi / 2])
    assert not in_lane(layout, box, by="corner")  # the reading of 0.3 missed it
    assert in_lane(layout, box, by="overlap") and in_lane(layout, box)


def test_a_corner_in_the_lane_always_means_the_boxes_overlap(layout):
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(-20, 20, 400), rng.uniform(-8, 5, 400), rng.uniform(-math.pi, math.pi, 400)])
    answers = [(in_lane(layout, _box(layout, p), by="corner"), in_lane(layout, _box(layout, p), by="overlap"))
               for p in poses]
    assert all(overlap for corner, overlap in answers if corner)
    assert any(corner for corner, _ in answers) and any(overlap and not corner for corner, overlap in answers)


def test_in_lane_refuses_an_unknown_test(layout):
    with pytest.raises(ValueError, match="by='touch' must be 'corner' or 'overlap'"):
        in_lane(layout, _box(layout, [0.0, LANE_Y, 0.0]), by="touch")  # type: ignore[arg-type]


# ------------------------------------------------------------------------------ ahead
def test_route_arc_of_the_rear_axle_and_of_the_box_centre(layout):
    start = float(layout.route_ego.points[0, 0])  # the ego's route runs east along the centre line
    pose = [12.0, LANE_Y, 0.0, 5.0]
    assert route_arc(layout, pose) == pytest.approx(12.0 - start, abs=1e-12)
    assert route_arc(layout, pose, layout.ego) == pytest.approx(12.0 + 1.35 - start, abs=1e-12)


def test_ahead_by_rear_axle_and_by_box_centre_disagree_for_cars_of_different_lengths(layout):
    ours = layout.ego
    van = dataclasses.replace(ours, wheelbase=3.5, hull_offset=np.array([2.9, 0.0]), hull_half=np.array([3.4, 1.0]))
    ego = [11.0, LANE_Y, 0.0, 10.0]
    level_van = [10.0, -LANE_Y, 0.0, 10.0]  # in the next lane, its rear axle 1 m behind the ego's
    assert not ahead(layout, level_van, van, ego, ours, by="axle")
    assert ahead(layout, level_van, van, ego, ours, by="centre")  # its centre is 0.55 m ahead of the ego's
    # Cars of one size agree (both points move by the same offset), and neither asks for the lane.
    ours_level = [12.0, -LANE_Y, 0.0, 10.0]
    assert ahead(layout, ours_level, ours, ego, ours, by="axle") and ahead(layout, ours_level, ours, ego, ours,
                                                                          by="centre")
    assert ahead(layout, level_van, van, ego, ours)  # the box centres are the one definition
    assert ahead(layout, ours_level, ours, ego, None, by="axle")  # the reading of 0.3 needs no follower car
    with pytest.raises(ValueError, match="by='centre' needs follower_car"):
        ahead(layout, level_van, van, ego, None)


def test_ahead_by_extent_counts_a_car_level_with_the_ego_or_reaching_its_tail(layout):
    """The reactive planner's ahead: the lead's front-most corner at or past the follower's
    rearmost, along the route; true wherever ``by="axle"`` is on the straight lane, and
    also for a car level with the ego or overlapping its length from behind."""
    ours = layout.ego
    ego = [11.0, LANE_Y, 0.0, 10.0]  # its box from x = 10.05 to 14.65
    cases = {  # name: (pose, by axle, by extent)
        "well ahead": ([20.0, LANE_Y, 0.0, 8.0], True, True),
        "level, next lane": ([11.0, -LANE_Y, 0.0, 8.0], False, True),  # the same arc: not further by axle
        "overlapping from behind": ([8.0, -LANE_Y, 0.0, 8.0], False, True),  # its front at x = 11.65
        "reversed, level": ([11.5, -LANE_Y, math.pi, 8.0], True, True),  # its rear bumper leads: x = 12.45
        "reversed, behind": ([10.5, -LANE_Y, math.pi, 8.0], False, True),  # front-most corner x = 11.45
        "just behind the tail": ([10.05 - FRONT - 0.01, LANE_Y, 0.0, 8.0], False, False),  # front at 10.04
    }
    for name, (pose, by_axle, by_extent) in cases.items():
        assert ahead(layout, pose, ours, ego, ours, by="axle") is by_axle, name
        assert ahead(layout, pose, ours, ego, ours, by="extent") is by_extent, name
    same = [11.0, LANE_Y, 0.0, 10.0]  # the boundary counts: a car is ahead of its own tail
    assert ahead(layout, same, ours, ego, ours, by="extent") and not ahead(layout, same, ours, ego, ours)
    with pytest.raises(ValueError, match="by='extent' needs follower_car"):
        ahead(layout, same, ours, ego, None, by="extent")
    with pytest.raises(ValueError, match="must be 'axle', 'centre' or 'extent'"):
        ahead(layout, same, ours, ego, ours, by="front")  # type: ignore[arg-type]


def test_ahead_by_extent_is_the_reactive_planners_old_test_bit_for_bit(layout):
    """The formula ReactivePlanner computed itself before it asked here, on random poses."""
    rng = np.random.default_rng(34)
    route = layout.route_ego
    for _ in range(300):
        ego = [float(rng.uniform(-20.0, 30.0)), float(rng.uniform(-6.0, 2.0)), float(rng.uniform(-0.5, 0.5)), 5.0]
        obs = [float(rng.uniform(-20.0, 30.0)), float(rng.uniform(-6.0, 6.0)), float(rng.uniform(-math.pi, math.pi)),
               5.0]
        front = max(route.project_point(float(x), float(y))[0] for x, y in layout.obstacle.footprint_one(*obs[:3]))
        tail = min(route.project_point(float(x), float(y))[0] for x, y in layout.ego.footprint_one(*ego[:3]))
        assert ahead(layout, obs, layout.obstacle, ego, layout.ego, by="extent") is (front >= tail)


def test_heading_within_the_following_heading(layout):
    assert math.degrees(FOLLOW_HEADING) == pytest.approx(30.0)
    assert heading_within(0.3, 0.3 + math.radians(29.0)) and heading_within(0.3 + math.radians(29.0), 0.3)
    assert not heading_within(0.0, math.radians(31.0))
    assert heading_within(0.0, math.radians(89.0), math.pi / 2) and not heading_within(0.0, math.pi, math.pi / 2)


def test_in_lane_ahead_with_and_without_the_heading_check(layout):
    car, ours = layout.obstacle, layout.ego
    ego = [0.0, LANE_Y, 0.0, 10.0]
    merged = [20.0, LANE_Y, 0.0, 8.0]
    turning = [20.0, LANE_Y, math.radians(60.0), 8.0]  # still turning into the lane
    assert in_lane_ahead(layout, merged, car, ego, ours)
    assert in_lane_ahead(layout, merged, car, ego, ours, within=FOLLOW_HEADING)
    assert in_lane_ahead(layout, turning, car, ego, ours)  # the episode's end waits for it
    assert not in_lane_ahead(layout, turning, car, ego, ours, within=FOLLOW_HEADING)  # not yet followed
    assert in_lane_ahead(layout, turning, car, ego, ours, within=math.pi / 2)  # the layered rule's follow layer
    assert not in_lane_ahead(layout, [20.0, -LANE_Y, 0.0, 8.0], car, ego, ours)  # the other lane
    assert not in_lane_ahead(layout, [-20.0, LANE_Y, 0.0, 8.0], car, ego, ours)  # behind
    # A crossing car straddling the lane: in it and ahead (box meets lane, centres compared),
    # which the reading of 0.3 (a corner inside, rear axles) missed.
    crossing = [5.0, LANE_Y + 1.35, -math.pi / 2, 5.0]
    assert in_lane_ahead(layout, crossing, car, ego, ours)
    assert not in_lane_ahead(layout, crossing, car, ego, None, lane="corner", by="axle")


# ------------------------------------------------------------------------------ gap
def test_car_gap_is_bumper_to_bumper(layout):
    ego = [-30.0, LANE_Y, 0.0, 13.4]
    lead = [-30.0 + FRONT + 7.5 + REAR, LANE_Y, 0.0, 8.0]
    assert car_gap(layout.ego, ego, layout.obstacle, lead) == pytest.approx(7.5, abs=1e-9)
    assert car_gap(layout.obstacle, lead, layout.ego, ego) == pytest.approx(7.5, abs=1e-9)
    assert car_gap(layout.ego, ego, layout.obstacle, [-28.0, LANE_Y, 0.0, 0.0]) == 0.0  # overlapping


# ------------------------------------------------------------------------------ IDM
def _interaction_before(gap, v, v_lead, a_max, b, time_gap, min_gap, max_brake):
    """``cdf_mj.model.following.idm_interaction`` as it was written (car following)."""
    desired = min_gap + max(v, 0.0) * time_gap + v * (v - v_lead) / (2.0 * math.sqrt(a_max * b))
    return max(a_max * (1.0 - (max(desired, 0.0) / max(gap, 1e-3)) ** 2), -max_brake)


def _drivers_before(v, v0, a, b, gap=math.inf, v_lead=0.0):
    """``cdf_mj.scenario.drivers.idm_accel`` as it was written (the driver families)."""
    acc = 1.0 - (max(v, 0.0) / max(v0, 1e-6)) ** 4.0
    if math.isfinite(gap):
        s_star = 1.0 + max(0.0, v * 1.0 + v * (v - v_lead) / (2.0 * math.sqrt(a * b)))
        acc -= (s_star / max(gap, 0.05)) ** 2
    return a * acc


def test_the_idm_forms_equal_the_formulas_they_replaced_bit_for_bit():
    rng = np.random.default_rng(7)
    for _ in range(3000):
        v, v_lead, v0 = rng.uniform(-1.0, 20.0), rng.uniform(-5.0, 20.0), rng.uniform(0.0, 15.0)
        gap = float(rng.choice([rng.uniform(-1.0, 60.0), rng.uniform(0.0, 0.06), 0.0, math.inf]))
        a_max, b = rng.uniform(0.5, 4.0), rng.uniform(0.5, 4.0)
        time_gap, min_gap, max_brake = rng.uniform(0.1, 3.0), rng.uniform(0.0, 4.0), rng.uniform(0.5, 8.0)
        following = idm(v, v_lead, gap, a_max=a_max, b=b, time_gap=time_gap, min_gap=min_gap, s_star="total",
                        gap_floor=1e-3, max_brake=max_brake)
        assert following == _interaction_before(gap, v, v_lead, a_max, b, time_gap, min_gap, max_brake)
        family = idm(v, v_lead, gap, a_max=a_max, b=b, time_gap=1.0, min_gap=1.0, v0=v0, s_star="dynamic",
                     gap_floor=0.05)
        assert family == _drivers_before(v, v0, a_max, b, gap, v_lead)


def test_the_idm_at_its_fixed_points():
    common = {"a_max": 2.0, "b": 2.0, "time_gap": 1.5, "min_gap": 2.0, "gap_floor": 1e-3}
    # At the desired gap behind a car at the same speed, the interaction term is zero.
    assert idm(10.0, 10.0, 2.0 + 10.0 * 1.5, s_star="total", **common) == pytest.approx(0.0, abs=1e-12)
    # Free road: the interaction term alone is the full acceleration; the full IDM's is zero at v0.
    assert idm(10.0, 0.0, math.inf, s_star="total", **common) == 2.0
    assert idm(10.0, 0.0, math.inf, v0=10.0, s_star="dynamic", **common) == 0.0
    # Closing fast on a near car: clamped at -max_brake when asked, unclamped otherwise.
    assert idm(15.0, 0.0, 3.0, s_star="total", max_brake=4.0, **common) == -4.0
    assert idm(15.0, 0.0, 3.0, s_star="total", **common) < -100.0
    # The two desired gaps differ when the car ahead is much faster: "total" may fall below s0.
    fast = {"v": 5.0, "v_lead": 25.0, "gap": 1.5}
    assert idm(**fast, s_star="total", **common) > 0.0 > idm(**fast, s_star="dynamic", **common)
    with pytest.raises(ValueError, match="s_star='both' must be 'total' or 'dynamic'"):
        idm(1.0, 0.0, 5.0, s_star="both", **common)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------ RSS
def test_rss_distance_is_the_papers_formula():
    # Shalev-Shwartz, Shammah, Shashua (2017), Definition 1:
    # d_min = [v_r rho + a rho^2 / 2 + (v_r + rho a)^2 / (2 b_min) - v_f^2 / (2 b_max)]^+
    v_r, v_f, rho, a, b_min, b_max = 13.4, 8.0, 0.3, 3.0, 4.0, 8.0
    paper = v_r * rho + a * rho * rho / 2 + (v_r + rho * a) ** 2 / (2 * b_min) - v_f * v_f / (2 * b_max)
    assert rss_distance(v_r, v_f, rho, a, b_min, b_max) == pytest.approx(paper, rel=1e-12)
    assert paper == pytest.approx(4.02 + 0.135 + 14.3**2 / 8 - 4.0, rel=1e-12)  # 25.71625 m
    assert rss_distance(0.0, 20.0, rho, a, b_min, b_max) == 0.0  # [.]^+
    assert rss_distance(v_r, -3.0, rho, a, b_min, b_max) == rss_distance(v_r, 0.0, rho, a, b_min, b_max)
    assert rss_distance(-2.0, 0.0, rho, a, b_min, b_max) == rss_distance(0.0, 0.0, rho, a, b_min, b_max)


# ------------------------------------------------------------------------------ following
def test_follow_accel_is_the_idm_behind_a_merged_car_in_the_lane(layout):
    params = Ego()
    car = CarGeometry.ours()
    ego = np.array([-30.0, LANE_Y, 0.0, 13.4])
    lead = np.array([-30.0 + FRONT + 12.0 + REAR, LANE_Y, 0.1, 8.0])
    want = idm(13.4, 8.0 * math.cos(0.1), car_gap(car, ego, car, lead), a_max=car.max_accel, b=params.comfort_brake,
               time_gap=params.time_gap, min_gap=params.min_gap, s_star="total", gap_floor=1e-3,
               max_brake=car.max_brake)
    assert follow_accel(layout, car, ego, car, lead, params) == want < 0.0
    assert follow_accel(layout, car, ego, car, lead, params, max_brake=1.0) == max(want, -1.0) == -1.0
    turning = lead.copy()
    turning[2] = math.radians(45.0)
    assert follow_accel(layout, car, ego, car, turning, params) is None  # not merged: the planner's conflict
    missed = lead.copy()
    missed[:] = np.nan
    assert follow_accel(layout, car, ego, car, missed, params) is None  # a missed measurement
    assert follow_accel(layout, car, lead, car, ego, params) is None  # the car behind is not followed


def test_the_module_exports_one_rss_distance():
    assert road.rss_distance is rss_distance
    assert set(road.__all__) >= {"in_lane", "in_lane_ahead", "ahead", "car_gap", "idm", "rss_distance",
                                 "follow_accel", "FOLLOW_HEADING"}
