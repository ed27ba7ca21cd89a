"""The car in MuJoCo follows the paper's kinematic bicycle model.

Paper, section 2 (rear-axle reference point, wheelbase ``l``), in continuous time::

    dx/dt = v cos(theta)      dy/dt = v sin(theta)
    dtheta/dt = v tan(delta) / l      dv/dt = a      (v >= 0: the car cannot reverse)

The reference below integrates these equations on its own (RK4 at 1 ms, no cdf_mj code)
and the MuJoCo car, driven with the same constant controls from :meth:`Scene.reset`,
must stay within the tolerances stated here. ``cdf_mj.model.driver.bicycle_step`` (the
paper's Euler step, used by the drivers and the particle filter) is checked by hand.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from cdf_mj.config import MAX_BRAKE
from cdf_mj.model.driver import bicycle_step
from cdf_mj.sim.scene import Scene

#: Agreement of MuJoCo (timestep 0.005 s, implicitfast) with the continuous bicycle
#: equations over 4 s, checked every 0.1 s. Measured on the cases below: 1.6-5.0 cm in
#: position, < 0.002 rad in heading, < 1e-3 m/s in speed. Sources, largest first:
#:  - the step integrates positions with the velocity of the step's end (first-order
#:    error proportional to the timestep; it halves when the timestep halves);
#:  - the tyres are stiff dampers (1e7 N s/m), not ideal constraints: in a turn the rear
#:    axle slips outward by m v^2 / (R c), about 5e-4 m/s in the gentle curve, which
#:    adds about 2e-4 rad/s of yaw rate (independent of the timestep);
#:  - a car started with its wheels already turned but no yaw rate gets a kick on the
#:    steering hinge for some 0.05 s (about 6e-4 rad of heading), see PRESET_YAW_RATE.
POS_TOL = 0.06  # [m]
HEADING_TOL = 0.01  # [rad]
SPEED_TOL = 0.05  # [m/s]

WHEELBASE = 2.7  # [m] car.xml: body front_axle at x = 2.7 from the rear axle
FT = 0.3048  # [m] per foot
REF_DT = 1e-3  # [s] RK4 step of the reference
TICK = 0.1  # [s] compare every planner tick
# The ego drives on the main road east of the junction (x > 40 m: no buildings there,
# so even the tightest turn below has free space).
START_XY = (60.0, -1.85)


# The fixture `scene` (tests/conftest.py) is the shared default scene; runs reset it.
# Tests that change the model's timestep load their own.


# ------------------------------------------------------------------ reference
def reference(pose0, accel: float, steer: float, duration: float, wheelbase: float = WHEELBASE,
              vmax: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(K,)`` and poses ``(K, 4)`` of the continuous bicycle, every REF_DT.

    Speed has the closed form ``v(t) = clip(v0 + a t, 0, vmax)`` (constant acceleration,
    no reverse); x, y, theta are integrated with classical RK4 using it.
    """
    x0, y0, th0, v0 = (float(p) for p in pose0)

    def speed(t: float) -> float:
        return min(max(v0 + accel * t, 0.0), vmax)

    k_turn = math.tan(steer) / wheelbase

    def f(t: float, z: np.ndarray) -> np.ndarray:
        v = speed(t)
        return np.array([v * math.cos(z[2]), v * math.sin(z[2]), v * k_turn])

    n = round(duration / REF_DT)
    out = np.empty((n + 1, 4))
    z = np.array([x0, y0, th0])
    out[0] = (*z, speed(0.0))
    h = REF_DT
    for i in range(n):
        t = i * h
        k1 = f(t, z)
        k2 = f(t + h / 2, z + h / 2 * k1)
        k3 = f(t + h / 2, z + h / 2 * k2)
        k4 = f(t + h, z + h * k3)
        z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[i + 1] = (*z, speed(t + h))
    return np.arange(n + 1) * h, out


def test_reference_matches_closed_form_circle():
    # Constant speed and steering: a circle of radius l / tan(delta) about the turn centre.
    v, delta, T = 6.0, 0.25, 4.0
    _, ref = reference([0.0, 0.0, 0.0, v], 0.0, delta, T)
    r = WHEELBASE / math.tan(delta)
    th = v * T / r
    np.testing.assert_allclose(ref[-1], [r * math.sin(th), r * (1 - math.cos(th)), th, v], atol=1e-9)


def test_reference_stops_and_stays_stopped():
    v0, a = 13.4, -MAX_BRAKE
    _, ref = reference([0.0, 0.0, 0.0, v0], a, 0.0, 4.0)
    assert ref[-1, 3] == 0.0
    assert ref[-1, 0] == pytest.approx(v0 ** 2 / (2 * MAX_BRAKE), abs=1e-6)
    assert np.all(np.diff(ref[:, 0]) >= 0)


# ------------------------------------------------------------------ MuJoCo vs reference
def run_mujoco(scene: Scene, which: str, pose0, accel: float, steer: float,
               duration: float, preset_yaw_rate: bool = True) -> np.ndarray:
    """Poses ``(K, 4)`` of one car every TICK, from ``pose0`` with constant controls.

    The steering hinge starts at the commanded angle, so that the comparison is with
    the bicycle model at constant steering from t = 0 (no servo transient). With
    ``preset_yaw_rate`` the chassis also starts with the kinematic yaw rate
    ``v tan(delta) / l`` that the bicycle model has at once.
    """
    other = "obstacle" if which == "ego" else "ego"
    parked = np.array([-100.0, -1.85, 0.0, 0.0])  # the other car, out of the way
    poses = {which: np.asarray(pose0, dtype=float), other: parked}
    scene.reset(ego=poses["ego"], obstacle=poses["obstacle"])
    car = scene.car(which)
    scene.data.qpos[car.steer_qpos] = steer
    if preset_yaw_rate:
        scene.data.qvel[car.qvel[2]] = poses[which][3] * math.tan(steer) / car.geometry.wheelbase
    scene.set_controls(which, accel=accel, steer=steer)
    mujoco.mj_forward(scene.model, scene.data)
    per_tick = round(TICK / scene.model.opt.timestep)
    out = [scene.pose(car)]
    for _ in range(round(duration / TICK)):
        assert scene.step(per_tick) is None, "the car hit something: the test's route is not free"
        out.append(scene.pose(car))
    assert all(w.number == 0 for w in scene.data.warning[: int(mujoco.mjtWarning.mjNWARNING)])
    return np.array(out)


def errors(sim: np.ndarray, ref: np.ndarray) -> tuple[float, float, float]:
    """Largest position [m], heading [rad] and speed [m/s] differences along a run."""
    pos = np.hypot(sim[:, 0] - ref[:, 0], sim[:, 1] - ref[:, 1]).max()
    heading = np.abs(np.remainder(sim[:, 2] - ref[:, 2] + np.pi, 2 * np.pi) - np.pi).max()
    speed = np.abs(sim[:, 3] - ref[:, 3]).max()
    return float(pos), float(heading), float(speed)


CASES = {
    # name: (v0 [m/s], accel [m/s^2], steer [rad], duration [s])
    "straight": (13.4, 0.0, 0.0, 4.0),
    "turn": (6.0, 1.0, 0.25, 4.0),
    "gentle_curve": (13.4, 0.0, 0.05, 4.0),
    "braking": (13.4, -4.877, 0.0, 4.0),  # stops after 2.75 s, then must stay stopped
    "braking_in_curve": (13.4, -4.877, 0.1, 4.0),
}


@pytest.mark.parametrize("preset_yaw_rate", [True, False], ids=["yaw_rate_preset", "wheels_only"])
@pytest.mark.parametrize("case", list(CASES))
def test_mujoco_follows_bicycle_equations(scene: Scene, case: str, preset_yaw_rate: bool):
    v0, accel, steer, duration = CASES[case]
    pose0 = [*START_XY, 0.0, v0]
    sim = run_mujoco(scene, "ego", pose0, accel, steer, duration, preset_yaw_rate)
    vmax = float(scene.model.actuator_actrange[scene.ego.accel, 1])
    _t, ref = reference(pose0, accel, steer, duration, scene.ego.geometry.wheelbase, vmax)
    stride = round(TICK / REF_DT)
    ref = ref[::stride]
    assert len(ref) == len(sim)
    pos, heading, speed = errors(sim, ref)
    assert pos < POS_TOL, f"{case}: position error {pos:.4f} m"
    assert heading < HEADING_TOL, f"{case}: heading error {heading:.5f} rad"
    assert speed < SPEED_TOL, f"{case}: speed error {speed:.5f} m/s"
    assert np.all(sim[:, 3] >= -1e-6), "the car reversed"
    if accel < 0:
        # Stopped for good: no creep after the stop.
        assert sim[-1, 3] == pytest.approx(0.0, abs=1e-3)
        assert np.hypot(*(sim[-1, :2] - sim[-5, :2])) < 1e-3


def test_obstacle_car_follows_the_same_model(scene: Scene):
    v0, accel, steer, duration = CASES["turn"]
    pose0 = [*START_XY, 0.0, v0]
    sim = run_mujoco(scene, "obstacle", pose0, accel, steer, duration)
    _, ref = reference(pose0, accel, steer, duration, scene.obstacle.geometry.wheelbase)
    pos, heading, speed = errors(sim, ref[:: round(TICK / REF_DT)])
    assert pos < POS_TOL and heading < HEADING_TOL and speed < SPEED_TOL


@pytest.mark.parametrize("case", ["turn", "braking"])
def test_error_shrinks_with_the_timestep(case: str):
    # Most of the position error is discretisation: halving the physics timestep
    # roughly halves it (measured: turn 2.8 -> 1.3 cm, braking 3.1 -> 1.5 cm), which a
    # modelling difference (e.g. a wrong wheelbase or speed) would not do.
    v0, accel, steer, duration = CASES[case]
    pose0 = [*START_XY, 0.0, v0]
    _, ref = reference(pose0, accel, steer, duration)
    ref = ref[:: round(TICK / REF_DT)]
    errs = []
    for dt in (0.005, 0.0025):
        scene = Scene.load()
        scene.model.opt.timestep = dt
        errs.append(errors(run_mujoco(scene, "ego", pose0, accel, steer, duration), ref)[0])
    assert errs[1] < 0.6 * errs[0], errs


# ------------------------------------------------------------------ model constants
def test_wheelbase_from_model(scene: Scene):
    for car in scene.cars.values():
        assert car.geometry.wheelbase == pytest.approx(WHEELBASE, abs=1e-3)


def test_max_brake_is_16_ft_per_s2(scene: Scene):
    assert pytest.approx(16 * FT, abs=1e-12) == MAX_BRAKE
    for car in scene.cars.values():
        assert car.geometry.max_brake == pytest.approx(16 * FT, abs=1e-3)
        assert car.geometry.accel_range[0] < 0 < car.geometry.accel_range[1]


def test_speed_state_cannot_go_negative(scene: Scene):
    for car in scene.cars.values():
        assert scene.model.actuator_actlimited[car.accel]
        assert scene.model.actuator_actrange[car.accel, 0] == 0.0


# ------------------------------------------------------------------ bicycle_step
def test_bicycle_step_one_step_by_hand():
    x = np.array([1.0, 2.0, 0.3, 5.0])
    u = np.array([2.0, 0.1])
    dt, wheelbase = 0.1, 2.7
    # Paper: x += v dt cos th; y += v dt sin th; th += v dt / l tan(delta); v += a dt.
    expected = np.array([1.0 + 0.5 * math.cos(0.3),
                         2.0 + 0.5 * math.sin(0.3),
                         0.3 + 0.5 / 2.7 * math.tan(0.1),
                         5.2])
    np.testing.assert_allclose(bicycle_step(x, u, dt, wheelbase), expected, rtol=0, atol=1e-12)
    # Numbers written out: cos 0.3 = 0.955336, sin 0.3 = 0.295520, tan 0.1 = 0.100335.
    np.testing.assert_allclose(bicycle_step(x, u, dt, wheelbase), [1.477668, 2.147760, 0.318581, 5.2],
                               atol=1e-6)


def test_bicycle_step_vectorised_shapes():
    rng = np.random.default_rng(7)
    n = 50
    x = np.column_stack([rng.normal(size=(n, 3)), rng.uniform(0, 15, n)])
    u = np.column_stack([rng.uniform(-5, 3, n), rng.uniform(-0.6, 0.6, n)])
    out = bicycle_step(x, u, 0.1, WHEELBASE)
    assert out.shape == (n, 4)
    for i in (0, 17, n - 1):
        np.testing.assert_allclose(out[i], bicycle_step(x[i], u[i], 0.1, WHEELBASE), atol=1e-15)
    # One control for all states broadcasts; so do extra leading axes.
    assert bicycle_step(x, u[0], 0.1, WHEELBASE).shape == (n, 4)
    assert bicycle_step(x.reshape(5, 10, 4), u.reshape(5, 10, 2), 0.1, WHEELBASE).shape == (5, 10, 4)
    # Inputs are not modified.
    x_copy = x.copy()
    bicycle_step(x, u, 0.1, WHEELBASE)
    np.testing.assert_array_equal(x, x_copy)


def test_bicycle_step_speed_never_negative():
    rng = np.random.default_rng(8)
    n = 1000
    x = np.column_stack([np.zeros((n, 3)), rng.uniform(0, 1.0, n)])
    u = np.column_stack([rng.uniform(-20.0, 0.0, n), np.zeros(n)])
    out = bicycle_step(x, u, 0.1, WHEELBASE)
    assert np.all(out[:, 3] >= 0.0)
    assert np.any(out[:, 3] == 0.0)
    # Repeated braking from speed stays at exactly zero.
    s = np.array([0.0, 0.0, 0.0, 13.4])
    for _ in range(40):
        s = bicycle_step(s, np.array([-MAX_BRAKE, 0.0]), 0.1, WHEELBASE)
        assert s[3] >= 0.0
    assert s[3] == 0.0


def test_bicycle_step_converges_to_the_continuous_equations():
    # The Euler step at a small dt agrees with the RK4 reference (first-order convergence).
    v0, accel, steer, duration = CASES["turn"]
    pose0 = np.array([0.0, 0.0, 0.0, v0])
    _, ref = reference(pose0, accel, steer, duration)
    errs = []
    for dt in (0.004, 0.002):
        s = pose0.copy()
        for _ in range(round(duration / dt)):
            s = bicycle_step(s, np.array([accel, steer]), dt, WHEELBASE)
        errs.append(float(np.hypot(*(s[:2] - ref[-1, :2]))))
    assert errs[1] < 0.05
    assert errs[1] == pytest.approx(errs[0] / 2, rel=0.1)
