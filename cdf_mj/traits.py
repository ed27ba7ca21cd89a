"""The obstacle driver's traits, declared once, and the bounds of every configured number.

Each :class:`Trait` is one line of :data:`TRAITS`: its name, unit, allowed range, the
world's default and the filter's prior. Everything else that spells a trait is derived
from it, so that adding one is one line here plus its use in the model:

- the world's driver (:class:`cdf_mj.config.ObstacleDriver`, ``ScenarioConfig.obstacle``):
  one field per trait, validated against its range;
- the filter's model of it (:class:`cdf_mj.config.DriverPrior`): the same names, each a
  ``(low, high)`` range drawn per particle, or one fixed value (``prior``);
- the per-car arguments of the driver kernels (:data:`PER_CAR`: the columns of
  :class:`cdf_mj.model.driver.DriverParams` and the first columns of the particles'
  parameters :data:`THETA`), and the traits packed into the driver's float vector
  (:data:`SHARED`, :data:`cdf_mj.model.kernels.DRIVER_FIELDS`), whose index constants the
  kernel modules compute from these names at import.

Numba's cache keys a compiled kernel on its own file's text, not on these names: each
kernel file carries a ``LAYOUT`` stamp, the digest of the names its offsets come from. A
change that moves a column or an offset makes the kernels compile without Numba's cache
(with a warning) until the stamp is updated to the digest that ``tests/test_traits.py``
prints; a stale kernel is never loaded. Importing this module compiles nothing::

    from cdf_mj.traits import TRAITS, THETA
    [t.name for t in TRAITS if t.prior is not None]     # the filter models these
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

__all__ = ["MAX_ACCEL", "MAX_DURATION", "MAX_LENGTH", "MAX_SPEED", "PER_CAR", "PRIOR_RANGES", "SHARED", "THETA",
           "TRAITS", "Range", "Trait", "bounded", "check", "finite", "pair_ok", "trait", "validate", "with_traits",
           "within"]

T = TypeVar("T")

# Upper bounds of physical values, far beyond any meaningful one: an absurd number is one
# clear error up front, never records of nonsense later (cdf_mj.config has the others).
#: Episode length and any other duration: 10 minutes is 6000 ticks at dt 0.1 s [s].
MAX_DURATION = 600.0
#: Any other length (margins, look-ahead, creep, std of a position) [m].
MAX_LENGTH = 1000.0
#: Any speed or speed std: 360 km/h [m/s].
MAX_SPEED = 100.0
#: Any acceleration, braking or its std: about 10 g [m/s^2].
MAX_ACCEL = 100.0
#: Any jerk (rate of change of acceleration): a brake that reaches 1 g in 10 ms [m/s^3].
MAX_JERK = 1000.0


# ------------------------------------------------------------------------------ checks
def check(cond: bool, name: str, value: object, allowed: str) -> None:
    """ValueError ``"{name}={value} is out of range: must be {allowed}"`` unless ``cond``."""
    if not cond:
        text = repr(value)  # a 400-digit number or a long list: its start and length suffice
        shown = text if len(text) <= 60 else f"{text[:40]}...({len(text)} characters)"
        raise ValueError(f"{name}={shown} is out of range: must be {allowed}")


def finite(*values: Any) -> bool:
    """Whether every value is a real number (not a bool, not a string) that is finite as a
    float (a 400-digit integer is not)."""
    try:
        return all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
                   for v in values)
    except OverflowError:
        return False


def within(value: Any, low: float, high: float, *, open_low: bool = False) -> bool:
    """Whether ``value`` is a finite real in ``[low, high]`` (``(low, high]`` with ``open_low``)."""
    return finite(value) and (value > low if open_low else value >= low) and value <= high


def pair_ok(pair: Any, low: float, positive: bool = False, high: float = math.inf) -> bool:
    """Whether ``pair`` is a finite ``(lo, hi)`` of numbers with ``low <= lo <= hi <= high``
    (``lo > low`` where ``positive``)."""
    if isinstance(pair, (str, bytes, Mapping)):
        return False
    try:
        first, second = pair
    except (TypeError, ValueError):
        return False
    if not finite(first, second):
        return False
    lo, hi = float(first), float(second)
    return (lo > low if positive else lo >= low) and lo <= hi <= high


@dataclass(frozen=True)
class Range:
    """The allowed values of a number, or of both ends of a ``(low, high)`` pair (``pair``):
    ``[low, high]``, or ``(low, high]`` with ``open_low``, in ``unit``; ``note`` is added to
    the error message."""

    low: float
    high: float
    unit: str  # "1" for a probability
    open_low: bool = False
    pair: bool = False
    note: str = ""

    def allowed(self) -> str:
        """What the error message says is allowed."""
        lo, hi = f"{self.low:g}", f"{self.high:g}"
        unit = " (a probability)" if self.unit == "1" else f" [{self.unit}]"
        if self.pair:
            text = f"a finite (low, high) pair with {lo} {'<' if self.open_low else '<='} low <= high <= {hi}{unit}"
        elif self.open_low:
            text = f"> {lo} and <= {hi}{unit}"
        else:
            text = f"in [{lo}, {hi}]{unit}"
        return f"{text} {self.note}" if self.note else text

    def check(self, name: str, value: Any) -> None:
        """ValueError naming ``name``, the value and :meth:`allowed` if ``value`` is not allowed."""
        ok = (pair_ok(value, self.low, positive=self.open_low, high=self.high) if self.pair
              else within(value, self.low, self.high, open_low=self.open_low))
        check(ok, name, value, self.allowed())


def bounded(default: Any, low: float, high: float, unit: str, *, open_low: bool = False, note: str = "") -> Any:
    """A dataclass field with ``default`` whose values :func:`validate` checks against
    ``Range(low, high, unit, open_low, pair)`` (a pair where the default is a tuple)."""
    pair = isinstance(default, tuple)
    return field(default=default, metadata={"range": Range(low, high, unit, open_low, pair, note)})


def validate(obj: Any, prefix: str) -> None:
    """Check every field of the dataclass ``obj`` that has a range (:func:`bounded`, the
    traits), naming it ``prefix + name``; a list read from JSON or TOML becomes a tuple."""
    for f in dataclasses.fields(obj):
        rng: Range | None = f.metadata.get("range")
        if rng is None:
            continue
        value = getattr(obj, f.name)
        if rng.pair and isinstance(value, list):
            value = tuple(value)
            object.__setattr__(obj, f.name, value)
        rng.check(prefix + f.name, value)


# ------------------------------------------------------------------------------ traits
@dataclass(frozen=True)
class Trait:
    """One trait of the obstacle driver (see the module docstring).

    ``prior``: the filter's model of it, a ``(low, high)`` range that each particle draws
    from (uniformly, a column of :data:`THETA`), one fixed value, or None (the filter's
    model has no such trait). ``kernel``: how the compiled driver reads it: ``"per_car"``
    (an argument per car: a column of ``DriverParams`` and of ``THETA``; needs a range
    prior), ``"shared"`` (one value for every car, packed into the driver's float vector),
    or ``""`` (read in Python only).
    """

    name: str
    default: float | tuple[float, float]  # the world's value
    range: Range  # allowed values (of each end, for a pair)
    prior: float | tuple[float, float] | None = None
    kernel: str = ""
    doc: str = ""


def trait(name: str, unit: str, default: float | tuple[float, float], low: float, high: float, *,
          open_low: bool = False, prior: float | tuple[float, float] | None = None, kernel: str = "",
          doc: str = "") -> Trait:
    """One :class:`Trait` (a pair where ``default`` is a tuple)."""
    return Trait(name, default, Range(low, high, unit, open_low, isinstance(default, tuple)), prior, kernel, doc)


#: The obstacle driver's traits, in the order of the fields of ``ScenarioConfig.obstacle``.
TRAITS: tuple[Trait, ...] = (
    trait("p_left", "1", 0.75, 0.0, 1.0, prior=0.75, doc="P(intent = left), paper: 0.75"),
    trait("beta", "1/tick", 0.05, 0.0, 1.0, prior=(0.03, 0.07),
          doc="P(observes the ego | the ego visible) per tick, paper: 0.05"),
    trait("accel", "m/s^2", 2.5, 0.0, MAX_ACCEL, open_low=True, prior=(1.5, 3.0), kernel="per_car",
          doc="pulling-out acceleration (moderate, urban; the car's limit is 3.0)"),
    trait("turn_speed", "m/s", 8.0, 0.0, MAX_SPEED, open_low=True, prior=(6.0, 10.0), kernel="per_car",
          doc="cruise speed through and after the turn"),
    trait("yield_brake", "m/s^2", 4.0, 0.0, MAX_ACCEL, open_low=True, prior=(3.0, 5.0), kernel="per_car",
          doc="braking when it decides to yield"),
    trait("critical_gap", "s", 5.0, 0.0, MAX_DURATION, open_low=True, prior=(4.0, 7.0), kernel="per_car",
          doc="goes if the believed ego needs longer than this to reach the conflict point: a typical "
              "accepted gap for a left turn from a minor road (HCM: 6-7 s)"),
    trait("clear_distance", "m", 10.0, 0.0, MAX_LENGTH, prior=(7.0, 13.0), kernel="per_car",
          doc="a believed ego nearer the conflict point (not past it by passed_margin) is never clear: about "
              "two car lengths at the ego's rear axle, so that a stopped ego is not taken for a gap"),
    trait("passed_margin", "m", 3.0, 0.0, MAX_LENGTH, prior=3.0, kernel="shared",
          doc="a believed ego past the conflict point by this is gone"),
    trait("stop_dwell", "s", (0.0, 0.0), 0.0, MAX_DURATION,
          doc="wait at the stop line, uniform (low, high), drawn per episode; t = 0 is the end of the full "
              "stop in the paper's scenario, so (0, 0)"),
    trait("departure_look", "1", 0.0, 0.0, 1.0,
          doc="P(looks once more on the tick it would leave the line), on top of the beta draw"),
    trait("hesitation", "1", 0.0, 0.0, 1.0,
          doc="P(stops again once after leaving the line), per episode; the filter's model has no such stop"),
    trait("hesitation_creep", "m", 0.7, 0.0, MAX_LENGTH, open_low=True,
          doc="travelled from the line before that stop (within the 1.45 m to the commit point)"),
    trait("hesitation_pause", "s", (0.5, 1.5), 0.0, MAX_DURATION, doc="length of that stop, uniform (low, high)"),
)

#: The per-car arguments of the driver kernels, in order: ``DriverParams`` columns.
PER_CAR: tuple[str, ...] = tuple(t.name for t in TRAITS if t.kernel == "per_car")
#: The traits packed into the driver's float vector (one value for every car).
SHARED: tuple[str, ...] = tuple(t.name for t in TRAITS if t.kernel == "shared")
#: The traits each particle draws from a range of the prior.
PRIOR_RANGES: tuple[str, ...] = tuple(t.name for t in TRAITS if isinstance(t.prior, tuple))
#: Columns of the particles' parameters ``ParticleFilter.theta``: the per-car traits, the
#: other ranges of the prior, and the departure hazard as a per-tick probability ``p_go``.
THETA: tuple[str, ...] = (*PER_CAR, *(n for n in PRIOR_RANGES if n not in PER_CAR), "p_go")


def _check_schema() -> None:
    """The schema's own rules (run at import): distinct names, per-car traits with a range."""
    names = [t.name for t in TRAITS]
    if len(set(names)) != len(names) or "p_go" in names:
        raise ValueError(f"cdf_mj.traits: trait names must be distinct and not 'p_go': {names}")
    for t in TRAITS:
        if t.kernel not in ("", "per_car", "shared"):
            raise ValueError(f"cdf_mj.traits: {t.name}: kernel must be '', 'per_car' or 'shared'")
        if t.kernel == "per_car" and not isinstance(t.prior, tuple):
            raise ValueError(f"cdf_mj.traits: {t.name}: a per-car trait needs a (low, high) prior")
        if t.kernel == "shared" and not isinstance(t.prior, float):
            raise ValueError(f"cdf_mj.traits: {t.name}: a shared trait needs one value as its prior (the filter's)")


_check_schema()


def _prior_range(t: Trait) -> Range:
    """The range a prior of ``t`` must lie in: a pair inside the trait's own range, or one value."""
    return dataclasses.replace(t.range, pair=isinstance(t.prior, tuple))


def with_traits(role: str) -> Callable[[type[T]], type[T]]:
    """Class decorator, applied under ``@dataclass``: one field per trait, before the
    class's own fields. ``role``: ``"world"`` (every trait, its default and range),
    ``"prior"`` (those with a prior: its range or value as the default) or ``"car"`` (the
    per-car traits, no default)."""
    if role not in ("world", "prior", "car"):
        raise ValueError(f"with_traits: role must be 'world', 'prior' or 'car', got {role!r}")

    def add(cls: type[T]) -> type[T]:
        own = dict(inspect.get_annotations(cls))
        annotations: dict[str, Any] = {}
        for t in TRAITS:
            if role == "world":
                value: Any = field(default=t.default, metadata={"range": t.range, "trait": t})
                kind = "tuple[float, float]" if t.range.pair else "float"
            elif role == "prior" and t.prior is not None:
                value = field(default=t.prior, metadata={"range": _prior_range(t), "trait": t})
                kind = "tuple[float, float]" if isinstance(t.prior, tuple) else "float"
            elif role == "car" and t.kernel == "per_car":
                value, kind = field(metadata={"trait": t}), "float | np.ndarray"
            else:
                continue
            if t.name in own:
                raise TypeError(f"{cls.__name__}: field {t.name!r} is a trait of cdf_mj.traits; do not declare it")
            annotations[t.name] = kind
            setattr(cls, t.name, value)
        cls.__annotations__ = {**annotations, **own}
        return cls

    return add
