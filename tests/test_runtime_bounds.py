"""Bounds on what a run may cost and on what the library takes (issue 28): list arguments
of the command line, empty output paths, seeds, a planner's answer, a scene's timestep,
buildings over a car's start or route, ``min_gap`` at a building contact, and the Ray
probe against a server that is not Ray (plain TCP servers here; Ray itself only where
installed)."""

from __future__ import annotations

import contextlib
import math
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from cdf_mj import cli
from cdf_mj.config import MAX_SEED, ScenarioConfig, check_seed
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.experiments.runner import ClusterUnreachableError, _probe_ray_address
from cdf_mj.planners.base import Planner, PlannerInput
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.world import World
from cdf_mj.sim.assets import MODELS_DIR
from cdf_mj.sim.checks import MAX_SUBSTEPS, MIN_TIMESTEP, SceneError
from cdf_mj.sim.scene import Scene
from tests.cli_helpers import assert_one_line_error, run_cli


# ------------------------------------------------------------------ command line lists
@pytest.mark.parametrize(("argv", "needle"), [
    (["bench", "--scale-particles", ",".join(["100"] * 20_000)], "--scale-particles"),
    (["bench", "--scale-workers", ",".join(["1"] * 101)], "--scale-workers"),
    (["sweep", "beta", "--values", ",".join(["0.5"] * 101)], "--values"),
])
def test_a_list_argument_holds_at_most_100_items(capsys, argv, needle):
    with pytest.raises(ValueError, match="1 to 100"):  # CLIError while parsing: before any run
        cli.build_parser().parse_args(argv)
    status, out, err = run_cli(capsys, *argv)
    assert_one_line_error(status, out, err, needle, "1 to 100")


def test_a_list_of_100_items_is_read():
    from cdf_mj.cli.args import MAX_LIST_ITEMS, comma_list, particle_count
    from cdf_mj.cli.sweep import MAX_SWEEP_VALUES, _value_list

    assert MAX_SWEEP_VALUES == MAX_LIST_ITEMS == 100
    assert comma_list(particle_count, "positive integers")(",".join(["7"] * 100)) == [7] * 100
    assert _value_list("0.5, 1e-3,") == [0.5, 1e-3]


_CHEAP = ("--episodes", "1", "--planner", "constant", "--workers", "1", "--quiet")  # fails fast before the fix


@pytest.mark.parametrize("argv", [
    ["experiment", *_CHEAP], ["reproduce", *_CHEAP], ["sweep", "beta", "--values", "0.5", "--no-figure", *_CHEAP],
    ["report", "."], ["render", "--seed", "1", "--planner", "constant", "--set", "timing.duration=0.2"],
])
@pytest.mark.parametrize("out", ["", "  "])
def test_an_empty_out_path_is_refused(capsys, tmp_path, monkeypatch, argv, out):
    monkeypatch.chdir(tmp_path)
    status, stdout, err = run_cli(capsys, *argv, "--out", out)
    assert_one_line_error(status, stdout, err, "--out", "empty path")
    assert list(tmp_path.iterdir()) == []  # nothing written into the working directory


# ------------------------------------------------------------------ seeds
@pytest.mark.parametrize("seed", [True, False, np.True_, 2**64, MAX_SEED + 1, -1, 1.0, "3"])
def test_every_api_entry_refuses_a_seed_that_is_not_an_integer_up_to_max_seed(scene, tmp_path, seed):
    with pytest.raises(ValueError, match=r"seed.*out of range.*integer from 0 to"):
        run_episode(seed=seed, planner="constant", scene=scene, label=False)
    with pytest.raises(ValueError, match=r"seed.*out of range"):
        World(scene).reset(seed)
    with pytest.raises(ValueError, match=r"seed.*out of range"):
        run_experiment(tmp_path / "run", seeds=[seed], planners=("constant",), workers=1, progress=False)
    assert not (tmp_path / "run").exists()  # refused before anything is written
    with pytest.raises(ValueError, match=r"rng.*out of range"):
        CDFMonitor(scene.layout(), rng=seed)


def test_a_range_of_seeds_is_bounded_by_its_ends(tmp_path):
    with pytest.raises(ValueError, match=r"seed=18446744073709551616 is out of range"):
        run_experiment(tmp_path / "run", seeds=range(2**64, 2**64 + 3), planners=("constant",), progress=False)
    assert check_seed(np.uint64(MAX_SEED)) == MAX_SEED and type(check_seed(np.int64(3))) is int


def test_the_env_refuses_such_a_seed_and_draws_its_own_below_max_seed():
    pytest.importorskip("gymnasium")
    from cdf_mj.envs.t_intersection import TIntersectionEnv

    env = TIntersectionEnv(run_filter=False, label=False)
    for seed in (True, 2**64, -1):
        with pytest.raises(ValueError, match=r"seed.*out of range"):
            env.reset(seed=seed)
    env.reset(seed=5)
    _, info = env.reset()
    assert 0 <= info["episode_seed"] <= MAX_SEED


# ------------------------------------------------------------------ a planner's answer
class _Answers(Planner):
    """Answers ``answer`` at every tick."""

    name = "answers"

    def __init__(self, answer: object) -> None:
        self.answer = answer

    def brake(self, obs: PlannerInput) -> object:  # type: ignore[override]
        return self.answer


@pytest.mark.parametrize("answer", [math.nan, "yes", None, 1, np.float64(0.0), np.array([True])])
def test_a_planner_must_answer_with_a_bool(scene, answer):
    with pytest.raises(TypeError, match=r"planner 'answers' \(_Answers\.brake\) returned .* it must return a bool"):
        run_episode(seed=0, planner=_Answers(answer), scene=scene, label=False)


@pytest.mark.parametrize("answer", [False, np.False_, np.bool_(True)])
def test_bools_and_numpy_bools_are_answers(scene, answer):
    record = run_episode(seed=0, planner=_Answers(answer), scene=scene, label=False)
    assert (record.brake_time is not None) == bool(answer)


# ------------------------------------------------------------------ scenes: timestep, buildings
def _scene_copy(tmp_path: Path) -> Path:
    """A copy of models/xml to edit; returns its scene.xml."""
    shutil.copytree(MODELS_DIR, tmp_path / "models")
    return tmp_path / "models" / "scene.xml"


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert text.count(old) == 1, old
    path.write_text(text.replace(old, new))


@pytest.mark.parametrize("timestep", ["1e-9", "1e-6", "9e-5"])
def test_a_timestep_below_the_minimum_is_refused_at_load(tmp_path, timestep):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', f'timestep="{timestep}"')
    started = time.perf_counter()
    with pytest.raises(SceneError, match=r"<option timestep=.*is shorter than 0\.0001 s"):
        Scene.load(scene)
    assert time.perf_counter() - started < 5.0


def test_the_minimum_timestep_loads_and_the_steps_per_tick_are_bounded(tmp_path):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', f'timestep="{MIN_TIMESTEP}"')
    loaded = Scene.load(scene)
    assert loaded.substeps(0.1) == MAX_SUBSTEPS
    with pytest.raises(SceneError, match=r"timing\.dt=1 s is 10000 timesteps .* more than 1000 physics steps"):
        World(loaded, ScenarioConfig(timing={"dt": 1.0, "duration": 10.0}))


def test_an_experiment_on_a_scene_with_a_tiny_timestep_is_one_line(capsys, tmp_path):
    scene = _scene_copy(tmp_path)
    _edit(scene, 'timestep="0.005"', 'timestep="1e-9"')
    started = time.perf_counter()
    status, out, err = run_cli(capsys, "experiment", "--scene", str(scene), "--out", str(tmp_path / "run"),
                               "--episodes", "2", "--workers", "1", "--quiet")
    assert_one_line_error(status, out, err, "timestep", "shorter than 0.0001 s")
    assert time.perf_counter() - started < 10.0


#: A building box (centre, half sizes [m]) over: the ego's start, the whole junction, the
#: ego's route ahead of it, the left-turner's arc; and one beside the road, which is fine.
_BUILDINGS = {
    "ego start": ("-40 -1.85 3", "3 3 3", ["at its start (site 'ego_start')", "body 'route_ego' is not drivable"]),
    "junction": ("0 0 3", "10 10 3", ["at its start (site 'obstacle_start')", "route_obstacle_left"]),
    "ego route": ("-20 -3 3", "1 1.4 3", ["body 'route_ego' is not drivable", "building_x"]),
    "left arc": ("1.5 0.5 3", "0.3 0.3 3", ["body 'route_obstacle_left' is not drivable"]),
}


def _with_building(tmp_path: Path, pos: str, size: str) -> Path:
    scene = _scene_copy(tmp_path)
    _edit(scene.parent / "intersection.xml", "    <!-- Start poses",
          f'    <geom name="building_x" class="building" pos="{pos}" size="{size}"/>\n    <!-- Start poses')
    return scene


@pytest.mark.parametrize("where", sorted(_BUILDINGS))
def test_a_building_over_a_start_or_a_route_is_refused_at_load(tmp_path, where):
    pos, size, needles = _BUILDINGS[where]
    with pytest.raises(SceneError) as caught:
        Scene.load(_with_building(tmp_path, pos, size))
    for needle in needles:
        assert needle in str(caught.value)


def test_a_building_beside_the_road_loads(tmp_path):
    Scene.load(_with_building(tmp_path, "-60 -6 3", "3 2.2 3"))  # 0.3 m from the ego's box


def test_an_experiment_on_a_scene_with_a_building_over_the_junction_is_one_line(capsys, tmp_path):
    scene = _with_building(tmp_path, "0 0 3", "10 10 3")
    status, out, err = run_cli(capsys, "experiment", "--scene", str(scene), "--out", str(tmp_path / "run"),
                               "--episodes", "2", "--workers", "1", "--quiet")
    assert_one_line_error(status, out, err, "meets building 'building_x'")
    assert not (tmp_path / "run").exists()


def test_min_gap_is_the_distance_between_the_cars_when_the_ego_hits_a_building(tmp_path, monkeypatch):
    """A building on the ego's lane, in a scene loaded with the checks off (they refuse it):
    the ego hits it far from the obstacle, and min_gap is the cars' distance, not 0."""
    monkeypatch.setattr("cdf_mj.sim.scene.validate", lambda *args, **kwargs: None)
    scene = Scene.load(_with_building(tmp_path, *_BUILDINGS["ego route"][:2]))
    record = run_episode(seed=0, planner="constant", scene=scene, label=False)
    assert record.collision_with == "building"
    assert record.min_gap > 10.0  # the cars were never near


# ------------------------------------------------------------------ the Ray probe
@contextlib.contextmanager
def _server(answer: bytes | None, close: bool = False) -> Iterator[str]:
    """A TCP server on 127.0.0.1 that accepts, reads the greeting and sends ``answer``
    (None: says nothing); ``close``: then hangs up. Yields its ``host:port``."""
    listener = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = listener.accept()
                held.append(conn)
                conn.settimeout(2.0)
                with contextlib.suppress(OSError):
                    conn.recv(1024)
                    if answer is not None:
                        conn.sendall(answer)
                if close:
                    conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{listener.getsockname()[1]}"
    finally:
        listener.close()
        for conn in held:
            conn.close()


_SETTINGS = bytes([0, 0, 6, 4, 0, 0, 0, 0, 0]) + bytes([0, 3, 0, 0, 0, 100])  # a server's first frame


@pytest.mark.parametrize(("answer", "close", "why"), [
    (None, False, "it said nothing"),
    (b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", False, "as a web server (HTTP/1)"),
    (b"-ERR unknown command 'PRI'\r\n", False, "not gRPC"),
    (None, True, "it closed the connection"),
])
def test_the_ray_probe_refuses_a_server_that_is_not_grpc(answer, close, why):
    with _server(answer, close) as address:
        started = time.perf_counter()
        with pytest.raises(ClusterUnreachableError, match=f"no Ray cluster answers at {address}: something "
                                                          "listens there, but") as caught:
            _probe_ray_address(address, timeout=1.0)
        assert why in str(caught.value)
        assert time.perf_counter() - started < 3.0


def test_the_ray_probe_passes_a_grpc_server_and_only_connects_under_tls(monkeypatch):
    with _server(_SETTINGS) as address:
        _probe_ray_address(address, timeout=2.0)
        _probe_ray_address(f"ray://{address}", timeout=2.0)
    monkeypatch.setenv("RAY_USE_TLS", "1")  # the probe does not speak TLS: the connection is all it checks
    with _server(None) as address:
        _probe_ray_address(address, timeout=1.0)


def test_an_experiment_on_ray_at_a_silent_server_is_one_line(capsys, tmp_path):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    with _server(None) as address:
        started = time.perf_counter()
        status, out, err = run_cli(capsys, "experiment", "--episodes", "2", "--planner", "constant", "--backend",
                                   "ray", "--address", address, "--quiet", "--out", str(tmp_path / "run"))
        assert_one_line_error(status, out, err, f"no Ray cluster answers at {address}", "it said nothing")
        assert time.perf_counter() - started < 10.0


def test_the_ray_probe_passes_a_real_ray_cluster():
    ray = pytest.importorskip("ray", reason="the ray extra is not installed")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        _probe_ray_address(ray.get_runtime_context().gcs_address, timeout=5.0)
    finally:
        if started:
            ray.shutdown()
