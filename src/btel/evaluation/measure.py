"""The one way btel measures a method: fit it (or take it fitted), localize, time, score.

:func:`measure` fits a method on the map (timed by :func:`timed_fit`), localizes the queries (timed
by :func:`btel.evaluation.timing.time_queries`) and returns one
:class:`~btel.evaluation.records.EvaluationResult`: recall@t, R@K, precision–recall
(:mod:`btel.evaluation.metrics`), timing, storage, and what the method really was
(:meth:`~btel.methods.auto.AutoLocalizer.choice`). ``btel evaluate``, ``btel demo``
(:func:`btel.evaluation.batch.run_methods`) and every experiment measure through it; a test fails
when another module times a ``fit`` or a ``predict`` itself. :func:`evaluate` is its older name.

This module reads and writes no files: run folders are :mod:`btel.evaluation.runs`, the text table
:mod:`btel.evaluation.tables`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from ..core.validation import check_descriptors, check_positive_int
from ..datasets.groundtruth import GroundTruth, check_predictions
from ..exceptions import InvalidAnswerError, InvalidParameterError
from .metrics import (DEFAULT_KS, TruthLike, check_ground_truth, check_points, default_curve_max,
                      default_tolerances, precision_recall, recall_at_k, recall_at_tolerance, recall_curve,
                      thin_curve)
from ..core.modelfile import jsonable
from ..core.params import chosen_at_fit
from ..core.storage import budget_of, parse_budget
from .records import EvaluationResult, _choice_of, _params_of, _storage_of
from .timing import time_queries

__all__ = ["measure", "evaluate", "timed_fit"]

logger = logging.getLogger(__name__)



def timed_fit(method: Any, X: Any, y: Any = None, **fit_params: Any) -> float:
    """Fit ``method`` on ``X`` (and ``y``, and ``fit_params`` such as auto's ``calibration``, when
    given) and return the wall-clock seconds it took.

    The one place btel times a fit: :func:`measure` and the experiments' model cache both call it.
    Whatever ``fit`` raises (e.g. :class:`~btel.exceptions.BudgetTooSmallError`) propagates.
    """
    start = time.perf_counter()
    if y is None:
        method.fit(X, **fit_params)
    else:
        method.fit(X, y, **fit_params)
    return time.perf_counter() - start


def measure(
    method: Any,
    X_map: Any,
    Q: Any,
    *,
    ground_truth: TruthLike = None,
    tolerances: Iterable[int] | None = None,
    ks: Iterable[int] = DEFAULT_KS,
    k_tolerance: int = 0,
    name: str | None = None,
    curve_max: int | None = None,
    fit: bool = True,
    budget: int | None = None,
    reference: bool = False,
    timing_repeats: int = 5,
    timing_threads: int | None = 1,
    score_answers: bool = True,
    fit_time_s: float | None = None,
    labels: dict[str, Any] | None = None,
    fit_params: dict[str, Any] | None = None,
) -> EvaluationResult:
    """Fit ``method`` on the map, localize the queries, and measure what a run reports: recall@t, R@K,
    precision–recall, stored bytes, fit and query times.

    Parameters
    ----------
    method : estimator or str
        A :class:`~btel.methods.base.PlaceLocalizer` or any object with ``fit(X)`` and ``predict(Q)``
        returning place indices (it is fitted itself, not a copy), or a method name (``"pq"``: made
        by :func:`~btel.methods.make_method` with ``budget``). Ranking (``rank(Q, k)``) is used when
        the method has ``rank``; storage is read from ``nbytes`` / ``storage_breakdown()`` when present.
    X_map : array-like of shape (n_map, n_features)
        Map descriptors, row i = place i. May be None when ``fit=False`` and the method knows its
        number of places (``n_places_``).
    Q : array-like of shape (n_queries, n_features)
        Query descriptors, one query per row.
    ground_truth : GroundTruth, array-like of int of shape (n_queries,), list of lists, or None
        None means frame-aligned: the true place of query j is j. One list of map places per query
        gives explicit positives (R@K; no tolerance).
    tolerances : iterable of int, optional
        Tolerances (frames) for recall@t; default :func:`default_tolerances` (none with explicit
        positives, which have no tolerance; giving some then is an error).
    ks : iterable of int
        K values for R@K. K larger than the map is left out.
    k_tolerance : int, default 0
        Tolerance applied to R@K.
    name : str, optional
        Name in reports; default the method's name (as given, or its ``label``: ``pq``, ``BTEL``).
    curve_max : int, optional
        The recall@t curve covers t = 0..curve_max; default :func:`default_curve_max`.
    fit : bool, default True
        False evaluates an already fitted method (``fit_time_s`` is then None).
    budget : int or str, optional
        The budget the method was given (``"8KB"`` or bytes; recorded in the result as bytes), and the
        budget of a method given by name.
    reference : bool, default False
        Mark the result as the unbudgeted reference row.
    timing_threads : int or None, default 1
        BLAS/OpenMP threads while localizing and timing (see :func:`time_queries`); reported as
        ``n_threads``.
    timing_repeats : int, default 5
        Timed batch calls behind the query-time median (:func:`time_queries`: warm-up, repeats,
        and single-query latency timed apart); 0 times the predicting call alone.
    score_answers : bool, default True
        Score every answer (``search(Q, k=1)`` when the method has no ranking asked for) and report
        the precision–recall figures; False skips that pass (the AUC-PR fields are then None).
    fit_time_s : float, optional
        With ``fit=False``: the seconds the method took to fit when it was fitted (e.g. by
        :func:`timed_fit` before it was cached), recorded as ``fit_time_s``.
    labels : dict, optional
        An experiment's own cells of the row (:attr:`EvaluationResult.labels`).
    fit_params : dict, optional
        Keyword arguments of ``fit`` beside the map, e.g. auto's ``calibration=(Q, truth)``
        (the fit time then includes the calibration).

    Returns
    -------
    EvaluationResult
    """
    budget = None if budget is None else parse_budget(budget)
    if isinstance(method, str):
        from ..methods.registry import make_method

        name, method = name or method, make_method(method, budget=budget)
    ks = tuple(ks)
    if ks:
        ks = check_points(ks, "ks", 1)
    if X_map is not None:
        X_map = check_descriptors(X_map, name="X_map")
        n_map = X_map.shape[0]
        n_features = X_map.shape[1]
    elif fit:
        raise InvalidParameterError("X_map is None but fit=True; give map descriptors or pass fit=False.")
    else:
        n_map = getattr(method, "n_places_", None)
        n_features = None
    Q = check_descriptors(Q, name="Q", n_features=n_features)
    n_queries = Q.shape[0]
    gt = check_ground_truth(ground_truth, n_queries, n_map)
    tolerances = _tolerances_for(tolerances, gt, n_map)
    curve_max = (default_curve_max(tolerances, n_map) if curve_max is None
                 else check_positive_int(curve_max, "curve_max", minimum=0))

    fit_time = timed_fit(method, X_map, **(fit_params or {})) if fit else fit_time_s

    raw, timing = time_queries(method, Q, repeats=timing_repeats, threads=timing_threads)
    query_time = timing.batch_s_per_query
    predictions = check_predictions(raw, n_queries, name=f"{type(method).__name__}.predict(Q)")
    if n_map is not None and predictions.size and (predictions.min() < 0 or predictions.max() >= n_map):
        raise InvalidAnswerError(  # never score an answer outside the map
            f"{type(method).__name__}.predict(Q) answered place {int(predictions[(predictions < 0) | (predictions >= n_map)][0])}, "
            f"outside the map's 0..{int(n_map) - 1}.")

    ranked = None
    rank_time = None
    r_at_k = None
    best_scores = None
    has_search = callable(getattr(method, "search", None))
    if ks and callable(getattr(method, "rank", None)):
        k = ks[-1] if n_map is None else min(ks[-1], n_map)
        start = time.perf_counter()
        if has_search:  # the ranking and each candidate's score in one call
            scores, ranked = method.search(Q, k=k)
            best_scores, ranked = np.asarray(scores)[:, 0], np.asarray(ranked)
        else:
            ranked = np.asarray(method.rank(Q, k=k))
        rank_time = (time.perf_counter() - start) / n_queries
        if ranked.ndim != 2 or ranked.shape[0] != n_queries:
            raise InvalidParameterError(
                f"{type(method).__name__}.rank(Q, k={k}) returned shape {ranked.shape}; "
                f"expected ({n_queries}, ≤ {k}), best candidate first."
            )
        usable = tuple(kk for kk in ks if kk <= ranked.shape[1])
        if len(usable) < len(ks):
            logger.info("R@K left out for K > %d (the map has %s places)", ranked.shape[1], n_map)
        r_at_k = recall_at_k(ranked, gt, usable, tolerance=k_tolerance) if usable else None
    elif ks:
        # No ranking: the point prediction is the one candidate, so R@K is known for K = 1 only.
        r_at_k = recall_at_k(predictions[:, None], gt, (1,), tolerance=k_tolerance)

    if best_scores is None and has_search and score_answers:
        best_scores = np.asarray(method.search(Q, k=1)[0])[:, 0]
    pr = None
    if score_answers and best_scores is not None and best_scores.shape == (n_queries,):
        pr = precision_recall(best_scores, gt.is_correct(predictions, k_tolerance),
                              n_relevant=max(1, gt.n_queries - gt.n_without_positives))

    nbytes, breakdown = _storage_of(method)
    return EvaluationResult(
        name=name if name is not None else getattr(method, "label", type(method).__name__),
        params=_params_of(method),
        chosen_at_fit=jsonable(chosen_at_fit(method)),
        n_map=int(n_map) if n_map is not None else None,
        n_queries=int(n_queries),
        recall=recall_at_tolerance(predictions, gt, tolerances) if tolerances else {},
        recall_curve=recall_curve(predictions, gt, curve_max) if gt.uses_tolerance else np.zeros(0),
        recall_at_k=r_at_k,
        nbytes=nbytes,
        storage_breakdown=breakdown,
        fit_time_s=fit_time,
        query_time_s_per_query=query_time,
        rank_time_s_per_query=rank_time,
        query_latency_s=timing.latency_s,
        n_threads=timing.n_threads,
        timing_repeats=timing.repeats,
        auc_pr_vpr_bench=None if pr is None else pr["auc_pr_vpr_bench"],
        auc_pr_vpr_tutorial=None if pr is None else pr["auc_pr_vpr_tutorial"],
        recall_at_100_precision=None if pr is None else pr["recall_at_100_precision"],
        pr_curve=None if pr is None else dict(zip(("precision", "recall"), thin_curve(pr["precision"],
                                                                                        pr["recall"]))),
        predictions=predictions,
        ranked=ranked,
        ground_truth=gt,
        tolerance_for_k=int(k_tolerance),
        chosen_method=(getattr(method, "choice_", None) or {}).get("method"),  # auto: what it chose
        budget=budget if budget is not None else budget_of(method),
        # The method says when its budget did not shape it (the largest model its parameters allow).
        budget_saturated=budget_of(method) is not None and bool(getattr(method, "budget_saturated", bool)()),
        reference=bool(reference),
        uses_query_sequence=bool(getattr(method, "uses_query_sequence", False)),
        choice=_choice_of(method),
        labels=dict(labels or {}),
    )


#: The older name of :func:`measure`.
evaluate = measure


def _tolerances_for(tolerances: Iterable[int] | None, gt: GroundTruth, n_map: int | None) -> tuple[int, ...]:
    """Checked tolerances, or the default for this ground truth and map."""
    if tolerances is None:
        return default_tolerances(n_map, gt)
    tolerances = check_points(tolerances, "tolerances", 0)
    if not gt.uses_tolerance:
        raise InvalidParameterError(
            "tolerances (recall@t) need one true place per query; this ground truth lists explicit positives, "
            "which already say what is close enough. Report R@K (ks) instead."
        )
    return tolerances


