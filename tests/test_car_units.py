"""A car's lengths checked the same way wherever a user gives them (issue 39, cause 13):
:class:`TrackedCar` refuses a rear axle no car has (millimetres) with the unit hint
:class:`CarGeometry` gives, and the monitor takes every car ``CarGeometry`` takes, the
largest included (its safety margin pads the box past ``CarGeometry``'s bounds)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from cdf_mj.model.vehicle import CAR_LENGTH, CAR_SIZE, CAR_WIDTH, CarGeometry
from cdf_mj.scenario.monitor import CDFMonitor, attach
from cdf_mj.sim.scene import DEFAULT_SCENE
from cdf_mj.sim.tracking import TrackedCar


def _car(length: float, width: float) -> CarGeometry:
    return CarGeometry(wheelbase=min(2.7, 0.6 * length), hull_offset=(0.3 * length, 0.0),
                       hull_half=(length / 2, width / 2), hull_height=1.5, eye_offset=(0.1, 0.0, 1.2),
                       accel_range=(-4.8, 3.0), steer_range=(-0.6, 0.6))


@pytest.mark.parametrize(("rear_axle", "hint"), [
    ((-1350.0, 0.0), "millimetres"), ((0.0, -1350.0), "millimetres"), ((-135.0, 0.0), "centimetres"),
    ((-45.0, 0.0), ""), ((1e9, 1e9), ""),
])
def test_a_rear_axle_no_car_has_is_refused_with_the_unit_hint(rear_axle, hint):
    with pytest.raises(ValueError, match=r"^TrackedCar: rear_axle=") as info:
        TrackedCar(body="car", rear_axle=rear_axle)
    message = str(info.value)
    far = math.hypot(*rear_axle)
    assert f"is {far:g} m from the body's origin" in message and f"within {CAR_SIZE:g} m" in message, message
    assert hint in message and "\n" not in message
    if not hint:
        assert "?" not in message


def test_a_rear_axle_within_a_car_is_taken():
    assert TrackedCar(rear_axle=(-1.35, 0.0)).rear_axle == (-1.35, 0.0)
    assert TrackedCar(rear_axle=(-CAR_SIZE, 0.0)).rear_axle == (-CAR_SIZE, 0.0)


def test_attach_refuses_a_rear_axle_in_millimetres_before_reading_anything(scene):
    model = mujoco.MjModel.from_xml_path(str(DEFAULT_SCENE))
    with pytest.raises(ValueError, match="millimetres"):
        attach(model, mujoco.MjData(model), ego=TrackedCar(rear_axle=(-1350.0, 0.0)))


@pytest.mark.parametrize(("length", "width"), [
    (CAR_LENGTH[1], 1.8), (29.6, 2.5), (4.6, CAR_WIDTH[1]), (4.6, 9.8), (CAR_LENGTH[1], CAR_WIDTH[1]),
])
def test_the_monitor_takes_every_car_car_geometry_takes(scene, length, width):
    car = _car(length, width)
    for cars in ({"obstacle": car}, {"ego": car}):
        monitor = CDFMonitor(scene.layout(), rng=0, **cars)
        assert monitor.layout.obstacle.length == pytest.approx(length if "obstacle" in cars else 4.6)


def test_padding_a_car_adds_to_its_box_and_nothing_else():
    car = _car(CAR_LENGTH[1], CAR_WIDTH[1])
    wide = car.padded(0.3)
    assert np.allclose(wide.hull_half, car.hull_half + 0.3) and not wide.hull_half.flags.writeable
    assert wide.wheelbase == car.wheelbase and np.array_equal(wide.eye_offset, car.eye_offset)
    assert car.padded(0.0) is car
    for bad in (math.nan, math.inf, -car.hull_half[1], 2 * CAR_SIZE):
        with pytest.raises(ValueError, match=r"^CarGeometry\.padded"):
            car.padded(bad)
