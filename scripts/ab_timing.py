#!/usr/bin/env python3
"""Time two checkouts of cdf_mj against each other, alternating, in one run.

On a shared, noisy machine a figure from yesterday cannot be compared with one from
today; two versions timed in alternation, minutes apart, can. Each round runs a fresh
interpreter per checkout (pinned to one core where ``taskset`` exists) and times, on the
same poses and seeds:

- one particle-filter tick (``predict`` + ``update``) at N = 1000 [ms];
- one CDF episode without the counterfactual [ms];
- one labelled reactive episode and one labelled CDF episode [ms].

Usage (make the older checkout with ``git worktree add /tmp/base <commit>``)::

    python scripts/ab_timing.py /tmp/base . --rounds 3

It prints every round and the median of each figure per checkout with the ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

# Runs inside the child interpreter, importing cdf_mj from the checkout on PYTHONPATH.
# Only APIs that every version since the layer subpackages has (run_episode,
# ParticleFilter): a filter is built from the scene's layout and the tick, from the layout
# and the world's config before the config had groups, or from the scene itself before
# Scene.layout() existed.
_CHILD = r"""
import json, statistics, time
import numpy as np
import cdf_mj
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

scene, cfg = Scene.load(), ScenarioConfig()
poses = np.array(run_episode(cfg, 1, "constant", scene, trace=True).trace["poses"])
args = (cfg, CDFConfig(n_particles=1000), np.random.default_rng(0))
if hasattr(cfg, "timing"):  # the filter takes the tick, not the world's config
    pf = ParticleFilter.from_layout(scene.layout(), *args[1:], cfg.timing.dt)
elif hasattr(scene, "layout"):
    pf = ParticleFilter.from_layout(scene.layout(), *args)
else:
    pf = ParticleFilter.from_scene(scene, *args)
ticks = []
for rep in range(6):
    pf.reset(poses[0])
    for k in range(1, len(poses)):
        t = time.perf_counter()
        pf.predict(poses[k - 1])
        pf.update(poses[k])
        ticks.append(time.perf_counter() - t)
ticks = ticks[len(poses) - 1:]  # the first replay warms up

def episode_ms(planner, label):
    walls = []
    for seed in range(2000, 2012):
        t = time.perf_counter()
        run_episode(cfg, seed, planner, scene, label=label)
        walls.append(time.perf_counter() - t)
    return 1e3 * statistics.median(walls)

run_episode(cfg, 1999, "cdf", scene, label=False)  # warm-up
print(json.dumps({"__file__": cdf_mj.__file__, "filter tick N=1000": 1e3 * statistics.median(ticks),
                  "cdf episode": episode_ms("cdf", False),
                  "reactive episode, labelled": episode_ms("reactive", True),
                  "cdf episode, labelled": episode_ms("cdf", True)}))
"""


def _run(checkout: Path) -> dict[str, float]:
    cmd = [sys.executable, "-c", _CHILD]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", "0", *cmd]
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    # Run from the checkout: "-c" puts the working directory first on sys.path, ahead
    # of PYTHONPATH, and an editable install's finder would otherwise win.
    done = subprocess.run(cmd, env=env, cwd=checkout, capture_output=True, text=True, check=False)
    if done.returncode:
        sys.exit(f"ab_timing: {checkout}: {done.stderr.strip().splitlines()[-1]}")
    figures = json.loads(done.stdout.strip().splitlines()[-1])
    imported = Path(figures.pop("__file__")).resolve()
    if not imported.is_relative_to(checkout):
        sys.exit(f"ab_timing: {checkout}: the child imported cdf_mj from {imported}; "
                 "uninstall the editable install or run from elsewhere")
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("a", type=Path, help="the first checkout (e.g. the older commit)")
    parser.add_argument("b", type=Path, help="the second checkout")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    args = parser.parse_args(argv)
    for path in (args.a, args.b):
        if not (path / "cdf_mj" / "__init__.py").is_file():
            parser.error(f"{path} is not a cdf_mj checkout (no cdf_mj/__init__.py)")
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    runs: dict[Path, list[dict[str, float]]] = {args.a: [], args.b: []}
    for r in range(args.rounds):
        for path in (args.a, args.b):
            runs[path].append(_run(path.resolve()))
            print(f"round {r + 1} {path}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in runs[path][-1].items()))
    print(f"\n| what (median of {args.rounds} rounds) | {args.a} | {args.b} | ratio |\n|---|---|---|---|")
    for key in runs[args.a][0]:
        ma = statistics.median(run[key] for run in runs[args.a])
        mb = statistics.median(run[key] for run in runs[args.b])
        print(f"| {key} | {ma:.2f} ms | {mb:.2f} ms | {ma / mb:.2f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
