"""The experiment runner and its record store: the same records on any backend, nothing
lost or duplicated by a killed run, failed episodes recorded, other settings refused."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.analysis.tables import experiment_tables
from cdf_mj.cli import main
from cdf_mj.config import CDFConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.experiments.runner import START_METHOD, WorkerDiedError
from cdf_mj.experiments.store import RecordStore, locked
from cdf_mj.planners import PLANNERS, Planner, PlannerInput, ReactivePlanner
from cdf_mj.records import FAILED, OK, load_records

SMALL = CDFConfig(n_particles=200)
SEEDS = range(30, 38)


def _key(rec: dict) -> tuple[int, str]:
    return rec["seed"], rec["planner"]


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    return run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False, workers=1)


def test_process_pool_gives_the_serial_records(serial, tmp_path):
    parallel = run_experiment(tmp_path, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False, workers=2)
    assert parallel.workers == 2 and parallel.ran == 2 * len(SEEDS)
    assert parallel.records == serial.records  # sorted by seed, then planner order
    assert sorted(load_records(tmp_path), key=_key) == sorted(serial.records, key=_key)
    assert all(r["status"] == OK for r in parallel)
    assert parallel.peak_worker_rss_mb > 10  # measured in the workers


def test_ray_gives_the_serial_records(serial, tmp_path):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    result = run_experiment(tmp_path, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False,
                            workers=2, backend="ray")
    assert result.backend == "ray"
    assert result.records == serial.records


def _count_lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def _children(pid: int) -> list[int] | None:
    """Child process ids of ``pid`` (Linux /proc); None where that cannot be read."""
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return None


def _state(pid: int) -> str:
    """A process's state letter (Z: exited, not yet reaped); "" once it is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return ""


def test_sigkilled_run_resumes_without_loss_or_duplicates(tmp_path):
    out, seeds = tmp_path / "killed", range(0, 40)
    cmd = [sys.executable, "-m", "cdf_mj.cli", "experiment", "--episodes", str(len(seeds)),
           "--planner", "reactive", "--workers", "2", "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while _count_lines(out / "episodes.jsonl") < 5 and proc.poll() is None:
        assert time.monotonic() < deadline, "the experiment wrote nothing in 120 s"
        time.sleep(0.02)
    workers = _children(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)  # the main process only: its workers must not outlive it
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    if workers is not None:  # Linux: the workers exit with their parent (no orphans left behind)
        assert len(workers) == 2
        deadline = time.monotonic() + 30
        while any(Path(f"/proc/{pid}").exists() and _state(pid) != "Z" for pid in workers):
            assert time.monotonic() < deadline, f"worker processes {workers} outlived their parent"
            time.sleep(0.05)
    else:
        os.killpg(proc.pid, signal.SIGKILL)
    saved = _count_lines(out / "episodes.jsonl")
    assert 5 <= saved < len(seeds)  # really killed in the middle

    # The same command again completes the run.
    assert main(cmd[3:]) == 0
    records = load_records(out)
    counts = Counter(_key(r) for r in records)
    assert set(counts) == {(s, "reactive") for s in seeds}
    assert max(counts.values()) == 1
    fresh = run_experiment(tmp_path / "fresh", seeds, ("reactive",), progress=False, workers=1)
    assert sorted(records, key=_key) == fresh.records


class ExplodingPlanner(ReactivePlanner):
    """Raises on episodes whose ego starts behind site ego_start (about half the seeds)."""

    name = "exploding"

    def brake(self, obs: PlannerInput) -> bool:
        if obs.t == 0.0 and obs.poses[0, 0] < -40.8:
            raise RuntimeError("deliberate failure for the test")
        return super().brake(obs)


def test_a_failing_episode_is_recorded_and_the_run_goes_on(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(PLANNERS, "exploding", ExplodingPlanner)
    seeds = range(0, 10)
    assert main(["experiment", "--episodes", "10", "--planner", "reactive,exploding", "--workers", "2",
                 "--out", str(tmp_path), "--quiet"]) == 1
    err = capsys.readouterr().err
    records = load_records(tmp_path)
    assert len(records) == 20
    reactive = {r["seed"]: r for r in records if r["planner"] == "reactive"}
    failed = [r for r in records if r["status"] == FAILED]
    expected = {s for s in seeds if reactive[s]["ego_start_offset"] < 0}  # behind ego_start
    assert expected and len(expected) < len(seeds)
    assert {r["seed"] for r in failed} == expected
    assert all(r["planner"] == "exploding" for r in failed)
    assert all("deliberate failure" in r["error"] and "in brake" in r["traceback"] for r in failed)
    assert f"{len(expected)} of 20 episodes failed" in err
    assert f"{len(expected)} failed episode(s) left out" in experiment_tables(records)
    # The others ran to the end, labelled like the reactive run of the same seed.
    for r in records:
        if r["planner"] == "exploding" and r["status"] == OK:
            assert r["label"] == reactive[r["seed"]]["label"]

    # Running it again keeps the failures; --retry-failed runs them again (here, once fixed).
    args = ["experiment", "--episodes", "10", "--planner", "reactive,exploding", "--workers", "2",
            "--out", str(tmp_path), "--quiet"]
    assert main(args) == 1 and len(load_records(tmp_path)) == 20
    monkeypatch.setitem(PLANNERS, "exploding", ReactivePlanner)  # the bug is fixed
    assert main([*args, "--retry-failed"]) == 0
    retried = load_records(tmp_path)
    assert len(retried) == 20 and all(r["status"] == OK for r in retried)
    assert Counter(_key(r) for r in retried) == Counter(_key(r) for r in records)


class DyingPlanner(ReactivePlanner):
    """Kills its own worker process once (while the marker file is missing)."""

    name = "dying"

    def brake(self, obs: PlannerInput) -> bool:
        marker = Path(os.environ["CDF_MJ_TEST_MARKER"])
        if not marker.exists():
            marker.touch()
            os.kill(os.getpid(), signal.SIGKILL)
        return super().brake(obs)


def test_a_worker_that_dies_is_reported_and_resumed(tmp_path, monkeypatch):
    monkeypatch.setitem(PLANNERS, "dying", DyingPlanner)
    monkeypatch.setenv("CDF_MJ_TEST_MARKER", str(tmp_path / "died"))
    with pytest.raises(WorkerDiedError, match="resume"):
        run_experiment(tmp_path / "r", range(6), ("dying",), progress=False, workers=2)
    result = run_experiment(tmp_path / "r", range(6), ("dying",), progress=False, workers=2, resume=True)
    assert sorted(r["seed"] for r in result) == list(range(6))
    assert all(r["status"] == OK for r in result)


def test_resume_with_other_settings_is_refused(serial, tmp_path):
    out = serial.out_dir
    before = (out / "episodes.jsonl").read_bytes()
    with pytest.raises(ValueError,
                       match=r"other settings \(differing: cdf.n_particles, planner_args.cdf.cdf.n_particles\)"):
        run_experiment(out, SEEDS, ("cdf", "reactive"), progress=False, resume=True)
    with pytest.raises(ValueError, match="planners"):
        run_experiment(out, SEEDS, ("reactive",), cdf=SMALL, progress=False, resume=True)
    assert main(["experiment", "--episodes", "8", "--seed", "30", "--out", str(out),
                 "--set", "obstacle.beta=0.1", "--quiet"]) == 2
    assert (out / "episodes.jsonl").read_bytes() == before
    # The same settings: nothing left to run, the same records.
    again = run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False, resume=True)
    assert again.ran == 0 and again.resumed == 2 * len(SEEDS) and again.records == serial.records


def test_store_drops_a_half_written_last_line_and_refuses_a_damaged_one(serial, tmp_path):
    path = tmp_path / "episodes.jsonl"
    good = [r for r in serial.records if r["planner"] == "reactive"][:3]
    path.write_text("".join(json.dumps(r) + "\n" for r in good[:2]) + json.dumps(good[2])[:40])
    with RecordStore.open(path) as store:
        assert store.records == good[:2] and store.done() == {(30, "reactive"), (31, "reactive")}
        store.append([good[2]])
    assert load_records(tmp_path) == good  # the cut line truncated, the new one whole

    path.write_text(json.dumps(good[0]) + "\nnot json\n" + json.dumps(good[1]) + "\n")
    with pytest.raises(ValueError, match=r"episodes.jsonl:2 is not an episode record: not JSON .*the file is damaged"):
        RecordStore.open(path)
    path.write_text(json.dumps({**good[0], "label": "Maybe"}) + "\n")
    with pytest.raises(ValueError, match=r"episodes.jsonl:1 is not an episode record: field 'label' must be one of"):
        RecordStore.open(path)


def test_bad_runner_arguments_are_refused_before_work(tmp_path):
    with pytest.raises(ValueError, match="workers"):
        run_experiment(tmp_path / "a", range(4), ("reactive",), progress=False, workers=0)
    with pytest.raises(ValueError, match="backend"):
        run_experiment(tmp_path / "b", range(4), ("reactive",), progress=False, backend="mpi")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="distinct"):
        run_experiment(tmp_path / "c", range(4), ("reactive", "reactive"), progress=False)
    with pytest.raises(ValueError, match=r"seed=0.5 is out of range: must be an integer"):
        run_experiment(tmp_path / "d", [0.5, 1.5], ("reactive",), progress=False)
    assert main(["experiment", "--episodes", "2", "--address", "host:6379", "--out", str(tmp_path / "e")]) == 2

    assert not any((tmp_path / name).exists() for name in "abcde")


def test_a_planner_defined_inside_a_function_runs_where_it_can(tmp_path, monkeypatch):
    class Local(Planner):  # not importable by name: a spawned worker cannot unpickle it
        name = "local"

        def brake(self, obs: PlannerInput) -> bool:
            return False

    monkeypatch.setitem(PLANNERS, "local", Local)
    assert len(run_experiment(tmp_path / "serial", range(2), ("local",), progress=False, workers=1)) == 2
    if START_METHOD == "fork":  # forked workers inherit it
        result = run_experiment(tmp_path / "pool", range(4), ("local",), progress=False, workers=2)
        assert [r["status"] for r in result] == [OK] * 4
    else:
        with pytest.raises(ValueError, match="cannot be sent to worker processes"):
            run_experiment(tmp_path / "pool", range(4), ("local",), progress=False, workers=2)
        assert not (tmp_path / "pool").exists()


def test_a_second_run_into_a_busy_directory_is_refused(tmp_path):
    with locked(tmp_path), pytest.raises(ValueError, match="in use by another run"):  # as another run holds it
        run_experiment(tmp_path, range(2), ("reactive",), progress=False, workers=1)
    assert not (tmp_path / "episodes.jsonl").exists()
    assert run_experiment(tmp_path, range(2), ("reactive",), progress=False, workers=1).ran == 2


def test_results_without_their_settings_are_refused(serial, tmp_path):
    out = tmp_path / "copy"
    out.mkdir()
    (out / "episodes.jsonl").write_bytes((serial.out_dir / "episodes.jsonl").read_bytes())
    with pytest.raises(ValueError, match=r"no settings\.json beside it"):
        run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False, resume=True)
    (out / "settings.json").write_text("")
    with pytest.raises(ValueError, match=r"settings\.json is damaged"):
        run_experiment(out, SEEDS, ("cdf", "reactive"), cdf=SMALL, progress=False, resume=True)


class NumpySummaryPlanner(ReactivePlanner):
    """Puts a NumPy scalar into its record (written as a plain number) and, on odd seeds,
    a NaN, which JSON cannot hold."""

    name = "numpy-summary"

    def reset(self, context, rng) -> None:
        super().reset(context, rng)
        self.odd = None

    def brake(self, obs: PlannerInput) -> bool:
        if self.odd is None:
            self.odd = obs.poses[0, 0] < -40.8  # the ego's start: about half the seeds
        return super().brake(obs)

    def summary(self) -> dict:
        return {"score": np.float32(float("nan") if self.odd else 1.0)}


def test_numpy_values_are_written_and_a_record_json_cannot_hold_is_a_failed_episode(tmp_path, monkeypatch):
    monkeypatch.setitem(PLANNERS, "numpy-summary", NumpySummaryPlanner)
    result = run_experiment(tmp_path, range(6), ("reactive", "numpy-summary"), progress=False, workers=1)
    mine = [r for r in load_records(tmp_path) if r["planner"] == "numpy-summary"]
    good = [r for r in mine if r["status"] == OK]
    bad = [r for r in mine if r["status"] == FAILED]
    assert good and bad and result.failed == len(bad)  # the run went on past the bad ones
    assert all(r["planner_info"]["score"] == 1.0 for r in good)
    assert all("not JSON-serialisable" in r["error"] and r["seed"] in range(6) for r in bad)
    assert all(r["status"] == OK for r in result if r["planner"] == "reactive")


def test_an_unwritable_output_is_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    assert main(["experiment", "--episodes", "2", "--planner", "reactive", "--out", str(afile), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cdf-mj: error: ") and "afile" in err and err.count("\n") == 1


def test_a_pool_started_in_a_thread_that_ends_keeps_its_workers():
    """The workers' death signal follows the thread that forked them: a pool started by a
    short-lived thread must not lose its workers when that thread ends."""
    import threading

    from cdf_mj.config import ScenarioConfig
    from cdf_mj.experiments.runner import SeedJob, run_seeds
    from cdf_mj.planners.registry import bind_planner
    from cdf_mj.sim.scene import DEFAULT_SCENE

    job = SeedJob(ScenarioConfig(), str(DEFAULT_SCENE), ("reactive",),
                  {"reactive": bind_planner("reactive", CDFConfig())})
    gen = run_seeds(job, [(s, ("reactive",)) for s in range(6)], backend="process", workers=2)
    first = []
    thread = threading.Thread(target=lambda: first.append(next(gen)))
    thread.start()
    thread.join()
    rest = list(gen)  # the thread that started the pool is gone
    assert sorted(r.seed for r in first + rest) == list(range(6))
