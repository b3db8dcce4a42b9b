"""Figures of an evaluation run folder (``btel evaluate``, ``btel demo``): recall@t curves, R@K,
recall against storage, precision–recall; each drawn from what the records hold."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ...exceptions import InvalidParameterError
from ..records import EvaluationResult
from ...core.storage import format_bytes
from ._figure import _DPI, _FIGSIZE, _finish_recall_plot, _new_figure, _save, recall_axis_top
from .styles import auto_label, method_styles
from .sweeps import plot_recall_vs_storage

__all__ = ["plot_recall_vs_tolerance", "plot_recall_at_k", "plot_run", "plot_precision_recall"]


def plot_recall_vs_tolerance(
    results: Sequence[EvaluationResult],
    path: str | os.PathLike,
    *,
    max_tolerance: int | None = None,
    title: str | None = None,
) -> Figure:
    """One line per method: recall (y) against tolerance in frames (x), legend with the bytes.

    Parameters
    ----------
    results : sequence of EvaluationResult
        Each with a ``recall_curve`` (recall at t = 0, 1, …) or, failing that, ``recall``
        (tolerance → recall, drawn as points); ``nbytes`` labels the legend. Records read back
        from ``metrics.json``: :meth:`EvaluationResult.from_dict`.
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
    right, highest = 0, 0.0
    styles = method_styles([_series(r) for r in results])
    for r in results:
        name = str(r.name)
        label = _legend_label(r)
        curve = r.recall_curve
        if curve is not None and len(curve):
            y = np.asarray(curve, dtype=float)
            x = np.arange(y.shape[0])
            every, drawstyle = max(1, y.size // 6), "steps-post"  # recall is defined at whole frames only
        else:
            recall = r.recall or {}
            if not recall:
                raise InvalidParameterError(f"result {name!r} has neither a recall curve nor recall points.")
            pairs = sorted((int(t), float(v)) for t, v in recall.items())
            x, y = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
            every, drawstyle = 1, "default"
        if max_tolerance is not None:
            keep = x <= max_tolerance
            x, y = x[keep], y[keep]
        right = max(right, int(x.max()) if x.size else 0)
        highest = max(highest, float(np.nanmax(y)) if y.size else 0.0)
        ax.plot(x, y, drawstyle=drawstyle, label=label, markevery=every, **styles[_series(r)].kwargs())
    ax.set_xlabel("tolerance t (frames)")
    ax.set_ylabel("recall@t")
    ax.set_ylim(0.0, recall_axis_top(highest))
    # The axis ends where the curves end (twice the largest reported tolerance), not at a fixed 80.
    ax.set_xlim(0, max(right, 1))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames: no 2.5 or 7.5
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small", loc="lower right")  # recall rises with t: the lower right is free
    if title:
        ax.set_title(title, fontsize="medium")
    _save(fig, path)
    return fig


def _legend_label(r: EvaluationResult) -> str:
    """``name code=random (bytes)``; the parameters the user set, and what the reference row and
    sequence methods are."""
    name = auto_label(r.chosen_method) if r.chosen_method else str(r.name)
    settings = r.settings or {}
    if settings:
        name += " " + " ".join(f"{k}={v}" for k, v in sorted(settings.items()))
    nbytes = r.nbytes
    notes = [format_bytes(nbytes)] if nbytes is not None else []
    if r.reference:
        notes.append("reference, unbudgeted")
    if r.uses_query_sequence:
        notes.append("† query sequence")
    return f"{name} ({', '.join(notes)})" if notes else name


def plot_recall_at_k(results: Sequence[EvaluationResult], path: str | os.PathLike, *, title: str | None = None) -> Figure:
    """R@K (y) against K (x), one line per method: the plot for ground truth with explicit positives.

    Parameters
    ----------
    results : sequence of EvaluationResult
        Each needs ``recall_at_k`` (K → R@K; keys int or str).
    path : path
        PNG file to write.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    series = [(r, sorted((int(k), float(v)) for k, v in (r.recall_at_k or {}).items())) for r in results]
    series = [(r, pts) for r, pts in series if pts]
    if not series:
        raise InvalidParameterError("nothing to plot: no result has R@K.")
    fig, ax = _new_figure()
    ks = sorted({k for _, pts in series for k, _ in pts})
    styles = method_styles([_series(r) for r, _ in series])
    for r, pts in series:
        ax.plot([k for k, _ in pts], [v for _, v in pts], label=_legend_label(r),
                **styles[_series(r)].kwargs())
    ax.set_xticks(ks)
    ax.set_xlim(0.5, ks[-1] + 0.5)
    _finish_recall_plot(fig, ax, path, xlabel="K (ranked candidates)", ylabel="R@K", title=title,
                        top=recall_axis_top(max(v for _, pts in series for _, v in pts)))
    return fig



def _series(r: EvaluationResult) -> str:
    """The series a record belongs to (one style per series); ``auto → lsh`` for auto's rows."""
    name = str(r.series or r.name)
    return f"{name} → {r.chosen_method}" if r.chosen_method else name


def _panels(results: Sequence[EvaluationResult]) -> list[tuple[int | None, list[EvaluationResult]]]:
    """Results grouped by budget, one panel each; the reference (unbudgeted) rows join every panel."""
    budgets = sorted({int(b) for r in results if (b := r.budget) is not None
                      and not r.reference})
    if len(budgets) <= 1:
        return [(budgets[0] if budgets else None, list(results))]
    shared = [r for r in results if r.reference or r.budget is None]
    return [(b, [r for r in results if r.budget == b and r not in shared] + shared) for b in budgets]


def _run_figure(results: Sequence[EvaluationResult], path: Path, *, kind: str, title: str | None,
                unit: str = "frames") -> Figure:
    """recall@t curves (``kind="tolerance"``) or R@K lines (``kind="k"``), one panel per budget.

    A method keeps its colour in every panel; each panel's legend sits below it (two columns), so
    it never covers a curve however many methods there are; the title is wrapped to the width.
    """
    import textwrap

    panels = _panels(results)
    series = list(dict.fromkeys(_series(r) for r in results))
    styles = method_styles(series)
    rows_of_legend = -(-max(len(members) for _, members in panels) // 2)
    width = min(6.4 * len(panels), 19.2)
    fig = Figure(figsize=(width, 4.0 + 0.2 * rows_of_legend), dpi=_DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
    # One recall axis for every panel (shared), as tall as the highest value of any of them needs.
    values = [v for r in results for v in (r.recall_curve if kind == "tolerance" and r.recall_curve is not None
                                           else (r.recall_at_k or {}).values() if kind != "tolerance" else [])]
    top = recall_axis_top(max((float(v) for v in values), default=1.0))
    for ax, (budget, members) in zip(axes, panels):
        right = 1
        for r in members:
            name = _series(r)
            style = dict(styles[name].kwargs(), label=_legend_label(r))
            if kind == "tolerance":
                curve = r.recall_curve
                curve = np.asarray(curve if curve is not None else [], dtype=float)
                if curve.size:
                    # Markers at points offset per method: curves that coincide (PQ and OPQ at the same
                    # bytes) still show one marker of each.
                    index = series.index(name)
                    every = max(len(series), curve.size // 6)
                    start = min((index * max(1, every // len(series))) % every, curve.size - 1)
                    ax.plot(np.arange(curve.size), curve, drawstyle="steps-post", markevery=(start, every),
                            **{"markersize": 4, **style})
                    right = max(right, curve.size - 1)
            else:
                pts = sorted((int(k), float(v)) for k, v in (r.recall_at_k or {}).items())
                if pts:
                    ax.plot([k for k, _ in pts], [v for _, v in pts], **style)
                    right = max(right, pts[-1][0])
        if kind == "tolerance":
            ax.set_xlim(0, right)  # twice the largest reported tolerance, not a fixed 80 frames
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # frames: no 2.5 or 7.5
            ax.set_xlabel(f"tolerance t ({unit})")
        else:
            ks = sorted({int(k) for r in members for k in (r.recall_at_k or {})})
            ax.set_xticks(ks)  # R@K exists only at the K that were measured
            ax.set_xlim(0.5, right + 0.5)
            ax.set_xlabel("K (ranked candidates)")
        ax.set_ylim(0.0, top)
        ax.grid(True, alpha=0.3)
        if len(panels) > 1:
            ax.set_title(f"budget {format_bytes(budget)}" if budget is not None else "no budget", fontsize="small")
        ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    axes[0].set_ylabel("recall@t" if kind == "tolerance" else "R@K")
    if title:
        fig.suptitle(textwrap.fill(title, width=int(12 * width), break_on_hyphens=False), fontsize="medium")
    _save(fig, path)
    return fig


def plot_run(results: Sequence[EvaluationResult], out_dir: str | os.PathLike, *, title: str | None = None,
             not_run: Sequence[EvaluationResult] = (), tolerance_unit: str = "frames") -> list[Path]:
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
    missing = "; ".join(f"{r.name} ({r.status})" for r in not_run)
    if missing:
        title = (f"{title} — " if title else "") + f"not shown: {missing}"
    written: list[Path] = []
    if any(len(r.recall_curve if r.recall_curve is not None else ()) for r in results):
        written.append(out_dir / "recall_vs_tolerance.png")
        _run_figure(results, written[-1], kind="tolerance", title=title, unit=tolerance_unit)
    elif any(r.recall_at_k for r in results):
        written.append(out_dir / "recall_at_k.png")
        _run_figure(results, written[-1], kind="k", title=title)
    points, metrics = [], []  # one record per (method, bytes): the headline recall by tolerance (or R@1)
    for r in results:
        if r.nbytes is None:
            continue
        recall = {int(t): v for t, v in (r.recall or {}).items()}
        metric = "recall@t"
        if not recall:
            recall = {int(k): v for k, v in (r.recall_at_k or {}).items() if int(k) == 1}
            metric = "R@1"
        if recall:
            points.append(EvaluationResult(name=_legend_label_short(r), nbytes=r.nbytes, recall=recall))
            metrics.append(metric)
    common = set.intersection(*(set(r.recall) for r in points)) if points else set()
    if common:
        if metrics[0] == "R@1":
            key, ylabel = 1, "R@1"
        else:
            ordered = sorted(common)
            key = 10 if 10 in common else ordered[len(ordered) // 2]
            ylabel = f"recall@{key} (within {key} {tolerance_unit})"
        budgets = sorted({int(b) for r in results if (b := r.budget) is not None
                          and not r.reference})
        written.append(out_dir / "recall_vs_storage.png")
        plot_recall_vs_storage(points, written[-1], tolerance=key, title=title, ylabel=ylabel, budgets=budgets)
    if any(r.pr_curve for r in results):
        written.append(out_dir / "precision_recall.png")
        plot_precision_recall(results, written[-1], title=title)
    return written


def plot_precision_recall(results: Sequence[EvaluationResult], path: str | os.PathLike, *,
                          title: str | None = None) -> Figure:
    """Precision (y) against recall (x) of accepting each query's top-1 match by its score, per method.

    One point per distinct score threshold, joined by straight lines as VPR-Bench and VPR_Tutorial
    draw them, so a curve never shows precision 1 beyond its recall at 100 % precision; a method
    whose scores are all equal is one point. Recall is VPR_Tutorial's (over the queries with a true
    place). The legend gives both AUC-PRs (:func:`~btel.evaluation.metrics.precision_recall`) and
    R@100%P. Curves that coincide stay visible: each method has its own style
    (:func:`~btel.evaluation.plots.styles.method_styles`), markers at different points.

    Parameters
    ----------
    results : sequence of EvaluationResult
        Each needs ``pr_curve`` (``{"precision": [...], "recall": [...]}``); rows without
        one are left out.
    path : path
        PNG file to write.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    series = [r for r in results if r.pr_curve]
    if not series:
        raise InvalidParameterError("nothing to plot: no result has a precision-recall curve.")
    fig = Figure(figsize=(_FIGSIZE[0], _FIGSIZE[1] + 0.25 * len(series)), dpi=_DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    styles = method_styles([_series(r) for r in series])
    for i, r in enumerate(series):
        curve = r.pr_curve
        recall, precision = np.asarray(curve["recall"], float), np.asarray(curve["precision"], float)
        label = _legend_label(r) + _pr_note(r)
        n_marks = 6
        every = max(1, recall.size // n_marks)
        start = min((i * max(1, every // len(series))) % every, recall.size - 1)
        ax.plot(recall, precision, markevery=(start, every) if recall.size > 2 * n_marks else None,
                label=label, **{"markersize": 5, **styles[_series(r)].kwargs()})
    # Recall ends at the share of queries whose top-1 is right: the axis ends just past the longest curve.
    ax.set_xlim(0.0, min(1.0, recall_axis_top(max(float(np.max(r.pr_curve["recall"])) for r in series))))
    ax.set_ylim(0.0, 1.02)
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("recall (correct accepted top-1 matches / queries with a true place)")
    ax.set_ylabel("precision")
    # The legend below the axes: never on a curve. Its lines (with both AUC-PRs) are wider than the
    # default figure: the figure is widened to them, so the axes span the legend's width, not a third.
    legend = ax.legend(fontsize="x-small", loc="upper center", bbox_to_anchor=(0.5, -0.14), frameon=False)
    fig.canvas.draw()
    needed = legend.get_window_extent().width / fig.dpi + 0.8
    if needed > fig.get_figwidth():
        fig.set_figwidth(min(needed, 16.0))
    if title:
        import textwrap

        ax.set_title(textwrap.fill(title, width=int(14 * fig.get_figwidth()), break_on_hyphens=False), fontsize="small")
    _save(fig, path)
    return fig


def _pr_note(r: EvaluationResult) -> str:
    """``: AUC-PR 0.524 (VPR-Bench), 0.205 (VPR_Tutorial), R@100%P 0.000`` — what the record holds."""
    parts = [f"{v:.3f} ({source})" for v, source in ((r.auc_pr_vpr_bench, "VPR-Bench"),
                                                   (r.auc_pr_vpr_tutorial, "VPR_Tutorial")) if v is not None]
    notes = ([f"AUC-PR {', '.join(parts)}"] if parts else []) + (
        [f"R@100%P {r.recall_at_100_precision:.3f}"] if r.recall_at_100_precision is not None else [])
    return f": {', '.join(notes)}" if notes else ""


def _legend_label_short(r: EvaluationResult) -> str:
    name = _series(r)
    if r.reference:
        name += " (reference, unbudgeted)"
    if r.uses_query_sequence:
        name += " †"
    return name

