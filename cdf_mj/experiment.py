"""Many episodes: a batch runner that only loops and reports progress.

``run_many`` calls :func:`cdf_mj.episode.run_episode` for each seed with one scene
loaded once. It is serial; the parallel, resumable runner builds on it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Iterator

from tqdm import tqdm

from cdf_mj.config import ScenarioConfig
from cdf_mj.episode import EpisodeRecord, run_episode
from cdf_mj.scene import DEFAULT_SCENE, Scene

__all__ = ["run_many", "iter_episodes"]


def iter_episodes(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
                  scene: str | Path = DEFAULT_SCENE, progress: bool = True) -> Iterator[EpisodeRecord]:
    """Yield one labelled record per seed, in order, with a progress bar on stderr."""
    config = config or ScenarioConfig()
    sc = Scene.load(scene, names=config.names)
    seeds = list(seeds)
    for seed in tqdm(seeds, desc=f"{planner} episodes", unit="ep", disable=not progress, leave=False):
        yield run_episode(config, seed, planner, sc)


def run_many(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
             scene: str | Path = DEFAULT_SCENE, progress: bool = True) -> list[EpisodeRecord]:
    """Records of all ``seeds`` (see :func:`iter_episodes`)."""
    return list(iter_episodes(seeds, planner, config, scene, progress))
