"""Many episodes: run planners on the same seeds, persist every record, print the tables.

``run_experiment`` runs every planner on every seed (common random numbers: the obstacle
and the ego's start are the same for all planners), appends one JSON line per episode
and planner to ``DIR/episodes.jsonl`` as soon as it finishes (flushed), and writes the
settings to ``DIR/settings.json``. A directory holding results from other settings is
refused. ``experiment_tables`` turns records into the paper's two tables beside ours,
with 95 % Wilson intervals. ::

    records = run_experiment("results/run1", seeds=range(100), planners=("cdf", "reactive"))
    print(experiment_tables(records))
"""

from __future__ import annotations

import json
import os
import statistics
from pathlib import Path
from typing import Iterable, Iterator, Sequence

from tqdm import tqdm

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.episode import EpisodeRecord, Labels, run_episode
from cdf_mj.metrics import Rate
from cdf_mj.planners import CDFPlanner, Planner, make_planner
from cdf_mj.scene import DEFAULT_SCENE, Scene

__all__ = ["run_many", "iter_episodes", "run_experiment", "experiment_tables", "load_records",
           "PAPER_CONFUSION", "PAPER_PLANNERS"]

LABELS = (Labels.CUTOFF, Labels.YIELD, Labels.RIGHT)
#: The paper's Figure "Simulation results using the CDF": rows scenario, columns prediction.
PAPER_CONFUSION = {Labels.CUTOFF: (417, 0, 0), Labels.YIELD: (13, 334, 0), Labels.RIGHT: (0, 0, 236)}
#: The paper's planner comparison: (collisions imminent, collisions occurred).
PAPER_PLANNERS = {"cdf": (417, 9), "reactive": (404, 213)}


def _planner(name: str, cdf: CDFConfig | None) -> Planner:
    return CDFPlanner(cdf) if name == "cdf" else make_planner(name)


def iter_episodes(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
                  scene: str | Path = DEFAULT_SCENE, progress: bool = True,
                  cdf: CDFConfig | None = None) -> Iterator[EpisodeRecord]:
    """Yield one labelled record per seed, in order, with a progress bar on stderr."""
    config = config or ScenarioConfig()
    sc = Scene.load(scene, names=config.names)
    for seed in tqdm(list(seeds), desc=f"{planner} episodes", unit="ep", disable=not progress, leave=False):
        yield run_episode(config, seed, _planner(planner, cdf), sc)


def run_many(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
             scene: str | Path = DEFAULT_SCENE, progress: bool = True,
             cdf: CDFConfig | None = None) -> list[EpisodeRecord]:
    """Records of all ``seeds`` for one planner (see :func:`iter_episodes`)."""
    return list(iter_episodes(seeds, planner, config, scene, progress, cdf))


def _settings(seeds: Sequence[int], planners: Sequence[str], config: ScenarioConfig,
              cdf: CDFConfig, scene: str | Path) -> dict:
    return {"seeds": [int(seeds[0]), int(seeds[-1]) + 1] if seeds else [0, 0],
            "planners": list(planners), "scenario": config.to_dict(), "cdf": cdf.to_dict(),
            "scene": str(Path(scene).resolve())}


def run_experiment(out_dir: str | Path, seeds: Sequence[int], planners: Sequence[str] = ("cdf", "reactive"),
                   config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                   scene: str | Path = DEFAULT_SCENE, progress: bool = True) -> list[dict]:
    """Run every planner on every seed; persist and return the records (as dicts).

    ``seeds`` must be a contiguous range. Refuses a directory whose ``settings.json``
    differs from these settings, and a non-empty ``episodes.jsonl`` (resuming is not
    supported yet: choose a new directory).
    """
    config, cdf = config or ScenarioConfig(), cdf or CDFConfig()
    seeds = list(seeds)
    if not seeds or seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise ValueError("seeds must be a non-empty contiguous range")
    for name in planners:
        make_planner(name)  # unknown planner: refused before any work
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    settings = _settings(seeds, planners, config, cdf, scene)
    settings_path, records_path = out / "settings.json", out / "episodes.jsonl"
    if settings_path.exists():
        old = json.loads(settings_path.read_text())
        if old != json.loads(json.dumps(settings)):
            raise ValueError(f"{out} holds results from other settings; choose another directory")
    if records_path.exists() and records_path.stat().st_size > 0:
        raise ValueError(f"{records_path} already holds results; choose another directory")
    settings_path.write_text(json.dumps(settings, indent=2) + "\n")

    sc = Scene.load(scene, names=config.names)
    records: list[dict] = []
    with open(records_path, "a", encoding="utf-8") as fh, \
            tqdm(total=len(seeds) * len(planners), unit="ep", disable=not progress,
                 desc="episodes") as bar:
        for seed in seeds:
            labelled = None  # the label depends on the seed only: one counterfactual per seed
            for name in planners:
                rec = run_episode(config, seed, _planner(name, cdf), sc, label=labelled is None).to_dict()
                if labelled is None:
                    labelled = rec
                else:
                    rec["label"] = labelled["label"]
                    rec["counterfactual_collision"] = labelled["counterfactual_collision"]
                fh.write(json.dumps(rec, allow_nan=False) + "\n")
                fh.flush()
                records.append(rec)
                bar.update()
        os.fsync(fh.fileno())
    return records


def load_records(out_dir: str | Path) -> list[dict]:
    """The records of an experiment directory."""
    path = Path(out_dir) / "episodes.jsonl"
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]


def _prediction(rec: dict) -> str:
    return rec.get("planner_info", {}).get("prediction") or (Labels.CUTOFF if rec["brake_time"] is not None else "-")


def experiment_tables(records: Iterable[dict]) -> str:
    """Markdown: the CDF confusion matrix beside the paper's, and the planner comparison
    (imminent collisions, collisions, avoided, false alarms, lead time, gap, time lost)."""
    by_planner: dict[str, list[dict]] = {}
    for rec in records:
        by_planner.setdefault(rec["planner"], []).append(rec)
    lines: list[str] = []
    if "cdf" in by_planner:
        recs = by_planner["cdf"]
        lines += [f"CDF predictions ({len(recs)} episodes): ours | paper", "",
                  "| scenario \\ prediction | Cutoff | Yield | Right | total |", "|---|---|---|---|---|"]
        for lab in LABELS:
            row = [sum(1 for r in recs if r["label"] == lab and _prediction(r) == p) for p in LABELS]
            paper = PAPER_CONFUSION[lab]
            cells = " | ".join(f"{o} \\| {p}" for o, p in zip(row, paper))
            lines.append(f"| {lab} | {cells} | {sum(row)} \\| {sum(paper)} |")
        recall = Rate(sum(1 for r in recs if r["label"] == Labels.CUTOFF and _prediction(r) == Labels.CUTOFF),
                      sum(1 for r in recs if r["label"] == Labels.CUTOFF))
        lines += ["", f"Cutoff recall: {recall} (paper 100 %)", ""]
    lines += ["| planner | collisions imminent | collisions occurred | avoided (95 % CI) | (imminent - occurred) / imminent "
              "| paper: imminent / occurred / avoided | false alarms (95 % CI) | median lead time [s] "
              "| median min gap [m] | mean time lost, no collision [s] |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for name, recs in by_planner.items():
        cut = [r for r in recs if r["label"] == Labels.CUTOFF]
        occurred = sum(1 for r in recs if r["collision_with"] == "obstacle")
        avoided = Rate(sum(1 for r in cut if r["collision_with"] != "obstacle"), len(cut))
        false_alarm = Rate(sum(1 for r in recs if r["label"] != Labels.CUTOFF and r["brake_time"] is not None),
                           len(recs))
        leads = [r["entered_lane_time"] - r["brake_time"] for r in cut
                 if r["brake_time"] is not None and r["entered_lane_time"] is not None]
        lead = f"{statistics.median(leads):.2f}" if leads else "-"
        gap = statistics.median(r["min_gap"] for r in recs) if recs else float("nan")
        # Over episodes without a collision: a collision ends an episode early and would
        # make a planner that crashes look fast. Braking is latched, so this is large.
        intact = [r["time_lost"] for r in recs if not r["collision"]]
        lost = statistics.fmean(intact) if intact else float("nan")
        paper_style = (len(cut) - occurred) / len(cut) if cut else float("nan")
        if name in PAPER_PLANNERS:
            pi, po = PAPER_PLANNERS[name]
            paper = f"{pi} / {po} / {100 * (pi - po) / pi:.0f} %"
        else:
            paper = "-"
        lines.append(f"| {name} | {len(cut)} | {occurred} | {avoided} | {100 * paper_style:.1f} % | {paper} "
                     f"| {false_alarm} | {lead} "
                     f"| {gap:.2f} | {lost:.2f} |")
    return "\n".join(lines)
