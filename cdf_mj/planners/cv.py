"""The constant-velocity baseline ``cv`` (the velocity-obstacle assumption), with the risk
rule (``cv-risk``) and the layered rule (``cv-layered``).

It extrapolates the obstacle and the ego in straight lines at their measured speeds and
brakes when their collision boxes (the obstacle's widened by a margin) meet within a
horizon. It sees what every planner sees (:class:`cdf_mj.planners.PlannerInput`: the
measured system pose), and holds its brake once decided
(:class:`cdf_mj.planners.base.DecidingPlanner` with the threshold rule); ``cv-risk`` and
``cv-layered`` decide by the rules of :mod:`cdf_mj.planners.decision` on the obstacle's
straight-line path. Its parameters are :class:`CVConfig`, chosen on seeds 0-199 only
(docs/ANALYSIS.md says how). Each tick runs compiled
(:mod:`cdf_mj.planners.baseline_kernels`); the NumPy references of its path and box test
are :func:`~cdf_mj.planners.baseline_common.straight_path` and
:func:`~cdf_mj.planners.baseline_common.first_conflict`. Unlike ``imm`` it does not
import filterpy::

    from cdf_mj.planners.cv import CVConfig, CVPlanner
    record = run_episode(config, seed=7, planner=CVPlanner(CVConfig(horizon=2.0)))

Frames and units: world frame (x east, y north), metres, seconds, radians; poses are
rear-axle ``[x, y, theta, v]``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cdf_mj.config import LayeredConfig, RiskConfig
from cdf_mj.planners import baseline_kernels as kern
from cdf_mj.planners.base import DecidingPlanner, PlannerContext, PlannerInput, ThresholdRule, as_config
from cdf_mj.planners.baseline_common import (
    BASELINE_LAYERS,
    baseline_rule,
    check_field,
    finite_number,
    look_ahead_times,
)

__all__ = ["COAST_TIME", "CVConfig", "CVLayeredPlanner", "CVPlanner", "CVRiskPlanner"]

#: [s] How long a ``cv`` planner whose sensor is occluded coasts its track of the other car
#: out of sight (its last measured pose moved on in a straight line at its measured speed)
#: before it drops it: a tracker's usual hold of a lost track, a second or two.
COAST_TIME = 1.0


@dataclass(frozen=True)
class CVConfig:
    """Parameters of the constant-velocity planner ``cv`` (chosen on seeds 0-199)."""

    # Chosen on seeds 0-199 by the largest (avoided - false-alarm rate) over horizons
    # {0.5, 1, 1.5, 2, 2.5} s at margin 0.3 m, then margins 0 and 0.15 m at 1-2 s (the grid
    # in docs/ANALYSIS.md): 1.5 s, 0 m avoided 72/80 with 50/200 false alarms, every one a
    # right-turner.
    horizon: float = 1.5  # [s] look-ahead of the straight-line extrapolation
    margin: float = 0.0  # [m] added to each half size of the obstacle's collision box

    def __post_init__(self) -> None:
        check_field(finite_number(self.horizon) and 0 < self.horizon <= 10, "horizon", self.horizon,
                    "in (0, 10] [s]")
        check_field(finite_number(self.margin) and 0 <= self.margin <= 5, "margin", self.margin,
                    "in [0, 5] [m]")

    def replace(self, **changes: Any) -> CVConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)



class CVPlanner(DecidingPlanner):
    """Constant-velocity predictor (velocity obstacle): brake when the straight-line
    extrapolations of the obstacle and of the ego at their measured speeds put their
    boxes in contact within ``horizon`` (its threshold rule), or with the risk rule on the
    obstacle's straight-line path (``risk``; registered as ``cv-risk``). ``summary()``
    holds the decision time and the predicted time to conflict at that moment.

    A tick without a measurement of the obstacle (a dropout) keeps its last measured pose.
    With an occluded sensor (``PlannerContext.occluded``) the track coasts instead: that
    pose moved on in a straight line at its measured speed, for up to :data:`COAST_TIME`,
    after which the track is dropped and nothing is predicted until the next measurement
    (nor before the first).

    Args:
        params: horizon and margin (default :class:`CVConfig`).
        risk: run with :class:`~cdf_mj.planners.decision.RiskRule` of these parameters
            instead of the threshold rule.
    """

    name = "cv"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        self.params = as_config(params, CVConfig, "params")
        self.rule = baseline_rule(risk, layered, ThresholdRule(1.0))

    def reset(self, context: PlannerContext, rng: np.random.Generator) -> None:
        """Take the cars' footprints from the layout and the tick ``dt`` from ``context``."""
        super().reset(context, rng)
        layout = context.layout
        self._ego, self._obstacle, self._dt = layout.ego, layout.obstacle, context.dt
        self._times = look_ahead_times(self.params.horizon, context.dt)
        # The kernels' cars (the obstacle's box widened by the margin) and a buffer of the pose.
        self._cars = (kern.car_vector(layout.ego), kern.car_vector(layout.obstacle, self.params.margin))
        self._poses = np.zeros((2, 4))
        self._future_times: np.ndarray | None = None  # ticks 1..K of the rule's horizon [s]
        self.conflict_in: float | None = None
        self._obstacle_pose: np.ndarray | None = np.zeros(4)
        self._coasts = context.occluded
        # (time [s], pose) of the last measurement of the obstacle, kept with an occluded sensor only
        self._last_seen: tuple[float, np.ndarray] | None = None

    def time_to_conflict(self, poses: np.ndarray) -> float | None:
        """Predicted time [s] to the first conflict under constant velocities from the
        system pose ``(2, 4)`` (ego, obstacle), or None within the horizon (:func:`first_conflict`
        of the two :func:`straight_path`, compiled)."""
        poses = np.asarray(poses, dtype=float)
        if poses.shape != (2, 4):
            raise ValueError(f"time_to_conflict: poses must be (2, 4) rows [x, y, theta, v] of the ego and the "
                             f"obstacle, got shape {poses.shape}")
        self._poses[:] = poses
        k = kern.straight_conflict(self._poses, self._times, *self._cars)
        return round(k * self._dt, 6) if k >= 0 else None

    def observe(self, obs: PlannerInput) -> None:
        """Predict the conflict (until the decision, for the threshold rule); keep the
        obstacle's pose for its straight-line future (coasted out of an occluded sensor's
        sight, see the class)."""
        self.record(obs.t)
        measured = bool(np.isfinite(obs.poses[1]).all())
        if self._coasts:
            self._coast(obs, measured)
            return
        if not measured:  # no measurement of the obstacle: its last one stands
            return
        self._obstacle_pose = obs.poses[1]
        if self.decision_time is None and not self.rule.releases:
            self.conflict_in = self.time_to_conflict(obs.poses)

    def _coast(self, obs: PlannerInput, measured: bool) -> None:
        """:meth:`observe` with an occluded sensor: the measured pose, or the track coasted
        to ``obs.t`` in a straight line, or no track (``_obstacle_pose`` None) once it has
        been out of sight for longer than :data:`COAST_TIME`, or before the first measurement."""
        if measured:
            self._last_seen = (obs.t, np.array(obs.poses[1], dtype=float))
        pose: np.ndarray | None = None
        if self._last_seen is not None and obs.t - self._last_seen[0] <= COAST_TIME + 1e-9:
            t0, (x, y, th, v) = self._last_seen[0], self._last_seen[1].tolist()
            d = max(v, 0.0) * (obs.t - t0)
            pose = np.array([x + d * math.cos(th), y + d * math.sin(th), th, v])
        self._obstacle_pose = pose
        if self.decision_time is None and not self.rule.releases:
            self.conflict_in = None if pose is None else self.time_to_conflict(np.stack([obs.poses[0], pose]))

    def alarm(self) -> float:
        """1 if a conflict is predicted within the horizon, else 0."""
        return 1.0 if self.conflict_in is not None else 0.0

    def futures(self, react_ticks: int) -> np.ndarray:
        """The obstacle's straight-line path at its measured speed, ticks ``1..K`` of the
        rule's horizon ``(K, 4)``; ``(0, 4)`` without a track (an occluded sensor's, see the class)."""
        if self._future_times is None:
            n = max(1, math.ceil(self.rule.config.horizon / self._dt - 1e-9))  # type: ignore[attr-defined]
            self._future_times = np.arange(1, n + 1) * self._dt
        if self._obstacle_pose is None:
            return np.zeros((0, 4))
        x, y, th, v = (float(p) for p in self._obstacle_pose)
        return kern.straight_path(x, y, th, v, self._future_times)

    def summary(self) -> dict[str, Any]:
        """Rule, decision and release times [s], the brakes, the time to conflict [s]
        predicted at the decision (threshold rule) and, with the risk rule, its history."""
        info = {"rule": self.rule.name, "decision_time": self.decision_time, "release_time": self.release_time,
                "brakes": self.brakes, "predicted_conflict_in": self.conflict_in}
        if self.anticipated:  # a graded rule slowed for the obstacle's entry: it predicted the cut-off
            info["prediction"] = "Cutoff"
        return {**info, "history": self.history} if self.rule.releases else info


class CVLayeredPlanner(CVPlanner):
    """:class:`CVPlanner` with the layered rule (default :data:`BASELINE_LAYERS` and
    :class:`RiskConfig`), registered as ``cv-layered``."""

    name = "cv-layered"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None,
                 layered: LayeredConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, risk, BASELINE_LAYERS if layered is None else layered)


class CVRiskPlanner(CVPlanner):
    """:class:`CVPlanner` with the risk rule (default :class:`RiskConfig`), registered as ``cv-risk``."""

    name = "cv-risk"

    def __init__(self, params: CVConfig | Mapping[str, Any] | None = None,
                 risk: RiskConfig | Mapping[str, Any] | None = None) -> None:
        super().__init__(params, RiskConfig() if risk is None else risk)
