"""The CDF filter on any MuJoCo model: watch two cars in your simulation, get the posterior
and the brake decision each control step, without :func:`cdf_mj.run_episode`.

You step the physics yourself; every ``config.dt`` (0.1 s) of simulated time you call
:meth:`CDFMonitor.step`, which reads the system pose from your ``MjData`` (rear-axle
``[x, y, theta, v]`` of both cars, world frame: x, y [m], heading from the world x axis
[rad], speed [m/s]), runs one tick of the particle filter and returns a
:class:`Decision`. ::

    import mujoco
    from cdf_mj import SceneNames, add_car, attach

    spec = mujoco.MjSpec.from_file("my_junction.xml")     # roads, routes, sites, buildings
    add_car(spec, "ego_", pos=(-40, -1.85), yaw=0.0)
    add_car(spec, "obstacle_", pos=(-1.85, 8.35), yaw=-1.5708)
    model = spec.compile(); data = mujoco.MjData(model)
    monitor = attach(model, data, SceneNames(route_ego="my_ego_path"))
    nstep = round(monitor.scenario.dt / model.opt.timestep)  # physics steps per 0.1 s tick
    for _ in range(80):
        ...                                   # your controls into data.ctrl
        mujoco.mj_step(model, data, nstep=nstep)
        decision = monitor.step()
        if decision.brake: ...                # P(cutoff) reached tau: brake at the maximum rate

The cars must have the elements of our car (``models/xml/car.xml``; :func:`add_car` puts
it in your ``MjSpec``) and the world the sites and routes of docs/SCENES.md, under the
names of a :class:`cdf_mj.config.SceneNames`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig, SceneNames
from cdf_mj.inference.particle_filter import ParticleFilter, Posterior
from cdf_mj.sim.scene import Scene

__all__ = ["CDFMonitor", "Decision", "attach"]


@dataclass(frozen=True)
class Decision:
    """The monitor's answer at one control step."""

    t: float  # [s] simulated time (data.time) of the measurement
    poses: np.ndarray  # (2, 4) measured system pose: ego, obstacle [x m, y m, theta rad, v m/s]
    posterior: Posterior  # P(left), P(right), P(seen), P(cutoff), effective sample size
    brake: bool  # P(cutoff) has reached tau at this step or an earlier one (latched)
    brake_time: float | None  # [s] the first step at which it did


class CDFMonitor:
    """The CDF particle filter watching a scene whose physics someone else steps.

    Args:
        scene: the scene to watch (:meth:`cdf_mj.sim.scene.Scene.from_model` for your own
            model and data); use :func:`attach` to build it from a model.
        scenario: the obstacle model the filter assumes (beta, noise, driver behaviour,
            ``dt``, prior P(left)); default :class:`ScenarioConfig`.
        cdf: filter parameters (N, Sigma, tau); default :class:`CDFConfig`.
        rng: the Generator of the filter's randomness, or a seed.

    :meth:`step` must be called every ``scenario.dt`` of simulated time (``data.time``),
    within half a physics step; ValueError otherwise, as the filter's dynamics assume that
    tick. After resetting your simulation, call :meth:`reset`.
    """

    def __init__(self, scene: Scene, scenario: ScenarioConfig | None = None,
                 cdf: CDFConfig | None = None,
                 rng: np.random.Generator | int | None = None) -> None:
        self.scene = scene
        self.scenario = scenario or ScenarioConfig()
        self.cdf = cdf or CDFConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.filter = ParticleFilter.from_layout(scene.layout(), self.scenario, self.cdf, self.rng)
        self.reset()

    def reset(self) -> None:
        """Forget the episode: the next :meth:`step` starts the filter from the prior.

        The filter's random stream goes on from where it was, so a replayed episode gets
        other draws; build a new monitor with the same ``rng`` seed to repeat one exactly."""
        self._last_t: float | None = None
        self.brake_time: float | None = None
        self.decision: Decision | None = None

    def step(self) -> Decision:
        """Read both poses from the data, run one filter tick, return the decision.

        The first call after :meth:`reset` starts the filter at the measured pose (the
        obstacle waiting, unseen ego, intent from the prior); later calls weigh the
        particles by the new measurement and resample, then propagate them one tick.
        """
        data = self.scene.data
        t = float(data.time)
        if self._last_t is not None:
            elapsed = t - self._last_t
            tol = 0.5 * self.scene.model.opt.timestep + 1e-9
            if not math.isclose(elapsed, self.scenario.dt, abs_tol=tol):
                raise ValueError(f"CDFMonitor.step: {elapsed:.4g} s of simulated time since the "
                                 f"last call; call it every dt={self.scenario.dt} s, or reset() "
                                 "after resetting the simulation")
        poses = self.scene.poses()
        post = self.filter.reset(poses) if self._last_t is None else self.filter.update(poses)
        self.filter.predict(poses)
        self._last_t = t
        if self.brake_time is None and post.p_cutoff >= self.cdf.tau:
            self.brake_time = round(t, 6)
        self.decision = Decision(t=t, poses=poses, posterior=post,
                                 brake=self.brake_time is not None, brake_time=self.brake_time)
        return self.decision


def attach(model: mujoco.MjModel, data: mujoco.MjData, names: SceneNames | None = None,
           scenario: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
           rng: np.random.Generator | int | None = None) -> CDFMonitor:
    """A :class:`CDFMonitor` on your model and data: ``names`` picks the ego and obstacle
    cars (their prefixes) and the routes, lanes and sites (docs/SCENES.md). SceneError
    lists every missing or wrong element at once."""
    scene = Scene.from_model(model, data, names)
    return CDFMonitor(scene, scenario, cdf, rng)
