"""The Gymnasium environment cdf_mj/TIntersection-v0: Gymnasium's own checker, seeding,
the same world as run_episode, actions, rewards and episode ends, vectorised workers,
rendering (two envs in turn; headless without MUJOCO_GL, in a subprocess) and the example script."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402  (after the skip without Gymnasium)
from junctions import junction_scene  # noqa: E402

import cdf_mj  # noqa: E402
from cdf_mj.config import ScenarioConfig  # noqa: E402
from cdf_mj.extras import install_hint  # noqa: E402
from cdf_mj.model.driver import ego_control  # noqa: E402
from cdf_mj.records import Label  # noqa: E402
from cdf_mj.scenario.episode import run_episode  # noqa: E402
from cdf_mj.scenario.sensing import JerkLimiter  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
ORIGINAL_MUJOCO_GL = os.environ.get("MUJOCO_GL")  # the user's; render.gl_backend may set it later
# The one message check_env gives for an action box in physical units (see the class
# docstring): a recommendation to normalise, which normalized_actions=True follows.
NORMALISE_HINT = "we recommend using a symmetric and normalized space"


def _checker_warnings(env) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    return [str(w.message) for w in caught]


def test_check_env_normalized_actions_no_warnings():
    env = gym.make(cdf_mj.ENV_ID, normalized_actions=True, label=False)
    assert _checker_warnings(env.unwrapped) == []


def test_check_env_physical_actions_only_the_normalisation_hint():
    env = gym.make(cdf_mj.ENV_ID, posterior_in_observation=True, label=False)
    msgs = _checker_warnings(env.unwrapped)
    assert len(msgs) == 1 and NORMALISE_HINT in msgs[0], msgs


def test_spaces_come_from_the_model():
    env = gym.make(cdf_mj.ENV_ID, label=False).unwrapped
    ego = env.scene.layout().ego
    np.testing.assert_allclose(env.action_space.low, [ego.accel_range[0], ego.steer_range[0]], rtol=1e-6)
    np.testing.assert_allclose(env.action_space.high, [ego.accel_range[1], ego.steer_range[1]], rtol=1e-6)
    assert env.observation_space.shape == (8,)
    assert np.all(np.isfinite(env.observation_space.low))


def test_reset_seed_is_reproducible_and_is_run_episodes_world(scene):
    env = gym.make(cdf_mj.ENV_ID, scene=scene)
    rng = np.random.default_rng(0)
    actions = rng.uniform(env.action_space.low, env.action_space.high, size=(30, 2)).astype(np.float32)

    def rollout():
        obs, info = env.reset(seed=4)
        out = [obs]
        for a in actions:
            obs, _, te, tr, info = env.step(a)
            out.append(obs)
            if te or tr:
                break
        return np.array(out), info

    a, info_a = rollout()
    b, info_b = rollout()
    np.testing.assert_array_equal(a, b)
    assert info_a == info_b
    rec = run_episode(seed=4, planner="constant", scene=scene)
    assert info_a["label"] == rec.label and info_a["intent"] == rec.intent
    np.testing.assert_allclose(a[0][:2], [env.unwrapped.scene.layout().ego_start[0] + rec.ego_start_offset,
                                          env.unwrapped.scene.layout().ego_start[1]])


@pytest.mark.parametrize("planner", ["constant", "cdf"])
def test_env_with_the_planners_policy_replays_run_episode(scene, planner):
    """One implementation of the world: driving the env as the planner would gives
    run_episode's record (seed 1 is a cut-off). The env's agent is the ego's whole
    controller; here it is run_episode's: the CDF rule's graded command on the nominal speed
    hold (``info["accel"]``, read from the observation too), through the ego's actuator (its
    jerk limit), without following (ego.follow off in both)."""
    config = ScenarioConfig().with_values({"ego.follow": False})
    rec = run_episode(config, seed=1, planner=planner, scene=scene)
    assert rec.label == Label.CUTOFF
    env = gym.make(cdf_mj.ENV_ID, scene=scene, config=config, command_in_observation=True).unwrapped
    obs, info = env.reset(seed=1)
    assert obs.shape == (9,) and obs[8] == info["accel"]
    actuator = JerkLimiter(config.ego.jerk_limit, config.timing.dt)
    brake_time, done, ret = None, False, 0.0
    while not done:
        if planner == "cdf" and info["brake"] and brake_time is None:  # a hard brake of this tick's rule
            brake_time = info["t"]
        action = ego_control(env.world.driver, env.world.layout.ego, obs[:4], False)
        if planner == "cdf":
            action[0] = info["accel"]
        action[0] = actuator(float(action[0]))
        obs, reward, terminated, truncated, info = env.step(action)
        ret += reward
        done = terminated or truncated
    assert brake_time == rec.brake_time
    assert info["collision"] == rec.collision_with
    assert info["t"] == pytest.approx(rec.end_time)
    assert env.world.min_gap == pytest.approx(rec.min_gap)
    if planner == "constant":  # hit: the penalty is in the return, and the episode terminated
        assert terminated and not truncated and ret < -50
    else:  # avoided: it braked, let the obstacle go ahead and went on
        assert info["collision"] is None


NOISY = {"sensing.pos": 0.5, "sensing.heading": 0.05, "sensing.speed": 0.5}


def _rollout(env, seed, actions):
    """(observations, infos) of an episode under fixed actions."""
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    for a in actions:
        obs, _, te, tr, info = env.step(a)
        out.append((obs, info))
        if te or tr:
            break
    return out


@pytest.mark.parametrize("values", [NOISY, {"sensing.latency": 3}])
def test_sensing_changes_the_observation_and_the_filter_not_the_truth(scene, values):
    """The agent observes the obstacle through the ego's sensor (and the CDF filter reads
    what it observes); ``info`` keeps the truth, which is the perfect world's."""
    actions = np.random.default_rng(3).uniform([-2.0, -0.05], [1.0, 0.05], size=(25, 2))
    kwargs = {"scene": scene, "posterior_in_observation": True}
    perfect = _rollout(cdf_mj.TIntersectionEnv(**kwargs), 1, actions)
    sensed = _rollout(cdf_mj.TIntersectionEnv(config=ScenarioConfig().with_values(values), **kwargs), 1, actions)
    assert len(sensed) == len(perfect) > 10
    assert "true_poses" not in perfect[0][1]  # the default info is what it was
    for (obs, info), (obs0, info0) in zip(sensed, perfect, strict=True):
        truth = info["true_poses"]
        np.testing.assert_array_equal(truth.reshape(8), obs0[:8])  # the truth is the perfect world's
        np.testing.assert_array_equal(obs[:4], truth[0])  # the ego's own pose is exact
        assert info["obstacle_measured"] and (info["gap"], info["t"]) == (info0["gap"], info0["t"])
    moved = [not np.array_equal(obs[4:8], info["true_poses"][1]) for obs, info in sensed]
    assert all(moved) if "sensing.pos" in values else moved.count(True) >= 10  # standing still, late is the same
    assert [info["posterior"] for _, info in sensed] != [info["posterior"] for _, info in perfect]


@pytest.mark.parametrize("values", [NOISY, {"sensing.latency": 2}])
def test_with_sensing_the_planners_policy_still_replays_run_episode(scene, values):
    """The env's filter senses through run_episode's ego sensor (the same stream, the same
    ticks): the CDF rule's commands drive the same episode as run_episode's ``cdf`` ego,
    which the sensing changed (seed 3 ends 0.1-0.3 s later than with perfect sensing)."""
    config = ScenarioConfig().with_values({"ego.follow": False, **values})
    rec = run_episode(config, seed=3, planner="cdf", scene=scene)
    assert rec.end_time != run_episode(ScenarioConfig().with_values({"ego.follow": False}), seed=3,
                                       planner="cdf", scene=scene).end_time
    env = cdf_mj.TIntersectionEnv(scene=scene, config=config, command_in_observation=True)
    obs, info = env.reset(seed=3)
    actuator = JerkLimiter(config.ego.jerk_limit, config.timing.dt)
    done = False
    while not done:
        action = ego_control(env.world.driver, env.world.layout.ego, obs[:4], False)
        action[0] = actuator(float(info["accel"]))
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    assert (info["t"], info["collision"], env.world.min_gap) == (rec.end_time, rec.collision_with, rec.min_gap)


def test_a_dropped_measurement_keeps_the_last_one_in_the_observation(scene):
    config = ScenarioConfig().with_values({"sensing.dropout": 0.5, "sensing.pos": 0.2})
    env = cdf_mj.TIntersectionEnv(scene=scene, config=config, run_filter=False, label=False)
    steps = _rollout(env, 2, np.zeros((30, 2)))
    measured = [info["obstacle_measured"] for _, info in steps]
    assert 5 <= measured.count(False) <= 25
    for k in range(1, len(steps)):
        obs, info = steps[k]
        assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
        if not info["obstacle_measured"]:
            np.testing.assert_array_equal(obs[4:8], steps[k - 1][0][4:8])


def test_the_filter_skips_a_dropped_measurement(scene):
    """With the filter, a dropout is an update skipped, as the ``cdf`` planner skips it (the
    monitor takes the sensor's NaN row as no measurement)."""
    config = ScenarioConfig().with_values({"sensing.dropout": 0.3})
    env = cdf_mj.TIntersectionEnv(scene=scene, config=config, posterior_in_observation=True, label=False)
    steps = _rollout(env, 1, np.zeros((40, 2)))
    dropped = sum(not info["obstacle_measured"] for _, info in steps)
    assert dropped > 0 and env._monitor is not None
    # Every missed measurement is one the filter skipped (but those before its first one).
    assert 0 < env._monitor.planner.summary()["skipped_updates"] <= dropped
    assert all(np.all(np.isfinite(obs)) for obs, _ in steps)


def test_brake_latency_delays_the_actions_acceleration(scene):
    config = ScenarioConfig().with_values({"sensing.brake_latency": 2})
    env = cdf_mj.TIntersectionEnv(scene=scene, config=config, run_filter=False, label=False)
    env.reset(seed=2)
    applied = []
    step = env.world.step
    env.world.step = lambda controls: applied.append(controls.copy()) or step(controls)
    for k in range(4):
        env.step(np.array([-1.0 - k, 0.01 * k]))
    assert [a[0] for a in applied[2:]] == [-1.0, -2.0] and abs(applied[0][0]) < 0.5  # the speed hold first
    assert [a[1] for a in applied] == pytest.approx([0.0, 0.01, 0.02, 0.03])


def test_check_env_with_imperfect_sensing():
    config = ScenarioConfig().with_values({**NOISY, "sensing.dropout": 0.3, "sensing.latency": 1})
    env = gym.make(cdf_mj.ENV_ID, config=config, normalized_actions=True, run_filter=False, label=False)
    assert _checker_warnings(env.unwrapped) == []


def test_out_of_range_actions_are_clipped_and_bad_ones_refused(scene):
    env = gym.make(cdf_mj.ENV_ID, scene=scene, run_filter=False, label=False).unwrapped
    env.reset(seed=2)
    big = env.step(np.array([100.0, -7.0]))[0]
    env.reset(seed=2)
    edge = env.step(np.array([env.action_space.high[0], env.action_space.low[1]]))[0]
    np.testing.assert_allclose(big, edge)
    for bad in ([np.nan, 0.0], [0.0], [[0.0, 0.0]]):
        with pytest.raises(ValueError, match="action must be 2 finite numbers"):
            env.step(np.array(bad))
    env.reset(seed=2)
    applied = []
    step = env.world.step
    env.world.step = lambda controls: applied.append(controls.copy()) or step(controls)
    env.step(np.array([-100.0, 0.0]))  # clipped to the model's own braking limit, not its float32 copy
    assert applied[0][0] == scene.layout().ego.accel_range[0] == -4.877


@pytest.mark.parametrize("normalized", [False, True])
def test_the_action_space_samples_what_gymnasiums_box_samples(scene, normalized):
    env = cdf_mj.TIntersectionEnv(scene=scene, run_filter=False, label=False, normalized_actions=normalized)
    box = gym.spaces.Box(env.action_space.low, env.action_space.high, dtype=np.float32)
    assert isinstance(env.action_space, gym.spaces.Box) and env.action_space == box
    env.action_space.seed(11)
    box.seed(11)
    for _ in range(500):
        ours, theirs = env.action_space.sample(), box.sample()
        assert ours.dtype == theirs.dtype == np.float32 and ours.shape == theirs.shape == (2,)
        assert ours.tobytes() == theirs.tobytes()
    assert env.action_space.np_random.bit_generator.state == box.np_random.bit_generator.state
    with pytest.raises(gym.error.Error, match="mask"):
        env.action_space.sample(mask=np.ones(2))


def test_an_action_steps_the_same_whatever_holds_it(scene):
    """A float64 or float32 array, a strided view, a list, a tuple: the same steps; a
    non-finite one is refused in any of them, before anything is stepped."""
    forms = (np.array, lambda v: np.array(v, dtype=np.float32), lambda v: np.c_[v, v][:, 0], list, tuple)
    results = []
    for form in forms:
        env = cdf_mj.TIntersectionEnv(scene=scene, run_filter=False, label=False)
        env.reset(seed=4)
        with pytest.raises(ValueError, match="action must be 2 finite numbers"):
            env.step(form([np.inf, 0.0]))
        assert env.world.t == 0.0
        steps = [env.step(form([1.5, -0.125])) for _ in range(3)]
        results.append([(o.tobytes(), r, te, tr, sorted(info.items())) for o, r, te, tr, info in steps])
    assert all(r == results[0] for r in results[1:])


def test_an_observation_is_a_new_array_clipped_to_its_box(scene):
    env = cdf_mj.TIntersectionEnv(scene=scene, run_filter=False, label=False)
    env.reset(seed=1)
    poses = env.world.measure().poses
    obs = env._observation(poses)
    assert not np.shares_memory(obs, poses)
    np.testing.assert_array_equal(obs, poses.reshape(8))
    far = poses.copy()
    far[0, 3], far[1, 0] = 1e3, -1e9  # a speed kicked past its bound, a car far off
    box = env.observation_space
    np.testing.assert_array_equal(env._observation(far), np.clip(far.reshape(8), box.low, box.high))


@pytest.mark.parametrize("penalty", [float("nan"), float("inf"), -1.0, 1e300, "100", True])
def test_a_collision_penalty_that_is_not_a_bounded_number_is_refused(scene, penalty):
    with pytest.raises(ValueError, match=r"collision_penalty=.*must be a finite number in \[0, 1e\+06\]"):
        cdf_mj.TIntersectionEnv(scene=scene, collision_penalty=penalty, run_filter=False, label=False)
    env = cdf_mj.TIntersectionEnv(scene=scene, collision_penalty=0.0, run_filter=False, label=False)
    assert env.collision_penalty == 0.0


def test_a_scene_object_keeps_its_names_and_frames_follow_dt(scene):
    with pytest.raises(ValueError, match="names apply to a scene file"):
        gym.make(cdf_mj.ENV_ID, scene=scene, names=cdf_mj.SceneNames())
    env = gym.make(cdf_mj.ENV_ID, scene=scene, config=cdf_mj.ScenarioConfig(timing={"dt": 0.05}), run_filter=False)
    assert env.unwrapped.metadata["render_fps"] == 20


def test_right_turner_episode_ends_when_the_ego_is_past(scene):
    env = gym.make(cdf_mj.ENV_ID, scene=scene, run_filter=False).unwrapped
    _obs, info = env.reset(seed=0)
    assert info["label"] == Label.RIGHT and info["posterior"] is None
    ret, done, steps = 0.0, False, 0
    while not done:
        _, r, terminated, truncated, info = env.step(np.zeros(2))
        ret += r
        steps += 1
        done = terminated or truncated
    assert terminated and not truncated and info["collision"] is None
    assert ret == pytest.approx(steps, rel=0.05)  # ~1 per step at the nominal speed


def test_misuse_gives_clear_errors(scene):
    env = gym.make(cdf_mj.ENV_ID, scene=scene, label=False).unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match=r"camera 'drone' is not in the scene; cameras: top"):
        gym.make(cdf_mj.ENV_ID, scene=scene, camera="drone", render_mode="rgb_array")
    with pytest.raises(ValueError, match="offscreen buffer 1280 x 720"):
        gym.make(cdf_mj.ENV_ID, scene=scene, width=2000, render_mode="rgb_array")
    with pytest.raises(ValueError, match="needs run_filter"):
        gym.make(cdf_mj.ENV_ID, scene=scene, posterior_in_observation=True, run_filter=False)


def test_without_rendering_no_camera_is_needed():
    """render_mode None checks no camera and no frame size: a scene without a camera of the
    world and a camera name that is nowhere are both fine, and the env runs."""
    bare = junction_scene(camera=None, rotation=0.6)
    cams = [bare.model.camera(i).name for i in range(bare.model.ncam)]
    assert cams == ["ego_chase", "obstacle_chase"]  # the cars' own; no camera of the world
    env = gym.make(cdf_mj.ENV_ID, scene=bare, label=False, run_filter=False, camera="drone",
                   width=5000).unwrapped
    obs, _ = env.reset(seed=2)
    assert np.all(np.isfinite(obs))
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None  # and Gymnasium's warning says why
    # rendering asked for: the scene's "top", else the free camera; a missing name is an error
    assert gym.make(cdf_mj.ENV_ID, scene=bare, render_mode="rgb_array").unwrapped.camera == "free"
    assert gym.make(cdf_mj.ENV_ID, render_mode="rgb_array").unwrapped.camera == "top"
    with pytest.raises(ValueError, match=r"cameras: ego_chase, obstacle_chase \(camera=None looks down"):
        gym.make(cdf_mj.ENV_ID, scene=bare, render_mode="rgb_array", camera="top")


def test_make_vec_with_worker_processes():
    envs = gym.make_vec(cdf_mj.ENV_ID, num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "spawn"}, posterior_in_observation=True,
                        label=False)
    try:
        obs, _info = envs.reset(seed=[3, 4])
        assert obs.shape == (2, 11) and np.all(np.isfinite(obs))
        for _ in range(5):
            obs, reward, _, _, _ = envs.step(np.zeros((2, 2), dtype=np.float32))
        assert obs.shape == (2, 11) and reward.shape == (2,)
        assert np.all((obs[:, 8:] >= 0) & (obs[:, 8:] <= 1))
    finally:
        envs.close()



def test_two_envs_render_their_own_cameras_in_turn(backend):
    a = gym.make(cdf_mj.ENV_ID, render_mode="rgb_array", label=False, run_filter=False,
                 width=160, height=120, camera="top")
    b = gym.make(cdf_mj.ENV_ID, render_mode="rgb_array", label=False, run_filter=False,
                 width=160, height=120, camera="ego_chase")
    try:
        a.reset(seed=1)
        b.reset(seed=1)
        first = a.render()
        other = b.render()
        again = a.render()  # each renderer makes its own context current
        assert first.shape == other.shape == (120, 160, 3) and first.std() > 1
        assert np.array_equal(first, again) and not np.array_equal(first, other)
    finally:
        a.close()
        b.close()


def test_a_scene_without_cameras_renders_the_junction_from_above(backend):
    """The free camera over the junction: the frame shows the junction the same way up
    whatever the junction's rotation (the ego drives to the right of the frame)."""
    frames = []
    for rotation in (0.0, 2.0):
        env = gym.make(cdf_mj.ENV_ID, scene=junction_scene(camera=None, rotation=rotation),
                       render_mode="rgb_array", label=False, run_filter=False, width=160, height=120)
        try:
            env.reset(seed=1)
            frames.append(env.render().astype(float))
        finally:
            env.close()
    assert frames[0].shape == (120, 160, 3) and frames[0].std() > 10
    assert np.abs(frames[0] - frames[1]).mean() < 2.0  # the same picture, up to rasterisation


def test_render_check_env_and_example_script_in_a_subprocess(tmp_path, backend):
    """Headless without MUJOCO_GL (the env picks EGL or OSMesa itself, as `cdf-mj render`
    does): check_env including its render checks, and the example script driving the env
    with its own policy into a video."""
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL" or ORIGINAL_MUJOCO_GL}
    code = (
        "import warnings, gymnasium as gym, cdf_mj\n"
        "from gymnasium.utils.env_checker import check_env\n"
        "e = gym.make(cdf_mj.ENV_ID, render_mode='rgb_array', normalized_actions=True,"
        " label=False, width=160, height=120)\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        "    warnings.simplefilter('always'); check_env(e.unwrapped)\n"
        "assert not w, [str(x.message) for x in w]\n"
        "e.reset(seed=1); f = e.render(); assert f.shape == (120, 160, 3) and f.std() > 1\n"
        "print('render ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=False,
                         timeout=120)
    assert out.returncode == 0 and "render ok" in out.stdout, out.stderr[-2000:]
    video = tmp_path / "drive.mp4"
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "drive_env.py"), "--seed", "1",
                          "--out", str(video), "--width", "160", "--height", "120",
                          "--max-steps", "4"], env=env, capture_output=True, text=True, timeout=120,
                         check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert video.stat().st_size > 1000 and "5 frames" in out.stdout


def test_without_gymnasium_import_works_and_the_env_names_the_extra():
    code = ("import sys; sys.modules['gymnasium'] = None\n"
            "import cdf_mj\n"
            "try:\n    cdf_mj.TIntersectionEnv\n"
            "except ImportError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == f"the environment cdf_mj/TIntersection-v0 needs gymnasium: {install_hint('gym')}"
