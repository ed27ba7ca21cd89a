"""The bench's environment job: steps and resets of the Gymnasium environment, without the
filter, with it, and with the defaults."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cdf_mj.config import ScenarioConfig
from cdf_mj.experiments.bench.floor import FloorProbe, load_scene
from cdf_mj.experiments.bench.rows import Row, goal_reading
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["bench_env"]


def bench_env(seconds: float = 1.0, repeats: int = 3, scene: str | Path = DEFAULT_SCENE,
              config: ScenarioConfig | None = None, probe: FloorProbe | None = None) -> list[Row]:
    """Time per step of the Gymnasium environment (one 0.1 s planner tick, seeded random
    actions) without the filter, with it, and with the defaults (filter and the labelling
    counterfactual at each reset): ``repeats`` runs of ``seconds`` each, 5 floor samples
    (from ``probe``, a new one if not given) after each. A step row times the ``step``
    calls alone (the policy's sampling of the action and the resets are not in it); the
    resets of the same runs (random actions end an episode in about 20 steps) are a row of
    their own, per reset. No rows without Gymnasium."""
    try:
        import gymnasium  # noqa: F401
    except ImportError:
        return []
    from cdf_mj.envs.t_intersection import TIntersectionEnv

    probe = probe or FloorProbe(scene, config)
    clock = probe.time
    world, cfg = load_scene(scene, config)
    rows: list[Row] = []
    variants: tuple[tuple[str, dict[str, Any], str | None], ...] = (
        ("no filter", {"run_filter": False, "label": False}, "Gymnasium env step without the filter"),
        ("with the filter", {"label": False}, "env step with the filter"),
        ("defaults: filter and labels", {}, None))
    for what, kwargs, goal in variants:
        env = TIntersectionEnv(scene=world, config=cfg, **kwargs)
        env.action_space.seed(0)
        env.reset(seed=0)
        env.step(env.action_space.sample())  # warm-up
        per_step, floors, per_reset, reset_floors = [], [], [], []
        for rep in range(repeats):
            env.reset(seed=rep)
            steps = resets = 0
            in_steps = in_resets = 0.0
            start = clock()
            while clock() - start < seconds:
                action = env.action_space.sample()
                t0 = clock()
                _obs, _r, terminated, truncated, _info = env.step(action)
                t1 = clock()
                in_steps, steps = in_steps + t1 - t0, steps + 1
                if terminated or truncated:
                    env.reset()
                    in_resets, resets = in_resets + clock() - t1, resets + 1
            per_step.append(in_steps / steps)
            floors.append(probe.take(5))
            if resets:
                per_reset.append(in_resets / resets)
                reset_floors.append(floors[-1])
        note = f"{1.0 / min(per_step):.0f} steps/s at the least time a step (steps alone)"
        reads = (goal_reading(goal, text=f"{repeats} runs of {seconds:g} s"),) if goal else ()
        rows.append(Row(f"env step, {what}", tuple(per_step), note, floor=tuple(floors), readings=reads))
        if per_reset:  # (a run too short to end an episode has none)
            rows.append(Row(f"env reset, {what}", tuple(per_reset), "per reset, in the same runs",
                            floor=tuple(reset_floors)))
    return rows
