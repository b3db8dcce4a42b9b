"""The documentation runs as written: every ```python block of README.md and docs/guide/*.md, page by
page, in a fresh folder; every public name has an API entry; no module docstring is a history.

A page's blocks run in order in one namespace, in a new temporary working directory, with
``BTEL_SHARED_DATA`` set to the real data (``../shared/data`` beside the project). Blocks that must
not run (shell, output) are fenced ```bash or ```text.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import os
import re
from pathlib import Path

import pytest

from conftest import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "docs" / "index.md", *sorted((ROOT / "docs" / "guide").glob("*.md"))]
FENCE = re.compile(r"^```python\n(.*?)^```$", re.MULTILINE | re.DOTALL)
DOCSTRING_LINES = 40
HISTORY = re.compile(r"^\s*History\b|Added after|Before this rule", re.MULTILINE)
API_PACKAGES = {
    "btel": "btel.md", "btel.methods": "methods.md", "btel.methods.base": "methods.md",
    "btel.methods.btel": "methods.md", "btel.methods.codes": "methods.md", "btel.methods.auto": "methods.md",
    "btel.methods.ryth": "methods.md", "btel.methods.baselines": "methods.md",
    "btel.datasets": "datasets.md", "btel.descriptors": "descriptors.md",
    "btel.evaluation": "evaluation.md", "btel.sequence": "sequence.md", "btel.exceptions": "exceptions.md",
}


def python_blocks(page: Path) -> list[str]:
    """The ```python blocks of a markdown page, in order."""
    return FENCE.findall(page.read_text(encoding="utf-8"))


def test_the_pages_have_python_blocks() -> None:
    found = {page.name: len(python_blocks(page)) for page in PAGES}
    assert len(PAGES) >= 9, f"README and eight guide pages expected, found {[p.name for p in PAGES]}"
    assert found["README.md"] >= 1, found


def test_the_site_home_shows_the_readmes_python() -> None:
    # A Python user lands on the site's home page: it carries the README's ten lines, kept equal.
    assert python_blocks(ROOT / "docs" / "index.md") == python_blocks(ROOT / "README.md")[:1]


def test_block_extraction_ignores_other_fences(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text("```bash\nrm -rf /\n```\n\n```python\nx = 1\n```\n\n```text\nout\n```\n")
    assert python_blocks(page) == ["x = 1\n"]


@pytest.mark.realdata
@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_page_python_blocks_run(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                shared_data: Path) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BTEL_SHARED_DATA", str(SHARED_DATA))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict[str, object] = {"__name__": "__docs__"}
    for number, block in enumerate(python_blocks(page), 1):
        code = compile(block, f"{page.name}:block{number}", "exec")
        try:
            exec(code, namespace)  # noqa: S102 - the documentation's own examples
        except Exception as error:  # pragma: no cover - the failure message is the point
            pytest.fail(f"{page.relative_to(ROOT)} python block {number} failed: {error!r}\n{block}")


def test_every_public_name_has_an_api_entry() -> None:
    missing = []
    for package, page in API_PACKAGES.items():
        text = (ROOT / "docs" / "api" / page).read_text(encoding="utf-8")
        for name in importlib.import_module(package).__all__:
            if name.startswith("__"):
                continue
            if f"::: {package}.{name}\n" not in text and f"`{package}.{name}`" not in text:
                missing.append(f"{package}.{name} ({page})")
    assert not missing, f"public names without an API entry: {missing}"


def _module_docstrings() -> list[tuple[str, str]]:
    found = []
    for path in sorted((ROOT / "src").rglob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")), clean=False)
        if doc:
            found.append((path.relative_to(ROOT).as_posix(), doc))
    return found


def test_no_module_docstring_over_the_limit() -> None:
    over = {path: len(doc.splitlines()) for path, doc in _module_docstrings()
            if len(doc.splitlines()) > DOCSTRING_LINES}
    assert not over, (f"module docstrings over {DOCSTRING_LINES} lines (move the evidence to "
                      f"docs/decisions): {over}")


def test_no_history_in_module_docstrings() -> None:
    found = [path for path, doc in _module_docstrings() if HISTORY.search(doc)]
    assert not found, f"module docstrings telling a history (move it to docs/decisions): {found}"


def test_site_config_names_every_page() -> None:
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = [p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")]
    excluded = ("reading.md", "reading-codes.md", "refactor-check/")
    missing = [p for p in pages if not p.startswith(excluded) and p not in config]
    assert not missing, f"pages not in mkdocs.yml's nav: {missing}"
    assert os.path.isfile(ROOT / "docs" / "figures" / "frontier-frontier_recall_vs_bytes.png")


def test_readme_is_short_and_its_test_command_is_what_ci_runs() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = readme.splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines (at most 200)"
    long = [number for number, line in enumerate(lines, 1) if len(line) > 200]
    assert not long, f"README.md lines over 200 characters: {long}"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = re.search(r"# --- README: test command ---\n(.+)\n", ci)
    assert command is not None, ".ci/run lost its '# --- README: test command ---' marker"
    shown = f"```bash\n{command.group(1)}\n```"
    assert shown in readme, f"README does not show CI's test command {command.group(1)!r}"
    assert 'pip install -e ".[dev]"' in readme and "btel demo" in readme


def test_readme_links_resolve() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    missing = [t for t in targets if not t.startswith("http") and not (ROOT / t).exists()]
    assert targets and not missing, f"README links to missing files: {missing}"


def _rst_markup():
    spec = importlib.util.spec_from_file_location("rst_markup", ROOT / "docs" / "_griffe" / "rst_markup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_site_reads_rst_roles_tables_and_doctests_as_markdown() -> None:
    markdown = _rst_markup().markdown
    assert markdown("see :class:`~btel.exceptions.ModelFileError` and :func:`btel.load`") == \
        "see `ModelFileError` and `btel.load`"
    table = "\n".join(["intro", "", "====== =====", "where  what", "====== =====", "``a``  first",
                       "       more", "``b``  second", "====== =====", "", "after"])
    assert markdown(table).splitlines() == ["intro", "", "", "| where | what |", "| --- | --- |",
                                            "| ``a`` | first more |", "| ``b`` | second |", "", "", "after"]
    assert markdown("Pick one::\n\n    code\n") == "Pick one:\n\n    code"
    assert markdown("text\n>>> import btel\n>>> btel.load\nafter") == \
        "text\n```python\n>>> import btel\n>>> btel.load\n```\nafter"


#: How the README and the site's home name each row of `btel demo` in "What you should see".
DEMO_ROWS = {"brute force": "bruteforce", "`auto`": "auto", "PQ": "pq", "the output codes": "btel-codes",
             "BTEL with regions": "btel-r", "BTE-C": "btel-c"}


def demo_figures(page: Path) -> dict[str, float]:
    """Row → recall@0 from a page's sentence "What you should see: brute force and `auto` at recall@0 1.000, PQ
    0.93, … and BTE-C 0.05"."""
    text = " ".join(page.read_text(encoding="utf-8").split())
    said = re.search(r"should see: (.*?) —", text)
    assert said is not None, f"{page.name} no longer says what the demo should show"
    figures: dict[str, float] = {}
    for names, value in re.findall(r"([^0-9]+?) (\d\.\d+)", said.group(1).replace(" at recall@0", "")):
        for name in names.strip(" ,").removeprefix("and ").split(" and "):
            figures[DEMO_ROWS[name.strip()]] = float(value)
    return figures


@pytest.mark.slow
def test_the_demo_shows_what_the_readme_says_it_shows(tmp_path: Path) -> None:
    """The README's figures for `btel demo` (its default route, methods and budget) are those a run prints,
    to the two decimals given (±0.015: another BLAS may move a query or two)."""
    import json

    from click.testing import CliRunner

    from btel.cli import main

    pages = {page.name: demo_figures(page) for page in (ROOT / "README.md", ROOT / "docs" / "index.md")}
    assert pages["README.md"] == pages["index.md"] and len(pages["README.md"]) == len(DEMO_ROWS)
    result = CliRunner().invoke(main, ["demo", "--no-progress", "--out", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    rows = json.loads((tmp_path / "demo" / "metrics.json").read_text())["results"]
    measured = {row["name"]: row["recall"]["0"] for row in rows}
    for name, said in pages["README.md"].items():
        assert abs(measured[name] - said) <= 0.015, f"the README says {name} {said}; the demo gives {measured[name]:.3f}"
