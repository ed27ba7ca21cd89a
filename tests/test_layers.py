"""The package's layers: a module imports only from its own layer or lower ones.

Layers, lowest first (a name is a top-level module or subpackage of ``cdf_mj``)::

    config, records, extras, presets, traits, inputs -> model -> sim -> inference -> planners, analysis -> scenario
    -> viz -> envs -> experiments -> falsify -> cli, __main__

Every module's source is read with ``ast`` and every ``cdf_mj`` import counted, also
those inside functions and under ``TYPE_CHECKING``. The package's ``__init__`` is the
facade that re-exports names from every layer, lazily: it may import anything, and what
others import from it is resolved to the module that defines the name.
"""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import cdf_mj

PACKAGE = Path(cdf_mj.__file__).resolve().parent
LAYERS: list[set[str]] = [
    {"config", "records", "extras", "presets", "traits", "inputs"},
    {"model"},
    {"sim"},
    {"inference"},
    {"planners", "analysis"},
    {"scenario"},
    {"viz"},
    {"envs"},
    {"experiments"},
    {"falsify"},
    {"cli", "__main__"},
]
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    rel = Path(*name.split("."))
    return (PACKAGE.parent / rel).with_suffix(".py").is_file() or (PACKAGE.parent / rel / "__init__.py").is_file()


def _root_exports() -> dict[str, str]:
    """The facade's lazily re-exported names -> defining module (``_EXPORTS`` in __init__)."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "_EXPORTS" for t in node.targets):
            return ast.literal_eval(node.value)
    raise AssertionError("cdf_mj/__init__.py has no _EXPORTS dict")


def _imports(path: Path, module: str) -> set[str]:
    """The ``cdf_mj`` modules that the file imports (absolute names)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    exports = _root_exports()
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "cdf_mj"}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            if base.split(".")[0] != "cdf_mj":
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if _is_module(sub):
                    found.add(sub)
                elif base == "cdf_mj" and alias.name in exports:
                    found.add(exports[alias.name])
                elif base == "cdf_mj":
                    continue  # defined in the facade itself (__version__, ENV_ID's re-export)
                else:
                    found.add(base)
    return found


def _layer(module: str) -> str:
    """``cdf_mj.sim.scene`` -> ``sim``."""
    return module.split(".")[1]


def _graph() -> dict[str, set[str]]:
    """Every module of the package but the facade -> the cdf_mj modules it imports."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module != "cdf_mj":
            out[module] = _imports(path, module) - {"cdf_mj"}
    return out


def test_the_walk_sees_every_kind_of_import():
    """The collector finds absolute, relative, function-local and TYPE_CHECKING imports."""
    graph = _graph()
    assert "cdf_mj.scenario.world" in graph["cdf_mj.scenario.episode"]
    assert "cdf_mj.planners.baselines" in graph["cdf_mj.planners"]  # inside __getattr__
    assert "cdf_mj.config" in graph["cdf_mj.planners.cdf"]
    assert len(graph) > 30


def test_every_module_is_in_a_layer():
    unknown = sorted({_layer(m) for m in _graph()} - set(RANK))
    assert unknown == [], f"add these to LAYERS in tests/test_layers.py: {unknown}"


def test_no_import_points_up_a_layer():
    up = [f"{module} imports {target}" for module, targets in _graph().items() for target in sorted(targets)
          if RANK.get(_layer(target), -1) > RANK.get(_layer(module), len(LAYERS))]
    assert up == []


def test_no_cycle_between_subpackages():
    edges: dict[str, set[str]] = {}
    for module, targets in _graph().items():
        edges.setdefault(_layer(module), set()).update(_layer(t) for t in targets if _layer(t) != _layer(module))
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> None:
        if node in path:
            pytest.fail(f"import cycle between subpackages: {' -> '.join([*path[path.index(node):], node])}")
        if node in done:
            return
        for nxt in sorted(edges.get(node, ())):
            visit(nxt, [*path, node])
        done.add(node)

    for node in sorted(edges):
        visit(node, [])


def test_nothing_in_the_package_imports_the_command_line():
    """``cdf_mj.cli`` is the top: only its own modules and ``python -m cdf_mj`` import it."""
    users = [f"{module} imports {target}" for module, targets in _graph().items() for target in sorted(targets)
             if _layer(target) == "cli" and _layer(module) not in {"cli", "__main__"}]
    assert users == []


def test_the_command_modules_share_only_the_arguments_module():
    """Inside ``cdf_mj.cli``: ``args`` imports no other module of it, each command module
    (``episode``, ``sweep``, ...) imports only ``args``, and ``app`` assembles them."""
    graph = _graph()
    cli = {m: {t for t in targets if _layer(t) == "cli"} for m, targets in graph.items() if _layer(m) == "cli"}
    assert cli["cdf_mj.cli.args"] == set()
    commands = set(cli) - {"cdf_mj.cli", "cdf_mj.cli.__main__", "cdf_mj.cli.app", "cdf_mj.cli.args"}
    assert {"cdf_mj.cli.episode", "cdf_mj.cli.experiment", "cdf_mj.cli.bench"} <= commands
    for module in sorted(commands):
        assert cli[module] <= {"cdf_mj.cli.args"}, module
    assert commands <= cli["cdf_mj.cli.app"]


def test_the_records_schema_and_rules_need_no_file_io():
    """Inside ``cdf_mj.records``: ``schema`` imports no other module of it, ``counting``
    only ``schema``; ``files`` (the records and settings files) is beside them."""
    graph = _graph()
    inner = {m: {t for t in graph[m] if _layer(t) == "records"} for m in graph if _layer(m) == "records"}
    assert inner["cdf_mj.records.schema"] == set()
    assert inner["cdf_mj.records.counting"] == {"cdf_mj.records.schema"}
    assert inner["cdf_mj.records.files"] == {"cdf_mj.records.schema"}


@pytest.mark.parametrize("module", ["cdf_mj.model.driver", "cdf_mj.model.layout", "cdf_mj.model.occlusion",
                                    "cdf_mj.model.vehicle", "cdf_mj.inference.particle_filter",
                                    "cdf_mj.scenario.trace_file"])
def test_the_models_and_the_filter_run_without_mujoco(module):
    """Importing the NumPy layers loads neither MuJoCo nor the simulator (fresh interpreter)."""
    code = (f"import sys, {module}\n"
            "bad = sorted(m for m in sys.modules if m == 'mujoco' or m.startswith(('mujoco.', 'cdf_mj.sim')))\n"
            "print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_the_facade_lists_and_resolves_every_export():
    """``__all__`` (a literal, for linters) names exactly the lazy exports, and each one
    resolves to the object its defining module holds."""
    exports = _root_exports()
    assert sorted(cdf_mj.__all__) == sorted(["ENV_ID", "__version__", *exports])
    for name, module in exports.items():
        assert getattr(cdf_mj, name) is getattr(importlib.import_module(module), name), name
