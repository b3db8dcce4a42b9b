"""Figures of a run, as in the paper: recall vs tolerance, vs storage, vs number of places.

Figures are drawn on matplotlib's Agg canvas (no display, no pyplot state: safe in scripts,
tests and threads) and saved as PNG; each function returns the :class:`~matplotlib.figure.Figure`.
Every figure reads :class:`~btel.evaluation.records.EvaluationResult` records and draws what they hold: a
recall curve, R@K, precision–recall, bytes. Records of one method form one series, sorted by x,
drawn in that method's one style in every figure (:mod:`.styles`).

============== ==========================================================================
module         what
============== ==========================================================================
``run``        the figures of a run folder (:func:`plot_run`): recall@t, R@K, vs storage, PR
``sweeps``     recall against storage, N or a parameter; named curves; grouped bars
``styles``     one colour × marker × line style per method; ``auto → <choice>`` hollow
``_figure``    the Agg canvas, saving, the recall and bytes axes
============== ==========================================================================

Each experiment draws its own figure(s) with these (``plot`` in its module,
:mod:`btel.experiments`).
"""

from __future__ import annotations

from ._figure import NORDLAND_CREDIT, finish_recall_plot, new_figure
from .run import plot_precision_recall, plot_recall_at_k, plot_recall_vs_tolerance, plot_run
from .styles import METHOD_STYLES, Style, auto_label, method_styles
from .sweeps import (curve_label, plot_curves, plot_method_bars, plot_parameter_sweep, plot_recall_vs_n,
                     plot_recall_vs_storage)

__all__ = ["plot_recall_vs_tolerance", "plot_recall_vs_storage", "plot_recall_vs_n", "plot_curves",
           "plot_parameter_sweep", "plot_method_bars", "plot_recall_at_k", "plot_run", "plot_precision_recall",
           "curve_label", "new_figure", "finish_recall_plot", "NORDLAND_CREDIT", "method_styles", "METHOD_STYLES",
           "Style", "auto_label"]
