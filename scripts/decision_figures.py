#!/usr/bin/env python3
"""One picture per layer of the layered rule (docs/DECISION.md): an episode in which the
layer acts, drawn over time from the true poses of its trace.

=============  ===========================================================================
picture        the episode
=============  ===========================================================================
anticipate     the first Cutoff seed of the default scenario that ``cdf`` avoids without a
               hard brake: the anticipation layer slowed the ego
emergency      the first Cutoff seed of the default scenario whose first hard brake the
               emergency layer called (its risk at or above ``RiskConfig.brake`` then)
follow         the first Cutoff seed of ``stress-merge-brakes`` (the merged car brakes at
               4 m/s^2 to a stop) on which the follow layer brakes for it (at least the
               comfortable brake, once that car brakes and a second after it merged)
=============  ===========================================================================

Seeds are searched from 0 (development seeds; a picture is an illustration, not a
result). Each picture has four panels against time [s]: both cars' speeds [m/s]; the
rule's command and the acceleration the ego got [m/s^2], with the comfortable and hard
braking levels; the time to collision [s] (gap / closing speed, while closing); the gap
to a car ahead in the ego's lane [m] beside its RSS distance. Shading marks the ticks the
rule slowed (anticipation or following, light) and braked hard (dark)::

    python scripts/decision_figures.py                 # docs/img/decision/{anticipate,emergency,follow}.png
    python scripts/decision_figures.py --out /tmp/fig

Needs matplotlib (the ``viz`` extra). Bad input is one line ``decision_figures: error: ...``
and exit status 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from cdf_mj.analysis.pages import ScriptParser
from cdf_mj.analysis.safety import SafetyParams, closing_speed
from cdf_mj.config import LayeredConfig, RiskConfig, ScenarioConfig
from cdf_mj.model.road import car_gap, in_lane_ahead
from cdf_mj.presets import load_preset
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

PROG = "decision_figures"
MAX_SEED = 200  # development seeds searched for each picture
#: [rad] The heading off the ego's way within which the layered rule's follow layer follows
#: a car ahead (its ``FOLLOW_WITHIN``; cdf_mj/model/road.py's table).
FOLLOW_WITHIN = math.pi / 2


def _anticipates(rec: EpisodeRecord) -> bool:
    return rec.label == "Cutoff" and rec.brake_time is None and not rec.collision \
        and rec.planner_info.get("anticipated", False)


def _emergency(rec: EpisodeRecord) -> bool:
    if rec.label != "Cutoff" or rec.brake_time is None or rec.collision:
        return False
    h = rec.planner_info["history"]
    k = h["t"].index(rec.brake_time)
    return h["risk"][k] >= RiskConfig().brake and (rec.entered_lane_time is None
                                                  or rec.brake_time < rec.entered_lane_time)


def _follows(rec: EpisodeRecord) -> bool:
    """A cut-off after which the merged car braked and the rule braked for it (at least the
    comfortable brake, a second or more after the car entered the lane)."""
    if rec.label != "Cutoff" or rec.collision or rec.entered_lane_time is None:
        return False
    since = (rec.world.get("after_merge") or {}).get("since")
    if since is None:
        return False
    h = rec.planner_info["history"]
    late = max(since, rec.entered_lane_time + 1.0)
    floor = -LayeredConfig().comfort_brake + 1e-9
    return any(t >= late and a <= floor for t, a in zip(h["t"], h["accel"], strict=True))


#: picture -> (title, scenario, test of an episode)
PICTURES: dict[str, tuple[str, ScenarioConfig, Callable[[EpisodeRecord], bool]]] = {
    "anticipate": ("Anticipation: the ego slows gently, no hard brake", ScenarioConfig(), _anticipates),
    "emergency": ("Emergency: the full brake before the car enters the lane", ScenarioConfig(), _emergency),
    "follow": ("Follow: the merged car brakes to a stop ahead (stress-merge-brakes)",
               load_preset("stress-merge-brakes"), _follows),
}


def find(config: ScenarioConfig, test: Callable[[EpisodeRecord], bool], scene: Scene) -> EpisodeRecord:
    """The first episode of ``cdf`` on seeds 0..MAX_SEED-1 that passes ``test`` (with its trace)."""
    for seed in range(MAX_SEED):
        rec = run_episode(config, seed, "cdf", scene, trace=True)
        if test(rec):
            return rec
    raise LookupError(f"no seed below {MAX_SEED} shows this layer")


def series(rec: EpisodeRecord, scene: Scene) -> dict[str, np.ndarray]:
    """Per tick: time, both speeds, command, applied acceleration, TTC, gap ahead and RSS distance."""
    layout = scene.layout()
    params = SafetyParams.of_cars(layout)
    poses = np.array(rec.trace["poses"])  # type: ignore[index]
    t = np.array(rec.trace["t"])  # type: ignore[index]
    ttc, gap_ahead, rss = (np.full(len(t), np.nan) for _ in range(3))
    for k, (ego, obs) in enumerate(poses):
        gap = car_gap(layout.ego, ego, layout.obstacle, obs)
        closing = closing_speed(layout, poses[k])
        if closing > 1e-6:
            ttc[k] = gap / closing
        if in_lane_ahead(layout, obs, layout.obstacle, ego, layout.ego, within=FOLLOW_WITHIN):  # as the follow layer
            gap_ahead[k] = gap
            rss[k] = params.rss_distance(ego[3], obs[3] * math.cos(obs[2] - ego[2]))
    h = rec.planner_info["history"]
    speed = poses[:, 0, 3]
    applied = np.r_[np.diff(speed) / np.diff(t), np.nan]
    return {"t": t, "ego_v": speed, "obs_v": poses[:, 1, 3], "command": np.array(h["accel"]),
            "applied": applied, "ttc": ttc, "gap": gap_ahead, "rss": rss}


def draw(name: str, title: str, rec: EpisodeRecord, scene: Scene, out: Path) -> Path:
    """Draw one picture into ``out/<name>.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = series(rec, scene)
    lay = LayeredConfig()
    fig, axes = plt.subplots(4, 1, figsize=(7.5, 8.0), sharex=True, constrained_layout=True)
    t = s["t"]
    slowing = (s["command"] < -0.05) & (s["command"] > -lay.hard_brake)
    hard = s["command"] <= -lay.hard_brake
    for ax in axes:
        for mask, alpha in ((slowing, 0.12), (hard, 0.3)):
            for k in np.flatnonzero(mask):
                ax.axvspan(t[k], t[k] + 0.1, color="tab:red", alpha=alpha, lw=0)
        if rec.entered_lane_time is not None:
            ax.axvline(rec.entered_lane_time, color="k", ls=":", lw=1)
    axes[0].plot(t, s["ego_v"], label="ego")
    axes[0].plot(t, s["obs_v"], label="other car")
    axes[0].set_ylabel("speed [m/s]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].step(t, s["command"], where="post", label="rule's command (capped to the car)")
    axes[1].plot(t, s["applied"], label="ego's acceleration", lw=1)
    for level, text in ((-lay.comfort_brake, "comfortable"), (-lay.hard_brake, "hard")):
        axes[1].axhline(level, color="gray", ls="--", lw=0.8)
        axes[1].text(t[-1], level, f" {text}", va="center", fontsize=7, color="gray")
    axes[1].set_ylabel("accel. [m/s²]")
    axes[1].legend(loc="lower right", fontsize=8)
    axes[2].plot(t, s["ttc"], color="tab:purple")
    axes[2].axhline(SafetyParams().ttc_critical, color="gray", ls="--", lw=0.8)
    axes[2].set_ylim(0, 10)
    axes[2].set_ylabel("TTC [s]")
    axes[3].plot(t, s["gap"], label="gap to the car ahead")
    axes[3].plot(t, s["rss"], label="RSS safe distance", ls="--")
    axes[3].set_ylabel("[m]")
    axes[3].set_xlabel("time [s]  (dotted: the other car enters the ego's lane; shading: slowing, braking hard)")
    axes[3].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{title}\nseed {rec.seed}, label {rec.label}", fontsize=10)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    p = ScriptParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="docs/img/decision", help="folder of the pictures (default docs/img/decision)")
    p.add_argument("--only", default=None, help=f"comma-separated pictures (default: {', '.join(PICTURES)})")
    args = p.parse_args(argv)
    names = [n.strip() for n in args.only.split(",") if n.strip()] if args.only else list(PICTURES)
    unknown = [n for n in names if n not in PICTURES]
    if unknown or not names:
        p.error(f"unknown picture(s) {', '.join(unknown) or '(none)'}: choose from {', '.join(PICTURES)}")
    scene = Scene.load()
    for name in names:
        title, config, test = PICTURES[name]
        try:
            rec = find(config, test, scene)
        except LookupError as exc:
            p.error(f"{name}: {exc}")
        print(f"{name}: seed {rec.seed} -> {draw(name, title, rec, scene, Path(args.out))}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
