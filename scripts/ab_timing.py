#!/usr/bin/env python3
"""Time two checkouts of cdf_mj against each other, alternating, in one run.

On a shared, noisy machine a figure from yesterday cannot be compared with one from
today; two versions timed in alternation, minutes apart, can. Each round runs a fresh
interpreter per checkout (pinned to one core where ``taskset`` exists) and times, on the
same poses and seeds:

- one particle-filter tick (``predict`` + ``update``) at N = 1000 [ms], and the same with
  the layered rule's decision (where the checkout has it);
- one episode without the counterfactual of ``cdf`` and of the baselines ``imm``,
  ``imm-risk``, ``imm-layered``, ``cv-risk`` (where the checkout has them) [ms], the mean
  over seeds 2000-2011;
- one labelled reactive episode and one labelled CDF episode [ms], likewise;
- one step of the Gymnasium environment without and with the filter [ms] (with Gymnasium).

Times are the CPU time of the child process (``time.process_time``; ``--clock wall`` for
wall time): on a shared host an episode outlasts a scheduler slice, so wall time mixes in
other processes' work (docs/PERFORMANCE.md).

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
import json, os, statistics, time
import numpy as np
import cdf_mj
from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.inference.particle_filter import ParticleFilter
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

clock = time.process_time if os.environ.get("AB_CLOCK", "cpu") == "cpu" else time.perf_counter
scene, cfg = Scene.load(), ScenarioConfig()
poses = np.array(run_episode(cfg, 1, "constant", scene, trace=True).trace["poses"])
args = (cfg, CDFConfig(n_particles=1000), np.random.default_rng(0))
if hasattr(cfg, "timing"):  # the filter takes the tick, not the world's config
    pf = ParticleFilter.from_layout(scene.layout(), *args[1:], cfg.timing.dt)
elif hasattr(scene, "layout"):
    pf = ParticleFilter.from_layout(scene.layout(), *args)
else:
    pf = ParticleFilter.from_scene(scene, *args)
try:  # the layered rule's decision (version 0.3 on)
    from cdf_mj.planners.base import PlannerContext, PlannerInput
    from cdf_mj.planners.decision import LayeredRule
    rule = LayeredRule(CDFConfig().layered, CDFConfig().risk)
    rule.reset(PlannerContext.of(scene.layout(), cfg))
except ImportError:
    rule = None

class Futures:
    def __init__(self, pf): self.pf = pf
    def alarm(self): return float(self.pf.posterior().p_cutoff)
    def futures(self, react_ticks): return self.pf.futures(react_ticks)

ticks, decided = [], []
for rep in range(6):
    pf.reset(poses[0])
    if rule is not None:
        rule.reset(PlannerContext.of(scene.layout(), cfg))
    for k in range(1, len(poses)):
        t = clock()
        pf.predict(poses[k - 1])
        pf.update(poses[k])
        t1 = clock()
        if rule is not None:
            rule.command(Futures(pf), PlannerInput(t=k * cfg.timing.dt, poses=poses[k], obstacle_in_lane=False))
        ticks.append(t1 - t)
        decided.append(clock() - t)
ticks, decided = ticks[len(poses) - 1:], decided[len(poses) - 1:]  # the first replay warms up

def episode_ms(planner, label):
    run_episode(cfg, 1999, planner, scene, label=label)  # warm-up (and compiling)
    t = clock()
    for seed in range(2000, 2012):
        run_episode(cfg, seed, planner, scene, label=label)
    return 1e3 * (clock() - t) / 12  # the mean: what a run of many episodes pays

def env_ms(**kwargs):
    from cdf_mj.envs.t_intersection import TIntersectionEnv
    env = TIntersectionEnv(scene=scene, config=cfg, label=False, **kwargs)
    env.action_space.seed(0)
    env.reset(seed=0)
    times = []
    for rep in range(4):
        n, t = 0, clock()
        while n < 200:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            n += 1
            if terminated or truncated:
                env.reset()
        times.append((clock() - t) / n)
    return 1e3 * statistics.median(times[1:])

out = {"__file__": cdf_mj.__file__, "filter tick N=1000": 1e3 * statistics.median(ticks)}
if rule is not None:
    out["filter tick + layered decision N=1000"] = 1e3 * statistics.median(decided)
from cdf_mj.planners.registry import PLANNERS
for name in ("cdf", "imm", "imm-risk", "imm-layered", "cv-risk"):
    if name in PLANNERS:
        out[f"{name} episode"] = episode_ms(name, False)
out["reactive episode, labelled"] = episode_ms("reactive", True)
out["cdf episode, labelled"] = episode_ms("cdf", True)
try:
    import gymnasium  # noqa: F401
    out["env step, no filter"] = env_ms(run_filter=False)
    out["env step, with the filter"] = env_ms()
except ImportError:
    pass
print(json.dumps(out))
"""


def _run(checkout: Path, clock: str = "cpu") -> dict[str, float]:
    cmd = [sys.executable, "-c", _CHILD]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", "0", *cmd]
    env = {**os.environ, "PYTHONPATH": str(checkout), "AB_CLOCK": clock}
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
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                        help="the child's CPU time (default) or wall time")
    args = parser.parse_args(argv)
    for path in (args.a, args.b):
        if not (path / "cdf_mj" / "__init__.py").is_file():
            parser.error(f"{path} is not a cdf_mj checkout (no cdf_mj/__init__.py)")
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    runs: dict[Path, list[dict[str, float]]] = {args.a: [], args.b: []}
    for r in range(args.rounds):
        for path in (args.a, args.b):
            runs[path].append(_run(path.resolve(), args.clock))
            print(f"round {r + 1} {path}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in runs[path][-1].items()))
    print(f"\n| what (median of {args.rounds} rounds) | {args.a} | {args.b} | ratio |\n|---|---|---|---|")
    for key in (k for k in runs[args.b][0] if k in runs[args.a][0]):
        ma = statistics.median(run[key] for run in runs[args.a])
        mb = statistics.median(run[key] for run in runs[args.b])
        print(f"| {key} | {ma:.2f} ms | {mb:.2f} ms | {ma / mb:.2f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
