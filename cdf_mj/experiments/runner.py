"""Running many seeds: serially, on a process pool or on Ray, with lossless persistence.

The unit of work is one **seed**: every planner of the experiment runs on it (common
random numbers), and the counterfactual that labels the seed runs once. A seed's records
depend on nothing but the seed and the settings, so any backend and any number of
workers give the same records; only the order in which seeds finish differs.

============  ===================================================================
backend       where the seeds run
============  ===================================================================
``serial``    in this process (``workers=1``)
``process``   a ``concurrent.futures`` process pool, one scene per worker (``fork`` on
              Linux, so scripts need no ``__main__`` guard and planners registered
              anywhere are inherited; ``spawn`` elsewhere)
``ray``       Ray actors (``pip install 'cdf-mj[ray]'``), one scene per actor; a local
              Ray instance, or an existing cluster with ``address``
============  ===================================================================

:class:`RecordStore` persists records: one JSON line per episode, appended as soon as a
seed finishes, flushed and ``fsync``-ed, so a run killed at any moment (``SIGKILL``
included) loses at most the seeds that were still running. :meth:`RecordStore.open`
reads what an earlier run left, dropping a half-written last line, so that the run can
resume without duplicating or missing an episode.

An episode that raises is recorded as a *failed* record (``"status": "failed"``, with its
seed, planner, error and traceback) and the run goes on. Successful records carry
``"status": "ok"``.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import threading
import traceback
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Literal

import numpy as np

from cdf_mj.config import ScenarioConfig

__all__ = ["SeedJob", "SeedResult", "RecordStore", "run_seeds", "Backend", "BACKENDS",
           "WorkerDiedError", "OK", "FAILED", "check_backend", "effective_backend",
           "START_METHOD", "locked", "json_default"]

Backend = Literal["serial", "process", "ray"]
BACKENDS: tuple[str, ...] = ("serial", "process", "ray")
OK, FAILED = "ok", "failed"


class WorkerDiedError(RuntimeError):
    """A worker process died (killed, out of memory); finished seeds are saved."""


@dataclass(frozen=True)
class SeedJob:
    """Everything a worker needs to run seeds; pickled once per worker.

    ``factories`` maps each planner name to a zero-argument callable returning a fresh
    :class:`~cdf_mj.planners.Planner`; it must be picklable (a module-level class or
    ``functools.partial`` of one) for the ``process`` and ``ray`` backends.
    """

    config: ScenarioConfig
    scene: str
    planners: tuple[str, ...]
    factories: dict[str, Callable]


@dataclass(frozen=True)
class SeedResult:
    """The records of one seed (one per planner, in the job's planner order)."""

    seed: int
    records: list[dict]
    peak_rss_mb: float  # [MiB] the worker's peak resident memory so far
    pid: int


def _peak_rss_mb() -> float:
    # ru_maxrss is KiB on Linux, bytes on macOS.
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024) if sys.platform == "darwin" else rss / 1024


def _failed(seed: int, planner: str, exc: BaseException) -> dict:
    return {"seed": seed, "planner": planner, "status": FAILED,
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))}


class SeedWorker:
    """Runs seeds of one job with one scene loaded once (one per process or Ray actor)."""

    def __init__(self, job: SeedJob) -> None:
        from cdf_mj.sim.scene import Scene

        self.job = job
        self.scene = Scene.load(job.scene, names=job.config.names)

    def run(self, seed: int, planners: Sequence[str] | None = None) -> SeedResult:
        """Every planner (or those named) on ``seed``; a planner that raises gives a failed record.

        The seed's label needs the constant-speed counterfactual. A planner that never
        braked *is* that run (same random streams, same controls), so it is simulated
        only when every planner braked, and then once for all of them.
        """
        from cdf_mj.scenario.episode import counterfactual, label_of, run_episode

        job = self.job
        records: list[dict] = []
        for name in planners or job.planners:
            try:
                rec = run_episode(job.config, seed, job.factories[name](), self.scene, label=False).to_dict()
            except Exception as exc:  # noqa: BLE001 - recorded with its traceback; the run goes on
                records.append(_failed(seed, name, exc))
                continue
            rec["planner"] = name  # the experiment's name for it, whatever the class calls itself
            rec["status"] = OK
            records.append(rec)
        done = [r for r in records if r["status"] == OK]
        if done:
            hit = next((r["collision_with"] == "obstacle" for r in done if r["brake_time"] is None), None)
            try:
                label, hit = (label_of(done[0]["intent"], hit), hit) if hit is not None else \
                    counterfactual(job.config, seed, self.scene)
            except Exception as exc:  # noqa: BLE001 - without a label no record of this seed is usable
                records = [_failed(seed, r["planner"], exc) if r["status"] == OK else r for r in records]
            else:
                for r in done:
                    r["label"], r["counterfactual_collision"] = label, hit
        return SeedResult(seed, records, _peak_rss_mb(), os.getpid())


# ----------------------------------------------------------------- process pool
#: How worker processes start. ``fork`` (Linux) inherits the parent's imports and planner
#: registry and needs no ``if __name__ == "__main__"`` guard in a user's script; ``spawn``
#: (macOS, Windows, where forking a process with system frameworks loaded is unsafe)
#: needs both, and pickles the job.
START_METHOD = "fork" if sys.platform.startswith("linux") else "spawn"

_WORKER: SeedWorker | None = None


def _die_with_parent(parent: int) -> None:
    """Linux: make this worker receive SIGTERM when its parent dies (killed with SIGKILL
    included), so that a killed run leaves no orphaned workers. Elsewhere: nothing."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def _init_process(job: SeedJob, parent: int, die_with_parent: bool) -> None:
    global _WORKER
    if die_with_parent:
        _die_with_parent(parent)
    _WORKER = SeedWorker(job)


def _run_in_process(seed: int, planners: tuple[str, ...] | None) -> SeedResult:
    assert _WORKER is not None, "worker not initialised"
    return _WORKER.run(seed, planners)


def _serial(job: SeedJob, todo: Sequence[tuple[int, tuple[str, ...]]], workers: int,
            address: str | None) -> Iterator[SeedResult]:
    worker = SeedWorker(job)
    for seed, planners in todo:
        yield worker.run(seed, planners)


def _process_pool(job: SeedJob, todo: Sequence[tuple[int, tuple[str, ...]]], workers: int,
                  address: str | None) -> Iterator[SeedResult]:
    # At most 2 seeds in flight per worker keeps memory flat and cancellation prompt.
    ctx = get_context(START_METHOD)
    pending: set = set()
    queue = list(todo)[::-1]
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_process,
                             # The death signal follows the thread that forks the workers:
                             # only the main thread lives as long as the process.
                             initargs=(job, os.getpid(),
                                       threading.current_thread() is threading.main_thread())) as pool:
        try:
            while queue or pending:
                while queue and len(pending) < 2 * workers:
                    seed, planners = queue.pop()
                    pending.add(pool.submit(_run_in_process, seed, planners))
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                broken = None
                for fut in done:  # every finished seed is handed over before a death is reported
                    try:
                        result = fut.result()
                    except BrokenProcessPool as exc:
                        broken = exc
                        continue
                    yield result
                if broken is not None:
                    raise broken
        except BrokenProcessPool as exc:
            raise WorkerDiedError(f"a worker process died ({exc})") from None
        finally:
            for fut in pending:
                fut.cancel()


def _ray(job: SeedJob, todo: Sequence[tuple[int, tuple[str, ...]]], workers: int,
         address: str | None) -> Iterator[SeedResult]:
    try:
        import ray
        from ray.util import ActorPool
    except ImportError:
        raise ValueError("--backend ray needs Ray: pip install 'cdf-mj[ray]'") from None
    started = not ray.is_initialized()
    if started:
        kwargs = {"address": address} if address else {"num_cpus": workers}
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kwargs)
    try:
        actor = ray.remote(num_cpus=1)(SeedWorker)
        # One CPU per actor: more actors than the cluster has CPUs would never start and
        # the pool would wait for them for ever.
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        n_actors = min(workers, cpus) if workers else cpus
        pool = ActorPool([actor.remote(job) for _ in range(n_actors)])
        for seed, planners in todo:
            pool.submit(lambda a, item: a.run.remote(*item), (seed, planners))
        while pool.has_next():
            try:
                yield pool.get_next_unordered()
            except ray.exceptions.RayActorError as exc:
                raise WorkerDiedError(f"a Ray actor died ({exc})") from None
    finally:
        if started:
            ray.shutdown()


_BACKENDS: dict[str, Callable[..., Iterator[SeedResult]]] = {
    "serial": _serial, "process": _process_pool, "ray": _ray}


def run_seeds(job: SeedJob, todo: Sequence[tuple[int, tuple[str, ...]]], backend: Backend = "process",
              workers: int | None = None, address: str | None = None) -> Iterator[SeedResult]:
    """Yield one :class:`SeedResult` per ``(seed, planners)`` item, in completion order.

    ``workers`` defaults to the CPU count (with Ray and an ``address``: one actor per CPU
    of the cluster); ``backend="process"`` with one worker, or fewer than two seeds, runs
    in this process. Raises :class:`WorkerDiedError` if a
    worker dies; seeds already yielded are unaffected.
    """
    cluster_default = backend == "ray" and address is not None and workers is None
    workers = check_backend(backend, workers)
    backend = effective_backend(backend, workers, len(todo))
    if cluster_default:
        workers = 0  # one actor per CPU of the cluster
    return _BACKENDS[backend](job, todo, min(workers, max(1, len(todo))), address)


def effective_backend(backend: str, workers: int, n_items: int) -> str:
    """Where ``n_items`` seeds on ``workers`` really run: a process pool of one worker,
    or for fewer than two seeds, is this process (``serial``)."""
    if backend == "process" and (workers == 1 or n_items < 2):
        return "serial"
    return backend


def check_backend(backend: str, workers: int | None) -> int:
    """The worker count (default: the CPU count); ValueError for a bad backend or count."""
    if backend not in _BACKENDS:
        raise ValueError(f"unknown backend {backend!r}: choose one of {', '.join(BACKENDS)}")
    workers = workers if workers is not None else (os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers={workers!r} must be a positive integer")
    return workers


# ----------------------------------------------------------------- persistence
def json_default(obj: object) -> object:
    """NumPy values in records (planner summaries, traces) as plain JSON; TypeError otherwise."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


@contextmanager
def locked(directory: str | Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``directory`` (which must exist) for the block, so
    that a second run into the same directory is refused (ValueError, at once) instead
    of writing the same episodes twice. The lock goes when the block ends or every
    process holding it has exited, however it ended. No lock where ``fcntl`` does not
    exist (Windows)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ValueError(f"{directory} is in use by another run: wait for it to finish, "
                             "or choose another directory") from None
        yield
    finally:
        os.close(fd)


class RecordStore:
    """Append-only JSON lines of episode records: every seed is flushed and ``fsync``-ed.

    Use :meth:`open`; the store is a context manager that closes the file.
    """

    def __init__(self, path: Path, records: list[dict], fh) -> None:
        self.path = path
        self.records = records  # everything on disk, in file order
        self._fh = fh

    @classmethod
    def open(cls, path: str | Path, drop_failed: bool = False) -> RecordStore:
        """Open ``path`` for appending, reading the records already there.

        A last line cut short by a killed run is dropped (truncated from the file); any
        other line that is not a JSON object is an error naming its line number. With
        ``drop_failed``, failed records are removed from the file (rewritten atomically)
        so that their episodes run again. Writers of one file must not overlap: hold
        :func:`locked` on its directory.
        """
        path = Path(path)
        records: list[dict] = []
        if path.exists():
            data = path.read_bytes()
            end = data.rfind(b"\n") + 1  # everything after the last newline is a partial line
            for number, line in enumerate(data[:end].splitlines(), start=1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                except ValueError:
                    rec = None
                if not isinstance(rec, dict) or "seed" not in rec or "planner" not in rec:
                    raise ValueError(f"{path}:{number} is not an episode record; "
                                     "the file is damaged: move it away or choose another directory")
                records.append(rec)
            if end < len(data):
                with open(path, "r+b") as fh:
                    fh.truncate(end)
                    fh.flush()
                    os.fsync(fh.fileno())
        if drop_failed and any(r.get("status") == FAILED for r in records):
            records = [r for r in records if r.get("status") != FAILED]
            tmp = path.with_name(path.name + ".tmp")
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write("".join(json.dumps(r, allow_nan=False) + "\n" for r in records))
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        fh = open(path, "a", encoding="utf-8")  # noqa: SIM115 - closed by close() / __exit__
        return cls(path, records, fh)

    def done(self) -> set[tuple[int, str]]:
        """``(seed, planner)`` pairs already recorded (failed ones included)."""
        return {(int(r["seed"]), str(r["planner"])) for r in self.records}

    def append(self, records: Iterable[dict]) -> None:
        """Write records as one block, then flush and fsync (one seed per call).

        NumPy values are written as plain JSON (:func:`json_default`); a record JSON cannot
        hold (a NaN, an object) is stored as a failed record of its seed and planner
        instead, so that one planner's odd summary never stops the run."""
        kept, lines = [], []
        for rec in records:
            try:
                line = json.dumps(rec, allow_nan=False, default=json_default)
            except (TypeError, ValueError) as exc:
                rec = {"seed": rec.get("seed"), "planner": rec.get("planner"), "status": FAILED,
                       "error": f"the record is not JSON-serialisable: {exc}", "traceback": ""}
                line = json.dumps(rec)
            kept.append(rec)
            lines.append(line + "\n")
        if not lines:
            return
        self._fh.write("".join(lines))
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.records.extend(kept)

    def close(self) -> None:
        """Close the file."""
        self._fh.close()

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

