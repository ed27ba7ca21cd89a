"""The ``cdf-mj`` command line.

::

    cdf-mj                                                 # the commands, one line each
    cdf-mj episode --seed 7 --planner reactive            # one episode, record as JSON
    cdf-mj episode --seed 7 --set beta=0.1 --set ego_start_spread='[-4, 4]'
    python -m cdf_mj episode --seed 7                      # the same without the script

Bad input (unknown planner, negative seed, out-of-range parameter, unreadable scene,
a simulation that diverges) ends with one line ``cdf-mj: error: ...`` on stderr and exit
status 2; ``--debug`` shows the traceback instead. Every count and size has an upper bound
(``cdf_mj.config.MAX_*``: 10^6 particles, 10^7 episodes, 1024 workers, seeds below 2^53),
checked before any work; control characters in a message (a path with a newline) are
escaped, so the error stays one line. A run in which episodes failed
(``experiment``, ``reproduce``, ``sweep``) exits with status 1. With stderr closed
(``2>&-``) commands run as usual and only their messages are lost; with stdout closed
(``>&-``) nothing runs (status 2), as what they print would be lost.

Adding a subcommand: write ``_add_<name>(subparsers)``, which builds its parser with
``_command`` (use :func:`add_scenario_arguments` for ``--scene`` and ``--set``) and sets
``func`` to a function ``(args) -> int``; append it to ``_SUBCOMMANDS``. Raise :class:`CLIError` (or
any ``ValueError``) for bad input; logic lives in the package, not here. Scripts that take
``--set`` too can call :func:`parse_overrides`.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import json
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, NoReturn, get_args

try:  # MuJoCo loads the OpenGL backend named by MUJOCO_GL as it is imported
    import mujoco  # noqa: F401
except (ImportError, AttributeError, RuntimeError) as _exc:
    if not os.environ.get("MUJOCO_GL"):
        raise
    print(f"cdf-mj: error: MuJoCo cannot load the OpenGL backend MUJOCO_GL={os.environ['MUJOCO_GL']} "
          f"({' '.join(str(_exc).split()) or type(_exc).__name__}); unset MUJOCO_GL (cdf-mj render "
          "then tries EGL, then OSMesa) or set it to one installed here", file=sys.stderr)
    raise SystemExit(2) from None

from cdf_mj import __version__
from cdf_mj.analysis.tables import TableFormat
from cdf_mj.config import (
    MAX_EPISODES,
    MAX_PARTICLES,
    MAX_SEED,
    MAX_WORKERS,
    CDFConfig,
    RiskConfig,
    ScenarioConfig,
)
from cdf_mj.experiments.runner import WorkerDiedError
from cdf_mj.experiments.store import json_default, locked
from cdf_mj.extras import install_hint
from cdf_mj.planners.base import PLANNERS
from cdf_mj.presets import preset_names, read_preset
from cdf_mj.records import RECORDS_FILE
from cdf_mj.scenario.episode import run_episode
from cdf_mj.sim.checks import read_names
from cdf_mj.sim.scene import DEFAULT_SCENE, Scene

__all__ = ["CLIError", "add_scenario_arguments", "build_parser", "config_from_args", "main", "parse_overrides",
           "scene_from_args"]

PROG = "cdf-mj"
EXIT_USAGE = 2  # argparse's status for bad input
EXIT_FAILED_EPISODES = 1  # an experiment finished, but some of its episodes raised
#: What an experiment directory holds of its run; ``--force`` removes these and nothing else.
RUN_FILES = (RECORDS_FILE, "settings.json")

#: ScenarioConfig fields that ``--set`` may change (``names`` is a nested object).
SETTABLE = tuple(f.name for f in dataclasses.fields(ScenarioConfig) if f.name != "names")


class CLIError(ValueError):
    """Bad input, reported as one line on stderr with exit status 2."""


class _Exit(Exception):
    """argparse asked to exit (``--help``, ``--version``) with this status."""

    def __init__(self, status: int) -> None:
        super().__init__(status)
        self.status = status


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser that raises instead of exiting, so that ``main`` returns."""

    def error(self, message: str) -> NoReturn:
        raise CLIError(message)

    def exit(self, status: int = 0, message: str | None = None) -> NoReturn:
        if message:
            sys.stderr.write(message)
        raise _Exit(status)


# ----------------------------------------------------------------- shared arguments
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
                        help="override a ScenarioConfig field, e.g. beta=0.1 or "
                             "ego_start_spread=[-4,4]; values are JSON, else strings; "
                             "repeatable. Fields: " + ", ".join(SETTABLE))


def _parse_value(text: str) -> Any:
    """JSON if it parses (lists become tuples), else the text itself."""
    try:
        value = json.loads(text)
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
    """``["beta=0.1", "ego_start_spread=[-4, 4]"]`` -> ``{"beta": 0.1, ...}``, each value in
    its ScenarioConfig field's type; later items win. CLIError (a ValueError) on an unknown
    field, a missing ``=`` or a value of the wrong type; ranges are checked by the config."""
    base = ScenarioConfig()
    changes: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise CLIError(f"--set: expected key=value, got {item!r}")
        if key not in SETTABLE:
            raise CLIError(f"--set {key}: unknown parameter; choose from {', '.join(SETTABLE)}")
        changes[key] = _coerce(key, _parse_value(text), getattr(base, key))
    return changes


def config_from_args(args: argparse.Namespace) -> ScenarioConfig:
    """The ScenarioConfig of ``--preset`` (default: the defaults) with the ``--set``
    overrides applied after it (validated), and the scene names of ``--names FILE``."""
    preset = getattr(args, "preset", None)
    base = read_preset(preset).config() if preset else ScenarioConfig()  # PresetError: one line
    names_file = getattr(args, "names", None)
    if names_file is not None:
        base = base.replace(names=read_names(names_file))  # SceneError: one line naming the file
    return base.replace(**parse_overrides(args.overrides))  # ValueError names field and range


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
_THRESHOLD_PLANNERS = ("cdf-threshold",)
_RISK_PLANNERS = ("cdf", "imm-risk", "cv-risk")


def cdf_from_args(args: argparse.Namespace, planners: Sequence[str] | None = None) -> CDFConfig:
    """The :class:`cdf_mj.config.CDFConfig` of :func:`add_cdf_arguments` (validated). With
    ``planners``, a flag that none of them reads is refused (``--tau`` without
    ``cdf-threshold``; a risk flag without ``cdf``, ``imm-risk`` or ``cv-risk``), since it
    would change nothing."""
    d = CDFConfig()
    if planners is not None:
        given = [f for f, v in (("--tau", args.tau),) if v is not None]
        if given and not set(planners) & set(_THRESHOLD_PLANNERS):
            raise CLIError(f"--tau is the threshold of the paper's rule, which none of the planners "
                           f"{','.join(planners)} uses: add cdf-threshold to them")
        given = [f for f, v in (("--brake-risk", args.brake_risk), ("--release-risk", args.release_risk),
                                ("--risk-latency", args.risk_latency)) if v is not None]
        if given and not set(planners) & set(_RISK_PLANNERS):
            raise CLIError(f"{given[0]} sets the risk rule, which none of the planners {','.join(planners)} "
                           f"uses: add one of {', '.join(_RISK_PLANNERS)}")
    brake = args.brake_risk if args.brake_risk is not None else d.risk.brake
    release = args.release_risk if args.release_risk is not None else brake / 2
    latency = args.risk_latency if args.risk_latency is not None else d.risk.latency
    risk = RiskConfig(brake=brake, release=release, latency=latency)
    return CDFConfig(n_particles=args.particles, tau=args.tau if args.tau is not None else d.tau,
                     cutoff_rule=args.cutoff_rule, risk=risk)


def _print_json(obj: Any) -> None:
    # allow_nan=False: stdout is strict JSON or nothing (NaN is not JSON).
    sys.stdout.write(json.dumps(obj, indent=2, allow_nan=False, default=json_default) + "\n")


# ----------------------------------------------------------------- subcommands
def _command(subparsers: argparse._SubParsersAction, name: str, *, summary: str,
             description: str, compiles: bool = False) -> argparse.ArgumentParser:
    """The parser of subcommand ``name``; ``summary`` is its line in the list of commands;
    ``compiles``: it simulates, so its first run after an install compiles the kernels
    (and says so, :func:`_note_first_compile`)."""
    p: argparse.ArgumentParser = subparsers.add_parser(name, help=summary, description=description)
    p.set_defaults(summary=summary, compiles=compiles)
    return p


def _cmd_episode(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    scene = scene_from_args(args, config)
    record = run_episode(config, seed=args.seed, planner=args.planner, scene=scene,
                         label=args.label, trace=args.trace)
    _print_json(record.to_dict())
    return 0


def _add_episode(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "episode", compiles=True, summary="run one episode and print its record as JSON",
        description="Run one episode of the T-intersection scenario and print its record "
                    "as JSON on stdout. The same seed gives the same record.")
    p.add_argument("--seed", type=_non_negative_int, default=0,
                   help="episode seed, a non-negative integer (default: 0)")
    p.add_argument("--planner", choices=sorted(PLANNERS), default="reactive",
                   help="ego planner (default: reactive)")
    add_scenario_arguments(p)
    p.add_argument("--no-label", dest="label", action="store_false",
                   help="skip the counterfactual run that labels the episode Cutoff/Yield/Right")
    p.add_argument("--trace", action="store_true", help="include per-tick poses, modes and beliefs")
    p.set_defaults(func=_cmd_episode)


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value <= 600.0):  # a timing run of 10 minutes at most
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, at most 600, got "
                                         f"{_shown(text)}")
    return value


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


def _cmd_experiment(args: argparse.Namespace) -> int:
    from cdf_mj.analysis.tables import experiment_tables
    from cdf_mj.experiments.experiment import SettingsMismatchError, run_experiment

    config = config_from_args(args)
    cdf = cdf_from_args(args, args.planners)
    seeds = _seed_range(args.seed0, args.episodes)
    if args.retry_failed and args.force:
        raise CLIError("--force starts over, so --retry-failed has nothing to retry: give one of them")
    if args.address is not None and args.backend != "ray":
        raise CLIError("--address is the address of a Ray cluster: it needs --backend ray")
    if args.force:
        _remove_run(Path(args.out))
    try:  # resume: the same command again continues a run, or shows its tables if it is complete
        result = run_experiment(args.out, seeds, args.planners, config, cdf, args.scene,
                                progress=not args.quiet, workers=args.workers, backend=args.backend,
                                resume=True, retry_failed=args.retry_failed, address=args.address)
    except SettingsMismatchError as exc:
        raise CLIError(f"{exc}, or give --force to replace them") from None
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; the finished episodes are saved in {args.out}/episodes.jsonl: "
              f"run the same command again to continue", file=sys.stderr)
        return 130
    what = f"{args.episodes} episodes from seed {args.seed0}, planners {','.join(args.planners)}"
    if result.ran:
        resumed = f", {result.resumed} already on disk" if result.resumed else ""
        print(f"{what}: {result.ran} run in {result.wall_time:.1f} s on {result.workers} worker(s) "
              f"({result.backend}){resumed}; peak memory per worker {result.peak_worker_rss_mb:.0f} MiB; "
              f"records in {args.out}/episodes.jsonl\n")
    else:
        print(f"{what}: all {result.resumed} records were already in {args.out}/episodes.jsonl "
              f"(--force runs them again)\n")
    print(experiment_tables(result.records, fmt=args.format))
    if result.failed:
        print(f"{PROG}: {result.failed} of {len(result)} episodes failed; their records in "
              f"{args.out}/episodes.jsonl hold the error and traceback (\"status\": \"failed\")",
              file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _remove_run(out: Path) -> None:
    """Remove the records and settings of the run in ``out`` (:data:`RUN_FILES`), under the
    directory's lock so that a run still using it is not pulled from under it."""
    if not out.is_dir():
        return
    with locked(out):
        for name in RUN_FILES:
            (out / name).unlink(missing_ok=True)


def _add_experiment_arguments(p: argparse.ArgumentParser, episodes: int, out: str) -> None:
    p.add_argument("--episodes", type=_episodes, default=episodes,
                   help=f"number of seeds, 1 to 10^7 (default {episodes})")
    p.add_argument("--seed0", type=_non_negative_int, default=0, help="first seed (default 0)")
    p.add_argument("--planners", type=_planner_list, default=["cdf", "reactive"],
                   help="comma-separated planners run on the same seeds (default cdf,reactive)")
    p.add_argument("--out", default=out, help=f"result directory (default {out})")
    add_cdf_arguments(p)
    p.add_argument("--workers", type=_workers, default=None,
                   help="worker processes, 1 to 1024 (default: the CPU count; 1 runs in this process)")
    p.add_argument("--backend", choices=("process", "ray"), default="process",
                   help=f"where episodes run: a local process pool (default) or Ray ({install_hint('ray')})")
    p.add_argument("--address", default=None,
                   help="with --backend ray: the address of an existing Ray cluster "
                        "(default: start a local Ray instance)")
    p.add_argument("--force", action="store_true",
                   help="start over: remove the records and settings of the run in --out (no other file)")
    p.add_argument("--retry-failed", action="store_true",
                   help="run the episodes of the run in --out that failed again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_format_argument(p)
    add_scenario_arguments(p)
    p.set_defaults(func=_cmd_experiment)


def _add_experiment(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "experiment", compiles=True,
        summary="run planners on the same seeds; print the paper's tables beside ours",
        description="Run each planner on the same seeds, write one JSON line per episode and "
                    "planner to OUT/episodes.jsonl, and print the paper's two tables beside ours. "
                    "The same command again continues an interrupted run, or only prints the "
                    "tables of a finished one; other settings in the same OUT are refused.")
    _add_experiment_arguments(p, episodes=100, out="results/experiment")


def _add_reproduce(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "reproduce", compiles=True, summary="the paper's experiment: 1000 episodes, CDF and reactive",
        description="The paper's experiment with the default settings: seeds 0-999, the CDF "
                    "(with its risk rule; --planners cdf-threshold,reactive for the paper's rule) "
                    "and the reactive planner on the same seeds, both tables. The same command "
                    "again continues an interrupted run, or only prints the tables of a finished one.")
    _add_experiment_arguments(p, episodes=1000, out="results/reproduce")


#: Most points of one sweep (each an experiment on every seed).
MAX_SWEEP_VALUES = 100


def _value_list(text: str) -> list[float]:
    """Comma-separated finite numbers, 1 to :data:`MAX_SWEEP_VALUES` of them (the range of
    each is the swept setting's, checked by its configuration)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {_shown(text)}") from None
    if not values or len(values) > MAX_SWEEP_VALUES:
        raise argparse.ArgumentTypeError(f"expected 1 to {MAX_SWEEP_VALUES} values, got {len(values)}")
    bad = [v for v in values if not abs(v) < float("inf")]  # inf, nan; also a 400-digit number
    if bad:
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {bad[0]!r} in {_shown(text)}")
    return values


def _cmd_sweep(args: argparse.Namespace) -> int:
    from cdf_mj.experiments.sweep import VizUnavailableError, run_sweep

    config = config_from_args(args)
    cdf = cdf_from_args(args, args.planners)
    seeds = _seed_range(args.seed0, args.episodes)
    if args.values is not None and len(args.sweeps) > 1:
        raise CLIError("--values applies to one sweep at a time; name a single sweep")
    failed = []
    for name in args.sweeps:
        try:
            result = run_sweep(name, args.out, seeds, planners=args.planners, values=args.values, config=config,
                               cdf=cdf, scene=args.scene, workers=args.workers,
                               progress=not args.quiet, figure=not args.no_figure)
        except VizUnavailableError as exc:
            raise CLIError(f"{exc} (the tables are written; --no-figure skips the figure)") from None
        print(result.markdown + "\n")
        figure = f", {result.figure_path}" if result.figure_path else ""
        print(f"wrote {result.csv_path}, {result.markdown_path}{figure}\n")
        failed += [f"{name} = {f.value:g}: {f}" for f in result.failures]
    for line in failed:  # as `experiment` does: the run goes on, the status says it
        print(f"{PROG}: {line}", file=sys.stderr)
    if failed:
        print(f"{PROG}: the failed episodes are left out of the tables; their records hold the error and "
              "traceback (\"status\": \"failed\")", file=sys.stderr)
        return EXIT_FAILED_EPISODES
    return 0


def _add_sweep(subparsers: argparse._SubParsersAction) -> None:
    from cdf_mj.experiments.sweep import SWEEPS

    p = _command(
        subparsers, "sweep", compiles=True,
        summary="run the planners over a range of one setting; table (CSV, Markdown) and figure",
        description="Sweep one setting (beta, particle count, threshold tau, noise levels) over "
                    "values, each point an experiment on the same seeds; write OUT/<sweep>.csv, "
                    "OUT/<sweep>.md and OUT/<sweep>.png. Finished points are reused. The figure "
                    f"needs matplotlib ({install_hint('viz')}).")
    p.add_argument("sweeps", nargs="+", choices=sorted(SWEEPS), metavar="SWEEP",
                   help=f"one or more of: {', '.join(SWEEPS)}")
    p.add_argument("--values", type=_value_list, default=None,
                   help="comma-separated values (one sweep only; default: the sweep's own)")
    p.add_argument("--episodes", type=_episodes, default=200, help="seeds per point, 1 to 10^7 (default 200)")
    p.add_argument("--seed0", type=_non_negative_int, default=0, help="first seed (default 0)")
    p.add_argument("--planners", type=_planner_list, default=["cdf", "reactive"],
                   help="comma-separated planners (default cdf,reactive)")
    p.add_argument("--out", default="results/sweeps", help="output directory (default results/sweeps)")
    add_cdf_arguments(p, swept=True)
    p.add_argument("--workers", type=_workers, default=None,
                   help="worker processes per point (default: the CPU count; 1 runs in this process)")
    p.add_argument("--no-figure", action="store_true", help="tables only (no matplotlib needed)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scenario_arguments(p)
    p.set_defaults(func=_cmd_sweep)


def _cmd_render_trace(args: argparse.Namespace) -> int:
    from cdf_mj.viz.trace import render_trace

    unused = [flag for flag, given in (("--set", args.overrides), ("--preset", args.preset),
                                       ("--compare", args.compare), ("--layout", args.layout != "overlay"),
                                       ("--seed", args.seed is not None), ("--planner", args.planner))
              if given]
    if unused:
        raise CLIError(f"{', '.join(unused)}: not used with --trace (the trace holds the episode "
                       "and is drawn with the panel over the view)")
    names = read_names(args.names) if args.names is not None else None
    result = render_trace(args.trace, args.scene, args.out, names=names, width=args.width,
                          height=args.height, fps=args.fps, frame_time=args.frame, camera=args.camera)
    what = (f"{result.n_frames} frames, {result.duration:.2f} s of the trace at "
            f"{result.frames_per_second:g} fps" if result.n_frames > 1
            else f"the frame at {result.duration:.2f} s")
    print(f"wrote {result.path}: {what} ({result.backend}); brake {result.brake_time}")
    return 0


def _cmd_render_compare(args: argparse.Namespace, config: ScenarioConfig, scene: Scene,
                        cdf: CDFConfig) -> int:
    from cdf_mj.viz.render import parse_planners, render_compare, tile_caption

    if args.planner is not None:
        raise CLIError("--planner: not used with --compare (it names the planners)")
    result = render_compare(args.out, seed=args.seed, planners=parse_planners(args.compare),
                            config=config, cdf=cdf, scene=scene, camera=args.camera, width=args.width,
                            height=args.height, fps=args.fps, frame_time=args.frame,
                            layout=args.layout, max_particles=args.max_particles,
                            shadows=args.shadows, antialias=args.antialias)
    rate = result.n_frames / max(result.render_seconds, 1e-9)
    what = (f"{result.n_frames} frames of {len(result.records)} tiles, {result.duration:.2f} s at "
            f"{result.frames_per_second:g} fps; rendered at {rate:.1f} frames/s" if result.n_frames > 1
            else f"the frame at {result.duration:.2f} s of {len(result.records)} tiles")
    print(f"wrote {result.path}: {what} ({result.backend}); label {result.label}; "
          + "; ".join(tile_caption(r) for r in result.records))
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from cdf_mj.viz.render import DEFAULT_SEED, render_episode

    if args.trace is not None:
        return _cmd_render_trace(args)
    config = config_from_args(args)
    scene = scene_from_args(args, config)
    cdf = cdf_from_args(args, [n.strip() for n in args.compare.split(",")] if args.compare
                        else [args.planner or "cdf"])
    args.seed = DEFAULT_SEED if args.seed is None else args.seed
    if args.compare is not None:
        return _cmd_render_compare(args, config, scene, cdf)
    result = render_episode(args.out, seed=args.seed, planner=args.planner or "cdf", config=config,
                            cdf=cdf, scene=scene, camera=args.camera, width=args.width,
                            height=args.height, fps=args.fps, frame_time=args.frame,
                            layout=args.layout, max_particles=args.max_particles,
                            shadows=args.shadows, antialias=args.antialias)
    if result.n_frames > 1:
        rate = result.n_frames / max(result.render_seconds, 1e-9)
        what = (f"{result.n_frames} frames, {result.duration:.2f} s of simulated time at "
                f"{result.frames_per_second:g} fps; rendered at {rate:.1f} frames/s")
    else:
        what = f"the frame at {result.duration:.2f} s"
    print(f"wrote {result.path}: {what} ({result.backend}); label {result.label}, "
          f"brake {result.record.brake_time}")
    return 0


def _add_render(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "render", compiles=True, summary="render one episode offscreen to MP4, GIF or a PNG frame",
        description="Run one episode and render it offscreen (MUJOCO_GL=egl unless set, else "
                    "osmesa) at a constant frame rate in simulated time, with the obstacle's "
                    "isovist, the CDF's particles, the braking moment and P(left), P(seen), "
                    "P(cutoff) drawn in. The suffix of --out chooses MP4, GIF or PNG (--frame). "
                    "--layout side puts charts of the probabilities and both cars' speeds over "
                    "time beside the view; --compare cdf,imm,reactive draws the same seed under "
                    "each planner, tiles side by side. "
                    "With --trace FILE it draws your own episode instead: a trace that "
                    "CDFMonitor.save_trace wrote, over --scene (your junction's MJCF; --names "
                    "for its names, default those in the trace), both cars' boxes and the "
                    "posterior panel; --seed, --planner, --compare and --layout are then refused and "
                    "the CDF options not used. "
                    f"Needs imageio and Pillow ({install_hint('viz')}).")
    p.add_argument("--seed", type=_non_negative_int, default=None,
                   help="episode seed (default 1: a cut-off the CDF brakes for, so the default "
                        "video shows a decision; `episode` defaults to seed 0, reactive, a "
                        "record rather than a picture)")
    p.add_argument("--planner", choices=sorted(PLANNERS), default=None,
                   help="ego planner (default cdf: the planner whose belief is drawn)")
    p.add_argument("--compare", metavar="P1,P2,...", default=None,
                   help="render the seed under each of these planners (2 to 6, e.g. "
                        "cdf,imm,reactive), tiles side by side, each the size of one render and "
                        "captioned with its planner and brake time; a shorter episode holds "
                        "its last frame")
    p.add_argument("--layout", choices=("overlay", "side"), default="overlay",
                   help="overlay (default): the posterior panel over the view's top-left; side: "
                        "charts of the probabilities with tau, both cars' speeds, the brake "
                        "decision and the obstacle's lane entry beside the view (adds 3/4 of "
                        "--height to the width; --height >= 160)")
    p.add_argument("--out", required=True, help="output file: .mp4, .gif, or .png with --frame")
    p.add_argument("--trace", metavar="FILE", default=None,
                   help="draw a monitor trace (CDFMonitor.save_trace, JSON lines) over --scene "
                        "instead of running an episode; --frame T is seconds from its first tick")
    p.add_argument("--camera", default=None,
                   help="a camera of the scene, e.g. top, ego_chase or obstacle_chase (default: "
                        "a view that follows both cars and the conflict zone)")
    p.add_argument("--width", type=_pixels, default=640, help="image width [px], even for MP4 (default 640)")
    p.add_argument("--height", type=_pixels, default=480, help="image height [px], even for MP4 (default 480)")
    p.add_argument("--fps", type=_finite_float(1e-3, 1000.0, "frames per second"), default=None,
                   help="frames per simulated second (default 30 for MP4, 25 for GIF)")
    p.add_argument("--frame", type=_finite_float(0.0, 600.0, "[s]"), default=None, metavar="T",
                   help="render the one frame at T seconds to a .png (T from 0 to the episode's "
                        "end; past it is an error naming the end)")
    add_cdf_arguments(p)
    p.add_argument("--max-particles", type=_int_in(0, MAX_PARTICLES, "particles"), default=100,
                   help="most distinct particles drawn per frame (default 100)")
    p.add_argument("--shadows", action="store_true", help="draw shadows (slower)")
    p.add_argument("--antialias", action="store_true", help="4x multisampling (slower)")
    add_scenario_arguments(p)
    p.set_defaults(func=_cmd_render)


def _cmd_report(args: argparse.Namespace) -> int:
    from cdf_mj.viz.report import write_report

    result = write_report(args.dir, out=args.out, seeds=args.seeds, planner=args.planner)
    skipped = f"; skipped {result.failed} failed episode(s)" if result.failed else ""
    if result.unreadable:
        skipped += f" and {result.unreadable} unreadable line(s)"
    print(f"wrote {result.markdown} and {len(result.figures)} figure(s): "
          f"{', '.join(p.name for p in result.figures.values())} from {result.records} records{skipped}")
    for name, why in result.omitted.items():
        print(f"  {name}: not drawn ({why})")
    return 0


def _seed_list(text: str) -> list[int]:
    try:
        seeds = [_non_negative_int(v) for v in text.split(",") if v.strip()]
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected comma-separated seeds from 0 to {MAX_SEED}, got "
                                         f"{_shown(text)}") from None
    if not seeds:
        raise argparse.ArgumentTypeError("expected at least one seed")
    return seeds


def _add_report(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "report", summary="figures (PNG) and a Markdown page from an experiment directory",
        description="Turn an experiment directory (settings.json, episodes.jsonl) into PNG "
                    "figures and report.md: confusion matrix beside the paper's, avoidance per "
                    "planner with 95 %% intervals, trajectories, posterior traces, braking lead "
                    "times. Failed episodes are skipped and counted. "
                    f"Needs matplotlib ({install_hint('viz')}).")
    p.add_argument("dir", metavar="DIR", help="experiment directory (cdf-mj experiment --out DIR)")
    p.add_argument("--out", default=None, help="output directory (default DIR)")
    p.add_argument("--seeds", type=_seed_list, default=None,
                   help="comma-separated seeds for trajectories and posteriors (default: one per label)")
    p.add_argument("--planner", default=None,
                   help="planner whose trajectories are drawn (default cdf, else the first)")
    p.set_defaults(func=_cmd_report)


def _cmd_bench(args: argparse.Namespace) -> int:
    from cdf_mj.experiments.bench import (
        bench_core,
        bench_env,
        bench_filter,
        bench_planners,
        bench_reproduction,
        bench_startup,
        format_rows,
        physics_floor,
    )

    sizes = tuple(args.particles)
    config = config_from_args(args)
    where = {"scene": args.scene, "config": config}
    floor = physics_floor(**where)  # every row's x floor, from this run
    rows = [] if args.only_reproduce else [*bench_core(args.episodes, floor=floor, **where),
                                           *bench_filter(sizes, **where),
                                           *bench_planners(args.episodes, **where),
                                           *bench_env(args.env_seconds, **where),
                                           *bench_startup()]
    if args.reproduce or args.only_reproduce:
        rows += bench_reproduction(args.reproduce_episodes, tuple(args.workers), progress=not args.quiet,
                                   **where)
    print(format_rows(rows, floor))
    return 0


def _int_list(item: Callable[[str], int]) -> Callable[[str], list[int]]:
    """An argparse type: comma-separated integers, each parsed (and bounded) by ``item``."""
    def parse(text: str) -> list[int]:
        try:
            values = [item(v) for v in text.split(",") if v.strip()]
        except argparse.ArgumentTypeError as exc:  # it names the bound
            raise argparse.ArgumentTypeError(f"expected comma-separated positive integers; each {exc}") from None
        if not values:
            raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {_shown(text)}")
        return values
    return parse


def _add_bench(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "bench", compiles=True,
        summary="timing table: physics, filter stages, planners, startup, reproduction scaling",
        description="Print the benchmark table of docs/PERFORMANCE.md: medians from one run "
                    "(pin to one core with taskset -c 0 for the single-core rows), each beside its "
                    "ratio to the physics floor of the same run (x floor), and the startup of fresh "
                    "processes (Numba compiling or loading its cache, a cold cdf-mj episode).")
    p.add_argument("--episodes", type=_episodes, default=30,
                   help="episodes timed per planner (default 30)")
    p.add_argument("--particles", type=_int_list(_particles), default=[250, 1000, 10000],
                   help="filter sizes N to time, each 1 to 10^6 (default 250,1000,10000)")
    p.add_argument("--env-seconds", type=_positive_seconds, default=1.0,
                   help="seconds of each of the 3 timed runs of the Gymnasium env per setting (default 1)")
    p.add_argument("--reproduce", action="store_true",
                   help="also time the paper's reproduction with each --workers count (minutes)")
    p.add_argument("--only-reproduce", action="store_true", help="only the reproduction rows")
    p.add_argument("--reproduce-episodes", type=_episodes, default=1000,
                   help="seeds in the timed reproduction (default 1000)")
    p.add_argument("--workers", type=_int_list(_workers), default=[1, 2],
                   help="worker counts for the reproduction (default 1,2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_scenario_arguments(p)
    p.set_defaults(func=_cmd_bench)


def _cmd_presets(args: argparse.Namespace) -> int:
    if args.name is None:
        names = preset_names()
        width = max(map(len, names))
        for name in names:
            print(f"{name:<{width}}  {read_preset(name).summary}")
        print(f"\n'{PROG} presets NAME' shows the settings of one; "
              f"'{PROG} experiment --preset NAME' runs it.")
        return 0
    preset = read_preset(args.name)  # PresetError: one line
    preset.config()  # values in range
    print(f"{preset.name}: {preset.description}\nsource: {preset.source}")
    changes = preset.changes()
    if not changes:
        print("the default ScenarioConfig: no field changed")
    for key, (default, value) in changes.items():
        print(f"  {key} = {json.dumps(value)}  (default {json.dumps(default)})")
    return 0


def _add_presets(subparsers: argparse._SubParsersAction) -> None:
    p = _command(
        subparsers, "presets", summary="list the scenario presets (--preset NAME), or show one",
        description="List the named scenario presets that --preset takes, each a driver (or "
                    "ego) that differs from the defaults in one trait; with NAME (or a .toml "
                    "file of your own), print the ScenarioConfig fields it changes. The CDF "
                    "keeps its own defaults under every preset.")
    p.add_argument("name", nargs="?", default=None, metavar="NAME",
                   help="a preset name or the path of a .toml preset file")
    p.set_defaults(func=_cmd_presets)


#: In the order of the list of commands: a newcomer's first steps first.
_SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [_add_reproduce, _add_episode, _add_experiment,
                                                                    _add_presets, _add_sweep, _add_render,
                                                                    _add_report, _add_bench]


# ----------------------------------------------------------------- entry point
def build_parser() -> argparse.ArgumentParser:
    """The ``cdf-mj`` parser with every subcommand."""
    parser = _Parser(prog=PROG, description="MuJoCo port of the Cognitive Driving Framework "
                                            "T-intersection scenario.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="on error, show the full traceback instead of one line")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for add in _SUBCOMMANDS:
        add(sub)
    return parser


def _command_list(parser: argparse.ArgumentParser) -> str:
    """What ``cdf-mj`` without a command prints: usage, then every command on one line."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    width = max(map(len, sub.choices))
    lines = [f"usage: {PROG} [--version] [--debug] COMMAND [options]", "", f"{parser.description}", "",
             "commands:"]
    lines += [f"  {name:<{width}}  {p.get_default('summary')}" for name, p in sub.choices.items()]
    lines += ["", f"'{PROG} COMMAND --help' shows the options of a command."]
    return "\n".join(lines)


def _guard_standard_streams() -> str | None:
    """Make closed standard streams harmless; returns why the command cannot run, or None.

    A standard descriptor (0, 1, 2) that is closed (``cdf-mj ... 2>&-``) is opened on
    ``/dev/null``, so that no file the run opens later takes its number and receives what
    is meant for the terminal (MuJoCo's and ffmpeg's messages, a worker's output). With
    stderr closed, what goes there (progress bars, warnings, the one-line error) is dropped
    and the command runs as usual: its exit status still tells the outcome (0 done, 1 some
    episodes failed, 2 bad input). With stdout closed (``>&-``) the output a command exists
    to print (a record, the tables) would be lost, so nothing runs: the reason is returned
    (exit status 2); ``> /dev/null`` discards the output on purpose.
    """
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:  # closed: hold the number with /dev/null
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    if sys.stderr is None:  # Python found fd 2 closed at start-up
        sys.stderr = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115 - for the life of the process
    if sys.stdout is None:
        return ("standard output is closed, so what the command prints would be lost; redirect it to a "
                "file, or to /dev/null to discard it")
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``cdf-mj`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status.
    Closed standard streams: see :func:`_guard_standard_streams`."""
    closed = _guard_standard_streams()
    if closed is not None:
        return _fail(CLIError(closed))
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _Exit as exc:  # --help, --version
        return exc.status
    except CLIError as exc:
        return _fail(exc)
    if args.command is None:
        print(_command_list(parser))
        return 0
    if getattr(args, "compiles", False) and not getattr(args, "quiet", False):
        _note_first_compile()
    try:
        return args.func(args)
    except BrokenPipeError:  # `cdf-mj episode | head`: the reader left; no traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's flush at exit
        return 1
    # ValueError: bad parameters or seed (SceneError, CLIError are ValueErrors too);
    # FloatingPointError: a diverged simulation (NonFiniteStateError, SimulationDivergedError);
    # WorkerDiedError: a worker process died (the finished episodes are saved);
    # OSError: a path that cannot be written (not a directory, no permission, disk full);
    # ImportError: an optional extra is missing (cdf_mj.extras.require names it).
    # OverflowError: a number too large for a float that slipped past the bounds.
    except (ValueError, FloatingPointError, OverflowError, WorkerDiedError, OSError, ImportError) as exc:
        if args.debug:
            raise
        out = getattr(args, "out", None)
        if isinstance(exc, OSError) and exc.filename is None and exc.errno in _WRITE_ERRORS and out:
            exc.filename = f"{out} (writing)"  # a failed write() names no file: name the output
        return _fail(exc)


def _note_first_compile() -> None:
    """One line on stderr before a command that simulates, the first time after an install:
    its kernels compile first (seconds of silence otherwise look like a hang)."""
    from cdf_mj.model.kernels import compile_pending

    folder = compile_pending()
    if folder is not None:
        print(f"cdf-mj: first run here: compiling the simulation's kernels (about 10 s, once; "
              f"cached in {folder})", file=sys.stderr, flush=True)


#: Errors of a write that names no file (``[Errno 28] No space left on device``): reported
#: with the command's output path (``--out``), the only place a command writes.
_WRITE_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS})


def _one_line(text: str) -> str:
    """``text`` with every control character escaped (a path with a newline stays one line)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _fail(exc: Exception) -> int:
    if isinstance(exc, OSError) and exc.filename is not None:
        where = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
        message = _one_line(f"{where if isinstance(where, str) else os.fsdecode(where)}: "
                            f"{exc.strerror or type(exc).__name__}")
    else:
        message = _one_line(" ".join(str(exc).split()) or type(exc).__name__)  # one line
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
