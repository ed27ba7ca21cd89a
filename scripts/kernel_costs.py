#!/usr/bin/env python3
"""What the compiled kernels' parts cost, one by one: the figures of docs/PERFORMANCE.md
("What was compiled, and how" and "Where the time goes now") that ``cdf-mj bench`` does
not print::

    taskset -c 0 python scripts/kernel_costs.py            # about ten seconds

On the particles of a CDF filter that has run 20 ticks of seed 1 (N = 1000), medians of
repeated timings in this process:

- route projection per particle, tracked from the kept segment against the full search;
- a per-particle helper that reads a cache (as the filter's kernels do), called with
  seven array arguments, compiled with and without Numba's reference counting, per call;
- one draw from a ``numpy.random.Generator`` inside Numba (uniform, normal), and one
  cosine-and-sine pair;
- ``resample`` with the filter's parameter jitter and without it (``param_jitter = 0``);
- building the conflict map (the compiled overlap table), per process.

Each kernel is called many times in one compiled loop, so the per-call figures have no
Python dispatch in them.
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from collections.abc import Callable

import numba
import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference import kernels as filter_kernels
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.model import kernels
from cdf_mj.model.conflict import ConflictMap
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

N = 1000
REPEATS = 200


def _median(fn: Callable[[], object], repeats: int = REPEATS) -> float:
    """Median wall time [s] of ``fn()``, after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@numba.njit
def _project_all(table: np.ndarray, nseg: np.ndarray, r: np.ndarray, xy: np.ndarray, seg: np.ndarray,
                 full: bool) -> float:
    total = 0.0
    for i in range(xy.shape[0]):
        s, _ = kernels.project(table, nseg, r[i], xy[i, 0], xy[i, 1], kernels.NO_SEGMENT if full else seg[i])
        total += s
    return total


def _cached_arc(i: int, table: np.ndarray, nseg: np.ndarray, pose: np.ndarray, intent: np.ndarray, s: np.ndarray,
                seg: np.ndarray, s_route: np.ndarray) -> float:
    """The body of a per-particle helper as the filter's kernels call them (the same as
    ``cdf_mj.inference.kernels._arc``): a cache read, filled where it is stale."""
    if seg[i] < 0 or s_route[i] != intent[i]:
        s[i], seg[i] = kernels.project(table, nseg, intent[i], pose[i, 0], pose[i, 1], kernels.NO_SEGMENT)
        s_route[i] = intent[i]
    return float(s[i])


# Not cached: Numba's cache is keyed by the function's source, which both variants share.
_with_nrt = numba.njit(_cached_arc)
_without_nrt = numba.njit(_nrt=False)(_cached_arc)  # what cdf_mj.model.kernels.helper compiles with


@numba.njit
def _calls_with_nrt(table: np.ndarray, nseg: np.ndarray, pose: np.ndarray, intent: np.ndarray, s: np.ndarray,
                    seg: np.ndarray, s_route: np.ndarray) -> float:
    total = 0.0
    for i in range(pose.shape[0]):
        if intent[i] == 0:
            total += _with_nrt(i, table, nseg, pose, intent, s, seg, s_route)
    return total


@numba.njit
def _calls_without_nrt(table: np.ndarray, nseg: np.ndarray, pose: np.ndarray, intent: np.ndarray, s: np.ndarray,
                       seg: np.ndarray, s_route: np.ndarray) -> float:
    total = 0.0
    for i in range(pose.shape[0]):
        if intent[i] == 0:
            total += _without_nrt(i, table, nseg, pose, intent, s, seg, s_route)
    return total


@numba.njit
def _uniforms(rng: np.random.Generator, n: int) -> float:
    total = 0.0
    for _ in range(n):
        total += filter_kernels._uniform(rng)
    return total


@numba.njit
def _normals(rng: np.random.Generator, n: int) -> float:
    total = 0.0
    for _ in range(n):
        total += filter_kernels._normal(rng)
    return total


@numba.njit
def _trig(th: np.ndarray) -> float:
    total = 0.0
    for i in range(th.shape[0]):
        total += math.cos(th[i]) + math.sin(th[i])
    return total


def main() -> int:
    scene, cfg = Scene.load(), ScenarioConfig()
    layout = scene.layout()
    trace = run_episode(cfg, 1, "constant", scene, label=False, trace=True).trace
    assert trace is not None  # asked for
    poses = np.array(trace["poses"])
    pf = ParticleFilter.from_layout(layout, CDFConfig(n_particles=N), np.random.default_rng(0), cfg.timing.dt)
    pf.reset(poses[0])
    for k in range(1, 21):
        pf.predict(poses[k - 1])
        pf.update(poses[k])
    tab = pf.model.table
    xy = np.ascontiguousarray(pf.pose[:, :2])
    intent = np.ascontiguousarray(pf.intent)
    seg = pf._caches()[1].copy()  # each particle's kept segment
    rows: list[tuple[str, float, str]] = []

    def per(total: float, n: int = N) -> float:
        return total / n

    tracked = per(_median(lambda: _project_all(tab.table, tab.nseg, intent, xy, seg, False)))
    full = per(_median(lambda: _project_all(tab.table, tab.nseg, intent, xy, seg, True)))
    rows += [("route projection, tracked from the kept segment", tracked, "per particle"),
             ("route projection, full search", full,
              f"per particle ({', '.join(str(int(k)) for k in tab.nseg[:2])} segments on the left and right routes)")]
    s, seg_kept, route, _ = pf._caches()
    args = (tab.table, tab.nseg, pf.pose, intent, s.copy(), seg_kept.copy(), route.copy())
    left = int(np.count_nonzero(intent == 0))
    rows += [("cache-reading helper with 7 array arguments, reference counted", per(_median(
                 lambda: _calls_with_nrt(*args)), left), "per call"),
             ("the same helper, _nrt=False (cdf_mj.model.kernels.helper)", per(_median(
                 lambda: _calls_without_nrt(*args)), left), "per call")]
    rng = np.random.default_rng(1)
    draws = 100_000
    rows += [("Generator draw in Numba, uniform", per(_median(lambda: _uniforms(rng, draws), 20), draws), "per draw"),
             ("Generator draw in Numba, standard normal", per(_median(lambda: _normals(rng, draws), 20), draws),
              "per draw"),
             ("cosine and sine of one angle", per(_median(lambda: _trig(np.ascontiguousarray(pf.pose[:, 2])))),
              "per pair")]

    def resample(jitter: float) -> Callable[[], object]:
        other = ParticleFilter.from_layout(layout, CDFConfig(n_particles=N, param_jitter=jitter),
                                           np.random.default_rng(0), cfg.timing.dt)
        other.reset(poses[0])
        for k in range(1, 21):
            other.predict(poses[k - 1])
            other.update(poses[k])

        return other.resample  # on the weights of the last resampling (equal) from the second call on

    rows += [("resample, with the parameter jitter", _median(resample(CDFConfig().param_jitter)),
              f"per tick, N = {N}"),
             ("resample, param_jitter = 0", _median(resample(0.0)), f"per tick, N = {N}")]
    rows.append(("conflict map (compiled overlap table)", _median(lambda: ConflictMap.build(layout, 0.3), 5),
                 "per build (once per process and layout)"))

    print("| what | time | per |\n|---|---|---|")
    for what, sec, note in rows:
        value = (f"{sec * 1e9:.1f} ns" if sec < 1e-6 else f"{sec * 1e6:.1f} µs" if sec < 1e-3
                 else f"{sec * 1e3:.1f} ms")
        print(f"| {what} | {value} | {note} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
