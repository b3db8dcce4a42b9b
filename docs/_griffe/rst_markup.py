"""A griffe extension: the reStructuredText in btel's docstrings, read as Markdown by the site.

btel's docstrings are numpydoc with a little reST — Sphinx roles (``:class:`X```), simple tables
(``=== ===`` borders), literal blocks introduced by ``::`` and bare ``>>>`` lines. mkdocstrings
renders docstrings as Markdown, so before rendering each docstring this extension rewrites roles to
inline code (the last dotted part when the target starts with ``~``), simple tables to Markdown
tables, ``::`` to ``:`` (the indented block after it is already code in Markdown) and runs of
``>>>`` lines to fenced Python blocks. The source keeps its reST; only the site's copy changes.
"""

from __future__ import annotations

import re
from typing import Any

try:  # the site's build has griffe (the docs extra); the tests read the text functions without it
    import griffe
except ImportError:  # pragma: no cover - depends on the environment
    griffe = None

ROLE = re.compile(r":(?:py:)?(?:mod|func|class|meth|data|attr|exc|obj|const|term|ref):`(~?)([^`]+)`")
BORDER = re.compile(r"^(\s*)(=+)( +=+)+\s*$")


def _role(match: re.Match[str]) -> str:
    target = match.group(2).strip()
    return f"`{target.rsplit('.', 1)[-1] if match.group(1) else target}`"


def _columns(border: str) -> list[tuple[int, int | None]]:
    spans = [(m.start(), m.end()) for m in re.finditer(r"=+", border)]
    return [(start, spans[i + 1][0] if i + 1 < len(spans) else None) for i, (start, _) in enumerate(spans)]


def _cells(line: str, columns: list[tuple[int, int | None]]) -> list[str]:
    return [line[start:end].strip() for start, end in columns]


def _table(lines: list[str], columns: list[tuple[int, int | None]]) -> list[str]:
    """A reST simple table (its lines between the first and last border) as a Markdown table."""
    header: list[str] | None = None
    rows: list[list[str]] = []
    for line in lines:
        if BORDER.match(line):
            if header is None and rows:
                header, rows = rows[0], rows[1:]
            continue
        cells = _cells(line, columns)
        if rows and not cells[0]:  # a continuation line: its text belongs to the row above
            rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells)]
        elif any(cells):
            rows.append(cells)
    if header is None:
        header = [""] * len(columns)
    out = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(columns)]
    out += ["| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |" for row in rows]
    return ["", *out, ""]


def _tables(text: str) -> str:
    lines, out, i = text.splitlines(), [], 0
    while i < len(lines):
        if BORDER.match(lines[i]):
            columns, borders, j = _columns(lines[i]), [i], i + 1
            while j < len(lines) and lines[j].strip() and len(borders) < 3:
                if BORDER.match(lines[j]):
                    borders.append(j)
                j += 1
            if len(borders) == 3:
                out += _table(lines[i:j], columns)
                i = j
                continue
        out.append(lines[i])
        i += 1
    return "\n".join(out)


def _doctests(text: str) -> str:
    out: list[str] = []
    block: list[str] = []
    for line in [*text.splitlines(), ""]:
        if line.lstrip().startswith((">>>", "...")) and (block or line.lstrip().startswith(">>>")):
            block.append(line.strip())
            continue
        if block:
            out += ["```python", *block, "```"]
            block = []
        out.append(line)
    return "\n".join(out[:-1])


def markdown(text: str) -> str:
    """The Markdown the site renders for a reST-flavoured docstring ``text``."""
    text = ROLE.sub(_role, text)
    text = _tables(text)
    text = re.sub(r"(\S)::\n", r"\1:\n", text)
    text = re.sub(r"^(\s*)::\n", r"\n", text, flags=re.MULTILINE)
    return _doctests(text)


if griffe is not None:

    class RstMarkup(griffe.Extension):
        """Rewrite every docstring griffe loads (modules, classes, functions, attributes)."""

        def on_instance(self, *, obj: Any, **kwargs: Any) -> None:
            if obj.docstring is not None:
                obj.docstring.value = markdown(obj.docstring.value)
