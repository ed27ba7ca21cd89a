"""The world's independent obstacle drivers (cdf_mj/scenario/drivers.py), closed loop.

Each driver is run on the default scene's layout against its own kinematic bicycle,
integrated here at dt = 0.1 s (controls clipped to the car's limits, speed >= 0), with a
scripted ego driving east along its route at 13.4 m/s from its nominal start. Line of
sight is scripted too: the ego always in sight, never, or from a time on.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from driver_loop import DT, EGO_SPEED, always, assert_written_apart, progress, run

from cdf_mj.model.modes import COMMITTED, GOING, LEFT, RIGHT, WAITING, YIELDING, Intent, Mode
from cdf_mj.scenario.drivers import (
    FAMILIES,
    GapAcceptanceParams,
    OffRouteParams,
    RollingStopParams,
    WorldDriver,
    make_driver,
)


@pytest.fixture(scope="module")
def layout(scene):
    return scene.layout()


def ego_passed(layout) -> float:
    """[s] when the scripted ego's rear bumper passes the conflict point."""
    route, ego = layout.route_ego, layout.ego
    s0 = float(route.project(layout.ego_start[:2])[0])
    return (float(route.project(layout.conflict)[0]) + ego.hull_half[0] - ego.hull_offset[0] - s0) / EGO_SPEED


def in_ego_lane(layout, pose: np.ndarray) -> np.ndarray:
    return layout.ego_lane.contains(layout.obstacle.footprint(pose)).any(axis=-1)


# ---------------------------------------------------------------------------- interface
def test_every_family_meets_the_protocol(layout):
    assert set(FAMILIES) == {"gap-acceptance", "rolling-stop", "aggressive", "off-route",
                             "looked-but-failed", "misjudged-speed", "distracted", "creeper"}
    for name in FAMILIES:
        driver = make_driver(name)
        assert isinstance(driver, WorldDriver) and driver.family == name
        driver.reset(layout, LEFT, np.random.default_rng(1))
        assert driver.mode == WAITING and set(driver.params) >= {"reaction_time", "critical_gap", "path_offset"}


@pytest.mark.parametrize(("module", "then"), [
    ("cdf_mj.scenario.drivers", ""),
    # Whichever module comes first: the registry then a crash family.
    ("cdf_mj.scenario.crash_drivers", "from cdf_mj.scenario.drivers import make_driver\n"
                                      "assert make_driver('creeper').family == 'creeper'\n"),
    ("cdf_mj.scenario.sumo_driver", ""),
])
def test_written_apart_from_the_filter_model(module: str, then: str) -> None:
    """The world's drivers (version 0.2's families, the junction-crash ones, SUMO's) share
    no code with the filter's driver model, directly or through what they import."""
    assert_written_apart(module, then)


def test_modes_and_intents_are_the_shared_ints():
    """The records share one vocabulary: the families' modes are cdf_mj.model.modes' ints
    (the filter's Mode and Intent; tests/test_driver.py checks its side)."""
    assert (WAITING, GOING, YIELDING, COMMITTED) == tuple(Mode) == (0, 1, 2, 3)
    assert (LEFT, RIGHT) == tuple(Intent) == (0, 1)
    assert all(type(v) is int for v in (WAITING, GOING, YIELDING, COMMITTED, LEFT, RIGHT))


# ---------------------------------------------------------------------------- at the line
@pytest.mark.parametrize("family", ["gap-acceptance", "aggressive", "off-route"])
def test_stopping_drivers_come_to_rest_at_the_line(layout, family):
    params = dataclasses.replace(FAMILIES[family].Params(), approach_distance=(12.0, 12.0),
                                 approach_speed=(6.0, 6.0))
    driver = make_driver(family, params)
    r = run(layout, driver, LEFT, seed=2, seconds=12.0)
    assert math.dist(driver.start[:2], layout.obstacle_start[:2]) == pytest.approx(12.0)
    assert driver.start[3] == pytest.approx(6.0)
    x = progress(layout, r.pose)
    depart = r.first(r.mode >= GOING)
    rest = r.first((r.pose[:, 3] < 0.2) & (np.abs(x) < 0.3))
    assert rest < depart < 12.0
    assert np.all(x[r.t < depart] < 0.2)  # nowhere past the line before it goes
    wait = max(driver.params["dwell"], driver.params["reaction_time"])
    assert depart >= rest + wait - DT
    # By default it starts where the world's driver does: at rest on the line.
    driver = make_driver(family)
    driver.reset(layout, LEFT, np.random.default_rng(0))
    np.testing.assert_allclose(driver.start, layout.obstacle_start)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rolling_stop_never_comes_to_rest(layout, seed):
    driver = make_driver("rolling-stop")
    r = run(layout, driver, LEFT, seed=seed, seconds=10.0)
    p = driver.params
    assert math.dist(driver.start[:2], layout.obstacle_start[:2]) == pytest.approx(p["approach_distance"])
    assert r.pose[:, 3].min() > 0.5 * p["rolling_speed"]
    at_line = np.flatnonzero(progress(layout, r.pose) >= 0.0)[0]
    assert r.pose[at_line, 3] == pytest.approx(p["rolling_speed"], abs=0.5)
    assert YIELDING not in r.mode and r.mode[-1] == COMMITTED


# ---------------------------------------------------------------------------- paths
@pytest.mark.parametrize("intent", [LEFT, RIGHT])
@pytest.mark.parametrize("family", ["gap-acceptance", "rolling-stop", "aggressive"])
def test_follows_its_route_with_no_ego_in_sight(layout, family, intent):
    r = run(layout, make_driver(family), intent, seed=4, seconds=10.0)
    route = layout.obstacle_routes[intent]
    s, lateral = route.project(r.pose[:, :2])
    assert np.abs(lateral).max() < 0.4
    assert abs(lateral[-1]) < 0.05 and s[-1] > 20.0  # out of the turn, on its lane's centre
    assert in_ego_lane(layout, r.pose[-1:])[0] == (intent == LEFT)


@pytest.mark.parametrize("offset", [-1.0, 1.0])
@pytest.mark.parametrize("intent", [LEFT, RIGHT])
def test_off_route_keeps_to_its_offset(layout, intent, offset):
    driver = make_driver("off-route", OffRouteParams(path_offset=(offset, offset)))
    r = run(layout, driver, intent, seconds=10.0)
    _, lateral = layout.obstacle_routes[intent].project(r.pose[:, :2])
    inside = 1.0 if intent == LEFT else -1.0  # the left turn bends left, the right one right
    assert np.abs(lateral).max() < abs(offset) + 0.4
    if intent == RIGHT and offset < 0.0:  # a wide right turn would reach into the ego's lane
        assert np.abs(lateral).max() < 0.4
    else:
        assert (inside * np.sign(offset) * lateral).max() > 0.6 * abs(offset)  # it does leave the route
    assert abs(lateral[-1]) < 0.05


@pytest.mark.parametrize("family", [*FAMILIES])
def test_a_right_turner_never_enters_the_ego_lane(layout, family):
    for seed in range(3):
        r = run(layout, make_driver(family), RIGHT, seed=seed, sight=always, seconds=10.0)
        assert not in_ego_lane(layout, r.pose).any()
    for offset in (-1.0, 1.0):
        r = run(layout, make_driver("off-route", OffRouteParams(path_offset=(offset, offset))), RIGHT)
        assert not in_ego_lane(layout, r.pose).any()


# ---------------------------------------------------------------------------- gaps and reaction
@pytest.mark.parametrize("family", ["gap-acceptance", "off-route"])
def test_waits_for_a_near_ego_and_goes_once_it_has_passed(layout, family):
    t_pass = ego_passed(layout)
    for seed in range(3):
        driver = make_driver(family)
        r = run(layout, driver, LEFT, seed=seed, sight=always)
        depart = r.first(r.mode >= GOING)
        tau = driver.params["reaction_time"]
        assert t_pass + tau - 0.05 <= depart <= t_pass + tau + 0.15
        assert YIELDING not in r.mode
        assert not in_ego_lane(layout, r.pose[r.t < t_pass]).any()
        assert 0.0 < progress(layout, r.pose[r.t < depart]).max() <= driver.params["creep_distance"] + 0.05
        # With no ego in sight it goes once its stop is over.
        r = run(layout, driver, LEFT, seed=seed)
        wait = max(driver.params["dwell"], driver.params["reaction_time"])
        assert r.first(r.mode >= GOING) == pytest.approx(wait, abs=DT + 1e-9)


@pytest.mark.parametrize("tau", [0.3, 1.2])
def test_the_reaction_time_delays_the_response(layout, tau):
    react = {"reaction_time": (tau, tau), "dwell": (2.0, 2.0)}
    r = run(layout, make_driver("gap-acceptance", GapAcceptanceParams(**react)), LEFT, sight=always)
    assert tau - 0.05 <= r.first(r.mode >= GOING) - ego_passed(layout) <= tau + 0.15
    # Going, no ego in sight; it appears near at t_on: the driver brakes about tau later.
    t_on = 1.5
    params = GapAcceptanceParams(reaction_time=(tau, tau), dwell=(0.0, 0.0), commit_distance=(8.0, 8.0))
    r = run(layout, make_driver("gap-acceptance", params), LEFT, sight=lambda t: t >= t_on, ego_shift=10.0)
    assert r.first(r.mode >= GOING) < t_on
    assert tau - 0.05 <= r.first(r.mode == YIELDING) - t_on <= tau + 0.15
    assert r.first((r.t >= t_on) & (r.accel < 0.0)) == r.first(r.mode == YIELDING)


def test_aggressive_takes_a_gap_that_gap_acceptance_refuses(layout):
    ego = layout.ego
    s0 = float(layout.route_ego.project(layout.ego_start[:2])[0])
    front_at = float(layout.route_ego.project(layout.conflict)[0]) - ego.hull_offset[0] - ego.hull_half[0] - 70.0
    shift = front_at - s0  # the ego's front 70 m (5.2 s) from the conflict point at t = 0
    t_pass = ego_passed(layout) - shift / EGO_SPEED
    for seed in range(3):
        bold = run(layout, make_driver("aggressive"), LEFT, seed=seed, sight=always, ego_shift=shift)
        careful = run(layout, make_driver("gap-acceptance"), LEFT, seed=seed, sight=always, ego_shift=shift)
        assert bold.first(bold.mode >= GOING) < 1.5 < t_pass < careful.first(careful.mode >= GOING)


# ---------------------------------------------------------------------------- parameters
@pytest.mark.parametrize("family", [*FAMILIES])
def test_drawn_parameters_stay_in_range_and_repeat_per_seed(layout, family):
    driver = make_driver(family)
    ranges = driver.ranges
    draws = []
    for seed in range(20):
        driver.reset(layout, seed % 2, np.random.default_rng(seed))
        draws.append(dict(driver.params))
        for name, value in driver.params.items():
            if name in type(driver).extra_draws:  # a draw of its own beside the ranges (the creeper's restops)
                assert isinstance(value, float), (name, value)
                continue
            low, high = getattr(ranges, name)
            assert low <= value <= high, (name, value)
    again = make_driver(family)
    again.reset(layout, LEFT, np.random.default_rng(7))
    assert dict(again.params) == draws[7]  # the same seed, the same driver (whatever the intent)
    assert draws[7] != draws[8]


@pytest.mark.parametrize(("kind", "name", "value"), [
    (GapAcceptanceParams, "reaction_time", (math.nan, 1.0)),
    (GapAcceptanceParams, "critical_gap", (7.0, 6.0)),
    (GapAcceptanceParams, "dwell", (-1.0, 2.0)),
    (GapAcceptanceParams, "reaction_time", "quick"),
    (GapAcceptanceParams, "path_offset", (0.0, 5.0)),
    (GapAcceptanceParams, "creep_distance", (0.5, 3.0)),  # beyond the commit distance
    (RollingStopParams, "rolling_speed", (0.0, 2.0)),
    (RollingStopParams, "hard_brake", (3.0, math.inf)),
])
def test_bad_parameters_are_refused_by_name(kind, name, value):
    with pytest.raises(ValueError, match=rf"{kind.__name__}: .*{name}="):
        kind(**{name: value})


def test_bad_calls_are_refused(layout):
    with pytest.raises(ValueError, match=r"unknown driver family 'cautious': known families are gap-acceptance"):
        make_driver("cautious")
    with pytest.raises(ValueError, match="takes RollingStopParams"):
        make_driver("rolling-stop", GapAcceptanceParams())
    driver = make_driver("aggressive")
    with pytest.raises(RuntimeError, match="reset"):
        driver.control(0.0, layout.obstacle_start, None, DT)
    with pytest.raises(ValueError, match="intent=2"):
        driver.reset(layout, 2, np.random.default_rng(0))
