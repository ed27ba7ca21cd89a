"""cdf_mj: the Cognitive Driving Framework's T-intersection scenario in MuJoCo.

An ego car with the right of way meets an obstacle car that waits at a stop sign and
turns left (across the ego's lane) or right; whether it pulls out depends on its intent
and on whether it has seen the ego. One episode is a pure function of a config and a
seed::

    from cdf_mj import ScenarioConfig, Scene, run_episode

    scene = Scene.load()                                  # models/xml/scene.xml
    record = run_episode(ScenarioConfig(), seed=7, planner="reactive", scene=scene)
    record.label, record.collision, record.to_dict()

The names below are imported on first use, so ``import cdf_mj`` stays light (no MuJoCo
import) for tools that only want ``cdf_mj.__version__``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# public name -> module that defines it
_EXPORTS = {
    "ScenarioConfig": "cdf_mj.config",
    "Scene": "cdf_mj.scene",
    "SceneError": "cdf_mj.scene",
    "run_episode": "cdf_mj.episode",
    "EpisodeRecord": "cdf_mj.episode",
    "CDFConfig": "cdf_mj.config",
    "CDFPlanner": "cdf_mj.planners",
    "ParticleFilter": "cdf_mj.inference",
    "run_experiment": "cdf_mj.experiment",
}

__all__ = ["__version__", *_EXPORTS]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time see __getattr__
    from cdf_mj.config import CDFConfig, ScenarioConfig
    from cdf_mj.episode import EpisodeRecord, run_episode
    from cdf_mj.experiment import run_experiment
    from cdf_mj.inference import ParticleFilter
    from cdf_mj.planners import CDFPlanner
    from cdf_mj.scene import Scene, SceneError


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first access (PEP 562)."""
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'cdf_mj' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
