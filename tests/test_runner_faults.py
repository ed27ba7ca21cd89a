"""cdf_mj.experiments.runner under faults: a planner that exits, a Ray cluster that is not
there, more workers asked for than seeds (issue 15, items 8 and 11)."""

from __future__ import annotations

import socket
import sys
import time

import pytest

from cdf_mj.cli import EXIT_FAILED_EPISODES, EXIT_USAGE, main
from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.experiments.runner import (
    RAY_CONNECT_TIMEOUT_S,
    ClusterUnreachableError,
    SeedJob,
    run_seeds,
    worker_count,
)
from cdf_mj.planners.registry import PLANNERS
from cdf_mj.planners.simple import ReactivePlanner
from cdf_mj.records import FAILED, OK
from cdf_mj.sim.scene import DEFAULT_SCENE


class _QuitsOnOddSeeds(ReactivePlanner):
    """A user's planner that calls ``sys.exit()`` from ``reset`` on some episodes."""

    def reset(self, context, rng):
        if int(rng.integers(2)):
            sys.exit(0)  # SystemExit(0): must not end the run as a success
        super().reset(context, rng)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_planner_raising_system_exit_is_a_failed_episode(tmp_path, monkeypatch, workers):
    monkeypatch.setitem(PLANNERS, "quitter", _QuitsOnOddSeeds)
    result = run_experiment(tmp_path, range(6), ["quitter", "reactive"], progress=False, workers=workers)
    mine = [r for r in result.records if r["planner"] == "quitter"]
    assert len(result.records) == 12  # every seed of every planner has its record
    assert {r["status"] for r in mine} == {OK, FAILED}  # some quit, some did not
    assert all(r["error"].startswith("SystemExit") for r in mine if r["status"] == FAILED)
    assert result.failed == sum(r["status"] == FAILED for r in mine)
    assert all(r["status"] == OK for r in result.records if r["planner"] == "reactive")


def test_the_cli_exits_1_when_a_planner_raised_system_exit(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(PLANNERS, "quitter", _QuitsOnOddSeeds)
    status = main(["experiment", "--episodes", "6", "--planner", "quitter", "--workers", "1", "--quiet",
                   "--out", str(tmp_path)])
    assert status == EXIT_FAILED_EPISODES
    assert "episodes failed" in capsys.readouterr().err


def test_worker_count_is_what_runs():
    assert worker_count("process", 10**30, 3) == 3
    assert worker_count("process", 4, 100) == 4
    assert worker_count("process", 8, 1) == 1  # one seed runs in this process
    assert worker_count("ray", 10**30, 3) == 3


def _closed_port() -> int:
    """A local TCP port on which nothing listens (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_ray_without_a_cluster_fails_at_once_with_one_line(tmp_path, capsys):
    pytest.importorskip("ray", reason="the ray extra is not installed")
    address = f"127.0.0.1:{_closed_port()}"
    job = SeedJob(config=ScenarioConfig(), scene=str(DEFAULT_SCENE), planners=("reactive",),
                  factories={"reactive": PLANNERS["reactive"]})
    t0 = time.perf_counter()
    with pytest.raises(ClusterUnreachableError, match=f"no Ray cluster answers at {address}"):
        run_seeds(job, [(0, ("reactive",)), (1, ("reactive",))], backend="ray", address=address)
    with pytest.raises(ClusterUnreachableError, match="port must be a number"):
        run_seeds(job, [(0, ("reactive",)), (1, ("reactive",))], backend="ray", address="127.0.0.1:http")
    status = main(["experiment", "--episodes", "2", "--planner", "reactive", "--backend", "ray", "--address",
                   address, "--quiet", "--out", str(tmp_path)])
    assert status == EXIT_USAGE
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"cdf-mj: error: no Ray cluster answers at {address}")
    assert time.perf_counter() - t0 < RAY_CONNECT_TIMEOUT_S  # refused, not waited for
