"""Baseline planners (cv, imm) and the filter metrics (Brier scores, planner metrics).

Constructed situations: ``beta = 0`` (the obstacle never sees the ego, so it never yields)
with ``p_left`` = 1 or 0 fixes the obstacle's behaviour, and a degenerate
``ego_start_spread`` fixes where the ego starts. With ``p_left = 1`` the counterfactual run
collides (the test checks the label Cutoff), so the planner must brake before the obstacle
enters the ego lane.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdf_mj.analysis.metrics import brier_over_time, brier_score, planner_metrics
from cdf_mj.analysis.tables import paired_table, planner_table
from cdf_mj.config import ScenarioConfig
from cdf_mj.model.geometry import box_corners, boxes_overlap
from cdf_mj.planners import PLANNERS, PlannerInput, make_planner
from cdf_mj.planners.base import PlannerContext
from cdf_mj.planners.baseline_common import route_heading
from cdf_mj.planners.cv import CVConfig, CVPlanner
from cdf_mj.planners.imm import IMMConfig, IMMPlanner
from cdf_mj.scenario.episode import run_episode


def _situation(intent: str, offset: float) -> ScenarioConfig:
    return ScenarioConfig(obstacle={"p_left": 1.0 if intent == "left" else 0.0, "beta": 0.0},
                          ego={"start_spread": (offset, offset)})


@pytest.mark.parametrize("planner", [CVPlanner, IMMPlanner])
def test_brakes_before_a_cutoff_enters_the_lane(scene, planner):
    rec = run_episode(_situation("left", 0.0), seed=0, planner=planner(), scene=scene)
    assert rec.label == "Cutoff"  # the constant-speed run of the same world collides
    assert rec.brake_time is not None
    assert rec.brake_time < rec.entered_lane_time
    assert not rec.collision


@pytest.mark.parametrize(("planner", "offset"), [
    # The IMM knows the intent from the obstacle's heading and path within about 1 s, before
    # the left-turn model's conflict comes within its horizon: ego at the centre or the back.
    (IMMPlanner, 0.0), (IMMPlanner, -8.0),
    # The straight-line extrapolation of a turning car crosses the ego lane while the car
    # swings west; with the ego 8 m ahead of the centre it is through before that line is.
    (CVPlanner, 8.0),
])
def test_no_brake_for_a_right_turn(scene, planner, offset):
    rec = run_episode(_situation("right", offset), seed=0, planner=planner(), scene=scene)
    assert rec.label == "Right"
    assert rec.brake_time is None


def test_cv_does_not_brake_for_a_car_leaving_in_the_far_lane(scene):
    """A right-turner past its turn, westbound in the far lane, passing the eastbound ego."""
    cfg = ScenarioConfig()
    p = CVPlanner()
    p.reset(PlannerContext.of(scene.layout(), cfg), np.random.default_rng(0))
    for k in range(30):
        t = 0.1 * k
        poses = np.array([[-40.0 + 13.4 * t, -1.85, 0.0, 13.4], [-8.0 - 6.0 * t, 1.85, math.pi, 6.0]])
        assert not p.brake(PlannerInput(t=t, poses=poses, obstacle_in_lane=False))


def test_imm_mode_probabilities_sum_to_one_and_find_the_intent(scene):
    for intent, offset in (("left", 0.0), ("right", 0.0), ("left", -8.0)):
        cfg = _situation(intent, offset)
        trace = run_episode(cfg, seed=3, planner="constant", scene=scene, label=False, trace=True).trace
        p = IMMPlanner()
        p.reset(PlannerContext.of(scene.layout(), cfg), np.random.default_rng(0))
        for t, poses, in zip(trace["t"], trace["poses"], strict=True):
            p.brake(PlannerInput(t=t, poses=np.array(poses), obstacle_in_lane=False))
            mu = p.mode_probabilities
            assert mu.shape == (2,)
            assert np.all((mu >= 0) & (mu <= 1))
            assert mu.sum() == pytest.approx(1.0, abs=1e-12)
        assert p.mode_probabilities[0 if intent == "left" else 1] > 0.99
        hist = p.summary()["history"]
        assert len(hist["t"]) == len(trace["t"]) == len(hist["p_left"]) == len(hist["p_conflict"])


def test_registered_and_summaries(scene):
    assert {"cv", "imm"} <= set(PLANNERS)
    assert make_planner("imm").name == "imm" and make_planner("cv").name == "cv"
    rec = run_episode(ScenarioConfig(), seed=1, planner="imm", scene=scene, label=False)
    assert rec.planner == "imm"
    assert set(rec.planner_info) >= {"prediction", "decision_time", "history"}
    rec = run_episode(ScenarioConfig(), seed=1, planner="cv", scene=scene, label=False)
    assert set(rec.planner_info) == {"rule", "decision_time", "release_time", "brakes", "predicted_conflict_in"}
    assert rec.planner_info["rule"] == "threshold" and rec.planner_info["release_time"] is None


@pytest.mark.parametrize(("cls", "field", "value"), [
    (CVConfig, "horizon", 0.0), (CVConfig, "horizon", math.nan), (CVConfig, "margin", -1.0),
    (IMMConfig, "threshold", 0.0), (IMMConfig, "threshold", 1.5), (IMMConfig, "switch_prob", 0.0),
    (IMMConfig, "pos_std", -0.1), (IMMConfig, "init_std", (1.0, 1.0)), (IMMConfig, "max_speed", 0.0),
    (IMMConfig, "horizon", True),
])
def test_config_refuses_bad_values(cls, field, value):
    with pytest.raises(ValueError, match=field):
        cls(**{field: value})


def test_boxes_overlap_and_route_heading(scene):
    a = box_corners(np.array([[0.0, 0.0]] * 3), np.zeros(3), np.array([1.0, 0.5]))
    b = box_corners(np.array([[1.9, 0.0], [2.1, 0.0], [1.6, 1.6]]), np.array([0.0, 0.0, math.pi / 4]),
                    np.array([1.0, 0.5]))
    assert boxes_overlap(a, b).tolist() == [True, False, False]
    # The left route starts southbound (-pi/2) and ends eastbound (0).
    left = scene.layout().route_left
    th = route_heading(left, np.array([0.0, left.length]))
    assert th[0] == pytest.approx(-math.pi / 2, abs=1e-6) and th[1] == pytest.approx(0.0, abs=1e-6)


# ----------------------------------------------------------------- metrics
def _rec(planner, intent, label, first_seen, p_left, p_seen, brake=None, collision=None, entered=None):
    return {"planner": planner, "intent": intent, "label": label, "first_seen_time": first_seen,
            "brake_time": brake, "entered_lane_time": entered, "collision": collision is not None,
            "collision_with": collision, "min_gap": 1.0, "time_lost": 0.5, "seed": 0,
            "planner_info": {"history": {"t": [0.0, 0.1, 0.2], "p_left": p_left, "p_seen": p_seen}}}


def test_brier_scores_against_intent_and_first_seen():
    assert brier_score([1.0, 0.0], [1, 0]) == 0.0
    assert brier_score([0.5, 0.5], [1, 0]) == 0.25
    with pytest.raises(ValueError, match="probabilities"):
        brier_score([1.5], [1])
    recs = [_rec("cdf", "left", "Cutoff", 0.1, [0.75, 1.0, 1.0], [0.0, 0.0, 1.0]),
            _rec("cdf", "right", "Right", None, [0.75, 0.5, 0.0], [0.5, 0.0, 0.0]),
            {"planner": "cdf", "status": "failed", "seed": 9}]
    left = brier_over_time(recs, "p_left")
    assert left.episodes == 2 and left.ticks == 6
    assert left.overall == pytest.approx((0.0625 + 0.5625 + 0.25) / 6)
    assert left.scores.tolist() == pytest.approx([(0.0625 + 0.5625) / 2, 0.125, 0.0])
    # Seen at 0.1 s: the truth is 1 from the next tick on (the planner at 0.1 s decides
    # before the obstacle's look at 0.1 s).
    seen = brier_over_time(recs, "p_seen")
    assert seen.overall == pytest.approx(0.25 / 6)
    assert seen.reference.tolist() == pytest.approx([0.0, 0.0, 0.25])


def test_planner_metrics_and_table():
    recs = [_rec("imm", "left", "Cutoff", None, [0.9] * 3, [0.0] * 3, brake=1.0, entered=2.0),
            _rec("imm", "left", "Cutoff", None, [0.9] * 3, [0.0] * 3, collision="obstacle"),
            _rec("imm", "left", "Yield", 0.5, [0.9] * 3, [0.0] * 3, brake=0.8),
            _rec("imm", "right", "Right", None, [0.1] * 3, [0.0] * 3)]
    for r in recs:
        r["planner_info"]["history"].pop("p_seen")
    m = planner_metrics(recs)["imm"]
    assert (m.imminent, m.collisions, m.avoided.k, m.avoided.n) == (2, 1, 1, 2)
    assert (m.false_alarms.k, m.false_alarms.n) == (1, 4)
    assert m.lead_time == pytest.approx(1.0)
    assert m.brier_seen is None and m.brier_left == pytest.approx(0.01)
    assert "| imm | 4 | 2 | 1 |" in planner_table(recs)


def test_paired_table_counts_seed_by_seed():
    def rec(planner, seed, label, brake=None, collision=None):
        return {**_rec(planner, "left", label, None, [0.9] * 3, [0.0] * 3, brake=brake, collision=collision),
                "seed": seed}

    recs = [rec("cdf", 0, "Cutoff", brake=0.9), rec("imm", 0, "Cutoff", collision="obstacle"),
            rec("cdf", 1, "Cutoff", collision="obstacle"), rec("imm", 1, "Cutoff", collision="obstacle"),
            rec("cdf", 2, "Yield", brake=0.9), rec("imm", 2, "Yield"),
            rec("cdf", 3, "Right", brake=1.0), rec("imm", 3, "Right", brake=1.2),
            rec("cdf", 4, "Yield"), rec("imm", 4, "Yield", brake=1.5),
            rec("cdf", 5, "Yield", brake=0.9)]  # seed 5: the IMM did not run it, not counted
    assert paired_table(recs, [("cdf", "imm")]).splitlines()[2] == "| cdf / imm | 0 | 1 | 1 | 1 | 1 | 0 | 0 |"
