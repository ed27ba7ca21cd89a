"""Packaging: a wheel built from this checkout holds the MJCF files and installs and runs
outside the checkout.

Slow (about 20 s): builds the wheel without network (``--no-build-isolation``: setuptools
from the ``test`` extra), installs it into a new virtual environment in a temporary
directory, and runs the installed ``cdf-mj`` from another directory. The new environment
sees the dependencies of this one through a ``.pth`` file instead of downloading them;
files there are on ``sys.path`` but their own ``.pth`` files are not run, so an editable
install of this checkout cannot shadow the wheel (the tests check where ``cdf_mj`` is
imported from).
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from cdf_mj import __version__
from cdf_mj.extras import WHEEL

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
#: What the build reads from the checkout (pyproject.toml names README.md and LICENSE).
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "cdf_mj", "models")
MJCF = sorted(p.name for p in (REPO / "models" / "xml").glob("*.xml"))


def _run(argv: list[str | Path], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` in ``cwd`` with no PYTHONPATH (nothing of the checkout is importable)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    proc = subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f"{argv} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel of a copy of the checkout (so the build leaves nothing in the checkout)."""
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(path, source / name)
    out = tmp_path_factory.mktemp("wheelhouse")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "--quiet", "--wheel-dir", out, source], cwd=source)
    (built,) = out.glob("*.whl")
    return built


@pytest.fixture(scope="module")
def venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A new virtual environment outside the checkout with the wheel installed; the
    dependencies come from this interpreter's site-packages."""
    root = tmp_path_factory.mktemp("venv")
    _run([sys.executable, "-m", "venv", "--without-pip", root], cwd=root)
    python = root / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", "--quiet",
          wheel], cwd=root)
    purelib = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=root)
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"], *site.getsitepackages()}
    if site.ENABLE_USER_SITE:
        ours.add(site.getusersitepackages())
    Path(purelib.stdout.strip(), "dependencies.pth").write_text(
        "".join(f"{p}\n" for p in sorted(ours) if Path(p).is_dir()))
    return root


@pytest.fixture
def elsewhere(tmp_path: Path) -> Path:
    """A working directory with nothing of the checkout in it."""
    return tmp_path


def test_the_wheel_holds_the_package_the_mjcf_files_and_the_licence(wheel):
    assert wheel.name == WHEEL  # the file install_hint names
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        dist_info = f"cdf_mj-{__version__}.dist-info"
        metadata = zf.read(f"{dist_info}/METADATA").decode()
        entry_points = zf.read(f"{dist_info}/entry_points.txt").decode()
    assert {f"cdf_mj/assets/{name}" for name in MJCF} <= names
    modules = {path.relative_to(REPO).as_posix() for path in (REPO / "cdf_mj").rglob("*.py")}
    assert modules - names == set(), "modules missing from the wheel (a subpackage not in pyproject.toml?)"
    assert {"cdf_mj/assets/README.md", "cdf_mj/py.typed", "cdf_mj/__main__.py",
            f"{dist_info}/licenses/LICENSE"} <= names
    assert len(MJCF) >= 5  # car, intersection, scene and the four-way pair
    presets = {path.relative_to(REPO).as_posix() for path in (REPO / "cdf_mj" / "presets").glob("*.toml")}
    assert len(presets) >= 5 and presets - names == set(), "preset files missing from the wheel"
    assert not any(n.startswith(("tests/", "scripts/", "docs/", "models/")) for n in names)
    assert "License-Expression: Apache-2.0" in metadata
    assert "cdf-mj = cdf_mj.cli:main" in entry_points


def test_the_installed_package_is_the_wheel_and_reads_its_own_mjcf(venv, elsewhere):
    proc = _run([venv / "bin" / "python", "-c",
                 "import json, cdf_mj, cdf_mj.sim.assets as a; "
                 "print(json.dumps([cdf_mj.__file__, str(a.DEFAULT_SCENE)]))"], cwd=elsewhere)
    module, scene = (Path(p) for p in json.loads(proc.stdout))
    assert module.is_relative_to(venv), f"cdf_mj imported from {module}, not from the wheel"
    assert scene.is_relative_to(venv) and scene.is_file()


def test_the_installed_command_runs_an_episode_like_the_checkout(venv, elsewhere):
    installed = _run([venv / "bin" / "cdf-mj", "episode", "--seed", "1"], cwd=elsewhere)
    record = json.loads(installed.stdout)
    assert record["seed"] == 1 and record["label"] in {"Cutoff", "Yield", "Right"}
    checkout = _run([sys.executable, "-m", "cdf_mj", "episode", "--seed", "1"], cwd=REPO)
    assert installed.stdout == checkout.stdout


def test_the_installed_command_reads_its_own_presets(venv, elsewhere):
    shown = _run([venv / "bin" / "cdf-mj", "presets", "fast-ego"], cwd=elsewhere)
    assert "source: fast-ego" in shown.stdout and "ego.speed = 17.9" in shown.stdout
    listing = _run([venv / "bin" / "cdf-mj", "presets"], cwd=elsewhere)
    shipped = sorted(p.stem for p in (REPO / "cdf_mj" / "presets").glob("*.toml"))
    assert [line.split()[0] for line in listing.stdout.splitlines()[:len(shipped)]] == shipped


def test_python_m_cdf_mj(venv, elsewhere):
    version = _run([venv / "bin" / "python", "-m", "cdf_mj", "--version"], cwd=elsewhere)
    assert version.stdout.strip() == f"cdf-mj {__version__}"
    listing = _run([venv / "bin" / "python", "-m", "cdf_mj"], cwd=elsewhere)
    assert "commands:" in listing.stdout and "reproduce" in listing.stdout


def test_the_installed_command_renders_a_frame(venv, elsewhere):
    pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
    pytest.importorskip("PIL", reason="the viz extra (Pillow) is not installed")
    from cdf_mj.sim.gl import RenderError, gl_backend

    try:
        gl_backend()  # as tests/test_render.py decides: skip only when no backend works here
    except RenderError as exc:
        pytest.skip(f"no OpenGL backend can be created here: {exc}")
    _run([venv / "bin" / "cdf-mj", "render", "--frame", "1", "--out", "x.png", "--width", "160",
          "--height", "120"], cwd=elsewhere)
    png = (elsewhere / "x.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 1000
