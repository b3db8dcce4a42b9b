"""The command line knows no method: read from the source of every module of ``btel.cli`` with :mod:`ast`.

No module imports a method module (only :mod:`btel.methods.registry`, and the plain role names
of :mod:`btel.methods.roles`), spells a registered method name as a string literal (or a
comma-separated list of them), or names a method class. What needs a method by role (the
default, the unbudgeted reference, the demo set) asks the library. The checker is itself tested
on sources that break each rule, so a violation in the package cannot pass unseen.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import btel
import btel.cli
from btel.methods import MODEL_CLASSES, REGISTRY
from test_import_graph import import_source

CLI = Path(btel.cli.__file__).resolve().parent
SRC = CLI.parents[1]

#: Method modules: the shared layers reach methods only through the registry.
METHOD_PACKAGES = ("btel.methods.btel", "btel.methods.codes", "btel.methods.baselines", "btel.methods.ryth",
                   "btel.methods.auto")


def is_module(name: str) -> bool:
    path = SRC.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(tree: ast.AST, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, dotted name) of every btel module imported anywhere in ``tree`` (relative imports resolved)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = import_source(node, module, is_package)
            for alias in node.names:  # `from btel.methods import btel` imports the submodule
                sub = f"{source}.{alias.name}"
                out.append((node.lineno, sub if is_module(sub) else source))
    return out


def violations(source: str, module: str = "btel.cli.x", is_package: bool = False) -> list[str]:
    """Every way ``source`` (a module of btel.cli) names a method, one line each; empty when it names none."""
    names = set(REGISTRY)
    classes = set(MODEL_CLASSES)
    tree = ast.parse(source)
    found = [f"line {line}: imports the method module {name}" for line, name in
             imported_modules(tree, module, is_package)
             if any(name == p or name.startswith(p + ".") for p in METHOD_PACKAGES)]
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            parts = [p.strip() for p in node.value.split(",")]
            if all(p in names for p in parts):
                found.append(f"line {node.lineno}: the method name(s) {node.value!r} as a string literal")
        elif isinstance(node, ast.Name) and node.id in classes:
            found.append(f"line {node.lineno}: the method class {node.id}")
        elif isinstance(node, ast.Attribute) and node.attr in classes:
            found.append(f"line {node.lineno}: the method class {node.attr}")
    return found


def cli_modules() -> list[Path]:
    return sorted(CLI.rglob("*.py"))


def test_the_cli_is_a_package_of_small_modules() -> None:
    paths = cli_modules()
    assert {"__init__", "train", "evaluate", "localize", "demo", "extract", "info", "methods",
            "experiment", "report"} <= {p.stem for p in paths}
    long = {p.name: n for p in paths if (n := len(p.read_text(encoding="utf-8").splitlines())) >= 450}
    assert not long, f"modules of 450 lines or more: {long}"


@pytest.mark.parametrize("path", cli_modules(), ids=lambda p: p.name)
def test_no_cli_module_names_a_method(path: Path) -> None:
    parts = ["btel", *path.relative_to(SRC / "btel").with_suffix("").parts]
    is_package = parts[-1] == "__init__"
    module = ".".join(parts[:-1] if is_package else parts)
    found = violations(path.read_text(encoding="utf-8"), module, is_package)
    assert not found, f"{path.name} names a method (ask btel.methods.registry instead):\n  " + "\n  ".join(found)


@pytest.mark.parametrize("source, what", [
    ('x = "bruteforce"\n', "as a string literal"),
    ('def f(m):\n    return m == "btel-c"\n', "as a string literal"),
    ('DEFAULT = "btel-c, btel-r,pq"\n', "as a string literal"),
    ("from ..methods.btel.localizer import block_size_for_tolerance\n", "method module btel.methods.btel.localizer"),
    ("def f():\n    from ..methods import auto\n", "method module btel.methods.auto"),
    ("import btel.methods.codes.estimator\n", "method module btel.methods.codes.estimator"),
    ("from btel.methods.baselines import BASELINES\n", "method module btel.methods.baselines"),
    ("def f(m):\n    return isinstance(m, BTELocalizer)\n", "method class BTELocalizer"),
    ("def f(m):\n    return isinstance(m, btel.CodeLocalizer)\n", "method class CodeLocalizer"),
])
def test_the_checker_finds_each_kind_of_violation(source: str, what: str) -> None:
    found = violations(source)
    assert len(found) == 1 and what in found[0], found


def test_the_checker_lets_through_what_is_not_a_method_name() -> None:
    source = ('"""Docstring: e.g. --methods btel-c,btel-r,pq --param bruteforce:budget=1MB."""\n'
              "from ..methods.registry import REFERENCE_METHOD, make_method\n"
              "from ..methods.roles import DEFAULT_METHOD\n"
              'HELP = "number of regions r, or \'auto\'."\n'
              'x = {"route": 1, "l2": 2, "": 3}\n')
    assert violations(source) == []


def test_the_roles_are_registered_methods() -> None:
    from btel.methods import roles
    from btel.methods import registry

    assert roles.DEFAULT_METHOD in REGISTRY and roles.REFERENCE_METHOD in REGISTRY
    assert roles.DEMO_METHODS and set(roles.DEMO_METHODS) <= set(REGISTRY)
    assert (registry.DEFAULT_METHOD, registry.REFERENCE_METHOD, registry.DEMO_METHODS) == (
        roles.DEFAULT_METHOD, roles.REFERENCE_METHOD, roles.DEMO_METHODS)


@pytest.mark.parametrize("command, role", [("train", "DEFAULT_METHOD"), ("evaluate", "DEFAULT_METHOD"),
                                           ("demo", "DEMO_METHODS")])
def test_command_help_shows_the_defaults_without_loading_the_methods(command: str, role: str) -> None:
    """The defaults in ``--help`` come from the registry's role names, not from importing every method."""
    from btel.methods import registry

    value = getattr(registry, role)
    default = value if isinstance(value, str) else ",".join(value)
    code = (f"import sys; sys.argv = ['btel', '{command}', '--help']\nfrom btel.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print('LOADED', *sorted(m for m in sys.modules if m.split('.')[0] in ('sklearn', 'scipy', 'faiss')))")
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True).stdout
    assert f"[default:{default}]" in "".join(out.split())  # the help wraps lines, even inside a word
    assert out.rstrip().splitlines()[-1] == "LOADED", out.splitlines()[-1]


def test_every_command_that_writes_takes_dash_o() -> None:
    """-o names what a command writes, a file (train, localize, extract) or a folder (evaluate, demo,
    experiment): one flag to remember."""
    import click

    from btel.cli import main

    ctx = click.Context(main)
    for name in ("train", "localize", "extract", "evaluate", "demo", "experiment"):
        command = main.get_command(ctx, name)
        flags = {opt for p in command.params for opt in getattr(p, "opts", [])}
        assert "-o" in flags, name
