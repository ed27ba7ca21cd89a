"""A testbed at another scale or in other units: cars and configs refuse values in the
wrong unit with the unit in the message, and the CDF monitor, set up as the README's "A
testbed at another scale" says, watches a 1:10 junction with small cars (driven here by
the test as mocap bodies) as it watches the full-size one."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cdf_mj.config import SceneNames
from cdf_mj.model.vehicle import CarGeometry
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
