"""The README's snippets work as printed: every Python block runs, every ``cdf-mj``
command parses, and CI runs exactly the README's test command."""

from __future__ import annotations

import importlib.util
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from cdf_mj.cli import build_parser, main
from cdf_mj.cli.args import notes
from cdf_mj.extras import EXTRAS

REPO = Path(__file__).resolve().parent.parent
README = (REPO / "README.md").read_text(encoding="utf-8")


def _blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```$", README, flags=re.S | re.M)


PYTHON = _blocks("python")
BASH = _blocks("bash")


def _missing_extra(code: str) -> str | None:
    """The extra whose modules ``code`` imports and that is not installed here, if any."""
    imported = set(re.findall(r"^\s*(?:import|from)\s+([A-Za-z_]\w*)", code, flags=re.M))
    for extra, modules in EXTRAS.items():
        if any(m in imported and importlib.util.find_spec(m) is None for m in modules):
            return extra
    return None


def test_the_readme_has_snippets():
    assert len(PYTHON) >= 3 and len(BASH) >= 5


@pytest.mark.parametrize("code", PYTHON, ids=[f"python-{i}" for i in range(len(PYTHON))])
def test_python_snippet_runs(code, tmp_path):
    extra = _missing_extra(code)
    if extra:
        pytest.skip(f"the snippet needs the {extra} extra, which is not installed")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f"{code}\n{proc.stderr}"
    assert proc.stdout.strip(), "the snippet printed nothing"


def _cli_lines() -> list[str]:
    """Each ``cdf-mj ...`` or ``python -m cdf_mj ...`` command of the bash blocks, without comments."""
    lines = []
    for block in BASH:
        for line in block.splitlines():
            for command in line.split("&&"):
                words = shlex.split(command, comments=True)
                if words[:1] == ["cdf-mj"]:
                    lines.append(words[1:])
                elif words[:3] == ["python", "-m", "cdf_mj"]:
                    lines.append(words[3:])
    return [shlex.join(w) for w in lines]


@pytest.mark.parametrize("command", _cli_lines())
def test_cli_command_parses(command, capsys):
    words = shlex.split(command)
    if "--help" in words:  # prints and exits 0; nothing runs
        assert main(words) == 0 and capsys.readouterr().out.startswith(f"usage: cdf-mj {words[0]}")
        return
    args = build_parser().parse_args(words)
    assert args.command == (words[0] if words else None)
    assert notes(args) == [], "the README spells a flag as earlier releases did"


def test_ci_runs_the_readme_test_command():
    ci_commands = [line for line in (REPO / ".ci" / "run").read_text().splitlines()
                   if line.strip() and not line.startswith("#")]
    test_command = next(b.strip() for b in BASH if "pytest" in b)
    assert ci_commands[-1] == test_command
    assert "-q" in test_command.split()


def test_citation_file_and_readme_cite_the_same_paper():
    yaml = pytest.importorskip("yaml", reason="PyYAML (which the ray extra brings) is not installed")
    cff = yaml.safe_load((REPO / "CITATION.cff").read_text(encoding="utf-8"))
    paper = cff["preferred-citation"]
    citing = README.split("## Citing", 1)[1].split("\n## ", 1)[0]
    assert cff["cff-version"] == "1.2.0" and cff["license"] == "Apache-2.0"
    assert paper["title"] in " ".join(citing.split())
    for author in paper["authors"]:
        assert author["family-names"] in citing and author["given-names"] in citing
    assert str(paper["year"]) in citing
    assert "1504.00060" in paper["identifiers"][0]["value"] and "1504.00060" in citing
