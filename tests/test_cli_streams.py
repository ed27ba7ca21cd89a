"""``cdf-mj`` with closed standard streams (issue 15, item 10): real processes, real
closed descriptors (``>&-``, ``2>&-``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="closes POSIX descriptors")


def _cdf_mj(*args: str, close: tuple[int, ...], cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m cdf_mj ARGS`` with the descriptors ``close`` closed; what the process
    writes to the others is captured."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))

    def closing() -> None:
        for fd in close:
            os.close(fd)

    return subprocess.run([sys.executable, "-m", "cdf_mj", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120, preexec_fn=closing, check=False)


def test_stdout_closed_is_refused_before_any_work(tmp_path):
    """`cdf-mj episode >&-`: the record would be lost; one line, status 2, no traceback."""
    run = _cdf_mj("episode", "--seed", "1", close=(1,), cwd=tmp_path)
    assert run.returncode == 2
    assert run.stderr.startswith("cdf-mj: error: standard output is closed") and run.stderr.count("\n") == 1
    run = _cdf_mj("experiment", "--episodes", "1", "--out", str(tmp_path / "x"), close=(1,), cwd=tmp_path)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert not (tmp_path / "x").exists()  # nothing ran


def test_stderr_closed_runs_and_keeps_the_records_clean(tmp_path):
    """`cdf-mj experiment 2>&-` with the progress bar on: the run happens, exit 0, and no
    message meant for stderr lands in the records file that took descriptor 2's place."""
    out = tmp_path / "run"
    run = _cdf_mj("experiment", "--episodes", "2", "--planner", "reactive", "--workers", "1", "--out",
                  str(out), close=(2,), cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:]
    assert "episodes from seed 0" in run.stdout
    lines = (out / "episodes.jsonl").read_text(encoding="utf-8").splitlines()
    assert [json.loads(line)["seed"] for line in lines] == [0, 1]
    # A failure with stderr closed still says so through the status.
    bad = _cdf_mj("episode", "--set", "obstacle.beta=7", close=(2,), cwd=tmp_path)
    assert bad.returncode == 2 and bad.stdout == ""
