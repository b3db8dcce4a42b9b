"""The shared layers ask the methods, never which method they are.

Evaluation, metrics, records, timing, tables, runs, plots, report and experiments reach a method
through :mod:`btel.methods.registry` (``make_method``, ``load``, ``REGISTRY``) and the
:class:`~btel.methods.base.PlaceLocalizer` interface. Read from the source with :mod:`ast` (wherever an
import stands, in functions too), each of their modules must

- import no method module: ``btel.methods.btel``, ``btel.methods.codes``, ``btel.methods.baselines``
  (or anything inside them), ``btel.methods.ryth``, ``btel.methods.auto``;
- name no method class (a class behind :data:`btel.methods.REGISTRY`, or one of its bases inside
  ``btel.methods``) in ``isinstance``/``issubclass``/``hasattr``/``type(...)`` checks.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

import btel
from btel.methods import REGISTRY
from test_import_graph import import_source

SRC = Path(btel.__file__).resolve().parent

#: The shared layers: modules or packages under ``btel``.
SHARED = ("evaluation", "experiments")
#: Method modules (and packages) the shared layers must not import.
FORBIDDEN = ("btel.methods.btel", "btel.methods.codes", "btel.methods.baselines", "btel.methods.ryth",
             "btel.methods.auto")
#: Calls in which a method class must not be named.
CHECKS = {"isinstance", "issubclass", "hasattr", "type"}


def method_class_names() -> set[str]:
    """Names of every class behind the registry, and of its bases defined inside ``btel.methods``."""
    names = set()
    for factory, _ in REGISTRY.values():
        cls = getattr(factory, "func", factory)  # functools.partial → the class
        for base in inspect.getmro(cls):
            if base.__module__.startswith("btel.methods") and base.__module__ != "btel.methods.base":
                names.add(base.__name__)
    return names


def shared_files() -> dict[str, Path]:
    """Dotted module name → file, for every shared module."""
    out = {}
    for name in SHARED:
        package = SRC / name
        paths = sorted(package.rglob("*.py")) if package.is_dir() else [SRC / f"{name}.py"]
        for path in paths:
            parts = ["btel", *path.relative_to(SRC).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _imported(node: ast.AST, module: str, is_package: bool) -> list[str]:
    """The absolute module names an import statement names (``from P import x`` names ``P.x``)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        source = import_source(node, module, is_package)
        return [source] + [f"{source}.{alias.name}" for alias in node.names]
    return []


def _names_in(node: ast.AST) -> set[str]:
    """Every identifier, attribute name and string constant inside ``node``."""
    out = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name):
            out.add(sub.id)
        elif isinstance(sub, ast.Attribute):
            out.add(sub.attr)
        elif isinstance(sub, ast.Constant) and isinstance(sub.value, str):
            out.add(sub.value)
    return out


def violations(source: str, module: str, classes: set[str], *, is_package: bool = False) -> list[str]:
    """What in ``source`` (the text of ``module``) breaks the two rules, one line each."""
    found = []
    tree = ast.parse(source)
    for node in ast.walk(tree):
        for name in _imported(node, module, is_package):
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN):
                found.append(f"{module}:{node.lineno} imports {name}")
                break
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in CHECKS:
            named = sorted(_names_in(node) & classes)
            if named:
                found.append(f"{module}:{node.lineno} {node.func.id}(…) on method class {', '.join(named)}")
        if isinstance(node, ast.Compare):  # type(m).__name__ == "CodeLocalizer"
            named = sorted(_names_in(node) & classes)
            if named and any(isinstance(sub, ast.Call) and getattr(sub.func, "id", None) == "type"
                             for sub in ast.walk(node)):
                found.append(f"{module}:{node.lineno} compares a type with method class {', '.join(named)}")
    return found


CLASSES = method_class_names()


def test_the_method_classes_are_read_from_the_registry() -> None:
    assert {"BTELocalizer", "CodeLocalizer", "RYTHLocalizer", "AutoLocalizer", "PQLocalizer"} <= CLASSES
    assert "PlaceLocalizer" not in CLASSES  # the interface itself may be named
    assert {"btel.evaluation", "btel.experiments", "btel.experiments.beyond", "btel.evaluation.plots.run"} <= set(shared_files())


@pytest.mark.parametrize(("source", "module", "what"), [
    ("from ..methods.btel.diagnostics import bit_accuracy\n", "btel.experiments.beyond", "imports btel.methods.btel"),
    ("from ..methods.codes import planning\n", "btel.experiments.codes", "imports btel.methods.codes"),
    ("def f():\n    from .methods import ryth\n", "btel.evaluation", "imports btel.methods.ryth"),
    ("import btel.methods.baselines.pq\n", "btel.evaluation.runs", "imports btel.methods.baselines"),
    ("from btel.methods.auto import AutoLocalizer\n", "btel.experiments.report", "imports btel.methods.auto"),
    ("def f(m):\n    return isinstance(m, CodeLocalizer)\n", "btel.evaluation", "isinstance(…) on method class"),
    ("def f(m):\n    return isinstance(m, (int, registry.BTELocalizer))\n", "btel.evaluation.runs", "on method class BTELocalizer"),
    ("def f():\n    return hasattr(RYTHLocalizer, 'periods_')\n", "btel.evaluation.plots.run", "hasattr(…) on method class"),
    ("def f(m):\n    return type(m).__name__ == 'PQLocalizer'\n", "btel.evaluation.tables", "compares a type"),
])
def test_the_check_finds_a_violation(source: str, module: str, what: str) -> None:
    found = violations(source, module, CLASSES)
    assert len(found) == 1 and what in found[0], found


def test_the_check_passes_the_registry_and_the_interface() -> None:
    source = ("from ..methods.registry import make_method, load\nfrom ..methods.base import PlaceLocalizer\n"
              "def f(m):\n    return isinstance(m, PlaceLocalizer) and hasattr(m, 'check_budget')\n")
    assert violations(source, "btel.experiments._common", CLASSES) == []


def test_the_shared_layers_ask_the_methods_not_which_method() -> None:
    found = [v for module, path in shared_files().items()
             for v in violations(path.read_text(encoding="utf-8"), module, CLASSES,
                                 is_package=path.name == "__init__.py")]
    assert not found, "the shared layers name method modules or classes:\n  " + "\n  ".join(found)
