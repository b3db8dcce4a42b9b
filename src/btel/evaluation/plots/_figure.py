"""What every figure shares: the Agg canvas, saving, the recall axis, the bytes axis."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from ...exceptions import InvalidParameterError
from ...core.storage import format_bytes

#: The credit line of figures drawn from Nordland frames.
NORDLAND_CREDIT = "Nordland footage: NRK, CC BY 3.0"

_FIGSIZE = (6.4, 4.4)
_DPI = 120


def _new_figure() -> tuple[Figure, Any]:
    fig = Figure(figsize=_FIGSIZE, dpi=_DPI)
    FigureCanvasAgg(fig)  # attach the Agg canvas: savefig then needs no GUI backend
    return fig, fig.add_subplot(1, 1, 1)


def _save(fig: Figure, path: str | os.PathLike) -> None:
    """Save as PNG through a temporary beside ``path`` (:func:`btel.core.claims.atomic_output`): a full disk
    leaves the old file or none, never half a figure."""
    from ...core.claims import atomic_output

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    with atomic_output(path, suffix=".tmp") as fh:
        fig.savefig(fh, format="png", bbox_inches="tight")  # a legend outside the axes is kept whole


def recall_axis_top(highest: float) -> float:
    """Top of a recall axis whose highest value is ``highest``: the whole [0, 1] once a value reaches 0.6,
    else the tenth above it with room for a marker (0.1 at least), so that a run whose rows all lie near 0
    (a small budget on a hard map) is not drawn flat along the bottom of the axis."""
    if not np.isfinite(highest) or highest >= 0.6:
        return 1.02
    return float(max(0.1, np.ceil(highest * 10.8 + 1e-9) / 10))


def _finish_recall_plot(fig: Figure, ax: Any, path: str | os.PathLike, *, xlabel: str, ylabel: str = "recall",
                        title: str | None = None, credit: str | None = None, legend_size: str = "small",
                        top: float = 1.02) -> None:
    """Labels, the recall axis from 0 to ``top`` (:func:`recall_axis_top`), grid, legend, title and credit
    line; then save."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0.0, top)
    ax.grid(True, which="both", alpha=0.3)  # minor lines only show on log axes
    ax.legend(fontsize=legend_size)
    if title:
        import textwrap

        ax.set_title(textwrap.fill(title, 70, break_on_hyphens=False), fontsize="medium")
    if credit:
        fig.text(0.99, 0.005, credit, ha="right", va="bottom", fontsize="xx-small", color="grey")
    _save(fig, path)



def _recall_at(recall: Mapping[Any, float] | None, tolerance: int, who: str) -> float:
    if recall:
        for key in (tolerance, str(tolerance)):
            if key in recall:
                return float(recall[key])
    available = sorted(int(k) for k in (recall or {}))
    raise InvalidParameterError(
        f"{who} has no recall at tolerance {tolerance} (available: {available}); "
        "evaluate with that tolerance or plot another one."
    )



def _tick_bytes(value: float) -> str:
    """``format_bytes`` without a trailing ``.0`` (``50 KB``, ``2.5 MB``): tick labels stay short."""
    return format_bytes(value).replace(".0 ", " ")


def _bytes_axis(ax: Any, xs: Sequence[float]) -> None:
    """A log axis of bytes labelled in one unit style (``50 KB``), no 3×10⁴ minor labels.

    Ticks at 1-2-5 steps over a narrow range, at powers of ten over a wide one, so that labels
    never run into each other.
    """
    ax.set_xscale("log")
    decades = np.log10(max(xs) / min(xs)) if xs and min(xs) > 0 else 0.0
    subs = (1.0, 2.0, 5.0) if decades <= 1.5 else (1.0, 3.0) if decades <= 2.5 else (1.0,)
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _pos: _tick_bytes(value)))
    ax.xaxis.set_minor_formatter(NullFormatter())


#: Public names of the helpers an experiment's own figure uses.
new_figure = _new_figure
finish_recall_plot = _finish_recall_plot
