"""Running a search's episodes: points of a :class:`~cdf_mj.falsify.space.SearchSpace`
with their seeds, on any planner, through the experiment runner (serial, process pool or
Ray), every result appended to a journal as it arrives.

The journal (``evaluations.jsonl`` in the run's directory) is the run's memory: one JSON
line per episode, flushed and ``fsync``-ed, keyed by planner, seed, point and the options
kept at their defaults. :meth:`Evaluator.evaluate` runs only what the journal lacks, so a
run killed at any moment (``SIGKILL`` included) and started again with the same command
repeats no finished episode and loses at most those in flight; the search, the
minimisation and the estimators replay their own decisions from the journal's numbers.
A last line cut short by the kill is dropped; any other damaged line is one error naming
the file and the line: a line that is not JSON or is nested too deeply (read by
:func:`cdf_mj.inputs.parse_json`), a field of the wrong type, a robustness that is not
finite (the writer never writes one), a ``failed`` that does not follow from the
robustness, or a key recorded again with another outcome. The journal is opened without
following a link and only if it is a regular file, as an experiment's records file is.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from cdf_mj.config import MAX_SEED
from cdf_mj.experiments.runner import Backend, SeedJob, SeedPool
from cdf_mj.falsify.space import SearchSpace
from cdf_mj.falsify.space_check import check_joint, check_on_scene
from cdf_mj.inputs import RECORDS_MAX_BYTES, InputError, parse_json, read_regular
from cdf_mj.planners.registry import bind_planner
from cdf_mj.records import OK
from cdf_mj.records.files import open_no_follow
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["JOURNAL_FILE", "Evaluation", "Evaluator", "Journal", "episode_seed", "key_of"]

#: The journal's name in a run's directory.
JOURNAL_FILE = "evaluations.jsonl"
#: What a record's summary keeps (the rest of a record is for experiments).
_SUMMARY = ("intent", "label", "collision", "collision_with", "collision_time", "min_gap", "brake_time",
            "entered_lane_time", "end_time", "time_lost")
#: The robustness the search is given for an episode that raised (a bug, reported): far
#: from failure, so that the search moves away.
ERROR_ROBUSTNESS = 1e3


def episode_seed(run_seed: int, index: int, stream: int = 0) -> int:
    """The episode seed of item ``index`` of a run seeded ``run_seed`` (``stream`` keeps a
    run's stages apart): 53 bits of a SeedSequence, so distinct items get unrelated seeds."""
    state = np.random.SeedSequence([int(run_seed), int(stream), int(index)]).generate_state(2, np.uint32)
    return int((int(state[0]) << 21) ^ int(state[1])) & MAX_SEED


@dataclass(frozen=True)
class Evaluation:
    """One episode of a point: its robustness [m or s] (<= 0 fails) and its record's summary."""

    planner: str
    seed: int
    point: tuple[float, ...]
    keep: tuple[str, ...]
    robustness: float
    failed: bool
    summary: dict[str, Any]
    error: str | None = None  # the episode raised: its error (robustness is ERROR_ROBUSTNESS)

    def to_dict(self) -> dict[str, Any]:
        return {"key": key_of(self.planner, self.seed, self.point, self.keep), "planner": self.planner,
                "seed": self.seed, "point": list(self.point), "keep": list(self.keep),
                "robustness": self.robustness, "failed": self.failed, "summary": self.summary,
                "error": self.error}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Evaluation:
        """The evaluation of a journal line (:meth:`to_dict`), checked: ValueError (or
        KeyError, TypeError) saying which field is wrong."""
        if not isinstance(data, dict):
            raise TypeError(f"a JSON object expected, got {type(data).__name__}")
        planner, seed, point, keep = data["planner"], data["seed"], data["point"], data["keep"]
        robustness, failed, summary, error = data["robustness"], data["failed"], data["summary"], data.get("error")
        if not isinstance(planner, str):
            raise TypeError("'planner' is not a string")
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            raise ValueError(f"'seed' is not an integer from 0 to {MAX_SEED}")
        if not (isinstance(point, list) and all(_number(x) and math.isfinite(x) for x in point)):
            raise ValueError("'point' is not a list of finite numbers")
        if not (isinstance(keep, list) and all(isinstance(k, str) for k in keep)):
            raise TypeError("'keep' is not a list of option keys")
        if not (_number(robustness) and math.isfinite(robustness)):
            raise ValueError(f"its robustness {robustness!r} is not a finite number (the journal's writer "
                             "never writes one)")
        if not isinstance(failed, bool):
            raise TypeError("'failed' is not true or false")
        if not (error is None or isinstance(error, str)) or not isinstance(summary, dict):
            raise TypeError("'error' is not a string or null, or 'summary' not an object")
        if error is not None and (failed or robustness != ERROR_ROBUSTNESS):
            raise ValueError(f"an episode that raised has robustness {ERROR_ROBUSTNESS:g} and did not fail, got "
                             f"robustness {robustness!r} and failed {failed}")
        if error is None and failed != (robustness <= 0.0):
            raise ValueError(f"'failed' is {'true' if failed else 'false'} for robustness {robustness!r} (an episode "
                             "fails where its robustness is <= 0)")
        return cls(planner=planner, seed=seed, point=tuple(float(x) for x in point), keep=tuple(keep),
                   robustness=float(robustness), failed=failed, summary=summary, error=error)


def _number(value: object) -> bool:
    """Whether ``value`` is a JSON number (an int or a float, not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def key_of(planner: str, seed: int, point: Sequence[float], keep: Sequence[str] = ()) -> str:
    """The journal's key of an episode (floats exactly, as JSON writes them)."""
    return json.dumps([planner, int(seed), [float(x) for x in point], sorted(keep)])


class Journal:
    """The append-only journal of a run's episodes (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.entries: dict[str, Evaluation] = {}
        # Never through a link, never a FIFO or a device: refused before anything is read or written.
        fd = open_no_follow(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT, "journal")
        try:
            self._read(fd)
            self._fh: IO[str] = os.fdopen(fd, "a", encoding="utf-8")
        except BaseException:
            os.close(fd)
            raise

    def _read(self, fd: int) -> None:
        raw = read_regular(self.path, "journal", RECORDS_MAX_BYTES)
        complete = raw.rfind(b"\n") + 1
        first: dict[str, int] = {}  # key -> the line it was first recorded on
        for number, line in enumerate(raw[:complete].splitlines(), 1):
            if not line.strip():
                continue
            try:
                data = parse_json(line, f"{self.path}: line {number}")
                ev = Evaluation.from_dict(data)
                if data.get("key") != key_of(ev.planner, ev.seed, ev.point, ev.keep):
                    raise ValueError("its key does not match its contents")
            except (ValueError, KeyError, TypeError) as exc:  # JSONDecodeError, UnicodeDecodeError, InputError
                why = ("nested too deeply" if isinstance(exc, InputError) else
                       "not UTF-8 text" if isinstance(exc, UnicodeDecodeError) else
                       f"no {exc}" if isinstance(exc, KeyError) else " ".join(str(exc).split())[:200])
                raise ValueError(f"{self.path}: line {number} is not an evaluation ({why}); the file is damaged: "
                                 "move it away or choose another directory") from None
            key = data["key"]
            if key in self.entries and self.entries[key] != ev:
                raise ValueError(f"{self.path}: line {number} records an episode of line {first[key]} again with "
                                 "another outcome (each episode has one); the file is damaged: move it away or "
                                 "choose another directory")
            first.setdefault(key, number)
            self.entries[key] = ev
        if complete < len(raw):  # a line cut short by a killed run
            os.ftruncate(fd, complete)
            os.fsync(fd)

    def get(self, planner: str, seed: int, point: Sequence[float], keep: Sequence[str] = ()) -> Evaluation | None:
        return self.entries.get(key_of(planner, seed, point, keep))

    def append(self, evaluations: Iterable[Evaluation]) -> None:
        lines = []
        for ev in evaluations:
            self.entries[key_of(ev.planner, ev.seed, ev.point, ev.keep)] = ev
            lines.append(json.dumps(ev.to_dict(), allow_nan=False) + "\n")
        if lines:
            self._fh.write("".join(lines))
            self._fh.flush()
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


def _summary(record: dict[str, Any]) -> dict[str, Any]:
    out = {k: record.get(k) for k in _SUMMARY}
    safety = record.get("safety") or {}
    out["min_ttc"], out["min_headway"] = safety.get("min_ttc"), safety.get("min_headway")
    return out


def _finite(value: float) -> float:
    return value if math.isfinite(value) else ERROR_ROBUSTNESS


class Evaluator:
    """Runs points of ``space`` on planners, each episode once (see the module docstring).

    ``workers``/``backend``/``address`` as :func:`cdf_mj.experiments.runner.run_seeds`, the
    workers kept up between calls (:class:`~cdf_mj.experiments.runner.SeedPool`; close the
    evaluator, or use it in a ``with`` block, to stop them);
    ``on_episode`` is called with the count of episodes each call settles, run or found in
    the journal (for a progress bar). :attr:`errors` keeps every episode asked for that
    raised (the caller reports them and exits 1). The space is checked as a whole on the
    scene first (:mod:`cdf_mj.falsify.space_check`): SpaceError naming the file and the
    dimensions, before any episode.
    """

    def __init__(self, space: SearchSpace, planners: Sequence[str], journal: Journal, *,
                 scene: str | Path = DEFAULT_SCENE, backend: Backend = "process", workers: int | None = None,
                 address: str | None = None, on_episode: Callable[[int], None] | None = None) -> None:
        # The space as a whole, on this scene, before any episode (SpaceError naming the file
        # and the dimensions): values the world refuses together or on this scene.
        check_joint(space)
        check_on_scene(space, Scene.load(scene, names=space.base.names))
        self.space = space
        self.journal = journal
        self.job = SeedJob(config=space.base, scene=str(scene), planners=tuple(planners),
                           factories={name: bind_planner(name) for name in planners})
        # The workers stay up from one batch to the next (a search's generation is a dozen
        # episodes); started on the first batch the journal lacks, stopped by close().
        self.pool = SeedPool(self.job, backend, workers, address)
        self.on_episode = on_episode
        self.episodes_run = 0  # this process's, not the journal's
        self.errors: dict[str, Evaluation] = {}  # journal key -> an episode that raised

    def evaluate(self, items: Sequence[tuple[Sequence[float], int]], planners: Sequence[str],
                 keep: Sequence[Sequence[str]] | None = None) -> list[dict[str, Evaluation]]:
        """For each ``(point, seed)`` item, planner -> its :class:`Evaluation` (``keep[i]``:
        the options item ``i`` leaves at the base's values). Runs what the journal lacks,
        several items at once; an item's seed must not repeat within one call."""
        keeps = [tuple(sorted(k)) for k in keep] if keep is not None else [()] * len(items)
        points = [tuple(float(x) for x in p) for p, _ in items]
        seeds = [int(s) for _, s in items]
        if len(set(seeds)) != len(seeds):
            raise ValueError("Evaluator.evaluate: each item of one call needs its own seed")
        todo, found = [], 0
        for point, seed, kept in zip(points, seeds, keeps, strict=True):
            missing = tuple(p for p in planners if self.journal.get(p, seed, point, kept) is None)
            found += len(planners) - len(missing)
            if missing:
                todo.append((seed, missing, self.space.config(point, kept)))
        if found and self.on_episode is not None:
            self.on_episode(found)
        where = {seed: (point, kept) for point, seed, kept in zip(points, seeds, keeps, strict=True)}
        if todo:
            for result in self.pool.run(todo):
                point, kept = where[result.seed]
                new = [self._evaluation(rec, point, kept) for rec in result.records]
                self.journal.append(new)
                self.episodes_run += len(new)
                if self.on_episode is not None:
                    self.on_episode(len(new))
        out = []
        for point, seed, kept in zip(points, seeds, keeps, strict=True):
            got = {p: self.journal.get(p, seed, point, kept) for p in planners}
            out.append({p: ev for p, ev in got.items() if ev is not None})
            for p, ev in got.items():
                if ev is not None and ev.error is not None:
                    self.errors[key_of(p, seed, point, kept)] = ev
        return out

    def close(self) -> None:
        """Stop the workers (a later evaluate starts them again)."""
        self.pool.close()

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _evaluation(self, record: dict[str, Any], point: tuple[float, ...], keep: tuple[str, ...]) -> Evaluation:
        seed, planner = int(record["seed"]), str(record["planner"])
        if record.get("status") != OK:
            return Evaluation(planner, seed, point, keep, ERROR_ROBUSTNESS, False, {},
                              error=str(record.get("error", "the episode failed")))
        r = _finite(self.space.failure.robustness(record))
        return Evaluation(planner, seed, point, keep, r, r <= 0.0, _summary(record))
