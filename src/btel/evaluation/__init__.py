"""Measuring methods: :func:`measure` (fit, localize, time, score — the one way btel measures),
:func:`run_methods` (several methods into a run folder), the result record, metrics as plain
functions of arrays, tables, run folders, galleries and plots."""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names
from .measure import evaluate, measure, timed_fit  # eager: the function, never its module of one name

_WHERE = {
    ".batch": ("preflight", "evaluate_all", "run_methods"),
    ".inputs": ("Job", "make_jobs", "RUNTIME_PARAMS"),
    ".metrics": ("DEFAULT_TOLERANCES", "DEFAULT_KS", "TABLE_KS", "PR_CURVE_POINTS", "recall_at_tolerance",
                 "recall_curve", "recall_at_k", "default_tolerances", "default_ks", "default_curve_max",
                 "check_ground_truth", "precision_recall"),
    ".records": ("EvaluationResult", "STATUS_OK", "STATUS_REFUSED", "STATUS_DOES_NOT_FIT", "STATUS_FAILED",
                 "STATUS_NOT_RUN", "does_not_fit_status"),
    ".tables": ("format_table",),
    ".timing": ("QueryTiming", "time_queries"),
}

__all__ = ["measure", "evaluate", "timed_fit", *(name for names in _WHERE.values() for name in names)]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .batch import evaluate_all, preflight, run_methods
    from .inputs import RUNTIME_PARAMS, Job, make_jobs
    from .metrics import (DEFAULT_KS, DEFAULT_TOLERANCES, PR_CURVE_POINTS, TABLE_KS, check_ground_truth,
                          default_curve_max, default_ks, default_tolerances, precision_recall, recall_at_k,
                          recall_at_tolerance, recall_curve)
    from .records import (STATUS_DOES_NOT_FIT, STATUS_FAILED, STATUS_NOT_RUN, STATUS_OK, STATUS_REFUSED,
                          EvaluationResult, does_not_fit_status)
    from .tables import format_table
    from .timing import QueryTiming, time_queries

__getattr__, __dir__ = lazy_names(__name__, {n: where for where, names in _WHERE.items() for n in names})
