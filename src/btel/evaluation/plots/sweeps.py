"""Figures of result rows against a quantity: storage, N, a parameter, a tolerance curve, bar groups."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ...exceptions import InvalidParameterError
from ...methods.roles import REFERENCE_METHOD
from ..records import EvaluationResult
from ._figure import _FIGSIZE, _bytes_axis, _finish_recall_plot, _new_figure, _recall_at, _save, recall_axis_top
from .styles import method_styles

__all__ = ["plot_recall_vs_storage", "plot_recall_vs_n", "plot_curves", "plot_parameter_sweep", "plot_method_bars",
           "curve_label"]


#: The x axis of :func:`plot_recall_vs_storage` and :func:`plot_recall_vs_n`: record field → cell name.
_X_CELLS = {"nbytes": "nbytes", "n_map": "n_places"}


def _plot_rows(
    rows: Sequence[EvaluationResult],
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
        x = getattr(row, x_key)
        if x is None or not np.isfinite(float(x)) or float(x) <= 0:
            raise InvalidParameterError(f"row {i} ({row.name}) has {_X_CELLS[x_key]}={x!r}; a log axis needs a value > 0.")
        y = _recall_at(row.recall, tolerance, f"row {i} ({row.name})")
        series.setdefault(str(row.name), []).append((float(x), y))
    fig, ax = _new_figure()
    styles = method_styles(list(series))
    for method, points in series.items():
        points.sort()
        ax.plot([p[0] for p in points], [p[1] for p in points], label=method, **styles[method].kwargs())
    for i, budget in enumerate(sorted(set(budgets))):
        ax.axvline(budget, color="grey", linestyle=":", linewidth=1, label="budget" if i == 0 else None)
    xs = [p[0] for points in series.values() for p in points] + list(budgets)
    top = recall_axis_top(max(p[1] for points in series.values() for p in points))
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
        ax.set_ylim(0.0, top)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
        if title:
            import textwrap

            ax.set_title(textwrap.fill(title, 70, break_on_hyphens=False), fontsize="medium")
        _save(fig, path)
        return fig
    _finish_recall_plot(fig, ax, path, xlabel=xlabel, ylabel=ylabel or f"recall@{tolerance} (within {tolerance} frames)",
                        title=title, top=top)
    return fig


def plot_recall_vs_storage(
    rows: Sequence[EvaluationResult], path: str | os.PathLike, tolerance: int = 10, *, title: str | None = None,
    ylabel: str | None = None, budgets: Sequence[int] = (),
) -> Figure:
    """Recall at ``tolerance`` (y) against storage in bytes (x, log scale), one series per method.

    Parameters
    ----------
    rows : sequence of EvaluationResult
        Each with ``nbytes`` and ``recall``; the records of one ``name`` form one series.
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
    return _plot_rows(rows, path, x_key="nbytes", xlabel="storage (bytes, log scale)", tolerance=tolerance,
                      title=title, bytes_axis=True, ylabel=ylabel, budgets=budgets)


def plot_recall_vs_n(
    rows: Sequence[EvaluationResult], path: str | os.PathLike, tolerance: int = 10, *, title: str | None = None
) -> Figure:
    """Recall at ``tolerance`` (y) against the number of map places N (x, log scale), one series per method.

    Parameters
    ----------
    rows : sequence of EvaluationResult
        Each with ``n_map`` and ``recall``; the records of one ``name`` form one series.
    path : path
        PNG file to write.
    tolerance : int, default 10

    Returns
    -------
    matplotlib.figure.Figure
    """
    return _plot_rows(rows, path, x_key="n_map", xlabel="N (map places)", tolerance=tolerance, title=title)


def curve_label(method: str, sequence_methods: set[str]) -> str:
    """A curve's legend entry: the method, marked as the reference or as using the query sequence."""
    if method == REFERENCE_METHOD:
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
    styles = method_styles(list(curves))
    for label, values in curves.items():
        ax.plot(np.arange(len(values)), values, drawstyle="steps-post", label=label,
                markevery=max(1, len(values) // 6), **{"markersize": 4, **styles[label].kwargs()})
    _finish_recall_plot(fig, ax, path, xlabel="tolerance t (frames)", ylabel=ylabel, title=title, credit=credit,
                        legend_size="x-small")
    return fig


def plot_parameter_sweep(
    rows: Sequence[EvaluationResult], path: str | os.PathLike, *, x_key: str, xlabel: str,
    tolerances: Sequence[int] = (0, 5, 10, 20), title: str | None = None, credit: str | None = None,
) -> Figure:
    """Recall@t (y) against a parameter (x, linear axis), one line per tolerance t.

    ``x_key`` and ``recall@<t>`` are cells of each record's flat row (:meth:`EvaluationResult.to_row`).
    """
    ok = [r.to_row() for r in rows if r.ok]
    if not ok:
        raise InvalidParameterError("nothing to plot: no successful rows.")
    ok.sort(key=lambda r: float(r[x_key]))
    fig, ax = _new_figure()
    xs = [float(r[x_key]) for r in ok]
    for t in tolerances:
        ax.plot(xs, [float(r[f"recall@{t}"]) for r in ok], marker="o", label=f"recall@{t}")
    _finish_recall_plot(fig, ax, path, xlabel=xlabel, title=title, credit=credit)
    return fig



def plot_method_bars(
    rows: Sequence[EvaluationResult], path: str | os.PathLike, *, group_key: str, value_key: str = "recall@10",
    title: str | None = None, credit: str | None = None,
) -> Figure:
    """Grouped horizontal bars: one bar group per method, one bar per ``group_key`` value.

    ``group_key`` and ``value_key`` are cells of each record's flat row (:meth:`EvaluationResult.to_row`);
    records without the value (a budget the method could not meet) are left out.
    """
    ok = [row for r in rows if r.ok and (row := r.to_row()).get(value_key) is not None]
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

        ax.set_title(textwrap.fill(title, 70, break_on_hyphens=False), fontsize="medium")
    if credit:
        fig.text(0.99, 0.005, credit, ha="right", va="bottom", fontsize="xx-small", color="grey")
    fig.tight_layout()
    _save(fig, path)
    return fig

