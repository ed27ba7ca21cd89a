"""Worker processes bounded by the work and quiet on Ctrl-C (issue 39, causes 5 and 10): a
pool kept across a search's batches (:class:`SeedPool`, what ``falsify`` and ``estimate``
run on) starts no more workers than the largest batch it was given, as ``experiment``
does; and an idle worker ignores SIGINT, so that Ctrl-C on a pool prints no traceback of a
worker and breaks no pool."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.runner import START_METHOD, SeedJob, SeedPool
from cdf_mj.planners.registry import bind_planner
from cdf_mj.sim.scene import DEFAULT_SCENE

REPO = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(START_METHOD != "fork", reason="counts forked workers (Linux)")


def _job() -> SeedJob:
    return SeedJob(config=ScenarioConfig(), scene=str(DEFAULT_SCENE), planners=("reactive",),
                   factories={"reactive": bind_planner("reactive")})


def _workers() -> int:
    """Worker processes of this process now alive."""
    return len(multiprocessing.active_children())


def test_a_seed_pool_starts_no_more_workers_than_its_batch_holds():
    """``--workers 1024`` on 4 episodes started about 600 processes; here 6 asked, 2 seeds."""
    before = _workers()
    with SeedPool(_job(), "process", workers=6) as pool:
        got = sorted(r.seed for r in pool.run([(0, ("reactive",)), (1, ("reactive",))]))
        assert got == [0, 1]
        assert _workers() - before <= 2
    assert _workers() == before


def test_a_seed_pool_grows_to_a_larger_batch_up_to_its_workers():
    before = _workers()
    with SeedPool(_job(), "process", workers=2) as pool:
        assert [r.seed for r in pool.run([(5, ("reactive",))])] == [5]  # one seed: in this process
        assert _workers() == before
        assert sorted(r.seed for r in pool.run([(6, ("reactive",)), (7, ("reactive",)), (8, ("reactive",))])) \
            == [6, 7, 8]
        assert _workers() - before == 2  # never more than asked
    assert _workers() == before


_IDLE_SIGINT = textwrap.dedent("""
    import os, signal, sys, time
    from concurrent.futures import wait
    from cdf_mj.config import ScenarioConfig
    from cdf_mj.experiments.runner import SeedJob, SeedPool
    from cdf_mj.planners.registry import bind_planner
    from cdf_mj.sim.scene import DEFAULT_SCENE

    job = SeedJob(config=ScenarioConfig(), scene=str(DEFAULT_SCENE), planners=("reactive",),
                  factories={"reactive": bind_planner("reactive")})
    pool = SeedPool(job, "process", workers=2)
    list(pool.run([(0, ("reactive",)), (1, ("reactive",))]))  # both workers up, now idle
    executor = pool._backend.pool
    pids = list(executor._processes)
    assert len(pids) == 2, pids
    for pid in pids:
        os.kill(pid, signal.SIGINT)  # what Ctrl-C sends every process of the group
    time.sleep(1.0)
    alive = [p.is_alive() for p in executor._processes.values()]
    again = sorted(r.seed for r in pool.run([(2, ("reactive",)), (3, ("reactive",))]))
    pool.close()
    print("alive", alive, "again", again)
""")


def test_idle_workers_ignore_sigint_so_ctrl_c_prints_no_worker_traceback():
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", _IDLE_SIGINT], capture_output=True, text=True, timeout=120,
                          env=env, cwd=REPO)
    assert "Traceback" not in done.stderr and "KeyboardInterrupt" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["alive", "[True,", "True]", "again", "[2,", "3]"]
