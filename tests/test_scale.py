"""A testbed at another scale or in other units: cars and configs refuse values in the
wrong unit with the unit in the message, and the CDF monitor, set up as the README's "A
testbed at another scale" says, watches a 1:10 junction with small cars (driven here by
the test as mocap bodies) as it watches the full-size one."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from cars import add_mocap_car, set_mocap_pose
from junctions import build_junction

from cdf_mj import CarGeometry, CDFMonitor, DriverPrior, RiskConfig, TrackedCar, attach, scaled
from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames
from cdf_mj.model.conflict import FULL_SIZE_LENGTH
from cdf_mj.sim.checks import SceneError
from cdf_mj.sim.scene import car_geometry
from cdf_mj.sim.spec import add_car

OURS = CarGeometry.ours().to_dict()


# ------------------------------------------------------------------ units of a car
@pytest.mark.parametrize(("field", "value", "message"), [
    ("hull_half", (2300.0, 900.0), "hull_half=[2300.0, 900.0] makes the box 4600 m long: a car is 0.05-30 m "
                                   "long; millimetres?"),
    ("hull_half", (2.3, 90.0), "makes the box 180 m wide: a car is 0.02-10 m wide; millimetres or centimetres?"),
    ("hull_half", (0.01, 0.005), "makes the box 0.02 m long: a car is 0.05-30 m long; metres expected"),
    ("wheelbase", 2700.0, "wheelbase=2700 m: a car's is at most 30 m; millimetres or centimetres?"),
    ("eye_offset", (1200.0, 350.0, 1200.0), "eye_offset=[1200.0, 350.0, 1200.0] reaches 1200 m from the rear "
                                            "axle"),
    ("accel_range", (-4877.0, 3000.0), "reaches 4877 m/s^2: a car's is at most 100 m/s^2 (about 10 g); mm/s^2?"),
    ("steer_range", (-35.0, 35.0), "steer_range=(-35.0, 35.0) reaches 35 rad: a car steers at most pi/2 rad "
                                   "(90 deg); degrees? Steering angles are radians (35 deg = 0.611 rad)"),
])
def test_a_car_in_other_units_is_refused_naming_the_unit(field, value, message):
    with pytest.raises(ValueError, match=r"^CarGeometry: ") as err:
        CarGeometry(**{**OURS, field: value})
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("scale", [0.025, 0.1, 1.0, 4.0])
def test_cars_from_a_1_to_40_model_to_a_road_train_are_accepted(scale: float):
    """Our car at 1:40 (0.115 m long: MuJoCo's example car is 0.2 m), 1:10, full size and
    a 18 m road train, each with its accelerations scaled the same way."""
    car = CarGeometry(**{k: np.asarray(v) * scale if k not in ("steer_range",) else v for k, v in OURS.items()})
    assert car.length == pytest.approx(4.6 * scale) and car.width == pytest.approx(1.8 * scale)


def test_a_car_in_millimetres_in_a_scene_is_one_scene_error():
    """Our car built with add_car, its hull then written in millimetres: reading its
    dimensions from the model says so."""
    spec = mujoco.MjSpec()
    spec.compiler.degree = False
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[100, 100, 0.1])
    add_car(spec, "ego_")
    spec.geom("ego_hull").size = [2300.0, 900.0, 725.0]  # the box written in millimetres
    with pytest.raises(SceneError, match=r"car .ego_.: CarGeometry: hull_half=.* millimetres\?"):
        car_geometry(spec.compile(), SceneNames(), "ego_")


# ------------------------------------------------------------------ configurations at another scale
def test_scaling_by_one_keeps_every_config_and_by_a_tenth_scales_lengths_speeds_accelerations():
    for config in (ScenarioConfig(), CDFConfig(), RiskConfig(), DriverPrior()):
        assert scaled(config, 1.0) == config
    cdf, scenario = scaled(CDFConfig(), 0.1), scaled(ScenarioConfig(), 0.1)
    assert cdf.risk.replace(margin=0.3) == RiskConfig() and cdf.risk.margin == pytest.approx(0.03)
    assert cdf.likelihood_std == pytest.approx((0.03, 0.03, 0.05, 0.03))  # [m, m, rad, m/s]
    assert cdf.prior.turn_speed == pytest.approx((0.6, 1.0)) and cdf.prior.accel == pytest.approx((0.15, 0.3))
    assert cdf.prior.critical_gap == (4.0, 7.0) and cdf.prior.beta == (0.03, 0.07)
    assert cdf.prior.pursuit.lookahead == pytest.approx(0.3) and cdf.prior.pursuit.lookahead_gain == 0.3
    assert (cdf.n_particles, cdf.tau, cdf.ego_brake) == (1000, 0.85, None)
    timing = ScenarioConfig().timing  # times stay; the episode's end and the label's horizon are lengths
    assert scenario.ego.speed == pytest.approx(1.34) and scenario.timing == timing.replace(
        end_distance=timing.end_distance * 0.1, label_distance=timing.label_distance * 0.1)
    assert scenario.names == SceneNames()
    cov = CDFConfig(likelihood_cov=np.diag([0.09, 0.09, 0.0025, 0.09]).tolist())
    np.testing.assert_allclose(scaled(cov, 0.1).covariance, np.diag([9e-4, 9e-4, 0.0025, 9e-4]))
    for bad in (0.0, -0.1, math.nan, 1000.0):
        with pytest.raises(ValueError, match=r"^length_scale=.* is out of range"):
            scaled(RiskConfig(), bad)


# ------------------------------------------------------------------ the monitor on a 1:10 junction
SCALE = 0.1
#: Our car at 1:10 (a 0.46 m box), its accelerations scaled as the law says: the testbed is
#: then the full-size scenario shrunk, tick for tick.
OURS_AT_A_TENTH = CarGeometry(**{k: np.asarray(v) * SCALE if k != "steer_range" else v for k, v in OURS.items()})
#: A 1:10 RC touring car as its maker would list it: 0.45 m x 0.19 m, 0.26 m wheelbase,
#: braking at 4 m/s^2 (far harder than a car's tenth), steering +-0.45 rad.
RC_CAR = CarGeometry(wheelbase=0.26, hull_offset=(0.12, 0.0), hull_half=(0.225, 0.095), hull_height=0.14,
                     eye_offset=(0.1, 0.0, 0.12), accel_range=(-4.0, 3.0), steer_range=(-0.45, 0.45))
CARS = {"our car at 1:10, ego at 1.34 m/s": (OURS_AT_A_TENTH, 1.34),
        "an RC car, ego at 2 m/s": (RC_CAR, 2.0)}


def _drive(car: CarGeometry, ego_speed: float, intent: str, wait: float, seed: int, *, scale: float = SCALE,
           yields: bool = False, **junction: object) -> tuple[CDFMonitor, float | None]:
    """Two mocap cars on the paper's junction at ``scale``, the monitor set up as the
    README's "A testbed at another scale" says. The ego holds ``ego_speed`` [m/s] and
    reaches the conflict point 2.4 s after the obstacle's ``wait`` [s] at the line; the
    obstacle then pulls out along its ``intent`` route at the scaled driver's 2.5 m/s^2 up
    to 8 m/s (times ``scale``). With ``yields`` it waits instead until the ego's tail is a
    car length past the conflict point. Returns the monitor and when the obstacle first
    put a corner into the ego's lane [s]."""
    spec = build_junction(cars=False, scale=scale, **junction)  # type: ignore[arg-type]
    add_mocap_car(spec, "ego_car", scale=scale)
    add_mocap_car(spec, "obstacle_car", scale=scale)
    model = spec.compile()
    data = mujoco.MjData(model)
    monitor = attach(model, data, rng=seed, nominal_speed=ego_speed, scenario=scaled(ScenarioConfig(), scale),
                     cdf=scaled(CDFConfig(), scale), ego=TrackedCar(body="ego_car", geometry=car),
                     obstacle=TrackedCar(body="obstacle_car", geometry=car))
    lay = monitor.layout
    route = lay.route_left if intent == "left" else lay.route_right
    s_line = route.project_point(*lay.obstacle_start[:2])[0]
    s_conflict = lay.route_ego.project_point(*lay.conflict)[0]
    ego_start = s_conflict - ego_speed * (wait + 2.4)
    tail = float(car.hull_half[0] - car.hull_offset[0])  # [m] behind the rear axle
    s = v = 0.0
    go, entered = (None if yields else wait), None
    steps = round(monitor.scenario.timing.dt / model.opt.timestep)
    for k in range(int((wait + 5.0) / 0.1)):
        t = 0.1 * k
        ego = ego_start + ego_speed * t
        if go is None and ego - tail > s_conflict + car.length:
            go = t
        if go is not None and t >= go - 1e-9:
            v = min(v + 2.5 * scale * 0.1, 8.0 * scale)
            s += v * 0.1
        for name, path, at in (("ego_car", lay.route_ego, ego), ("obstacle_car", route, s_line + s)):
            p, q = path.point_at(at), path.point_at(at + 0.5 * scale)
            set_mocap_pose(model, data, name, p[0], p[1], math.atan2(q[1] - p[1], q[0] - p[0]))
        decision = monitor.step()
        if entered is None and lay.ego_lane.contains(car.footprint(decision.poses[1])).any():
            entered = t
        mujoco.mj_step(model, data, nstep=steps)
    return monitor, entered


@pytest.mark.parametrize("car", list(CARS))
def test_a_1_to_10_monitor_warns_for_a_cut_off(car: str):
    """A left-turner that waited 0 or 1 s at the line is braked for before it enters the
    ego's lane, on a mirrored and rotated 1:10 junction too."""
    geometry, speed = CARS[car]
    for wait, junction in ((0.0, {}), (1.0, {"mirror": True, "rotation": 0.7})):
        monitor, entered = _drive(geometry, speed, "left", wait, seed=int(wait), **junction)
        assert entered is not None and monitor.brake_time is not None, (wait, "no warning for a cut-off")
        assert monitor.brake_time < entered, (wait, monitor.brake_time, entered)


@pytest.mark.parametrize("car", list(CARS))
@pytest.mark.parametrize("driver", ["turns right", "yields"])
def test_a_1_to_10_monitor_stays_quiet_for_a_right_turn_and_a_yielding_driver(car: str, driver: str):
    """A car that turns away from the ego's lane, or that waits at the line until the ego
    has passed and then turns left behind it: the monitor never brakes."""
    geometry, speed = CARS[car]
    for wait in (0.0, 1.0):
        monitor, _ = _drive(geometry, speed, "right" if driver == "turns right" else "left", wait, seed=int(wait),
                            yields=driver == "yields")
        assert monitor.brake_time is None, (wait, f"braked at {monitor.brake_time} s")


def test_the_1_to_10_testbed_is_the_full_size_scenario_shrunk():
    """Our car and junction at 1:10 with the configs scaled: the filter's posterior is the
    full-size one, tick for tick (measured: within 0.014), and the first brake comes on the
    same tick: the risk rule's overlap table shrinks with the cars
    (cdf_mj.model.conflict.resolution), so it is the full-size table, shrunk."""
    assert CarGeometry.ours().length == FULL_SIZE_LENGTH
    for wait, seed in ((0.0, 1), (1.0, 5), (0.5, 3)):
        small, _ = _drive(OURS_AT_A_TENTH, 1.34, "left", wait, seed=seed)
        full, _ = _drive(CarGeometry.ours(), 13.4, "left", wait, seed=seed, scale=1.0)
        assert small.brake_time is not None and full.brake_time is not None
        assert small.brake_time == pytest.approx(full.brake_time, abs=1e-9)
        for a, b in zip(small.trace, full.trace, strict=True):
            for key in ("p_left", "p_seen", "p_cutoff"):
                assert a["posterior"][key] == pytest.approx(b["posterior"][key], abs=0.03), (a["t"], key)


def test_full_size_settings_on_a_small_car_are_refused():
    spec = build_junction(cars=False, scale=SCALE)
    add_mocap_car(spec, "ego_car", scale=SCALE)
    add_mocap_car(spec, "obstacle_car", scale=SCALE)
    model = spec.compile()
    cars = {"ego": TrackedCar(body="ego_car", geometry=RC_CAR), "obstacle": TrackedCar(body="obstacle_car",
                                                                                       geometry=RC_CAR)}
    with pytest.raises(ValueError, match=r"RiskConfig.margin=0.3 m is more than half the narrower car's width "
                                         r"\(0.095 m\).*cdf_mj.scaled\(config, 0.11\)"):
        attach(model, mujoco.MjData(model), **cars)
    slow = CarGeometry(**{**RC_CAR.to_dict(), "accel_range": (-0.5, 0.3)})
    with pytest.raises(ValueError, match=r"RiskConfig.horizon=5 s is shorter than the 27.00 s the ego needs .* "
                                         r"from 13.4 m/s at 0.5 m/s\^2"):
        attach(model, mujoco.MjData(model), cdf=scaled(CDFConfig(), SCALE), ego=TrackedCar("ego_car", geometry=slow),
               obstacle=cars["obstacle"])
