"""What every ``cdf-mj`` command shares: the program's name and exit statuses,
:class:`CLIError`, the argument types that bound every count and size, and the adders and
readers of the shared options (``--scene``, ``--names``, ``--preset``, ``--set``, the CDF's
``--particles``, ``--tau`` and risk flags, ``--format``).

The command modules (``cdf_mj.cli.episode``, ``.experiment``, ...) build their parsers with
:func:`_command` and these types; names with a leading underscore are for the modules of
``cdf_mj.cli`` only. Scripts that take ``--set`` too can call :func:`parse_overrides`.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TypeVar, get_args

from cdf_mj.analysis.tables import TableFormat
from cdf_mj.config import (
    FLAT_KEYS,
    MAX_EPISODES,
    MAX_PARTICLES,
    MAX_SEED,
    MAX_WORKERS,
    SCENARIO_KEYS,
    CDFConfig,
    RiskConfig,
    ScenarioConfig,
)
from cdf_mj.inputs import InputError, parse_json
from cdf_mj.planners.registry import PLANNERS, bind_planner, planner_spec
from cdf_mj.presets import preset_names, read_preset
from cdf_mj.sim.checks import read_names
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

PROG = "cdf-mj"
EXIT_USAGE = 2  # argparse's status for bad input
EXIT_FAILED_EPISODES = 1  # an experiment finished, but some of its episodes raised

_T = TypeVar("_T")

#: ScenarioConfig fields that ``--set`` may change, by dotted key (``names`` is given with
#: ``--names``); the flat keys of version 0.1 (:data:`cdf_mj.config.FLAT_KEYS`) still work.
SETTABLE = SCENARIO_KEYS


class CLIError(ValueError):
    """Bad input, reported as one line on stderr with exit status 2."""


def _shown(text: str) -> str:
    """``text`` for an error message: quoted, and cut if long (a 400-digit number)."""
    return repr(text) if len(text) <= 40 else f"{text[:30]!r}...({len(text)} characters)"


def _int_in(low: int, high: int, why: str) -> Callable[[str], int]:
    """An argparse type: an integer in ``[low, high]``; ``why`` gives the bound's reason in
    the error. Every count and size of the CLI goes through it, checked before any work."""
    def parse(text: str) -> int:
        try:
            value: int | None = int(text)
        except ValueError:  # also a number of more than 4300 digits
            value = None
        if value is None or not low <= value <= high:
            kind = {0: "a non-negative integer", 1: "a positive integer"}.get(low, f"an integer >= {low}")
            raise argparse.ArgumentTypeError(f"must be {kind} of at most {high} ({why}), got {_shown(text)}")
        return value
    return parse


#: Seeds: non-negative, at most MAX_SEED (exact in every JSON reader).
_non_negative_int = _int_in(0, MAX_SEED, "a seed; 2^53 - 1 at most, exact in JSON")
_episodes = _int_in(1, MAX_EPISODES, "at most 10^7 episodes per run: ~10 GB of records")
_particles = _int_in(1, MAX_PARTICLES, "memory: ~0.3 GB per filter at 10^6")
_workers = _int_in(1, MAX_WORKERS, "processes on one machine")
_pixels = _int_in(1, 16384, "pixels; MuJoCo's offscreen buffer is smaller")


def _finite_float(low: float, high: float, what: str, open_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in ``[low, high]`` (``(low, high]`` with ``open_low``;
    ``what``: its unit, for the error)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (low < value <= high if open_low else low <= value <= high):  # NaN fails too
            span = f"in ({low:g}, {high:g}]" if open_low else f"from {low:g} to {high:g}"
            raise argparse.ArgumentTypeError(f"must be a number {span} {what}, got {_shown(text)}")
        return value
    return parse


#: Most items of a comma-separated list argument (``sweep --values``, ``bench --particles``,
#: ``bench --workers``): each item is a run of its own, so a long list is hours of work.
MAX_LIST_ITEMS = 100


def _comma_list(item: Callable[[str], _T], what: str) -> Callable[[str], list[_T]]:
    """An argparse type: 1 to :data:`MAX_LIST_ITEMS` comma-separated ``what`` (``"positive
    integers"``), each parsed and bounded by ``item`` (an argparse type, or a converter
    that raises ValueError), counted before any is parsed."""
    def parse(text: str) -> list[_T]:
        parts = [v for v in text.split(",") if v.strip()]
        if not parts or len(parts) > MAX_LIST_ITEMS:
            raise argparse.ArgumentTypeError(f"expected 1 to {MAX_LIST_ITEMS} comma-separated {what}, got "
                                             f"{len(parts)}" + ("" if parts else f": {_shown(text)}"))
        try:
            return [item(v) for v in parts]
        except argparse.ArgumentTypeError as exc:  # it names the bound
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}; each {exc}") from None
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {_shown(text)}") from None
    return parse


def _out_path(text: str) -> str:
    """An argparse type for ``--out``: a path that names something (an empty one would
    write into the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a file or directory, got {_shown(text)} (an empty path "
                                         "would write into the working directory; give '.' for that)")
    return text


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--scene PATH``, ``--preset NAME`` and repeatable ``--set key=value`` (read by
    the helpers below)."""
    parser.add_argument("--scene", metavar="PATH", default=DEFAULT_SCENE,
                        help="MJCF scene file (default: models/xml/scene.xml)")
    parser.add_argument("--names", metavar="FILE", default=None,
                        help="the scene's element names: a .json or .toml object whose keys are "
                             "SceneNames fields, e.g. {\"ego_prefix\": \"av/\", \"route_ego\": "
                             "\"av_path\"}; fields not given keep their defaults (docs/SCENES.md)")
    parser.add_argument("--preset", metavar="NAME", default=None,
                        help="start from a scenario preset (cdf-mj presets lists them: "
                             f"{', '.join(preset_names())}) or a .toml file of your own; "
                             "--set applies after it")
    parser.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append",
                        default=[],
                        help="override a ScenarioConfig field by its dotted key, e.g. obstacle.beta=0.1 "
                             "or ego.start_spread=[-4,4]; values are JSON, else strings; "
                             "repeatable (the flat keys of version 0.1, e.g. beta=0.1, still work). "
                             "Keys: " + ", ".join(SETTABLE))


def _parse_value(text: str, name: str) -> Any:
    """JSON if it parses (lists become tuples), else the text itself. CLIError naming the
    field ``name`` for a value nested deeper than :data:`cdf_mj.inputs.MAX_DEPTH` levels
    (checked before the parser recurses)."""
    try:
        value = parse_json(text, f"--set {name}: the value")
    except InputError as exc:
        raise CLIError(str(exc)) from None
    except ValueError:
        return text
    return tuple(value) if isinstance(value, list) else value


def _coerce(name: str, value: Any, default: Any) -> Any:
    """``value`` in the type of the field's default; CLIError if it cannot be."""
    def number(v: Any) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise CLIError(f"--set {name}: expected a number, got {_shown(str(v))}")
        try:
            return float(v)
        except OverflowError:  # a 400-digit integer
            raise CLIError(f"--set {name}: {_shown(str(v))} is too large a number") from None

    if isinstance(default, float):
        return number(value)
    if isinstance(default, tuple):
        if not isinstance(value, tuple) or len(value) != len(default):
            raise CLIError(f"--set {name}: expected a list of {len(default)} numbers, "
                           f"e.g. {json.dumps(list(default))}, got {value!r}")
        return tuple(number(v) for v in value)
    if not isinstance(value, type(default)):
        raise CLIError(f"--set {name}: expected {type(default).__name__}, got {value!r}")
    return value


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["obstacle.beta=0.1", "ego.start_spread=[-4, 4]"]`` -> ``{"obstacle.beta": 0.1, ...}``
    (dotted keys), each value in its ScenarioConfig field's type; later items win. A flat
    key of version 0.1 (``beta=0.1``) is taken with a one-line note on stderr naming its
    dotted key. CLIError (a ValueError) on an unknown field, a missing ``=`` or a value of
    the wrong type; ranges are checked by the config."""
    base = ScenarioConfig()
    changes: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise CLIError(f"--set: expected key=value, got {item!r}")
        if key in FLAT_KEYS:
            print(f"{PROG}: note: --set {key} is now --set {FLAT_KEYS[key]}", file=sys.stderr)
            key = FLAT_KEYS[key]
        if key not in SETTABLE:
            raise CLIError(f"--set {key}: unknown parameter; choose from {', '.join(SETTABLE)}")
        changes[key] = _coerce(key, _parse_value(text, key), base.get(key))
    return changes


def config_from_args(args: argparse.Namespace) -> ScenarioConfig:
    """The ScenarioConfig of ``--preset`` (default: the defaults) with the ``--set``
    overrides applied after it (validated), and the scene names of ``--names FILE``."""
    preset = getattr(args, "preset", None)
    base = read_preset(preset).config() if preset else ScenarioConfig()  # PresetError: one line
    names_file = getattr(args, "names", None)
    if names_file is not None:
        base = base.replace(names=read_names(names_file))  # SceneError: one line naming the file
    return base.with_values(parse_overrides(args.overrides))  # ValueError names field and range


def scene_from_args(args: argparse.Namespace, config: ScenarioConfig) -> Scene:
    """The scene named by ``--scene`` (SceneError if it cannot be loaded)."""
    return Scene.load(args.scene, names=config.names)


def add_format_argument(parser: argparse.ArgumentParser) -> None:
    """``--format {text,markdown}``: how the tables are printed (default text, for a terminal;
    markdown: pipe tables for documents)."""
    parser.add_argument("--format", choices=get_args(TableFormat), default="text",
                        help="tables as aligned text for a terminal (default) or as Markdown")


def add_cdf_arguments(parser: argparse.ArgumentParser, swept: bool = False) -> None:
    """``--particles``, ``--tau``, ``--cutoff-rule`` and the risk rule's ``--brake-risk``,
    ``--release-risk`` and ``--risk-latency``: the CDF planner's settings
    (:class:`cdf_mj.config.CDFConfig`; the risk rule's are shared by ``imm-risk`` and
    ``cv-risk``). ``swept``: say they apply where not swept."""
    d = CDFConfig()
    r = d.risk
    where = " where not swept" if swept else ""
    parser.add_argument("--particles", type=_particles, default=d.n_particles,
                        help=f"CDF particle count N{where}, 1 to 10^6 (memory) (default {d.n_particles})")
    parser.add_argument("--tau", type=_finite_float(0.0, 1.0, "(a probability)", open_low=True), default=None,
                        help=f"braking threshold on P(cutoff) of cdf-threshold, the paper's rule{where} "
                             f"(default {d.tau})")
    parser.add_argument("--brake-risk", type=_finite_float(0.0, 1.0, "(a probability)", open_low=True),
                        default=None, help=f"risk rule (cdf, imm-risk, cv-risk): brake when P(collision if "
                                           f"braking is deferred) reaches this{where} (default {r.brake})")
    parser.add_argument("--release-risk", type=_finite_float(0.0, 1.0, "(a probability)", open_low=True),
                        default=None, help="risk rule: release the brake below this risk, at most --brake-risk "
                                           "(default: half of --brake-risk)")
    parser.add_argument("--risk-latency", type=_finite_float(0.0, 10.0, "[s]"), default=None,
                        help=f"risk rule: margin [s] on top of one decision interval (default {r.latency})")
    parser.add_argument("--cutoff-rule", choices=("predictive", "paper"), default=d.cutoff_rule,
                        help=f"how P(cutoff) is computed (default {d.cutoff_rule}; see docs/RESULTS.md)")


#: The planners that read ``--tau`` and the risk rule's flags.
def _rules_read(name: str) -> set[str]:
    """Which of the CDF flags planner ``name`` reads, as its registry entry builds it with a
    run's CDF settings: ``"tau"`` (the paper's threshold rule on the CDF's P(cutoff)) and
    ``"risk"`` (the risk rule's settings)."""
    from cdf_mj.planners.decision import RiskRule, ThresholdRule

    shared = planner_spec(name).shared
    rule = getattr(bind_planner(name)(), "rule", None)
    return ({"tau"} if isinstance(rule, ThresholdRule) and "cdf" in shared else set()) | (
        {"risk"} if isinstance(rule, RiskRule) and shared else set())


def cdf_from_args(args: argparse.Namespace, planners: Sequence[str] | None = None) -> CDFConfig:
    """The :class:`cdf_mj.config.CDFConfig` of :func:`add_cdf_arguments` (validated). With
    ``planners``, a flag that none of them reads is refused (``--tau`` without
    ``cdf-threshold``; a risk flag without ``cdf``, ``imm-risk`` or ``cv-risk``), since it
    would change nothing."""
    d = CDFConfig()
    if planners is not None:
        flags = {"tau": [f for f, v in (("--tau", args.tau),) if v is not None],
                 "risk": [f for f, v in (("--brake-risk", args.brake_risk), ("--release-risk", args.release_risk),
                                         ("--risk-latency", args.risk_latency)) if v is not None]}
        for kind, given in flags.items():
            if given and not any(kind in _rules_read(p) for p in planners if p in PLANNERS):
                readers = [p for p in sorted(PLANNERS) if kind in _rules_read(p)]
                what = "the threshold of the paper's rule" if kind == "tau" else "sets the risk rule"
                raise CLIError(f"{given[0]} {'is ' if kind == 'tau' else ''}{what}, which none of the planners "
                               f"{','.join(planners)} uses: add {'one of ' if len(readers) > 1 else ''}"
                               f"{', '.join(readers)}")
    brake = args.brake_risk if args.brake_risk is not None else d.risk.brake
    release = args.release_risk if args.release_risk is not None else brake / 2
    latency = args.risk_latency if args.risk_latency is not None else d.risk.latency
    risk = RiskConfig(brake=brake, release=release, latency=latency)
    return CDFConfig(n_particles=args.particles, tau=args.tau if args.tau is not None else d.tau,
                     cutoff_rule=args.cutoff_rule, risk=risk)


def _command(subparsers: argparse._SubParsersAction, name: str, *, summary: str,
             description: str, compiles: bool = False) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``; ``summary`` is its line in the list of commands;
    ``compiles``: it simulates, so its first run after an install compiles the kernels
    (and says so, :func:`_note_first_compile`)."""
    p: argparse.ArgumentParser = subparsers.add_parser(name, help=summary, description=description)
    p.set_defaults(summary=summary, compiles=compiles)
    return p


def _planner_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in PLANNERS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown planner(s) {', '.join(unknown) or text!r}: choose from {', '.join(sorted(PLANNERS))}")
    return names


def _seed_range(seed0: int, episodes: int) -> range:
    """Seeds ``seed0 ... seed0 + episodes - 1``, lazily (a range); CLIError if the last one is
    beyond :data:`MAX_SEED`."""
    if seed0 + episodes - 1 > MAX_SEED:
        raise CLIError(f"--seed0 {seed0} with --episodes {episodes} runs seeds up to "
                       f"{seed0 + episodes - 1}, beyond the largest seed {MAX_SEED}")
    return range(seed0, seed0 + episodes)
