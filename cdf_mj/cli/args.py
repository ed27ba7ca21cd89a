"""What every ``cdf-mj`` command shares: the program's name and exit statuses,
:class:`CLIError`, the argument types that bound every count and size, the one vocabulary
of flags (:func:`add_option` keeps the old spellings working), and the adders and readers
of the shared options (:func:`add_run_arguments`: where and on what episodes run;
:func:`add_cdf_arguments`: the CDF's settings; ``--format``).

One idea, one flag, on every command that has it:

=========================  =================================================  ==========================================
flag                       meaning                                            old spellings (work, with a note)
=========================  =================================================  ==========================================
``--seed S``               the seed a command starts from: the episode's      ``--seed0`` (experiment, reproduce, sweep)
                           (episode, render), the first of ``--episodes``
                           consecutive seeds (experiment, reproduce, sweep),
                           the search's or estimator's (falsify, estimate)
``--episodes N``           how many episodes: seeds from ``--seed``           ``--budget`` (falsify, estimate)
                           (experiment, reproduce, sweep: per point), the
                           search's or estimator's budget (falsify,
                           estimate), the seeds of a timed row (bench)
``--seeds S1,S2,...``      chosen seeds, a list (report)                      --
``--planner P[,P...]``     the planner; a comma-separated list where a        ``--planners`` (experiment, reproduce,
                           command runs several on the same seeds             sweep), ``--compare`` (render)
                           (experiment, reproduce, sweep; render: 2 to 6
                           side by side); one under test (falsify, estimate),
                           drawn (report), run (episode)
``--compare P[,P...]``     falsify: the planners its counterexamples are      --
                           replayed on, beside ``--planner``
``--out PATH``             where a command writes (a file or a directory)     --
``--workers N``            worker processes (1 runs in this process); bench:  bench ``--workers N1,N2,...``
                           the timed reproduction's                           (now ``--scale-workers``)
``--backend``,             a process pool or Ray; a Ray cluster's address     --
``--address``              (experiment, reproduce, sweep, falsify, estimate)
``--scene``, ``--names``   the MJCF scene and its element names               --
``--preset``, ``--set``    the scenario: a preset, then fields by dotted key  --
                           (falsify, estimate: over the space's own preset)
``--quiet``                no progress bar                                    --
``--particles N``          the CDF's particle count; bench: the filter rows'  bench ``--particles N1,N2,...``
                           size                                               (now ``--scale-particles``)
``--adaptive-particles``   an adaptive count (KLD-sampling) from MIN up to    --
                           ``--particles``
``--scale-particles``,     bench: the lists a scaling table runs over         --
``--scale-workers``
=========================  =================================================  ==========================================

Every command that runs episodes takes ``--scene``, ``--names``, ``--preset`` and
``--set``; those that run many take ``--workers``, ``--backend``, ``--address`` and
``--quiet`` too (:func:`add_run_arguments`; bench times its own pool: ``--workers`` and
``--quiet`` only). An old spelling does what it did and leaves one line on stderr when
the command has run, ``cdf-mj: note: --planners is now --planner (the old spelling still
works)``; a bad command line stays one error line. The old and the new spelling of one
flag together are refused. ``--help`` shows the new spellings only.

The command modules (``cdf_mj.cli.episode``, ``.experiment``, ...) build their parsers with
:func:`command` and these public types and adders; scripts that take the same options
import them from here. Scripts that take ``--set`` too can call :func:`parse_overrides`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TypeVar, get_args

from cdf_mj.analysis.tables import TableFormat
from cdf_mj.config import (
    MAX_EPISODES,
    MAX_PARTICLES,
    MAX_SEED,
    MAX_WORKERS,
    SCENARIO_KEYS,
    AdaptiveConfig,
    CDFConfig,
    RiskConfig,
    ScenarioConfig,
)
from cdf_mj.config.user_values import UserValueError, apply_values, coerce_value, dotted_key, flat_key_notes
from cdf_mj.extras import install_hint
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


def shown(text: str) -> str:
    """``text`` for an error message: quoted, and cut if long (a 400-digit number)."""
    return repr(text) if len(text) <= 40 else f"{text[:30]!r}...({len(text)} characters)"


_shown = shown  # the name the readers of --set below use


def int_in(low: int, high: int, why: str) -> Callable[[str], int]:
    """An argparse type: an integer in ``[low, high]``; ``why`` gives the bound's reason in
    the error. Every count and size of the CLI goes through it, checked before any work."""
    def parse(text: str) -> int:
        try:
            value: int | None = int(text)
        except ValueError:  # also a number of more than 4300 digits
            value = None
        if value is None or not low <= value <= high:
            kind = {0: "a non-negative integer", 1: "a positive integer"}.get(low, f"an integer >= {low}")
            raise argparse.ArgumentTypeError(f"must be {kind} of at most {high} ({why}), got {shown(text)}")
        return value
    return parse


#: ``--seed``: non-negative, at most MAX_SEED (exact in every JSON reader).
seed_value = int_in(0, MAX_SEED, "a seed; 2^53 - 1 at most, exact in JSON")
#: ``--episodes``: 1 to MAX_EPISODES.
episode_count = int_in(1, MAX_EPISODES, "at most 10^7 episodes per run: ~10 GB of records")
#: ``--particles``: 1 to MAX_PARTICLES.
particle_count = int_in(1, MAX_PARTICLES, "memory: ~0.3 GB per filter at 10^6")
#: ``--workers``: 1 to MAX_WORKERS.
worker_count = int_in(1, MAX_WORKERS, "processes on one machine")
#: Image sizes [px].
pixel_count = int_in(1, 16384, "pixels; MuJoCo's offscreen buffer is smaller")


def finite_float(low: float, high: float, what: str, open_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in ``[low, high]`` (``(low, high]`` with ``open_low``;
    ``what``: its unit, for the error)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (low < value <= high if open_low else low <= value <= high):  # NaN fails too
            span = f"in ({low:g}, {high:g}]" if open_low else f"from {low:g} to {high:g}"
            raise argparse.ArgumentTypeError(f"must be a number {span} {what}, got {shown(text)}")
        return value
    return parse


#: Most items of a comma-separated list argument (``sweep --values``, ``bench
#: --scale-particles``, ``bench --scale-workers``): each item is a run of its own, so a long
#: list is hours of work.
MAX_LIST_ITEMS = 100


def comma_list(item: Callable[[str], _T], what: str) -> Callable[[str], list[_T]]:
    """An argparse type: 1 to :data:`MAX_LIST_ITEMS` comma-separated ``what`` (``"positive
    integers"``), each parsed and bounded by ``item`` (an argparse type, or a converter
    that raises ValueError), counted before any is parsed."""
    def parse(text: str) -> list[_T]:
        parts = [v for v in text.split(",") if v.strip()]
        if not parts or len(parts) > MAX_LIST_ITEMS:
            raise argparse.ArgumentTypeError(f"expected 1 to {MAX_LIST_ITEMS} comma-separated {what}, got "
                                             f"{len(parts)}" + ("" if parts else f": {shown(text)}"))
        try:
            return [item(v) for v in parts]
        except argparse.ArgumentTypeError as exc:  # it names the bound
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}; each {exc}") from None
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {shown(text)}") from None
    return parse


def out_path(text: str) -> str:
    """An argparse type for ``--out``: a path that names something (an empty one would
    write into the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a file or directory, got {shown(text)} (an empty path "
                                         "would write into the working directory; give '.' for that)")
    return text


# ------------------------------------------------------------ old spellings of a flag
#: The namespace attribute that collects the notes of old spellings (:func:`notes`).
_NOTES = "cli_notes"
#: The namespace attribute that records which spelling set each option.
_SPELLED = "cli_spelled"


class _Spelling(argparse.Action):
    """Stores an option's value like ``store``; an old spelling also leaves a note. Both
    spellings of one option on one command line are refused (which would win is a guess)."""

    def __init__(self, option_strings: Sequence[str], dest: str, *, name: str, **kwargs: Any) -> None:
        self.name = name  # the current spelling
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        spelled = dict(getattr(namespace, _SPELLED, {}))
        used = option_string or self.name
        earlier = spelled.get(self.dest)
        if earlier is not None and earlier != used:
            old = earlier if used == self.name else used
            raise CLIError(f"{self.name}: not used with {old}, its old spelling: give {self.name} once")
        spelled[self.dest] = used
        setattr(namespace, _SPELLED, spelled)
        if used != self.name:
            add_note(namespace, f"{used} is now {self.name} (the old spelling still works)")
        setattr(namespace, self.dest, values)


def add_option(parser: argparse.ArgumentParser, name: str, *, old: Sequence[str] = (),
               **kwargs: Any) -> argparse.Action:
    """``parser.add_argument(name, **kwargs)`` (an option that takes a value), with each of
    ``old`` as a spelling of earlier releases: it sets the same value, is hidden from
    ``--help`` and leaves the note ``--OLD is now NAME`` (:func:`notes`)."""
    if not old:
        return parser.add_argument(name, **kwargs)
    action = parser.add_argument(name, action=_Spelling, name=name, **kwargs)
    same = {k: kwargs[k] for k in ("type", "choices", "metavar") if k in kwargs}  # read as the new one
    for flag in old:
        parser.add_argument(flag, action=_Spelling, name=name, dest=action.dest, help=argparse.SUPPRESS,
                            default=argparse.SUPPRESS, **same)
    return action


def add_note(args: argparse.Namespace, text: str) -> None:
    """Keep ``text`` (about an old spelling) for :func:`notes`."""
    setattr(args, _NOTES, [*getattr(args, _NOTES, ()), text])


def notes(args: argparse.Namespace) -> list[str]:
    """The notes that the command line ``args`` came from left (old spellings, once each):
    :func:`cdf_mj.cli.main` prints them on stderr after the command has run, so that a bad
    command line stays one error line."""
    return list(dict.fromkeys(getattr(args, _NOTES, ())))


# ------------------------------------------------------------------ the shared options
def add_scenario_arguments(parser: argparse.ArgumentParser, preset_help: str | None = None) -> None:
    """Add ``--scene PATH``, ``--names FILE``, ``--preset NAME`` and repeatable ``--set
    key=value`` (read by :func:`config_from_args`); ``preset_help``: what ``--preset`` does,
    where it does not start from the defaults."""
    parser.add_argument("--scene", metavar="PATH", default=DEFAULT_SCENE,
                        help="MJCF scene file (default: models/xml/scene.xml)")
    parser.add_argument("--names", metavar="FILE", default=None,
                        help="the scene's element names: a .json or .toml object whose keys are "
                             "SceneNames fields, e.g. {\"ego_prefix\": \"av/\", \"route_ego\": "
                             "\"av_path\"}; fields not given keep their defaults (docs/SCENES.md)")
    parser.add_argument("--preset", metavar="NAME", default=None,
                        help=preset_help or "start from a scenario preset (cdf-mj presets lists them: "
                                            f"{', '.join(preset_names())}) or a .toml file of your own; "
                                            "--set applies after it")
    parser.add_argument("--set", dest="overrides", metavar="KEY=VALUE", action="append",
                        default=[],
                        help="override a ScenarioConfig field by its dotted key, e.g. obstacle.beta=0.1 "
                             "or ego.start_spread=[-4,4]; values are JSON, else strings; "
                             "repeatable (the flat keys of version 0.1, e.g. beta=0.1, still work). "
                             "Keys: " + ", ".join(SETTABLE))


#: Where episodes run (``--backend``).
BACKENDS = ("process", "ray")


def add_run_arguments(parser: argparse.ArgumentParser, *, pool: bool = True, progress: bool = True,
                      preset_help: str | None = None) -> None:
    """The options of every command that runs episodes: ``--scene``, ``--names``,
    ``--preset``, ``--set`` (:func:`add_scenario_arguments`); with ``pool`` (many episodes)
    ``--workers``, ``--backend`` and ``--address`` (read by :func:`pool_from_args`); with
    ``progress`` ``--quiet``."""
    if pool:
        parser.add_argument("--workers", type=worker_count, default=None,
                            help="worker processes, 1 to 1024 (default: the CPU count; 1 runs in this process)")
        parser.add_argument("--backend", choices=BACKENDS, default="process",
                            help=f"where episodes run: a local process pool (default) or Ray "
                                 f"({install_hint('ray')})")
        parser.add_argument("--address", default=None,
                            help="with --backend ray: the address of an existing Ray cluster "
                                 "(default: start a local Ray instance)")
    if progress:
        parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scenario_arguments(parser, preset_help)


def pool_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """``workers``, ``backend`` and ``address`` of :func:`add_run_arguments`, as keyword
    arguments of the runners; CLIError for ``--address`` without ``--backend ray``."""
    if args.address is not None and args.backend != "ray":
        raise CLIError("--address is the address of a Ray cluster: it needs --backend ray")
    return {"workers": args.workers, "backend": args.backend, "address": args.address}


def _parse_value(text: str, name: str) -> Any:
    """JSON if it parses, else the text itself. CLIError naming the field ``name`` for a
    value nested deeper than :data:`cdf_mj.inputs.MAX_DEPTH` levels (checked before the
    parser recurses)."""
    try:
        return parse_json(text, f"--set {name}: the value")
    except InputError as exc:
        raise CLIError(str(exc)) from None
    except ValueError:
        return text


def parse_overrides(items: Iterable[str]) -> dict[str, Any]:
    """``["obstacle.beta=0.1", "ego.start_spread=[-4, 4]"]`` -> ``{"obstacle.beta": 0.1, ...}``
    (dotted keys), each value read as preset and space files read theirs
    (:func:`cdf_mj.config.user_values.read_value`: in its field's type); later items win.
    A flat key of version 0.1 (``beta=0.1``) is taken with a FlatKeyWarning, shown here as
    a one-line note on stderr naming its dotted key (by :func:`config_from_args`, as the
    command's note). CLIError (a ValueError) on an unknown field, a missing ``=`` or a
    value of the wrong type; ranges are checked by the config."""
    changes: dict[str, Any] = {}
    with flat_key_notes(lambda note: print(f"{PROG}: note: {note}", file=sys.stderr)):
        for item in items:
            key, sep, text = item.partition("=")
            key = key.strip()
            if not sep or not key:
                raise CLIError(f"--set: expected key=value, got {item!r}")
            try:
                dotted = dotted_key(key, lambda k: f"--set {k}")
                changes[dotted] = coerce_value(dotted, _parse_value(text, key))
            except UserValueError as exc:
                raise CLIError(f"--set: {exc}") from None
    return changes


def config_from_args(args: argparse.Namespace) -> ScenarioConfig:
    """The ScenarioConfig of ``--preset`` (default: the defaults) with the ``--set``
    overrides applied after it (validated), and the scene names of ``--names FILE``. The
    flat keys of version 0.1 in either are taken, each with a note (:func:`notes`)."""
    preset = getattr(args, "preset", None)
    with flat_key_notes(lambda note: add_note(args, note)):
        base = read_preset(preset).config() if preset else ScenarioConfig()  # PresetError: one line
        names_file = getattr(args, "names", None)
        if names_file is not None:
            base = base.replace(names=read_names(names_file))  # SceneError: one line naming the file
        try:
            return apply_values(base, parse_overrides(args.overrides))
        except UserValueError as exc:  # the config names the field and its range
            raise CLIError(f"--set: {exc}") from None


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
    parser.add_argument("--particles", type=particle_count, default=d.n_particles,
                        help=f"CDF particle count N{where}, 1 to 10^6 (memory) (default {d.n_particles}); with "
                             "--adaptive-particles the most")
    parser.add_argument("--adaptive-particles", type=particle_count, default=None, metavar="MIN",
                        help="an adaptive particle count: KLD-sampling from MIN up to --particles at each "
                             "resampling (docs/PARAMETERS.md, 'How many particles'; default: a fixed count)")
    parser.add_argument("--tau", type=finite_float(0.0, 1.0, "(a probability)", open_low=True), default=None,
                        help=f"braking threshold on P(cutoff) of cdf-threshold, the paper's rule{where} "
                             f"(default {d.tau})")
    parser.add_argument("--brake-risk", type=finite_float(0.0, 1.0, "(a probability)", open_low=True),
                        default=None, help=f"risk rule (cdf, imm-risk, cv-risk): brake when P(collision if "
                                           f"braking is deferred) reaches this{where} (default {r.brake})")
    parser.add_argument("--release-risk", type=finite_float(0.0, 1.0, "(a probability)", open_low=True),
                        default=None, help="risk rule: release the brake below this risk, at most --brake-risk "
                                           "(default: half of --brake-risk)")
    parser.add_argument("--risk-latency", type=finite_float(0.0, 10.0, "[s]"), default=None,
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
    adaptive = getattr(args, "adaptive_particles", None)
    if adaptive is not None and adaptive > args.particles:
        raise CLIError(f"--adaptive-particles {adaptive} is more than --particles {args.particles}, the most the "
                       "adaptive count may reach")
    return CDFConfig(n_particles=args.particles, tau=args.tau if args.tau is not None else d.tau,
                     cutoff_rule=args.cutoff_rule, risk=risk,
                     adaptive=None if adaptive is None else AdaptiveConfig(n_min=adaptive))


def command(subparsers: argparse._SubParsersAction, name: str, *, summary: str,
            description: str, compiles: bool = False) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``; ``summary`` is its line in the list of commands;
    ``compiles``: it simulates, so its first run after an install compiles the kernels
    (and says so)."""
    p: argparse.ArgumentParser = subparsers.add_parser(name, help=summary, description=description)
    p.set_defaults(summary=summary, compiles=compiles)
    return p


def planner_list(text: str) -> list[str]:
    """An argparse type: comma-separated registered planner names (``"cdf,reactive"``)."""
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in PLANNERS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown planner(s) {', '.join(unknown) or text!r}: choose from {', '.join(sorted(PLANNERS))}")
    return names


def add_planner_option(parser: argparse.ArgumentParser, default: str | list[str] | None, help: str, *,
                       several: bool = False, old: Sequence[str] = (), dest: str = "planners") -> argparse.Action:
    """``--planner``: one registered planner, or with ``several`` a comma-separated list
    (:func:`planner_list`, kept as ``dest``); ``old``: its old spellings (:func:`add_option`)."""
    choices = ", ".join(sorted(PLANNERS))
    if several:
        return add_option(parser, "--planner", old=old, dest=dest, type=planner_list, default=default,
                          metavar="PLANNER[,PLANNER...]", help=f"{help}; any of: {choices}")
    return add_option(parser, "--planner", old=old, choices=sorted(PLANNERS), default=default, metavar="PLANNER",
                      help=f"{help}; one of: {choices}")


def seed_range(seed: int, episodes: int) -> range:
    """Seeds ``seed ... seed + episodes - 1``, lazily (a range); CLIError if the last one is
    beyond :data:`MAX_SEED`."""
    if seed + episodes - 1 > MAX_SEED:
        raise CLIError(f"--seed {seed} with --episodes {episodes} runs seeds up to "
                       f"{seed + episodes - 1}, beyond the largest seed {MAX_SEED}")
    return range(seed, seed + episodes)

