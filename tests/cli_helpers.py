"""Helpers for tests that run the command line in-process: the exit status and both
streams of one call, and the check that an error is one line of ours."""

from __future__ import annotations

import pytest

from cdf_mj import cli


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """``cdf-mj ARGV...`` in this process: (exit status, stdout, stderr)."""
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_line_error(status: int, out: str, err: str, *needles: str) -> None:
    """Exit 2, nothing on stdout, one ``cdf-mj: error:`` line holding every needle."""
    assert status == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("cdf-mj: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
