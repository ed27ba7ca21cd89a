"""A falsification or estimation run in a directory: its settings, its journal, its
results, and a second start of the same command that goes on where the first stopped.

``falsify`` writes into ``out``::

    settings.json          what was asked (the space file's text, planner, seed, ...)
    evaluations.jsonl      every episode, as it finished (cdf_mj.falsify.evaluate)
    summary.json           the search's generations, failures and counterexamples
    report.md              the same for a person
    progress.png           least robustness per generation (with matplotlib)
    counterexamples/       NN-seed-S.toml presets, one per cluster

``estimate`` writes ``settings.json``, ``evaluations.jsonl`` and ``estimate.json``. A
directory holds one kind of run with one set of settings and one version of the package
(a search's budget may grow; an estimate's budget changes its sample); another is
refused with one line, as is a second run into a directory in use.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cdf_mj._version import __version__
from cdf_mj.experiments.runner import Backend
from cdf_mj.experiments.store import check_run_kind, locked
from cdf_mj.falsify.counterexamples import Counterexample, find_counterexamples, write_counterexamples
from cdf_mj.falsify.estimate import Estimate, cross_entropy, monte_carlo
from cdf_mj.falsify.evaluate import JOURNAL_FILE, Evaluation, Evaluator, Journal
from cdf_mj.falsify.search import SEARCH, Generation, SearchResult, run_search
from cdf_mj.falsify.space import SearchSpace
from cdf_mj.inputs import SETTINGS_MAX_BYTES, InputError, parse_json, read_text
from cdf_mj.records import jsonable, write_atomic
from cdf_mj.records.files import check_output_target
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["METHODS", "MIXTURE_COMPONENTS", "SETTINGS", "FalsifyResult", "estimate", "falsify"]

SETTINGS = "settings.json"
#: The estimators of :func:`estimate`.
METHODS = ("ce", "mixture", "mc")
#: Most components of the mixture estimator's proposal (failure modes weighed apart).
MIXTURE_COMPONENTS = 8


@dataclass
class FalsifyResult:
    """A finished search and what was made of its failures."""

    space: SearchSpace
    search: SearchResult
    counterexamples: list[Counterexample]
    out: Path
    episodes_run: int  # by this call (the rest came from the journal)
    errors: list[Evaluation]  # every episode of the run that raised: search, minimisation, replays

    def to_dict(self) -> dict[str, Any]:
        return {"space": self.space.name, "failure": self.space.failure.text, "search": self.search.to_dict(),
                "counterexamples": [c.to_dict() for c in self.counterexamples],
                "errors": [e.to_dict() for e in self.errors]}


def space_spec(space: SearchSpace) -> dict[str, Any]:
    """What of a space decides its episodes: the base world, the failure and the
    dimensions (not the description or the file's comments), as JSON."""
    return {"base": jsonable(space.base), "failure": jsonable(space.failure), "dims": jsonable(space.dims)}


#: Settings stored beside a run but not compared on resume (the space's name and text: a new
#: comment or description does not make another run).
_NOT_COMPARED = ("space", "space_text")


def _scene_settings(scene: str | Path, space: SearchSpace) -> dict[str, Any]:
    """The scene a run is bound to: its resolved path and every file it is made from with
    its hash (:func:`cdf_mj.experiments.experiment.scene_files`), after loading it once here
    with the space's names (a missing or wrong scene is one error before anything is
    written, not one per worker)."""
    from cdf_mj.experiments.experiment import scene_files

    Scene.load(scene, names=space.base.names)
    return {"scene": str(Path(scene).resolve()), "scene_files": scene_files(scene)}


def _settings(out: Path, wanted: dict[str, Any]) -> None:
    """Write ``wanted`` to ``out/settings.json``, or check it against what is there; a
    directory whose journal holds no episode yet takes the new settings (it binds nothing).
    Keys a directory made by an earlier version lacks (``scene_files``) are not compared;
    a directory of another kind of run (an experiment's) is refused whatever it holds."""
    check_run_kind(out, wanted["kind"])
    path = out / SETTINGS
    journal = out / JOURNAL_FILE
    if path.exists() and journal.exists() and journal.stat().st_size > 0:
        try:
            have = parse_json(read_text(path, "settings file", SETTINGS_MAX_BYTES), f"settings file {path}")
        except (InputError, ValueError, OSError) as exc:
            raise ValueError(f"{path} cannot be read ({exc}); move it away or choose another directory") from None
        kind = wanted["kind"]
        if not isinstance(have, dict) or have.get("kind") != kind:
            raise ValueError(f"{out} holds another kind of run ({have.get('kind') if isinstance(have, dict) else '?'}"
                             f"), not {_article(kind)} {kind}; choose another directory")
        for key, value in wanted.items():
            if key in _NOT_COMPARED or (key not in have and key == "scene_files") or have.get(key) == value:
                continue
            if key == "space_spec":
                what = "space (its base world, failure or dimensions differ from the run's)"
            elif key == "version":
                what = (f"version of cdf_mj ({_short(have.get(key))} there, {value} now: episodes of two versions "
                        "are not mixed)")
            else:
                what = f"{key} ({_short(have.get(key))} there, {_short(value)} now)"
            raise ValueError(f"{out} holds {_article(kind)} {kind} run with another {what}; give the same settings "
                             "to go on with it, or choose another directory")
        return
    write_atomic(path, json.dumps(wanted, indent=2) + "\n")


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _open(out: str | Path, wanted: dict[str, Any], stack: ExitStack) -> tuple[Path, Journal]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stack.enter_context(locked(out))
    _settings(out, wanted)
    journal = Journal(out / JOURNAL_FILE)
    stack.callback(journal.close)
    return out, journal


def falsify(space: SearchSpace, planner: str, budget: int, out: str | Path, *, compare: Sequence[str] = (),
            seed: int = 0, popsize: int | None = None, objective: str = "robustness",
            scene: str | Path = DEFAULT_SCENE, backend: Backend = "process", workers: int | None = None,
            address: str | None = None, max_clusters: int = 12, figure: bool = True,
            on_episode: Callable[[int], None] | None = None,
            on_generation: Callable[[Generation], None] | None = None,
            on_search_done: Callable[[int], None] | None = None, scene_args: str = "") -> FalsifyResult:
    """Search ``space`` for failures of ``planner`` within ``budget`` episodes, cluster and
    minimise them, replay them on ``compare``, and write the run's files into ``out``
    (see the module docstring); ``objective``: what the search ranks by
    (:func:`~cdf_mj.falsify.search.run_search`). Resumable: the same call goes on from the journal. A scene
    of your own: ``scene`` and, with other names, ``space.base.names`` (``scene_args``: how
    the replay commands in the counterexamples' descriptions should name them)."""
    from cdf_mj.falsify.report import falsify_markdown, progress_figure

    wanted = {"kind": "falsify", "version": __version__, "space": space.name, "space_spec": space_spec(space),
              "space_text": space.text, "planner": planner, "seed": seed, "popsize": popsize,
              "search": SEARCH, "objective": objective, **_scene_settings(scene, space)}
    with ExitStack() as stack:
        out_dir, journal = _open(out, wanted, stack)
        for name in ("summary.json", "report.md", *(("progress.png",) if figure else ())):
            check_output_target(out_dir / name)  # a FIFO or a device there: refused before the search
        evaluator = Evaluator(space, [planner, *compare], journal, scene=scene, backend=backend, workers=workers,
                              address=address, on_episode=on_episode)
        stack.callback(evaluator.close)
        search = run_search(evaluator, planner, budget, seed=seed, popsize=popsize, objective=objective,
                            on_generation=on_generation)
        if on_search_done is not None:
            on_search_done(len(search.failures))
        found = find_counterexamples(evaluator, planner, search.failures, [c for c in compare if c != planner],
                                     max_clusters=max_clusters)
        write_counterexamples(space, found, out_dir / "counterexamples", scene_args)
        result = FalsifyResult(space, search, found, out_dir, evaluator.episodes_run, list(evaluator.errors.values()))
        write_atomic(out_dir / "summary.json", json.dumps(result.to_dict(), indent=2, allow_nan=False) + "\n")
        figure_path = out_dir / "progress.png"
        if figure:
            progress_figure({planner: [search]}, figure_path, space.failure.margin)
        write_atomic(out_dir / "report.md", falsify_markdown(result, figure_path.name if figure else None))
        return result


def estimate(space: SearchSpace, planner: str, budget: int, out: str | Path, *, method: str = "ce",
             seed: int = 0, stage: int | None = None, scene: str | Path = DEFAULT_SCENE,
             backend: Backend = "process", workers: int | None = None, address: str | None = None,
             on_episode: Callable[[int], None] | None = None,
             on_stage: Callable[[dict[str, Any]], None] | None = None) -> Estimate:
    """P(failure) of ``planner`` per encounter of ``space``'s nominal distribution, by
    ``method`` ``"ce"`` (cross-entropy importance sampling, one proposal), ``"mixture"``
    (cross-entropy with a mixture proposal, a component per failure mode) or ``"mc"``
    (plain Monte Carlo), within ``budget`` episodes; written to ``out/estimate.json``.
    Resumable."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    wanted = {"kind": "estimate", "version": __version__, "space": space.name, "space_spec": space_spec(space),
              "space_text": space.text, "planner": planner, "seed": seed, "method": method, "stage": stage,
              **_scene_settings(scene, space)}
    with ExitStack() as stack:
        out_dir, journal = _open(out, wanted, stack)
        check_output_target(out_dir / "estimate.json")  # a FIFO or a device there: refused before any episode
        evaluator = Evaluator(space, [planner], journal, scene=scene, backend=backend, workers=workers,
                              address=address, on_episode=on_episode)
        stack.callback(evaluator.close)
        if method == "mc":
            result = monte_carlo(evaluator, planner, budget, seed=seed)
        else:
            result = cross_entropy(evaluator, planner, budget, seed=seed, stage=stage, on_stage=on_stage,
                                   components=MIXTURE_COMPONENTS if method == "mixture" else 1)
        write_atomic(out_dir / "estimate.json", json.dumps({"space": space.name, "failure": space.failure.text,
                                                             **result.to_dict()}, indent=2, allow_nan=False) + "\n")
        return result
