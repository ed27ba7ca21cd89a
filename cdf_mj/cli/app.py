"""The ``cdf-mj`` entry point: the parser with every command, the list of commands, the
guard of the standard streams, and the mapping of errors to one line and an exit status
(:func:`main`; the behaviour is described in :mod:`cdf_mj.cli`)."""

from __future__ import annotations

import argparse
import errno
import os
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

from cdf_mj._version import __version__
from cdf_mj.cli.args import EXIT_USAGE, PROG, CLIError, add_note, notes
from cdf_mj.cli.bench import add_bench
from cdf_mj.cli.episode import add_episode
from cdf_mj.cli.experiment import add_experiment, add_reproduce
from cdf_mj.cli.falsify import add_estimate, add_falsify
from cdf_mj.cli.presets import add_presets
from cdf_mj.cli.render import add_render
from cdf_mj.cli.report import add_report
from cdf_mj.cli.sweep import add_sweep
from cdf_mj.config.user_values import flat_key_notes
from cdf_mj.experiments.runner import WorkerDiedError


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


#: In the order of the list of commands: a newcomer's first steps first.
_SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [add_reproduce, add_episode, add_experiment,
                                                                    add_presets, add_sweep, add_render,
                                                                    add_report, add_falsify, add_estimate,
                                                                    add_bench]


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
        # A flat key of version 0.1 read anywhere in the command (--set, a preset, a space
        # file) is a note printed after it has run, never a Python warning.
        with flat_key_notes(lambda note: add_note(args, note)):
            status: int = args.func(args)
    except BrokenPipeError:  # `cdf-mj episode | head`: the reader left; no traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's flush at exit
        return 1
    except KeyboardInterrupt:  # Ctrl-C: a command that keeps a journal says how it resumes itself
        if args.debug:
            raise
        out = getattr(args, "out", None)
        print(f"{PROG}: interrupted" + (f"; what finished is saved in {out}: run the same command again to "
                                        "continue" if out and args.command in _RESUMABLE else ""), file=sys.stderr)
        return 130
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
    if status != EXIT_USAGE:  # old spellings, once the command has run (an error stays one line)
        for text in notes(args):
            print(f"{PROG}: note: {text}", file=sys.stderr)
    return status


def _note_first_compile() -> None:
    """One line on stderr before a command that simulates, the first time after an install:
    its kernels compile first (seconds of silence otherwise look like a hang)."""
    from cdf_mj.model.kernels import compile_pending

    folder = compile_pending()
    if folder is not None:
        print(f"cdf-mj: first run here: compiling the simulation's kernels (about 10 s, once; "
              f"cached in {folder})", file=sys.stderr, flush=True)


#: Commands whose runs go on from their --out directory when given again (experiment says
#: so itself, with the file).
_RESUMABLE = frozenset({"falsify", "estimate", "sweep"})

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
