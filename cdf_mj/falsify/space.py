"""A search space over the world: which options of :class:`~cdf_mj.config.ScenarioConfig`
a falsification varies, their ranges, their nominal distribution, and what counts as a
failure. Declared in a TOML file (the package's ``default`` space, or one of your own)::

    description = "Who varies what, and why."
    preset = "default"                 # the world the space varies (a preset name or .toml file)

    [failure]
    margin = "gap"                     # gap [m] | ttc [s] | headway [s]
    threshold = 0.0                    # a collision, or the margin at or below this, fails

    [dims."obstacle.family"]           # a choice: its values, and their nominal weights
    choices = ["model", "aggressive"]
    weights = [0.9, 0.1]

    [dims."ego.start_spread"]          # a range; a (low, high) option is pinned to (v, v)
    range = [-8.0, 8.0]                # nominal: uniform on the range ...

    [dims."ego.speed"]
    range = [9.0, 18.0]
    mean = 13.4                        # ... or a normal truncated to it
    std = 1.5

    [dims."sensing.latency"]           # an integer option: every whole value of the range
    range = [0, 3]
    weights = [0.7, 0.15, 0.1, 0.05]   # nominal weights (default: equal)

A point of the space is one value per dimension (a row of floats: a range's value, a
choice's index); :meth:`SearchSpace.config` is its world, the base preset with each option
set (a pair option pinned to the value, so the world draws nothing for it). What the space
does not name (the obstacle family's own parameters, the noise of each tick) is drawn from
the episode's seed: a failure is a point *and* a seed.

The nominal distribution (each dimension independent) is what "per encounter" means for
:mod:`cdf_mj.falsify.estimate`: the declared mix of drivers, behaviours and sensing that a
probability of failure is taken over. The search itself (:mod:`cdf_mj.falsify.search`)
reads only the ranges.

Options and choices are read as ``--set`` and presets read them
(:mod:`cdf_mj.config.user_values`): the same types, the same words, and a flat key of
version 0.1 (``[dims."beta"]``) taken with a :class:`~cdf_mj.config.FlatKeyWarning`. Every
mistake in a file (not TOML, an unknown key or option, a range that is empty, inverted or
not finite, weights that do not match, a value the world refuses) is a
:class:`SpaceError` of one line naming the file and the dimension.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from cdf_mj.config import ScenarioConfig
from cdf_mj.config.user_values import UserValueError, apply_values, coerce_value, dotted_key
from cdf_mj.inputs import (
    PRESET_MAX_BYTES,
    TOML_SUFFIX,
    is_path,
    packaged_files,
    parse_user_toml,
    printable,
    read_named,
)
from cdf_mj.presets import PresetError, read_preset

__all__ = [
    "LATENT_CAP",
    "MARGINS",
    "MARGIN_CAP",
    "MAX_DIMS",
    "MAX_VALUES",
    "PET_GAP_SPEED",
    "Choice",
    "Dim",
    "FailureSpec",
    "Range",
    "SearchSpace",
    "SpaceError",
    "load_space",
    "space_names",
    "truncnorm_logpdf",
    "truncnorm_matching",
    "truncnorm_moments",
    "truncnorm_sample",
]

#: What a failure's margin may be: the least bumper-to-bumper gap [m] (the record's
#: ``min_gap``), the least time to collision [s], the least time headway [s] or the
#: post-encroachment time at the conflict area [s] (its ``safety.min_ttc`` /
#: ``safety.min_headway`` / ``safety.pet``, docs/SAFETY.md).
MARGINS = ("gap", "ttc", "headway", "pet")
#: [s] The margin of an episode in which a time margin never happened (never closing,
#: never following): far above any threshold, and finite for the search.
MARGIN_CAP = 10.0
#: Most dimensions of a space: the search's and the estimator's cost grow with them.
MAX_DIMS = 64
#: Most values of one choice or integer range.
MAX_VALUES = 1000
#: [m/s] With the ``pet`` margin, two cars in the conflict area on one tick (a PET of 0)
#: read their least gap at this speed [s]: 0 only at contact, as the other margins.
PET_GAP_SPEED = 10.0
#: The search's standard-normal coordinates are read within this many standard deviations:
#: a range whose nominal is far narrower than it is searched within about 8 of the
#: nominal's standard deviations of its mean (beyond, the nominal density is below e^-32);
#: to have a far corner searched, give the space a wider nominal there.
LATENT_CAP = 8.0
SUFFIX = TOML_SUFFIX
_TOP = ("description", "preset", "failure", "dims")
_NORMAL = NormalDist()


class SpaceError(ValueError):
    """A space file that cannot be read or used; one line naming the file and the dimension."""


@dataclass(frozen=True)
class FailureSpec:
    """What fails: a collision, or the ``margin`` at or below ``threshold`` (its unit).

    :meth:`robustness` is the signed distance to failure that the search lowers: the
    margin less the threshold, at most 0 for a collision; an episode fails where it is <= 0.
    A gap or a TTC of 0 is a collision, so threshold 0 on either fails collisions only;
    they guide a search differently: the least gap is over the whole episode, so a
    right-turner passing the ego 1 m away in its own lane reads nearer failure than a
    pull-out 3 m ahead of a fast ego; the least TTC is over the ticks with the obstacle in
    the ego's lane and falls with the closing speed (the default space's margin), so on a
    narrow junction a right-turner whose turn sweeps into the ego's lane reads near failure
    too. The post-encroachment time (``pet``) is the time between one car leaving the
    conflict area and the other entering it: only crossing traffic has one (a car passing
    in its own lane never enters, and reads the cap), and it falls smoothly as their
    crossings come closer in time; where both are in the area on one tick it reads their
    least gap over :data:`PET_GAP_SPEED`, so that it too is 0 only at contact and
    threshold 0 fails collisions only.
    """

    margin: str = "gap"
    threshold: float = 0.0

    def robustness(self, record: Mapping[str, Any]) -> float:
        """Signed distance to failure of an episode record (a dict) [m or s]: <= 0 fails."""
        if self.margin == "gap":
            value = float(record["min_gap"])
        else:
            safety = record.get("safety") or {}
            got = safety.get({"ttc": "min_ttc", "headway": "min_headway", "pet": "pet"}[self.margin])
            value = MARGIN_CAP if got is None else min(float(got), MARGIN_CAP)
            if self.margin == "pet" and got is not None and value <= 0.0:  # both in the conflict area together:
                value = max(float(record["min_gap"]), 0.0) / PET_GAP_SPEED  # how near they came, as time
        r = value - self.threshold
        return min(r, 0.0) if record.get("collision") else r

    @property
    def text(self) -> str:
        """In words, for reports."""
        if self.threshold == 0.0 and self.margin in ("gap", "ttc", "pet"):
            return "a collision"
        unit = "m" if self.margin == "gap" else "s"
        return f"a collision, or the least {self.margin} at or below {self.threshold:g} {unit}"


@dataclass(frozen=True)
class Range:
    """A continuous dimension: ``key`` takes a value in ``[low, high]`` (a pair option is
    pinned to ``(v, v)``). Nominal: uniform, or a normal (``mean``, ``std``) truncated to the range."""

    key: str
    low: float
    high: float
    mean: float | None = None
    std: float | None = None
    pair: bool = False  # the option is a (low, high) pair

    discrete = False

    @property
    def width(self) -> float:
        return self.high - self.low

    def value(self, x: float) -> Any:
        """The option's value at point coordinate ``x`` (the option's unit; clipped to the
        range; a pair option as ``(x, x)``)."""
        v = float(min(max(x, self.low), self.high))
        return (v, v) if self.pair else v

    def from_unit(self, u: float) -> float:
        """The coordinate (the option's unit) at ``u`` in [0, 1] of the range."""
        return self.low + float(min(max(u, 0.0), 1.0)) * self.width

    def to_unit(self, x: float) -> float:
        """The share of the range at coordinate ``x``."""
        return (x - self.low) / self.width

    def nominal_mean_std(self) -> tuple[float, float]:
        """The nominal's location and scale as a truncated normal's (a uniform is one of
        very large std centred on the range)."""
        if self.mean is None or self.std is None:
            return (self.low + self.high) / 2, math.inf
        return self.mean, self.std

    def from_latent(self, z: float) -> float:
        """The coordinate at standard-normal ``z``: its nominal's inverse CDF at Phi(z), so
        that ``z ~ N(0, 1)`` gives the nominal distribution."""
        u = _NORMAL.cdf(float(min(max(z, -LATENT_CAP), LATENT_CAP)))
        mean, std = self.nominal_mean_std()
        if _flat(std, self.low, self.high):
            return self.from_unit(u)
        a, b = _NORMAL.cdf((self.low - mean) / std), _NORMAL.cdf((self.high - mean) / std)
        q = min(max(a + u * (b - a), 1e-15), 1 - 1e-15)
        return float(min(max(mean + std * _NORMAL.inv_cdf(q), self.low), self.high))

    def log_nominal(self, x: np.ndarray) -> np.ndarray:
        """Log density of the nominal at coordinates ``x`` [per the option's unit]."""
        return truncnorm_logpdf(x, *self.nominal_mean_std(), self.low, self.high)


@dataclass(frozen=True)
class Choice:
    """A discrete dimension: ``key`` takes one of ``values``; nominal probabilities ``weights``."""

    key: str
    values: tuple[Any, ...]
    weights: tuple[float, ...]

    discrete = True

    def value(self, x: float) -> Any:
        """The value at coordinate ``x`` (a value's index, rounded)."""
        return self.values[self.index(x)]

    def index(self, x: float) -> int:
        """The index of coordinate ``x``, rounded and clipped."""
        return int(min(max(round(x), 0), len(self.values) - 1))

    def from_unit(self, u: float) -> float:
        """The index at ``u`` in [0, 1): the unit interval cut into equal parts."""
        return float(min(int(float(min(max(u, 0.0), 1.0)) * len(self.values)), len(self.values) - 1))

    def to_unit(self, x: float) -> float:
        """The middle of index ``x``'s part of the unit interval."""
        return (self.index(x) + 0.5) / len(self.values)

    def from_latent(self, z: float) -> float:
        """The index at standard-normal ``z``: Phi(z) cut by the nominal weights' cumulative
        sums, so that ``z ~ N(0, 1)`` draws each value with its nominal weight."""
        u = _NORMAL.cdf(float(min(max(z, -LATENT_CAP), LATENT_CAP)))
        cum = np.cumsum(self.weights)
        cum = cum / cum[-1]
        last = max(i for i, w in enumerate(self.weights) if w > 0)  # never a value of weight 0 past the last
        return float(min(int(np.searchsorted(cum, u, side="right")), last))

    def log_nominal(self, x: np.ndarray) -> np.ndarray:
        """Log of the nominal weight of the values at coordinates ``x``."""
        w = np.asarray(self.weights, dtype=float) / sum(self.weights)
        idx = np.clip(np.rint(np.asarray(x, dtype=float)).astype(int), 0, len(w) - 1)
        with np.errstate(divide="ignore"):
            return np.log(w[idx])


Dim = Range | Choice


@dataclass(frozen=True)
class SearchSpace:
    """A declared space (see the module docstring); build it with :func:`load_space`.

    A point is a float array of one coordinate per dimension, in ``dims`` order: a
    range's value in its unit, a choice's index.
    """

    name: str
    description: str
    preset: str  # what the base world was read from
    base: ScenarioConfig
    failure: FailureSpec
    dims: tuple[Dim, ...]
    source: str = ""
    text: str = field(default="", repr=False)  # the file, as read (stored beside a run)

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(d.key for d in self.dims)

    def values(self, point: Sequence[float]) -> dict[str, Any]:
        """Option key -> value at ``point`` (pairs as one number: the pinned value)."""
        out = {}
        for d, x in zip(self.dims, point, strict=True):
            v = d.value(float(x))
            out[d.key] = v[0] if isinstance(v, tuple) else v
        return out

    def config(self, point: Sequence[float], keep: Sequence[str] = ()) -> ScenarioConfig:
        """The world at ``point``: the base with every option set, but those in ``keep``,
        which stay the base's (the defaults a minimised failure falls back to)."""
        values = {d.key: d.value(float(x)) for d, x in zip(self.dims, point, strict=True) if d.key not in keep}
        return self.base.with_values(values)

    def from_unit(self, u: Sequence[float]) -> np.ndarray:
        """The point of a unit-cube vector (the old search's coordinates): each range scaled,
        each choice's ``[0, 1)`` cut into equal parts."""
        return np.array([d.from_unit(float(x)) for d, x in zip(self.dims, u, strict=True)])

    def to_unit(self, point: Sequence[float]) -> np.ndarray:
        return np.array([d.to_unit(float(x)) for d, x in zip(self.dims, point, strict=True)])

    def from_latent(self, z: Sequence[float]) -> np.ndarray:
        """The point of a standard-normal vector (the search's coordinates): each dimension
        through its nominal's inverse CDF, so that ``z ~ N(0, I)`` is a nominal draw."""
        return np.array([d.from_latent(float(x)) for d, x in zip(self.dims, z, strict=True)])

    def log_likelihood(self, points: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
        """Log-likelihood of each point under the nominal (a density for the ranges times a
        probability for the choices): how likely the world is per encounter, up to the
        ranges' units. Shape ``(n,)`` for ``points`` ``(n, d)``."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        out = np.zeros(len(pts))
        for j, d in enumerate(self.dims):
            out += d.log_nominal(pts[:, j])
        return out

    def default_of(self, key: str) -> Any:
        """The base world's value of an option (a pair as it stands: the world draws from it)."""
        return self.base.get(key)

    def at_default(self, dim: Dim, x: float) -> bool:
        """Whether coordinate ``x`` of ``dim`` gives the base world's own value."""
        v = dim.value(float(x))
        return v == self.default_of(dim.key)


# ------------------------------------------------------------------------ reading
#: Where the shipped spaces are: the package and its folder.
_PACKAGED = ("cdf_mj.falsify", "spaces")


def space_names() -> list[str]:
    """The spaces shipped with the package."""
    return list(packaged_files(*_PACKAGED, suffix=SUFFIX))


def _finite_number(v: Any) -> bool:
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:  # a 400-digit integer: no float holds it
        return False


def _spell(key: str) -> str:
    """How a space file writes ``key``: ``[dims."obstacle.beta"]``."""
    return f'[dims."{key}"]'


def _dim(written: str, spec: Any, base: ScenarioConfig, where: str) -> Dim:
    """One ``[dims."KEY"]`` table as a :class:`Range` or :class:`Choice` (a flat key of
    version 0.1 read as its dotted key, with a FlatKeyWarning, as ``--set`` and presets do)."""
    at = f"{where}: {_spell(written)}"
    try:
        key = dotted_key(written, _spell, f"{where}: ")
    except UserValueError as exc:
        raise SpaceError(f"{at}: {exc}") from None
    if not isinstance(spec, dict):
        raise SpaceError(f"{at} must be a table (range = [low, high] or choices = [...]), got {spec!r}")
    unknown = sorted(set(spec) - {"range", "choices", "weights", "mean", "std"})
    if unknown:
        raise SpaceError(f"{at}: unknown key {unknown[0]!r}; a dimension has range (with mean, std or weights) "
                         "or choices (with weights)")
    if ("range" in spec) == ("choices" in spec):
        raise SpaceError(f"{at} needs exactly one of range = [low, high] or choices = [...]")
    default = base.get(key)
    if "choices" in spec:
        values = spec["choices"]
        if not isinstance(values, list) or not values or len(values) > MAX_VALUES:
            raise SpaceError(f"{at}: choices must be a list of 1 to {MAX_VALUES} values, got {values!r}")
        if isinstance(default, tuple):
            raise SpaceError(f"{at}: {key} is a (low, high) pair: give range = [low, high] (a point pins it to "
                             "(v, v)), not choices")
        try:  # each choice as --set and presets read a value: ranges are checked below
            values = [coerce_value(key, v) for v in values]
        except UserValueError as exc:
            raise SpaceError(f"{at}: {exc}") from None
        if len(set(values)) != len(values):
            raise SpaceError(f"{at}: choices must be distinct, got {values!r}")
        if "mean" in spec or "std" in spec:
            raise SpaceError(f"{at}: mean and std are for a range; a choice's nominal is its weights")
        return Choice(key, tuple(values), _weights(spec.get("weights"), len(values), at))
    lo_hi = spec["range"]
    if (not isinstance(lo_hi, list) or len(lo_hi) != 2 or not all(_finite_number(v) for v in lo_hi)):
        raise SpaceError(f"{at}: range must be [low, high], two finite numbers, got {lo_hi!r}")
    low, high = lo_hi
    if not low < high:
        what = "empty" if low == high else "inverted"
        raise SpaceError(f"{at}: range [{low:g}, {high:g}] is {what}: it needs low < high (to fix an option, "
                         "set it in the preset instead)")
    if isinstance(default, (bool, str)):
        raise SpaceError(f"{at}: {key} is not a number; give choices = [...] instead of a range")
    if isinstance(default, int):  # a count of ticks: every whole value
        if not (float(low).is_integer() and float(high).is_integer()):
            raise SpaceError(f"{at}: {key} is a whole number; its range needs whole ends, got {lo_hi!r}")
        if high - low + 1 > MAX_VALUES:
            raise SpaceError(f"{at}: range {lo_hi!r} has more than {MAX_VALUES} whole values")
        if "mean" in spec or "std" in spec:
            raise SpaceError(f"{at}: a whole-number option's nominal is its weights, not mean and std")
        values = list(range(int(low), int(high) + 1))
        return Choice(key, tuple(values), _weights(spec.get("weights"), len(values), at))
    if "weights" in spec:
        raise SpaceError(f"{at}: weights are for choices and whole-number ranges; a range's nominal is uniform "
                         "or mean and std")
    mean, std = spec.get("mean"), spec.get("std")
    if (mean is None) != (std is None):
        raise SpaceError(f"{at}: give both mean and std (a truncated normal), or neither (uniform)")
    if mean is not None and not (_finite_number(mean) and _finite_number(std) and std > 0  # type: ignore[operator]
                                 and low <= mean <= high):
        raise SpaceError(f"{at}: mean must be a number within the range [{low:g}, {high:g}] and std a finite "
                         f"number > 0, got mean={mean!r}, std={std!r}")
    return Range(key, float(low), float(high), None if mean is None else float(mean),
                 None if std is None else float(std), pair=isinstance(default, tuple))


def _weights(raw: Any, n: int, at: str) -> tuple[float, ...]:
    if raw is None:
        return (1.0 / n,) * n
    if (not isinstance(raw, list) or len(raw) != n or not all(_finite_number(w) and w >= 0 for w in raw)
            or not sum(raw) > 0):
        raise SpaceError(f"{at}: weights must be {n} finite numbers >= 0 (one per value), not all 0, got {raw!r}")
    scaled = [float(w) / float(max(raw)) for w in raw]  # weights of 1e308 sum to infinity; scaled, they do not
    total = sum(scaled)
    return tuple(w / total for w in scaled)


def parse_space(text: str, name: str, source: str, root: Path | None = None) -> SearchSpace:
    """The space in TOML ``text`` read from ``source`` (its preset path, if a path, is
    taken relative to ``root``); SpaceError (one line) for any mistake."""
    where = f"space {source}"
    data = parse_user_toml(text, where, SpaceError)
    unknown = sorted(set(data) - set(_TOP))
    if unknown:
        raise SpaceError(f"{where}: unknown key {unknown[0]!r}; a space holds {', '.join(_TOP)}")
    description = data.get("description")
    if not isinstance(description, str) or not description.strip():
        raise SpaceError(f"{where}: needs description = \"...\" (what the space varies and why)")
    preset = data.get("preset", "default")
    if not isinstance(preset, str) or not preset:
        raise SpaceError(f"{where}: preset must be a preset name or the path of a .toml file, got {preset!r}")
    preset_path = preset
    if is_path(preset, SUFFIX) and root is not None and not Path(preset).is_absolute():
        preset_path = str(root / preset)
    try:
        base = read_preset(preset_path).config()
    except PresetError as exc:
        raise SpaceError(f"{where}: {exc}") from None
    failure = _failure(data.get("failure", {}), where)
    dims_table = data.get("dims")
    if not isinstance(dims_table, dict) or not dims_table:
        raise SpaceError(f"{where}: needs at least one dimension ([dims.\"obstacle.beta\"] range = [0.01, 0.2])")
    if len(dims_table) > MAX_DIMS:
        raise SpaceError(f"{where}: {len(dims_table)} dimensions; at most {MAX_DIMS}")
    dims = tuple(_dim(key, spec, base, where) for key, spec in dims_table.items())
    keys = [d.key for d in dims]
    twice = next((k for k in keys if keys.count(k) > 1), None)
    if twice is not None:  # a flat key and its dotted key
        raise SpaceError(f"{where}: {_spell(twice)} is given twice (once by its flat key of version 0.1)")
    space = SearchSpace(name=name, description=" ".join(description.split()), preset=preset, base=base,
                        failure=failure, dims=dims, source=source, text=text)
    _check_values(space, where)
    return space


def _failure(table: Any, where: str) -> FailureSpec:
    if not isinstance(table, dict):
        raise SpaceError(f"{where}: [failure] must be a table (margin, threshold), got {table!r}")
    unknown = sorted(set(table) - {"margin", "threshold"})
    if unknown:
        raise SpaceError(f"{where}: [failure] unknown key {unknown[0]!r}; it holds margin and threshold")
    margin = table.get("margin", "gap")
    if margin not in MARGINS:
        raise SpaceError(f"{where}: [failure] margin must be one of {', '.join(MARGINS)}, got {margin!r}")
    threshold = table.get("threshold", 0.0)
    if not _finite_number(threshold) or threshold < 0 or (margin != "gap" and threshold >= MARGIN_CAP):
        raise SpaceError(f"{where}: [failure] threshold must be a finite number >= 0"
                         f"{'' if margin == 'gap' else f' and below {MARGIN_CAP:g} s'}, got {threshold!r}")
    return FailureSpec(margin, float(threshold))


def _check_values(space: SearchSpace, where: str) -> None:
    """Every end of every range and every choice gives a world the config accepts."""
    for d in space.dims:
        ends: Sequence[float] = (d.low, d.high) if isinstance(d, Range) else range(len(d.values))
        for x in ends:
            try:
                apply_values(space.base, {d.key: d.value(float(x))})
            except UserValueError as exc:
                raise SpaceError(f"{where}: {_spell(d.key)}: {exc}") from None


def load_space(name_or_path: str | Path) -> SearchSpace:
    """The :class:`SearchSpace` of a shipped name (``"default"``) or of a TOML file of your
    own (a path: ends in ``.toml`` or has a directory part, :func:`cdf_mj.inputs.is_path`).
    SpaceError (one line) for an unknown name, a file that cannot be read, or any mistake
    in it."""
    named = read_named(name_or_path, "space", _PACKAGED[0], SpaceError, folder=_PACKAGED[1],
                       max_bytes=PRESET_MAX_BYTES, suffix=SUFFIX)
    name = printable(named.name)  # a file's name, printed by the commands: escape codes and newlines escaped
    return parse_space(named.text, name, named.source, root=None if named.path is None else named.path.parent)


# ------------------------------------------------------------------------ densities
def _flat(std: float, low: float, high: float) -> bool:
    """A normal this wide is uniform on the range to within 1e-12 (and its CDF difference
    would underflow): treated as the uniform."""
    return not math.isfinite(std) or std > 1e12 * (high - low)


def truncnorm_logpdf(x: np.ndarray, mean: float, std: float, low: float, high: float) -> np.ndarray:
    """Log density of a normal (``mean``, ``std``) truncated to ``[low, high]`` at ``x``
    (a uniform for an infinite ``std``)."""
    x = np.asarray(x, dtype=float)
    if _flat(std, low, high):
        return np.full_like(x, -math.log(high - low))
    a, b = _NORMAL.cdf((low - mean) / std), _NORMAL.cdf((high - mean) / std)
    z = (x - mean) / std
    return -0.5 * z * z - math.log(std * math.sqrt(2 * math.pi)) - math.log(max(b - a, 1e-300))


def truncnorm_sample(rng: np.random.Generator, n: int, mean: float, std: float, low: float,
                     high: float) -> np.ndarray:
    """``n`` draws of a normal (``mean``, ``std``) truncated to ``[low, high]`` (inverse
    CDF; a uniform for an infinite ``std``)."""
    u = rng.random(n)
    if _flat(std, low, high):
        return low + u * (high - low)
    a, b = _NORMAL.cdf((low - mean) / std), _NORMAL.cdf((high - mean) / std)
    if b - a < 1e-12:  # the mass lies beyond an end: the nearer end
        return np.full(n, low if mean < low else high)
    p = np.clip(a + u * (b - a), 1e-15, 1 - 1e-15)
    return np.clip(np.array([mean + std * _NORMAL.inv_cdf(float(q)) for q in p]), low, high)


def truncnorm_moments(mean: float, std: float, low: float, high: float) -> tuple[float, float]:
    """Mean and std of a normal (``mean``, ``std``) truncated to ``[low, high]`` (the
    uniform's for an infinite ``std``)."""
    if _flat(std, low, high):
        return (low + high) / 2, (high - low) / math.sqrt(12)
    a, b = (low - mean) / std, (high - mean) / std
    z = _NORMAL.cdf(b) - _NORMAL.cdf(a)
    if z < 1e-300:  # all the mass beyond an end: that end
        return (low if mean < low else high), 0.0
    pa, pb = _NORMAL.pdf(a), _NORMAL.pdf(b)
    shift = (pa - pb) / z
    var = std * std * (1 + (a * pa - b * pb) / z - shift * shift)
    return mean + std * shift, math.sqrt(max(var, 0.0))


def truncnorm_matching(target_mean: float, target_std: float, low: float, high: float) -> tuple[float, float]:
    """The normal (mean, std) whose truncation to ``[low, high]`` has the given mean and
    std (the method of moments for the truncated family), by damped Newton steps on
    (mean, log std); a std beyond 1000 widths is the uniform (``inf``). Falls back to the
    targets themselves if it does not converge."""
    width = high - low
    m = min(max(target_mean, low + 1e-6 * width), high - 1e-6 * width)
    s = min(max(target_std, 1e-4 * width), width / math.sqrt(12))
    if s >= 0.999 * width / math.sqrt(12) and abs(m - (low + high) / 2) <= 1e-3 * width:
        return (low + high) / 2, math.inf  # the uniform
    x = np.array([m, math.log(s)])
    cap = math.log(1e3 * width)

    def residual(v: np.ndarray) -> np.ndarray:
        got = truncnorm_moments(float(v[0]), math.exp(min(float(v[1]), cap)), low, high)
        return np.array([(got[0] - m) / width, (got[1] - s) / width])

    for _ in range(80):
        f = residual(x)
        if float(np.abs(f).max()) < 1e-9:
            break
        jac = np.empty((2, 2))
        for k, h in enumerate((1e-7 * width, 1e-7)):
            step = np.zeros(2)
            step[k] = h
            jac[:, k] = (residual(x + step) - f) / h
        try:
            delta = np.linalg.solve(jac, -f)
        except np.linalg.LinAlgError:
            break
        scale = max(1.0, float(abs(delta[0]) / width), float(abs(delta[1])))
        x = x + delta / scale
        x[1] = min(x[1], cap)
    if float(np.abs(residual(x)).max()) > 1e-5:  # not reached (no truncated normal has these moments)
        return target_mean, max(target_std, 1e-4 * width)
    return float(x[0]), (math.inf if x[1] >= cap - 1e-9 else math.exp(float(x[1])))
