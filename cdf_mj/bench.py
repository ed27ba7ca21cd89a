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
        for rep in range(repeats + 1):  # the first pass warms caches and is not timed
            pf.reset(poses[0])
            for k in range(1, len(poses)):
                t0 = time.perf_counter()
                pf.predict(poses[k - 1])
                t1 = time.perf_counter()
                pf.update(poses[k])
                if rep:
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


def bench_filter_parts(n_values: tuple[int, ...] = (250, 1000, 4000),
                       passes: int = 3) -> list[tuple[str, float, str]]:
    """Median time of one particle-filter tick (update + predict) at each N, split into
    its parts: predict (looks, belief ``g``, driver ``h``, bicycle ``f``), update without
    resampling (likelihood, normalise, posterior with P(cutoff)) and resampling.

    Driven by the measured system poses of a recorded constant-planner episode with the
    default scenario (the first seed of 0-99 with intent left labelled Cutoff: seed 1);
    ``passes`` runs of the filter along it. The predict parts re-run the stages of
    :meth:`ParticleFilter.predict` on a copy of the state (same calls, own Generator);
    the update part times ``update`` on a shallow copy of the filter that never
    resamples; the resample part is ``stratified_resample`` plus the gather of the five
    particle arrays. Run on one core: ``taskset -c 1 python scripts/bench.py --filter``.
    """
    import copy

    from cdf_mj.config import CDFConfig
    from cdf_mj.driver import bicycle_step, obstacle_control, update_belief
    from cdf_mj.episode import Labels
    from cdf_mj.inference import ParticleFilter
    from cdf_mj.resampling import stratified_resample

    scene = Scene.load()
    cfg = ScenarioConfig()
    for seed in range(100):
        rec = run_episode(cfg, seed, "constant", scene, label=True, trace=True)
        if rec.intent == "left" and rec.label == Labels.CUTOFF:
            break
    else:  # pragma: no cover - the default scenario has many
        raise RuntimeError("no Cutoff episode in seeds 0-99")
    poses = np.array(rec.trace["poses"])
    obs_std = np.array([cfg.obs_noise_pos, cfg.obs_noise_pos, cfg.obs_noise_heading, cfg.obs_noise_speed])
    parts = ("tick", "predict", "looks", "belief", "driver", "bicycle", "update_nr", "resample", "update")
    rows: list[tuple[str, float, str]] = []
    for n in n_values:
        cdf = CDFConfig(n_particles=n)
        pf = ParticleFilter.from_scene(scene, cfg, cdf, np.random.default_rng(0))
        nu_std = cdf.process_noise_scale * np.array([cfg.noise_accel, cfg.noise_steer])
        no_resample = cdf.replace(resample_ess_fraction=0.0)
        rng = np.random.default_rng(1)
        t: dict[str, list[float]] = {p: [] for p in parts}
        for pass_i in range(passes + 1):  # the first pass warms up and is not counted
            pf.reset(poses[0])
            warm = pass_i == 0
            for k in range(1, len(poses)):
                ego = poses[k - 1][0]
                # --- predict, stage by stage, on a copy of the state (as in predict)
                c0 = time.perf_counter()
                observed = rng.random(n) < cfg.beta
                idx = np.flatnonzero(observed)
                if idx.size:
                    corners = pf.ego.footprint(ego)
                    targets = np.vstack([corners, corners.mean(axis=0)])
                    observed[idx] = pf.occluders.visible(pf.obstacle.eye(pf.pose[idx]), targets)
                obs = ego + rng.standard_normal((n, 4)) * obs_std
                c1 = time.perf_counter()
                belief, has_belief = update_belief(pf.belief, pf.has_belief, observed, obs, cfg.dt,
                                                   pf.ego.wheelbase)
                c2 = time.perf_counter()
                u, _mode = obstacle_control(pf.model, pf.pose, pf.mode, belief, has_belief, pf.intent)
                u = u + rng.standard_normal((n, 2)) * nu_std
                u[:, 0] = np.clip(u[:, 0], pf.obstacle.accel_range[0], pf.obstacle.accel_range[1])
                u[:, 1] = np.clip(u[:, 1], pf.obstacle.steer_range[0], pf.obstacle.steer_range[1])
                c3 = time.perf_counter()
                bicycle_step(pf.pose, u, cfg.dt, pf.obstacle.wheelbase)
                c4 = time.perf_counter()
                # --- the real tick
                pf.predict(poses[k - 1])
                c5 = time.perf_counter()
                twin = copy.copy(pf)  # shares the arrays; update only rebinds them
                twin.cdf, twin.rng = no_resample, np.random.default_rng(k)
                c6 = time.perf_counter()
                twin.update(poses[k])
                c7 = time.perf_counter()
                keep = stratified_resample(twin.weights, rng)
                _g = (twin.pose[keep], twin.mode[keep], twin.belief[keep], twin.has_belief[keep],
                      twin.intent[keep])
                c8 = time.perf_counter()
                pf.update(poses[k])
                c9 = time.perf_counter()
                if warm:
                    continue
                for p, dt_ in zip(parts, (c5 - c4 + c9 - c8, c5 - c4, c1 - c0, c2 - c1, c3 - c2, c4 - c3,
                                          c7 - c6, c8 - c7, c9 - c8)):
                    t[p].append(dt_)
        med = {p: statistics.median(v) for p, v in t.items()}
        note = ""
        if n == 1000:
            note = (f"target <= 1 ms: {'met' if med['tick'] <= 1e-3 else 'MISSED'}, "
                    f"stretch <= 0.5 ms: {'met' if med['tick'] <= 5e-4 else 'missed'}")
        ticks = len(t["tick"])
        rows += [
            (f"filter tick N={n} (update + predict), {ticks} ticks of seed {rec.seed}", med["tick"], note),
            (f"  predict N={n}", med["predict"], ""),
            ("    looks: beta draws, occlusion of the GOING few, observation noise", med["looks"], ""),
            ("    belief g (dead reckoning of every particle)", med["belief"], ""),
            ("    driver h (route projection, FSM, pure pursuit) + process noise", med["driver"], ""),
            ("    bicycle f", med["bicycle"], ""),
            (f"  update N={n}", med["update"], "incl. resampling every step"),
            ("    likelihood + normalise + posterior (no resampling)", med["update_nr"], ""),
            ("    resample (stratified) + gather", med["resample"], ""),
        ]
    return rows
