"""Benchmarks that print medians from one run (the machine is shared and noisy).

    python scripts/bench.py            # episodes per planner, physics, rays

Each figure is the median of repeated timings on one core (this process).
"""

from __future__ import annotations

import platform
import statistics
import time
from typing import Callable

import mujoco
import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.episode import run_episode
from cdf_mj.scene import Scene
from cdf_mj.visibility import ego_visible, isovist

__all__ = ["median_time", "bench_core", "bench_filter", "format_rows"]


def median_time(fn: Callable[[int], object], repeats: int) -> float:
    """Median wall time [s] of ``fn(i)`` for i in range(repeats), after one warm-up call."""
    fn(-1)
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_core(episodes: int = 60) -> list[tuple[str, float, str]]:
    """Rows ``(what, median seconds, note)`` for the scenario's building blocks."""
    scene = Scene.load()
    cfg = ScenarioConfig()
    rows: list[tuple[str, float, str]] = []
    ego = np.array([-30.0, -1.85, 0.0, 13.4])
    scene.reset(ego, scene.obstacle_start)
    n_sub = int(round(cfg.dt / scene.model.opt.timestep))
    rows.append(("mj_step (two cars)", median_time(lambda i: mujoco.mj_step(scene.model, scene.data), 2000), ""))
    rows.append((f"planner tick of physics ({n_sub} steps + contact check)",
                 median_time(lambda i: scene.step(n_sub), 300), ""))
    scene.reset(ego, scene.obstacle_start)
    scene.sync()
    eye = scene.obstacle.eye(scene.obstacle_start)
    rows.append(("ego_visible (5 sight lines, mj_multiRay)", median_time(lambda i: ego_visible(scene), 500), ""))
    rows.append(("isovist 360 rays + shapely polygon",
                 median_time(lambda i: isovist(scene, eye).polygon, 300), ""))
    seed = lambda i: 1000 + max(i, 0)  # noqa: E731
    rows.append(("episode, constant (labels itself)",
                 median_time(lambda i: run_episode(cfg, seed(i), "constant", scene), episodes), ""))
    reactive = median_time(lambda i: run_episode(cfg, seed(i), "reactive", scene), episodes)
    rows.append(("episode, reactive + counterfactual", reactive,
                 f"target < 50 ms: {'met' if reactive < 0.05 else 'MISSED'}"))
    return rows


def format_rows(rows: list[tuple[str, float, str]]) -> str:
    """Markdown table of benchmark rows, times in the most readable unit."""
    out = [f"Machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
           f"MuJoCo {mujoco.__version__}, NumPy {np.__version__}", "",
           "| what | median | note |", "|---|---|---|"]
    for what, sec, note in rows:
        val = f"{sec * 1e6:.1f} µs" if sec < 1e-3 else f"{sec * 1e3:.2f} ms"
        out.append(f"| {what} | {val} | {note} |")
    return "\n".join(out)


def bench_filter(n_values: tuple[int, ...] = (250, 1000, 4000), repeats: int = 3) -> list[tuple[str, float, str]]:
    """Median time of one particle-filter tick (predict + update) at each N, with its
    parts, driven by the measured poses of a recorded cut-off episode, and a CDF episode."""
    from cdf_mj.config import CDFConfig
    from cdf_mj.inference import ParticleFilter
    from cdf_mj.planners import CDFPlanner

    scene = Scene.load()
    cfg = ScenarioConfig()
    rec = run_episode(cfg.replace(beta=0.0, p_left=1.0), 3, "constant", scene, label=False, trace=True)
    poses = np.array(rec.trace["poses"])
    rows: list[tuple[str, float, str]] = []
    for n in n_values:
        pf = ParticleFilter.from_scene(scene, cfg, CDFConfig(n_particles=n), np.random.default_rng(0))
        t_pred, t_upd = [], []
        for _ in range(repeats):
            pf.reset(poses[0])
            for k in range(1, len(poses)):
                t0 = time.perf_counter()
                pf.predict(poses[k - 1])
                t1 = time.perf_counter()
                pf.update(poses[k])
                t_pred.append(t1 - t0)
                t_upd.append(time.perf_counter() - t1)
        pred, upd = statistics.median(t_pred), statistics.median(t_upd)
        note = f"target <= 1 ms: {'met' if pred + upd <= 1e-3 else 'MISSED'}" if n == 1000 else ""
        rows.append((f"filter tick N={n} (predict + update)", pred + upd, note))
        rows.append((f"  predict N={n} (looks, belief, driver FSM, bicycle)", pred, ""))
        rows.append((f"  update N={n} (likelihood, P(cutoff), resample)", upd, ""))
    walls, factors = [], []
    for i in range(20):
        t0 = time.perf_counter()
        rec = run_episode(cfg, 1000 + i, CDFPlanner(), scene, label=False)
        walls.append(time.perf_counter() - t0)
        factors.append(rec.end_time / walls[-1])
    speed = statistics.median(factors)
    rows.append(("episode, cdf (N=1000, no counterfactual)", statistics.median(walls),
                 f"{speed:.0f}x faster than real time (median; target >= 50x: "
                 f"{'met' if speed >= 50 else 'MISSED'})"))
    return rows
