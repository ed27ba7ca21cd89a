"""From a search's failures to a handful a person reads: clustered, minimised, replayed
on other planners, and written as preset files that ``cdf-mj episode`` and
``cdf-mj render`` replay.

- **Clusters**: failures with the same choices (driver family, route, after-merge
  behaviour, whole-number latencies: every discrete dimension) form one cluster; its
  representative is its most severe failure (least robustness, then the first found).
- **Likelihood**: every counterexample carries the nominal log-likelihood of its
  representative's world and of its cluster's likeliest failure
  (:meth:`SearchSpace.log_likelihood`), and the nominal probability of its choices (an
  upper bound on the cluster's probability mass); the counterexamples are listed
  likeliest first (the likeliest failure of each, then the choices' probability), so a
  failure of everyday traffic comes before one that needs a rare corner of the space.
- **Minimised**: each representative's options are put back to the base world's values
  one at a time, in the space's order, keeping each reset under which the same seed still
  fails, in passes until a pass puts none back (a one-minimal set: no single remaining
  option can go back). Clusters
  whose minimised choices agree are merged. What is left is the failure's *traits*: the
  fewest options away from the defaults found to fail.
- **Replayed**: the minimised counterexample and up to ``replay`` members of its cluster
  run on every planner compared, same worlds and seeds.
- **Written**: ``NN-seed-S.toml``, a preset of every option that differs from the
  package's defaults, its description saying the planner, the seed and the command::

      cdf-mj episode --preset counterexamples/01-seed-123.toml --seed 123 --planner cdf
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cdf_mj.config import GROUPS, ScenarioConfig
from cdf_mj.falsify.evaluate import Evaluation, Evaluator
from cdf_mj.falsify.space import SearchSpace
from cdf_mj.records import write_atomic

__all__ = ["Counterexample", "choice_mass", "cluster_failures", "find_counterexamples", "preset_text",
           "write_counterexamples"]


@dataclass
class Counterexample:
    """One cluster of failures and its minimised representative."""

    planner: str
    seed: int
    point: tuple[float, ...]
    keep: tuple[str, ...]  # options put back to the base world's values
    changed: dict[str, Any]  # the minimised traits: option -> value, away from the base
    robustness: float  # of the minimised counterexample, <= 0 [the margin's unit: m or s]
    summary: dict[str, Any]
    members: list[Evaluation]
    contact: dict[str, float] | None = None  # speeds at the first touch [m/s]
    others: dict[str, bool | None] = field(default_factory=dict)  # planner -> fails on the minimised case
    # (None: the episode raised)
    others_members: dict[str, tuple[int, int]] = field(default_factory=dict)  # planner -> (fail, replayed)
    path: str | None = None
    log_likelihood: float = math.nan  # of the representative's point under the space's nominal
    likeliest: float = math.nan  # the largest of the cluster's failures'
    choice_mass: float = math.nan  # the nominal probability of its choices (every discrete dimension)

    def to_dict(self) -> dict[str, Any]:
        return {"planner": self.planner, "seed": self.seed, "point": list(self.point), "keep": list(self.keep),
                "changed": self.changed, "robustness": self.robustness, "summary": self.summary,
                "cluster_size": len(self.members), "contact": self.contact, "others": self.others,
                "others_members": {k: list(v) for k, v in self.others_members.items()}, "path": self.path,
                "log_likelihood": _finite_or_none(self.log_likelihood),
                "likeliest": _finite_or_none(self.likeliest), "choice_mass": _finite_or_none(self.choice_mass)}


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def choice_mass(space: SearchSpace, point: Sequence[float]) -> float:
    """The nominal probability of ``point``'s choices: the product of each discrete
    dimension's nominal weight of its value."""
    mass = 1.0
    for d, x in zip(space.dims, point, strict=True):
        if d.discrete:
            mass *= float(np.exp(d.log_nominal(np.array([float(x)]))[0]))
    return mass


def _signature(space: SearchSpace, point: Sequence[float], keep: Sequence[str] = ()) -> tuple[Any, ...]:
    return tuple((d.key, d.value(float(x))) for d, x in zip(space.dims, point, strict=True)
                 if d.discrete and d.key not in keep)


def cluster_failures(space: SearchSpace, failures: Sequence[Evaluation]) -> list[list[Evaluation]]:
    """Failures grouped by their discrete coordinates, largest group first; each group's
    first member is its representative (least robustness, then the first found)."""
    groups: dict[tuple[Any, ...], list[Evaluation]] = {}
    for ev in failures:
        groups.setdefault(_signature(space, ev.point), []).append(ev)
    out = [sorted(g, key=lambda e: e.robustness) for g in groups.values()]  # stable: first found first
    return sorted(out, key=lambda g: -len(g))


def _minimise(evaluator: Evaluator, planner: str, reps: Sequence[Evaluation]) -> list[tuple[tuple[str, ...],
                                                                                          Evaluation]]:
    """One-minimal reset of each representative (batched across them): passes over the
    dimensions in order, each trying to put one more option back, until a pass puts none
    back (a reset can make another one possible). A trial that raised keeps its option
    (and is in :attr:`Evaluator.errors`)."""
    space = evaluator.space
    kept: list[list[str]] = [[d.key for d, x in zip(space.dims, rep.point, strict=True) if space.at_default(d, x)]
                             for rep in reps]
    last: list[Evaluation] = list(reps)
    tried: list[set[tuple[str, ...]]] = [set() for _ in reps]  # keep sets already run
    changed = True
    while changed:
        changed = False
        for dim in space.dims:
            trials = [i for i in range(len(reps)) if dim.key not in kept[i]
                      and tuple(sorted([*kept[i], dim.key])) not in tried[i]]
            if not trials:
                continue
            keeps = [[*kept[i], dim.key] for i in trials]
            got = evaluator.evaluate([(reps[i].point, reps[i].seed) for i in trials], [planner], keep=keeps)
            for i, k, result in zip(trials, keeps, got, strict=True):
                tried[i].add(tuple(sorted(k)))
                ev = result[planner]
                if ev.failed:
                    kept[i].append(dim.key)
                    last[i] = ev
                    changed = True
    return [(tuple(sorted(k)), ev) for k, ev in zip(kept, last, strict=True)]


def _contact(space: SearchSpace, planner: str, ev: Evaluation, scene: str) -> dict[str, float] | None:
    """Both cars' speeds [m/s] on the first tick they touch, and the ego's braking then."""
    from cdf_mj.scenario.episode import EpisodeTick, run_episode
    from cdf_mj.sim.scene import Scene

    seen: dict[str, float] = {}

    def watch(step: EpisodeTick) -> None:
        if not seen and step.tick.collision == "obstacle":
            seen.update(ego_speed=float(step.tick.poses[0, 3]), obstacle_speed=float(step.tick.poses[1, 3]),
                        ego_command=float(step.command) if math.isfinite(step.command) else float("nan"),
                        t=float(step.tick.t))

    config = space.config(ev.point, ev.keep)
    run_episode(config, ev.seed, planner, Scene.load(scene, names=config.names), label=False, observers=[watch])
    return {k: round(v, 3) for k, v in seen.items() if math.isfinite(v)} or None


def find_counterexamples(evaluator: Evaluator, planner: str, failures: Sequence[Evaluation],
                         compare: Sequence[str] = (), *, max_clusters: int = 12,
                         replay: int = 20) -> list[Counterexample]:
    """Cluster ``failures`` of ``planner``, minimise the ``max_clusters`` largest clusters'
    representatives, merge those that minimise alike, order them likeliest first (module
    docstring) and replay them on ``compare``."""
    space = evaluator.space
    clusters = cluster_failures(space, failures)[:max_clusters]
    if not clusters:
        return []
    minimised = _minimise(evaluator, planner, [c[0] for c in clusters])
    merged: dict[tuple[Any, ...], Counterexample] = {}
    for cluster, (keep, ev) in zip(clusters, minimised, strict=True):
        sig = (_signature(space, ev.point, keep), tuple(k for k in space.keys if k not in keep))
        if sig in merged:
            merged[sig].members.extend(cluster)
            continue
        changed = {k: v for k, v in space.values(ev.point).items() if k not in keep}
        merged[sig] = Counterexample(planner, ev.seed, ev.point, keep, changed, ev.robustness, ev.summary,
                                     list(cluster))
    for c in merged.values():
        c.log_likelihood = float(space.log_likelihood([c.members[0].point])[0])
        c.likeliest = float(space.log_likelihood([m.point for m in c.members]).max())
        cells = {_signature(space, m.point): m.point for m in c.members}  # merged clusters span several
        c.choice_mass = sum(choice_mass(space, point) for point in cells.values())
    out = sorted(merged.values(), key=lambda c: (-c.likeliest, -c.choice_mass, -len(c.members)))
    for other in compare:
        got = evaluator.evaluate([(c.point, c.seed) for c in out], [other], keep=[c.keep for c in out])
        for c, result in zip(out, got, strict=True):
            c.others[other] = None if result[other].error is not None else result[other].failed
        for c in out:
            members = c.members[:replay]
            res = evaluator.evaluate([(m.point, m.seed) for m in members], [other])
            c.others_members[other] = (sum(r[other].failed for r in res), len(members))
    for c in out:
        c.contact = _contact(space, planner, Evaluation(planner, c.seed, c.point, c.keep, c.robustness, True, {}),
                             evaluator.job.scene)
    return out


# ------------------------------------------------------------------------ files
def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if isinstance(value, int) else repr(float(value))
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return '"' + _toml_text(str(value)).replace("\n", "\\n") + '"'


def _toml_text(text: str) -> str:
    """``text`` inside a TOML multi-line basic string: backslashes and quotes escaped, other
    control characters as ``\\uXXXX``."""
    out = text.replace("\\", "\\\\").replace('"', '\\"')
    return "".join(c if c == "\n" or c.isprintable() else f"\\u{ord(c):04x}" for c in out)


def preset_text(config: ScenarioConfig, description: str) -> str:
    """A preset file (:mod:`cdf_mj.presets`) of ``config``: every option that differs from
    the package's defaults, by group."""
    default = ScenarioConfig()
    lines = ['description = """', *_toml_text(description.strip()).splitlines(), '"""']
    for group in GROUPS:
        ours, theirs = getattr(config, group).to_dict(), getattr(default, group).to_dict()
        changed = {k: v for k, v in ours.items() if v != theirs[k]}
        if changed:
            lines += ["", f"[scenario.{group}]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in changed.items()]
    return "\n".join(lines) + "\n"


def write_counterexamples(space: SearchSpace, found: Sequence[Counterexample], directory: str | Path,
                          scene_args: str = "") -> None:
    """Write each counterexample as ``directory/NN-seed-S.toml`` (sets ``path``); files of
    that form left by an earlier run are removed first, so the directory holds this run's.
    ``scene_args`` (``--scene FILE --names FILE`` of a scene of your own, which a preset
    cannot hold) go into the replay commands of the descriptions. ValueError naming
    ``directory`` if it is a symbolic link (its files would land outside the run's
    directory) or not a directory; nothing is removed or written then."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if directory.is_symlink() or not directory.is_dir():
        what = "a symbolic link" if directory.is_symlink() else "not a directory"
        raise ValueError(f"{directory} is {what}: the counterexamples are written into a directory of the run's "
                         "own; move it away or choose another directory")
    for old in directory.glob("[0-9][0-9]-seed-*.toml"):
        old.unlink()
    for i, c in enumerate(found, 1):
        path = directory / f"{i:02d}-seed-{c.seed}.toml"
        traits = ", ".join(f"{k} = {_short(v)}" for k, v in c.changed.items()) or "none (the base world)"
        what = "collided" if c.summary.get("collision") else f"reached robustness {c.robustness:.3g}"
        text = (f"Counterexample {i} of a search of space {space.name!r} for planner {c.planner!r}: with seed "
                f"{c.seed}, the ego {what} (label {c.summary.get('label')}). {len(c.members)} failure(s) of the "
                f"search share its choices. Traits away from the space's base world ({space.preset}): "
                f"{traits}. Replay: cdf-mj episode --preset {path} --seed {c.seed} --planner {c.planner}"
                f"{scene_args and ' ' + scene_args}; watch: cdf-mj render --preset {path} --seed {c.seed} "
                f"--planner {c.planner}{scene_args and ' ' + scene_args}.")
        write_atomic(path, preset_text(space.config(c.point, c.keep), _wrap(text)))
        c.path = str(path)


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def _wrap(text: str, width: int = 88) -> str:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    return "\n".join([*lines, line])
