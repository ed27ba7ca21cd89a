"""A world refused where it is made, not part-way through a run (issue 39, causes 7 and
11): what ``sensing.told`` tells the planner is bounded where :class:`ScenarioConfig` is
validated (the bounds of ``PlannerContext``), and an ego start before its route's first
point is refused by the world (it would start at that point while the record kept the
offset drawn, and a negative time lost from it)."""

from __future__ import annotations

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.config import ScenarioConfig
from cdf_mj.planners.base import PlannerContext
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.world import World

TOLD_TOO_LATE = {"sensing.latency": 60, "sensing.brake_latency": 60, "sensing.told": True}


# ----------------------------------------------------------------- cause 7: told sensing
@pytest.mark.parametrize(("values", "needle"), [
    (TOLD_TOO_LATE, "sensing.latency + sensing.brake_latency=120 is out of range: must be at most 10 s"),
    ({"sensing.latency": 25, "sensing.brake_latency": 0, "sensing.told": True, "timing.dt": 0.5,
      "timing.duration": 20.0}, "sensing.latency + sensing.brake_latency=25 is out of range"),
    ({"sensing.pos": 500.0, "sensing.told": True}, "sensing.pos=500.0 is out of range: must be at most 100 m"),
])
def test_told_sensing_a_planner_cannot_take_is_refused_by_the_config(values, needle):
    with pytest.raises(ValueError, match=r"sensing\.") as info:
        ScenarioConfig().with_values(values)
    assert needle in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("values", [
    {"sensing.latency": 50, "sensing.brake_latency": 50, "sensing.told": True},  # 10 s: the bound
    {"sensing.pos": 100.0, "sensing.heading": 3.14, "sensing.speed": 100.0, "sensing.told": True},
    {**TOLD_TOO_LATE, "sensing.told": False},  # not told: the planner is told nothing
])
def test_every_told_config_the_config_takes_a_planner_takes(scene, values):
    config = ScenarioConfig().with_values(values)
    PlannerContext.of(scene.layout(), config)


def test_the_command_line_refuses_told_sensing_before_running(tmp_path, capsys):
    out = tmp_path / "exp"
    sets = [arg for key, v in TOLD_TOO_LATE.items() for arg in ("--set", f"{key}={str(v).lower()}")]
    status, stdout, err = run_cli(capsys, "experiment", "--episodes", "2", "--workers", "1", "--out", str(out),
                                  "--quiet", *sets)
    assert_one_line_error(status, stdout, err, "sensing.latency + sensing.brake_latency=120")
    assert not (out / "episodes.jsonl").exists()


# ----------------------------------------------------------------- cause 11: a start before the route
@pytest.mark.parametrize("spread", [(-150.0, 0.0), (-110.0, -110.0), (-200.0, -200.0)])
def test_a_start_before_the_routes_first_point_is_refused_by_the_world(scene, spread):
    config = ScenarioConfig().with_values({"ego.start_spread": spread})
    with pytest.raises(ValueError, match=r"puts the ego's start off its route") as info:
        World(scene, config)
    assert "\n" not in str(info.value) and "109.2 m along a route" in str(info.value)


def test_a_start_on_the_route_is_where_the_record_says(scene):
    config = ScenarioConfig().with_values({"ego.start_spread": (-109.0, -109.0)})
    World(scene, config)  # the route's first metre: taken
    from cdf_mj.planners import make_planner

    record = run_episode(config.with_values({"ego.start_spread": (-100.0, -100.0)}), 3, make_planner("reactive"),
                         scene)
    assert record.ego_start_offset == -100.0 and record.time_lost >= -1e-6


def test_the_command_line_refuses_a_start_before_the_route(tmp_path, capsys):
    out = tmp_path / "exp"
    status, stdout, err = run_cli(capsys, "experiment", "--episodes", "1", "--workers", "1", "--out", str(out),
                                  "--quiet", "--set", "ego.start_spread=[-150,-150]")
    assert_one_line_error(status, stdout, err, "ego.start_spread=(-150, -150) m puts the ego's start off its route")
    assert not (out / "episodes.jsonl").exists()
