"""The CDF monitor's trace file: what :meth:`cdf_mj.scenario.monitor.CDFMonitor.save_trace`
writes and :func:`read_trace` reads back (``cdf-mj render --trace`` draws it,
:mod:`cdf_mj.viz.trace`).

JSON lines: a header object (``"format": TRACE_FORMAT``, the scene names, the scenario and
CDF configs, the decision rule and its threshold, both cars' geometries), then one object
per observation ``{"t", "ego", "obstacle", "posterior", "brake"}`` (and ``"risk"`` with the
risk rule): time [s], rear-axle poses ``[x m, y m, yaw rad, v m/s]`` in the world frame,
the posterior's probabilities, the brake decision; and, in traces that count every
intervention, ``"command"`` (the planner's command as it acts, within the car's limits) and
``"own"`` (the ego's own controller's acceleration) [m/s^2] and ``"intervening"`` (the
command below ``own`` by more than the tolerance). A monitor with another planner than
``cdf`` names it in the header (``"planner"``); one without a posterior (``reactive``,
``imm-*``, ``cv-*``, a user's) writes ``"posterior": false`` there, no ``cdf`` nor ``tau``,
its rule's name (``null`` for a planner without one) and threshold where it has them, and
observations without ``"posterior"``. ::

    from cdf_mj.scenario.trace_file import read_trace

    trace = read_trace("episode.jsonl")
    trace.times, trace.poses[:, 1], trace.posterior["p_cutoff"], trace.brake_time
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cdf_mj.config import MAX_DURATION, SceneNames
from cdf_mj.inputs import TRACE_MAX_BYTES, InputError, parse_json, read_text
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.records import write_atomic

__all__ = ["MAX_TRACE_TICKS", "MIN_TRACE_STEP", "TRACE_FORMAT", "MonitorTrace", "TraceError", "read_trace",
           "write_trace"]

#: The ``format`` of the header line of a trace file (:meth:`CDFMonitor.save_trace`).
TRACE_FORMAT = "cdf_mj.monitor_trace/1"
#: [s] the least time between two observations of a trace (the monitor writes one per
#: 0.1 s tick; a simulation at 1 kHz still fits).
MIN_TRACE_STEP = 1e-3
#: Most observations a trace holds: 600 s (:data:`cdf_mj.config.MAX_DURATION`, the longest
#: span a trace may cover from its first observation) at about 166 Hz, or 100 s at 1 kHz.
MAX_TRACE_TICKS = 100_000
_ROUNDING = 1e-9  # [s] how far a difference of two times may miss a bound by rounding (10.001 - 10)


def write_trace(path: str | Path, header: dict[str, Any], rows: Iterable[dict[str, Any]]) -> Path:
    """Write ``header`` and then each of ``rows`` as one line of strict JSON (no NaN) to
    ``path``; the file appears complete or not at all (:func:`cdf_mj.records.write_atomic`),
    and only if :func:`read_trace` reads it back: a trace it would refuse (more than
    :data:`MAX_TRACE_TICKS` observations, a span over :data:`~cdf_mj.config.MAX_DURATION`,
    times closer than :data:`MIN_TRACE_STEP`, no observation, a bad field) is a
    :class:`TraceError` naming the path and the observation, and nothing is written.
    Returns ``path``."""
    path = Path(path)
    lines = [json.dumps(header, allow_nan=False)]
    lines += [json.dumps(row, allow_nan=False) for row in rows]
    try:
        _parse(path, list(enumerate(lines)), "the trace", lambda no: f"observation {no}" if no else "the header")
    except TraceError as exc:
        raise TraceError(f"the trace is not saved to {path}, as read_trace would refuse it: {exc}") from None
    return write_atomic(path, "\n".join(lines) + "\n")


class TraceError(ValueError):
    """A trace file that cannot be read: one line naming ``file:line`` and what is wrong."""


@dataclass(frozen=True)
class MonitorTrace:
    """A trace file read back (:func:`read_trace`).

    ``times`` (K,) [s]; ``poses`` (K, 2, 4) rear-axle ``[x m, y m, yaw rad, v m/s]`` of ego
    and obstacle, world frame; ``posterior`` maps ``t`` and each probability (``p_left``,
    ``p_right``, ``p_seen``, ``p_cutoff``, ``ess``, and ``risk`` for the risk rule) to (K,)
    arrays. ``rule`` is the decision rule (``threshold`` for traces written before the
    risk rule; None for a planner without one) and ``threshold`` the value at which it
    brakes on its quantity (NaN where unknown). ``planner`` names the monitor's planner;
    for one without a posterior (:attr:`has_posterior` False) ``posterior`` holds only
    ``t`` (and ``risk`` with the risk rule) and ``tau`` is NaN.
    """

    path: Path
    header: dict[str, Any]
    names: SceneNames
    ego: CarGeometry
    obstacle: CarGeometry
    tau: float
    times: np.ndarray
    poses: np.ndarray
    posterior: dict[str, np.ndarray]
    brake: np.ndarray  # (K,) bool: the brake decision per observation
    rule: str | None = "threshold"
    threshold: float = math.nan
    planner: str = "cdf"
    # (K,) per observation, where the trace holds them (else NaN, NaN, False): the planner's
    # command as it acts and the ego's own acceleration [m/s^2], and whether it intervened
    command: np.ndarray = field(default_factory=lambda: np.empty(0))
    own: np.ndarray = field(default_factory=lambda: np.empty(0))
    intervening: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))

    def __post_init__(self) -> None:
        k = len(self.times)
        for name, fill in (("command", math.nan), ("own", math.nan), ("intervening", False)):
            n = len(getattr(self, name))
            if n == 0:  # not in the trace: NaN or False per observation
                object.__setattr__(self, name, np.full(k, fill, dtype=type(fill)))
            elif n != k:
                raise ValueError(f"MonitorTrace: {name} has {n} values for {k} observations")

    @property
    def has_posterior(self) -> bool:
        """Whether the trace holds the CDF posterior (written by a ``cdf`` planner)."""
        return "p_cutoff" in self.posterior

    @property
    def brake_time(self) -> float | None:
        """[s] the first observation with the brake decision, None if never."""
        idx = np.flatnonzero(self.brake)
        return round(float(self.times[idx[0]]), 6) if idx.size else None


_POSTERIOR_KEYS = ("p_left", "p_right", "p_seen", "p_cutoff", "ess")
#: Per-observation fields of a trace that counts every intervention: optional, but a trace
#: whose first observation holds one holds it in every observation.
_INTERVENTION_KEYS = ("command", "own", "intervening")


def _intervention_values(row: dict[str, Any], keys: tuple[str, ...], where: str) -> list[float | bool]:
    """The observation ``row``'s values of ``keys`` (of :data:`_INTERVENTION_KEYS`):
    ``command`` and ``own`` finite numbers [m/s^2], ``intervening`` true or false; TraceError
    ``WHERE: what`` for one missing or of another kind."""
    out: list[float | bool] = []
    for key in keys:
        if key not in row:
            raise TraceError(f"{where}: the observation lacks {key!r} (the first observation has it)")
        v = row[key]
        ok = isinstance(v, bool) if key == "intervening" else (
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v))
        if not ok:
            kind = "true or false" if key == "intervening" else "a finite acceleration [m/s^2]"
            raise TraceError(f"{where}: {key!r} must be {kind}, got {v!r}"[:160])
        out.append(v)
    return out


def read_trace(path: str | Path) -> MonitorTrace:
    """Read a file of :meth:`CDFMonitor.save_trace`. TraceError ``file:line: what`` for a
    file that is missing, not JSON lines, of another format, or with a bad field; for more
    than :data:`MAX_TRACE_TICKS` observations (counted before parsing), and for times that
    are not finite, not :data:`MIN_TRACE_STEP` apart or more, or more than
    :data:`~cdf_mj.config.MAX_DURATION` after the first (so that whatever draws the trace
    has a bounded span and count of ticks)."""
    path = Path(path)
    try:  # a regular file (a FIFO or a device is refused unopened) of at most TRACE_MAX_BYTES
        text = read_text(path, "trace", TRACE_MAX_BYTES)
    except InputError as exc:
        raise TraceError(str(exc)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise TraceError(f"{path}: cannot read the trace ({getattr(exc, 'strerror', None) or exc})") from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()]
    return _parse(path, lines, str(path), lambda no: f"{path}:{no}")


def _parse(path: Path, lines: list[tuple[int, str]], whole: str, at: Callable[[int], str]) -> MonitorTrace:
    """The trace of the numbered non-blank ``lines`` of ``path``; TraceError ``AT: what``,
    where ``at(number)`` names a line (``file:line`` when reading; ``observation N`` when
    checking what :func:`write_trace` would write) and ``whole`` the trace."""
    if len(lines) - 1 > MAX_TRACE_TICKS:  # counted before any line is parsed
        raise TraceError(f"{whole}: {len(lines) - 1} observations, more than the {MAX_TRACE_TICKS} a trace "
                         "may hold; split it or write fewer ticks")
    if not lines:
        raise TraceError(f"{at(1)}: empty file; a trace starts with a header line ({TRACE_FORMAT})")
    rows: list[tuple[int, dict[str, Any]]] = []
    for no, line in lines:
        try:
            obj = parse_json(line, f"{at(no)}: the line")  # nested at most MAX_DEPTH levels
        except InputError as exc:
            raise TraceError(str(exc)) from None
        except json.JSONDecodeError as exc:
            raise TraceError(f"{at(no)}: not JSON ({exc.msg} at column {exc.colno})") from None
        if not isinstance(obj, dict):
            raise TraceError(f"{at(no)}: expected a JSON object, got {type(obj).__name__}")
        rows.append((no, obj))
    no, header = rows[0]
    if header.get("format") != TRACE_FORMAT:
        raise TraceError(f"{at(no)}: not a monitor trace: the header's format is "
                         f"{header.get('format')!r}, expected {TRACE_FORMAT!r}")
    valid = [f.name for f in dataclasses.fields(SceneNames)]
    unknown = sorted(set(header.get("names") or {}) - set(valid)) if isinstance(header.get("names"), dict) else []
    if "names" in header and not isinstance(header["names"], dict):
        raise TraceError(f"{at(no)}: the header's 'names' must be an object of SceneNames fields")
    if unknown:
        raise TraceError(f"{at(no)}: the header's 'names' has unknown key(s) {', '.join(unknown)}; "
                         f"valid: {', '.join(valid)}")
    planner, has_post = header.get("planner", "cdf"), header.get("posterior", True)
    if not isinstance(planner, str) or not planner:
        raise TraceError(f"{at(no)}: the header's 'planner' must be a planner's name, got {planner!r}")
    if not isinstance(has_post, bool):
        raise TraceError(f"{at(no)}: the header's 'posterior' must be true or false, got {has_post!r}")
    try:
        names = SceneNames(**header["names"])
        ego = CarGeometry.from_dict(header["ego"])
        obstacle = CarGeometry.from_dict(header["obstacle"])
        tau = float(header["tau"]) if has_post else math.nan
    except KeyError as exc:
        raise TraceError(f"{at(no)}: the header lacks {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise TraceError(f"{at(no)}: bad header: {' '.join(str(exc).split())}") from None
    rule = header.get("rule", "threshold")
    threshold = header.get("threshold", tau if has_post else math.nan)
    for key, value in (("tau", tau), ("threshold", threshold)):
        if not has_post and key not in header:  # a planner without a posterior: none, or not known
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and 0.0 < value <= 1.0):
            raise TraceError(f"{at(no)}: the header's {key!r} must be in (0, 1], got {header.get(key, value)!r}")
    if rule not in ("threshold", "risk", "layered") and not (rule is None and not has_post):
        raise TraceError(f"{at(no)}: the header's 'rule' must be 'threshold', 'risk' or 'layered'"
                         f"{' (or null)' if not has_post else ''}, got {rule!r}")
    risky = rule in ("risk", "layered")  # the emergency layer's risk is the risk rule's
    keys = (*(_POSTERIOR_KEYS if has_post else ()), *(("risk",) if risky else ()))
    if len(rows) < 2:
        raise TraceError(f"{at(no)}: the trace has no observation after its header")
    times: list[float] = []
    poses: list[np.ndarray] = []
    brake: list[bool] = []
    post: dict[str, list[float]] = {k: [] for k in keys}
    extra_keys = tuple(k for k in _INTERVENTION_KEYS if k in rows[1][1])
    extra: dict[str, list[float | bool]] = {k: [] for k in extra_keys}
    for no, row in rows[1:]:
        try:
            t = float(row["t"])
            pose = np.array([row["ego"], row["obstacle"]], dtype=float)
            p = {**(row["posterior"] if has_post else {}), **({"risk": row["risk"]} if risky else {})}
            values = [float(p[k]) for k in keys]
            b = row["brake"]
        except KeyError as exc:
            raise TraceError(f"{at(no)}: the observation lacks {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise TraceError(f"{at(no)}: bad observation: {' '.join(str(exc).split())}") from None
        if pose.shape != (2, 4) or not np.all(np.isfinite(pose)) or not math.isfinite(t):
            raise TraceError(f"{at(no)}: 'ego' and 'obstacle' must be 4 finite numbers each "
                             "and 't' a finite time")
        if times and not t - times[-1] >= MIN_TRACE_STEP - _ROUNDING:
            raise TraceError(f"{at(no)}: time {t:g} s does not follow {times[-1]:g} s by at least "
                             f"{MIN_TRACE_STEP:g} s (MIN_TRACE_STEP)")
        if times and not t - times[0] <= MAX_DURATION + _ROUNDING:
            raise TraceError(f"{at(no)}: time {t:g} s is {t - times[0]:g} s after the first observation "
                             f"({times[0]:g} s); a trace spans at most {MAX_DURATION:g} s (MAX_DURATION)")
        if not isinstance(b, bool):
            raise TraceError(f"{at(no)}: 'brake' must be true or false, got {b!r}")
        bad = [k for k, v in zip(keys, values, strict=True)
               if not math.isfinite(v) or (v < 0.0 if k == "ess" else not 0.0 <= v <= 1.0)]
        if bad:
            raise TraceError(f"{at(no)}: 'posterior' has {', '.join(bad)} out of range "
                             "(probabilities in [0, 1], ess a finite number >= 0)")
        for k, v in zip(extra_keys, _intervention_values(row, extra_keys, at(no)), strict=True):
            extra[k].append(v)
        times.append(t)
        poses.append(pose)
        brake.append(b)
        for k, v in zip(keys, values, strict=True):
            post[k].append(v)
    posterior = {"t": np.array(times)} | {k: np.array(v) for k, v in post.items()}
    return MonitorTrace(path=path, header=header, names=names, ego=ego, obstacle=obstacle, tau=tau,
                        times=np.array(times), poses=np.array(poses), posterior=posterior,
                        brake=np.array(brake, dtype=bool), rule=rule, threshold=float(threshold),
                        planner=planner, **{k: np.array(v, dtype=bool if k == "intervening" else float)
                                            for k, v in extra.items()})
