"""Figures of a run, as in the paper: recall vs tolerance, vs storage, vs number of places.

Figures are drawn on matplotlib's Agg canvas (no display, no pyplot state: safe in scripts,
tests and threads) and saved as PNG; each function returns the :class:`~matplotlib.figure.Figure`.

Rows for :func:`plot_recall_vs_storage` and :func:`plot_recall_vs_n` are dicts::

    {"method": "BTE-C",           # series name
     "bytes": 492240,             # storage in bytes (SPEC §7)
     "n_places": 3576,            # N, map places
     "recall": {0: 0.31, 10: 0.38}}  # tolerance (frames) → recall; keys int or str (from JSON)

:meth:`btel.evaluation.EvaluationResult.to_row` builds one. Rows of one method form one series,
sorted by x.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, MaxNLocator, NullFormatter

from .exceptions import InvalidParameterError
from .storage import format_bytes

__all__ = [
    "plot_recall_vs_tolerance",
    "plot_recall_vs_storage",
    "plot_recall_vs_n",
    "plot_curves",
    "plot_parameter_sweep",
    "plot_experiment",
    "plot_recall_at_k",
    "plot_run",
    "plot_precision_recall",
]

_FIGSIZE = (6.4, 4.4)
_DPI = 120


def _new_figure() -> tuple[Figure, Any]:
    fig = Figure(figsize=_FIGSIZE, dpi=_DPI)
    FigureCanvasAgg(fig)  # attach the Agg canvas: savefig then needs no GUI backend
    return fig, fig.add_subplot(1, 1, 1)


def _save(fig: Figure, path: str | os.PathLike) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, format="png")


def _finish_recall_plot(fig: Figure, ax: Any, path: str | os.PathLike, *, xlabel: str, ylabel: str = "recall",
                        title: str | None = None, credit: str | None = None, legend_size: str = "small") -> None:
    """Labels, the [0, 1] recall axis, grid, legend, title and credit line; then save."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, which="both", alpha=0.3)  # minor lines only show on log axes
    ax.legend(fontsize=legend_size)
    if title:
        import textwrap

        ax.set_title(textwrap.fill(title, 70), fontsize="medium")
    if credit:
        fig.text(0.99, 0.005, credit, ha="right", va="bottom", fontsize="xx-small", color="grey")
    _save(fig, path)


def _field(item: Any, key: str, default: Any = None) -> Any:
    """Read ``key`` from an EvaluationResult-like object or a dict (e.g. from metrics.json)."""
    if isinstance(item, Mapping):
        return item.get(key, default)
    return getattr(item, key, default)


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


def plot_recall_vs_tolerance(
    results: Sequence[Any],
    path: str | os.PathLike,
    *,
    max_tolerance: int | None = None,
    title: str | None = None,
) -> Figure:
    """One line per method: recall (y) against tolerance in frames (x), legend with the bytes.

    Parameters
    ----------
    results : sequence of EvaluationResult or dict
        Each needs ``name`` and ``recall_curve`` (recall at t = 0, 1, …) or, failing that,
        ``recall`` (tolerance → recall, drawn as points); ``nbytes`` labels the legend.
        Dicts as in ``metrics.json["results"]`` work too.
    path : path
        PNG file to write.
    max_tolerance : int, optional
        Right end of the x axis (default: the longest curve).
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not results:
        raise InvalidParameterError("nothing to plot: results is empty.")
    fig, ax = _new_figure()
    right = 0
    for r in results:
        name = str(_field(r, "name", "method"))
        label = _legend_label(r)
        curve = _field(r, "recall_curve")
        if curve is not None and len(curve):
            y = np.asarray(curve, dtype=float)
            x = np.arange(y.shape[0])
            marker, drawstyle = None, "steps-post"  # recall is defined at whole frames only
        else:
            recall = _field(r, "recall") or {}
            if not recall:
                raise InvalidParameterError(f"result {name!r} has neither a recall curve nor recall points.")
            pairs = sorted((int(t), float(v)) for t, v in recall.items())
            x, y = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
            marker, drawstyle = "o", "default"
        if max_tolerance is not None:
            keep = x <= max_tolerance
            x, y = x[keep], y[keep]
        right = max(right, int(x.max()) if x.size else 0)
        ax.plot(x, y, marker=marker, drawstyle=drawstyle, label=label, linestyle=_linestyle(r))
    ax.set_xlabel("tolerance t (frames)")
    ax.set_ylabel("recall@t")
    ax.set_ylim(0.0, 1.02)
    # The axis ends where the curves end (twice the largest reported tolerance), not at a fixed 80.
    ax.set_xlim(0, max(right, 1))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames: no 2.5 or 7.5
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small", loc="lower right")  # recall rises with t: the lower right is free
    if title:
        ax.set_title(title, fontsize="medium")
    _save(fig, path)
    return fig


def _legend_label(r: Any) -> str:
    """``name code=random (bytes)``; the parameters the user set, and what the reference row and
    sequence methods are."""
    name = str(_field(r, "name", "method"))
    settings = _field(r, "settings") or {}
    if settings:
        name += " " + " ".join(f"{k}={v}" for k, v in sorted(settings.items()))
    nbytes = _field(r, "nbytes")
    notes = [format_bytes(nbytes)] if nbytes is not None else []
    if _field(r, "reference", False):
        notes.append("reference, unbudgeted")
    if _field(r, "uses_query_sequence", False):
        notes.append("† query sequence")
    return f"{name} ({', '.join(notes)})" if notes else name


def _linestyle(r: Any) -> str:
    """Dashed for rows that are not single-frame methods under the budget (reference, sequence)."""
    return "--" if _field(r, "reference", False) or _field(r, "uses_query_sequence", False) else "-"


def plot_recall_at_k(results: Sequence[Any], path: str | os.PathLike, *, title: str | None = None) -> Figure:
    """R@K (y) against K (x), one line per method: the plot for ground truth with explicit positives.

    Parameters
    ----------
    results : sequence of EvaluationResult or dict
        Each needs ``name`` and ``recall_at_k`` (K → R@K; keys int or str).
    path : path
        PNG file to write.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    series = [(r, sorted((int(k), float(v)) for k, v in (_field(r, "recall_at_k") or {}).items())) for r in results]
    series = [(r, pts) for r, pts in series if pts]
    if not series:
        raise InvalidParameterError("nothing to plot: no result has R@K.")
    fig, ax = _new_figure()
    ks = sorted({k for _, pts in series for k, _ in pts})
    for r, pts in series:
        ax.plot([k for k, _ in pts], [v for _, v in pts], marker="o", label=_legend_label(r), linestyle=_linestyle(r))
    ax.set_xticks(ks)
    ax.set_xlim(0.5, ks[-1] + 0.5)
    _finish_recall_plot(fig, ax, path, xlabel="K (ranked candidates)", ylabel="R@K", title=title)
    return fig


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


def _series(r: Any) -> str:
    return str(_field(r, "series") or _field(r, "name", "method"))


def _panels(results: Sequence[Any]) -> list[tuple[int | None, list[Any]]]:
    """Results grouped by budget, one panel each; the reference (unbudgeted) rows join every panel."""
    budgets = sorted({int(b) for r in results if (b := _field(r, "budget")) is not None
                      and not _field(r, "reference", False)})
    if len(budgets) <= 1:
        return [(budgets[0] if budgets else None, list(results))]
    shared = [r for r in results if _field(r, "reference", False) or _field(r, "budget") is None]
    return [(b, [r for r in results if _field(r, "budget") == b and r not in shared] + shared) for b in budgets]


def _run_figure(results: Sequence[Any], path: Path, *, kind: str, title: str | None,
                unit: str = "frames") -> Figure:
    """recall@t curves (``kind="tolerance"``) or R@K lines (``kind="k"``), one panel per budget.

    A method keeps its colour in every panel; each panel's legend sits below it (two columns), so
    it never covers a curve however many methods there are; the title is wrapped to the width.
    """
    import textwrap

    panels = _panels(results)
    series = list(dict.fromkeys(_series(r) for r in results))
    colours = {name: f"C{i % 10}" for i, name in enumerate(series)}
    markers = {name: "osD^v<>ph*"[i // 10 % 10] for i, name in enumerate(series)}
    rows_of_legend = -(-max(len(members) for _, members in panels) // 2)
    width = min(6.4 * len(panels), 19.2)
    fig = Figure(figsize=(width, 4.0 + 0.2 * rows_of_legend), dpi=_DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
    for ax, (budget, members) in zip(axes, panels):
        right = 1
        for r in members:
            name = _series(r)
            style = dict(color=colours[name], linestyle=_linestyle(r), label=_legend_label(r))
            if kind == "tolerance":
                curve = _field(r, "recall_curve")
                curve = np.asarray(curve if curve is not None else [], dtype=float)
                if curve.size:
                    # Markers at points offset per method: curves that coincide (PQ and OPQ at the same
                    # bytes) still show one marker of each.
                    index = series.index(name)
                    every = max(len(series), curve.size // 6)
                    start = (index * max(1, every // len(series))) % every
                    ax.plot(np.arange(curve.size), curve, drawstyle="steps-post", marker="osD^v<>ph*"[index % 10],
                            markersize=4, markevery=(start, every), **style)
                    right = max(right, curve.size - 1)
            else:
                pts = sorted((int(k), float(v)) for k, v in (_field(r, "recall_at_k") or {}).items())
                if pts:
                    ax.plot([k for k, _ in pts], [v for _, v in pts], marker=markers[name], **style)
                    right = max(right, pts[-1][0])
        if kind == "tolerance":
            ax.set_xlim(0, right)  # twice the largest reported tolerance, not a fixed 80 frames
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames: no 2.5 or 7.5
            ax.set_xlabel(f"tolerance t ({unit})")
        else:
            ks = sorted({int(k) for r in members for k in (_field(r, "recall_at_k") or {})})
            ax.set_xticks(ks)  # R@K exists only at the K that were measured
            ax.set_xlim(0.5, right + 0.5)
            ax.set_xlabel("K (ranked candidates)")
        ax.set_ylim(0.0, 1.02)
        ax.grid(True, alpha=0.3)
        if len(panels) > 1:
            ax.set_title(f"budget {format_bytes(budget)}" if budget is not None else "no budget", fontsize="small")
        ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    axes[0].set_ylabel("recall@t" if kind == "tolerance" else "R@K")
    if title:
        fig.suptitle(textwrap.fill(title, width=int(12 * width)), fontsize="medium")
    _save(fig, path)
    return fig


def plot_run(results: Sequence[Any], out_dir: str | os.PathLike, *, title: str | None = None,
             not_run: Sequence[Any] = (), tolerance_unit: str = "frames") -> list[Path]:
    """The plots of an evaluation run folder (``btel evaluate``, ``btel demo``).

    - ``recall_vs_tolerance.png`` when the ground truth has one true place per query (the curve
      runs to twice the largest reported tolerance), else ``recall_at_k.png`` (R@K vs K); one
      panel per budget when the run has several, the reference in each;
    - ``recall_vs_storage.png`` when storage is known: recall@t at the middle reported
      tolerance (10 frames when reported), or R@1 with explicit positives, against stored bytes,
      one line per method through its budgets, the budgets as dotted lines;
    - ``precision_recall.png`` when the methods give scores: the PR curve of accepting each query's
      top-1 match by its score, AUC-PR and recall at 100 % precision in the legend.

    ``not_run``: rows without numbers (does not fit, failed, …); each figure names them under its
    title, so a method never vanishes from a figure without a word.

    ``tolerance_unit``: what a tolerance step is, in the axis labels — ``"frames"`` when the
    queries run along a route, ``"map places"`` when they are independent places (``btel evaluate
    --query-order independent``), so no figure speaks of frames on a map of independent places.

    Returns
    -------
    list of Path
        The PNG files written.
    """
    out_dir = Path(out_dir)
    results = list(results)
    missing = "; ".join(f"{_field(r, 'name')} ({_field(r, 'status')})" for r in not_run)
    if missing:
        title = (f"{title} — " if title else "") + f"not shown: {missing}"
    written: list[Path] = []
    if any(len(_field(r, "recall_curve") if _field(r, "recall_curve") is not None else ()) for r in results):
        written.append(out_dir / "recall_vs_tolerance.png")
        _run_figure(results, written[-1], kind="tolerance", title=title, unit=tolerance_unit)
    elif any(_field(r, "recall_at_k") for r in results):
        written.append(out_dir / "recall_at_k.png")
        _run_figure(results, written[-1], kind="k", title=title)
    rows = []
    for r in results:
        if _field(r, "nbytes") is None:
            continue
        recall = {int(t): v for t, v in (_field(r, "recall") or {}).items()}
        metric = "recall@t"
        if not recall:
            recall = {int(k): v for k, v in (_field(r, "recall_at_k") or {}).items() if int(k) == 1}
            metric = "R@1"
        if recall:
            rows.append({"method": _legend_label_short(r), "bytes": _field(r, "nbytes"), "recall": recall,
                         "metric": metric})
    common = set.intersection(*(set(r["recall"]) for r in rows)) if rows else set()
    if common:
        metric = rows[0]["metric"]
        if metric == "R@1":
            key, ylabel = 1, "R@1"
        else:
            ordered = sorted(common)
            key = 10 if 10 in common else ordered[len(ordered) // 2]
            ylabel = f"recall@{key} (within {key} {tolerance_unit})"
        budgets = sorted({int(b) for r in results if (b := _field(r, "budget")) is not None
                          and not _field(r, "reference", False)})
        written.append(out_dir / "recall_vs_storage.png")
        plot_recall_vs_storage(rows, written[-1], tolerance=key, title=title, ylabel=ylabel, budgets=budgets)
    if any(_field(r, "pr_curve") for r in results):
        written.append(out_dir / "precision_recall.png")
        plot_precision_recall(results, written[-1], title=title)
    return written


def plot_precision_recall(results: Sequence[Any], path: str | os.PathLike, *, title: str | None = None) -> Figure:
    """Precision (y) against recall (x) of accepting each query's top-1 match by its score, one curve per method.

    The legend gives each method's AUC-PR and recall at 100 % precision. Curves that coincide (two
    methods with the same answers) stay visible: each method has its own marker, placed at
    different points along the curve.

    Parameters
    ----------
    results : sequence of EvaluationResult or dict
        Each needs ``name`` and ``pr_curve`` (``{"precision": [...], "recall": [...]}``); rows without
        one are left out.
    path : path
        PNG file to write.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    series = [r for r in results if _field(r, "pr_curve")]
    if not series:
        raise InvalidParameterError("nothing to plot: no result has a precision-recall curve.")
    fig = Figure(figsize=(_FIGSIZE[0], _FIGSIZE[1] + 0.25 * len(series)), dpi=_DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    markers = "osD^v<>ph*"
    for i, r in enumerate(series):
        curve = _field(r, "pr_curve")
        recall, precision = np.asarray(curve["recall"], float), np.asarray(curve["precision"], float)
        auc, perfect = _field(r, "auc_pr"), _field(r, "recall_at_100_precision")
        label = _legend_label(r) + (f": AUC {auc:.3f}, R@100%P {perfect:.3f}" if auc is not None else "")
        n_marks = 6
        start = (i * max(1, recall.size // (n_marks * len(series)))) % max(1, recall.size)
        ax.plot(recall, precision, drawstyle="steps-post", color=f"C{i % 10}", linestyle=_linestyle(r),
                marker=markers[i % len(markers)], markevery=(start, max(1, recall.size // n_marks)), markersize=5,
                label=label)
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("recall (correct accepted top-1 matches / all queries)")
    ax.set_ylabel("precision")
    ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.14), frameon=False)  # never on a curve
    if title:
        import textwrap

        ax.set_title(textwrap.fill(title, width=70), fontsize="small")
    _save(fig, path)
    return fig


def _legend_label_short(r: Any) -> str:
    name = _series(r)
    if _field(r, "reference", False):
        name += " (reference, unbudgeted)"
    if _field(r, "uses_query_sequence", False):
        name += " †"
    return name


def _plot_rows(
    rows: Sequence[Mapping[str, Any]],
    path: str | os.PathLike,
    *,
    x_key: str,
    xlabel: str,
    tolerance: int,
    title: str | None,
    bytes_axis: bool = False,
    ylabel: str | None = None,
    budgets: Sequence[int] = (),
) -> Figure:
    if not rows:
        raise InvalidParameterError("nothing to plot: rows is empty.")
    series: dict[str, list[tuple[float, float]]] = {}
    for i, row in enumerate(rows):
        missing = [k for k in ("method", x_key, "recall") if k not in row]
        if missing:
            raise InvalidParameterError(
                f"row {i} lacks {missing}; rows are dicts with keys method, bytes, n_places, recall."
            )
        x = row[x_key]
        if x is None or not np.isfinite(float(x)) or float(x) <= 0:
            raise InvalidParameterError(f"row {i} ({row['method']}) has {x_key}={x!r}; a log axis needs a value > 0.")
        y = _recall_at(row["recall"], tolerance, f"row {i} ({row['method']})")
        series.setdefault(str(row["method"]), []).append((float(x), y))
    fig, ax = _new_figure()
    for method, points in series.items():
        points.sort()
        ax.plot([p[0] for p in points], [p[1] for p in points], marker="o", label=method)
    for i, budget in enumerate(sorted(set(budgets))):
        ax.axvline(budget, color="grey", linestyle=":", linewidth=1, label="budget" if i == 0 else None)
    xs = [p[0] for points in series.values() for p in points] + list(budgets)
    if bytes_axis:
        _bytes_axis(ax, xs)
    else:
        ax.set_xscale("log")
    if max(xs) / min(xs) < 4:  # a narrow range: widen it so the points do not sit on the frame
        ax.set_xlim(min(xs) / 2, max(xs) * 2)
    if len(series) > 5:
        # Many methods: the legend goes beside the axes, where it cannot cover a point.
        fig.set_size_inches(_FIGSIZE[0] + 2.4, _FIGSIZE[1])
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel or f"recall@{tolerance} (within {tolerance} frames)")
        ax.set_ylim(0.0, 1.02)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        if title:
            import textwrap

            ax.set_title(textwrap.fill(title, 70), fontsize="medium")
        _save(fig, path)
        return fig
    _finish_recall_plot(fig, ax, path, xlabel=xlabel, ylabel=ylabel or f"recall@{tolerance} (within {tolerance} frames)",
                        title=title)
    return fig


def plot_recall_vs_storage(
    rows: Sequence[Mapping[str, Any]], path: str | os.PathLike, tolerance: int = 10, *, title: str | None = None,
    ylabel: str | None = None, budgets: Sequence[int] = (),
) -> Figure:
    """Recall at ``tolerance`` (y) against storage in bytes (x, log scale), one series per method.

    Parameters
    ----------
    rows : sequence of dict
        Keys ``method``, ``bytes``, ``recall`` (and ``n_places``); see the module docstring.
    path : path
        PNG file to write.
    tolerance : int, default 10
        Which recall point to plot; every row must have it.
    ylabel : str, optional
        Default ``recall@<tolerance> (within <tolerance> frames)``.
    budgets : sequence of int, optional
        Budgets in bytes, drawn as dotted vertical lines.

    Returns
    -------
    matplotlib.figure.Figure
    """
    return _plot_rows(rows, path, x_key="bytes", xlabel="storage (bytes, log scale)", tolerance=tolerance,
                      title=title, bytes_axis=True, ylabel=ylabel, budgets=budgets)


def plot_recall_vs_n(
    rows: Sequence[Mapping[str, Any]], path: str | os.PathLike, tolerance: int = 10, *, title: str | None = None
) -> Figure:
    """Recall at ``tolerance`` (y) against the number of map places N (x, log scale), one series per method.

    Parameters
    ----------
    rows : sequence of dict
        Keys ``method``, ``n_places``, ``recall`` (and ``bytes``); see the module docstring.
    path : path
        PNG file to write.
    tolerance : int, default 10

    Returns
    -------
    matplotlib.figure.Figure
    """
    return _plot_rows(rows, path, x_key="n_places", xlabel="N (map places)", tolerance=tolerance, title=title)


def _curve_label(method: str, sequence_methods: set[str]) -> str:
    if method == "bruteforce":
        return f"{method} (reference, unbudgeted)"
    return f"{method} † query sequence" if method in sequence_methods else method


def plot_curves(
    curves: Mapping[str, Sequence[float]], path: str | os.PathLike, *, title: str | None = None,
    credit: str | None = None, ylabel: str = "recall@t",
) -> Figure:
    """recall@t (y) against tolerance t = 0, 1, … (x), one line per named curve."""
    if not curves:
        raise InvalidParameterError("nothing to plot: no curves.")
    fig, ax = _new_figure()
    for label, values in curves.items():
        ax.step(np.arange(len(values)), values, where="post", label=label)
    _finish_recall_plot(fig, ax, path, xlabel="tolerance t (frames)", ylabel=ylabel, title=title, credit=credit,
                        legend_size="x-small")
    return fig


def plot_parameter_sweep(
    rows: Sequence[Mapping[str, Any]], path: str | os.PathLike, *, x_key: str, xlabel: str,
    tolerances: Sequence[int] = (0, 5, 10, 20), title: str | None = None, credit: str | None = None,
) -> Figure:
    """Recall@t (y) against a parameter (x, linear axis), one line per tolerance t.

    Rows are flat dicts with ``x_key`` and ``recall@<t>`` keys (the experiments' result rows).
    """
    ok = [r for r in rows if r.get("status", "ok") == "ok"]
    if not ok:
        raise InvalidParameterError("nothing to plot: no successful rows.")
    ok.sort(key=lambda r: float(r[x_key]))
    fig, ax = _new_figure()
    xs = [float(r[x_key]) for r in ok]
    for t in tolerances:
        ax.plot(xs, [float(r[f"recall@{t}"]) for r in ok], marker="o", label=f"recall@{t}")
    _finish_recall_plot(fig, ax, path, xlabel=xlabel, title=title, credit=credit)
    return fig


NORDLAND_CREDIT = "Nordland footage: NRK, CC BY 3.0"


def _as_plot_rows(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Experiment rows (flat ``recall@t`` keys) → the row format of :func:`plot_recall_vs_n`."""
    out = []
    for r in rows:
        if r.get("status", "ok") != "ok":
            continue
        recall = {int(k.split("@")[1]): v for k, v in r.items() if k.startswith("recall@")}
        out.append({"method": r["method"], "bytes": r.get("nbytes"), "n_places": r["n_places"], "recall": recall})
    return out


def plot_experiment(run: Any, out_dir: str | os.PathLike) -> list[Path]:
    """The plot(s) of one :class:`btel.experiments.ExperimentRun`, written as PNG into ``out_dir``."""
    out_dir = Path(out_dir)
    written: list[Path] = []
    name = run.name
    if name == "accuracy":
        # The budget and N in the title are the ones the rows were run with (2 MB and 2000 in the full
        # run, 50 KB and 300 in --quick), never a fixed text.
        budgets = sorted({int(r["budget"]) for r in run.rows if r.get("budget")})
        budget_text = ", ".join(format_bytes(b) for b in budgets) or "no budget"
        n_text = ", ".join(str(n) for n in sorted({int(r["n_places"]) for r in run.rows}))
        sequence = {r["method"] for r in run.rows if r.get("uses_query_sequence")}
        for direction in sorted({k.split(" ", 1)[1] for k in run.curves}):
            curves = {_curve_label(k.split(" ", 1)[0], sequence): v for k, v in run.curves.items()
                      if k.endswith(direction)}
            path = out_dir / f"recall_vs_tolerance_{direction.replace('→', '_to_')}.png"
            plot_curves(curves, path, title=f"Nordland {direction}, N = {n_text}, ≤ {budget_text} "
                                            "(brute force: reference, unbudgeted)",
                        credit=NORDLAND_CREDIT, ylabel="recall@t")
            written.append(path)
    elif name == "sequence-filter":
        path = out_dir / "sequence_filter.png"
        plot_curves(run.curves, path, title="Sequence filter (a = 0, 5, 20)", credit=NORDLAND_CREDIT)
        written.append(path)
    elif name == "vs-n":
        path = out_dir / "recall_vs_n.png"
        plot_recall_vs_n(_as_plot_rows(run.rows), path, tolerance=10, title="recall@10 vs N")
        written.append(path)
    elif name == "vs-budget":
        path = out_dir / "recall_vs_storage.png"
        plot_recall_vs_storage(_as_plot_rows(run.rows), path, tolerance=10, title="recall@10 vs stored bytes")
        written.append(path)
    elif name == "feature-ratio":
        path = out_dir / "recall_vs_feature_ratio.png"
        plot_parameter_sweep(run.rows, path, x_key="feature_ratio", xlabel="feature ratio c = d'/d",
                             title="BTE-C, r = 1", credit=NORDLAND_CREDIT)
        written.append(path)
    elif name == "beyond":
        written += _plot_beyond(run.rows, out_dir)
    elif name == "front-ends":
        written += _plot_front_ends(run.rows, out_dir)
    elif name == "regions":
        path = out_dir / "recall_vs_regions.png"
        plot_parameter_sweep(run.rows, path, x_key="n_regions", xlabel="regions r",
                             title="BTEL, c = 0.1", credit=NORDLAND_CREDIT)
        written.append(path)
    return written


def plot_method_bars(
    rows: Sequence[Mapping[str, Any]], path: str | os.PathLike, *, group_key: str, value_key: str = "recall@10",
    title: str | None = None, credit: str | None = None,
) -> Figure:
    """Grouped horizontal bars: one bar group per method, one bar per ``group_key`` value.

    Rows are flat dicts with ``method``, ``group_key`` and ``value_key``; rows without the value
    (a budget the method could not meet) are left out.
    """
    ok = [r for r in rows if r.get("status", "ok") == "ok" and r.get(value_key) is not None]
    if not ok:
        raise InvalidParameterError("nothing to plot: no successful rows.")
    methods = list(dict.fromkeys(str(r["method"]) for r in ok))
    groups = list(dict.fromkeys(str(r[group_key]) for r in ok))
    fig = Figure(figsize=(7.2, 0.5 + 0.42 * len(methods) * max(1, len(groups)) ** 0.5), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    height = 0.8 / len(groups)
    for g, group in enumerate(groups):
        values = {str(r["method"]): float(r[value_key]) for r in ok if str(r[group_key]) == group}
        ys = [i + g * height for i, m in enumerate(methods) if m in values]
        ax.barh(ys, [values[m] for m in methods if m in values], height=height, label=group)
    ax.set_yticks([i + 0.4 - height / 2 for i in range(len(methods))], methods, fontsize="small")
    ax.invert_yaxis()
    ax.set_xlabel(value_key)
    ax.set_xlim(0.0, 1.0)
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(fontsize="x-small", loc="lower right")
    if title:
        import textwrap

        ax.set_title(textwrap.fill(title, 70), fontsize="medium")
    if credit:
        fig.text(0.99, 0.005, credit, ha="right", va="bottom", fontsize="xx-small", color="grey")
    fig.tight_layout()
    _save(fig, path)
    return fig


def _plot_beyond(rows: Sequence[Mapping[str, Any]], out_dir: Path) -> list[Path]:
    """The "beyond" experiment: Nordland read-outs per method, Gardens Point vs bytes, synthetic crossover."""
    written = []
    for direction in sorted({r["direction"] for r in rows if r.get("part") == "nordland"}):
        part = [r for r in rows if r.get("part") == "nordland" and r["direction"] == direction]
        path = out_dir / f"nordland_{direction.replace('→', '_to_')}.png"
        plot_method_bars(part, path, group_key="decoder",
                         title=f"Nordland {direction}, HOG, same budget: recall@10 (reported stretches)",
                         credit=NORDLAND_CREDIT)
        written.append(path)
    gp = [r for r in rows if r.get("part") == "gardens-point" and r.get("status") == "ok" and r.get("budget")]
    if gp:
        path = out_dir / "gardens_point_recall_vs_bytes.png"
        plot_recall_vs_storage(_as_plot_rows(gp), path, tolerance=5,
                               title="Gardens Point day→night, NetVLAD 500-D: recall@5 vs stored bytes")
        written.append(path)
    synth = [r for r in rows if r.get("part") == "synthetic" and r.get("status") == "ok"]
    if synth:
        fig, ax = _new_figure()
        for method in dict.fromkeys(r["method"] for r in synth):
            pts = sorted((float(r["condition_shift"]), float(r["recall@10"])) for r in synth if r["method"] == method)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=method)
        budget = synth[0].get("budget")
        path = out_dir / "synthetic_crossover.png"
        _finish_recall_plot(fig, ax, path, xlabel="appearance change between map and query traverse (condition_shift)",
                            ylabel="recall@10",
                            title=f"Synthetic route, N = {synth[0]['n_places']}, ≤ {format_bytes(budget) if budget else '?'}")
        written.append(path)
    return written


def _plot_front_ends(rows: Sequence[Mapping[str, Any]], out_dir: Path) -> list[Path]:
    """The "front-ends" experiment: one bar group per method (and budget), one bar per front end."""
    written = []
    for part, direction in dict.fromkeys((r.get("part"), r.get("direction")) for r in rows if r.get("direction")):
        single = [{**r, "method": f"{r['method']} ({format_bytes(r['budget']) if r.get('budget') else 'no budget'})"}
                  for r in rows if r.get("part") == part and r.get("direction") == direction
                  and r.get("decoder") == "single"]
        if not any(r.get("status") == "ok" for r in single):
            continue
        t = 10 if part == "nordland" else 2
        path = out_dir / f"{part}_{direction.replace('→', '_to_')}.png"
        what = "Nordland HOG" if part == "nordland" else "Gardens Point NetVLAD"
        plot_method_bars(single, path, group_key="front", value_key=f"recall@{t}",
                         title=f"{what} {direction}: single-frame recall@{t} by front end",
                         credit=NORDLAND_CREDIT if part == "nordland" else None)
        written.append(path)
    return written
