"""The bench's startup job: what a fresh Python process pays before its first tick runs at
speed (Numba's first call, and a cold start with an empty Numba cache)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cdf_mj.experiments.bench.floor import CLOCKS, Clock, FloorProbe
from cdf_mj.experiments.bench.rows import Row, goal_reading, one_off
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

__all__ = ["bench_startup"]


def bench_startup(planner: str = "cdf", seed: int = 0, probe: FloorProbe | None = None) -> list[Row]:
    """What a fresh Python process pays before its first tick runs at speed, on the default
    scene and scenario: two rows, each a time of new processes (with ``probe``'s CPU
    clock, their CPU time, user and system; the note gives the wall time too), 10 floor
    samples (from ``probe``, a new one if not given) after each.

    - ``numba first call``: in a fresh process (``NUMBA_CACHE_DIR`` unset: Numba's cache
      as installed), one episode of ``planner`` without labels minus a second run of it
      (timed in that process with ``probe``'s clock):
      compiling the package's Numba kernels, or loading them from the cache (and starting
      Numba itself). The note says how many kernels were loaded or compiled, and where the
      cache lives (the directories Numba read or wrote, checked for its ``*.nbi`` index
      files).
    - ``cold start``: ``python -m cdf_mj episode --planner planner`` (what ``cdf-mj
      episode`` runs) with ``NUMBA_CACHE_DIR`` pointing at a new empty directory, so that
      every kernel compiles; target < 5 s (issue 27; < 10 s in issue 16).
    """
    probe = probe or FloorProbe()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    probe_code = (f"from cdf_mj.experiments.bench.startup import _first_calls; "
                  f"_first_calls({planner!r}, {seed}, {probe.clock!r})")
    t0 = time.perf_counter()
    done = _run_python(["-c", probe_code], env)
    wall = time.perf_counter() - t0
    first = json.loads(done.stdout.strip().splitlines()[-1])
    kernels = first["kernels"]
    hits = sum(k["hits"] for k in kernels.values())
    misses = sum(k["misses"] for k in kernels.values())
    paths = sorted({k["cache_path"] for k in kernels.values()})
    indexed = [p for p in paths if any(Path(p).glob("*.nbi"))]
    where = ", ".join(indexed) if indexed else "none found (nothing written)"
    rows = [one_off(
        f"numba first call (compile or cache load): episode, {planner}, in a fresh process",
        first["first"] - first["second"],
        f"first episode minus the second; {len(kernels)} kernels: {hits} loaded from Numba's cache, "
        f"{misses} compiled; cache: {where}; the process took {wall:.1f} s of wall time", probe)]

    with tempfile.TemporaryDirectory(prefix="cdf-mj-numba-") as cache:
        t0, c0 = time.perf_counter(), _children_cpu()
        done = _run_python(["-m", "cdf_mj", "episode", "--planner", planner, "--seed", str(seed)],
                           {**env, "NUMBA_CACHE_DIR": cache})
        wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
        compiled = len(list(Path(cache).rglob("*.nbi")))
    json.loads(done.stdout)  # the record it printed: the episode ran to the end
    # What a user waits for: the wall time of the process (its CPU time beside it), whatever the clock.
    rows.append(one_off(
        f"cold start: cdf-mj episode --planner {planner}, empty Numba cache", wall,
        f"wall time of a new process (python -m cdf_mj episode, labels included; CPU {cpu:.1f} s); {compiled} "
        f"kernels compiled into an empty NUMBA_CACHE_DIR; target < 5 s (issue 27): {'met' if wall < 5 else 'MISSED'}",
        probe, readings=(goal_reading("cold start with an empty Numba cache", text=f"{compiled} kernels compiled"),)
        if planner == "cdf" else ()))
    return rows


def _children_cpu() -> float:
    """[s] CPU time, user and system, of this process's finished children (NaN where the
    platform does not tell)."""
    try:
        import resource
    except ImportError:  # not on Windows
        return math.nan
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _run_python(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run this Python with ``args`` and ``env``; ChildProcessError (an OSError: ``cdf-mj``
    reports it in one line and exits 1) with the end of its stderr if it fails."""
    done = subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ChildProcessError(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return done


def _first_calls(planner: str, seed: int, clock: Clock = "wall") -> None:
    """The fresh process of :func:`bench_startup`: print as JSON the times [s] (``clock``)
    of two runs of one episode of ``planner`` (no labels) and the cache path, hits and
    misses of every Numba kernel of the package that they loaded or compiled."""
    import numba

    scene = Scene.load()
    now = CLOCKS[clock]
    t1 = now()
    run_episode(None, seed, planner, scene, label=False)
    t2 = now()
    run_episode(None, seed, planner, scene, label=False)
    t3 = now()
    kernels = {}
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] != "cdf_mj":
            continue
        for value in vars(module).values():
            if isinstance(value, numba.core.dispatcher.Dispatcher):
                stats = value.stats
                hits, misses = sum(stats.cache_hits.values()), sum(stats.cache_misses.values())
                if hits or misses:
                    kernels[f"{value.py_func.__module__}.{value.py_func.__name__}"] = {
                        "hits": hits, "misses": misses, "cache_path": stats.cache_path}
    print(json.dumps({"first": t2 - t1, "second": t3 - t2, "kernels": kernels}))
