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
``ray``       Ray actors (the ``ray`` extra), one scene per actor; a local Ray
              instance, or an existing cluster with ``address``
============  ===================================================================

An episode that raises is recorded as a *failed* record (``"status": "failed"``, with its
seed, planner, error and traceback) and the run goes on; a planner that calls
``sys.exit()`` (raises ``SystemExit``) is a failed episode too, not the end of the run. Only
``KeyboardInterrupt`` (Ctrl-C) stops the run. Successful records carry
``"status": "ok"``. The records are persisted by :mod:`cdf_mj.experiments.store`.

A process pool's workers ignore ``SIGINT`` while they wait for work and take it only while
they run a seed, so Ctrl-C (sent to the whole process group) stops the seeds in flight and
reaches the caller as one ``KeyboardInterrupt``, without a traceback from each idle worker.
A pool never starts more workers than the seeds it is given (:func:`worker_count`; a
:class:`SeedPool` grows up to its ``workers`` as larger batches come).
"""

from __future__ import annotations

import os
import resource
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context
from typing import TYPE_CHECKING, Any, Literal

from cdf_mj.config import ScenarioConfig
from cdf_mj.extras import require
from cdf_mj.records import FAILED, OK

if TYPE_CHECKING:
    from cdf_mj.planners.base import Planner

__all__ = ["BACKENDS", "RAY_ANSWER_TIMEOUT_S", "RAY_CONNECT_TIMEOUT_S", "START_METHOD", "Backend",
           "ClusterUnreachableError", "SeedJob", "SeedPool", "SeedResult", "WorkItem", "WorkerDiedError",
           "check_backend", "effective_backend", "run_seeds", "worker_count"]

Backend = Literal["serial", "process", "ray"]
BACKENDS: tuple[str, ...] = ("serial", "process", "ray")


class WorkerDiedError(RuntimeError):
    """A worker process died (killed, out of memory); finished seeds are saved."""


class ClusterUnreachableError(ConnectionError):
    """No Ray cluster answers at the ``address`` given (an OSError); no seed was run."""


#: [s] How long the ``ray`` backend waits for the cluster at ``address`` to accept a
#: connection and answer a gRPC greeting before it gives up with
#: :class:`ClusterUnreachableError` (instead of Ray's own retrying, which goes on for minutes
#: when nothing, or something other than Ray, listens there).
RAY_CONNECT_TIMEOUT_S = 10.0
#: [s] Of that, how long it waits for the answer to its gRPC greeting once connected: a Ray
#: cluster answers at once (a round trip), so a server silent this long is not one.
RAY_ANSWER_TIMEOUT_S = 5.0


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
    factories: dict[str, Callable[[], Planner]]


@dataclass(frozen=True)
class SeedResult:
    """The records of one seed (one per planner, in the job's planner order)."""

    seed: int
    records: list[dict[str, Any]]
    peak_rss_mb: float  # [MiB] the worker's peak resident memory so far
    pid: int


def _peak_rss_mb() -> float:
    # ru_maxrss is KiB on Linux, bytes on macOS.
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / (1024 * 1024) if sys.platform == "darwin" else rss / 1024


def _failed(seed: int, planner: str, exc: BaseException) -> dict[str, Any]:
    return {"seed": seed, "planner": planner, "status": FAILED,
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))}


class SeedWorker:
    """Runs seeds of one job with one scene loaded once (one per process or Ray actor)."""

    def __init__(self, job: SeedJob) -> None:
        from cdf_mj.sim.scene import Scene

        self.job = job
        self.scene = Scene.load(job.scene, names=job.config.names)

    def run(self, seed: int, planners: Sequence[str] | None = None,
            config: ScenarioConfig | None = None) -> SeedResult:
        """Every planner (or those named) on ``seed``; a planner that raises gives a failed record.

        ``config``: this seed's world instead of the job's (a search's candidate; the scene
        and its names stay the job's). The seed's label comes from
        :func:`cdf_mj.scenario.episode.seed_label` over all the seed's runs: the
        counterfactual is simulated only when every planner braked, and then once for all
        of them.
        """
        from cdf_mj.scenario.episode import run_episode, seed_label

        job = self.job
        world = job.config if config is None else config
        records: list[dict[str, Any]] = []
        for name in planners or job.planners:
            try:
                rec = run_episode(world, seed, job.factories[name](), self.scene, label=False).to_dict()
            except (Exception, SystemExit) as exc:  # recorded with its traceback; the run goes on
                records.append(_failed(seed, name, exc))
                continue
            rec["planner"] = name  # the experiment's name for it, whatever the class calls itself
            rec["status"] = OK
            records.append(rec)
        done = [r for r in records if r["status"] == OK]
        if done:
            try:
                label, hit = seed_label(world, seed, self.scene,
                                        [(r["intent"], r["counterfactual_collision"]) for r in done])
            except (Exception, SystemExit) as exc:  # without a label no record of this seed is usable
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
    # Ctrl-C goes to the whole process group: an idle worker, waiting for its next seed,
    # would print a traceback of its own and die. It takes SIGINT only while it runs one.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if die_with_parent:
        _die_with_parent(parent)
    _WORKER = SeedWorker(job)


#: One unit of work: ``(seed, planners)``, or ``(seed, planners, config)`` to run that
#: seed in a world of its own (:meth:`SeedWorker.run`).
WorkItem = tuple[int, tuple[str, ...]] | tuple[int, tuple[str, ...], ScenarioConfig | None]


def _run_in_process(*item: Any) -> SeedResult:
    assert _WORKER is not None, "worker not initialised"
    signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C stops this seed: sent back as its result
    try:
        return _WORKER.run(*item)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Serial:
    """Seeds run in this process, one scene loaded once."""

    def __init__(self, job: SeedJob, workers: int, address: str | None) -> None:
        self.worker = SeedWorker(job)

    def run(self, todo: Sequence[WorkItem]) -> Iterator[SeedResult]:
        for item in todo:
            yield self.worker.run(*item)

    def close(self) -> None:
        pass


class _Processes:
    """A ``concurrent.futures`` process pool, one scene per worker, kept until :meth:`close`."""

    def __init__(self, job: SeedJob, workers: int, address: str | None) -> None:
        self.workers = workers
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context(START_METHOD),
                                        initializer=_init_process,
                                        # The death signal follows the thread that forks the workers:
                                        # only the main thread lives as long as the process.
                                        initargs=(job, os.getpid(),
                                                  threading.current_thread() is threading.main_thread()))

    def run(self, todo: Sequence[WorkItem]) -> Iterator[SeedResult]:
        # At most 2 seeds in flight per worker keeps memory flat and cancellation prompt.
        pending: set[Future[SeedResult]] = set()
        queue = list(todo)[::-1]
        try:
            while queue or pending:
                while queue and len(pending) < 2 * self.workers:
                    pending.add(self.pool.submit(_run_in_process, *queue.pop()))
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

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


#: What a client sends first on an HTTP/2 connection (RFC 9113, 3.4): the preface, then an
#: empty SETTINGS frame (length 0, type 4, no flags, stream 0).
_H2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _h2_answer(sock: socket.socket, seconds: float) -> str | None:
    """Greet the server on ``sock`` as an HTTP/2 (gRPC) client and read its first 9 bytes
    for at most ``seconds``: None if they open a SETTINGS frame on stream 0, the server
    preface that every gRPC server (Ray's GCS and its client server among them) sends first;
    else what it did instead, in words."""
    deadline = time.monotonic() + seconds
    sock.sendall(_H2_HELLO)
    head = b""
    while len(head) < 9:
        sock.settimeout(max(deadline - time.monotonic(), 1e-3))
        try:
            chunk = sock.recv(9 - len(head))
        except TimeoutError:
            return f"it said nothing within {seconds:g} s" if not head else f"it sent {head!r} and stopped"
        if not chunk:
            return "it closed the connection" if not head else f"it sent {head!r} and closed the connection"
        head += chunk
    length, kind, stream = int.from_bytes(head[:3], "big"), head[3], int.from_bytes(head[5:9], "big") & 0x7FFFFFFF
    if kind == 4 and stream == 0 and length % 6 == 0:
        return None
    if head.startswith(b"HTTP/"):
        return ("it answers as a web server (HTTP/1): Ray's dashboard? The cluster's address is its GCS "
                "port (6379 by default), as `ray start --head` prints it")
    return f"it answers {head!r}, not gRPC"


def _probe_ray_address(address: str, timeout: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """:class:`ClusterUnreachableError` (one line) unless a Ray cluster may answer at ``address``
    (``host:port`` or ``ray://host:port``) within ``timeout`` seconds: a TCP connection opens,
    and the server answers an HTTP/2 greeting as every gRPC server does (Ray's GCS and its
    client server speak gRPC; a silent port, a web server, Redis or SSH do not, and Ray
    itself would retry against them for minutes). With ``RAY_USE_TLS`` set (TLS, which this
    probe does not speak) only the connection is checked. An address without a port
    (``auto``, ``local``) is left to Ray."""
    scheme, sep, rest = address.strip().partition("://")
    host, colon, port_text = (rest if sep else scheme).rpartition(":")
    if not colon:
        return
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 < port < 65536:
        raise ClusterUnreachableError(f"Ray address {address!r}: the port must be a number from 1 to 65535; "
                                      "give host:port, e.g. 127.0.0.1:6379")
    deadline = time.monotonic() + timeout
    tls = os.environ.get("RAY_USE_TLS", "0").strip().lower() in ("1", "true")
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            why = None if tls else _h2_answer(sock, max(min(deadline - time.monotonic(), RAY_ANSWER_TIMEOUT_S), 0.1))
    except OSError as exc:
        why = exc.strerror or str(exc) or type(exc).__name__
        raise ClusterUnreachableError(f"no Ray cluster answers at {address} within {timeout:g} s ({why}); start "
                                      "one there (ray start --head), or leave out the address to run a "
                                      "local Ray instance") from None
    if why is not None:
        raise ClusterUnreachableError(f"no Ray cluster answers at {address}: something listens there, but {why} "
                                      "to a gRPC greeting, which a Ray cluster answers at once; check the "
                                      "address (ray start --head prints it)")


class _Ray:
    """Ray actors, one scene each, kept until :meth:`close` (which shuts down a Ray instance
    it started)."""

    def __init__(self, job: SeedJob, workers: int, address: str | None) -> None:
        self.ray = ray = require("ray", "ray", "the ray backend")
        self.started = not ray.is_initialized()
        if self.started:
            kwargs = {"address": address} if address else {"num_cpus": workers}
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kwargs)
        try:
            actor = ray.remote(num_cpus=1)(SeedWorker)
            # One CPU per actor: more actors than the cluster has CPUs would never start and
            # the pool would wait for them for ever.
            cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
            n_actors = min(workers, cpus) if workers else cpus
            self.actors = [actor.remote(job) for _ in range(n_actors)]
        except BaseException:
            self.close()
            raise

    def run(self, todo: Sequence[WorkItem]) -> Iterator[SeedResult]:
        from ray.util import ActorPool

        pool = ActorPool(self.actors)
        for item in todo:
            pool.submit(lambda a, item: a.run.remote(*item), item)
        while pool.has_next():
            try:
                yield pool.get_next_unordered()
            except self.ray.exceptions.RayActorError as exc:
                raise WorkerDiedError(f"a Ray actor died ({exc})") from None

    def close(self) -> None:
        if self.started:
            self.ray.shutdown()
            self.started = False


_BACKENDS: dict[str, Callable[[SeedJob, int, str | None], _Serial | _Processes | _Ray]] = {
    "serial": _Serial, "process": _Processes, "ray": _Ray}


def _once(kind: str, job: SeedJob, todo: Sequence[WorkItem], workers: int, address: str | None
          ) -> Iterator[SeedResult]:
    """Start ``kind``'s workers (on the first result asked for), run ``todo``, stop them."""
    backend = _BACKENDS[kind](job, workers, address)
    try:
        yield from backend.run(todo)
    finally:
        backend.close()


class SeedPool:
    """Workers kept up across runs, for a caller that runs seeds in many small batches (a
    search's generations): :meth:`run` is :func:`run_seeds` without starting a process
    pool or Ray each time (about half a second a start for a pool of 2 on this project's
    machine). Started on the first run; :meth:`close` (or the ``with`` block's end) stops
    them. The same backends, worker counts and errors as :func:`run_seeds`; a process pool
    of one worker is this process. ::

        with SeedPool(job, workers=4) as pool:
            for batch in batches:
                results = list(pool.run(batch))
    """

    def __init__(self, job: SeedJob, backend: Backend = "process", workers: int | None = None,
                 address: str | None = None) -> None:
        cluster_default = backend == "ray" and address is not None and workers is None
        n = check_backend(backend, workers)
        self._kind = backend
        self._where = effective_backend(backend, n, 2)
        if self._where == "ray" and address is not None:
            require("ray", "ray", "the ray backend")
            _probe_ray_address(address)
        self._job, self._n, self._address = job, (0 if cluster_default else n), address
        self._backend: _Serial | _Processes | _Ray | None = None
        self._size = 0  # workers of the running process pool (1: this process)

    def run(self, todo: Sequence[WorkItem]) -> Iterator[SeedResult]:
        """One :class:`SeedResult` per item, in completion order. A process pool has at
        most one worker per item of the largest batch so far (``workers=1024`` on 4 seeds
        starts 4): one started for a smaller batch is replaced by a larger one when a
        larger batch comes, up to ``workers``."""
        if not todo:
            return iter(())
        if self._where == "process":
            want = worker_count(self._kind, self._n, len(todo))
            if self._backend is not None and want > self._size:
                self.close()  # a larger batch than the pool was started for
            if self._backend is None:
                where = effective_backend(self._kind, want, len(todo))
                self._backend = _BACKENDS[where](self._job, want, self._address)
                self._size = want
        elif self._backend is None:
            self._backend = _BACKENDS[self._where](self._job, self._n, self._address)
        return self._backend.run(todo)

    def close(self) -> None:
        """Stop the workers (nothing if none started); a later :meth:`run` starts them again."""
        if self._backend is not None:
            backend, self._backend = self._backend, None
            backend.close()

    def __enter__(self) -> SeedPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_seeds(job: SeedJob, todo: Sequence[WorkItem], backend: Backend = "process",
              workers: int | None = None, address: str | None = None) -> Iterator[SeedResult]:
    """Yield one :class:`SeedResult` per ``(seed, planners)`` item, in completion order (an
    item ``(seed, planners, config)`` runs in its own world, as a search's candidates do).

    ``workers`` defaults to the CPU count (with Ray and an ``address``: one actor per CPU
    of the cluster); ``backend="process"`` with one worker, or fewer than two seeds, runs
    in this process. Raises :class:`WorkerDiedError` if a
    worker dies; seeds already yielded are unaffected. With ``backend="ray"`` and an
    ``address``, raises :class:`ClusterUnreachableError` at once (before any seed runs) if
    nothing accepts a connection there, or what does is not a gRPC server (a Ray cluster's
    GCS is one), within :data:`RAY_CONNECT_TIMEOUT_S`.
    """
    cluster_default = backend == "ray" and address is not None and workers is None
    workers = check_backend(backend, workers)
    where = effective_backend(backend, workers, len(todo))
    if where == "ray" and address is not None:
        require("ray", "ray", "the ray backend")  # a missing extra is told first
        _probe_ray_address(address)
    n = 0 if cluster_default else worker_count(backend, workers, len(todo))  # 0: one actor per cluster CPU
    return _once(where, job, todo, n, address)


def worker_count(backend: str, workers: int, n_items: int) -> int:
    """How many workers really run ``n_items`` seeds when ``workers`` are asked for: one in
    this process (see :func:`effective_backend`), else at most one per seed (``workers=10**6``
    on 3 seeds is 3)."""
    if effective_backend(backend, workers, n_items) == "serial":
        return 1
    return min(workers, max(1, n_items))


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
