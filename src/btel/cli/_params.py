"""``btel methods --params``: each parameter's allowed values and meaning, from one source each.

The allowed values come from the method's declared ``_parameter_constraints`` (what ``fit``
checks); the meaning is the first sentence of the parameter's entry in the class docstring
(numpydoc ``Parameters`` section). Nothing is written twice, so the listing cannot drift from the
code.
"""

from __future__ import annotations

import inspect
import json
import re
from typing import Any

def _param_value(text: str) -> Any:
    """VALUE of ``--param NAME=VALUE``: the JSON literal it spells (``3``, ``0.5``, ``true``, ``null``,
    ``"x"``, ``[1, 2]``), else the text itself (``auto``, ``float16``). NaN and Infinity stay text."""
    def reject(constant: str) -> Any:
        raise ValueError(constant)

    try:
        return json.loads(text, parse_constant=reject)
    except ValueError:
        return text


def _param_text(value: Any) -> str:
    """How to write ``value`` after --param NAME= (text as is unless it would read as JSON)."""
    if isinstance(value, str) and _param_value(value) == value:
        return value
    try:
        return json.dumps(value)
    except TypeError:
        return repr(value)


_HEADING = re.compile(r"^(\w[\w ]*)\n-{3,}\s*$", re.MULTILINE)
_ENTRY = re.compile(r"^([A-Za-z_][\w]*(?:\s*,\s*[A-Za-z_][\w]*)*)\s*(?::.*)?$")


def parameter_meanings(cls: type) -> dict[str, str]:
    """Parameter name → the first sentence of its description in ``cls``'s numpydoc ``Parameters``."""
    doc = inspect.getdoc(cls) or ""
    headings = list(_HEADING.finditer(doc))
    section = ""
    for i, h in enumerate(headings):
        if h.group(1).strip() == "Parameters":
            end = headings[i + 1].start() if i + 1 < len(headings) else len(doc)
            section = doc[h.end():end]
            break
    meanings: dict[str, str] = {}
    names: list[str] = []
    text: list[str] = []

    def flush() -> None:
        if names:
            sentence = _plain(re.split(r"(?<=\.)(?<!e\.g\.)(?<!i\.e\.)\s", " ".join(text).strip(), maxsplit=1)[0])
            for n in names:
                meanings[n] = sentence
    for line in section.splitlines():
        if line and not line[0].isspace():
            match = _ENTRY.match(line.strip())
            if match:
                flush()
                names, text = [n.strip() for n in match.group(1).split(",")], []
                continue
        if line.strip():
            text.append(line.strip())
    flush()
    return meanings


def _plain(text: str, limit: int = 140) -> str:
    """reST markup off (``x`` → x, :mod:`y` → y), and at most ``limit`` characters."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "")
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


def describe_constraints(constraints: list[Any]) -> str:
    """``None or an int in [1, 64]``: the declared constraints in words."""
    return " or ".join("None" if c is None else c.describe() for c in constraints)


def parameter_lines(model: Any, *, runtime: set[str] | frozenset[str] = frozenset()) -> list[str]:
    """One line per parameter of ``model``: ``name=default — allowed values — meaning``."""
    cls = type(model)
    constraints = getattr(cls, "_parameter_constraints", {})
    meanings = parameter_meanings(cls)
    out = []
    for name, default in sorted(model.get_params(deep=False).items()):
        allowed = describe_constraints(constraints[name]) if name in constraints else "any"
        meaning = meanings.get(name, "")
        tag = " [runtime]" if name in runtime else ""
        out.append(f"{name}={_param_text(default)}{tag}: {allowed}" + (f" — {meaning}" if meaning else ""))
    return out
