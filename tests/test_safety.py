"""Safety and comfort metrics: hand-built situations on the real junction whose answers are
known in closed form, and one real episode read by the recorder."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cdf_mj.analysis import safety
from cdf_mj.analysis.safety import (
    SafetyMetrics,
    SafetyParams,
    SafetyRecorder,
    closing_speed,
    safety_summary,
)
from cdf_mj.config import ScenarioConfig
from cdf_mj.model import road
from cdf_mj.scenario.episode import run_episode

LANE_Y = -1.85  # [m] the ego lane's centre line in scene.xml (heading east)
FRONT = 1.35 + 2.3  # [m] our car's front bumper ahead of its rear axle
REAR = 2.3 - 1.35  # [m] its rear bumper behind its rear axle
FAR = [-1.85, 30.0, -math.pi / 2, 0.0]  # an obstacle up the side road, far from everything


@pytest.fixture(scope="module")
def layout(scene):
    return scene.layout()


def _ticks(rec: SafetyRecorder, poses: list, braking: list[bool] | None = None, dt: float = 0.1) -> SafetyMetrics:
    """Feed ``rec`` one tick per system pose, ``dt`` apart, and return its metrics."""
    braking = braking or [False] * len(poses)
    for k, (pose, brake) in enumerate(zip(poses, braking, strict=True)):
        rec.observe(round(k * dt, 6), np.array(pose, dtype=float), brake)
    return rec.result()


def _behind(gap: float, v_ego: float, v_lead: float) -> list[list[float]]:
    """The ego at x = -30 m in its lane and a car ahead in it ``gap`` [m] from bumper to bumper."""
    x = -30.0
    return [[x, LANE_Y, 0.0, v_ego], [x + FRONT + gap + REAR, LANE_Y, 0.0, v_lead]]


def test_following_a_slower_car_gives_ttc_headway_and_gap(layout):
    m = _ticks(SafetyRecorder(layout=layout), [_behind(10.0, 13.4, 8.0)])
    assert m.min_gap == pytest.approx(10.0, abs=1e-9)
    assert m.min_ttc == pytest.approx(10.0 / 5.4, rel=1e-6)
    assert m.min_headway == pytest.approx(10.0 / 13.4, rel=1e-9)
    assert m.following_ticks == 1
    assert closing_speed(layout, np.array(_behind(10.0, 13.4, 8.0))) == pytest.approx(5.4, rel=1e-6)
    # A faster car ahead is not closing: no time to collision, still a headway.
    m = _ticks(SafetyRecorder(layout=layout), [_behind(10.0, 8.0, 13.4)])
    assert m.min_ttc is None and m.min_headway == pytest.approx(10.0 / 8.0)


def test_closing_speed_of_a_crossing_car_is_along_the_closest_points(layout):
    # The obstacle crosses the lane southwards at 5 m/s, its west side 6 m ahead of the ego's
    # bumper: the closest points face each other along x, so only the ego's 10 m/s closes.
    ox = FRONT + 6.0 + 0.9
    poses = [[0.0, LANE_Y, 0.0, 10.0], [ox, LANE_Y + 1.35, -math.pi / 2, 5.0]]
    assert closing_speed(layout, np.array(poses)) == pytest.approx(10.0, rel=1e-6)
    m = _ticks(SafetyRecorder(layout=layout), [poses])
    # Its box spans the lane with no corner inside it: still in the lane, and ahead.
    assert m.min_ttc == pytest.approx(0.6, rel=1e-6) and m.following_ticks == 1


def test_only_a_car_ahead_in_the_ego_lane_is_followed(layout):
    behind = [[0.0, LANE_Y, 0.0, 13.4], [-15.0, LANE_Y, 0.0, 8.0]]
    other_lane = [[0.0, LANE_Y, 0.0, 13.4], [15.0, -LANE_Y, 0.0, 8.0]]
    waiting = [[-12.0, LANE_Y, 0.0, 13.4], [-1.85, 8.35, -math.pi / 2, 0.0]]  # at its stop line
    for poses in (behind, other_lane, waiting):
        m = _ticks(SafetyRecorder(layout=layout), [poses])
        assert m.following_ticks == 0 and m.min_headway is None and m.rss_share is None
    # Not in the lane: a car waiting at its stop line beside the road has no time to collision.
    assert _ticks(SafetyRecorder(layout=layout), [waiting]).min_ttc is None


def test_rss_distance_against_a_hand_computation():
    p = SafetyParams()
    b = 16 * 0.3048
    hand = 13.4 * 0.2 + 0.5 * 3.0 * 0.2**2 + (13.4 + 0.2 * 3.0) ** 2 / (2 * b) - 8.0**2 / (2 * b)
    assert p.rss_distance(13.4, 8.0) == pytest.approx(hand, rel=1e-12)
    assert hand == pytest.approx(16.2735, abs=1e-4)
    assert p.rss_distance(0.0, 13.4) == 0.0  # [.]^+: a fast car ahead needs no distance
    assert p.rss_distance(13.4, -5.0) == p.rss_distance(13.4, 0.0)  # a car coming back counts as standing
    q = SafetyParams(rho=0.5, a_acc=0.0, b_min=4.0, b_max=8.0)
    assert q.rss_distance(10.0, 10.0) == pytest.approx(5.0 + 100 / 8 - 100 / 16)
    assert q.rss_distance(10.0, 10.0) == road.rss_distance(10.0, 10.0, 0.5, 0.0, 4.0, 8.0)  # the road's, bit for bit


def test_the_module_rss_distance_is_deprecated_for_the_params_method():
    with pytest.warns(DeprecationWarning, match=r"params\.rss_distance\(v_r, v_f\)"):
        from cdf_mj.analysis.safety import rss_distance
    assert rss_distance(13.4, 8.0, SafetyParams()) == SafetyParams().rss_distance(13.4, 8.0)
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        _ = safety.nothing


def test_rss_share_counts_following_ticks_closer_than_the_safe_distance(layout):
    d = SafetyParams().rss_distance(13.4, 8.0)
    m = _ticks(SafetyRecorder(layout=layout), [_behind(d - 1.0, 13.4, 8.0), _behind(d + 1.0, 13.4, 8.0)])
    assert (m.following_ticks, m.rss_ticks, m.rss_share) == (2, 1, 0.5)
    # A lead heading the other way counts with speed 0 along the ego's direction.
    poses = _behind(SafetyParams().rss_distance(13.4, 0.0) - 0.5, 13.4, 0.0)
    poses[1][2:] = [math.pi, 8.0]
    poses[1][0] += FRONT - REAR  # the same bumper gap, turned round about its box centre
    m = _ticks(SafetyRecorder(layout=layout), [poses])
    assert m.rss_ticks == 1 and m.min_ttc == pytest.approx(m.min_gap / 21.4, rel=1e-6)


def test_brake_switches_and_applications(layout):
    poses = [_behind(10.0, 13.4, 8.0)] * 5
    m = _ticks(SafetyRecorder(layout=layout), poses, [False, True, True, False, True])
    assert (m.brake_switches, m.brake_applications, m.brake_time) == (3, 2, 0.1)
    assert m.ttc_at_brake == pytest.approx(10.0 / 5.4, rel=1e-6)
    m = _ticks(SafetyRecorder(layout=layout), poses)
    assert (m.brake_switches, m.brake_applications, m.brake_time, m.ttc_at_brake) == (0, 0, None, None)


def _speeds(v: list[float]) -> list[list[list[float]]]:
    return [[[-30.0 + 1.0 * k, LANE_Y, 0.0, vk], FAR] for k, vk in enumerate(v)]


def test_constant_deceleration_peak_decel_and_jerk(layout):
    v = [13.4 - 4.0 * 0.1 * k for k in range(21)]
    m = _ticks(SafetyRecorder(layout=layout), _speeds(v))
    assert m.peak_decel == pytest.approx(4.0, rel=1e-9)
    assert m.peak_jerk == pytest.approx(0.0, abs=1e-9)
    assert m.hard_brake_time == pytest.approx(2.0)  # 20 ticks at 4 >= 3 m/s^2
    # Cruising, then braking at 4 m/s^2: one jump of 4 m/s^2 within a tick, 40 m/s^3.
    v = [13.4] * 5 + [13.4 - 0.4 * k for k in range(1, 6)]
    m = _ticks(SafetyRecorder(layout=layout), _speeds(v))
    assert m.peak_jerk == pytest.approx(40.0, rel=1e-9)
    assert m.peak_jerk_comfort == pytest.approx(0.0, abs=1e-9)  # the onset is hard braking
    m = _ticks(SafetyRecorder(SafetyParams(hard_brake=5.0), layout=layout), _speeds(v))
    assert m.peak_jerk_comfort == pytest.approx(40.0, rel=1e-9) and m.hard_brake_time == 0.0
    one = _ticks(SafetyRecorder(layout=layout), _speeds([13.4]))
    assert one.peak_decel is None and one.peak_jerk is None


def _crossing(early: int = 0) -> list[list[list[float]]]:
    """45 ticks: the ego east at 10 m/s from x = -20.5 m; the obstacle south at 5 m/s along
    x = 2.5 m (through the conflict area) from y = 20.1 m, ``early`` ticks ahead of that."""
    return [[[-20.5 + 1.0 * k, LANE_Y, 0.0, 10.0], [2.5, 20.1 - 0.5 * (k + early), -math.pi / 2, 5.0]]
            for k in range(45)]


def test_post_encroachment_time_of_two_crossing_cars(layout):
    # The conflict area is x in [0.65, 4.35], y in [-3.7, 0]. The ego's box (x - 0.95 to
    # x + 3.65) meets it for x in [-3, 5.3]: ticks 18-25 (1.8-2.5 s), out at 2.6 s. The
    # obstacle's box (y - 3.65 to y + 0.95) meets it from y <= 3.65: tick 33, 3.3 s.
    m = _ticks(SafetyRecorder(layout=layout), _crossing())
    assert m.conflict_first == "ego" and m.pet == pytest.approx(0.7, abs=1e-9)
    # The obstacle 8 ticks earlier: in from 2.5 s, when the ego is still in: both at once.
    m = _ticks(SafetyRecorder(layout=layout), _crossing(early=8))
    assert m.pet == 0.0
    # Only the ego ever enters: no encroachment.
    m = _ticks(SafetyRecorder(layout=layout), [[p[0], FAR] for p in _crossing()])
    assert m.pet is None and m.conflict_first == "ego"


def test_collision_sets_the_least_margins_to_zero(layout):
    rec = SafetyRecorder(layout=layout)
    rec.observe(0.0, np.array(_behind(1.0, 13.4, 5.0)), True)
    rec.observe(0.1, np.array(_behind(0.2, 13.4, 5.0)), True, collision="obstacle")
    m = rec.result()
    assert m.collision and (m.min_gap, m.min_ttc, m.min_headway) == (0.0, 0.0, 0.0)


def test_recorder_records_one_episode_and_needs_a_layout(layout):
    rec = SafetyRecorder(layout=layout)
    rec.observe(0.0, np.array(_behind(10.0, 13.4, 8.0)), False)
    with pytest.raises(ValueError, match="one episode"):
        rec.observe(0.0, np.array(_behind(10.0, 13.4, 8.0)), False)
    with pytest.raises(ValueError, match="layout"):
        SafetyRecorder().observe(0.0, np.array(_behind(10.0, 13.4, 8.0)), False)


def test_params_are_validated_and_follow_the_cars(layout):
    with pytest.raises(ValueError, match=r"SafetyParams\.rho=-0\.1 is out of range: must be in \[0, 600\] \[s\]"):
        SafetyParams(rho=-0.1)
    for bad in ({"b_min": 0.0}, {"b_max": math.nan}, {"a_acc": 1e9}, {"ttc_critical": True}):
        with pytest.raises(ValueError, match=rf"SafetyParams\.{next(iter(bad))}="):
            SafetyParams(**bad)
    p = SafetyParams.of_cars(layout, rho=0.5)
    assert (p.a_acc, p.b_min, p.b_max, p.rho) == (layout.ego.max_accel, layout.ego.max_brake,
                                                  layout.obstacle.max_brake, 0.5)


def test_metrics_are_validated_and_read_back(layout):
    m = _ticks(SafetyRecorder(layout=layout), _crossing())
    assert SafetyMetrics.from_dict(json.loads(json.dumps(m.to_dict(), allow_nan=False))) == m
    with pytest.raises(ValueError, match=r"SafetyMetrics\.min_gap=-1\.0"):
        SafetyMetrics.from_dict({**m.to_dict(), "min_gap": -1.0})
    with pytest.raises(ValueError, match=r"SafetyMetrics\.rss_ticks"):
        SafetyMetrics.from_dict({**m.to_dict(), "rss_ticks": m.following_ticks + 1})
    with pytest.raises(ValueError, match="'extra' is unknown"):
        SafetyMetrics.from_dict({**m.to_dict(), "extra": 1})


def test_summary_gives_medians_minima_and_shares(layout):
    runs = [_ticks(SafetyRecorder(layout=layout), [_behind(gap, 13.4, 8.0)], [True]) for gap in (1.0, 5.0, 20.0)]
    quiet = _ticks(SafetyRecorder(layout=layout), _speeds([13.4, 13.4]))
    items = [runs[0], runs[1].to_dict(), {"seed": 3, "safety": runs[2].to_dict()}, {"seed": 4, "safety": None},
             {"seed": 5, "status": "failed"}, quiet]
    s = safety_summary(items)
    json.dumps(s, allow_nan=False)
    assert s["episodes"] == 4
    assert s["min_gap"]["n"] == 4 and s["min_gap"]["median"] == pytest.approx(12.5)  # 1, 5, 20 and far
    assert s["ttc_at_brake"] == {"n": 3, "median": pytest.approx(5.0 / 5.4), "min": pytest.approx(1.0 / 5.4),
                                 "max": pytest.approx(20.0 / 5.4)}
    assert (s["late_brake"]["k"], s["late_brake"]["n"]) == (2, 3)  # 1/5.4 and 5/5.4 s < 1.5 s
    assert (s["rss_episodes"]["k"], s["rss_episodes"]["n"]) == (2, 3)  # 1 and 5 m < 16.3 m
    assert s["rss_ticks"]["n"] == 3 and 0.0 <= s["rss_ticks"]["ci95"][0] <= s["rss_ticks"]["ci95"][1] <= 1.0
    assert safety_summary([])["late_brake"]["value"] is None


def test_a_real_episode_is_read_from_the_truth(scene):
    rec = SafetyRecorder()
    record = run_episode(ScenarioConfig(), seed=1, planner="cdf-threshold", scene=scene, observers=[rec])
    m = rec.result()
    assert m.ticks == round(record.end_time / ScenarioConfig().timing.dt)
    assert m.min_gap == record.min_gap  # the same boxes, the same distance
    assert m.brake_time == record.brake_time and m.ttc_at_brake is not None and m.ttc_at_brake > 0.0
    assert m.min_ttc is not None and m.min_ttc > 0.0 and m.min_headway is not None and m.min_headway > 0.0
    assert m.brake_applications >= 1 and m.peak_decel == pytest.approx(4.877, abs=0.05)
    assert json.dumps(m.to_dict(), allow_nan=False)
