#!/usr/bin/env python3
"""How few particles the CDF needs for the same decisions: an accuracy check of candidate
particle counts against a large-N reference, and a closed-loop check that a cheaper filter
loses nothing (issue 38).

A candidate is a fixed count ``N`` or ``adaptive:MIN-MAX`` (KLD-sampling at each
resampling, :class:`~cdf_mj.config.AdaptiveConfig`, from MIN up to MAX particles). Two
parts, each on held-out seeds (from 830000 by default: a range first used here; the
development look of issue 38 ran on 810000-810299), on six presets (the default world,
``stop-and-wait``, two junction-crash families, noisy and late sensing, an occluded ego):

``agreement`` (open loop): on every tick of ``cdf`` episodes (the ego obeying the shipped
``cdf``), shadow CDF planners with each candidate and one reference (``--reference``,
default N = 10 000) are given the same measurement, each drawing from its own stream. Per
candidate: the share of ticks whose command is of the reference's class (none; slowing, a
negative cap above the hard brake; hard brake), the episodes that agree on whether the ego
was slowed at all and braked hard at all, the absolute error of P(cutoff) and of the
emergency layer's risk against the reference (mean, 99th percentile, largest), its mean
particle count and the median CPU time of its tick (filter and decision).

``closed`` (closed loop): ``cdf`` with each candidate drives the ego on the same seeds as
``cdf`` with the shipped count, and so does the shipped count drawing from another stream
(the null: what a new stream alone changes); each against the shipped count, seed by seed
(:func:`cdf_mj.analysis.pareto.compare`: exact McNemar on collisions, non-Cutoff
interventions and non-Cutoff hard brakes; the time lost at the fixed point against the same
seed's ``constant``, by the sign test), per preset and pooled over the six. A candidate
loses nothing where each of its three p-values is at least 0.5 on every preset (issue 38's
"no loss"). The criterion for changing the default, declared after the closed loop of the
fixed counts had been seen and before that of the adaptive count ran: pooled over the six
presets no more collisions than the shipped count and each of the three pooled p-values
at least 0.5 (per preset, the null shows how often a new stream alone falls below 0.5).
``--streams K`` runs the shipped filter on K - 1 other streams and adds a table of their
spread beside each candidate's counts, a diagnostic::

    python scripts/particle_count.py                         # both parts, Markdown on stdout
    python scripts/particle_count.py --parts agreement --seeds 830000-830009 --presets default

Runs the agreement in this process and the closed loop on ``--workers`` processes (default
one per CPU), nothing written to disk: about 15 minutes on 2 cores for both parts (and
about 1.5 minutes more per extra stream). Bad arguments are one line
``particle_count: error: ...`` and exit status 2.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import math
import os
import statistics
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cdf_mj.analysis.pages import markdown_table
from cdf_mj.analysis.pareto import compare
from cdf_mj.cli.args import worker_count
from cdf_mj.config import AdaptiveConfig, CDFConfig, ScenarioConfig
from cdf_mj.planners.base import Planner, PlannerContext, PlannerInput
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.presets import load_preset
from cdf_mj.records.counting import hit_obstacle, intervened, is_false_alarm, is_imminent
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

PRESETS = ("default", "stop-and-wait", "stress-looked-but-failed", "stress-creeper", "stress-combined",
           "stress-occluded-rolling-stop")
SHIPPED = CDFConfig().n_particles
#: A count loses nothing where each of its McNemar p-values against the shipped count is at least this.
NO_LOSS_P = 0.5
#: Seeds of one preset are moved by this much times its place in the list when all are pooled.
_POOL_STRIDE = 10**9


def _range(text: str) -> range:
    """``A-B`` (inclusive) as a range of seeds."""
    try:
        lo, _, hi = text.partition("-")
        seeds = range(int(lo), int(hi or lo) + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds must be A-B, got {text!r}") from None
    if not seeds or seeds.start < 0:
        raise argparse.ArgumentTypeError(f"seeds must be a non-empty range of non-negative seeds, got {text!r}")
    return seeds


def candidate(text: str) -> CDFConfig:
    """The ``cdf`` filter of a count: ``N`` (a fixed count) or ``adaptive:MIN-MAX`` (KLD-sampling,
    :class:`~cdf_mj.config.AdaptiveConfig` with ``n_min`` MIN, at most MAX); ValueError else."""
    if text.startswith("adaptive:"):
        lo, _, hi = text.removeprefix("adaptive:").partition("-")
        return CDFConfig(n_particles=int(hi), adaptive=AdaptiveConfig(n_min=int(lo)))
    return CDFConfig(n_particles=int(text))


def _counts(text: str) -> tuple[str, ...]:
    """Comma-separated counts (:func:`candidate`), each checked."""
    counts = tuple(x.strip() for x in text.split(","))
    try:
        for x in counts:
            candidate(x)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"particle counts must be N or adaptive:MIN-MAX: {exc}") from None
    return counts


def _shown(count: str) -> str:
    """A candidate as the tables name it: ``N = 500``, ``adaptive 500-4000``."""
    return count.replace("adaptive:", "adaptive ") if count.startswith("adaptive:") else f"N = {count}"


def _reference(text: str) -> str:
    """One fixed particle count, checked by :class:`CDFConfig`."""
    try:
        CDFConfig(n_particles=int(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"the reference must be one fixed particle count: {exc}") from None
    return text


def _kind(command: float, hard: float) -> int:
    """A command's class: 0 none (no cap below zero), 1 slowing, 2 a hard brake."""
    return 2 if command <= -hard else 1 if command < 0.0 else 0


@dataclass
class _Shadow:
    """What one shadow planner said on every tick."""

    kinds: list[int] = field(default_factory=list)
    p_cutoff: list[float] = field(default_factory=list)
    risk: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)  # CPU time of each tick
    particles: list[int] = field(default_factory=list)  # the filter's count after each tick


class _Shadowed(Planner):
    """Drives with ``drive``; gives every shadow planner the same input each tick."""

    name = "cdf"

    def __init__(self, drive: CDFPlanner, shadows: Sequence[CDFPlanner]) -> None:
        self.drive, self.shadows = drive, list(shadows)
        self.said = [_Shadow() for _ in self.shadows]

    @property
    def graded(self) -> bool:
        return True

    @property
    def releases_brake(self) -> bool:
        return True

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        streams = rng.spawn(len(self.shadows))  # each shadow its own stream; the driving one keeps rng
        self.drive.reset(context, rng)
        for planner, stream in zip(self.shadows, streams, strict=True):
            planner.reset(context, stream)

    def command(self, obs: PlannerInput) -> float:
        command = self.drive.command(obs)
        hard = float(self.drive.hard_brake or math.inf)
        for planner, said in zip(self.shadows, self.said, strict=True):
            t0 = time.process_time()
            c = planner.command(obs)
            said.seconds.append(time.process_time() - t0)
            said.kinds.append(_kind(c, hard))
            said.p_cutoff.append(planner.posterior.p_cutoff)
            said.risk.append(float(planner.rule.values()["risk"]))
            said.particles.append(planner.filter.n)
        return command

    def summary(self) -> dict[str, Any]:
        return self.drive.summary()


def agreement(presets: Sequence[str], seeds: range, counts: Sequence[str], reference: str) -> list[str]:
    """Part ``agreement``: a table per preset (see the module)."""
    lines = ["## Agreement with the reference, open loop", "",
             f"Every tick of `cdf` episodes (N = {SHIPPED}, the ego obeying it), seeds {seeds.start}-{seeds[-1]}; "
             f"shadow filters of each count beside a reference of N = {reference}, each drawing from its own "
             "stream. Class: none, slowing, hard brake. Errors against the reference.", ""]
    header = ["count", "ticks, same class", "episodes, same (slowed, braked hard)", "P(cutoff) error: mean / p99 / max",
              "emergency risk error: mean / p99 / max", "particles, mean", "tick [us], median"]
    for preset in presets:
        config = load_preset(preset)
        scene = Scene.load(names=config.names)
        ticks = 0
        same = np.zeros(len(counts), dtype=int)
        episodes = np.zeros(len(counts), dtype=int)
        err_p: list[list[float]] = [[] for _ in counts]
        err_r: list[list[float]] = [[] for _ in counts]
        secs: list[list[float]] = [[] for _ in counts]
        sizes: list[list[int]] = [[] for _ in counts]
        for seed in seeds:
            planner = _Shadowed(CDFPlanner(), [CDFPlanner(candidate(n)) for n in (*counts, reference)])
            run_episode(config, seed, planner, scene, label=False)
            ref = planner.said[-1]
            ref_kinds = np.array(ref.kinds)
            ticks += len(ref_kinds)
            for i, said in enumerate(planner.said[:-1]):
                kinds = np.array(said.kinds)
                same[i] += int((kinds == ref_kinds).sum())
                episodes[i] += int(bool((kinds >= 1).any()) == bool((ref_kinds >= 1).any())
                                   and bool((kinds == 2).any()) == bool((ref_kinds == 2).any()))
                err_p[i] += np.abs(np.subtract(said.p_cutoff, ref.p_cutoff)).tolist()
                err_r[i] += np.abs(np.subtract(said.risk, ref.risk)).tolist()
                secs[i] += said.seconds
                sizes[i] += said.particles
            print(f"agreement: {preset} seed {seed}", file=sys.stderr, flush=True)

        def errors(values: list[float]) -> str:
            e = np.asarray(values)
            return f"{e.mean():.4f} / {np.quantile(e, 0.99):.3f} / {e.max():.3f}"

        rows = [[_shown(n), f"{same[i] / ticks:.2%}", f"{episodes[i]}/{len(seeds)}", errors(err_p[i]), errors(err_r[i]),
                 f"{statistics.fmean(sizes[i]):.0f}", f"{1e6 * statistics.median(secs[i]):.0f}"]
                for i, n in enumerate(counts)]
        lines += [f"`{preset}` ({ticks} ticks):", "", *markdown_table(header, rows), ""]
    return lines


class _OtherStream(CDFPlanner):
    """The shipped ``cdf`` drawing from another stream than the episode's planner stream
    (the ``stream``-th child of it, from 1): the closed loop's null comparisons (what a new
    stream alone changes)."""

    def __init__(self, stream: int) -> None:
        super().__init__()
        self.stream = stream

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        super().reset(context, rng.spawn(self.stream)[-1])


def _stream_name(j: int) -> str:
    """The planner name of the shipped filter on its ``j``-th other stream."""
    return "cdf-other-stream" if j == 1 else f"cdf-stream-{j}"


@functools.cache
def _world(preset: str) -> tuple[ScenarioConfig, Scene]:
    """A preset's scenario and its scene, loaded once per process."""
    config = load_preset(preset)
    return config, Scene.load(names=config.names)


def _seed_records(preset: str, seed: int, counts: tuple[str, ...], streams: int) -> list[dict[str, Any]]:
    """One seed of the closed loop: ``constant`` (labelled: the label and the reference of
    the time lost), ``cdf`` as shipped, on ``streams - 1`` other streams (``cdf-other-stream``,
    ``cdf-stream-2``, ...) and with each other count (``cdf-N``), the label copied onto each."""
    config, scene = _world(preset)
    reference = run_episode(config, seed, "constant", scene).to_dict()
    planners: list[tuple[str, Planner]] = [("cdf", CDFPlanner())]
    planners += [(_stream_name(j), _OtherStream(j)) for j in range(1, streams)]
    planners += [(f"cdf-{n}", CDFPlanner(candidate(n))) for n in counts if n != str(SHIPPED)]
    records = [reference]
    for name, planner in planners:
        record = run_episode(config, seed, planner, scene, label=False).to_dict()
        records.append({**record, "planner": name, "label": reference["label"]})
    return records


def closed(presets: Sequence[str], seeds: range, counts: tuple[str, ...], workers: int | None,
           streams: int = 2) -> tuple[list[str], dict[str, bool]]:
    """Part ``closed``: the paired comparisons per preset and count, and which counts lose nothing."""
    lines = ["## No loss, closed loop", "",
             f"`cdf` with each count against `cdf` with N = {SHIPPED} on seeds {seeds.start}-{seeds[-1]}, seed by "
             "seed (exact McNemar; the time lost at the fixed point against `constant`, the sign test). Loses "
             f"nothing: every p >= {NO_LOSS_P:g} on collisions, non-Cutoff interventions and non-Cutoff hard "
             f"brakes. The first row of each preset is the null: N = {SHIPPED} again, drawing from another "
             "stream, what a new stream alone changes.", ""]
    header = ["preset", "against N = " + str(SHIPPED), "collisions", "non-Cutoff interventions",
              "non-Cutoff hard brakes", "non-Cutoff time lost [s]", "loses nothing"]
    passes = {n: True for n in counts if n != str(SHIPPED)}
    rows = []
    jobs = [(preset, seed) for preset in presets for seed in seeds]
    with ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        chunk = max(1, len(jobs) // (8 * (workers or os.cpu_count() or 1)))
        done = list(pool.map(_seed_records, *zip(*jobs, strict=True), itertools.repeat(counts),
                             itertools.repeat(streams), chunksize=chunk))
    by_preset = {preset: [r for (p, _), rs in zip(jobs, done, strict=True) if p == preset for r in rs]
                 for preset in presets}
    # All presets together: each preset's seeds moved apart, so that a seed pairs within its preset.
    by_preset["all, pooled"] = [{**r, "seed": int(r["seed"]) + k * _POOL_STRIDE}
                                for k, preset in enumerate(presets) for r in by_preset[preset]]
    others = ["cdf-other-stream", *(f"cdf-{n}" for n in passes)]
    bar: dict[str, bool] = {}
    for preset, records in by_preset.items():
        for name in others:
            verdict = compare(records, "cdf", name)
            ok = all(c.p >= NO_LOSS_P for c in verdict.criteria[:3])
            if preset == "all, pooled":  # the declared bar: no more collisions, every pooled p >= 0.5
                collisions = verdict.criteria[0]
                bar[name] = ok and collisions.second <= collisions.first
            if name != "cdf-other-stream" and preset != "all, pooled":
                n = name.removeprefix("cdf-")
                passes[n] = passes[n] and ok
            cells = [f"{c.shown(c.first)} vs {c.shown(c.second)} (p {c.p:.2f})" for c in verdict.criteria]
            other = name == "cdf-other-stream"
            label = f"N = {SHIPPED}, another stream" if other else _shown(name.removeprefix("cdf-"))
            rows.append([preset, label, *cells, "yes" if ok else "**no**"])
    met = [_shown(name.removeprefix("cdf-")) for name, ok in bar.items() if ok and name != "cdf-other-stream"]
    lines += [*markdown_table(header, rows), "",
              "Counts that lose nothing on every preset: "
              + (", ".join(_shown(n) for n, ok in passes.items() if ok) or "none") + ". The declared bar for "
              "changing the default (pooled: no more collisions than the shipped count and every p >= "
              f"{NO_LOSS_P:g}) is met by: " + (", ".join(met) or "none") + (
                  " (the null meets it too)." if bar.get("cdf-other-stream") else
                  " (the null, the shipped count on another stream, does not meet it either)."), ""]
    if streams > 2:
        lines += _spread(by_preset, streams, list(passes))
    return lines, passes


def _count(records: list[dict[str, Any]], planner: str, rule: Any, quiet: bool) -> int:
    """How many of ``planner``'s records ``rule`` holds for (``quiet``: of those not labelled Cutoff)."""
    return sum(bool(rule(r)) for r in records if r.get("planner") == planner and not (quiet and is_imminent(r)))


def _spread(by_preset: dict[str, list[dict[str, Any]]], streams: int, counts: list[str]) -> list[str]:
    """The shipped filter's counts over its ``streams`` streams, least to most, and each
    candidate's, marked where it lies outside that range: what a new stream alone moves."""
    shipped = ["cdf", *(_stream_name(j) for j in range(1, streams))]
    rules = (("collisions", hit_obstacle, False), ("non-Cutoff interventions", intervened, True),
             ("non-Cutoff hard brakes", is_false_alarm, True))
    lines = [f"#### Spread over {streams} streams of N = {SHIPPED}", "",
             f"Each count of `cdf` with N = {SHIPPED} on its episode's planner stream and on {streams - 1} others, "
             "least to most, and each candidate's (**bold**: outside that range). A diagnostic beside the paired "
             "tests above, not the declared bar.", ""]
    header = ["preset", f"N = {SHIPPED}, {streams} streams", *(_shown(n) for n in counts)]
    rows = []
    for preset, records in by_preset.items():
        for what, rule, quiet in rules:
            ref = [_count(records, name, rule, quiet) for name in shipped]
            lo, hi = min(ref), max(ref)
            cells = [str(c) if lo <= c <= hi else f"**{c}**"
                     for c in (_count(records, f"cdf-{n}", rule, quiet) for n in counts)]
            rows.append([f"{preset}: {what}", f"{lo}-{hi}", *cells])
    return [*lines, *markdown_table(header, rows), ""]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="particle_count", description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", default="agreement,closed", help="agreement, closed or both (default both)")
    parser.add_argument("--counts", type=_counts, default=("250", "500", "1000", "adaptive:500-4000"),
                        help="candidates: N (a fixed count) or adaptive:MIN-MAX (KLD-sampling), comma-separated")
    parser.add_argument("--reference", type=_reference, default="10000",
                        help="the reference's fixed particle count (agreement; default 10000)")
    parser.add_argument("--seeds", type=_range, default=None,
                        help="seeds A-B (default 830000-830039 for agreement, 830000-830299 closed loop)")
    parser.add_argument("--presets", default=",".join(PRESETS), help="comma-separated presets")
    parser.add_argument("--workers", type=worker_count, default=None, help="worker processes (closed loop)")
    parser.add_argument("--streams", type=int, default=2,
                        help="streams of the shipped filter in the closed loop, 2 or more (default 2: its own and "
                             "the null's; more adds a table of their spread)")
    args = parser.parse_args(argv)
    parts = args.parts.split(",")
    if not parts or any(p not in ("agreement", "closed") for p in parts):
        parser.error(f"--parts must be agreement, closed or both, got {args.parts!r}")
    if args.streams < 2:
        parser.error(f"--streams must be 2 or more, got {args.streams}")
    presets = args.presets.split(",")
    try:
        for preset in presets:
            load_preset(preset)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
    lines = [f"# Particle counts (N shipped: {SHIPPED})", ""]
    if "agreement" in parts:
        lines += agreement(presets, args.seeds or range(830000, 830040), args.counts, args.reference)
    if "closed" in parts:
        lines += closed(presets, args.seeds or range(830000, 830300), args.counts, args.workers, args.streams)[0]
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
