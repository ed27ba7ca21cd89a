"""The registry of planners by name, in the style of ``gymnasium.envs.registration``.

A registry entry (:class:`PlannerSpec`) carries its target and its default constructor
arguments; ``make_planner(name, **kwargs)`` updates them with the caller's and builds.
Every component that builds a planner (episodes, experiments, sweeps, the CLI, videos,
reports) calls it, and a stored run keeps each planner's arguments
(:func:`planner_arguments`) so that it can be rebuilt exactly. :func:`register` adds one,
by a ``"module:Class"`` string (imported on first use) or by any callable::

    register("mine", "my_package.planners:MyPlanner", horizon=2.0)
    planner = make_planner("mine", horizon=3.0)

The registry names its planners by string: it imports none of their modules (no cycle,
and filterpy loads only with the first ``imm`` planner made).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from cdf_mj.config import CDFConfig
from cdf_mj.planners.base import Planner, as_config
from cdf_mj.records.files import jsonable

__all__ = ["PLANNERS", "LazyPlanner", "PlannerSpec", "bind_planner", "make_planner", "planner_arguments",
           "planner_spec", "register", "shared_arguments", "stored_planner_arguments"]


#: Planner classes whose ``reset`` signature has been checked.
_CHECKED: set[type] = set()


def _check_reset(cls: type[Planner]) -> None:
    """TypeError, in one line, for a planner class whose ``reset`` still takes the
    ``(layout, config, rng)`` of version 0.1 (checked once per class)."""
    if cls in _CHECKED:
        return
    try:
        params = [p for p in inspect.signature(cls.reset).parameters.values()
                  if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    except (TypeError, ValueError):
        params = []
    if len(params) == 4:  # self, layout, config, rng
        raise TypeError(f"planner class {cls.__name__}: reset(self, layout, config, rng) is the form of "
                        "cdf_mj 0.1; a planner's reset now takes (self, context, rng), where context is a "
                        "cdf_mj.planners.PlannerContext (layout, dt, nominal_speed, speed_gain): a planner is "
                        "told only what the ego knows")
    _CHECKED.add(cls)


@dataclass(frozen=True)
class LazyPlanner:
    """A planner class named ``"module:Class"``, imported when a planner is first made.

    Picklable (worker processes get the string) and free of import cycles: registering
    a planner imports nothing. Calling it with the constructor's arguments returns a new
    planner.
    """

    target: str  # "package.module:ClassName"

    def __post_init__(self) -> None:
        module, _, cls = self.target.partition(":")
        if not (module and cls and all(p.isidentifier() for p in (*module.split("."), cls))):
            raise ValueError(f"planner target {self.target!r} must be 'package.module:ClassName'")

    def resolve(self) -> Callable[..., Planner]:
        """The class (or factory) the target names; ImportError if it cannot be imported."""
        module, _, cls = self.target.partition(":")
        try:
            factory: Callable[..., Planner] = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as exc:
            raise ImportError(f"planner target {self.target!r} cannot be imported: {exc}") from exc
        return factory

    def __call__(self, **kwargs: Any) -> Planner:
        return self.resolve()(**kwargs)


@dataclass(frozen=True)
class PlannerSpec:
    """A registry entry: how to build one named planner (``gymnasium.envs.registration``'s
    ``EnvSpec`` for planners).

    ``target`` builds it (a :class:`LazyPlanner`, or a picklable callable); ``kwargs`` are
    its constructor arguments; ``shared`` names the settings of a run that it takes from
    the run's shared CDF configuration (``"cdf"``: the whole :class:`~cdf_mj.config.CDFConfig`,
    ``"risk"``: its :class:`~cdf_mj.config.RiskConfig`, so that every planner with the risk
    rule decides alike), see :func:`shared_arguments`. Calling a spec builds a fresh planner
    (a picklable zero-argument factory for worker processes).
    """

    name: str
    target: Callable[..., Planner]
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    shared: tuple[str, ...] = ()

    def make(self, **kwargs: Any) -> Planner:
        """A fresh planner with the spec's arguments updated by ``kwargs``. TypeError, naming
        the planner, for arguments its constructor does not take or for a target that does
        not make a :class:`Planner`."""
        args = {**self.kwargs, **kwargs}
        try:
            planner = self.target(**args)
        except TypeError as exc:
            raise TypeError(f"planner {self.name!r}: {exc}") from None
        if not isinstance(planner, Planner):
            raise TypeError(f"planner {self.name!r} made a {type(planner).__name__}, not a cdf_mj.planners.Planner")
        _check_reset(type(planner))
        return planner

    def __call__(self) -> Planner:
        return self.make()

    def bind(self, **kwargs: Any) -> PlannerSpec:
        """The same entry with ``kwargs`` added to its arguments."""
        return dataclasses.replace(self, kwargs={**self.kwargs, **kwargs})

    def arguments(self) -> dict[str, Any]:
        """The spec's arguments as JSON (configuration dataclasses as objects), what a stored
        run keeps; ``make(**arguments())`` builds the same planner."""
        return {k: jsonable(v) for k, v in self.kwargs.items()}


#: The registered planners by name (:func:`register`, :func:`make_planner`). A plain
#: factory put here by hand is read as an entry without arguments.
PLANNERS: dict[str, PlannerSpec | Callable[..., Planner]] = {}


def register(name: str, target: str | Callable[..., Planner], *, shared: Sequence[str] = (),
             **kwargs: Any) -> None:
    """Make a planner available by ``name`` (to ``run_episode``, experiments and the CLI).

    ``target`` is ``"package.module:ClassName"`` (imported on first use; worker processes
    import it by name, so it works with any start method) or a callable returning a fresh
    planner (a class, a ``functools.partial``; it must be picklable to run in worker
    processes). ``kwargs`` are its default constructor arguments; ``shared`` the run's
    shared settings it takes (``"cdf"``, ``"risk"``: :class:`PlannerSpec`). Registering a
    name again replaces it. ValueError for an empty name, a malformed target string or an
    unknown shared setting; TypeError for a target that is neither.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"a planner name must be a non-empty string, got {name!r}")
    bad = [s for s in shared if s not in _SHARED]
    if bad:
        raise ValueError(f"planner {name!r}: shared settings {bad} unknown; choose from {sorted(_SHARED)}")
    if isinstance(target, str):
        factory: Callable[..., Planner] = LazyPlanner(target)
    elif callable(target):
        factory = target
    else:
        raise TypeError(f"planner {name!r}: target must be 'module:Class' or a callable, "
                        f"got {type(target).__name__}")
    PLANNERS[name] = PlannerSpec(name, factory, dict(kwargs), tuple(shared))


def planner_spec(name: str) -> PlannerSpec:
    """The registry entry of ``name``; ValueError naming the registered planners if unknown."""
    try:
        spec = PLANNERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown planner {name!r}: choose one of {', '.join(sorted(PLANNERS))}") from None
    if not isinstance(spec, PlannerSpec):  # a factory put into PLANNERS by hand (version 0.1 did so)
        spec = PlannerSpec(name, spec)
    return spec


def make_planner(name: str | Planner, **kwargs: Any) -> Planner:
    """A fresh planner from its registered name, its registered arguments updated by
    ``kwargs``; planner objects pass through (with no ``kwargs``). ValueError naming the
    registered planners for an unknown name; TypeError for arguments it does not take."""
    if isinstance(name, Planner):
        if kwargs:
            raise TypeError(f"make_planner: arguments {sorted(kwargs)} given with a planner object; "
                            "pass a registered name to build one with them")
        _check_reset(type(name))
        return name
    return planner_spec(name).make(**kwargs)


def planner_arguments(name: str, **kwargs: Any) -> dict[str, Any]:
    """The JSON constructor arguments of planner ``name`` with ``kwargs`` (what a stored run
    keeps; ``make_planner(name, **planner_arguments(name, **kwargs))`` builds the same)."""
    return planner_spec(name).bind(**kwargs).arguments()


#: The shared settings a registered planner may take from a run's CDF configuration.
_SHARED: dict[str, Callable[[Any], Any]] = {"cdf": lambda cdf: cdf, "risk": lambda cdf: cdf.risk}


def shared_arguments(name: str, cdf: Any) -> dict[str, Any]:
    """The constructor arguments planner ``name`` takes from a run's shared
    :class:`~cdf_mj.config.CDFConfig` ``cdf`` (its ``shared`` settings: the CDF planners
    the whole configuration, the ``-risk`` baselines its risk rule); ``{}`` for the others."""
    return {key: _SHARED[key](cdf) for key in planner_spec(name).shared}


def bind_planner(name: str, cdf: CDFConfig | None = None, arguments: Mapping[str, Any] | None = None) -> PlannerSpec:
    """The registry entry of planner ``name`` bound to a run's arguments: what it takes of
    the run's shared :class:`~cdf_mj.config.CDFConfig` (:func:`shared_arguments`; default
    ``CDFConfig()``), updated by its own ``arguments``. Every component that runs planners
    (experiments, sweeps, videos, reports) builds them through it. A picklable
    zero-argument factory; ValueError for an unknown name."""
    shared = shared_arguments(name, cdf if cdf is not None else CDFConfig())
    return planner_spec(name).bind(**{**shared, **(arguments or {})})


def stored_planner_arguments(settings: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Each planner's constructor arguments in a stored run's settings (``settings.json``):
    its ``planner_args``, or, for a run stored before they were kept, what each registered
    planner took of the run's ``cdf`` settings (:func:`bind_planner`). ValueError (or
    TypeError) for ``cdf`` settings this version cannot read."""
    stored = settings.get("planner_args")
    if isinstance(stored, Mapping):
        return {str(k): dict(v) for k, v in stored.items() if isinstance(v, Mapping)}
    cdf = as_config(settings.get("cdf"), CDFConfig, "settings.json cdf")
    return {name: bind_planner(name, cdf).arguments() if name in PLANNERS else {}
            for name in settings.get("planners", ())}


register("constant", "cdf_mj.planners.simple:ConstantPlanner")
register("reactive", "cdf_mj.planners.simple:ReactivePlanner")
register("cdf", "cdf_mj.planners.cdf:CDFPlanner", shared=("cdf",))
register("cdf-option", "cdf_mj.planners.cdf:OptionCDFPlanner", shared=("cdf",))
register("cdf-risk", "cdf_mj.planners.cdf:RiskCDFPlanner", shared=("cdf",))
register("cdf-threshold", "cdf_mj.planners.cdf:ThresholdCDFPlanner", shared=("cdf",))
register("cv", "cdf_mj.planners.cv:CVPlanner")
register("cv-risk", "cdf_mj.planners.cv:CVRiskPlanner", shared=("risk",))
register("cv-layered", "cdf_mj.planners.cv:CVLayeredPlanner", shared=("risk",))
register("caution-waiting", "cdf_mj.planners.caution:CautionWaitingPlanner", shared=("cdf",))
register("caution-moving", "cdf_mj.planners.caution:CautionMovingPlanner", shared=("cdf",))
register("caution-phantom", "cdf_mj.planners.caution:PhantomPlanner", shared=("cdf",))
register("imm", "cdf_mj.planners.imm:IMMPlanner")
register("imm-risk", "cdf_mj.planners.imm:IMMRiskPlanner", shared=("risk",))
register("imm-layered", "cdf_mj.planners.imm:IMMLayeredPlanner", shared=("risk",))
