"""``cdf-mj bench``'s falsification job: how many episodes a second a falsification's Monte
Carlo estimate runs on a number of worker processes (wall time). Here, not among the
bench's other jobs (:mod:`cdf_mj.experiments.bench`), because it runs the falsifier, a
layer above them."""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.bench.floor import FloorProbe
from cdf_mj.experiments.bench.rows import Row, duration, goal_reading, one_off, planner_ticks
from cdf_mj.falsify.evaluate import JOURNAL_FILE
from cdf_mj.falsify.run import estimate
from cdf_mj.falsify.space import load_space
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["bench_falsification"]

#: The goal's worker count (issue 38: >= 60 CDF episodes a second on 2 workers).
GOAL_WORKERS = 2


def bench_falsification(episodes: int = 400, workers: int = GOAL_WORKERS, planner: str = "cdf",
                        space: str = "default", scene: str | Path = DEFAULT_SCENE,
                        config: ScenarioConfig | None = None, probe: FloorProbe | None = None) -> Row:
    """Wall time of a plain Monte Carlo estimate (:func:`cdf_mj.falsify.run.estimate`,
    ``method="mc"``) of ``episodes`` episodes of ``planner`` on the shipped search space
    ``space``, on ``workers`` worker processes, in a fresh temporary directory (its journal
    written as a falsification writes it; the workers' start included), on ``scene`` with
    ``config`` as the space's base world (its names, preset and values; default the space's
    own): one row, with 10
    floor samples (from ``probe``, a new one if not given) after it and a reading of the
    throughput target where ``workers`` is :data:`GOAL_WORKERS`; its x floor is per planner
    tick of the episodes (each is labelled: the seed's counterfactual runs too)."""
    probe = probe or FloorProbe(scene, config)
    searched = load_space(space)
    if config is not None:
        searched = dataclasses.replace(searched, base=config)
    dt = searched.base.timing.dt
    with tempfile.TemporaryDirectory(prefix="cdf-mj-bench-") as tmp:
        t0 = time.perf_counter()
        result = estimate(searched, planner, episodes, tmp, method="mc", scene=scene, workers=workers)
        wall = time.perf_counter() - t0
        with open(Path(tmp) / JOURNAL_FILE, encoding="utf-8") as journal:
            ends = [json.loads(line).get("summary", {}).get("end_time") for line in journal]
    ticks = sum(planner_ticks(float(t), dt) for t in ends if t is not None)
    rate = episodes / wall
    text = (f"{rate:.0f} episodes/s: {episodes} episodes of {planner} on the space {space!r} in {duration(wall)} "
            f"(wall) on {workers} worker(s)")
    reads = (goal_reading("falsification throughput on 2 workers", rate, text),) if workers == GOAL_WORKERS else ()
    return one_off(f"falsification: Monte Carlo estimate, {episodes} x {planner}, {workers} worker(s)", wall,
                   f"{text}; {result.failures} failures, {result.errors} raised", probe, wall / max(ticks, 1),
                   reads)
