"""What each parameter of an estimator may be and means, from one declared source each.

The allowed values come from the class's declared ``_parameter_constraints`` (what ``fit``
checks). The meaning is the first sentence of the parameter's entry in the class docstring
(numpydoc ``Parameters`` section), else the meaning the class declares in
``_parameter_meanings``: the base class declares the shared parameters there (the budget and the
front end's three), so a new method's docstring need only describe its own parameters.
"""

from __future__ import annotations

import inspect
import re
from typing import Any

__all__ = ["parameter_meanings", "describe_constraints", "parameter_table"]

_HEADING = re.compile(r"^(\w[\w ]*)\n-{3,}\s*$", re.MULTILINE)
_ENTRY = re.compile(r"^([A-Za-z_][\w]*(?:\s*,\s*[A-Za-z_][\w]*)*)\s*(?::.*)?$")
_SENTENCE_END = re.compile(r"(?<=\.)(?<!e\.g\.)(?<!i\.e\.)\s")


def _parameters_section(doc: str) -> str:
    headings = list(_HEADING.finditer(doc))
    for i, h in enumerate(headings):
        if h.group(1).strip() == "Parameters":
            return doc[h.end():headings[i + 1].start() if i + 1 < len(headings) else len(doc)]
    return ""


def parameter_meanings(cls: type) -> dict[str, str]:
    """Parameter name → one sentence: from ``cls``'s numpydoc ``Parameters``, else ``_parameter_meanings``.

    An entry naming several parameters (``normalize, whiten, delta``) describes them together, so
    a meaning declared for one of them is more precise and wins.
    """
    meanings: dict[str, str] = {}
    shared: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []

    def flush() -> None:
        sentence = _plain(_SENTENCE_END.split(" ".join(text).strip(), maxsplit=1)[0])
        for name in names if sentence else ():
            (meanings if len(names) == 1 else shared)[name] = sentence
    for line in _parameters_section(inspect.getdoc(cls) or "").splitlines():
        if line and not line[0].isspace() and (match := _ENTRY.match(line.strip())):
            flush()
            names, text = [n.strip() for n in match.group(1).split(",")], []
        elif line.strip():
            text.append(line.strip())
    flush()
    return {**shared, **getattr(cls, "_parameter_meanings", {}), **meanings}


def _plain(text: str, limit: int = 160) -> str:
    """reST markup off (``x`` → x, :mod:`y` → y), and at most ``limit`` characters: a longer sentence
    ends at its last clause break (``,`` ``;`` ``:`` ``—``) within the limit, else its last whole word,
    marked ``…`` (the class docstring has the rest)."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "")
    if len(text) <= limit:
        return text
    head = text[: limit - 2]
    breaks = [m.start() for m in re.finditer(r"[,;:](?=\s)|\s—\s", head)]
    cut = breaks[-1] if breaks and breaks[-1] > limit // 2 else head.rfind(" ")
    return head[: cut if cut > 0 else len(head)].rstrip(" ,;:—") + " …"


def describe_constraints(constraints: list[Any]) -> str:
    """``None or an integer ≥ 1``: the declared constraints of one parameter in words."""
    return " or ".join("None" if c is None else c.describe() for c in constraints)


def parameter_table(estimator: Any) -> list[tuple[str, Any, str, str, bool]]:
    """``(name, default, allowed values, meaning, runtime?)`` of every parameter of ``estimator``."""
    cls = type(estimator)
    constraints = getattr(cls, "_parameter_constraints", {})
    meanings = parameter_meanings(cls)
    runtime = set(getattr(cls, "_runtime_params", ()))
    return [(name, value, describe_constraints(constraints[name]) if name in constraints else "any",
             meanings.get(name, ""), name in runtime)
            for name, value in sorted(estimator.get_params(deep=False).items())]
