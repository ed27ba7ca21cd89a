"""Gymnasium environment ``cdf_mj/TIntersection-v0``: you drive the ego through the junction.

Registered when ``cdf_mj`` is imported (if Gymnasium is installed: the ``gym`` extra),
also in the worker processes of ``gymnasium.make_vec``::

    import gymnasium as gym
    import cdf_mj  # noqa: F401  (registers the environment)

    env = gym.make("cdf_mj/TIntersection-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=7)            # the world of run_episode(seed=7)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    frame = env.render()                     # (480, 640, 3) uint8 from camera "top"

A scene with no camera ``top`` renders too: through a free camera looking straight down
at the junction (``camera=None``, the default).

The obstacle is the scenario's (:class:`cdf_mj.scenario.world.World`, the same code as
:func:`cdf_mj.run_episode`); the agent replaces the ego's planner and controller, and
senses the obstacle through the ego's own sensor (:class:`cdf_mj.scenario.ego_agent.EgoAgent`:
``config.sensing``'s noise, dropouts, latencies; perfect by default).
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from cdf_mj.config import MAX_SEED, CDFConfig, ScenarioConfig, SceneNames, check_seed
from cdf_mj.extras import require

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError:  # the one-line error that names the extra (require raises it)
    require("gymnasium", "gym", "the environment cdf_mj/TIntersection-v0")
    raise
from cdf_mj.model.driver import Intent
from cdf_mj.scenario.ego_agent import EgoAgent
from cdf_mj.scenario.episode import episode_label
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.world import Measurement, World
from cdf_mj.sim.gl import Offscreen
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["TIntersectionEnv"]

_DEFAULT_CAMERA = "top"  # the camera used when the scene has one and none is named
_FREE_VIEW = 70.0  # [m] what the free camera over the junction shows, top to bottom of the frame
#: Largest collision penalty: 10^6 steps' progress; more swamps every return in float32 [1].
_MAX_PENALTY = 1e6


class _ActionBox(spaces.Box):
    """The action space: a bounded float32 :class:`gymnasium.spaces.Box` whose :meth:`sample`
    draws what ``Box.sample`` draws (one uniform per entry, from ``low`` to ``high``, from
    the same ``np_random`` stream), on Python floats instead of its masks and fancy
    indexing: about 3 µs instead of 18."""

    def sample(self, mask: None = None, probability: None = None) -> np.ndarray:
        """A uniform sample of the box (``Box.sample``'s values); masks are refused as there."""
        if mask is not None or probability is not None:
            return super().sample(mask, probability)
        # Generator.uniform(low, high) is low + (high - low) * random(), in float64: the same
        # operations on Python floats.
        low, high = self.low.tolist(), self.high.tolist()
        u = self.np_random.random(len(low)).tolist()
        return np.array([lo + (hi - lo) * x for lo, hi, x in zip(low, high, u, strict=True)], dtype=self.dtype)


class TIntersectionEnv(gym.Env[np.ndarray, np.ndarray]):
    """The ego car at the T-intersection, with the obstacle driver of the CDF scenario.

    Each :meth:`step` is one planner tick of ``config.timing.dt`` = 0.1 s (20 MuJoCo steps of
    the default scene). Frames: world x east, y north [m]; headings from the x axis
    towards y [rad]; poses are of the rear axle.

    **Action** ``Box(2,)`` float32, the ego's actuator commands, ranges read from the
    model's ``ctrlrange`` (``ego_accel``, ``ego_steer``):

    ===  ==================  ======  =======================
    idx  meaning             unit    range (default scene)
    ===  ==================  ======  =======================
    0    acceleration u1     m/s^2   -4.877 ... 3.0
    1    steering angle u2   rad     -0.6 ... 0.6
    ===  ==================  ======  =======================

    With ``normalized_actions=True`` the box is ``[-1, 1]^2``, mapped affinely onto these
    ranges (Gymnasium's ``check_env`` recommends such a box and warns about any other, so
    the physical default gets that one recommendation from it and nothing else).

    Out-of-range actions are **clipped** to the box (as MuJoCo clips ``ctrl``); an action
    of the wrong shape or with NaN/inf is **refused** with ValueError. The scenario's
    process noise (``noise_accel``, ``noise_steer``) is added to the action, as to the
    obstacle's controls; the speed cannot go below 0 (no reverse).

    **Observation** ``Box(8,)`` float64; ``Box(11,)`` with ``posterior_in_observation``; one
    more entry, last, with ``command_in_observation``.
    Position bounds enclose everything a car can reach in ``duration`` at its top speed;
    speed bounds are [-1, top speed + 1] m/s; values are clipped to the box (a guard):

    =====  =====================================================  ==========
    idx    meaning                                                unit
    =====  =====================================================  ==========
    0-3    ego pose x, y, theta, v (measured system pose S_t)     m, m, rad, m/s
    4-7    obstacle pose x, y, theta, v, as the ego senses it     m, m, rad, m/s
           (``config.sensing``; see **Sensing**)
    8      CDF posterior P(obstacle intends to turn left)         1
    9      CDF posterior P(obstacle has seen the ego)             1
    10     CDF posterior P(cut-off)                               1
    last   the CDF rule's acceleration ``Decision.accel`` (its    m/s^2
           graded command on the ego's speed hold; negative
           when braking), within the ego car's limits
    =====  =====================================================  ==========

    **Sensing** (``config.sensing``; perfect by default: the observation is the truth). The
    ego's sensor is the one of :func:`~cdf_mj.run_episode`'s ego
    (:class:`~cdf_mj.scenario.ego_agent.EgoAgent`, drawing from the seed's ``sensing``
    stream), and the CDF filter (``info["posterior"]``, ``"brake"``, ``"accel"`` and the
    observation's entries 8 on) reads what it senses:

    =================  ===============================================================
    option             what the agent gets
    =================  ===============================================================
    ``pos``,           the obstacle pose plus Gaussian noise of these std [m] (x and y),
    ``heading``,       [rad], [m/s]; the ego's own pose is exact
    ``speed``
    ``latency``        the obstacle pose ``latency`` steps old
    ``dropout``        with this probability per step no measurement: the observation
                       keeps the last measured obstacle pose (before any, a fixed
                       placeholder: the map's obstacle start site at rest,
                       ``layout.obstacle_start``, wherever the obstacle really starts, e.g.
                       a driver family's own start) and ``info["obstacle_measured"]`` is
                       False; the filter skips that update
    ``brake_latency``  the action's acceleration acts ``brake_latency`` steps late (until
                       the first arrives, the ego's own speed hold, as in
                       ``run_episode``); its steering at once
    =================  ===============================================================

    With any of these set, ``info`` also has ``true_poses`` ((2, 4) float64 array, the true
    system pose: ego, obstacle) and ``obstacle_measured``; the other entries of ``info`` are
    the truth whatever the sensing.

    **Reward** per step, the sum of:

    ===========  ======================================================  ===========
    term         value                                                   unit
    ===========  ======================================================  ===========
    progress     distance the ego's rear axle advanced along its route   1 (= 1.0 per
                 in the step / (``ego_speed`` x ``dt``)                  step at 13.4 m/s)
    collision    ``-collision_penalty`` (default 100) on the step the    1
                 ego touches the obstacle or a building
    ===========  ======================================================  ===========

    **Episode end**:

    ==========  =========================================================================
    kind        condition
    ==========  =========================================================================
    terminated  the ego touched the obstacle or a building (``info["collision"]``)
    terminated  the ego's rear axle is 20 m past the conflict point (the junction is behind)
    truncated   ``config.timing.duration`` elapsed (8 s = 80 steps by default)
    ==========  =========================================================================

    **info** (after reset and every step): ``posterior`` (dict ``p_left``, ``p_right``,
    ``p_seen``, ``p_cutoff``, ``ess`` of the CDF filter watching the episode, or None with
    ``run_filter=False``; on a collision step it is the one of the previous step),
    ``brake`` (the CDF would brake hard now, by its decision rule: ``CDFConfig.decision``),
    ``accel`` (the acceleration the CDF's rule commands now [m/s^2], ``Decision.accel``; None
    with ``run_filter=False``), ``collision``
    (None, ``"obstacle"`` or ``"building"``), ``label`` (``Cutoff``/``Yield``/``Right``
    from the constant-speed counterfactual of the same seed, None with ``label=False``),
    ``intent`` (``left``/``right``), ``t`` [s], ``obstacle_in_lane`` (the truth), ``gap`` [m]
    between the two collision boxes at the start of the step (0 when they touch; None after
    reset), ``episode_seed``; with imperfect sensing also ``true_poses`` and
    ``obstacle_measured`` (**Sensing**). ``label``, ``intent``, ``obstacle_in_lane``, ``gap``
    and ``true_poses`` are ground truth for evaluation: a policy should not read them.

    **Seeding**: ``reset(seed=n)`` plays the world of ``run_episode(seed=n)`` (same
    intent, ego start, obstacle observations and noise); ``reset()`` without a seed draws
    the episode seed (0 to :data:`~cdf_mj.config.MAX_SEED`) from the environment's
    ``np_random``; a seed that is not such an integer (``True``, ``2**64``) is a ValueError.

    Args:
        render_mode: None or ``"rgb_array"``.
        scene: path of an MJCF scene or a loaded :class:`Scene` (default models/xml/scene.xml).
        config: scenario parameters (default :class:`ScenarioConfig`).
        cdf: CDF filter parameters (default :class:`CDFConfig`).
        posterior_in_observation: append P(left), P(seen), P(cut-off) to the observation.
        command_in_observation: append the CDF rule's acceleration [m/s^2] to the observation.
        run_filter: run the CDF filter (for ``info`` and the observation); about 0.5 ms
            per step at N = 1000.
        label: compute ``info["label"]`` at reset (one counterfactual run, ~15 ms).
        collision_penalty: reward on a collision step, negated [1]: a finite number in
            [0, 10^6] (ValueError otherwise, e.g. for NaN).
        camera: name of the MJCF camera ``render`` uses (``top``, ``ego_chase``, ...), or
            None (default): the scene's camera ``top`` if it has one, else a free camera
            looking straight down at the junction (at the point of the ego's route nearest
            the obstacle's start, the ego driving to the right of the frame, about 70 m
            across). Checked only with ``render_mode="rgb_array"``: ValueError naming the
            scene's cameras if the named one is not among them.
        width, height: rendered frame size [pixels], at most the model's offscreen buffer
            (checked only with ``render_mode="rgb_array"``).
        names: element names of the scene (default :class:`SceneNames`).
        normalized_actions: the action space is ``[-1, 1]^2`` instead, mapped affinely onto
            the actuator ranges (-1 = maximum braking / full right steer, +1 = maximum
            acceleration / full left steer), as most RL libraries prefer.
    """

    # An instance attribute of gym.Env: each environment sets its own render_fps (1 / dt).
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, scene: str | Path | Scene = DEFAULT_SCENE,
                 config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                 posterior_in_observation: bool = False, run_filter: bool = True,
                 label: bool = True, collision_penalty: float = 100.0, camera: str | None = None,
                 width: int = 640, height: int = 480, names: SceneNames | None = None,
                 normalized_actions: bool = False, command_in_observation: bool = False) -> None:
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode={render_mode!r}: choose None or 'rgb_array'")
        if posterior_in_observation and not run_filter:
            raise ValueError("posterior_in_observation=True needs run_filter=True")
        if command_in_observation and not run_filter:
            raise ValueError("command_in_observation=True needs run_filter=True")
        try:
            penalty = float(collision_penalty) if isinstance(collision_penalty, numbers.Real) else math.nan
        except OverflowError:  # an integer too large for a float
            penalty = math.nan
        if isinstance(collision_penalty, bool) or not 0.0 <= penalty <= _MAX_PENALTY:
            raise ValueError(f"collision_penalty={collision_penalty!r} is out of range: must be a finite "
                             f"number in [0, {_MAX_PENALTY:g}] (the reward on a collision step, negated; "
                             "a progress step earns about 1)")
        self.config = config or ScenarioConfig()
        self.cdf = cdf or CDFConfig()
        if isinstance(scene, Scene) and names is not None:
            raise ValueError("names apply to a scene file; a Scene object was loaded with its own")
        self.scene = scene if isinstance(scene, Scene) else Scene.load(scene, names or self.config.names)
        self.world = World(self.scene, self.config)
        #: The ego's sensor and brake latency (the agent is its planner and controller).
        self.ego = EgoAgent(self.world.layout, self.config, self.world.driver)
        self._sensing = not self.config.sensing.perfect
        self._held: np.ndarray = self.world.layout.obstacle_start  # the last measured obstacle pose
        self._measured_now = True
        self.render_mode = render_mode
        # One frame per planner tick of the scenario (the class default assumes dt = 0.1 s).
        fps = 1.0 / self.config.timing.dt
        self.metadata = {**self.metadata, "render_fps": round(fps) if abs(fps - round(fps)) < 1e-9 else fps}
        self.posterior_in_observation = posterior_in_observation
        self.command_in_observation = command_in_observation
        self.run_filter = run_filter
        self.label = label
        self.collision_penalty = penalty
        m = self.scene.model
        self._camera_id = -1  # -1: the free camera over the junction
        if render_mode is not None:  # no camera, no frame size needed when nothing is drawn
            if camera is not None:
                self._camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, camera)
                if self._camera_id < 0:
                    cams = ", ".join(m.camera(i).name for i in range(m.ncam)) or "none"
                    raise ValueError(f"camera {camera!r} is not in the scene; cameras: {cams} "
                                     "(camera=None looks down at the junction)")
            else:
                self._camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, _DEFAULT_CAMERA)
            if not (0 < width <= m.vis.global_.offwidth and 0 < height <= m.vis.global_.offheight):
                raise ValueError(f"width x height = {width} x {height} must be positive and at most "
                                 f"the scene's offscreen buffer {m.vis.global_.offwidth} x "
                                 f"{m.vis.global_.offheight}")
        #: The camera frames come from: a camera of the scene, or "free" (over the junction).
        self.camera = (m.camera(self._camera_id).name if self._camera_id >= 0 else "free") \
            if render_mode is not None else camera
        self.width, self.height = int(width), int(height)
        self._renderer: Offscreen | None = None  # made on the first render()

        ego = self.world.layout.ego
        self._ctrl_low = np.array([ego.accel_range[0], ego.steer_range[0]])
        self._ctrl_high = np.array([ego.accel_range[1], ego.steer_range[1]])
        self.normalized_actions = normalized_actions
        if normalized_actions:
            self.action_space = _ActionBox(-1.0, 1.0, shape=(2,), dtype=np.float32)
        else:
            self.action_space = _ActionBox(self._ctrl_low.astype(np.float32),
                                           self._ctrl_high.astype(np.float32), dtype=np.float32)
        # The action's bounds and the observation's as Python floats (checked every step).
        self._ctrl_py = (*self._ctrl_low.tolist(), *self._ctrl_high.tolist(),
                         *(self._ctrl_high - self._ctrl_low).tolist())
        self._obs_box = self._observation_box()
        self._obs_bounds = tuple(zip(self._obs_box.low.tolist(), self._obs_box.high.tolist(), strict=True))
        self.observation_space = self._obs_box
        self._monitor: CDFMonitor | None = None
        self._label: str | None = None
        self._episode_seed: int | None = None
        self._intent_name = ""

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` makes it reproducible (see the class docstring)."""
        if seed is not None:  # before gymnasium's own seeding, which takes True for 1
            seed = check_seed(seed)
        super().reset(seed=seed)
        episode_seed = seed if seed is not None else int(self.np_random.integers(MAX_SEED + 1))
        self._episode_seed = episode_seed
        self._label = episode_label(self.config, episode_seed, self.scene) if self.label else None
        m = self.world.reset(episode_seed)
        self.ego.reset(self.world.rng)
        self._held = self.world.layout.obstacle_start
        self._intent_name = Intent(self.world.intent).name.lower()
        self._monitor = None
        sensed = self._sense(m)
        if self.run_filter:  # its trace is not kept: nothing reads it
            self._monitor = CDFMonitor(self.scene, self.config, self.cdf,
                                       rng=self.world.rng["planner"], record_trace=False)
            self._observe(sensed)
        self._s = self._progress(m.poses[0])
        return self._observation(self._seen(sensed)), self._info(m, gap=None)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply the ego's ``[acceleration m/s^2, steering rad]`` for one tick of ``dt``."""
        if self._episode_seed is None:
            raise RuntimeError("call reset() before step()")
        # Two floats: an array of two floats directly (the per-step call), anything else as
        # NumPy reads it; then every check on those two numbers.
        if type(action) is np.ndarray and action.shape == (2,) and action.dtype.char in "fd":
            a0, a1 = action.tolist()
        else:
            a = np.asarray(action, dtype=float)
            a0, a1 = a.tolist() if a.shape == (2,) else (math.nan, math.nan)
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise ValueError(f"action must be 2 finite numbers [acceleration m/s^2, steering "
                             f"rad], got {np.asarray(action).tolist()!r}")
        lo0, lo1, hi0, hi1, w0, w1 = self._ctrl_py
        if self.normalized_actions:  # [-1, 1] -> [ctrl low, ctrl high], affinely
            a0, a1 = min(max(a0, -1.0), 1.0), min(max(a1, -1.0), 1.0)
            a0, a1 = lo0 + 0.5 * (a0 + 1.0) * w0, lo1 + 0.5 * (a1 + 1.0) * w1
        else:  # the model's own limits in float64 (the float32 box would round -4.877 to -4.87699985)
            a0, a1 = min(max(a0, lo0), hi0), min(max(a1, lo1), hi1)
        world = self.world
        tick = world.step(self.ego.drive(a0, a1))  # the acceleration brake_latency steps late
        # After a collision the cars touch: the obstacle is in the ego's sight (visible 1).
        m = world.measure() if tick.collision is None else \
            Measurement(t=world.t, poses=self.scene.poses(), obstacle_in_lane=tick.obstacle_in_lane, visible=1.0)
        sensed = self._sense(m)
        if self._monitor is not None and tick.collision is None:
            self._observe(sensed)
        s = world.ego_arc  # the ego's progress along its route, as _progress(poses[0]) gives it
        reward = (s - self._s) / (self.config.ego.speed * self.config.timing.dt)
        self._s = s
        if tick.collision is not None:
            reward -= self.collision_penalty
        truncated = world.end_reason == "duration"
        terminated = world.end_reason in ("collision", "passed")
        return (self._observation(self._seen(sensed)), float(reward), bool(terminated), bool(truncated),
                self._info(m, gap=0.0 if tick.collision == "obstacle" else tick.gap, collision=tick.collision))

    def render(self) -> np.ndarray | None:
        """An RGB frame ``(height, width, 3)`` uint8 from ``camera``; None without
        ``render_mode="rgb_array"``."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'; returning None")
            return None
        if self._renderer is None:
            # The renderer of `cdf-mj render`: the OpenGL backend is chosen when the first
            # frame is asked for (MUJOCO_GL if set, else EGL, then OSMesa), so a headless
            # machine needs no MUJOCO_GL before importing mujoco; RenderError names the fix.
            model = self.scene.model  # the model's own multisampling, as mujoco.Renderer has
            self._renderer = Offscreen(model, self.width, self.height,
                                       samples=int(model.vis.quality.offsamples))
            if self._camera_id >= 0:
                self._renderer.use_camera(self._camera_id)
            else:
                self._look_at_junction(self._renderer.camera)
        self.scene.sync()
        self._renderer.update(self.scene.data)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Free the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ helpers
    def _look_at_junction(self, cam: mujoco.MjvCamera) -> None:
        """A free camera straight above the junction: centred on the point of the ego's
        route nearest the obstacle's start, the ego's direction to the right of the frame,
        ``_FREE_VIEW`` metres across the frame's height."""
        layout = self.world.layout
        route = layout.route_ego
        s = float(route.project(layout.obstacle_start[:2])[0])
        centre = route.point_at(s)
        ahead = route.point_at(s + 1.0) - centre
        fovy = math.radians(float(self.scene.model.vis.global_.fovy))
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = (float(centre[0]), float(centre[1]), 0.0)
        cam.distance = 0.5 * _FREE_VIEW / math.tan(0.5 * fovy)
        cam.azimuth = math.degrees(math.atan2(ahead[1], ahead[0])) + 90.0  # frame up = the ego's left
        cam.elevation = -90.0

    def _observation_box(self) -> spaces.Box:
        """Finite bounds: no car can leave the box around the scene's routes and start
        sites that its top speed (the speed actuator's ``actrange``) covers in
        ``duration``, plus 10 m; speeds within [-1, top speed + 1] m/s."""
        sc, m, layout = self.scene, self.scene.model, self.world.layout
        pts = np.vstack([layout.route_ego.points, layout.route_left.points, layout.route_right.points,
                         layout.ego_start[None, :2], layout.obstacle_start[None, :2]])
        vmax = max(float(m.actuator_actrange[car.accel][1]) if m.actuator_actlimited[car.accel]
                   else 50.0 for car in (sc.ego, sc.obstacle))
        reach = vmax * self.config.timing.duration + 10.0
        lo_xy, hi_xy = pts.min(axis=0) - reach, pts.max(axis=0) + reach
        car_lo = np.array([lo_xy[0], lo_xy[1], -np.pi, -1.0])
        car_hi = np.array([hi_xy[0], hi_xy[1], np.pi, vmax + 1.0])
        low, high = np.tile(car_lo, 2), np.tile(car_hi, 2)
        if self.posterior_in_observation:
            low, high = np.r_[low, 0.0, 0.0, 0.0], np.r_[high, 1.0, 1.0, 1.0]
        if self.command_in_observation:
            ego = self.world.layout.ego
            low, high = np.r_[low, -ego.max_brake], np.r_[high, ego.max_accel]
        return spaces.Box(low=low, high=high, dtype=np.float64)

    def _observe(self, poses: np.ndarray) -> None:
        """The filter's tick on the poses just measured (what ``CDFMonitor.step`` reads from the
        scene: the simulated time and ``Scene.poses()``, already at hand)."""
        assert self._monitor is not None
        self._monitor.observe(float(self.scene.data.time), poses[0], poses[1])

    def _sense(self, m: Measurement) -> np.ndarray:
        """The (2, 4) poses the ego measures at ``m`` (its sensor; with perfect sensing the
        sensor passes the truth through and draws nothing, so it is not asked)."""
        return self.ego.sense(m).poses if self._sensing else m.poses

    def _seen(self, sensed: np.ndarray) -> np.ndarray:
        """The poses of the observation from the sensed ones: a dropped obstacle (a NaN row)
        keeps the last measured pose."""
        if not self._sensing:
            return sensed
        self._measured_now = not math.isnan(sensed[1, 0])
        if self._measured_now:
            self._held = sensed[1].copy()
            return sensed
        return np.stack([sensed[0], self._held])

    def _progress(self, ego_pose: np.ndarray) -> float:
        return float(self.world.layout.route_ego.project(ego_pose[:2])[0])

    def _observation(self, poses: np.ndarray) -> np.ndarray:
        obs = poses.reshape(8)
        if not (self.posterior_in_observation or self.command_in_observation):
            # Within the box (every step but a contact's kick), clipping changes nothing.
            for v, (lo, hi) in zip(obs.tolist(), self._obs_bounds, strict=True):
                if not lo <= v <= hi:
                    break
            else:
                return obs.copy()
        else:
            decision = self._monitor.decision if self._monitor is not None else None
            if decision is None:
                raise RuntimeError("the CDF monitor has not run: call reset() first")
            if self.posterior_in_observation:
                p = decision.posterior
                assert p is not None  # the env's monitor runs the cdf planner
                obs = np.r_[obs, p.p_left, p.p_seen, p.p_cutoff]
            if self.command_in_observation:
                obs = np.r_[obs, decision.accel]
        # Clipping is a guard (a contact can kick a speed past its bound for one step).
        clipped: np.ndarray = np.clip(obs, self._obs_box.low, self._obs_box.high)
        return clipped

    def _info(self, m: Measurement, gap: float | None, collision: str | None = None) -> dict[str, Any]:
        """The step's ``info`` (the class docstring) from the true measurement ``m``."""
        w = self.world
        d = self._monitor.decision if self._monitor is not None else None
        info: dict[str, Any] = {
            "posterior": d.posterior.to_dict() if d is not None and d.posterior is not None else None,
            "brake": bool(d.brake) if d is not None else False,
            "accel": float(d.accel) if d is not None else None,
            "collision": collision, "label": self._label,
            "intent": self._intent_name, "t": w.end_time,
            "obstacle_in_lane": bool(m.obstacle_in_lane), "gap": gap,
            "episode_seed": self._episode_seed}
        if self._sensing:
            info["true_poses"] = np.array(m.poses, dtype=float)
            info["obstacle_measured"] = self._measured_now
        return info
