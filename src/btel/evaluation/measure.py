"""The evaluation harness (SPEC §9): fit a method, localize the queries, measure everything.

:func:`evaluate` measures one method — recall@t, R@K, precision–recall (:mod:`btel.evaluation.metrics`),
timing (:mod:`btel.evaluation.timing`), storage — into an :class:`~btel.evaluation.records.EvaluationResult`.
:func:`evaluate_all` is the harness of ``btel evaluate`` and ``btel demo``: it checks every method
against its budget before fitting any (:func:`preflight`), runs each in turn, turns a method that
does not fit or fails into a row with its status and reason instead of an error, and hands each
finished row to a callback (the run folder is written as each method finishes).

Writing results to disk (run folders, run metadata) is :mod:`btel.evaluation.runs`, the text table
:mod:`btel.evaluation.tables`; this module reads and writes no files. The metrics, the record, the timing
and the table are importable from here too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.validation import check_descriptors, check_positive_int
from ..datasets.groundtruth import GroundTruth, check_predictions
from ..exceptions import BTELError, BudgetTooSmallError, InvalidAnswerError, InvalidParameterError
from .metrics import (DEFAULT_KS, DEFAULT_TOLERANCES, PR_CURVE_POINTS, TABLE_KS, TruthLike, check_ground_truth,
                      check_points, default_curve_max, default_ks, default_tolerances, precision_recall,
                      recall_at_k, recall_at_tolerance, recall_curve, thin_curve)
from .records import (STATUS_DOES_NOT_FIT, STATUS_FAILED, STATUS_NOT_RUN, STATUS_OK, STATUS_REFUSED,
                      EvaluationResult, _params_of, _storage_of)
from ..core.storage import parse_budget
from .tables import format_table
from .timing import QueryTiming, time_queries

__all__ = ["DEFAULT_TOLERANCES", "DEFAULT_KS", "TABLE_KS", "PR_CURVE_POINTS", "recall_at_tolerance", "recall_curve",
           "recall_at_k", "EvaluationResult", "evaluate", "Job", "preflight", "evaluate_all", "default_tolerances",
           "default_ks", "default_curve_max", "check_ground_truth", "format_table", "STATUS_OK", "STATUS_REFUSED",
           "STATUS_DOES_NOT_FIT", "STATUS_FAILED", "STATUS_NOT_RUN", "QueryTiming", "time_queries",
           "precision_recall"]

logger = logging.getLogger(__name__)



def evaluate(
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
) -> EvaluationResult:
    """Fit ``method`` on the map, localize the queries, and measure everything SPEC §9 asks for.

    Parameters
    ----------
    method : estimator
        A :class:`~btel.methods.base.PlaceLocalizer` or any object with ``fit(X)`` and ``predict(Q)``
        returning place indices. Ranking (``rank(Q, k)``) is used when the method has ``rank``;
        storage is read from ``nbytes`` /
        ``storage_breakdown()`` when present.
    X_map : array-like of shape (n_map, n_features)
        Map descriptors, row i = place i. May be None when ``fit=False`` and the method knows its
        number of places (``n_places_``).
    Q : array-like of shape (n_queries, n_features)
        Query descriptors, one query per row.
    ground_truth : GroundTruth, array-like of int of shape (n_queries,), or None
        None means frame-aligned: the true place of query j is j.
    tolerances : iterable of int, optional
        Tolerances (frames) for recall@t; default :func:`default_tolerances` (none with explicit
        positives, which have no tolerance; giving some then is an error).
    ks : iterable of int
        K values for R@K. K larger than the map is left out.
    k_tolerance : int, default 0
        Tolerance applied to R@K.
    name : str, optional
        Name in reports; default the method's class name.
    curve_max : int, optional
        The recall@t curve covers t = 0..curve_max; default :func:`default_curve_max`.
    fit : bool, default True
        False evaluates an already fitted method (``fit_time_s`` is then None).
    budget : int, optional
        The budget the method was given (recorded in the result only).
    reference : bool, default False
        Mark the result as the unbudgeted reference row.
    timing_threads : int or None, default 1
        BLAS/OpenMP threads while localizing and timing (see :func:`time_queries`); reported as
        ``n_threads``.
    timing_repeats : int, default 5
        Timed batch calls behind the query-time median (:func:`time_queries`: warm-up, repeats,
        and single-query latency timed apart).

    Returns
    -------
    EvaluationResult
    """
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

    fit_time = None
    if fit:
        start = time.perf_counter()
        method.fit(X_map)
        fit_time = time.perf_counter() - start

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

    if best_scores is None and has_search:
        best_scores = np.asarray(method.search(Q, k=1)[0])[:, 0]
    pr = None
    if best_scores is not None and best_scores.shape == (n_queries,):
        pr = precision_recall(best_scores, gt.is_correct(predictions, k_tolerance),
                              n_relevant=max(1, gt.n_queries - gt.n_without_positives))

    nbytes, breakdown = _storage_of(method)
    return EvaluationResult(
        name=name if name is not None else type(method).__name__,
        params=_params_of(method),
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
        budget=budget if budget is not None else parse_budget(getattr(method, "budget", None)),
        reference=bool(reference),
        uses_query_sequence=bool(getattr(method, "uses_query_sequence", False)),
    )


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


# -- the harness of `btel evaluate` and `btel demo` ----------------------------------------------
@dataclass
class Job:
    """One row of an evaluation run: a method to fit (or an already fitted one) under a budget.

    Attributes
    ----------
    name : str
        Row name (distinct within a run).
    method : estimator
        Unfitted (``fit=True``) or fitted (``fit=False``, e.g. a saved model).
    fit : bool
    reference : bool
        The unbudgeted reference row (brute force).
    series : str, optional
        The method this row is one point of, when a run has several budgets (``pq`` for ``pq@100KB``).
    settings : dict, optional
        The parameters the user set for this row (``--param code=random``), shown in plot legends
        so that two rows of one method can be told apart.
    """

    name: str
    method: Any
    fit: bool = True
    reference: bool = False
    series: str | None = None
    settings: dict[str, Any] | None = None

    @property
    def budget(self) -> int | None:
        return parse_budget(getattr(self.method, "budget", None))




def _budget_check(method: Any, n_rows: int, n_features: int, budget: int | None) -> None:
    """Raise what the method's own fit would raise for this map shape and budget, without fitting:
    the method answers (:meth:`btel.methods.base.PlaceLocalizer.check_budget`, its own planner). An object
    outside btel's base class without that method is left to its fit."""
    check = getattr(method, "check_budget", None)
    if check is not None:
        check(n_rows, n_features, budget)


def preflight(jobs: Sequence[Job], n_map: int | None, n_features: int | None, *,
              queries_are_route: bool = True) -> dict[str, EvaluationResult]:
    """Every row that cannot run, found before anything is fitted, by job name.

    - a job whose method does not fit its budget (the method's own planning rules applied to the
      map's shape) → status ``"does not fit"`` with the method's message and minimum bytes;
    - a job whose parameters cannot work on this map (too few places for its regions, periods or
      sub-quantisers) → ``"failed"``;
    - a method that uses the query sequence when ``queries_are_route`` is False → ``"refused"``.

    Jobs of already fitted methods are only checked for the last rule.

    Returns
    -------
    dict of str to EvaluationResult
        Only the jobs that will not run; every other job is left to :func:`evaluate_all`.
    """
    out: dict[str, EvaluationResult] = {}
    for job in jobs:
        common = dict(method=job.method, n_map=n_map, budget=job.budget, reference=job.reference)
        if not queries_are_route and getattr(job.method, "uses_query_sequence", False):
            out[job.name] = EvaluationResult.not_measured(
                job.name, STATUS_REFUSED,
                "uses the query sequence (SeqSLAM or a delta front end), but the query rows are independent "
                "places, not a route", **common)
            continue
        if not job.fit or n_map is None or n_features is None:
            continue
        try:
            _budget_check(job.method, int(n_map), int(n_features), job.budget)
        except BudgetTooSmallError as exc:
            out[job.name] = EvaluationResult.not_measured(job.name, STATUS_DOES_NOT_FIT, _short_reason(exc),
                                                          minimum_bytes=exc.minimum, **common)
        except BTELError as exc:
            out[job.name] = EvaluationResult.not_measured(job.name, STATUS_FAILED, _short_reason(exc), **common)
    return out


def _short_reason(exc: BaseException) -> str:
    """An exception as one line: its message (its type when it has none)."""
    message = " ".join(str(exc).split())
    return message or type(exc).__name__


def evaluate_all(
    jobs: Sequence[Job],
    X_map: Any,
    Q: Any,
    *,
    ground_truth: TruthLike = None,
    tolerances: Iterable[int] | None = None,
    ks: Iterable[int] = DEFAULT_KS,
    k_tolerance: int = 0,
    curve_max: int | None = None,
    queries_are_route: bool = True,
    on_preflight: Callable[[dict[str, EvaluationResult]], None] | None = None,
    on_result: Callable[[list[EvaluationResult]], None] | None = None,
    on_start: Callable[[int, Job], None] | None = None,
    finished: Sequence[EvaluationResult] = (),
    timing_threads: int | None = 1,
) -> list[EvaluationResult]:
    """Evaluate every job; one that does not fit or fails becomes a row, never an abort.

    Order of work: the ground truth is checked against the query and map counts, then
    :func:`preflight` finds every row that cannot run (all of them, reported at once through
    ``on_preflight``), then each remaining job is fitted and measured in turn. A
    :class:`~btel.exceptions.BudgetTooSmallError` the preflight could not foresee becomes a
    ``"does not fit"`` row, any other error of btel, numpy or faiss (``ValueError``,
    ``RuntimeError``, ``MemoryError``, ``OSError``) a ``"failed"`` row, and the next job runs.
    After each job ``on_result`` receives every row so far, in job order (write them there: a
    crash or Ctrl-C then keeps what is done). On Ctrl-C the rows not yet run become ``"not run"``,
    ``on_result`` sees them, and the ``KeyboardInterrupt`` propagates.

    Parameters
    ----------
    jobs : sequence of Job
        Distinct names.
    X_map : array-like of shape (n_map, n_features) or None
        Map descriptors (None when every job is already fitted).
    Q : array-like of shape (n_queries, n_features)
    ground_truth, tolerances, ks, k_tolerance, curve_max
        As in :func:`evaluate`.
    queries_are_route : bool, default True
        False says the query rows are independent places, not a traverse: methods that use the
        query sequence are refused.
    on_preflight : callable, optional
        Called once with the rows that will not run (may be empty), before any fit.
    on_result : callable, optional
        Called with the list of rows so far after each job.
    on_start : callable, optional
        Called with (index, job) before a job is fitted (progress display).
    timing_threads : int or None, default 1
        Threads while localizing and timing each method (:func:`time_queries`).
    finished : sequence of EvaluationResult, optional
        Rows of an earlier, interrupted run of the same jobs (``btel evaluate --resume``): a job
        with a row of status ``"ok"`` here is not run again; that row is kept.

    Returns
    -------
    list of EvaluationResult
        One per job, in job order.
    """
    names = [job.name for job in jobs]
    if len(set(names)) != len(names):
        raise InvalidParameterError(f"job names must be distinct; got {names}.")
    if X_map is not None:
        X_map = check_descriptors(X_map, name="X_map")
    n_map = X_map.shape[0] if X_map is not None else next(
        (int(j.method.n_places_) for j in jobs if not j.fit and hasattr(j.method, "n_places_")), None)
    n_features = X_map.shape[1] if X_map is not None else None
    Q = check_descriptors(Q, name="Q", n_features=n_features)
    gt = check_ground_truth(ground_truth, Q.shape[0], n_map)
    tolerances = _tolerances_for(tolerances, gt, n_map)
    skipped = preflight(jobs, n_map, n_features, queries_are_route=queries_are_route)
    for job in jobs:
        if job.name in skipped:
            skipped[job.name].series = job.series
            skipped[job.name].settings = job.settings
    if on_preflight is not None:
        on_preflight(skipped)
    done: dict[str, EvaluationResult] = dict(skipped)
    done.update({r.name: r for r in finished if r.ok and r.name in names})

    def rows() -> list[EvaluationResult]:
        return [done[name] for name in names if name in done]

    for index, job in enumerate(jobs):
        if job.name in done:
            continue
        common = dict(method=job.method, n_map=n_map, n_queries=Q.shape[0], budget=job.budget,
                      reference=job.reference)
        if on_start is not None:
            on_start(index, job)
        try:
            done[job.name] = evaluate(job.method, X_map if job.fit else None, Q, ground_truth=gt,
                                      tolerances=tolerances or None, ks=ks, k_tolerance=k_tolerance, name=job.name,
                                      curve_max=curve_max, fit=job.fit, budget=job.budget, reference=job.reference,
                                      timing_threads=timing_threads)
        except BudgetTooSmallError as exc:
            done[job.name] = EvaluationResult.not_measured(job.name, STATUS_DOES_NOT_FIT, _short_reason(exc),
                                                           minimum_bytes=exc.minimum, **common)
        except KeyboardInterrupt:
            for later in jobs[index:]:
                if later.name not in done:
                    done[later.name] = EvaluationResult.not_measured(
                        later.name, STATUS_NOT_RUN, "interrupted (Ctrl-C) before it finished",
                        method=later.method, n_map=n_map, n_queries=Q.shape[0], budget=later.budget,
                        reference=later.reference)
                    done[later.name].series = later.series
            if on_result is not None:
                on_result(rows())
            raise
        except (ValueError, RuntimeError, MemoryError, OSError, ArithmeticError) as exc:
            logger.debug("%s failed", job.name, exc_info=True)
            done[job.name] = EvaluationResult.not_measured(
                job.name, STATUS_FAILED, f"{type(exc).__name__}: {_short_reason(exc)}", **common)
        done[job.name].series = job.series
        done[job.name].settings = job.settings
        if on_result is not None:
            on_result(rows())
    return rows()

