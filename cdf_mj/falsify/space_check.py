"""A search space checked as a whole, before any episode: what each dimension alone allows
is checked where the file is read (:func:`cdf_mj.falsify.space.parse_space`: every end of
a range, every choice); here, what the dimensions allow together and what a scene allows.

* :func:`check_joint`: the base world with **every pair** of dimensions at their probe
  values (a range's two ends; a choice's values, or its least and greatest and its first
  and last where it has more than :data:`MAX_PROBES`), and with **every combination** of
  the dimensions of :data:`JOINT_KEYS` (the options that :class:`~cdf_mj.config.ScenarioConfig`
  checks against each other: the sensing latencies against the episode's ticks, what
  ``sensing.told`` tells the planner) at their probe values and at the base's own (a
  minimised counterexample falls back to it). A range over :data:`QUANTISED` options is
  refused: the values between its ends are not all values a scene takes.
* :func:`check_on_scene`: the world (:class:`~cdf_mj.scenario.world.World`) built on the
  run's scene at every probe value of every dimension, and with every dimension at its
  lows and at its highs: what the scene refuses (a ``timing.dt`` that is not a whole
  multiple of its timestep, an ego start off its route) is found before the first episode.

Every refusal is a :class:`~cdf_mj.falsify.space.SpaceError` of one line naming the file
and the dimensions with their values. ::

    from cdf_mj.falsify.space_check import check_on_scene

    check_on_scene(space, Scene.load(path))
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

from cdf_mj.falsify.space import Dim, Range, SearchSpace, SpaceError
from cdf_mj.inputs import printable

if TYPE_CHECKING:
    from cdf_mj.sim.scene import Scene

__all__ = ["JOINT_KEYS", "MAX_PROBES", "QUANTISED", "check_joint", "check_on_scene", "probes"]

#: The options that :class:`~cdf_mj.config.ScenarioConfig` checks against one another (not
#: each against its own range): checked at every combination of their probe values.
JOINT_KEYS = ("timing.dt", "timing.duration", "sensing.latency", "sensing.brake_latency", "sensing.told",
              "sensing.pos", "sensing.heading", "sensing.speed")
#: Options whose values a scene takes only on a grid (``timing.dt``: whole multiples of the
#: scene's timestep): a space gives them as choices, not as a range.
QUANTISED = {"timing.dt": "a whole multiple of the scene's timestep"}
#: Most values of a choice probed one by one; a longer one is probed at its least and
#: greatest value and its first and last.
MAX_PROBES = 8

#: The base's value of a dimension (a minimised counterexample falls back to it).
_BASE = None


def probes(dim: Dim) -> list[float]:
    """The coordinates of ``dim`` at which a space is checked: a range's two ends; every
    value of a choice of at most :data:`MAX_PROBES`, else its first and last and its least
    and greatest (numbers only)."""
    if isinstance(dim, Range):
        return [dim.low, dim.high] if dim.high != dim.low else [dim.low]
    n = len(dim.values)
    if n <= MAX_PROBES:
        return [float(i) for i in range(n)]
    picked = {0, n - 1}
    numbers = [i for i, v in enumerate(dim.values) if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if numbers:
        picked |= {min(numbers, key=lambda i: dim.values[i]), max(numbers, key=lambda i: dim.values[i])}
    return [float(i) for i in sorted(picked)]


def _shown(dim: Dim, x: float | None) -> str:
    if x is None:
        return f'[dims."{dim.key}"] at the base\'s value'
    value = dim.value(x)
    value = value[0] if isinstance(value, tuple) else value
    return f'[dims."{dim.key}"] = {value!r}'


def _where(space: SearchSpace, where: str | None) -> str:
    return where if where is not None else f"space {printable(space.source or space.name)}"


def _try(space: SearchSpace, where: str, combo: Sequence[tuple[Dim, float | None]]) -> None:
    """SpaceError naming the file and every dimension of ``combo`` unless the base world
    takes their values together."""
    values = {d.key: d.value(x) for d, x in combo if x is not _BASE}
    try:
        space.base.with_values(values)
    except ValueError as exc:
        given = " with ".join(_shown(d, x) for d, x in combo)
        raise SpaceError(f"{where}: {given}: {' '.join(str(exc).split())}") from None


def check_joint(space: SearchSpace, where: str | None = None) -> None:
    """SpaceError (one line naming ``where``, default the space's file, and the dimensions)
    for a range over a :data:`QUANTISED` option, or for values of two or more dimensions
    that the base world refuses together (see the module docstring)."""
    where = _where(space, where)
    for d in space.dims:
        if isinstance(d, Range) and d.key in QUANTISED and d.high > d.low:
            raise SpaceError(f'{where}: [dims."{d.key}"]: a range gives values between its ends, and {d.key} '
                             f"must be {QUANTISED[d.key]}: give its values as choices = [...]")
    for a, b in itertools.combinations(space.dims, 2):
        for xa, xb in itertools.product(probes(a), probes(b)):
            _try(space, where, ((a, xa), (b, xb)))
    joint = [d for d in space.dims if d.key in JOINT_KEYS]
    if len(joint) > 2:
        for xs in itertools.product(*[[*probes(d), _BASE] for d in joint]):
            _try(space, where, tuple(zip(joint, xs, strict=True)))


def _corners(space: SearchSpace) -> Iterator[tuple[tuple[Dim, float], ...]]:
    """Each dimension alone at each probe value, then all at their lows, then all at their
    highs (a choice's first and last value)."""
    for d in space.dims:
        for x in probes(d):
            yield ((d, x),)
    if len(space.dims) > 1:
        yield tuple((d, probes(d)[0]) for d in space.dims)
        yield tuple((d, probes(d)[-1]) for d in space.dims)


def check_on_scene(space: SearchSpace, scene: Scene, where: str | None = None) -> None:
    """SpaceError (one line naming ``where``, default the space's file, the dimensions and
    what the scene says) unless the world can be built on ``scene`` at every probe value of
    every dimension and with all dimensions at their lows and at their highs."""
    from cdf_mj.scenario.world import World

    where = _where(space, where)
    seen: set[str] = set()
    for combo in _corners(space):
        values: dict[str, Any] = {d.key: d.value(x) for d, x in combo}
        key = repr(sorted(values.items()))
        if key in seen:
            continue
        seen.add(key)
        try:
            World(scene, space.base.with_values(values))
        except ValueError as exc:  # SceneError too
            given = " with ".join(_shown(d, x) for d, x in combo) if len(combo) < 3 else "every dimension at its " + (
                "low" if all(x == probes(d)[0] for d, x in combo) else "high") + " end"
            raise SpaceError(f"{where}: {given}: {' '.join(str(exc).split())}") from None
