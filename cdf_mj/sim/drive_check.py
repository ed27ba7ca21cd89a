"""Scene checks that need more than the model: the scenario tick must be a whole multiple
of the timestep (:func:`substeps`), and both cars must move, speed up and steer when
commanded (:func:`check_drive`, a test drive on a scratch ``MjData``). ::

    from cdf_mj.sim.drive_check import check_drive, substeps
    n = substeps(model.opt.timestep, 0.1, source="my_scene.xml")
    check_drive(model, SceneNames(), source="my_scene.xml")   # SceneError or nothing
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from cdf_mj.config import SceneNames
from cdf_mj.sim.errors import SceneError

__all__ = ["MAX_SUBSTEPS", "MIN_TIMESTEP", "check_drive", "substeps"]

#: [s] The shortest physics timestep of a scene (``<option timestep>``): 10^4 steps per
#: simulated second. Shorter ones make an episode take minutes to hours (10^-6 s: 51 s for
#: one episode; 10^-9 s: 10^8 steps per tick) and are refused when the scene is loaded.
MIN_TIMESTEP = 1e-4
#: Most physics steps per scenario tick (``timing.dt / timestep``): 1000, the paper's 0.1 s
#: tick at :data:`MIN_TIMESTEP`.
MAX_SUBSTEPS = 1000

_DRIVE_TIME = 0.3  # [s] length of each phase of the test drive
_FAR = (2000.0, -3000.0)  # [m] chassis-frame y of ego, obstacle in the test drive: apart, alone


def substeps(timestep: float, dt: float, source: str = "<model>") -> int:
    """Physics steps per scenario tick, ``dt / timestep`` [s / s], which must be a whole
    number from 1 to :data:`MAX_SUBSTEPS`: SceneError naming both otherwise (a 0.03 s
    timestep would make ticks of 0.09 s, not 0.1 s)."""
    ratio = dt / timestep
    n = round(ratio)
    if n < 1 or abs(ratio - n) > 1e-6 * max(1.0, ratio):
        raise SceneError(f"scene {source}: the scenario tick timing.dt={dt:g} s is not a whole multiple of "
                         f"the timestep {timestep:g} s ({ratio:.4g} steps per tick); use a timestep "
                         f"that divides it, e.g. {dt / max(n, 1):.4g} s or 0.005 s, or another timing.dt")
    if n > MAX_SUBSTEPS:
        raise SceneError(f"scene {source}: the scenario tick timing.dt={dt:g} s is {n} timesteps of "
                         f"{timestep:g} s, more than {MAX_SUBSTEPS} physics steps per tick; use a timestep "
                         f"of at least {dt / MAX_SUBSTEPS:g} s, or a shorter timing.dt")
    return n


def check_drive(model: mujoco.MjModel, names: SceneNames, source: str = "<model>") -> None:
    """Test-drive both cars on a scratch ``MjData`` (the model is not changed): from rest,
    full acceleration for 0.3 s, then half the left steering limit for 0.3 s, each car alone
    and far from everything. SceneError listing every car that does not move forward, does
    not speed up, does not steer, or turns the wrong way; or if the simulation diverges.

    Run it once for a scene whose cars the code will drive (``Scene``, ``World``,
    ``run_episode``), not for cars that are only observed. Expects a model that passed
    :func:`validate` with its cars. About 0.6 s of simulated time.
    """
    m, n = model, names
    d = mujoco.MjData(m)
    cars = []
    for p, far in zip((n.ego_prefix, n.obstacle_prefix), _FAR, strict=True):
        x, y, yaw = (m.joint(p + j) for j in n.planar_joints)
        d.qpos[y.qposadr[0]] = far  # alone: no building, ground marking or other car near it
        cars.append(_TestCar(p, int(x.qposadr[0]), int(x.dofadr[0]), int(yaw.qposadr[0]),
                             m.actuator(p + n.accel), m.actuator(p + n.steer),
                             int(m.joint(p + n.steer_joint).qposadr[0])))
    mujoco.mj_forward(m, d)
    nstep = max(1, round(_DRIVE_TIME / m.opt.timestep))
    t = nstep * m.opt.timestep

    def run(phase: str) -> None:
        mujoco.mj_step(m, d, nstep=nstep)
        w = d.warning
        if (w[mujoco.mjtWarning.mjWARN_BADQACC].number or w[mujoco.mjtWarning.mjWARN_BADQVEL].number
                or w[mujoco.mjtWarning.mjWARN_BADQPOS].number or not np.all(np.isfinite(d.qpos))):
            integrator = mujoco.mjtIntegrator(int(m.opt.integrator)).name.removeprefix("mjINT_")
            raise SceneError(f"scene {source}: the simulation diverged in a test drive of the cars "
                             f"({phase}; integrator {integrator}, timestep {m.opt.timestep:g} s): "
                             "use <option integrator=\"implicitfast\"/>")

    bad: list[str] = []
    for c in cars:
        d.ctrl[c.accel.id] = c.accel.ctrlrange[1]
        d.ctrl[c.steer.id] = 0.0
    run("full acceleration")
    drives = {}
    for c in cars:
        a = float(c.accel.ctrlrange[1])
        want_x, want_v = 0.5 * a * t * t, a * t
        dx, v, yaw = float(d.qpos[c.qx]), float(d.qvel[c.vx]), float(d.qpos[c.qyaw])
        drives[c.prefix] = dx > 0.5 * want_x and v > 0.5 * want_v and abs(yaw) < 0.05
        if not drives[c.prefix]:
            bad.append(f"car '{c.prefix}' does not drive forward when commanded: actuator "
                       f"'{c.prefix}{n.accel}' at {a:g} m/s^2 for {t:g} s moved body "
                       f"'{c.prefix}{n.chassis}' {dx:.3f} m at {v:.2f} m/s and turned it {yaw:.3f} rad "
                       f"(expected about {want_x:.3f} m, {want_v:.2f} m/s, 0 rad); check the "
                       "actuator's transmission (gear, site or joint) and gain")
    yaw0 = {c.prefix: float(d.qpos[c.qyaw]) for c in cars}
    for c in cars:
        d.ctrl[c.steer.id] = 0.5 * c.steer.ctrlrange[1]
    run("steering left")
    for c in cars:
        cmd = 0.5 * float(c.steer.ctrlrange[1])
        angle, turned = float(d.qpos[c.steer_q]), float(d.qpos[c.qyaw]) - yaw0[c.prefix]
        if angle < 0.5 * cmd:
            bad.append(f"car '{c.prefix}' does not steer when commanded: actuator "
                       f"'{c.prefix}{n.steer}' at {cmd:.3g} rad for {t:g} s turned joint "
                       f"'{c.prefix}{n.steer_joint}' to {angle:.3g} rad; it must be a position servo "
                       "on that joint")
        elif drives[c.prefix] and turned <= 0.0:
            bad.append(f"car '{c.prefix}' turns right ({turned:.3f} rad) when steered left: a "
                       f"positive angle of joint '{c.prefix}{n.steer_joint}' must turn the car left")
    if bad:
        raise SceneError(f"scene {source}: {'; '.join(bad)}")


@dataclass(frozen=True)
class _TestCar:
    """Addresses of one car in the test drive."""

    prefix: str
    qx: int  # qpos address of the chassis x slide
    vx: int  # dof address of the chassis x slide
    qyaw: int  # qpos address of the yaw hinge
    accel: Any  # the accel actuator's view (model.actuator)
    steer: Any  # the steering actuator's view
    steer_q: int  # qpos address of the steering hinge
