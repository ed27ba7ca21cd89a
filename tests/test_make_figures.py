"""scripts/make_figures.py: one command for every figure under docs/img."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import load_script

from cdf_mj.viz.report import FIGURES

pytest.importorskip("matplotlib", reason="the viz extra (matplotlib) is not installed")

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "make_figures.py"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _script():
    return load_script(SCRIPT, "make_figures_script")


def test_help_lists_every_group() -> None:
    proc = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    for group in ("report", "analysis", "sweeps", "frame", "gif"):
        assert group in proc.stdout
    assert "--only" in proc.stdout and "--fresh" in proc.stdout


def test_an_unknown_group_is_one_line_before_anything_runs(tmp_path, capsys) -> None:
    status = _script().main(["--only", "report,pictures", "--docs", str(tmp_path / "img"),
                             "--results", str(tmp_path / "res")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert err.startswith("make_figures: error: unknown group(s) pictures")
    assert not (tmp_path / "img").exists() and not (tmp_path / "res").exists()


def test_every_docs_figure_has_a_maker() -> None:
    """Every image the README and the docs show is one that a group of the script writes."""
    shown = set()
    for page in (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))):
        for ref in re.findall(r"(?:docs/)?(img/[\w./-]+\.(?:png|gif))", page.read_text(encoding="utf-8")):
            shown.add(ref.removeprefix("img/"))
    out = subprocess.run([sys.executable, str(SCRIPT), "--dry-run", "--docs", "D"], capture_output=True,
                         text=True, timeout=60).stdout
    made = {f"report/{name}.png" for name in FIGURES}
    made |= set(re.findall(r"\bD/([\w./-]+\.(?:png|gif))", out))
    for kind in ("dev", "heldout"):  # comparison_figures writes these two into D/analysis/KIND
        if f"D/analysis/{kind}" in out:
            made |= {f"analysis/{kind}/brake_times.png", f"analysis/{kind}/brier_over_time.png"}
    assert shown and shown <= made, sorted(shown - made)


def test_only_report_makes_the_report_figures(tmp_path, capsys) -> None:
    docs, results = tmp_path / "img", tmp_path / "res"
    status = _script().main(["--only", "report", "--episodes", "4", "--workers", "1", "--docs", str(docs),
                             "--results", str(results)])
    out = capsys.readouterr().out
    assert status == 0
    assert f"$ cdf-mj report {results / 'report4'} --out {docs / 'report'}" in out
    for name in FIGURES:
        png = docs / "report" / f"{name}.png"
        assert png.read_bytes()[:8] == PNG_MAGIC, name
    assert "## Tables" in (docs / "report" / "report.md").read_text()
    assert sorted(p.name for p in docs.iterdir()) == ["report"]  # no other group ran
