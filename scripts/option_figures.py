#!/usr/bin/env python3
"""One picture per behaviour of the option rule, ``cdf-option`` (docs/DECISION.md): an
episode of the default scenario, drawn over time from its record.

=========  ================================================================================
picture    the episode (first development seed from 0 that shows it)
=========  ================================================================================
waits      a Yield episode in which the other car pulled out and stopped for the ego: the
           belief was unsure while the option was not yet at stake, so the ego held its
           speed (no intervention) and the belief resolved first
right      a Right episode: the same, for a car that turns away
slows      a Cutoff episode the option rule slowed for before any hard brake
brakes     a Cutoff episode whose first hard brake the emergency layer called (its risk at
           or above ``RiskConfig.brake`` then): the comfortable brake's option was gone
rss        a Cutoff episode whose first hard brake the emergency layer did not call: the RSS
           distance behind a car merging ahead did (the option rule's escalation before the
           car is in the lane, or the follow layer once it is)
=========  ================================================================================

Each picture has three panels against time [s]: the filter's P(left), P(seen) and P(cutoff)
with the option risk (P(a collision going on that ``option_time`` more would leave beyond
the comfortable brake, or short of the RSS distance behind a car merging ahead)) and the
rule's threshold; the planner's command beside the ego's own
controller's acceleration [m/s^2], with the ticks it intervened shaded; both cars' speeds
[m/s] beside the same seed's ``constant`` ego::

    python scripts/option_figures.py                   # docs/img/decision/option_*.png
    python scripts/option_figures.py --out /tmp/fig

Needs matplotlib (the ``viz`` extra). Bad input is one line ``option_figures: error: ...``
and exit status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cdf_mj.analysis.pages import ScriptParser
from cdf_mj.config import RiskConfig, ScenarioConfig
from cdf_mj.planners.cdf import OPTION_ANTICIPATION
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.scene import Scene

PROG = "option_figures"
MAX_SEED = 200  # development seeds searched for each picture
PLANNER = "cdf-option"


def _intervened(rec: EpisodeRecord) -> bool:
    return bool((rec.intervention or {}).get("ticks", 0))


def _unsure(rec: EpisodeRecord) -> bool:
    """The filter gave a cut-off a real chance at some tick (P(cutoff) >= 0.3)."""
    return max(rec.planner_info["history"]["p_cutoff"], default=0.0) >= 0.3


PICTURES: dict[str, tuple[str, Callable[[EpisodeRecord], bool]]] = {
    "waits": ("Yield: the belief resolves before the option is at stake, no intervention",
              lambda r: r.label == "Yield" and _unsure(r) and not _intervened(r)),
    "right": ("Right: a car turning away, no intervention",
              lambda r: r.label == "Right" and _unsure(r) and not _intervened(r)),
    "slows": ("Cutoff: the option rule slows, no hard brake",
              lambda r: r.label == "Cutoff" and _intervened(r) and r.brake_time is None and not r.collision),
    "brakes": ("Cutoff: the emergency layer brakes hard",
               lambda r: _first_brake_risk(r) is not None and _first_brake_risk(r) >= RiskConfig().brake),
    "rss": ("Cutoff: a car merging ahead, the full brake for the RSS distance",
            lambda r: _first_brake_risk(r) is not None and _first_brake_risk(r) < RiskConfig().brake),
}


def _first_brake_risk(rec: EpisodeRecord) -> float | None:
    """The emergency layer's risk on the tick of a Cutoff episode's first hard brake (None
    for another episode, or one without a hard brake or with a collision)."""
    if rec.label != "Cutoff" or rec.brake_time is None or rec.collision:
        return None
    hist = rec.planner_info["history"]
    k = int(np.argmin(np.abs(np.asarray(hist["t"]) - rec.brake_time)))
    return float(hist["risk"][k])


def _draw(path: Path, title: str, rec: EpisodeRecord, ref: EpisodeRecord, threshold: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hist, tr = rec.planner_info["history"], rec.trace or {}
    t = np.asarray(hist["t"])
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7.0), sharex=True, constrained_layout=True)
    ax = axes[0]
    for key, label, style in (("p_left", "P(left)", "-"), ("p_seen", "P(seen)", "--"),
                              ("p_cutoff", "P(cutoff)", ":"), ("anticipate", "option risk", "-")):
        ax.plot(t, hist[key], style, label=label, lw=2.0 if key == "anticipate" else 1.2)
    ax.axhline(threshold, color="0.4", lw=0.8, ls="-.", label=f"threshold {threshold:g}")
    ax.set_ylim(-0.02, 1.02)
    ax.set_ylabel("probability")
    ax.legend(loc="upper right", fontsize=8, ncols=3)
    ax.set_title(f"{title} (seed {rec.seed})", fontsize=10)
    ax = axes[1]
    tt = np.asarray(tr["t"])
    ax.plot(tt, tr["command"], color="k", lw=1.4, label="planner's command")
    ax.plot(tt, tr["own"], color="tab:blue", lw=1.2, label="own controller")
    on = np.asarray(tr["intervening"], dtype=bool)
    dt = float(tt[1] - tt[0]) if len(tt) > 1 else 0.1
    for k in np.flatnonzero(on):
        ax.axvspan(tt[k], tt[k] + dt, color="tab:orange", alpha=0.3, lw=0)
    ax.set_ylabel("acceleration [m/s²]")
    ax.legend(loc="lower right", fontsize=8, title="shaded: intervening", title_fontsize=8)
    ax = axes[2]
    speed = [p[0][3] for p in tr["poses"]]
    ax.plot(tt, speed, color="tab:blue", lw=1.4, label="ego")
    ref_tr = ref.trace or {}
    ax.plot(ref_tr["t"], [p[0][3] for p in ref_tr["poses"]], color="tab:blue", lw=1.0, ls="--",
            label="ego, `constant` on the same seed")
    ax.plot(tt, [p[1][3] for p in tr["poses"]], color="tab:red", lw=1.2, label="other car")
    ax.set_ylabel("speed [m/s]")
    ax.set_xlabel("time [s]")
    ax.legend(loc="lower left", fontsize=8)
    ax.set_xlim(0, min(float(tt[-1]) + dt, 6.0))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = ScriptParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/img/decision"), help="figure directory")
    args = parser.parse_args(argv)
    config = ScenarioConfig()
    scene = Scene.load(names=config.names)
    threshold = float(OPTION_ANTICIPATION["anticipate"])
    args.out.mkdir(parents=True, exist_ok=True)
    for name, (title, wanted) in PICTURES.items():
        for seed in range(MAX_SEED):
            rec = run_episode(config, seed, PLANNER, scene=scene, trace=True)
            if wanted(rec):
                ref = run_episode(config, seed, "constant", scene=scene, trace=True, label=False)
                path = args.out / f"option_{name}.png"
                _draw(path, title, rec, ref, threshold)
                print(f"{path}: seed {seed}")
                break
        else:
            print(f"{name}: no seed in 0-{MAX_SEED - 1} shows it (no picture)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
