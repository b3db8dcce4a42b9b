"""The import graph of ``src/btel`` has no cycle: every module can be read knowing only those below it.

The graph is built from the source with :mod:`ast`, not by importing: an edge A → B for every
``import``/``from … import`` in A naming btel module B, wherever it stands (module level, inside
functions, under ``if TYPE_CHECKING:`` — a type-only import is still a dependency of the design).
Relative imports are resolved against A's package; ``from P import x`` is an import of ``P.x``
when x is a module of package P, else of P itself. A cycle is a strongly connected component of
more than one module (or a module importing itself).
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path


import btel

SRC = Path(btel.__file__).resolve().parent

#: The layers above the method core.
UPPER = ("btel.experiments", "btel.evaluation", "btel.cli")

#: The package's layers, bottom first: a module imports only from its own layer or those below it.
#: ``btel`` (the root's lazy public names) and ``btel._lazy`` sit outside the order.
LAYERS = (
    ("btel.exceptions",),
    ("btel.core",),
    ("btel.sequence", "btel.learning", "btel.descriptors"),
    ("btel.datasets",),
    ("btel.methods.base", "btel.methods.roles"),
    ("btel.methods",),
    ("btel.evaluation",),
    ("btel.experiments",),
    ("btel.cli",),
)


def within(module: str, names: Iterable[str]) -> bool:
    """``module`` is one of ``names`` or inside one of those packages."""
    return any(module == n or module.startswith(n + ".") for n in names)


def module_files(root: Path, package: str) -> dict[str, Path]:
    """Dotted module name → source file, for every ``.py`` file under ``root`` (the package ``package``)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = [package, *path.relative_to(root).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def import_source(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute module a ``from … import`` statement in ``module`` reads from (relative levels resolved)."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph(root: Path, package: str) -> dict[str, set[str]]:
    """Module → the modules of ``package`` it imports (see the module docstring for the rules)."""
    files = module_files(root, package)

    def resolve(name: str) -> str | None:
        """``name`` if it is a module, else its longest prefix that is; None outside the package."""
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        is_package = path.name == "__init__.py"
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                edges.update(filter(None, (resolve(alias.name) for alias in node.names)))
            elif isinstance(node, ast.ImportFrom):
                source = import_source(node, module, is_package)
                if source != package and not source.startswith(package + "."):
                    continue
                for alias in node.names:
                    submodule = f"{source}.{alias.name}"
                    edges.add(submodule if submodule in files else resolve(source))
        edges.discard(None)
        graph[module] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with a cycle (Tarjan), each sorted, largest first."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:  # recursion depth ≤ number of modules (~70)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found, key=lambda c: (-len(c), c))


def a_cycle_through(component: Iterable[str], graph: dict[str, set[str]]) -> list[str]:
    """One closed path A → … → A inside a strongly connected component (for the failure message)."""
    members = set(component)
    start = min(members)
    path, seen = [start], {start}
    while True:  # follow edges inside the component until a module repeats: that stretch is a cycle
        nxt = min(w for w in graph[path[-1]] if w in members)
        if nxt in seen:
            return path[path.index(nxt):] + [nxt]
        path.append(nxt)
        seen.add(nxt)


def describe(found: list[list[str]], graph: dict[str, set[str]]) -> str:
    return "\n".join(f"  {len(c)} modules {c}; e.g. {' → '.join(a_cycle_through(c, graph))}" for c in found)


GRAPH = import_graph(SRC, "btel")


def test_the_graph_is_read_from_the_source() -> None:
    assert len(GRAPH) > 40
    assert "btel.experiments.beyond" in GRAPH["btel.experiments"]  # from .beyond import …
    assert "btel.experiments._common" in GRAPH["btel.experiments.beyond"]
    assert {"btel.evaluation.batch", "btel.evaluation.measure"} <= GRAPH["btel.evaluation"]  # in functions
    assert "btel.experiments" in GRAPH["btel.cli.experiment"] and "btel.experiments.report" in GRAPH["btel.cli.report"]
    assert "btel.evaluation.plots" in GRAPH["btel.evaluation.runs"]  # `from . import plots as _plots`: the submodule, not the package


def test_the_cycle_finder_on_a_toy_package(tmp_path: Path) -> None:
    pkg = tmp_path / "toy"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .a import f\n")
    (pkg / "a.py").write_text("def f():\n    from .sub import b\n")  # function-level import
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "b.py").write_text("from .. import c\nimport toy.sub.d\n")  # `from .. import c`: module c
    (pkg / "c.py").write_text("from toy import a\nimport os\n")
    (pkg / "sub" / "d.py").write_text("from . import VALUE\n")  # a name of the package: an edge to toy.sub
    graph = import_graph(pkg, "toy")
    assert graph == {"toy": {"toy.a"}, "toy.a": {"toy.sub.b"}, "toy.sub": set(), "toy.sub.b": {"toy.c", "toy.sub.d"},
                     "toy.c": {"toy.a"}, "toy.sub.d": {"toy.sub"}}
    assert cycles(graph) == [["toy.a", "toy.c", "toy.sub.b"]]
    assert a_cycle_through(cycles(graph)[0], graph) == ["toy.a", "toy.sub.b", "toy.c", "toy.a"]


def test_the_import_graph_has_no_cycle() -> None:
    found = cycles(GRAPH)
    assert not found, f"{len(found)} import cycle(s) in src/btel:\n" + describe(found, GRAPH)


def test_the_method_interface_does_not_import_its_implementations() -> None:
    """base.py (the interface) imports no method, registry or upper layer."""
    below = {"btel.methods", "btel.methods.btel.localizer", "btel.methods.ryth", "btel.methods.baselines", *UPPER}
    bad = sorted(m for m in GRAPH.get("btel.methods.base", ()) if within(m, below))
    assert not bad, f"btel.methods.base imports {bad}"


def test_no_module_is_above_450_lines() -> None:
    """A module is read in one sitting: what grows past 450 lines splits along its ideas."""
    long = {str(p.relative_to(SRC)): n for p in SRC.rglob("*.py")
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > 450}
    assert not long, f"modules above 450 lines: {long}"


def test_outside_the_methods_only_the_registry_is_imported() -> None:
    """Shared layers reach a method through btel.methods.registry (make_method, load), never its module;
    only the package's lazy public names (btel/__init__) point at the two estimators users import."""
    public = {"btel.methods.btel.localizer", "btel.methods.codes.estimator"}
    interface = {"btel.methods.registry", "btel.methods.base", "btel.methods.roles"}
    bad = {m: sorted(e for e in edges if within(e, ["btel.methods"]) and e not in interface
                     and not (m == "btel" and e in public))
           for m, edges in GRAPH.items() if not within(m, ["btel.methods"])}
    bad = {m: e for m, e in bad.items() if e}
    assert not bad, f"modules outside btel.methods importing a method module: {bad}"
    # and no method module imports a layer above the methods
    upward = {m: sorted(e for e in edges if within(e, UPPER)) for m, edges in GRAPH.items() if within(m, ["btel.methods"])}
    assert not {m: e for m, e in upward.items() if e}


def layer_of(module: str) -> int | None:
    """Index of ``module``'s layer in LAYERS (the most specific match), None outside the order."""
    best: tuple[int, int] | None = None
    for i, names in enumerate(LAYERS):
        for n in names:
            if within(module, [n]) and (best is None or len(n) > best[1]):
                best = (i, len(n))
    return None if best is None else best[0]


def test_every_module_sits_in_a_layer_and_imports_no_layer_above_it() -> None:
    """The folders show the layers: exceptions < core < sequence/learning/descriptors < datasets <
    the method interface < the methods < evaluation < experiments < cli. No arrow points up."""
    loose = sorted(m for m in GRAPH if layer_of(m) is None and m not in {"btel", "btel._lazy"})
    assert not loose, f"modules outside every layer (the root keeps only the public face): {loose}"
    upward = sorted(f"{m} → {e}" for m, edges in GRAPH.items() for e in edges
                    if layer_of(m) is not None and layer_of(e) is not None and layer_of(e) > layer_of(m))
    assert not upward, "imports that point up a layer:\n  " + "\n  ".join(upward)


def test_the_root_keeps_only_the_public_face() -> None:
    root_modules = sorted(p.name for p in SRC.glob("*.py"))
    assert len(root_modules) <= 12, root_modules
