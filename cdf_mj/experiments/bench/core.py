"""The bench's first job: the scenario's building blocks (the floor itself, one ``mj_step``,
a planner tick of physics, the sight lines, the isovist, and two labelled episodes)."""

from __future__ import annotations

from pathlib import Path

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.bench.floor import FloorProbe, load_scene, put_at_start
from cdf_mj.experiments.bench.rows import PHYSICS_TICK_ROW, Row, episode_passes, interleaved, timed_row
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import DEFAULT_SCENE
from cdf_mj.sim.visibility import ego_visible, isovist

__all__ = ["bench_core"]


def bench_core(episodes: int = 10, scene: str | Path = DEFAULT_SCENE,
               config: ScenarioConfig | None = None, probe: FloorProbe | None = None,
               repeats: int = 3) -> list[Row]:
    """Rows for the scenario's building blocks, on ``scene`` (an MJCF path) with ``config``:
    the floor itself (``100 * repeats`` floor samples in a row), one ``mj_step``, a planner
    tick of physics, the sight lines and the isovist (``100 * repeats`` calls each), and
    two labelled episodes of ``episodes`` seeds in ``repeats`` passes; the floor samples
    from ``probe`` (a new one if not given)."""
    probe = probe or FloorProbe(scene, config)
    world, cfg = load_scene(scene, config)
    layout = world.layout()
    n_sub, calls = probe.substeps, 100 * repeats
    probe.block()  # warm-up
    floor = tuple(probe.block() for _ in range(calls))
    rows: list[Row] = [
        Row("mj_step (two cars): a floor sample over its steps", tuple(f / n_sub for f in floor), "",
            floor=floor),
        Row(f"physics floor: {n_sub} mj_step per planner tick of {cfg.timing.dt:g} s", floor,
            "a floor sample: the unit of the x floor column", floor=floor)]

    def tick(i: int) -> float:
        put_at_start(world, cfg)  # like a floor sample: from the start (and the reset untimed)
        t0 = probe.time()
        world.step(n_sub)
        return probe.time() - t0

    _, ticks, floors = interleaved(tick, calls, probe)
    rows.append(Row(f"{PHYSICS_TICK_ROW} ({n_sub} steps + contact check)", tuple(ticks),
                    "from the start, like a floor sample: never under the floor", floor=tuple(floors)))
    put_at_start(world, cfg)
    world.sync()
    eye = layout.obstacle.eye(layout.obstacle_start)
    rows.append(timed_row("ego_visible (5 sight lines, mj_multiRay)", lambda i: ego_visible(world), calls, probe))
    rows.append(timed_row("isovist 360 rays + shapely polygon", lambda i: isovist(world, eye).polygon, calls,
                          probe))
    seeds = range(1000, 1000 + episodes)
    dt = cfg.timing.dt
    constant = episode_passes(lambda s: run_episode(cfg, s, "constant", world), seeds, repeats, dt, probe)
    rows.append(constant.row("episode, constant (labels itself)", episodes))
    reactive = episode_passes(lambda s: run_episode(cfg, s, "reactive", world), seeds, repeats, dt, probe)
    best = min(reactive.walls) / episodes
    rows.append(reactive.row("episode, reactive + counterfactual", episodes,
                             f"target < 50 ms (issue 12): {'met' if best < 0.05 else 'MISSED'}"))
    return rows
