"""One style per method — colour × marker × line style — the same in every figure.

Every registered method has a fixed style (:data:`METHOD_STYLES`): a reader who learned that LSH
is the red downward triangle finds it so in every plot of every run. A variant of a method (``pq
shrink``, ``btel-c code=random``) keeps its method's colour with another marker and line; any other
name takes the first free combination. :func:`method_styles` gives a figure's curves their styles
and never repeats one within a figure, however many curves there are.

``auto`` answers with the method it chose, so its curve lies exactly on that method's. It is drawn
in the chosen method's colour with hollow, larger markers and a dotted line on top, labelled
``auto → lsh``, so both curves stay visible.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import product
from typing import Any

__all__ = ["Style", "METHOD_STYLES", "AUTO", "method_styles", "auto_label"]

#: The registry name of the method that chooses another one.
AUTO = "auto"


@dataclass(frozen=True)
class Style:
    """How one curve is drawn: matplotlib colour, marker and line style; hollow markers for ``auto``."""

    color: str
    marker: str
    linestyle: str
    hollow: bool = False

    def kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``Axes.plot`` for this style."""
        out: dict[str, Any] = {"color": self.color, "marker": self.marker, "linestyle": self.linestyle}
        if self.hollow:
            out.update(markerfacecolor="none", markeredgewidth=1.6, markersize=9, linewidth=2.2, zorder=3)
        return out


#: The fixed style of every registered method. The paper's single tree (BTE-C, BTE-F) and its regions
#: (btel-r, btel-auto) have colours of their own: a demo draws BTE-C and btel-r side by side, and in one
#: colour they were told apart by marker alone. PQ and OPQ share one.
METHOD_STYLES: dict[str, Style] = {
    "bruteforce": Style("black", "o", "-"),
    "btel-c": Style("C0", "o", "-"),
    "btel-f": Style("C0", "s", "--"),
    "btel-r": Style("C8", "^", "-"),
    "btel-auto": Style("C8", "D", ":"),
    "btel-codes": Style("C9", "P", "-"),
    "ryth": Style("C5", ">", "-"),
    "pq": Style("C1", "s", "-"),
    "opq": Style("C1", "D", "--"),
    "itq": Style("C2", "^", "-"),
    "lsh": Style("C3", "v", "-"),
    "rabitq": Style("C4", "<", "-"),
    "seqslam": Style("C6", "p", "-."),
    AUTO: Style("C7", "X", ":"),
}

_COLOURS = ("C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9", "C7", "black")
_MARKERS = ("o", "s", "^", "v", "D", "<", ">", "p", "h", "*", "P", "X", "d")
_LINES = ("-", "--", "-.", ":")


def _method_of(name: str) -> str:
    """A legend entry without its notes: ``"bruteforce (reference, unbudgeted)"`` → ``"bruteforce"``."""
    return re.split(r" [(†:]", name, maxsplit=1)[0]


def _base(name: str) -> str:
    """The registered method a series name starts with (``"pq shrink"`` → ``"pq"``), else ``""``."""
    head = name.split(" ", 1)[0].split("@", 1)[0]
    return head if head in METHOD_STYLES else ""


def _choice(name: str) -> str:
    """The method named in an ``auto → lsh`` label (``""`` for any other name)."""
    found = re.match(rf"{AUTO}\b[^→]* → (\S+)", name)
    return found.group(1) if found else ""


def auto_label(choice: str | None) -> str:
    """``auto → lsh`` (or ``auto`` when the choice is not known)."""
    return f"{AUTO} → {choice}" if choice else AUTO


def method_styles(names: Sequence[str]) -> dict[str, Style]:
    """The style of each series name of one figure: fixed per method, no two alike.

    Parameters
    ----------
    names : sequence of str
        The series of the figure (a registered method, a variant ``"<method> <setting>"``, or any
        other name), in legend order; repeats are ignored. Notes after the method — `` (…)``,
        `` †…``, ``: …`` — do not change its style. ``auto → lsh`` (:func:`auto_label`) is drawn
        in the chosen method's colour and marker, hollow and dotted.

    Returns
    -------
    dict of str to Style
        One entry per distinct name. No two share colour and marker (up to 143 curves; beyond,
        the line style tells them apart, up to 572), except ``auto`` and its choice, told apart
        by hollow markers and a dotted line.
    """
    order = list(dict.fromkeys(str(n) for n in names))
    styles: dict[str, Style] = {}
    for name in order:  # registered methods first: their fixed style is never taken by another name
        chosen = METHOD_STYLES.get(_choice(name))
        if chosen is not None and Style(chosen.color, chosen.marker, ":", True) not in styles.values():
            styles[name] = Style(chosen.color, chosen.marker, ":", hollow=True)
        elif _method_of(name) in METHOD_STYLES and METHOD_STYLES[_method_of(name)] not in styles.values():
            styles[name] = METHOD_STYLES[_method_of(name)]
    taken = {(s.color, s.marker) for s in styles.values() if not s.hollow}
    for name in order:
        if name in styles:
            continue
        base = _base(name)
        used = [s.color for s in styles.values()]
        # A variant keeps its method's colour; any other name takes a colour no curve has yet, if any.
        fresh = tuple(c for c in _COLOURS if c not in used)
        pool = ((METHOD_STYLES[base].color,) if base else ()) + fresh + _COLOURS
        # A marker no curve has yet, if any: curves differ in colour and shape (colour-blind readers).
        markers = sorted(_MARKERS, key=lambda m: any(s.marker == m for s in styles.values()))
        free = next(((c, m) for c, m in product(pool, markers) if (c, m) not in taken), None)
        if free is None:  # every colour × marker in use: the line style tells the rest apart
            drawn = {(s.color, s.marker, s.linestyle) for s in styles.values()}
            combo = next((t for t in product(_COLOURS, _MARKERS, _LINES) if t not in drawn), ("C0", "o", "-"))
            styles[name] = Style(*combo)
            continue
        colour, marker = free
        styles[name] = Style(colour, marker, _LINES[used.count(colour) % len(_LINES)])
        taken.add((colour, marker))
    return {name: styles[name] for name in order}
