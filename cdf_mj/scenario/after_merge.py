"""What the obstacle does once it is in the ego's lane (:class:`cdf_mj.config.AfterMerge`):
the world overrides its driver's acceleration from then on, whichever driver it is.

==========  =============================================================================
keep        no override: its driver goes on as it would
slow        after ``at`` metres in the lane, decelerate at ``decel`` to ``slow_to`` x its
            speed there, then hold that speed
brake       after ``at`` metres in the lane, brake at ``brake`` to a stop and stand
stop        an aborted turn: brake at ``brake`` to a stop on entering the lane and stand
==========  =============================================================================

Each episode draws its values uniformly from the stated ranges with the world's
``after_merge`` stream (drawn whatever the behaviour, so a seed's draws are the same under
every behaviour). Steering stays the driver's. Units: metres, seconds.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cdf_mj.config import AfterMerge

__all__ = ["AfterMergeOverride"]


class AfterMergeOverride:
    """The acceleration override of one episode (see the module docstring)."""

    def __init__(self, config: AfterMerge) -> None:
        self.config = config
        self.params: dict[str, Any] = {"behaviour": config.behaviour}
        self._start: np.ndarray | None = None  # (x, y) [m] where it entered the lane
        self._v_target: float | None = None  # [m/s] the speed it goes to once it acts
        self.active_since: float | None = None  # [s] when the override first acted

    def reset(self, rng: np.random.Generator) -> None:
        """Draw this episode's values (four uniforms, always drawn: common random numbers)."""
        c = self.config
        decel, slow_to, brake, at = (float(rng.uniform(*r)) for r in (c.decel, c.slow_to, c.brake, c.at))
        self.params = {"behaviour": c.behaviour}
        if c.behaviour == "slow":
            self.params.update(decel=decel, slow_to=slow_to, at=at)
        elif c.behaviour == "brake":
            self.params.update(brake=brake, at=at)
        elif c.behaviour == "stop":
            self.params.update(brake=brake)
        self._start, self._v_target, self.active_since = None, None, None

    def accel(self, t: float, pose: np.ndarray, in_lane: bool, driver_accel: float) -> float:
        """The obstacle's acceleration [m/s^2] on this tick: ``driver_accel`` (what its driver
        commands), overridden once it has entered the ego's lane (``in_lane`` on this tick or
        before) and, for ``slow`` and ``brake``, gone ``at`` metres on. ``pose`` is its true
        rear-axle pose [x, y, theta, v]."""
        p = self.params
        behaviour = p["behaviour"]
        if behaviour == "keep":
            return driver_accel
        if self._start is None:
            if not in_lane:
                return driver_accel
            self._start = np.array(pose[:2], dtype=float)
        v = float(pose[3])
        if self._v_target is None:
            if behaviour != "stop" and math.dist(pose[:2], self._start) < p["at"]:
                return driver_accel
            self._v_target = p["slow_to"] * v if behaviour == "slow" else 0.0
            self.active_since = t
        if behaviour == "slow":
            return -p["decel"] if v > self._v_target else min(driver_accel, 0.0)
        return -p["brake"]  # to a standstill, then stand
