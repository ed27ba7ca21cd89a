"""What a sweep is: the setting it changes, its default values and how a value is applied
to a run's scenario and CDF settings (:class:`SweepSpec`, one per key of :data:`SWEEPS`).
:mod:`cdf_mj.experiments.sweep` runs them. ::

    from cdf_mj.config import CDFConfig, ScenarioConfig
    from cdf_mj.experiments.sweep_spec import SWEEPS
    config, cdf = SWEEPS["beta"].settings(0.05, ScenarioConfig(), CDFConfig())
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

from cdf_mj.config import CDFConfig, ScenarioConfig
from cdf_mj.planners.registry import PLANNERS, planner_spec

__all__ = ["SWEEPS", "SweepSpec"]


def _reads_cdf(name: str) -> bool:
    """Whether planner ``name`` takes any of a run's CDF settings (its registry entry's
    ``shared``); an unregistered name reads none."""
    return name in PLANNERS and bool(planner_spec(name).shared)


def _scale_process(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    """Both cars' process noise times ``k``, and the CDF filter's own model of it with them
    (the sweep asks how the noise level matters, not how a wrong model of it does)."""
    noise, own = config.noise, cdf.process_noise
    return (config.replace(noise=noise.replace(accel=noise.accel * k, steer=noise.steer * k)),
            cdf.replace(process_noise=own.replace(accel=own.accel * k, steer=own.steer * k)))


def _scale_obs(config: ScenarioConfig, cdf: CDFConfig, k: float) -> tuple[ScenarioConfig, CDFConfig]:
    """The obstacle driver's observation noise of the ego times ``k``, and the CDF filter's
    model of it with it."""
    seen, own = config.observation, cdf.prior.observation
    return (config.replace(observation=seen.replace(pos=seen.pos * k, heading=seen.heading * k,
                                                    speed=seen.speed * k)),
            cdf.replace(prior=dataclasses.replace(cdf.prior, observation=own.replace(
                pos=own.pos * k, heading=own.heading * k, speed=own.speed * k))))


@dataclass(frozen=True)
class SweepSpec:
    """One sweep: the setting it changes, its default values and how a value is applied."""

    name: str
    label: str  # axis label, with unit
    values: tuple[float, ...]
    apply: Callable[[ScenarioConfig, CDFConfig, float], tuple[ScenarioConfig, CDFConfig]]
    cdf_only: bool  # only the CDF reads it: other planners run once, at the first point
    integer: bool = False
    log_x: bool = False

    def settings(self, value: float, config: ScenarioConfig, cdf: CDFConfig) -> tuple[ScenarioConfig, CDFConfig]:
        """The scenario and CDF settings of one point (ValueError out of range)."""
        if self.integer:
            if float(value) != int(value):
                raise ValueError(f"{self.name} values must be whole numbers, got {value!r}")
            value = int(value)
        return self.apply(config, cdf, value)


SWEEPS: dict[str, SweepSpec] = {s.name: s for s in (
    SweepSpec("beta", "beta, P(observe a visible ego) per 0.1 s tick", (0.01, 0.02, 0.05, 0.1, 0.2),
              lambda c, d, v: (c.with_values({"obstacle.beta": float(v)}), d), cdf_only=False, log_x=True),
    SweepSpec("particles", "particle count N", (100, 250, 500, 1000, 2000, 4000),
              lambda c, d, v: (c, d.replace(n_particles=int(v))), cdf_only=True, integer=True, log_x=True),
    SweepSpec("tau", "braking threshold tau on P(cutoff) (the paper's rule)",
              (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99),
              lambda c, d, v: (c, d.replace(tau=float(v), decision="threshold")), cdf_only=True),
    SweepSpec("risk", "risk rule: braking threshold on P(collision if deferred)", (0.05, 0.1, 0.2, 0.3, 0.5),
              lambda c, d, v: (c, d.replace(decision="risk", risk=d.risk.replace(brake=float(v),
                                                                                  release=float(v) / 2))),
              cdf_only=True, log_x=True),
    SweepSpec("noise", "process noise factor (world's and filter's)",
              (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_process(c, d, float(v)), cdf_only=False, log_x=True),
    SweepSpec("obs-noise", "observation noise factor (world's and filter's)",
              (0.5, 1.0, 2.0, 4.0),
              lambda c, d, v: _scale_obs(c, d, float(v)), cdf_only=False, log_x=True),
)}


def _value_text(value: float) -> str:
    return f"{value:g}"
