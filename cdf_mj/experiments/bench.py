"""Benchmarks that print medians from one run (the machine is shared and noisy).

    cdf-mj bench                    # physics, rays, filter stages at N = 250/1000/10000, planners
    cdf-mj bench --reproduce        # and the paper's reproduction with 1 and 2 workers

Each timing is the median of repeated timings in this process (pin it to one core with
``taskset -c 0``); the reproduction rows are wall times of whole runs, with the parallel
efficiency ``T(1) / (k T(k))`` and the peak resident memory of a worker. The startup rows
(:func:`bench_startup`) are wall times of fresh Python processes.

Beside its time, every row shows its ratio to the physics floor measured in the same run
(:func:`physics_floor`: the median ``mj_step`` time times the physics steps of one planner
tick), per planner tick: a per-tick row (a filter tick, an env step) or a per-call row (one
call a tick) as it is, an episode row per tick of its episode, a reproduction row per
recorded tick, a one-off cost (startup, compiling) as a whole.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import mujoco
import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.checks import substeps
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene
from cdf_mj.sim.visibility import ego_visible, isovist

__all__ = [
    "PhysicsFloor",
    "Row",
    "bench_core",
    "bench_env",
    "bench_filter",
    "bench_planners",
    "bench_reproduction",
    "bench_startup",
    "format_rows",
    "median_time",
    "physics_floor",
]

# A row of the table: (what, seconds, note), or with a fourth item, the seconds per planner
# tick that the "x floor" column divides by the floor (without it, the time itself).
Row = tuple[str, float, str] | tuple[str, float, str, float]
_T = TypeVar("_T")


def median_time(fn: Callable[[int], object], repeats: int) -> float:
    """Median wall time [s] of ``fn(i)`` for i in range(repeats), after one warm-up call."""
    return statistics.median(t for t, _ in _timed(fn, repeats))


def _timed(fn: Callable[[int], _T], repeats: int) -> list[tuple[float, _T]]:
    """Wall time [s] and result of ``fn(i)`` for i in range(repeats), after one warm-up call."""
    fn(-1)
    out = []
    for i in range(repeats):
        t0 = time.perf_counter()
        result = fn(i)
        out.append((time.perf_counter() - t0, result))
    return out


def _ticks(end_time: float, dt: float) -> int:
    """Planner ticks of ``dt`` [s] in an episode that ended at ``end_time`` [s] (at least 1)."""
    return max(round(end_time / dt), 1)


def _median_episode(fn: Callable[[int], EpisodeRecord], repeats: int, dt: float) -> tuple[float, float]:
    """Median wall time [s] of one episode ``fn(i)`` and median wall time per tick [s] of
    its episode, for i in range(repeats), after one warm-up call."""
    timed = _timed(fn, repeats)
    return (statistics.median(t for t, _ in timed),
            statistics.median(t / _ticks(rec.end_time, dt) for t, rec in timed))


def _setup(scene: str | Path, config: ScenarioConfig | None) -> tuple[Scene, ScenarioConfig]:
    cfg = config or ScenarioConfig()
    return Scene.load(scene, names=cfg.names), cfg


def _at_start(world: Scene, cfg: ScenarioConfig) -> None:
    """Both cars at their start sites, the ego at its nominal speed, the obstacle at rest."""
    layout = world.layout()
    ego = layout.ego_start.copy()
    ego[3] = cfg.ego.speed
    world.reset(ego, layout.obstacle_start)


@dataclass(frozen=True)
class PhysicsFloor:
    """What physics alone costs: ``substeps`` MuJoCo steps (``dt / timestep``) per planner
    tick at the median time of one step, both cars apart and at speed (no contacts)."""

    step: float  # [s] median wall time of one mj_step (two cars)
    substeps: int  # physics steps per planner tick

    @property
    def tick(self) -> float:
        """[s] physics of one planner tick: the floor under any tick of an episode."""
        return self.step * self.substeps


def physics_floor(scene: str | Path = DEFAULT_SCENE, config: ScenarioConfig | None = None,
                  repeats: int = 2000) -> PhysicsFloor:
    """The median of ``repeats`` timed ``mj_step`` on ``scene`` with the ego at its start at
    speed and the obstacle at its start, and the steps per tick of ``config.timing.dt``."""
    world, cfg = _setup(scene, config)
    _at_start(world, cfg)
    step = median_time(lambda i: mujoco.mj_step(world.model, world.data), repeats)
    return PhysicsFloor(step, substeps(world.model.opt.timestep, cfg.timing.dt, world.source))


def bench_core(episodes: int = 60, scene: str | Path = DEFAULT_SCENE,
               config: ScenarioConfig | None = None, floor: PhysicsFloor | None = None) -> list[Row]:
    """Rows ``(what, median seconds, note[, seconds per tick])`` for the scenario's building
    blocks, on ``scene`` (an MJCF path) with ``config``; ``floor`` (measured if not given)
    gives the first two rows."""
    floor = floor or physics_floor(scene, config)
    world, cfg = _setup(scene, config)
    layout = world.layout()
    _at_start(world, cfg)
    n_sub = floor.substeps
    rows: list[Row] = [("mj_step (two cars)", floor.step, ""),
                       (f"physics floor: {n_sub} mj_step per planner tick of {cfg.timing.dt:g} s", floor.tick,
                        "what the x floor column divides by")]
    rows.append((f"planner tick of physics ({n_sub} steps + contact check)",
                 median_time(lambda i: world.step(n_sub), 300), ""))
    _at_start(world, cfg)
    world.sync()
    eye = layout.obstacle.eye(layout.obstacle_start)
    rows.append(("ego_visible (5 sight lines, mj_multiRay)", median_time(lambda i: ego_visible(world), 500), ""))
    rows.append(("isovist 360 rays + shapely polygon",
                 median_time(lambda i: isovist(world, eye).polygon, 300), ""))
    seed = lambda i: 1000 + max(i, 0)  # noqa: E731
    constant, per_tick = _median_episode(lambda i: run_episode(cfg, seed(i), "constant", world), episodes,
                                         cfg.timing.dt)
    rows.append(("episode, constant (labels itself)", constant, "", per_tick))
    reactive, per_tick = _median_episode(lambda i: run_episode(cfg, seed(i), "reactive", world), episodes,
                                         cfg.timing.dt)
    rows.append(("episode, reactive + counterfactual", reactive,
                 f"target < 50 ms: {'met' if reactive < 0.05 else 'MISSED'}", per_tick))
    return rows


def _duration(sec: float) -> str:
    """A time [s] in its most readable unit."""
    if sec < 1e-3:
        return f"{sec * 1e6:.1f} µs"
    if sec < 10:
        return f"{sec * 1e3:.2f} ms"
    return f"{sec:.1f} s"


def format_rows(rows: Sequence[Row], floor: PhysicsFloor | None = None) -> str:
    """Markdown table of benchmark rows, times in the most readable unit: medians, except
    the reproduction and startup rows, which are the wall time of one run (their notes say
    so); with ``floor``, an ``x floor`` column: each row's time per planner tick (its fourth
    item, else its time) over ``floor.tick``, and a line under the table that says so."""
    head = ["what", "time", *(["x floor"] if floor else []), "note"]
    out = [f"Machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
           f"MuJoCo {mujoco.__version__}, NumPy {np.__version__}", "",
           f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for row in rows:
        what, sec, note = row[:3]
        cells = [what, _duration(sec)]
        if floor:
            ratio = row[3] / floor.tick if len(row) > 3 else sec / floor.tick
            cells.append(f"{ratio:.2f}x" if ratio < 10 else f"{ratio:.0f}x")
        out.append(f"| {' | '.join([*cells, note])} |")
    if floor:
        out += ["", f"x floor: time per planner tick over the physics floor of this run, {floor.substeps} mj_step "
                    f"of {_duration(floor.step)} = {_duration(floor.tick)} per tick; episode rows per tick of "
                    "their episode (median over seeds; a labelling counterfactual's ticks not counted), "
                    "reproduction rows per recorded tick (wall time, all workers), one-off rows (startup, "
                    "compiling) whole."]
    return "\n".join(out)


def bench_filter(n_values: tuple[int, ...] = (250, 1000, 10000), passes: int = 3,
                 scene: str | Path = DEFAULT_SCENE,
                 config: ScenarioConfig | None = None) -> list[tuple[str, float, str]]:
    """Median time of one particle-filter tick at each N, stage by stage.

    Replays the measured system poses of a recorded cut-off episode (seed 1, constant
    planner) through the real :class:`ParticleFilter` stages, in the order the ``cdf``
    planner calls them: ``predict`` (one compiled pass: look, believe, act, move),
    ``weigh`` (likelihood, normalised weights, the posterior with P(cutoff)),
    ``resample`` (every tick, as in the paper), then the decision on the resampled
    particles (the default layered rule: the particles' futures, the compiled rollouts
    against the ego's four plans and the follow layer). The first row of each N is the
    whole tick, decision included; version 0.2's risk rule (three plans, going on rolled
    only where deferring collides) is timed on the same particles, apart. ``passes`` timed
    runs after one warm-up run (which also compiles the kernels, or loads them from
    Numba's cache).
    """
    from cdf_mj.config import CDFConfig
    from cdf_mj.inference.particle_filter import ParticleFilter
    from cdf_mj.planners.base import PlannerContext, PlannerInput
    from cdf_mj.planners.decision import LayeredRule, RiskRule

    world, cfg = _setup(scene, config)
    trace = run_episode(cfg, 1, "constant", world, trace=True).trace
    assert trace is not None  # asked for
    poses = np.array(trace["poses"])
    stages = ("predict", "weigh", "resample", "decide")
    rows: list[tuple[str, float, str]] = []
    context = PlannerContext.of(world.layout(), cfg)
    rule, layered = RiskRule(CDFConfig().risk), LayeredRule(CDFConfig().layered, CDFConfig().risk)
    rule.reset(context)
    targets = {1000: 1.5e-4, 10000: 1e-3}  # [s] issue 16
    for n in n_values:
        pf = ParticleFilter.from_layout(world.layout(), CDFConfig(n_particles=n), np.random.default_rng(0),
                                        cfg.timing.dt)
        predictor = _FilterFutures(pf)
        times: dict[str, list[float]] = {s: [] for s in ("tick", *stages, "risk")}
        for pass_i in range(passes + 1):  # the first pass warms up and is not timed
            pf.reset(poses[0])
            layered.reset(context)
            for k in range(1, len(poses)):
                c0 = time.perf_counter()
                pf.predict(poses[k - 1])
                c1 = time.perf_counter()
                pf.weigh(poses[k])
                c2 = time.perf_counter()
                pf.resample()
                c3 = time.perf_counter()
                layered.command(predictor, PlannerInput(t=k * cfg.timing.dt, poses=poses[k], obstacle_in_lane=False))
                c4 = time.perf_counter()
                rule.decide(predictor, poses[k][0], False)
                c5 = time.perf_counter()
                if pass_i:
                    times["tick"].append(c4 - c0)
                    for stage, dt in zip((*stages, "risk"), (c1 - c0, c2 - c1, c3 - c2, c4 - c3, c5 - c4), strict=True):
                        times[stage].append(dt)
        med = {s: statistics.median(v) for s, v in times.items()}
        note = ""
        if n in targets:
            note = (f"target <= {targets[n] * 1e3:g} ms: "
                    f"{'met' if med['tick'] <= targets[n] else 'MISSED'}")
            if n == 1000:  # and at most twice the physics of a tick (the x floor column)
                note += "; target <= 2x floor"
        rows += [(f"filter tick + decision N={n} ({len(times['tick'])} ticks of seed 1)", med["tick"], note),
                 ("  predict (look, believe, act, move: one compiled pass)", med["predict"], ""),
                 ("  weigh (likelihood, normalise, posterior with P(cutoff))", med["weigh"], ""),
                 ("  resample (stratified, gather, jitter, intent floor)", med["resample"], ""),
                 ("  decision (layered rule: futures, compiled rollouts of 4 plans, follow layer)", med["decide"],
                  "target <= 0.2 ms at N=1000 (issue 25): " + ("met" if med["decide"] <= 2e-4 else "MISSED")
                  if n == 1000 else ""),
                 ("  (apart) version 0.2's risk rule on the same particles", med["risk"], "")]
    return rows


class _FilterFutures:
    """The risk rule's view of a bare filter (what the ``cdf`` planner gives it)."""

    def __init__(self, pf: Any) -> None:
        self.pf = pf

    def alarm(self) -> float:
        return float(self.pf.posterior().p_cutoff)

    def futures(self, react_ticks: int) -> Any:
        return self.pf.futures(react_ticks)


def bench_planners(episodes: int = 20, scene: str | Path = DEFAULT_SCENE,
                   config: ScenarioConfig | None = None) -> list[Row]:
    """Median wall time of one episode (no counterfactual) for every registered planner,
    and how many times faster than real time it runs (median over seeds)."""
    from cdf_mj.planners.registry import PLANNERS, make_planner

    world, cfg = _setup(scene, config)
    rows: list[Row] = []
    for name in sorted(PLANNERS):
        run_episode(cfg, 1999, make_planner(name), world, label=False)  # warm-up
        walls, factors, per_tick = [], [], []
        for i in range(episodes):
            t0 = time.perf_counter()
            ep = run_episode(cfg, 2000 + i, make_planner(name), world, label=False)
            walls.append(time.perf_counter() - t0)
            factors.append(ep.end_time / walls[-1])
            per_tick.append(walls[-1] / _ticks(ep.end_time, cfg.timing.dt))
        speed = statistics.median(factors)
        note = f"{speed:.0f}x faster than real time (median of {episodes} seeds)"
        if name == "cdf":
            note += f"; target >= 300x: {'met' if speed >= 300 else 'MISSED'}"
        rows.append((f"episode, {name} (no counterfactual)", statistics.median(walls), note,
                     statistics.median(per_tick)))
    return rows


def bench_env(seconds: float = 1.0, repeats: int = 3, scene: str | Path = DEFAULT_SCENE,
              config: ScenarioConfig | None = None) -> list[Row]:
    """Time per step of the Gymnasium environment (one 0.1 s planner tick, seeded random
    actions) without the filter, with it, and with the defaults (filter and the labelling
    counterfactual at each reset): the median over ``repeats`` runs of ``seconds`` each.
    No rows without Gymnasium."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return []
    from cdf_mj.envs.t_intersection import TIntersectionEnv

    world, cfg = _setup(scene, config)
    rows: list[Row] = []
    variants: tuple[tuple[str, dict[str, Any]], ...] = (
        ("no filter", {"run_filter": False, "label": False}), ("with the filter", {"label": False}),
        ("defaults: filter and labels", {}))
    for what, kwargs in variants:
        env = TIntersectionEnv(scene=world, config=cfg, **kwargs)
        env.action_space.seed(0)
        per_step = []
        for rep in range(repeats):
            env.reset(seed=rep)
            n, t0 = 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                _obs, _r, terminated, truncated, _info = env.step(env.action_space.sample())
                n += 1
                if terminated or truncated:
                    env.reset()
            per_step.append((time.perf_counter() - t0) / n)
        step = statistics.median(per_step)
        note = f"{1.0 / step:.0f} steps/s"
        if what == "with the filter":
            note += f"; target >= 3000 steps/s: {'met' if 1.0 / step >= 3000 else 'MISSED'}"
        rows.append((f"env step, {what}", step, note))
    return rows


def bench_reproduction(episodes: int = 1000, workers: tuple[int, ...] = (1, 2),
                       planners: tuple[str, ...] = ("cdf", "reactive"),
                       progress: bool = False, scene: str | Path = DEFAULT_SCENE,
                       config: ScenarioConfig | None = None) -> list[Row]:
    """Wall time of the paper's reproduction (``episodes`` seeds from 0, every planner,
    labels included) with each worker count, in fresh temporary directories.

    Rows: one per worker count (note: parallel efficiency against the first count, peak
    resident memory of a worker), with the targets of issue 16 (<= 25 s on 2 workers of
    this 2-core machine, efficiency >= 90 %, <= 300 MB per worker).
    """
    from cdf_mj.experiments.experiment import run_experiment

    dt = (config or ScenarioConfig()).timing.dt
    rows: list[Row] = []
    base: tuple[int, float] | None = None
    for k in workers:
        with tempfile.TemporaryDirectory(prefix="cdf-mj-bench-") as tmp:
            result = run_experiment(tmp, range(episodes), planners, config, scene=scene,
                                    progress=progress, workers=k)
        wall = result.wall_time
        notes = [f"wall time of one run on {result.workers} worker(s) ({result.backend}); "
                 f"{len(result)} records, {result.failed} failed",
                 f"peak memory per worker {result.peak_worker_rss_mb:.0f} MiB "
                 f"(target <= 300 MB: {'met' if result.peak_worker_rss_mb * 1.048576 <= 300 else 'MISSED'})"]
        if base is None:
            base = (k, wall)
        else:
            eff = base[1] * base[0] / (k * wall)
            notes.append(f"efficiency {100 * eff:.0f} % against {base[0]} worker(s) "
                         f"(target >= 90 %: {'met' if eff >= 0.90 else 'MISSED'})")
        if k == 2 and episodes == 1000:
            notes.append(f"target <= 25 s: {'met' if wall <= 25 else 'MISSED'}")
        ticks = sum(_ticks(r["end_time"], dt) for r in result.records if "end_time" in r)
        rows.append((f"reproduction: {episodes} seeds x {'+'.join(planners)}, {k} worker(s)", wall,
                     "; ".join(notes), wall / max(ticks, 1)))
    return rows


def bench_startup(planner: str = "cdf", seed: int = 0) -> list[Row]:
    """What a fresh Python process pays before its first tick runs at speed, on the default
    scene and scenario: two rows, each a wall time of new processes.

    - ``numba first call``: in a fresh process (``NUMBA_CACHE_DIR`` unset: Numba's cache
      as installed), one episode of ``planner`` without labels minus a second run of it:
      compiling the package's Numba kernels, or loading them from the cache (and starting
      Numba itself). The note says how many kernels were loaded or compiled, and where the
      cache lives (the directories Numba read or wrote, checked for its ``*.nbi`` index
      files).
    - ``cold start``: ``python -m cdf_mj episode --planner planner`` (what ``cdf-mj
      episode`` runs) with ``NUMBA_CACHE_DIR`` pointing at a new empty directory, so that
      every kernel compiles; target < 10 s (issue 16).
    """
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    probe = f"from cdf_mj.experiments.bench import _first_calls; _first_calls({planner!r}, {seed})"
    t0 = time.perf_counter()
    done = _run_python(["-c", probe], env)
    wall = time.perf_counter() - t0
    first = json.loads(done.stdout.strip().splitlines()[-1])
    kernels = first["kernels"]
    hits = sum(k["hits"] for k in kernels.values())
    misses = sum(k["misses"] for k in kernels.values())
    paths = sorted({k["cache_path"] for k in kernels.values()})
    indexed = [p for p in paths if any(Path(p).glob("*.nbi"))]
    where = ", ".join(indexed) if indexed else "none found (nothing written)"
    rows: list[Row] = [(
        f"numba first call (compile or cache load): episode, {planner}, in a fresh process",
        first["first"] - first["second"],
        f"first episode minus the second; {len(kernels)} kernels: {hits} loaded from Numba's cache, "
        f"{misses} compiled; cache: {where}; the process took {wall:.1f} s")]

    with tempfile.TemporaryDirectory(prefix="cdf-mj-numba-") as cache:
        t0 = time.perf_counter()
        done = _run_python(["-m", "cdf_mj", "episode", "--planner", planner, "--seed", str(seed)],
                           {**env, "NUMBA_CACHE_DIR": cache})
        wall = time.perf_counter() - t0
        compiled = len(list(Path(cache).rglob("*.nbi")))
    json.loads(done.stdout)  # the record it printed: the episode ran to the end
    rows.append((f"cold start: cdf-mj episode --planner {planner}, empty Numba cache", wall,
                 f"wall time of a new process (python -m cdf_mj episode, labels included); {compiled} kernels "
                 f"compiled into an empty NUMBA_CACHE_DIR; target < 10 s: {'met' if wall < 10 else 'MISSED'}"))
    return rows


def _run_python(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run this Python with ``args`` and ``env``; ChildProcessError (an OSError: ``cdf-mj``
    reports it in one line and exits 1) with the end of its stderr if it fails."""
    done = subprocess.run([sys.executable, *args], env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ChildProcessError(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return done


def _first_calls(planner: str, seed: int) -> None:
    """The fresh process of :func:`bench_startup`: print as JSON the wall times [s] of two
    runs of one episode of ``planner`` (no labels) and the cache path, hits and misses of
    every Numba kernel of the package that they loaded or compiled."""
    import numba

    scene = Scene.load()
    t1 = time.perf_counter()
    run_episode(None, seed, planner, scene, label=False)
    t2 = time.perf_counter()
    run_episode(None, seed, planner, scene, label=False)
    t3 = time.perf_counter()
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
