"""Sweeps: how the planners' outcomes depend on one setting, through the experiment runner.

==========  ====================================================  =========================
sweep       what changes                                          default values
==========  ====================================================  =========================
beta        ``ScenarioConfig.beta``, P(observe a visible ego)     0.01 0.02 0.05 0.1 0.2
            per tick (the CDF is told the true beta)
particles   ``CDFConfig.n_particles`` N                           100 250 500 1000 2000 4000
tau         ``CDFConfig.tau``, the CDF's braking threshold        0.5 0.6 0.7 0.8 0.85 0.9
                                                                  0.95 0.99
noise       process noise: ``noise_accel`` and ``noise_steer``    0.5 1 2 4
            times the factor (both cars; the CDF's filter noise
            follows, as ``process_noise_scale`` x the scenario's)
obs-noise   observation noise: ``obs_noise_pos``, ``_heading``,   0.5 1 2 4
            ``_speed`` times the factor
==========  ====================================================  =========================

Every point is one :func:`cdf_mj.experiment.run_experiment` call in its own directory
``OUT/<sweep>/<value>/`` (so a point that finished is reused by a later call with the same
settings, and an interrupted one resumes), on the same seeds for every point (common
random numbers). Settings that only the CDF reads (``particles``, ``tau``) run the other
planners once, as references, in ``OUT/<sweep>/reference/`` (reported at the first point),
so that a point's directory holds the same settings whatever the other values are. Each
sweep writes ``OUT/<sweep>.csv``, ``OUT/<sweep>.md`` (the metrics of
:func:`cdf_mj.metrics.planner_metrics` per point and planner) and ``OUT/<sweep>.png``
(matplotlib, the optional extra ``viz``).

The ``tau`` sweep also writes ``OUT/tau_curve.csv``, the false alarms and detections for
a fine grid of thresholds, read from the filter's P(cutoff) history of the run at the
largest tau: before it brakes, the filter's history is the same whatever the threshold
(same seed, same random streams, the ego not yet braking), so the first tick at which
P(cutoff) >= tau is exactly where a run at that tau would brake, for every tau up to the
largest. Collisions are not read this way: avoidance comes from the braking runs only,
and the sweep reports how many derived brake times agree with those runs. ::

    from cdf_mj.experiments.sweep import run_sweep
    result = run_sweep("beta", "results/sweeps", seeds=range(200), planners=("cdf", "reactive"))
    print(result.markdown)
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.records import Labels
from cdf_mj.analysis.metrics import Rate, planner_metrics
from cdf_mj.sim.scene import DEFAULT_SCENE

__all__ = ["SWEEPS", "SweepResult", "SweepSpec", "VizUnavailableError", "run_sweep", "tau_curve"]

_VIZ_HINT = "pip install 'cdf-mj[viz]'"


class VizUnavailableError(ImportError):
    """matplotlib is missing: the figures need the optional extra ``viz``."""


def _scale_process(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    return config.replace(noise_accel=config.noise_accel * k, noise_steer=config.noise_steer * k), cdf


def _scale_obs(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    return config.replace(obs_noise_pos=config.obs_noise_pos * k,
                          obs_noise_heading=config.obs_noise_heading * k,
                          obs_noise_speed=config.obs_noise_speed * k), cdf


@dataclass(frozen=True)
class SweepSpec:
    """One sweep: the setting it changes, its default values and how a value is applied."""

    name: str
    label: str  # axis label, with unit
    values: tuple[float, ...]
    apply: Callable[[ScenarioConfig, CDFConfig, float], tuple[ScenarioConfig, CDFConfig]]
    cdf_only: bool  # only the CDF reads it: other planners run once, at the first point
    integer: bool = False
    log_x: bool = False

    def settings(self, value: float, config: ScenarioConfig, cdf: CDFConfig) -> tuple[ScenarioConfig, CDFConfig]:
        """The scenario and CDF settings of one point (ValueError out of range)."""
        if self.integer:
            if float(value) != int(value):
                raise ValueError(f"{self.name} values must be whole numbers, got {value!r}")
            value = int(value)
        return self.apply(config, cdf, value)


SWEEPS: dict[str, SweepSpec] = {s.name: s for s in (
    SweepSpec("beta", "beta, P(observe a visible ego) per 0.1 s tick", (0.01, 0.02, 0.05, 0.1, 0.2),
              lambda c, d, v: (c.replace(beta=float(v)), d), cdf_only=False, log_x=True),
    SweepSpec("particles", "particle count N", (100, 250, 500, 1000, 2000, 4000),
              lambda c, d, v: (c, d.replace(n_particles=int(v))), cdf_only=True, integer=True, log_x=True),
    SweepSpec("tau", "braking threshold tau on P(cutoff)", (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99),
              lambda c, d, v: (c, d.replace(tau=float(v))), cdf_only=True),
    SweepSpec("noise", "process noise, factor on noise_accel and noise_steer", (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_process(c, d, float(v)), cdf_only=False, log_x=True),
    SweepSpec("obs-noise", "observation noise, factor on obs_noise_*", (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_obs(c, d, float(v)), cdf_only=False, log_x=True),
)}


@dataclass
class SweepResult:
    """What :func:`run_sweep` wrote: one row per point and planner, and the file paths."""

    name: str
    rows: list[dict]
    csv_path: Path
    markdown_path: Path
    figure_path: Path | None
    markdown: str
    extra: dict = field(default_factory=dict)  # tau: the fine curve and the agreement check


def _value_text(value: float) -> str:
    return f"{value:g}"


def _planners_in(point: Path) -> list[str] | None:
    """The planners of the results already in a point's directory (None if there are none)."""
    try:
        planners = json.loads((point / "settings.json").read_text(encoding="utf-8")).get("planners")
    except (OSError, ValueError, AttributeError):
        return None
    return list(planners) if isinstance(planners, list) else None


def _run_point(out: Path, seeds: Sequence[int], planners: Sequence[str], config: ScenarioConfig,
               cdf: CDFConfig, scene: str | Path, progress: bool, workers: int | None) -> tuple[list[dict], float]:
    """One :func:`run_experiment` call, resumed where ``out`` holds the same settings (a
    finished point is reused, an interrupted one continues); returns its completed records
    and its wall time [s]."""
    from cdf_mj.experiments.experiment import completed, run_experiment

    result = run_experiment(out, seeds, list(planners), config, cdf, scene, progress,
                            workers=workers, resume=True)
    return completed(result), result.wall_time


def run_sweep(name: str, out_dir: str | Path, seeds: Iterable[int], planners: Sequence[str] = ("cdf", "reactive"),
              values: Sequence[float] | None = None, config: ScenarioConfig | None = None,
              cdf: CDFConfig | None = None, scene: str | Path = DEFAULT_SCENE, workers: int | None = None,
              progress: bool = False, figure: bool = True) -> SweepResult:
    """Run one sweep (see the module docstring) and write its table and figure.

    Args:
        name: a key of :data:`SWEEPS`.
        out_dir: result directory; points go to ``out_dir/<name>/<value>/``.
        seeds: a contiguous range of seeds, the same for every point.
        planners: registered planner names (``cdf`` must be among them for ``particles``
            and ``tau``).
        values: the values to sweep (default: the spec's).
        config, cdf: the settings every point starts from.
        scene: MJCF scene file.
        workers: worker processes per point (default: the runner's, the CPU count).
        progress: progress bars on stderr.
        figure: also draw ``out_dir/<name>.png`` (needs matplotlib: :class:`VizUnavailableError`).
    """
    if name not in SWEEPS:
        raise ValueError(f"unknown sweep {name!r}: choose one of {', '.join(SWEEPS)}")
    spec = SWEEPS[name]
    planners = list(dict.fromkeys(planners))
    if not planners:
        raise ValueError("a sweep needs at least one planner")
    if spec.cdf_only and "cdf" not in planners:
        raise ValueError(f"sweep {name} changes a CDF setting: include the planner 'cdf'")
    values = tuple(spec.values if values is None else values)
    if not values:
        raise ValueError(f"sweep {name}: no values")
    if len(set(values)) != len(values):
        raise ValueError(f"sweep {name}: repeated values {list(values)}")
    config, cdf = config or ScenarioConfig(), cdf or CDFConfig()
    points = [(v, *spec.settings(v, config, cdf)) for v in values]  # all validated before any run
    seeds = list(seeds)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if spec.name == "tau":  # the largest tau first: its histories give the fine curve
        points.sort(key=lambda p: -p[0])

    rows: list[dict] = []
    records_by_value: dict[float, list[dict]] = {}
    references = [p for p in planners if p != "cdf"] if spec.cdf_only else []
    for i, (value, cfg, cdf_v) in enumerate(points):
        point = out / name / _value_text(value)
        names = ["cdf"] if spec.cdf_only else planners
        if i == 0 and references and _planners_in(point) == list(planners):
            names, references = planners, []  # an earlier version's layout: every planner here
        recs, wall = _run_point(point, seeds, names, cfg, cdf_v, scene, progress, workers)
        if i == 0 and references:  # unaffected by the swept CDF setting: run once, at the base
            ref, ref_wall = _run_point(out / name / "reference", seeds, references, config, cdf, scene,
                                       progress, workers)
            recs, wall = recs + ref, wall + ref_wall
        records_by_value[value] = recs
        for m in planner_metrics(recs).values():
            rows.append({"sweep": name, "value": value, **m.to_row(), "point_wall_s": round(wall, 2)})
    rows.sort(key=lambda r: (r["value"], planners.index(r["planner"]) if r["planner"] in planners else 99))

    extra: dict = {}
    if spec.name == "tau":
        top = max(records_by_value)
        curve = tau_curve([r for r in records_by_value[top] if r["planner"] == "cdf"], tau_max=top)
        extra["curve"] = curve
        extra["agreement"] = _tau_agreement(records_by_value, top)
        _write_csv(out / "tau_curve.csv", curve)

    md = _markdown(spec, rows, extra)
    csv_path, md_path = out / f"{name}.csv", out / f"{name}.md"
    _write_csv(csv_path, rows)
    md_path.write_text(md + "\n", encoding="utf-8")
    fig_path = None
    if figure:
        fig_path = out / f"{name}.png"
        _figure(spec, rows, extra, fig_path)
    return SweepResult(name=name, rows=rows, csv_path=csv_path, markdown_path=md_path,
                       figure_path=fig_path, markdown=md, extra=extra)


# ----------------------------------------------------------------- tau from histories
def _decision_time(rec: dict, tau: float) -> float | None:
    hist = (rec.get("planner_info") or {}).get("history") or {}
    for t, p in zip(hist.get("t", ()), hist.get("p_cutoff", ())):
        if p >= tau:
            return float(t)
    return None


def tau_curve(records: Iterable[dict], tau_max: float, step: float = 0.01) -> list[dict]:
    """False alarms and detections of the CDF for thresholds ``step, 2 step, ..., tau_max``,
    from the P(cutoff) histories of CDF records run at ``tau_max`` (exact up to ``tau_max``:
    see the module docstring). A detection is a Cutoff episode in which it would brake
    before the obstacle enters the ego lane; rates carry their 95 % Wilson interval."""
    recs = [r for r in records if r.get("planner") == "cdf" and r.get("label") is not None]
    n_cut = sum(1 for r in recs if r["label"] == Labels.CUTOFF)
    out = []
    for tau in np.arange(step, tau_max + 1e-9, step):
        tau = round(float(tau), 6)
        fa = det = 0
        times = []
        for r in recs:
            d = _decision_time(r, tau)
            if d is None:
                continue
            if r["label"] != Labels.CUTOFF:
                fa += 1
            elif r.get("entered_lane_time") is None or d < r["entered_lane_time"]:
                det += 1
                times.append(d)
        far, detr = Rate(fa, len(recs)), Rate(det, n_cut)
        out.append({"tau": tau, "false_alarms": far.value, "false_alarms_lo": far.interval[0],
                    "false_alarms_hi": far.interval[1], "false_alarms_k": fa, "episodes": len(recs),
                    "detected": detr.value, "detected_k": det, "cutoffs": n_cut,
                    "median_decision_time": float(np.median(times)) if times else math.nan})
    return out


def _tau_agreement(records_by_value: dict[float, list[dict]], top: float) -> dict:
    """How many brake times of the braking runs (the top run's own included) the top run's
    histories predict. The history stores P(cutoff) rounded to 5 decimals, so a value within
    5e-6 of a threshold may be read on the other side of it."""
    base = {r["seed"]: r for r in records_by_value[top] if r["planner"] == "cdf"}
    same = total = 0
    for tau, recs in records_by_value.items():
        for r in recs:
            if r["planner"] != "cdf" or r["seed"] not in base:
                continue
            total += 1
            same += _decision_time(base[r["seed"]], tau) == r["brake_time"]
    return {"episodes": total, "agree": same}


# ----------------------------------------------------------------- output
_COLUMNS = ("sweep", "value", "planner", "episodes", "imminent", "collisions", "avoided", "avoided_lo",
            "avoided_hi", "avoided_k", "avoided_n", "false_alarms", "false_alarms_lo", "false_alarms_hi",
            "false_alarms_k", "false_alarms_n", "lead_time", "min_gap", "time_lost", "brier_left",
            "brier_seen", "point_wall_s")


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        path.write_text("", encoding="utf-8")
        return
    cols = [c for c in _COLUMNS if c in rows[0]] + [c for c in rows[0] if c not in _COLUMNS]
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in cols})


def _pct(rate: float, lo: float, hi: float, k: int, n: int) -> str:
    if not n:
        return "-"
    return f"{100 * rate:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({k}/{n})"


def _num(v: float | None, digits: int = 2) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def _markdown(spec: SweepSpec, rows: list[dict], extra: dict) -> str:
    lines = [f"Sweep `{spec.name}`: {spec.label}", "",
             ("| value | planner | imminent | collisions | avoided (95 % CI) | false alarms (95 % CI) "
             "| median lead [s] | median min gap [m] | mean time lost [s] | Brier P(left) | Brier P(seen) "
             "| point wall time [s] |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {_value_text(r['value'])} | {r['planner']} | {r['imminent']} | {r['collisions']} "
            f"| {_pct(r['avoided'], r['avoided_lo'], r['avoided_hi'], r['avoided_k'], r['avoided_n'])} "
            f"| {_pct(r['false_alarms'], r['false_alarms_lo'], r['false_alarms_hi'], r['false_alarms_k'], r['false_alarms_n'])} "
            f"| {_num(r['lead_time'])} | {_num(r['min_gap'])} | {_num(r['time_lost'])} "
            f"| {_num(r['brier_left'], 3)} | {_num(r['brier_seen'], 3)} | {_num(r['point_wall_s'], 1)} |")
    others = sorted({_value_text(r["value"]) for r in rows if r["planner"] != "cdf"})
    if spec.cdf_only and others:
        lines += ["", (f"Planners other than `cdf` do not read this setting: they ran once and are "
                       f"listed at {spec.name} = {', '.join(others)}.")]
    if "agreement" in extra:
        a = extra["agreement"]
        lines += ["", (f"Brake times derived from the histories of the largest-tau run agree with the "
                      f"braking runs in {a['agree']}/{a['episodes']} CDF episodes (`tau_curve.csv` "
                      "holds the fine curve; its false alarms are exact up to the 5-decimal rounding of the stored "
                      "P(cutoff), its avoidance is not computed).")]
    return "\n".join(lines)


def _pyplot():
    try:
        import matplotlib
    except ImportError:
        raise VizUnavailableError(f"the sweep figures need matplotlib: {_VIZ_HINT}") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    """Lay out, write as PNG (110 dpi, parents created) and close a figure; returns ``path``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _figure(spec: SweepSpec, rows: list[dict], extra: dict, path: Path) -> None:
    """Avoided and false alarms against the swept value (tau: the operating curve)."""
    plt = _pyplot()
    planners = list(dict.fromkeys(r["planner"] for r in rows))
    if spec.name == "tau":
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
        cdf_rows = sorted((r for r in rows if r["planner"] == "cdf"), key=lambda r: r["value"])
        ax.errorbar([100 * r["false_alarms"] for r in cdf_rows], [100 * r["avoided"] for r in cdf_rows],
                    yerr=[[100 * (r["avoided"] - r["avoided_lo"]) for r in cdf_rows],
                          [100 * (r["avoided_hi"] - r["avoided"]) for r in cdf_rows]],
                    fmt="o-", color="C0", capsize=2, label="cdf over tau (braking runs)")
        for k, r in enumerate(cdf_rows):
            ax.annotate(f"{_value_text(r['value'])}", (100 * r["false_alarms"], 100 * r["avoided"]),
                        textcoords="offset points", xytext=(3, 6 if k % 2 else -11), fontsize=7, color="C0")
        for j, p in enumerate(x for x in planners if x != "cdf"):
            r = next(r for r in rows if r["planner"] == p)
            ax.plot(100 * r["false_alarms"], 100 * r["avoided"], marker="s", ls="", color=f"C{j + 1}", label=p)
        ax.set_xlabel("false alarms [% of episodes]")
        ax.set_ylabel("imminent collisions avoided [% of Cutoff episodes]")
        ax.set_title("Operating curve (labels: tau)", fontsize=10)
        curve = extra.get("curve") or []
        if curve:
            taus = [c["tau"] for c in curve]
            bx.plot(taus, [100 * c["false_alarms"] for c in curve], color="C3",
                    label="false alarms, every 0.01 (from the histories)")
            bx.fill_between(taus, [100 * c["false_alarms_lo"] for c in curve],
                            [100 * c["false_alarms_hi"] for c in curve], color="C3", alpha=0.15, lw=0)
            bx.plot(taus, [100 * c["detected"] for c in curve], color="0.5", ls=":",
                    label="cut-offs braked for before lane entry (from the histories)")
        bx.plot([r["value"] for r in cdf_rows], [100 * r["false_alarms"] for r in cdf_rows], "o", color="C3",
                mfc="none", label="false alarms (braking runs)")
        bx.plot([r["value"] for r in cdf_rows], [100 * r["avoided"] for r in cdf_rows], "o-", color="C0",
                label="avoided (braking runs)")
        bx.set_xlabel("tau")
        bx.set_ylabel("[%]")
        bx.set_title("Against the threshold", fontsize=10)
        for a in (ax, bx):
            a.grid(alpha=0.3)
            a.legend(fontsize=7)
    else:
        fig, axes = plt.subplots(1, 3 if any(r["brier_left"] is not None for r in rows) else 2,
                                 figsize=(13, 4))
        series = [("avoided", "imminent collisions avoided [%]"), ("false_alarms", "false alarms [% of episodes]")]
        for ax, (key, title) in zip(axes, series):
            for j, p in enumerate(planners):
                rs = sorted((r for r in rows if r["planner"] == p), key=lambda r: r["value"])
                xs = [r["value"] for r in rs]
                ys = [100 * r[key] for r in rs]
                err = [[100 * (r[key] - r[f"{key}_lo"]) for r in rs], [100 * (r[f"{key}_hi"] - r[key]) for r in rs]]
                if len(rs) == 1 and spec.cdf_only:
                    ax.axhline(ys[0], color=f"C{j}", ls="--", lw=1, label=f"{p} (does not read it)")
                else:
                    ax.errorbar(xs, ys, yerr=err, fmt="o-", capsize=2, color=f"C{j}", label=p)
            ax.set_title(title, fontsize=10)
        if len(axes) == 3:
            ax = axes[2]
            for j, p in enumerate(planners):
                for key, style in (("brier_left", "o-"), ("brier_seen", "s--")):
                    rs = sorted((r for r in rows if r["planner"] == p and r[key] is not None),
                                key=lambda r: r["value"])
                    if len(rs) > 1:
                        ax.plot([r["value"] for r in rs], [r[key] for r in rs], style, color=f"C{j}",
                                label=f"{p} {'P(left)' if key == 'brier_left' else 'P(seen)'}")
            ax.set_title("Brier score over all ticks (lower is better)", fontsize=10)
        for ax in axes:
            ax.set_xlabel(spec.label, fontsize=8)
            if spec.log_x:
                ax.set_xscale("log")
                ax.minorticks_off()
            values = sorted({r["value"] for r in rows})
            ax.set_xticks(values)
            ax.set_xticklabels([_value_text(v) for v in values], fontsize=8)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle(f"Sweep: {spec.name}", fontsize=11)
    _save(fig, path)


def load_rows(path: str | Path) -> list[dict]:
    """Rows of a sweep's CSV (numbers as floats, empty cells as None)."""
    out = []
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            conv: dict = {}
            for k, v in row.items():
                if v == "":
                    conv[k] = None
                else:
                    try:
                        conv[k] = json.loads(v)
                    except ValueError:
                        conv[k] = v
            out.append(conv)
    return out


# ----------------------------------------------------------------- planner comparison figures
def comparison_figures(records: Iterable[dict], out_dir: str | Path, p_left: float = 0.75) -> list[Path]:
    """Figures of an experiment's records (planners on the same seeds), written to ``out_dir``:

    ``brier_over_time.png``: Brier score of P(left) and P(seen) per tick time for every
    planner with such a history, beside the prior ``p_left`` held constant and the per-time
    base rate (in-sample); ``brake_times.png``: when each planner brakes, relative to the
    obstacle entering the ego lane (Cutoff episodes), and the share of other episodes in
    which it has braked by each time (its false alarms).
    """
    from cdf_mj.analysis.metrics import brier_over_time

    plt = _pyplot()
    recs = [r for r in records if r.get("status") != "failed" and r.get("label") is not None]
    planners = list(dict.fromkeys(r["planner"] for r in recs))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for ax, q, title in ((axes[0], "p_left", "P(left) against the true intent"),
                         (axes[1], "p_seen", "P(seen) against 'observed the ego on an earlier tick'")):
        ref = None
        for j, p in enumerate(planners):
            c = brier_over_time([r for r in recs if r["planner"] == p], q)
            if not c.episodes:
                continue
            keep = c.counts >= max(10, 0.1 * c.episodes)
            ax.plot(c.times[keep], c.scores[keep], color=f"C{j}", label=f"{p} (all ticks {c.overall:.3f})")
            ref = ref or c
        if ref is not None:
            keep = ref.counts >= max(10, 0.1 * ref.episodes)
            if q == "p_left":
                first = [r for r in recs if r["planner"] == planners[0]]
                y = np.array([r["intent"] == "left" for r in first], dtype=float)
                ax.axhline(float(np.mean((p_left - y) ** 2)), color="0.5", ls=":",
                           label=f"prior {p_left:g}, held")
            else:
                ax.plot(ref.times[keep], ref.reference[keep], color="0.5", ls=":",
                        label="base rate per time (in-sample)")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("Brier score (lower is better)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "brier_over_time.png"))

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for j, p in enumerate(planners):
        mine = [r for r in recs if r["planner"] == p]
        lead = sorted(r["entered_lane_time"] - r["brake_time"] for r in mine if r["label"] == Labels.CUTOFF
                      and r["brake_time"] is not None and r["entered_lane_time"] is not None)
        n_cut = sum(1 for r in mine if r["label"] == Labels.CUTOFF)
        if lead and n_cut:
            axes[0].step(lead, np.arange(1, len(lead) + 1) / n_cut * 100, where="post", color=f"C{j}", label=p)
        other = [r for r in mine if r["label"] != Labels.CUTOFF]
        fa = sorted(r["brake_time"] for r in other if r["brake_time"] is not None)
        if other:
            axes[1].step([0.0, *fa, 8.0], [0.0, *(np.arange(1, len(fa) + 1) / len(other) * 100), len(fa) / len(other) * 100],
                         where="post", color=f"C{j}", label=p)
    axes[0].invert_xaxis()
    axes[0].set_xlabel("lead time: obstacle enters the ego lane minus brake [s]")
    axes[0].set_ylabel("Cutoff episodes braked with at least this lead [%]")
    axes[1].set_xlabel("time [s]")
    axes[1].set_ylabel("Yield and Right episodes braked by then [%]")
    axes[0].set_title("Lead time in Cutoff episodes", fontsize=10)
    axes[1].set_title("False alarms over time", fontsize=10)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    paths.append(_save(fig, out / "brake_times.png"))
    return paths
