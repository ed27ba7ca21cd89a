"""The figures of an experiment report (:data:`FIGURES`), each drawn from an
:class:`~cdf_mj.viz.report_data.Experiment` onto matplotlib's Agg canvas and written as a
PNG, or left out with a string saying why; and :func:`scene_extent`, the part of a junction
an episode uses. :func:`cdf_mj.viz.report.write_report` puts them on the page. ::

    from cdf_mj.viz.report_figures import scene_extent, trajectories_figure
    fig = trajectories_figure(exp, "cdf", [1, 2])
"""

from __future__ import annotations

import io
import math
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from cdf_mj.analysis.metrics import Rate, confusion_matrix, planner_metrics
from cdf_mj.analysis.tables import PAPER_CONFUSION, PAPER_PLANNERS
from cdf_mj.extras import require
from cdf_mj.model.geometry import box_corners
from cdf_mj.model.layout import Layout
from cdf_mj.records import LABELS, Label, lead_time, paper_avoided, prediction, write_atomic
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene
from cdf_mj.viz.report_data import Experiment, ReportError, _planner_factory, _scenario

__all__ = ["FIGURES", "scene_extent", "trajectories_figure"]

#: Figure file names and what each shows.
FIGURES = {
    "confusion": "the CDF's predictions against the scenario labels, beside the paper's",
    "avoidance": "imminent collisions avoided and false alarms per planner, 95 % Wilson intervals",
    "trajectories": "top-down paths of the ego and the obstacle for a few seeds",
    "posterior": "P(left), P(seen) and P(cutoff) of the CDF over time for the same seeds",
    "lead_times": "braking lead time (obstacle enters the ego lane minus brake decision) on Cutoff episodes",
}
_PLANNER_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f")
_CURVES = (("p_left", "P(left)", "#c020c0"), ("p_seen", "P(seen)", "#d4a000"),
           ("p_cutoff", "P(cutoff)", "#e04010"))


def _figure(width: float, height: float) -> Any:
    try:
        canvas = require("matplotlib.backends.backend_agg", "viz", "cdf-mj report").FigureCanvasAgg
        figure = require("matplotlib.figure", "viz", "cdf-mj report").Figure
    except ImportError as exc:
        raise ReportError(str(exc)) from None
    fig = figure(figsize=(width, height), dpi=100, layout="constrained")
    canvas(fig)
    return fig


def _save(fig: Any, path: Path) -> Path:
    """Write ``fig`` as PNG whole or not at all, never through a symlink (:func:`write_atomic`)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return write_atomic(path, buf.getvalue())


def _confusion(exp: Experiment, path: Path) -> Path | str:
    matrix = confusion_matrix(exp.by_planner("cdf"))
    ours = np.array([matrix[a] for a in LABELS])
    if not ours.sum():
        return "no CDF records with a prediction"
    paper = np.array([PAPER_CONFUSION[a] for a in LABELS])
    fig = _figure(8.0, 3.4)
    axes = fig.subplots(1, 2)
    for ax, mat, title in ((axes[0], ours, f"ours ({int(ours.sum())} episodes)"),
                           (axes[1], paper, f"paper ({int(paper.sum())} episodes)")):
        share = mat / np.maximum(mat.sum(axis=1, keepdims=True), 1)
        ax.imshow(share, cmap="Blues", vmin=0.0, vmax=1.0)
        for i in range(3):
            for j in range(3):
                ax.text(j, i, str(mat[i, j]), ha="center", va="center",
                        color="white" if share[i, j] > 0.6 else "black", fontsize=11)
        ax.set_xticks(range(3), LABELS)
        ax.set_yticks(range(3), LABELS)
        ax.set_xlabel("prediction")
        ax.set_ylabel("scenario")
        ax.set_title(title, fontsize=10)
    fig.suptitle("CDF predictions (colour: share of the row)", fontsize=11)
    return _save(fig, path)


def _avoidance(exp: Experiment, path: Path) -> Path | str:
    metrics = planner_metrics(exp.records)
    none = (Rate(0, 0), Rate(0, 0))  # a planner without labelled episodes
    rates = {p: (metrics[p].avoided, metrics[p].false_alarms) if p in metrics else none for p in exp.planners}
    fig = _figure(8.0, 3.8)
    axes = fig.subplots(1, 2)
    x = np.arange(len(exp.planners))
    colors = [_PLANNER_COLORS[i % len(_PLANNER_COLORS)] for i in range(len(exp.planners))]
    titles = ("imminent collisions avoided\n(of the Cutoff episodes)",
              "false alarms\n(braked in an episode not Cutoff; of all episodes)")
    for k, ax in enumerate(axes):
        vals = [rates[p][k] for p in exp.planners]
        v = np.array([100 * r.value if r.n else np.nan for r in vals])
        lo = np.array([100 * r.interval[0] if r.n else np.nan for r in vals])
        hi = np.array([100 * r.interval[1] if r.n else np.nan for r in vals])
        ax.bar(x, np.nan_to_num(v), color=colors, alpha=0.8)
        ax.errorbar(x, v, yerr=[np.nan_to_num(v - lo), np.nan_to_num(hi - v)], fmt="none", ecolor="black",
                    capsize=5, label="95 % Wilson interval")
        for xi, r, top in zip(x, vals, hi, strict=True):
            y = min(top, 92) + 1.5 if r.n else 1.5  # inside the axes, above the interval
            ax.text(xi + 0.08, y, f"{r.k}/{r.n}", ha="left", va="bottom", fontsize=8)
        if k == 0:
            if not any(r.n for r in vals):
                ax.text(0.5, 0.5, "no Cutoff episodes", transform=ax.transAxes, ha="center", va="center")
            paper = [(i, 100 * paper_avoided(*PAPER_PLANNERS[p])) for i, p in enumerate(exp.planners)
                     if p in PAPER_PLANNERS]
            if paper:
                ax.scatter([i for i, _ in paper], [v for _, v in paper], marker="D", color="black",
                           zorder=3, label="paper (its formula)")
        ax.set_xticks(x, exp.planners)
        ax.set_ylim(0, 105)
        ax.set_ylabel("%")
        ax.set_title(titles[k], fontsize=10)
        # Below the axes: over the bars it would hide their k/n labels.
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, frameon=False)
    return _save(fig, path)


def _draw_layout(ax: Any, scene: Scene) -> None:
    """The world-body boxes of the MJCF (roads, markings, buildings) as rectangles."""
    from matplotlib.patches import Polygon as MplPolygon

    m, d = scene.model, scene.data
    boxes = []
    for i in range(m.ngeom):
        if m.geom_bodyid[i] != 0 or m.geom_type[i] != mujoco.mjtGeom.mjGEOM_BOX:
            continue
        rgba = m.mat_rgba[m.geom_matid[i]] if m.geom_matid[i] >= 0 else m.geom_rgba[i]
        boxes.append((float(d.geom_xpos[i][2] + m.geom_size[i][2]), i, rgba))
    for _, i, rgba in sorted(boxes):
        hx, hy = m.geom_size[i][:2]
        rot = d.geom_xmat[i].reshape(3, 3)[:2, :2]
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) @ rot.T + d.geom_xpos[i][:2]
        ax.add_patch(MplPolygon(corners, closed=True, facecolor=tuple(rgba[:3]), edgecolor="none",
                                zorder=1))
    ax.set_facecolor((0.33, 0.42, 0.30))


def _pick_seeds(exp: Experiment, planner: str, count: int = 3) -> list[int]:
    """One seed per label (Cutoff, Yield, Right) for ``planner``, first in seed order;
    Cutoff seeds where the planner braked first."""
    recs = sorted(exp.by_planner(planner), key=lambda r: r["seed"])
    seeds: list[int] = []
    for lab in LABELS:
        cand = [r for r in recs if r.get("label") == lab]
        # A Cutoff the planner braked for; a Yield or Right it did not brake for.
        cand.sort(key=lambda r: (r.get("brake_time") is None) == (lab == Label.CUTOFF))
        if cand:
            seeds.append(int(cand[0]["seed"]))
    for r in recs:  # unlabelled runs, or fewer labels than wanted
        if len(seeds) >= count:
            break
        if int(r["seed"]) not in seeds:
            seeds.append(int(r["seed"]))
    return seeds[:count]


def _outline(box_center: np.ndarray, heading: float, half: np.ndarray, step: float) -> np.ndarray:
    """Points ``(P, 2)`` every ``step`` metres or closer along a rectangle's edges [m]."""
    corners = box_corners(np.asarray(box_center, dtype=float), heading, np.asarray(half, dtype=float))
    edges = []
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        edges.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.concatenate(edges)


def scene_extent(layout: Layout, points: np.ndarray | None = None, margin: float = 4.0,
                 step: float = 0.5) -> tuple[float, float, float, float]:
    """The part of a junction an episode uses, as axis limits ``(xmin, xmax, ymin, ymax)`` [m],
    world frame (x east, y north), for any scene: rotated, mirrored, of any size.

    The episode's area is the disc about the layout's conflict point that holds both start
    poses, the commit point, the stop line and every one of ``points`` (the cars' paths,
    ``(..., 2)`` [m]); the extent is the bounding box of those and of every part of the
    routes, the ego's lane and the buildings that lies in that disc (sampled every ``step``
    metres), widened by ``margin`` [m] on each side. Routes and lanes that run on for 150 m
    are thus cut where the episode ends, and the corners of the buildings that hide the
    cars from each other are kept. ValueError if ``points`` are not finite.
    """
    key = [layout.ego_start[None, :2], layout.obstacle_start[None, :2], layout.conflict[None],
           layout.commit[None], layout.stop_line.corners()]
    if points is not None:
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(pts)):
            raise ValueError("scene_extent: points must be finite [m]; a path holds NaN or inf")
        key.append(pts)
    must = np.concatenate(key)
    radius = float(np.max(np.linalg.norm(must - layout.conflict, axis=1)))
    occ = layout.occluders
    parts = [r.point_at(np.append(np.arange(0.0, r.length, step), r.length))
             for r in (layout.route_ego, layout.route_left, layout.route_right)]
    parts += [_outline(b.center, b.heading, b.half, step) for b in (layout.ego_lane, layout.stop_line)]
    parts += [_outline(occ.center[i], float(occ.heading[i]), occ.half[i], step) for i in range(len(occ.names))]
    near = np.concatenate(parts)
    near = near[np.linalg.norm(near - layout.conflict, axis=1) <= radius]
    every = np.concatenate([must, near])
    lo, hi = every.min(axis=0) - margin, every.max(axis=0) + margin
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _trajectories(exp: Experiment, planner: str, seeds: Sequence[int], path: Path,
                  notes: list[str]) -> Path | str:
    made = trajectories_figure(exp, planner, seeds, notes)
    return made if isinstance(made, str) else _save(made, path)


def trajectories_figure(exp: Experiment, planner: str, seeds: Sequence[int],
                        notes: list[str] | None = None) -> Any:
    """The top-down paths of both cars for ``seeds`` of ``planner``, re-simulated from the
    experiment's settings over the road layout of its scene: a matplotlib ``Figure`` (one
    axes, world frame x east / y north [m], equal aspect), or a string saying why none can
    be drawn. The axes span :func:`scene_extent` of the scene's layout and the paths; the
    legend lies below the axes, outside the data. Notes (a scene not found, a re-run that
    differs from the record) are appended to ``notes``."""
    notes = [] if notes is None else notes
    if not seeds:
        return f"no records of planner {planner}"
    config = _scenario(exp.settings)
    try:
        factory = _planner_factory(exp.settings, planner)
    except ReportError:
        raise
    except ValueError:
        return f"planner {planner!r} is not registered in this process, so it cannot be re-run"
    scene_path = Path(exp.settings.get("scene") or DEFAULT_SCENE)
    if not scene_path.is_file():
        notes.append(f"The scene {scene_path} of the settings was not found; the default scene was used.")
        scene_path = DEFAULT_SCENE
    scene = Scene.load(scene_path, names=config.names)
    layout = scene.layout()
    stored = {int(r["seed"]): r for r in exp.by_planner(planner)}
    runs = []
    for seed in seeds:
        rec = run_episode(config, seed, factory(), scene, label=False, trace=True)
        old = stored.get(seed)
        if old is not None and old.get("brake_time") != rec.brake_time:
            notes.append(f"Seed {seed} re-simulated with brake time {rec.brake_time} against "
                         f"{old.get('brake_time')} stored: the code changed since the experiment.")
        assert rec.trace is not None, "run_episode(trace=True) records a trace"
        poses = np.asarray(rec.trace["poses"], dtype=np.float64)  # (K, 2, 4)
        runs.append((seed, rec, poses, np.asarray(rec.trace["t"], dtype=np.float64), old))
    x0, x1, y0, y1 = scene_extent(layout, np.concatenate([p[:, :, :2] for _, _, p, _, _ in runs]))
    width = 8.0
    axes_h = min(max((width - 1.0) * (y1 - y0) / (x1 - x0), 2.4), 7.0)
    fig = _figure(width, axes_h + 1.2 + 0.18 * len(seeds))
    ax = fig.subplots()
    _draw_layout(ax, scene)
    for route, name in ((layout.route_left, "obstacle routes (left, right)"), (layout.route_right, "_")):
        ax.plot(route.points[:, 0], route.points[:, 1], color="#bbbbbb", lw=1.0, ls=":", zorder=2, label=name)
    for i, (seed, rec, poses, times, old) in enumerate(runs):
        color = _PLANNER_COLORS[i % len(_PLANNER_COLORS)]
        lab = old.get("label") if old else None
        name = f"seed {seed}" + (f" ({lab})" if lab else "")
        lw = max(3.2 - 0.8 * i, 1.0)  # later paths thinner, so that shared stretches stay visible
        ax.plot(poses[:, 0, 0], poses[:, 0, 1], color=color, lw=lw, zorder=3, label=f"{name}: ego")
        ax.plot(poses[:, 1, 0], poses[:, 1, 1], color=color, lw=lw, ls="--", zorder=3,
                label=f"{name}: obstacle")
        if rec.brake_time is not None:
            k = int(np.argmin(np.abs(times - rec.brake_time)))
            ax.scatter(poses[k, 0, 0], poses[k, 0, 1], marker="X", s=90, color=color, edgecolor="black",
                       zorder=4)
        if rec.collision:
            ax.scatter(poses[-1, 0, 0], poses[-1, 0, 1], marker="*", s=160, color="yellow",
                       edgecolor="black", zorder=4)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")  # the limits stay; the axes box takes their shape
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_title(f"{planner}: paths (ego solid, obstacle dashed; X brake decision, * collision)",
                 fontsize=10)
    fig.legend(loc="outside lower center", ncol=3, fontsize=7, frameon=False)
    return fig


def _posterior(exp: Experiment, seeds: Sequence[int], path: Path) -> Path | str:
    recs = {int(r["seed"]): r for r in exp.by_planner("cdf") if _history(r) is not None}
    chosen = [s for s in seeds if s in recs] or sorted(recs)[:3]
    if not chosen:
        return "no CDF records with a posterior history"
    tau = exp.settings["cdf"].get("tau")
    if not (isinstance(tau, (int, float)) and not isinstance(tau, bool) and math.isfinite(tau)):
        tau = None
    fig = _figure(8.0, 1.0 + 1.9 * len(chosen))
    axes = np.atleast_1d(fig.subplots(len(chosen), 1, sharex=True))
    for ax, seed in zip(axes, chosen, strict=True):
        rec = recs[seed]
        h = _history(rec)
        assert h is not None, "chosen from the records with a history"
        for key, name, color in _CURVES:
            ax.plot(h["t"], h[key], color=color, lw=1.8, label=name)
        if tau is not None:
            ax.axhline(tau, color="#e04010", ls=":", lw=1, label=f"tau = {tau}")
        if rec.get("brake_time") is not None:
            ax.axvline(rec["brake_time"], color="black", lw=1.4, label="brake decision")
        if rec.get("entered_lane_time") is not None:
            ax.axvline(rec["entered_lane_time"], color="grey", ls="--", lw=1.2, label="obstacle enters ego lane")
        ax.set_ylim(-0.03, 1.03)
        ax.set_ylabel("probability")
        ax.set_title(f"seed {seed}: label {rec.get('label')}, prediction {prediction(rec)}", fontsize=9)
    axes[-1].set_xlabel("time [s]")
    legend: dict[str, Any] = {}  # every curve and marker of any panel, once, above the panels
    for ax in axes:
        for handle, name in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(name, handle)
    fig.legend(list(legend.values()), list(legend), loc="outside upper center", ncol=3, fontsize=7,
               frameon=False)
    return _save(fig, path)


def _history(rec: dict[str, Any]) -> dict[str, list[float]] | None:
    """The CDF's posterior history of a record, ``t`` and the curves of :data:`_CURVES` as
    lists of finite numbers of one length; None if the record holds no such history."""
    h = rec["planner_info"].get("history")
    if not isinstance(h, dict):
        return None
    out = {}
    for key in ("t", *(c[0] for c in _CURVES)):
        v = h.get(key)
        if not (isinstance(v, list) and v and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
            return None
        out[key] = v
    return out if len({len(v) for v in out.values()}) == 1 else None


def _lead_times(exp: Experiment, path: Path) -> Path | str:
    leads = {p: [t for t in map(lead_time, exp.by_planner(p)) if t is not None] for p in exp.planners}
    if not any(leads.values()):
        return "no Cutoff episode with both a brake decision and a lane entry"
    every = np.concatenate([np.asarray(v, dtype=float) for v in leads.values() if v])
    lo, hi = math.floor(every.min() * 10) / 10, math.ceil(every.max() * 10) / 10
    bins = np.arange(lo - 0.05, hi + 0.1, 0.1)
    fig = _figure(8.0, 3.4)
    ax = fig.subplots()
    for i, (p, v) in enumerate(leads.items()):
        if not v:
            continue
        color = _PLANNER_COLORS[i % len(_PLANNER_COLORS)]
        med = statistics.median(v)
        ax.hist(v, bins=bins, histtype="stepfilled", alpha=0.35, color=color,
                label=f"{p}: median {med:.2f} s ({len(v)} episodes)")
        ax.hist(v, bins=bins, histtype="step", color=color, lw=1.5)
        ax.axvline(med, color=color, ls="--", lw=1.2)
    ax.axvline(0.0, color="black", lw=0.8)
    ax.set_xlabel("lead time = obstacle enters the ego lane - brake decision [s]")
    ax.set_ylabel("Cutoff episodes")
    fig.legend(loc="outside right upper", fontsize=8, frameon=False)
    return _save(fig, path)
