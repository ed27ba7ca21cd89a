"""The bench's planners job: episodes of every registered planner, in passes over the same
seeds, and how many times faster than real time they ran."""

from __future__ import annotations

from pathlib import Path

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.bench.floor import FloorProbe, load_scene
from cdf_mj.experiments.bench.rows import Reading, Row, duration, episode_passes, goal_reading
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["bench_planners"]


_EPISODE_GOALS = {"cdf": "CDF episode (planner cdf)", "imm": "imm episode", "imm-risk": "imm-risk episode",
                  "cv-risk": "cv-risk episode"}


def bench_planners(episodes: int = 10, scene: str | Path = DEFAULT_SCENE,
                   config: ScenarioConfig | None = None, probe: FloorProbe | None = None,
                   repeats: int = 3) -> list[Row]:
    """One episode (no counterfactual) of every registered planner: ``repeats`` passes over
    ``episodes`` seeds from 2000, 3 floor samples after each episode (from ``probe``, a new
    one if not given). A repeat is a pass: its mean time an episode, and per tick. The
    note says how many times faster than real time the episodes ran: the simulated over
    the wall seconds of the fastest pass (what the targets judge), and the median over
    every episode."""
    from cdf_mj.planners.registry import PLANNERS, make_planner

    probe = probe or FloorProbe(scene, config)
    world, cfg = load_scene(scene, config)
    rows: list[Row] = []
    seeds = range(2000, 2000 + episodes)
    for name in sorted(PLANNERS):
        def episode(seed: int, name: str = name) -> EpisodeRecord:
            return run_episode(cfg, seed, make_planner(name), world, label=False)

        timed = episode_passes(episode, seeds, repeats, cfg.timing.dt, probe)
        fastest, median = timed.fastest, timed.median_speed
        note = (f"{fastest:.0f}x faster than real time in the fastest of {repeats} passes over {episodes} seeds "
                f"(all its seeds together); {median:.0f}x the median episode")
        reads: tuple[Reading, ...] = ()
        if name in _EPISODE_GOALS:
            reads = (goal_reading(_EPISODE_GOALS[name], fastest,
                                  f"{fastest:.0f}x real time in the fastest pass over {episodes} seeds ({median:.0f}x "
                                  f"the median of {len(timed.speeds)} episodes); "
                                  f"{duration(min(timed.walls) / episodes)} an episode"),)
        rows.append(timed.row(f"episode, {name} (no counterfactual)", episodes, note, reads))
    return rows
