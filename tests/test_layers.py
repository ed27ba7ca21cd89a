"""The package's layers: a module imports only from its own layer or lower ones.

Layers, lowest first (a name is a top-level module or subpackage of ``cdf_mj``)::

    _version, config, records, extras, presets, traits, inputs -> model -> sim -> inference -> planners, analysis
    -> scenario -> viz -> envs -> experiments -> falsify -> cli, __main__

Every module's source is read with ``ast`` and every ``cdf_mj`` import counted, also
those inside functions and under ``TYPE_CHECKING``. The package's ``__init__`` is the
facade that re-exports names from every layer, lazily: it may import anything, and no
module imports from it (what it would give is resolved to the module that defines the
name). No two modules import each other, directly or round a longer circle.
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
    {"_version", "config", "records", "extras", "presets", "traits", "inputs"},
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


def _is_type_checking(node: ast.If) -> bool:
    """Whether ``node`` is ``if TYPE_CHECKING:`` (or ``if typing.TYPE_CHECKING:``)."""
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _import_time_nodes(tree: ast.Module) -> list[ast.AST]:
    """The nodes of a module that run when it is imported: its body and the bodies of its
    classes, ``if``, ``try`` and ``with`` blocks, not those of functions nor of ``if
    TYPE_CHECKING:`` (its ``else`` runs)."""
    out: list[ast.AST] = []
    todo: list[ast.AST] = list(tree.body)
    while todo:
        node = todo.pop()
        out.append(node)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(node, ast.If) and _is_type_checking(node):
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))
    return out


def _imports(path: Path, module: str, at_import: bool = False) -> set[str]:
    """The ``cdf_mj`` modules that the file imports (absolute names); with ``at_import``
    only those it imports when it is imported (:func:`_import_time_nodes`)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    exports = _root_exports()
    found: set[str] = set()
    for node in _import_time_nodes(tree) if at_import else ast.walk(tree):
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


def _graph(at_import: bool = False) -> dict[str, set[str]]:
    """Every module of the package but the facade -> the cdf_mj modules it imports (with
    ``at_import``: when it is imported)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module != "cdf_mj":
            out[module] = _imports(path, module, at_import) - {"cdf_mj"}
    return out


def test_the_walk_sees_every_kind_of_import():
    """The collector finds absolute, relative, function-local and TYPE_CHECKING imports;
    the import-time walk leaves the last two out."""
    graph, at_import = _graph(), _graph(at_import=True)
    assert "cdf_mj.scenario.world" in graph["cdf_mj.scenario.episode"]
    assert "cdf_mj.planners.cdf" in graph["cdf_mj.planners"]  # under TYPE_CHECKING
    assert "cdf_mj.planners.cdf" not in at_import["cdf_mj.planners"]
    assert "cdf_mj.planners.registry" in graph["cdf_mj.experiments.bench.planners"]  # inside a function
    assert "cdf_mj.planners.registry" not in at_import["cdf_mj.experiments.bench.planners"]
    assert "cdf_mj.config" in graph["cdf_mj.planners.cdf"]
    assert "cdf_mj.config" in at_import["cdf_mj.planners.cdf"]
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


def _circle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (its modules in order, the first again at the end),
    or None."""
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> list[str] | None:
        if node in path:
            return [*path[path.index(node):], node]
        if node in done:
            return None
        for nxt in sorted(graph.get(node, ())):
            found = visit(nxt, [*path, node])
            if found:
                return found
        done.add(node)
        return None

    for node in sorted(graph):
        found = visit(node, [])
        if found:
            return found
    return None


def test_no_import_circle_between_modules_at_import():
    """What a module imports when it is imported (not inside functions, not under
    ``TYPE_CHECKING``) never leads back to it: no module can meet itself half-initialised."""
    circle = _circle(_graph(at_import=True))
    assert circle is None, f"import circle at import time: {' -> '.join(circle)}"


def test_no_import_circle_between_modules_at_all():
    """Not even through a function-local or a ``TYPE_CHECKING`` import (the kind that
    ``falsify.report`` and ``falsify.run``, and ``planners.base`` and ``planners.registry``,
    once made): a lazy import is for a slow or optional module, not to hide a circle."""
    circle = _circle(_graph())
    assert circle is None, f"import circle: {' -> '.join(circle)}"


def test_no_module_imports_from_the_package_facade():
    """``cdf_mj/__init__.py`` re-exports names from every layer; a module that imported from
    it (``from cdf_mj import X``, ``import cdf_mj``) would import upwards. ``__version__``
    comes from ``cdf_mj._version``."""
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        if module == "cdf_mj":
            continue
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*anchor, base] if base else anchor)
                if base == "cdf_mj" and any(not _is_module(f"cdf_mj.{a.name}") for a in node.names):
                    bad.append(f"{module}:{node.lineno}")
            elif isinstance(node, ast.Import) and any(a.name == "cdf_mj" for a in node.names):
                bad.append(f"{module}:{node.lineno}")
    assert bad == []


def test_the_version_is_written_once():
    """``cdf_mj.__version__`` is ``cdf_mj._version``'s, which pyproject.toml reads."""
    from cdf_mj import _version

    assert cdf_mj.__version__ is _version.__version__
    assert 'version = { attr = "cdf_mj._version.__version__" }' in (PACKAGE.parent / "pyproject.toml").read_text()


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
