"""The bench's reproduction job: wall time of the paper's reproduction with each worker
count, its parallel efficiency and the peak memory of a worker."""

from __future__ import annotations

import tempfile
from pathlib import Path

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.bench.floor import FloorProbe
from cdf_mj.experiments.bench.rows import Row, duration, goal_reading, one_off, planner_ticks
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["bench_reproduction"]


def bench_reproduction(episodes: int = 1000, workers: tuple[int, ...] = (1, 2),
                       planners: tuple[str, ...] = ("cdf", "reactive"),
                       progress: bool = False, scene: str | Path = DEFAULT_SCENE,
                       config: ScenarioConfig | None = None, probe: FloorProbe | None = None) -> list[Row]:
    """Wall time of the paper's reproduction (``episodes`` seeds from 0, every planner,
    labels included) with each worker count, in fresh temporary directories; 10 floor
    samples (from ``probe``, a new one if not given) after each run.

    Rows: one per worker count (note: parallel efficiency against the first count, peak
    resident memory of a worker), with the targets of issue 16 (<= 25 s on 2 workers of
    this 2-core machine, efficiency >= 90 % at 2 workers against 1, <= 300 MB per worker).
    """
    from cdf_mj.experiments.experiment import run_experiment

    probe = probe or FloorProbe(scene, config)
    dt = (config or ScenarioConfig()).timing.dt
    rows: list[Row] = []
    base: tuple[int, float] | None = None
    for k in sorted(set(workers)):  # the fewest first: the efficiencies are against it
        with tempfile.TemporaryDirectory(prefix="cdf-mj-bench-") as tmp:
            result = run_experiment(tmp, range(episodes), planners, config, scene=scene,
                                    progress=progress, workers=k)
        wall = result.wall_time
        mb = result.peak_worker_rss_mb * 1.048576
        notes = [f"wall time of one run on {result.workers} worker(s) ({result.backend}); "
                 f"{len(result)} records, {result.failed} failed",
                 f"peak memory per worker {result.peak_worker_rss_mb:.0f} MiB"]
        reads = [goal_reading("memory per worker", mb, f"{mb:.0f} MB ({result.peak_worker_rss_mb:.0f} MiB): the "
                                                       f"peak of a worker in the run on {k} worker(s)")]
        if base is None:
            base = (k, wall)
        else:
            eff = base[1] * base[0] / (k * wall)
            notes.append(f"efficiency {100 * eff:.0f} % against {base[0]} worker(s)")
            if k == 2 and base[0] == 1:
                reads.append(goal_reading("parallel efficiency at 2 workers", 100 * eff,
                                          f"{100 * eff:.0f} %: T(1) / (2 T(2)), {duration(base[1])} and "
                                          f"{duration(wall)}, {episodes} seeds"))
        if k == 2 and episodes == 1000:
            notes.append(f"target <= 25 s (issue 16): {'met' if wall <= 25 else 'MISSED'}")
        ticks = sum(planner_ticks(r["end_time"], dt) for r in result.records if "end_time" in r)
        rows.append(one_off(f"reproduction: {episodes} seeds x {'+'.join(planners)}, {k} worker(s)", wall,
                            "; ".join(notes), probe, wall / max(ticks, 1), tuple(reads)))
    return rows
