"""The frontier at a glance: two maps, five methods and the unbudgeted reference (the README's figure).

The full frontier figure (:func:`btel.experiments.frontier._plots`) draws every row on every map: the
record, not a first look. This one draws, from the same rows, the two maps a reader knows — Gardens
Point mapped by day and queried at night, Nordland mapped in summer and queried in winter — with
``auto``, the paper's BTE-C, the output codes, LSH, PQ and brute force over the whole map, each in a
colour of its own, and recall on a labelled axis.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["OVERVIEW_FILE", "OVERVIEW_MAPS", "plot_overview"]

#: File name of the overview in the frontier's run folder (``btel report`` copies it to docs/figures/).
OVERVIEW_FILE = "frontier_overview.png"
#: The maps shown: frontier dataset name → panel title.
OVERVIEW_MAPS = {
    "gardens-point": "Gardens Point (NetVLAD 500-D, 200 places):\nmapped by day, queried at night",
    "nordland summer→winter": "Nordland (HOG 3780-D, 3,576 places):\nmapped in summer, queried in winter",
}
#: The rows shown, in legend order: frontier method label → (legend text, colour, marker, line width).
_SERIES = {
    "auto": ("auto (the default)", "black", "o", 3.0),
    "btel-codes": ("btel-codes (output codes)", "#1a9641", "s", 1.5),
    "lsh": ("lsh", "#2c7bb6", "^", 1.5),
    "pq": ("pq", "#fdae61", "D", 1.5),
    "btel-c": ("BTE-C (the paper)", "#d7191c", "v", 1.5),
    "brute force (cosine)": ("brute force: the whole map", "grey", "*", 0.0),
}


def _kilobytes(value: float, _position: Any = None) -> str:
    """Tick text: ``1 KB``, ``10 KB``, ``1 MB`` (no trailing ``.0``)."""
    for unit, size in (("MB", 1e6), ("KB", 1e3)):
        if value >= size:
            return f"{value / size:g} {unit}"
    return f"{value:g} B"


def _picks(rows: list[dict[str, Any]]) -> str:
    """``auto's pick: btel-codes 1 KB–16 KB, lsh (centred rows) 64 KB–1 MB`` from auto's rows of one map."""
    picks: list[tuple[str, list[float]]] = []
    for r in sorted(rows, key=lambda r: r["budget"]):
        params = r.get("chose_params") or {}
        what = str(r.get("chose_method"))
        what += " (centred rows)" if params.get("center") else " (whitened rows)" if params.get("whiten") else ""
        if picks and picks[-1][0] == what:
            picks[-1][1].append(r["budget"])
        else:
            picks.append((what, [r["budget"]]))
    spans = [f"{what} {_kilobytes(b[0])}" + (f"–{_kilobytes(b[-1])}" if len(b) > 1 else "") for what, b in picks]
    return "auto's pick: " + ", ".join(spans) if spans else ""


def plot_overview(rows: list[dict[str, Any]], path: str | Path) -> Path | None:
    """Draw the overview from the frontier's flat rows (``results.json``'s ``rows``) into ``path``.

    Returns ``path``, or None when the rows hold none of :data:`OVERVIEW_MAPS` (``--quick`` runs).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter, NullFormatter

    maps = [m for m in OVERVIEW_MAPS if any(r.get("dataset") == m for r in rows)]
    if not maps:
        return None
    fig = Figure(figsize=(12, 4.6), dpi=100)
    FigureCanvasAgg(fig)
    for i, dataset in enumerate(maps):
        ax = fig.add_subplot(1, len(maps), i + 1)
        sub = [r for r in rows if r.get("dataset") == dataset and r.get("status") == "ok"]
        for method, (label, colour, marker, width) in _SERIES.items():
            points = sorted((r["nbytes"], r["value"]) for r in sub if r.get("method") == method)
            if not points:
                continue
            style = {"linestyle": "none", "markersize": 14} if width == 0 else {"linewidth": width, "markersize": 6}
            ax.plot([p[0] for p in points], [p[1] for p in points], color=colour, marker=marker, label=label,
                    zorder=3 if method == "auto" else 2, **style)
            if width == 0:
                ax.annotate("brute force", points[0], textcoords="offset points", xytext=(0, 10), ha="center",
                            fontsize="small", color="dimgrey")
        picks = _picks([r for r in sub if r.get("method") == "auto" and r.get("budget")])
        if picks:
            ax.text(0.98, 0.97, picks, transform=ax.transAxes, ha="right", va="top", fontsize="small",
                    wrap=True, bbox={"boxstyle": "round", "facecolor": "white", "edgecolor": "lightgrey"})
        key = sub[0]["key"] if sub else "recall"
        within = key.split("@")[-1]
        ax.set_ylabel(f"{key}: share of queries within {within} places of the truth")
        ax.set_xlabel("bytes stored (the budget: 1 KB … 1 MB)")
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(_kilobytes))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_ylim(0, max(0.5, min(1.0, 1.15 * max((r["value"] for r in sub), default=0.5))))
        ax.set_title(OVERVIEW_MAPS[dataset], fontsize="medium")
        ax.grid(True, which="major", alpha=0.3)
    handles, labels = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False, fontsize="small",
               markerscale=0.8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    path = Path(path)
    fig.savefig(path)
    return path
