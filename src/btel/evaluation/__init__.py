"""Measuring methods: fit, localize, time and score them (:mod:`~btel.evaluation.measure`), the result record,
metrics as plain functions of arrays, tables, run folders, galleries and plots."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

__all__ = ["DEFAULT_TOLERANCES", "DEFAULT_KS", "TABLE_KS", "PR_CURVE_POINTS", "recall_at_tolerance", "recall_curve",
           "recall_at_k", "EvaluationResult", "evaluate", "Job", "preflight", "evaluate_all", "default_tolerances",
           "default_ks", "default_curve_max", "check_ground_truth", "format_table", "STATUS_OK", "STATUS_REFUSED",
           "STATUS_DOES_NOT_FIT", "STATUS_FAILED", "STATUS_NOT_RUN", "QueryTiming", "time_queries",
           "precision_recall"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .measure import (DEFAULT_KS, DEFAULT_TOLERANCES, PR_CURVE_POINTS, STATUS_DOES_NOT_FIT, STATUS_FAILED,
                          STATUS_NOT_RUN, STATUS_OK, STATUS_REFUSED, TABLE_KS, EvaluationResult, Job, QueryTiming,
                          check_ground_truth, default_curve_max, default_ks, default_tolerances, evaluate,
                          evaluate_all, format_table, precision_recall, preflight, recall_at_k,
                          recall_at_tolerance, recall_curve, time_queries)

__getattr__, __dir__ = lazy_names(__name__, dict.fromkeys(__all__, ".measure"))
