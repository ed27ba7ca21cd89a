"""An episode re-simulated with what a video of it needs at every tick.

:func:`record_episode` runs one episode with its trace (the same record as
:func:`cdf_mj.scenario.episode.run_episode` for that seed and planner) and, for a planner
with a particle filter (``cdf``, ``cdf-threshold``), the filter's weighted particles at
every tick, read by an observer of the episode (:class:`ParticleRecorder`): the planner
is built by the registry with the run's arguments and runs as in any episode. The :class:`Replay` it
returns gives the scene at any time ``t``: the cars' poses interpolated between the 0.1 s
ticks (positions and speed linearly, headings along the shorter arc), the filter's state
that of the last tick at or before ``t``; its :attr:`Replay.control` the planner's command
beside the ego's own controller per tick, read from the record's trace (:class:`Control`). ::

    from cdf_mj.viz.replay import record_episode

    replay = record_episode(7, "cdf")
    replay.pose_at(1.25), replay.particles[replay.tick(1.25)]
    replay.control.intervening[replay.tick(1.25)]
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.planners.base import Planner
from cdf_mj.planners.cdf import CDFPlanner
from cdf_mj.planners.decision import RiskRule
from cdf_mj.planners.registry import bind_planner
from cdf_mj.records import EpisodeRecord
from cdf_mj.scenario.episode import EpisodeTick, run_episode, seed_label
from cdf_mj.sim.gl import RenderError
from cdf_mj.sim.scene import Scene

__all__ = ["CONTROL_KEYS", "POSTERIOR_KEYS", "Control", "ParticleRecorder", "Particles", "Replay", "check_frame_time",
           "control_of", "record_episode"]

#: The probabilities a planner's ``history`` may hold that a replay keeps, in panel order
#: (``cdf``: p_left, p_seen, p_cutoff, risk; ``cdf-threshold``: p_left, p_seen, p_cutoff;
#: ``imm``: p_left, p_conflict). The last one a planner keeps is what it brakes on.
POSTERIOR_KEYS = ("p_left", "p_seen", "p_cutoff", "p_conflict", "risk")
#: The per-tick lists of a record's trace that :func:`control_of` reads (a trace written
#: before they were kept has none of them).
CONTROL_KEYS = ("command", "own", "intervening")


class Control(NamedTuple):
    """Per tick of an episode (the tick from ``times[k]`` to ``times[k + 1]``), what the
    planner commanded against what the ego's own controller wanted, from a record's trace."""

    command: np.ndarray  # (K,) [m/s^2] the planner's command as it acts, within the car's limits
    own: np.ndarray  # (K,) [m/s^2] the ego's own controller (speed hold, following), no planner
    intervening: np.ndarray  # (K,) bool: the command below own by more than the tolerance
    brake: np.ndarray  # (K,) bool: the ego braked hard (the trace's "brake"; all False without it)


def control_of(trace: Mapping[str, Any] | None) -> Control | None:
    """The :class:`Control` of a record's ``trace`` (its lists "command", "own",
    "intervening" and "brake"); None for a trace without the first three (written before
    they were kept, or none).

    Raises:
        ValueError: one of them of another length than the trace's "t", or not numbers, in
            one line naming it.
    """
    if not trace or any(k not in trace for k in CONTROL_KEYS):
        return None
    n = len(trace.get("t", trace["own"]))
    out: dict[str, np.ndarray] = {}
    for key, dtype in (("command", float), ("own", float), ("intervening", bool), ("brake", bool)):
        values = trace.get(key, [False] * n)
        try:
            out[key] = np.asarray(values if values is not None else [], dtype=dtype)
        except (TypeError, ValueError):
            raise ValueError(f"trace {key!r}: not a list of {dtype.__name__}s") from None
        if out[key].shape != (n,):
            raise ValueError(f"trace {key!r}: {out[key].shape[0] if out[key].ndim else 0} values for "
                             f"{n} ticks")
    return Control(**out)


class Particles(NamedTuple):
    """One tick's distinct particles, heaviest first (world frame): merged by position (to
    1 cm), intent and seen; unpacks as ``xy, code, weight, heading``."""

    xy: np.ndarray  # (M, 2) float32 obstacle rear-axle positions [m], to 1 cm
    code: np.ndarray  # (M,) uint8 2 * intent + seen (intent as cdf_mj.model.driver.Intent)
    weight: np.ndarray  # (M,) float32 summed weights
    heading: np.ndarray  # (M,) float32 [rad] the weighted circular mean heading of the merged


class ParticleRecorder:
    """An episode observer keeping, per tick, the distinct weighted particles behind a CDF
    planner's posterior (:attr:`cdf_mj.planners.cdf.CDFPlanner.particles`); it reads them
    only, so the recorded run is the plain run."""

    def __init__(self) -> None:
        self.snapshots: list[Particles] = []

    def __call__(self, step: EpisodeTick) -> None:
        planner = step.planner
        if isinstance(planner, CDFPlanner):
            p = planner.particles
            self.snapshots.append(_distinct_particles(p.pose[:, :2], p.intent, p.has_belief, p.weights,
                                                      p.pose[:, 2]))


def _distinct_particles(xy: np.ndarray, intent: np.ndarray, seen: np.ndarray,
                        weights: np.ndarray, heading: np.ndarray | None = None) -> Particles:
    """The particles merged by (position to 1 cm, intent, seen), heaviest first; the heading
    [rad] of each merged one is the weighted circular mean of its members' (0 if none given)."""
    code = (2 * np.asarray(intent) + np.asarray(seen)).astype(np.int64)
    key = np.column_stack([np.round(xy * 100.0).astype(np.int64), code])
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    mass = np.bincount(inverse, weights=weights, minlength=len(uniq))
    th = np.zeros(len(xy)) if heading is None else np.asarray(heading, dtype=float)
    w = np.asarray(weights, dtype=float) + 1e-300  # a zero-weight group keeps its heading
    mean = np.arctan2(np.bincount(inverse, weights=w * np.sin(th), minlength=len(uniq)),
                      np.bincount(inverse, weights=w * np.cos(th), minlength=len(uniq)))
    order = np.argsort(-mass, kind="stable")
    uniq, mass, mean = uniq[order], mass[order], mean[order]
    return Particles((uniq[:, :2] / 100.0).astype(np.float32), uniq[:, 2].astype(np.uint8),
                     mass.astype(np.float32), mean.astype(np.float32))


def check_frame_time(frame_time: float, end_time: float, start: float = 0.0) -> float:
    """``frame_time`` [s] of a one-frame render, checked against the episode's span
    ``[start, end_time]`` [s] (a small rounding past the end is clipped to it).

    Raises:
        RenderError: ``frame_time`` is past the end (or before the start), in one line
            naming ``--frame`` and the times to choose from.
    """
    if not math.isfinite(frame_time) or frame_time < start - 1e-9 or frame_time > end_time + 1e-6:
        raise RenderError(f"--frame {frame_time:g}: outside the episode, which runs from "
                          f"{start:g} s to {end_time:.2f} s; choose a time in that range")
    return min(max(frame_time, start), end_time)


@dataclass
class Replay:
    """One recorded episode, ready to be drawn at any time ``t`` in ``[0, end_time]`` [s].

    ``times`` are the tick times plus the end time, ``poses`` the system pose
    ``(ego, obstacle) x [x m, y m, theta rad, v m/s]`` at each (world frame).
    """

    record: EpisodeRecord
    label: str | None  # the scenario label, None when not computed
    times: np.ndarray  # (K + 1,) [s]
    poses: np.ndarray  # (K + 1, 2, 4)
    seen: np.ndarray  # (K,) the obstacle has seen the ego, per tick
    belief: np.ndarray  # (K, 4) the obstacle's belief of the ego's pose, per tick (world frame)
    particles: list[Particles] | None  # per tick, ``cdf`` only
    # "t" [s] and the POSTERIOR_KEYS the planner keeps per tick; None for a planner without any
    posterior: dict[str, np.ndarray] | None
    tau: float | None  # the threshold of the last of them at which the planner brakes

    @cached_property
    def control(self) -> Control | None:
        """The planner's command and the ego's own acceleration per tick (:func:`control_of`
        the record's trace); None for a trace without them."""
        return control_of(getattr(self.record, "trace", None))

    @property
    def end_time(self) -> float:
        """When the episode ended [s]."""
        return float(self.times[-1])

    def tick(self, t: float) -> int:
        """Index of the last tick at or before ``t`` [s]."""
        k = int(np.searchsorted(self.times[:-1], t + 1e-9, side="right")) - 1
        return min(max(k, 0), len(self.times) - 2)

    def pose_at(self, t: float) -> np.ndarray:
        """System pose ``(2, 4)`` at time ``t`` [s], interpolated between ticks."""
        k = min(int(np.searchsorted(self.times, t, side="right")) - 1, len(self.times) - 2)
        k = max(k, 0)
        t0, t1 = self.times[k], self.times[k + 1]
        a = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        p0, p1 = self.poses[k], self.poses[k + 1]
        out = p0 + a * (p1 - p0)
        dth = np.remainder(p1[:, 2] - p0[:, 2] + math.pi, 2 * math.pi) - math.pi
        out[:, 2] = p0[:, 2] + a * dth
        return out

    def braking(self, t: float) -> bool:
        """Whether the ego brakes at time ``t`` [s] (the tick's flag of the trace: a planner
        with the risk rule may release its brake)."""
        flags = (self.record.trace or {}).get("brake")
        if flags:
            return bool(flags[self.tick(t)])
        bt = self.record.brake_time
        return bt is not None and t + 1e-9 >= bt


def record_episode(seed: int, planner: str | Planner = "cdf", config: ScenarioConfig | None = None,
                   scene: Scene | None = None, cdf: CDFConfig | None = None,
                   label: bool = True, planner_args: Mapping[str, Any] | None = None) -> Replay:
    """Run one episode with its trace (and, for a CDF planner, the filter's particles per tick).

    Args:
        seed: episode seed.
        planner: a registered planner name (built as an experiment builds it:
            :func:`~cdf_mj.planners.base.bind_planner`) or a planner object.
        config: scenario parameters (default :class:`~cdf_mj.config.ScenarioConfig`).
        scene: a loaded scene (default the package's ``scene.xml``); left at the end state.
        cdf: the run's shared CDF settings (what the CDF planners and the risk rules take;
            default :class:`~cdf_mj.config.CDFConfig`).
        label: also label the episode (:func:`~cdf_mj.scenario.episode.seed_label`).
        planner_args: the planner's own constructor arguments on top (a stored run's
            ``planner_args`` entry).

    The record is the one :func:`cdf_mj.scenario.episode.run_episode` gives for the same
    seed and planner.
    """
    config = config or ScenarioConfig()
    scene = scene or Scene.load(names=config.names)
    plan = planner if isinstance(planner, Planner) else bind_planner(planner, cdf, planner_args).make()
    particle_recorder = ParticleRecorder()
    record = run_episode(config, seed, plan, scene, label=False, trace=True, observers=[particle_recorder])
    final = scene.poses()  # the scene holds the state at end_time
    trace = record.trace or {}
    times = np.append(np.asarray(trace["t"], dtype=float), record.end_time)
    poses = np.concatenate([np.asarray(trace["poses"], dtype=float).reshape(-1, 2, 4), final[None]])
    lab = seed_label(config, seed, scene, [(record.intent, record.counterfactual_collision)])[0] if label else None
    particles = particle_recorder.snapshots if isinstance(plan, CDFPlanner) else None
    tau: float | None
    rule = getattr(plan, "rule", None)
    if isinstance(rule, RiskRule):  # the braking quantity is the risk (the last key)
        tau = rule.config.brake
    elif isinstance(plan, CDFPlanner):
        tau = plan.cdf.tau
    else:  # a baseline with a probability history (imm): its own threshold
        tau = getattr(getattr(plan, "params", None), "threshold", None)
    posterior = None
    h = getattr(plan, "history", None)
    if isinstance(h, dict) and "t" in h and any(k in h for k in POSTERIOR_KEYS):
        posterior = {k: np.asarray(h[k], dtype=float) for k in ("t", *POSTERIOR_KEYS) if k in h}
    else:
        tau = None
    return Replay(record=record, label=lab, times=times, poses=poses,
                  seen=np.asarray(trace["seen"], dtype=bool),
                  belief=np.asarray(trace["belief"], dtype=float).reshape(-1, 4),
                  particles=particles, posterior=posterior, tau=tau)
