"""Fault injection on every input file and value of the command line (issue 28, causes 1,
2 and 10), beside :mod:`tests.test_fault_injection` (the experiment store): values nested
5000 levels deep through ``--set``, ``--names``, ``--preset``, ``cdf-mj presets FILE`` and
``render --trace``; a FIFO or ``/dev/zero`` given as a preset or a trace; a preset whose
description holds ESC and NUL. Each is one line ``cdf-mj: error: ...``, exit 2, within
10 s and 1 GB; the description is printed escaped.

The FIFO and ``/dev/zero`` cases run ``python -m cdf_mj.cli`` in a child process under a
1 GiB address-space limit and a 10 s timeout: a reader that blocks or reads without bound
fails the test instead of hanging it or filling the machine's memory.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.inputs import MAX_DEPTH

DEEP = 5000  # levels: past Python's recursion limit (1000), as in issue 28
TOO_DEEP = f"nested deeper than {MAX_DEPTH} levels"
needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
needs_dev_zero = pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
PRESET = 'description = "A driver who waits."\n[scenario.obstacle]\nbeta = 0.1\n'


def _without_note(err: str) -> str:
    """``err`` less the note a simulating command prints on the first run after an install
    (its kernels compile): it is not part of the error."""
    return "".join(line for line in err.splitlines(keepends=True) if not line.startswith("cdf-mj: first run here:"))


def _in_time(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """``cdf-mj ARGV...`` in this process, which must answer within 10 s."""
    start = time.monotonic()
    status, out, err = run_cli(capsys, *argv)
    assert time.monotonic() - start < 10, argv
    return status, out, _without_note(err)


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def _child(*argv: str, cwd: Path) -> tuple[int, str, str]:
    """``cdf-mj ARGV...`` in a child process: under 1 GiB of address space, within 10 s."""
    done = subprocess.run([sys.executable, "-m", "cdf_mj.cli", *argv], capture_output=True, text=True, cwd=cwd,
                          timeout=10, preexec_fn=_limit_memory if sys.platform != "win32" else None, check=False)
    return done.returncode, done.stdout, _without_note(done.stderr)


def _deep_trace(path: Path) -> Path:
    """A trace whose first line is a header and whose second nests 5000 levels deep."""
    path.write_text(json.dumps({"format": "cdf_mj.monitor_trace/1"}) + "\n"
                    + '{"t": 0.0, "ego": ' + "[" * DEEP + "]" * DEEP + "}\n")
    return path


# ------------------------------------------------------------------ cause 1: deep nesting
@pytest.mark.parametrize("key", ["obstacle.beta", "ego.start_spread"])
def test_a_deep_set_value_is_one_line(capsys, key):
    status, out, err = _in_time(capsys, "episode", "--set", f"{key}=" + "[" * DEEP + "]" * DEEP)
    assert_one_line_error(status, out, err, f"--set {key}", TOO_DEEP)
    status, out, err = _in_time(capsys, "episode", "--set", f"{key}=" + "[" * DEEP)  # unclosed too
    assert_one_line_error(status, out, err, TOO_DEEP)


@pytest.mark.parametrize(("name", "text"), [
    ("deep.json", '{"ego_prefix": ' + "[" * DEEP + "]" * DEEP + "}"),
    ("deep.toml", "ego_prefix = " + "[" * DEEP + "]" * DEEP + "\n"),
    ("dotted.toml", "ego_prefix" + ".x" * DEEP + ' = "a"\n'),
])
def test_a_deep_names_file_is_one_line(tmp_path, capsys, name, text):
    path = tmp_path / name
    path.write_text(text)
    status, out, err = _in_time(capsys, "episode", "--names", str(path))
    assert_one_line_error(status, out, err, f"names file {path}", TOO_DEEP)


@pytest.mark.parametrize("text", [
    PRESET + "start_spread = " + "[" * DEEP + "]" * DEEP + "\n",
    PRESET + "x = " + "{a = " * DEEP + "1" + "}" * DEEP + "\n",
    PRESET + "accel" + ".x" * DEEP + " = 1\n",
])
def test_a_deep_preset_is_one_line(tmp_path, capsys, text):
    path = tmp_path / "deep.toml"
    path.write_text(text)
    for argv in (["episode", "--preset", str(path)], ["presets", str(path)],
                 ["experiment", "--episodes", "1", "--out", str(tmp_path / "run"), "--preset", str(path)]):
        status, out, err = _in_time(capsys, *argv)
        assert_one_line_error(status, out, err, f"preset {path}", TOO_DEEP)
    assert not (tmp_path / "run" / "episodes.jsonl").exists()  # nothing ran


def test_a_deep_trace_line_is_one_line(tmp_path, capsys):
    trace = _deep_trace(tmp_path / "deep.jsonl")
    status, out, err = _in_time(capsys, "render", "--trace", str(trace), "--out", str(tmp_path / "t.png"))
    assert_one_line_error(status, out, err, f"{trace}:2", TOO_DEEP)
    assert not (tmp_path / "t.png").exists()


# ------------------------------------------------------------------ cause 2: not regular files
@needs_fifo
@pytest.mark.parametrize("argv", [
    ["episode", "--preset", "{fifo}.toml"],
    ["presets", "{fifo}.toml"],
    ["render", "--trace", "{fifo}.jsonl", "--out", "t.png"],
    ["episode", "--names", "{fifo}.json"],
])
def test_a_fifo_as_preset_trace_or_names_is_refused_without_hanging(tmp_path, argv):
    argv = [a.format(fifo=tmp_path / "pipe") for a in argv]
    os.mkfifo(next(a for a in argv if "pipe" in a))
    status, out, err = _child(*argv, cwd=tmp_path)
    assert_one_line_error(status, out, err, str(tmp_path / "pipe"), "is a FIFO (named pipe), not a regular file")


@needs_dev_zero
@pytest.mark.parametrize("argv", [
    ["episode", "--preset", "/dev/zero"],
    ["experiment", "--episodes", "1", "--out", "run", "--preset", "/dev/zero"],
    ["presets", "/dev/zero"],
    ["render", "--trace", "/dev/zero", "--out", "t.png"],
    ["episode", "--preset", "zero.toml"],  # a link to the device
    ["episode", "--names", "zero.json"],
])
def test_dev_zero_as_preset_trace_or_names_is_refused_before_reading(tmp_path, argv):
    for link in ("zero.toml", "zero.json"):
        (tmp_path / link).symlink_to("/dev/zero")
    status, out, err = _child(*argv, cwd=tmp_path)
    assert_one_line_error(status, out, err, "is a character device, not a regular file")
    assert not (tmp_path / "run").exists() and not (tmp_path / "t.png").exists()


def test_a_preset_larger_than_the_bound_is_refused(tmp_path, capsys):
    from cdf_mj.inputs import PRESET_MAX_BYTES

    path = tmp_path / "big.toml"
    path.write_text(PRESET + "#" * PRESET_MAX_BYTES + "\n")
    status, out, err = _in_time(capsys, "presets", str(path))
    assert_one_line_error(status, out, err, f"preset file {path}", "larger than the bound of 1 MiB")


# ------------------------------------------------------------------ cause 10: control characters
def test_a_description_with_esc_and_nul_is_printed_escaped(tmp_path, capsys):
    path = tmp_path / "loud.toml"
    path.write_text('description = "A driver \\u001b[31min red\\u001b[0m, a NUL \\u0000 and a bell \\u0007."\n'
                    "[scenario.obstacle]\nbeta = 0.1\n")
    status, out, err = _in_time(capsys, "presets", str(path))
    assert status == 0, err
    assert not any(ch in out for ch in "\x1b\x00\x07"), out
    assert "loud: A driver \\x1b[31min red\\x1b[0m, a NUL \\x00 and a bell \\x07." in out
    assert "obstacle.beta = 0.1" in out
