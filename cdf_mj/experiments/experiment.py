"""Many episodes: run planners on the same seeds, persist every record, print the tables.

``run_experiment`` runs every planner on every seed (common random numbers: the obstacle
and the ego's start are the same for all planners) on a process pool (default: one
worker per CPU; :mod:`cdf_mj.experiments.runner` also offers ``serial`` and ``ray``), and appends one
JSON line per episode and planner to ``DIR/episodes.jsonl`` as soon as its seed
finishes (flushed and fsync-ed); the settings go to ``DIR/settings.json``. The records
are the same whatever the backend and the number of workers.

A run that was killed continues with ``resume=True`` (as ``cdf-mj experiment`` does):
the seeds already on disk are skipped, a half-written last line is dropped, and nothing
is run twice. A directory holding results from other settings is refused, and so is a
directory with results when ``resume`` is not asked for (:class:`ResultsExistError`). An
episode that raises is recorded with its traceback (``"status": "failed"``) and the run
goes on.

:func:`~cdf_mj.analysis.tables.experiment_tables` turns records into the paper's two
tables beside ours, with 95 % Wilson intervals. ::

    from cdf_mj.analysis.tables import experiment_tables
    result = run_experiment("results/run1", seeds=range(100), planners=("cdf", "reactive"))
    print(experiment_tables(result.records))
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import stat
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, overload
from xml.etree import ElementTree

from tqdm import tqdm

from cdf_mj._version import __version__
from cdf_mj.config import CDFConfig, ScenarioConfig, check_seed, normalise_settings
from cdf_mj.experiments.runner import (
    START_METHOD,
    Backend,
    SeedJob,
    WorkerDiedError,
    check_backend,
    effective_backend,
    run_seeds,
    worker_count,
)
from cdf_mj.experiments.store import RecordStore, check_run_kind, locked, write_atomic
from cdf_mj.planners.base import Planner
from cdf_mj.planners.registry import PlannerSpec, bind_planner, stored_planner_arguments
from cdf_mj.records import FAILED, RECORDS_FILE, EpisodeRecord, read_settings
from cdf_mj.scenario.episode import run_episode
from cdf_mj.scenario.world import World
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["ExperimentResult", "ResultsExistError", "SettingsMismatchError", "iter_episodes", "run_experiment",
           "run_many", "scene_files"]


class ResultsExistError(ValueError):
    """The result directory already holds results of this experiment (the same settings)
    and ``resume`` was not asked for."""


class SettingsMismatchError(ValueError):
    """The result directory holds results made with other settings; the message names the
    differing keys. Nothing is run."""


def _planner(name: str, cdf: CDFConfig | None) -> Planner:
    return bind_planner(name, cdf)()


def iter_episodes(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
                  scene: str | Path = DEFAULT_SCENE, progress: bool = True,
                  cdf: CDFConfig | None = None) -> Iterator[EpisodeRecord]:
    """Yield one labelled record per seed, in order, in this process, with a progress bar."""
    config = config or ScenarioConfig()
    sc = Scene.load(scene, names=config.names)
    for seed in tqdm(list(seeds), desc=f"{planner} episodes", unit="ep", disable=not progress, leave=False):
        yield run_episode(config, seed, _planner(planner, cdf), sc)


def run_many(seeds: Iterable[int], planner: str = "reactive", config: ScenarioConfig | None = None,
             scene: str | Path = DEFAULT_SCENE, progress: bool = True,
             cdf: CDFConfig | None = None) -> list[EpisodeRecord]:
    """Records of all ``seeds`` for one planner (see :func:`iter_episodes`)."""
    return list(iter_episodes(seeds, planner, config, scene, progress, cdf))


#: MJCF elements whose ``file`` attribute names a file the compiled model is made from,
#: and the ``<compiler>`` directory each is looked up in first.
_FILE_ELEMENTS = {"include": None, "model": None, "mesh": "meshdir", "skin": "meshdir",
                  "hfield": "meshdir", "texture": "texturedir"}
_MAX_SCENE_FILES = 1000  # more is a loop or not a scene


def scene_files(scene: str | Path) -> dict[str, str]:
    """Every file the MJCF ``scene`` is made from, as absolute path -> SHA-256 (hex).

    The scene file, the files it includes (``<include file=...>``, recursively), the model
    files it attaches (``<model file=...>``, with their own includes and assets) and its
    meshes, skins, height fields and textures, looked up as MuJoCo does: includes from the
    directory of the file that starts the model, assets in the ``<compiler>`` ``meshdir``,
    ``texturedir`` or ``assetdir`` (relative to that directory) and then in it. A file that
    is not found is left out (MuJoCo refuses the scene then). ValueError naming a file
    that is not a regular file (a FIFO would block) or that is not XML where XML is due.
    """
    found: dict[str, str] = {}

    def digest(path: Path) -> bytes:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise ValueError(f"scene file {path} is not a regular file: give a file")
            with os.fdopen(fd, "rb", closefd=False) as fh:
                data = fh.read()
        finally:
            os.close(fd)
        found[str(path)] = hashlib.sha256(data).hexdigest()
        return data

    def walk(path: Path, root: Path) -> None:
        """Hash the MJCF ``path`` and everything it names; ``root``: the model's directory."""
        if str(path) in found or len(found) > _MAX_SCENE_FILES:
            return
        try:
            tree = ElementTree.fromstring(digest(path))
        except ElementTree.ParseError as exc:
            raise ValueError(f"scene file {path} is not XML ({exc})") from None
        dirs = {}
        for comp in tree.iter("compiler"):
            for key in ("meshdir", "texturedir", "assetdir"):
                if comp.get(key):
                    dirs[key] = root / comp.get(key, "")
        for elem in tree.iter():
            name = elem.get("file")
            if name is None or not isinstance(elem.tag, str) or elem.tag not in _FILE_ELEMENTS:
                continue
            kind = _FILE_ELEMENTS[elem.tag]
            places = [d for d in (dirs.get(kind or ""), dirs.get("assetdir")) if d is not None] if kind else []
            places += [root, path.parent]
            target = next((q / name for q in places if (q / name).exists()), None)
            if target is None:
                continue  # MuJoCo names it when it loads the scene
            target = target.resolve()
            if elem.tag == "include":
                walk(target, root)
            elif elem.tag == "model":
                walk(target, target.parent)  # an attached model resolves its own files
            elif str(target) not in found:
                digest(target)

    top = Path(scene).resolve()
    walk(top, top.parent)
    return found


def _settings(seeds: Sequence[int], planners: Sequence[str], config: ScenarioConfig,
              cdf: CDFConfig, scene: str | Path, factories: Mapping[str, PlannerSpec]) -> dict[str, Any]:
    return {"seeds": [int(seeds[0]), int(seeds[-1]) + 1] if seeds else [0, 0],
            "planners": list(planners), "scenario": config.to_dict(), "cdf": cdf.to_dict(),
            "planner_args": {name: factories[name].arguments() for name in planners},
            "scene": str(Path(scene).resolve()), "scene_files": scene_files(scene),
            "version": __version__}


def _shown(path: str) -> str:
    """``path`` relative to the working directory where it lies below it."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return path


def _differences(old: dict[str, Any], new: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two settings dicts."""
    keys = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            keys += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            keys.append(f"{prefix}{key}")
    return keys


@dataclass(frozen=True)
class ExperimentResult(Sequence[dict[str, Any]]):
    """What :func:`run_experiment` did; a sequence of its records (``list(result)``).

    ``records`` holds every record of the experiment (also those an earlier, resumed run
    wrote), sorted by seed and then in planner order; failed ones have ``"status": "failed"``.
    """

    out_dir: Path
    records: list[dict[str, Any]]
    ran: int  # episodes run by this call
    resumed: int  # episodes that were already on disk
    failed: int  # failed records among ``records``
    backend: str
    workers: int
    wall_time: float  # [s] of this call
    peak_worker_rss_mb: float  # [MiB] largest peak resident memory of a worker (nan if none ran)

    @overload
    def __getitem__(self, index: int) -> dict[str, Any]: ...

    @overload
    def __getitem__(self, index: slice) -> list[dict[str, Any]]: ...

    def __getitem__(self, index: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        """The record at ``index`` (a list of them for a slice)."""
        return self.records[index]

    def __len__(self) -> int:
        return len(self.records)


def run_experiment(out_dir: str | Path, seeds: Sequence[int], planners: Sequence[str] = ("cdf", "reactive"),
                   config: ScenarioConfig | None = None, cdf: CDFConfig | None = None,
                   scene: str | Path = DEFAULT_SCENE, progress: bool = True, *,
                   workers: int | None = None, backend: Backend = "process",
                   resume: bool = False, retry_failed: bool = False,
                   address: str | None = None,
                   planner_args: Mapping[str, Mapping[str, Any]] | None = None) -> ExperimentResult:
    """Run every planner on every seed; persist the records and return them.

    Args:
        out_dir: result directory (created): ``settings.json`` and ``episodes.jsonl``.
        seeds: a non-empty contiguous range of non-negative seeds.
        planners: registered planner names, run on the same seeds.
        config, cdf: scenario and CDF settings (defaults if ``None``); each planner takes
            what it shares of ``cdf`` (:func:`planner_factory`).
        scene: MJCF scene file.
        planner_args: per planner name, constructor arguments on top of those (e.g.
            ``{"imm": {"params": IMMConfig(threshold=0.9)}}``); kept in ``settings.json``.
        progress: a progress bar on stderr.
        workers: worker processes (default: the CPU count); 1 runs in this process.
        backend: ``process`` (default), ``serial`` or ``ray``.
        resume: continue a run in ``out_dir`` that was interrupted (same settings only).
        retry_failed: with ``resume``, run the failed episodes again (their records are
            replaced); without it they stay as recorded.
        address: with ``backend="ray"``, the address of an existing Ray cluster.

    Raises:
        ResultsExistError: ``out_dir`` holds results of this experiment and ``resume`` is
            False; nothing is run then.
        SettingsMismatchError: a directory holding results of other settings (a
            ValueError; the message names the differing keys); nothing is run then.
        ValueError: bad settings; nothing is run then.
        ImportError: ``backend="ray"`` without the ``ray`` extra.
        cdf_mj.experiments.runner.WorkerDiedError: a worker died; the finished seeds are saved.
    """
    t0 = time.perf_counter()
    config, cdf = config or ScenarioConfig(), cdf or CDFConfig()
    if isinstance(seeds, range) and seeds.step == 1 and seeds:  # its ends bound it: no loop over 10^7
        check_seed(seeds[0])
        check_seed(seeds[-1])
        seeds = list(seeds)
    else:  # True, 1.5 or 2^64 is refused, not truncated
        seeds = [check_seed(s) for s in seeds]
    if not seeds or seeds[0] < 0 or seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise ValueError("seeds must be a non-empty contiguous range of non-negative integers")
    planners = tuple(planners)
    if not planners or len(set(planners)) != len(planners):
        raise ValueError(f"planners must be distinct names, got {list(planners)}")
    n_workers = 1 if backend == "serial" else check_backend(backend, workers)
    unknown = sorted(set(planner_args or {}) - set(planners))
    if unknown:
        raise ValueError(f"planner_args names planners that do not run: {unknown}")
    factories = {name: bind_planner(name, cdf, (planner_args or {}).get(name)) for name in planners}
    for spec in factories.values():
        spec()  # arguments the planner does not take: TypeError before anything is written
    job = SeedJob(config=config, scene=str(scene), planners=planners, factories=dict(factories))
    if n_workers > 1 and backend == "process" and START_METHOD != "fork":
        try:  # spawned workers get the job pickled: refuse early what cannot be
            pickle.dumps(job)
        except Exception as exc:  # any pickling failure means the same
            raise ValueError(f"the planners cannot be sent to worker processes ({exc}); register "
                             "module-level planner classes, or run with workers=1") from None
    # A broken scene, or world options it cannot hold, is refused before anything is written.
    World(Scene.load(scene, names=config.names), config)

    out = Path(out_dir)
    settings = _settings(seeds, planners, config, cdf, scene, factories)
    settings_path, records_path = out / "settings.json", out / RECORDS_FILE
    out.mkdir(parents=True, exist_ok=True)
    with locked(out):  # a second run into this directory is refused here, before any check
        check_run_kind(out, "experiment")  # never over another command's settings.json
        _check_directory(out, settings, resume)
        # Whole or not at all, synced before and after the rename, never through a link.
        write_atomic(settings_path, json.dumps(settings, indent=2) + "\n")
        order = {name: i for i, name in enumerate(planners)}
        peaks: list[float] = []
        with RecordStore.open(records_path, drop_failed=resume and retry_failed,
                              seeds=range(seeds[0], seeds[-1] + 1), planners=planners) as store:
            done = store.done()
            resumed = len(done)
            todo = [(s, tuple(p for p in planners if (s, p) not in done)) for s in seeds]
            todo = [(s, ps) for s, ps in todo if ps]
            total = sum(len(ps) for _, ps in todo)
            with tqdm(total=total, unit="ep", disable=not progress, desc="episodes") as bar:
                try:
                    for result in run_seeds(job, todo, backend=backend, workers=workers, address=address):
                        store.append(result.records)
                        peaks.append(result.peak_rss_mb)
                        bar.update(len(result.records))
                except WorkerDiedError as exc:
                    raise WorkerDiedError(f"{exc}; {len(store.records)} episodes are saved in {records_path}, "
                                          "and a run with resume continues from there") from None
            records = sorted(store.records, key=lambda r: (r["seed"], order.get(r["planner"], len(order))))
    ran_on = effective_backend(backend, n_workers, len(todo))
    return ExperimentResult(out_dir=out, records=records, ran=total, resumed=resumed,
                            failed=sum(1 for r in records if r.get("status") == FAILED),
                            backend=ran_on, workers=worker_count(backend, n_workers, len(todo)),
                            wall_time=time.perf_counter() - t0,
                            peak_worker_rss_mb=max(peaks, default=float("nan")))


def _check_directory(out: Path, settings: dict[str, Any], resume: bool) -> None:
    """Refuse a directory whose results were made with other settings, results that
    cannot be checked, or results without ``resume`` (:class:`ResultsExistError`). An
    empty directory passes."""
    settings_path, records_path = out / "settings.json", out / RECORDS_FILE
    if not (records_path.exists() and records_path.stat().st_size > 0):
        return  # settings only matter where there are results made with them
    if not settings_path.exists():
        raise ValueError(f"{records_path} has no {settings_path.name} beside it, so its settings "
                         "cannot be checked: choose another directory")
    try:
        old = read_settings(settings_path)
    except ValueError as exc:
        raise ValueError(f"{exc}; {settings_path.name} is damaged: choose another directory") from None
    old_files: dict[str, str] = old.get("scene_files") or {}
    new_files: dict[str, str] = settings["scene_files"]
    if old.get("version") != settings["version"]:
        raise SettingsMismatchError(f"{out} holds results of cdf_mj {old.get('version') or '(version not recorded)'}, "
                                    f"and this is {settings['version']}: the records would mix two "
                                    "versions; choose another directory")
    if old.get("scene") == settings["scene"] and old_files != new_files:
        changed = sorted(set(old_files) ^ set(new_files)) + sorted(
            k for k in set(old_files) & set(new_files) if old_files[k] != new_files[k])
        raise SettingsMismatchError(f"the scene {_shown(changed[0]) if changed else settings['scene']} changed "
                                    f"since the run in {out} started: the records would mix two worlds; "
                                    "restore it, or choose another directory")
    old = {**old, "planner_args": stored_planner_arguments(old)}  # a run stored before they were kept
    diff = _differences(normalise_settings(old), json.loads(json.dumps(settings)))  # a run of 0.1 reads flat
    if diff:
        raise SettingsMismatchError(f"{out} holds results from other settings (differing: {', '.join(diff)}); "
                                    "choose another directory")
    if not resume:
        raise ResultsExistError(f"{out} already holds results of this experiment")
