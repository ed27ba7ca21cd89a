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
import) for tools that only want ``cdf_mj.__version__``. If Gymnasium is installed,
importing the package registers the environment ``cdf_mj/TIntersection-v0``
(:mod:`cdf_mj.envs.t_intersection`), which imports Gymnasium (about 0.2 s).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from cdf_mj._version import __version__  # the one place it is written
from cdf_mj.envs import ENV_ID  # light: neither Gymnasium nor MuJoCo

# public name -> module that defines it
_EXPORTS = {
    "ScenarioConfig": "cdf_mj.config",
    "CDFConfig": "cdf_mj.config",
    "SceneNames": "cdf_mj.config",
    "DriverPrior": "cdf_mj.config",
    "RiskConfig": "cdf_mj.config",
    "LayeredConfig": "cdf_mj.config",
    "scaled": "cdf_mj.config",
    "CarGeometry": "cdf_mj.model.vehicle",
    "TrackedCar": "cdf_mj.sim.tracking",
    "EpisodeRecord": "cdf_mj.records",
    "Label": "cdf_mj.records",
    "Scene": "cdf_mj.sim.scene",
    "SceneError": "cdf_mj.sim.checks",
    "add_car": "cdf_mj.sim.spec",
    "ParticleFilter": "cdf_mj.inference.particle_filter",
    "CDFPlanner": "cdf_mj.planners.cdf",
    "CVPlanner": "cdf_mj.planners.cv",
    "IMMPlanner": "cdf_mj.planners.imm",
    "make_planner": "cdf_mj.planners.registry",
    "register": "cdf_mj.planners.registry",
    "World": "cdf_mj.scenario.world",
    "run_episode": "cdf_mj.scenario.episode",
    "CDFMonitor": "cdf_mj.scenario.monitor",
    "attach": "cdf_mj.scenario.monitor",
    "TIntersectionEnv": "cdf_mj.envs.t_intersection",
    "run_experiment": "cdf_mj.experiments.experiment",
    "run_sweep": "cdf_mj.experiments.sweep",
    "render_episode": "cdf_mj.viz.render",
    "write_report": "cdf_mj.viz.report",
}

__all__ = [  # literal, for linters; tests/test_layers.py checks it against _EXPORTS
    "ENV_ID",
    "CDFConfig",
    "CDFMonitor",
    "CDFPlanner",
    "CVPlanner",
    "CarGeometry",
    "DriverPrior",
    "EpisodeRecord",
    "IMMPlanner",
    "Label",
    "LayeredConfig",
    "ParticleFilter",
    "RiskConfig",
    "ScenarioConfig",
    "Scene",
    "SceneError",
    "SceneNames",
    "TIntersectionEnv",
    "TrackedCar",
    "World",
    "__version__",
    "add_car",
    "attach",
    "make_planner",
    "register",
    "render_episode",
    "run_episode",
    "run_experiment",
    "run_sweep",
    "scaled",
    "write_report",
]

if TYPE_CHECKING:  # for type checkers and IDEs; at run time see __getattr__
    from cdf_mj.config import CDFConfig, DriverPrior, LayeredConfig, RiskConfig, ScenarioConfig, SceneNames, scaled
    from cdf_mj.envs.t_intersection import TIntersectionEnv
    from cdf_mj.experiments.experiment import run_experiment
    from cdf_mj.experiments.sweep import run_sweep
    from cdf_mj.inference.particle_filter import ParticleFilter
    from cdf_mj.model.vehicle import CarGeometry
    from cdf_mj.planners.cdf import CDFPlanner
    from cdf_mj.planners.cv import CVPlanner
    from cdf_mj.planners.imm import IMMPlanner
    from cdf_mj.planners.registry import make_planner, register
    from cdf_mj.records import EpisodeRecord, Label
    from cdf_mj.scenario.episode import run_episode
    from cdf_mj.scenario.monitor import CDFMonitor, attach
    from cdf_mj.scenario.world import World
    from cdf_mj.sim.checks import SceneError
    from cdf_mj.sim.scene import Scene
    from cdf_mj.sim.spec import add_car
    from cdf_mj.sim.tracking import TrackedCar
    from cdf_mj.viz.render import render_episode
    from cdf_mj.viz.report import write_report


def _register_env() -> None:
    """Register ``cdf_mj/TIntersection-v0`` with Gymnasium if it is installed.

    Runs on ``import cdf_mj`` (so also in the worker processes of ``gymnasium.make_vec``,
    which import the entry point's package); without Gymnasium it does nothing and imports
    nothing. The entry point is a string: the environment module (and MuJoCo) loads only
    when the environment is made.
    """
    import importlib.util

    try:
        if importlib.util.find_spec("gymnasium") is None:
            return
    except (ImportError, ValueError):  # a broken or blocked installation: nothing to register
        return
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="cdf_mj.envs.t_intersection:TIntersectionEnv")


_register_env()


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
