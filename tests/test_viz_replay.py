"""cdf_mj.viz.replay: an episode re-simulated with the per-tick data a video needs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.gl import RenderError
from cdf_mj.viz.replay import check_frame_time, record_episode

TWO_SECONDS = ScenarioConfig(timing={"duration": 2.0})


def test_recorded_episode_is_the_plain_episode(scene) -> None:
    rep = record_episode(1, "cdf-threshold", TWO_SECONDS, scene, label=False)
    plain = run_episode(TWO_SECONDS, 1, "cdf-threshold", scene, label=False)
    assert rep.record.to_dict() == {**plain.to_dict(), "trace": rep.record.trace}
    assert rep.record.brake_time == plain.brake_time is not None
    assert len(rep.particles) == len(rep.times) - 1 == len(rep.seen) == len(rep.belief)
    assert set(rep.posterior) == {"t", "p_left", "p_seen", "p_cutoff"}
    assert rep.tau == CDFConfig().tau
    # Interpolation passes through the ticks and ends at the final state.
    np.testing.assert_allclose(rep.pose_at(rep.times[3]), rep.poses[3])
    np.testing.assert_allclose(rep.pose_at(rep.end_time), rep.poses[-1])


def test_particle_snapshots_are_distinct_and_heaviest_first(scene) -> None:
    rep = record_episode(1, "cdf-threshold", TWO_SECONDS, scene, label=False)
    for xy, code, weight, heading in rep.particles:
        assert xy.dtype == np.float32 and xy.shape == (len(code), 2) and heading.shape == code.shape
        assert heading.dtype == np.float32 and np.all(np.abs(heading) <= math.pi + 1e-6)
        assert set(np.unique(code)) <= {0, 1, 2, 3}  # 2 * intent + seen
        assert np.all(np.diff(weight) <= 0) and math.isclose(weight.sum(), 1.0, rel_tol=1e-4)
        keys = {(round(x * 100), round(y * 100), c) for (x, y), c in zip(xy.tolist(), code.tolist(), strict=True)}
        assert len(keys) == len(code)  # merged to 1 cm


def test_particle_headings_are_the_weighted_circular_mean(scene) -> None:
    from cdf_mj.viz.replay import _distinct_particles

    xy = np.zeros((3, 2))
    merged = _distinct_particles(xy, np.zeros(3, int), np.zeros(3, bool), np.array([0.25, 0.25, 0.5]),
                                 np.array([math.pi - 0.1, -math.pi + 0.1, math.pi]))
    assert len(merged.code) == 1 and abs(abs(merged.heading[0]) - math.pi) < 1e-6  # not 0: across +-pi
    rep = record_episode(1, "cdf-threshold", TWO_SECONDS, scene, label=False)
    start = scene.layout().obstacle_start[2]
    first = rep.particles[0]
    assert np.all(np.abs(np.remainder(first.heading - start + math.pi, 2 * math.pi) - math.pi) < 0.05)


def test_a_frame_past_the_end_is_refused_in_one_line() -> None:
    assert check_frame_time(5.3000001, 5.3) == 5.3 and check_frame_time(1.5, 5.3) == 1.5
    for bad in (20.0, -1.0, float("nan")):
        with pytest.raises(RenderError, match=r"^--frame .*: outside the episode, which runs from 0 s to 5.30 s"):
            check_frame_time(bad, 5.3)


def test_a_baseline_keeps_its_own_probabilities_and_threshold(scene) -> None:
    rep = record_episode(1, "imm", TWO_SECONDS, scene, label=False)
    assert set(rep.posterior) == {"t", "p_left", "p_conflict"} and rep.tau == 0.95
    assert len(rep.posterior["t"]) == len(rep.posterior["p_conflict"]) > 0 and rep.particles is None
    plain = record_episode(1, "reactive", ScenarioConfig(timing={"duration": 1.0}), scene, label=False)
    assert plain.posterior is None and plain.tau is None and plain.particles is None


def test_label_is_the_scenario_label(scene) -> None:
    config = ScenarioConfig(timing={"duration": 1.0})
    assert record_episode(1, "reactive", config, scene).label == run_episode(config, 1, "reactive", scene).label


def test_time_lookups(scene) -> None:
    rep = record_episode(1, "cdf-threshold", TWO_SECONDS, scene, label=False)
    assert rep.tick(0.0) == 0 and rep.tick(0.1) == 1 and rep.tick(0.1999) == 1
    assert rep.tick(rep.end_time + 5.0) == len(rep.times) - 2
    brake = rep.record.brake_time
    assert not rep.braking(brake - 0.05) and rep.braking(brake)
    # Headings interpolate along the shorter arc: from +179 deg to -179 deg through 180.
    poses = rep.poses[:2].copy()
    poses[0, :, 2], poses[1, :, 2] = math.radians(179.0), math.radians(-179.0)
    turn = dataclasses.replace(rep, times=np.array([0.0, 0.1]), poses=poses)
    assert abs(abs(turn.pose_at(0.05)[0, 2]) - math.pi) < 1e-9
