"""Scene checks that catch meaning (cdf_mj.sim.checks): swapped routes, a conflict point off
the ego's route, angles in degrees, a timestep that does not divide the tick, an explicit
integrator, cars that do not move when commanded. Real MuJoCo models, built by
tests/junctions.py on junctions that are rotated and mirrored so that no check leans on
the default's coordinates."""

from __future__ import annotations

import math
import shutil
import warnings
from pathlib import Path

import mujoco
import pytest
from junctions import Placement, build_junction

from cdf_mj.config import SceneNames
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.checks import SceneError, SceneWarning, substeps
from cdf_mj.sim.scene import Scene, read_layout

MOVED = {"rotation": 2.3, "mirror": True, "center": (30.0, -12.0)}
PLACE = Placement(MOVED["rotation"], MOVED["mirror"], MOVED["center"])
NAMES = SceneNames()
#: Our car at 1:10 (a 0.46 m box), for junctions read without cars.
SMALL_CAR = CarGeometry(wheelbase=0.27, hull_offset=(0.135, 0.0), hull_half=(0.23, 0.09), hull_height=0.145,
                        eye_offset=(0.12, 0.035, 0.12), accel_range=(-0.4877, 0.3), steer_range=(-0.6, 0.6))


def _load(spec: mujoco.MjSpec, *, drive: bool = True) -> Scene:
    return Scene.from_model(spec.compile(), names=NAMES, source="test.xml", drive=drive)


def _error(spec: mujoco.MjSpec, *, drive: bool = True) -> str:
    with pytest.raises(SceneError) as err:
        _load(spec, drive=drive)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("scene test.xml: ")
    return msg


def _set_site(spec: mujoco.MjSpec, name: str, local_xy: tuple[float, float]) -> None:
    spec.site(name).pos = [*PLACE.point(local_xy), 0.0]


@pytest.mark.parametrize("kw", [{}, MOVED, {"rotation": -0.9, "lane_width": 3.2}])
def test_good_junctions_pass_every_check(kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no SceneWarning either
        _load(build_junction(**kw))


# ------------------------------------------------------------------ routes, conflict
def test_swapped_routes_are_named_as_such():
    spec = build_junction(**MOVED)
    left, right = spec.body(NAMES.route_left), spec.body(NAMES.route_right)
    left.name, right.name = "tmp", NAMES.route_left
    left.name = NAMES.route_right
    msg = _error(spec)
    assert "routes swapped?" in msg
    assert f"body '{NAMES.route_left}' never enters the ego's lane (site '{NAMES.ego_lane}')" in msg


def test_a_right_route_into_the_ego_lane_is_refused():
    spec = build_junction(**MOVED, right_radius=6.0)
    sites = spec.body(NAMES.route_right).sites
    sites[-1].pos = [*PLACE.point((-150.0, -1.85)), 0.0]  # ends in the ego's lane
    msg = _error(spec)
    assert f"body '{NAMES.route_right}' enters the ego's lane" in msg
    assert "swapped" not in msg


def test_a_conflict_point_on_the_wrong_carriageway_is_refused():
    spec = build_junction(**MOVED)
    _set_site(spec, NAMES.conflict, (2.5, 1.85))  # the westbound lane, not the ego's
    msg = _error(spec)
    assert f"site '{NAMES.conflict}' is 3.7 m from the ego's route" in msg
    assert "wrong carriageway?" in msg


def test_a_reversed_ego_route_is_refused():
    spec = build_junction(**MOVED)
    sites = spec.body(NAMES.route_ego).sites
    a, b = list(sites[0].pos), list(sites[1].pos)
    sites[0].pos, sites[1].pos = b, a
    msg = _error(spec)
    assert f"site '{NAMES.conflict}' is not ahead of site '{NAMES.ego_start}'" in msg
    assert "runs against the ego's direction" in msg


# ------------------------------------------------------------------ angles in degrees
def _copy_models(tmp_path: Path) -> Path:
    out = tmp_path / "xml"
    shutil.copytree(MODELS_DIR, out, ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    return out


def test_a_file_whose_compiler_reads_degrees_is_refused(tmp_path: Path):
    models = _copy_models(tmp_path)
    world = models / "intersection.xml"
    text = world.read_text()
    assert '<compiler angle="radian"' in text
    world.write_text(text.replace('<compiler angle="radian"', '<compiler angle="degree"'))
    with pytest.raises(SceneError) as err:
        Scene.load(models / "scene.xml")
    msg = str(err.value)
    assert "the compiler reads angles in degrees" in msg and '<compiler angle="radian"/>' in msg
    # what it did: the start site's euler -1.5707963 read as degrees
    assert f"site '{NAMES.obstacle_start}' heads -1.6 deg but body '{NAMES.route_left}' starts " \
           "towards -90.0 deg" in msg


def test_a_compiler_left_at_mujocos_default_is_refused(tmp_path: Path):
    models = _copy_models(tmp_path)
    for name in ("intersection.xml",):
        path = models / name
        path.write_text(path.read_text().replace('<compiler angle="radian" autolimits="true"/>',
                                                 '<compiler autolimits="true"/>'))
    with pytest.raises(SceneError, match="the compiler reads angles in degrees"):
        Scene.load(models / "scene.xml")


def test_what_degrees_give_away_in_a_compiled_model():
    spec = build_junction(**MOVED)
    spec.actuator("ego_steer").ctrlrange = [-35.0, 35.0]  # written in degrees
    spec.joint("obstacle_steer").range = [-0.6 * math.pi / 180, 0.6 * math.pi / 180]  # converted
    msg = _error(spec, drive=False)
    assert "actuator 'ego_steer' has a ctrlrange of [-35.0, 35.0], beyond 90 deg: angles in degrees?" in msg
    assert "joint 'obstacle_steer' has a range of +-0.01047 rad" in msg


# ------------------------------------------------------------------ timestep and integrator
def test_the_tick_must_be_a_whole_number_of_timesteps():
    spec = build_junction()
    spec.option.timestep = 0.03
    scene = _load(spec)
    with pytest.raises(SceneError, match=r"dt=0\.1 s is not a whole multiple of the timestep 0\.03 s"):
        scene.substeps(0.1)
    assert scene.substeps(0.09) == 3
    assert substeps(0.005, 0.1) == 20 and substeps(0.002, 0.1) == 50
    with pytest.raises(SceneError, match=r"0\.3 steps per tick"):
        substeps(0.5, 0.15)


@pytest.mark.parametrize("integrator", ["mjINT_EULER", "mjINT_RK4"])
def test_an_explicit_integrator_is_warned_and_diverges_in_the_test_drive(integrator: str):
    spec = build_junction(**MOVED)
    spec.option.integrator = getattr(mujoco.mjtIntegrator, integrator)
    name = integrator.removeprefix("mjINT_")
    with pytest.warns(SceneWarning, match=f"integrator {name} treats velocity-dependent actuator forces"):
        _load(spec, drive=False)  # observed only: a warning
    with pytest.warns(SceneWarning), pytest.raises(SceneError, match=f"diverged in a test drive.*{name}"):
        _load(spec)  # driven: our car diverges


def test_implicit_integrator_is_fine():
    spec = build_junction()
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICIT
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _load(spec)


# ------------------------------------------------------------------ cars that do not respond
def test_a_car_that_does_not_move_when_commanded_is_an_error_when_driven():
    spec = build_junction(**MOVED)
    spec.actuator("obstacle_accel").gear = [0, 0, 0, 0, 0, 0]
    msg = _error(spec)
    assert "car 'obstacle_' does not drive forward when commanded" in msg
    assert "moved body 'obstacle_chassis' 0.000 m" in msg and "ego_" not in msg.split(";")[0]
    _load(spec, drive=False)  # a user who only observes the car may drive it another way


def test_a_steering_actuator_on_another_joint_is_an_error():
    spec = build_junction(**MOVED)
    spec.actuator("ego_steer").target = "ego_yaw"  # drives the chassis yaw, not the wheels
    msg = _error(spec)
    assert "car 'ego_' does not steer when commanded" in msg


def test_a_car_that_turns_right_when_steered_left_is_an_error():
    spec = build_junction(**MOVED)
    spec.joint("ego_steer").axis = [0, 0, -1]  # positive steer turns the wheels right
    msg = _error(spec)
    assert "car 'ego_' turns right" in msg and "when steered left" in msg


def test_every_problem_is_listed_at_once():
    spec = build_junction(**MOVED)
    left, right = spec.body(NAMES.route_left), spec.body(NAMES.route_right)
    left.name, right.name = "tmp", NAMES.route_left
    left.name = NAMES.route_right
    _set_site(spec, NAMES.conflict, (2.5, 1.85))
    spec.actuator("obstacle_steer").ctrlrange = [-30.0, 30.0]
    spec.delete(spec.site(NAMES.commit))
    msg = _error(spec)
    for fragment in (f"lacks site '{NAMES.commit}'", "routes swapped?", "wrong carriageway?",
                     "beyond 90 deg"):
        assert fragment in msg, fragment


# ------------------------------------------------------------------ a testbed at another scale
def _junction_error(spec: mujoco.MjSpec) -> str:
    """The SceneError of reading a junction without our cars (the monitor's check)."""
    with pytest.raises(SceneError) as err:
        read_layout(spec.compile(), NAMES, ego=SMALL_CAR, obstacle=SMALL_CAR)
    return str(err.value)


@pytest.mark.parametrize("scale", [0.5, 0.1, 0.05])
def test_a_correct_small_junction_loads(scale: float):
    """The paper's junction at 1:2, 1:10 (0.37 m lanes) and 1:20, moved and mirrored: every
    check passes (a route's start direction measured over a fixed 1 m refused 1:10)."""
    spec = build_junction(**MOVED, scale=scale, cars=False)
    layout = read_layout(spec.compile(), NAMES, ego=SMALL_CAR, obstacle=SMALL_CAR)
    assert layout.ego_lane.half[1] == pytest.approx(1.85 * scale)


def test_a_wrong_small_junction_is_told_in_its_own_metres():
    spec = build_junction(**MOVED, scale=0.1, cars=False)
    start = spec.site(NAMES.obstacle_start)
    start.quat = [math.cos(0.5), 0.0, 0.0, math.sin(0.5)]  # turned by 1 rad off its routes
    msg = _junction_error(spec)
    assert f"site '{NAMES.obstacle_start}' heads" in msg and "over its first 0.123 m" in msg
    spec = build_junction(**MOVED, scale=0.1, cars=False)
    spec.site(NAMES.conflict).pos = [*Placement(*MOVED.values(), scale=0.1).point((2.5, 1.85)), 0.0]
    assert f"site '{NAMES.conflict}' is 0.37 m from the ego's route" in _junction_error(spec)


def test_a_lane_in_millimetres_is_named_as_such():
    spec = build_junction(cars=False)
    spec.site(NAMES.ego_lane).size = [150.0, 1850.0, 0.02]
    msg = _junction_error(spec)
    assert f"site '{NAMES.ego_lane}' makes the ego's lane 300 m wide" in msg  # the box's shorter side
    spec.site(NAMES.ego_lane).size = [90000.0, 1850.0, 0.02]
    assert "3700 m wide (its box's shorter side): a lane is 0.05-20 m wide; millimetres?" in _junction_error(spec)
