"""Evaluation protocol (SPEC §9): recall at a tolerance, R@K, timing, storage, run folders.

Queries are rows: query j is row j of ``Q``, entry j of the predictions and row j of a ranking.
Ground truth defaults to frame-aligned traverses (the true place of query j is j); pass a
:class:`~btel.datasets.groundtruth.GroundTruth` (or an array of true places) otherwise.

Two names, one meaning each, everywhere (tables, CSV, JSON, plots):

- **recall@t** — share of queries whose *point prediction* lies within t frames of the true place
  (``|pred − true| ≤ t``). Needs one true place per query (frame-aligned traverses); reported at
  the tolerances the route supports (:func:`default_tolerances`) and as a curve t = 0..t_max.
- **R@K** — share of queries with at least one of the top K *ranked* candidates correct (within
  ``k_tolerance`` frames, default 0, or among the positives). Every method ranks, and the first
  candidate is the point prediction, so R@1 = recall@0 (at ``k_tolerance`` 0) for every method.
- With explicit positives per query (VPR-Bench, GPS radius) the tolerance does not apply: only
  R@K is reported (R@1/5/10/20 on the command line, the field's convention).
- Every result carries storage bytes (and their breakdown), fit time and query time per query.

:func:`evaluate_all` is the harness of ``btel evaluate`` and ``btel demo``: it checks every method
against its budget before fitting any (:func:`preflight`), runs each in turn, turns a method that
does not fit or fails into a row with its status and reason instead of an error, and hands each
finished row to a callback (the run folder is written as each method finishes).

Writing results to disk (run folders, run metadata) is :mod:`btel.runs`; this module reads and
writes no files.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validation import check_descriptors, check_positive_int
from .datasets.groundtruth import GroundTruth, check_predictions
from .exceptions import BTELError, BudgetTooSmallError, InvalidAnswerError, InvalidParameterError
from .storage import format_bytes, parse_budget

__all__ = [
    "DEFAULT_TOLERANCES",
    "DEFAULT_KS",
    "recall_at_tolerance",
    "recall_curve",
    "recall_at_k",
    "EvaluationResult",
    "evaluate",
    "Job",
    "preflight",
    "evaluate_all",
    "default_tolerances",
    "default_ks",
    "check_ground_truth",
    "format_table",
    "STATUS_OK",
    "QueryTiming",
    "time_queries",
    "precision_recall",
]

logger = logging.getLogger(__name__)

#: Tolerances (frames) at which recall is reported (SPEC §9).
DEFAULT_TOLERANCES: tuple[int, ...] = (0, 1, 2, 5, 10, 20)
#: K values for R@K (SPEC §9).
DEFAULT_KS: tuple[int, ...] = (1, 5, 10, 20)
#: K values printed by default (R@20 stays in the files when asked for with ``ks``).
TABLE_KS: tuple[int, ...] = (1, 5, 10)
#: The status of a row that ran; anything else says why it did not.
STATUS_OK = "ok"

TruthLike = GroundTruth | np.ndarray | Sequence[int] | None


# -- recall -------------------------------------------------------------------------------------
def check_ground_truth(true_places: TruthLike, n_queries: int, n_map: int | None = None, *,
                       option: str = "ground_truth=") -> GroundTruth:
    """The ground truth for ``n_queries`` query rows and a map of ``n_map`` places, checked.

    Called before anything is fitted, so a mismatch costs nothing. ``option`` is how the caller
    gives a ground truth (``"ground_truth="`` in Python, ``"--ground-truth"`` on the command line)
    and is named in the messages.

    Parameters
    ----------
    true_places : GroundTruth, array-like of int of shape (n_queries,), or None
        None means frame-aligned (query j ↔ place j).
    n_queries : int
    n_map : int, optional

    Returns
    -------
    GroundTruth

    Raises
    ------
    InvalidParameterError
        Counts that do not match, or frame alignment with more queries than places.
    """
    if isinstance(true_places, GroundTruth):
        gt = true_places
    elif true_places is None:
        if n_map is not None and n_queries > n_map:
            raise InvalidParameterError(
                f"there are {n_queries} queries but only {n_map} map places, so the default frame-aligned "
                f"ground truth (query j ↔ place j) cannot hold. Give the true places with {option}."
            )
        gt = GroundTruth.frame_aligned(n_queries, n_map=n_map)
    else:
        gt = GroundTruth.from_places(true_places, n_map=n_map)
    if gt.n_queries != n_queries:
        raise InvalidParameterError(
            f"the ground truth ({option}) covers {gt.n_queries} queries but there are {n_queries} query rows."
        )
    if n_map is not None and gt.n_map is not None and gt.n_map != n_map:
        raise InvalidParameterError(
            f"the ground truth ({option}) refers to a map of {gt.n_map} places but the map has {n_map}."
        )
    if n_map is not None and gt.kind == "places" and gt.query_places.size and gt.query_places.max() >= n_map:
        raise InvalidParameterError(
            f"the ground truth ({option}) names map place {int(gt.query_places.max())} but the map has only "
            f"{n_map} places (0..{n_map - 1})."
        )
    if n_map is not None and gt.kind == "positives" and gt.indices.size and gt.indices.max() >= n_map:
        raise InvalidParameterError(
            f"the ground truth ({option}) names map place {int(gt.indices.max())} as a positive but the map has "
            f"only {n_map} places (0..{n_map - 1})."
        )
    return gt


_ground_truth = check_ground_truth


def default_tolerances(n_map: int | None, ground_truth: GroundTruth | None = None) -> tuple[int, ...]:
    """The recall@t tolerances a route supports: :data:`DEFAULT_TOLERANCES` up to a tenth of the map.

    A tolerance of 20 frames on a 111-frame route accepts over a third of the route as "correct";
    so only tolerances t ≤ max(1, N // 10) are reported by default. Explicit positives (kind
    ``"positives"``) have no tolerance: the result is ``()`` (report R@K instead).
    """
    if ground_truth is not None and not ground_truth.uses_tolerance:
        return ()
    if n_map is None:
        return DEFAULT_TOLERANCES
    limit = max(1, int(n_map) // 10)
    return tuple(t for t in DEFAULT_TOLERANCES if t <= limit)


def default_ks(n_map: int | None) -> tuple[int, ...]:
    """R@K values for a map of ``n_map`` places: :data:`TABLE_KS` (K ≤ N)."""
    return tuple(k for k in TABLE_KS if n_map is None or k <= n_map) or (1,)


def default_curve_max(tolerances: Sequence[int], n_map: int | None) -> int:
    """Right end of the recall@t curve: twice the largest reported tolerance (≥ 10), within the map."""
    t_max = max(10, 2 * max(tolerances, default=0))
    return t_max if n_map is None else max(0, min(t_max, int(n_map) - 1))


def _predictions_1d(predictions: Any) -> np.ndarray:
    pred = np.asarray(predictions)
    if pred.ndim != 1 or pred.shape[0] == 0:
        raise InvalidParameterError(
            f"predictions must be a non-empty 1-D array (one place per query row); got shape {pred.shape}."
        )
    return pred


def _check_points(values: Iterable[Any], name: str, minimum: int) -> tuple[int, ...]:
    points = tuple(check_positive_int(v, name, minimum=minimum) for v in values)
    if not points:
        raise InvalidParameterError(f"{name} is empty; give at least one value.")
    return tuple(sorted(set(points)))


def recall_at_tolerance(
    predictions: Any, true_places: TruthLike = None, tolerances: Iterable[int] = DEFAULT_TOLERANCES
) -> dict[int, float]:
    """Recall at each tolerance: share of queries with ``|pred − true| ≤ t``.

    Parameters
    ----------
    predictions : array-like of int, shape (n_queries,)
        Predicted map place per query row.
    true_places : array-like of int of shape (n_queries,), GroundTruth, or None
        True place per query; None means frame-aligned (query j ↔ place j). With a GroundTruth
        of explicit positives the tolerance does not apply (every t gives the same recall).
    tolerances : iterable of int ≥ 0
        Frames of slack.

    Returns
    -------
    dict of int to float
        Tolerance → recall in [0, 1], sorted by tolerance.
    """
    pred = _predictions_1d(predictions)
    gt = _ground_truth(true_places, pred.shape[0])
    return {t: float(gt.is_correct(pred, t).mean()) for t in _check_points(tolerances, "tolerances", 0)}


def recall_curve(predictions: Any, true_places: TruthLike = None, max_tolerance: int = 80) -> np.ndarray:
    """Recall at every tolerance t = 0, 1, …, ``max_tolerance``.

    Returns
    -------
    curve : ndarray of shape (max_tolerance + 1,), dtype float64
        ``curve[t]`` = recall at tolerance t (non-decreasing).
    """
    t_max = check_positive_int(max_tolerance, "max_tolerance", minimum=0)
    pred = _predictions_1d(predictions)
    gt = _ground_truth(true_places, pred.shape[0])
    if not gt.uses_tolerance:
        return np.full(t_max + 1, gt.is_correct(pred).mean(), dtype=np.float64)
    # Count queries by error (errors beyond t_max pooled in the last bin), then accumulate.
    errors = np.minimum(gt.distances(pred), t_max + 1)
    counts = np.bincount(errors, minlength=t_max + 2)[: t_max + 1]
    return np.cumsum(counts) / gt.n_queries


def recall_at_k(
    ranked: Any, true_places: TruthLike = None, ks: Iterable[int] = DEFAULT_KS, tolerance: int = 0
) -> dict[int, float]:
    """R@K: share of queries with at least one of their top K candidates correct.

    Parameters
    ----------
    ranked : array-like of int, shape (n_queries, k)
        Candidate places per query row, best first (``PlaceLocalizer.rank``).
    true_places : array-like of int of shape (n_queries,), GroundTruth, or None
        As in :func:`recall_at_tolerance`.
    ks : iterable of int ≥ 1
        Each K must be ≤ the number of ranked columns.
    tolerance : int, default 0
        A candidate within this many frames of the true place counts.

    Returns
    -------
    dict of int to float
        K → R@K in [0, 1].
    """
    arr = np.asarray(ranked)
    if arr.ndim != 2:
        raise InvalidParameterError(f"ranked must be 2-D (n_queries, k); got shape {arr.shape}.")
    points = _check_points(ks, "ks", 1)
    if points[-1] > arr.shape[1]:
        raise InvalidParameterError(
            f"R@{points[-1]} needs at least {points[-1]} ranked candidates per query; ranked has {arr.shape[1]}. "
            f"Call rank(Q, k={points[-1]}) or lower ks."
        )
    gt = _ground_truth(true_places, arr.shape[0])
    found = np.logical_or.accumulate(gt.rank_correct(arr, tolerance), axis=1)
    return {k: float(found[:, k - 1].mean()) for k in points}


# -- precision–recall from the best-match score (VPR-Bench, VPR_Tutorial) ----------------------------
#: Points kept of a PR curve in results (the curve is drawn from them; AUC-PR uses every point).
PR_CURVE_POINTS = 256


def precision_recall(best_scores: Any, correct: Any) -> dict[str, Any]:
    """The precision–recall curve of accepting a query's top-1 match when its score passes a threshold.

    Each query has one best match and its score (higher = more confident). Sweeping a threshold
    from the highest score down: precision = correct accepted matches / accepted matches, recall =
    correct accepted matches / all queries (every query has a true place in the map; VPR-Bench's and
    VPR_Tutorial's convention). Scores are compared within one method only, so any method's own
    scale serves (a monotone rescaling changes nothing).

    Parameters
    ----------
    best_scores : array-like of float, shape (n_queries,)
        Score of each query's best match (``search(Q, 1)[0][:, 0]``). NaN counts as least confident.
    correct : array-like of bool, shape (n_queries,)
        Whether that best match is a true place.

    Returns
    -------
    dict
        ``precision``, ``recall`` (ndarrays, one point per distinct threshold, recall increasing),
        ``auc_pr`` (area under the step curve: Σ ΔRecall × precision, i.e. average precision with
        recall over all queries) and ``recall_at_100_precision`` (the largest recall with no false
        match accepted; 0 when the most confident match is wrong).
    """
    from sklearn.metrics import precision_recall_curve

    scores = np.asarray(best_scores, dtype=np.float64).reshape(-1)
    correct = np.asarray(correct, dtype=bool).reshape(-1)
    if scores.shape != correct.shape or scores.size == 0:
        raise InvalidParameterError(f"best_scores and correct must be 1-D of one length ≥ 1; got {scores.shape} "
                                    f"and {correct.shape}.")
    finite = np.isfinite(scores)
    low = scores[finite].min() - 1.0 if finite.any() else 0.0
    scores = np.where(np.isnan(scores), low, np.clip(scores, low, None))
    n_correct = int(correct.sum())
    if n_correct == 0:
        return {"precision": np.zeros(1), "recall": np.zeros(1), "auc_pr": 0.0, "recall_at_100_precision": 0.0}
    precision, recall, _ = precision_recall_curve(correct, scores)
    # sklearn's recall counts correct top-1 matches only; VPR counts every query (a wrong top-1 is a miss).
    precision, recall = precision[::-1], recall[::-1] * (n_correct / correct.size)
    auc = float(np.sum(np.diff(recall) * precision[1:]))
    perfect = recall[precision >= 1.0]
    return {"precision": precision, "recall": recall, "auc_pr": auc,
            "recall_at_100_precision": float(perfect.max()) if perfect.size else 0.0}


def _thin_curve(precision: np.ndarray, recall: np.ndarray, n: int = PR_CURVE_POINTS) -> tuple[list[float], list[float]]:
    """At most ``n`` points of a PR curve, evenly spaced along it (first and last kept)."""
    keep = np.unique(np.linspace(0, precision.size - 1, min(n, precision.size)).round().astype(int))
    return [float(v) for v in precision[keep]], [float(v) for v in recall[keep]]


# -- evaluation of one method --------------------------------------------------------------------
def _jsonable(value: Any, depth: int = 0) -> Any:
    """A JSON-safe version of a parameter value (strict JSON: no NaN/inf)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, type):
        return value.__name__
    if isinstance(value, np.dtype):
        return value.name
    if depth < 4 and isinstance(value, Mapping):
        return {str(k): _jsonable(v, depth + 1) for k, v in value.items()}
    if depth < 4 and isinstance(value, (list, tuple)):
        return [_jsonable(v, depth + 1) for v in value]
    if isinstance(value, np.ndarray):
        if value.size <= 64:
            return _jsonable(value.tolist(), depth + 1)
        return f"ndarray(shape={value.shape}, dtype={value.dtype})"
    return repr(value)


def _params_of(method: Any) -> dict[str, Any]:
    get_params = getattr(method, "get_params", None)
    if get_params is None:
        return {}
    return {str(k): _jsonable(v) for k, v in get_params(deep=False).items()}


def _storage_of(method: Any) -> tuple[int | None, dict[str, int] | None]:
    """(nbytes, breakdown) of a fitted method, None where the method does not report them."""
    breakdown = None
    if callable(getattr(method, "storage_breakdown", None)):
        try:
            breakdown = {str(k): int(v) for k, v in method.storage_breakdown().items()}
        except NotImplementedError:
            breakdown = None
    try:
        nbytes = getattr(method, "nbytes", None)
    except NotImplementedError:
        nbytes = None
    if nbytes is None and breakdown is not None:
        nbytes = sum(breakdown.values())
    return (None if nbytes is None else int(nbytes)), breakdown


@dataclass
class EvaluationResult:
    """Everything measured for one method on one map/query pair — or why it was not measured.

    Attributes
    ----------
    name : str
        Method name (used in tables, legends and file names).
    params : dict
        ``get_params(deep=False)`` made JSON-safe (empty when the method has none).
    n_map : int or None
        Map places (None only when a pre-fitted method without ``n_places_`` was evaluated).
    n_queries : int
        Query rows.
    recall : dict of int to float
        recall@t: tolerance (frames) → share of point predictions within t of the true place.
        Empty with explicit positives (no tolerance applies) and for rows that did not run.
    recall_curve : ndarray of shape (curve_max + 1,), dtype float64
        recall@t at t = 0, 1, …, curve_max (empty where ``recall`` is).
    recall_at_k : dict of int to float or None
        R@K: K → share of queries with a correct place among the top K ranked candidates.
    nbytes : int or None
        Storage (SPEC §7); None when the method does not report it (plain scikit-learn objects).
    storage_breakdown : dict of str to int or None
        Part → bytes.
    fit_time_s : float or None
        Wall-clock seconds of ``fit`` (None when the method was evaluated already fitted).
    query_time_s_per_query : float or None
        Batch throughput: median wall-clock seconds of ``predict`` on all queries (after a warm-up
        call, over ``timing_repeats`` calls) divided by the number of queries.
    rank_time_s_per_query : float or None
        Wall-clock seconds of one ``rank`` call on all queries divided by the number of queries.
    query_latency_s : float or None
        Single-query latency: median seconds of one query answered alone (:func:`time_queries`).
    n_threads : int or None
        Threads the numerical libraries could use while timing.
    timing_repeats : int or None
        Timed batch calls behind ``query_time_s_per_query``.
    auc_pr : float or None
        Area under the precision–recall curve of accepting each query's top-1 match by its score
        (:func:`precision_recall`); None when the method gives no scores.
    recall_at_100_precision : float or None
        Recall at 100 % precision on that curve.
    pr_curve : dict or None
        ``{"precision": [...], "recall": [...]}``, at most :data:`PR_CURVE_POINTS` points.
    predictions : ndarray of shape (n_queries,), dtype int64
        Predicted place per query row (not written to JSON; see ``predictions_<name>.csv``).
    ranked : ndarray of shape (n_queries, k), dtype int64, or None
        Ranked candidates (not written to JSON).
    ground_truth : GroundTruth or None
        The ground truth used (not written to JSON).
    tolerance_for_k : int
        Tolerance used for R@K.
    status : str
        ``"ok"``, or why there are no numbers: ``"does not fit"`` (the budget), ``"failed"`` (an
        error while fitting or localizing), ``"refused"`` (e.g. a sequence method on queries that
        are not a route), ``"not run"`` (interrupted before its turn).
    reason : str or None
        The message behind a status other than ``"ok"``.
    budget : int or None
        The byte budget the method was given (None: unbudgeted).
    reference : bool
        The unbudgeted reference row (brute force).
    uses_query_sequence : bool
        Answers depend on the query sequence (SeqSLAM, a delta front end): not comparable with
        single-frame methods, marked in every table.
    minimum_bytes : int or None
        For ``"does not fit"``: the smallest budget the method needs.
    series : str or None
        The method this row is one point of (``pq`` for the rows ``pq@100KB`` and ``pq@500KB``);
        plots draw one line per series. None: the row's own name.
    settings : dict or None
        The parameters set by the user for this row (``--param``), shown in plot legends.
    """

    name: str
    params: dict[str, Any]
    n_map: int | None
    n_queries: int
    recall: dict[int, float]
    recall_curve: np.ndarray
    recall_at_k: dict[int, float] | None
    nbytes: int | None
    storage_breakdown: dict[str, int] | None
    fit_time_s: float | None
    query_time_s_per_query: float | None
    rank_time_s_per_query: float | None = None
    query_latency_s: float | None = None
    n_threads: int | None = None
    timing_repeats: int | None = None
    auc_pr: float | None = None
    recall_at_100_precision: float | None = None
    pr_curve: dict[str, list[float]] | None = field(default=None, repr=False)
    predictions: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    ranked: np.ndarray | None = field(default=None, repr=False)
    ground_truth: GroundTruth | None = field(default=None, repr=False)
    tolerance_for_k: int = 0
    status: str = STATUS_OK
    reason: str | None = None
    budget: int | None = None
    reference: bool = False
    uses_query_sequence: bool = False
    minimum_bytes: int | None = None
    series: str | None = None
    settings: dict[str, Any] | None = None

    @property
    def ok(self) -> bool:
        """True when the method ran and was measured."""
        return self.status == STATUS_OK

    @classmethod
    def not_measured(cls, name: str, status: str, reason: str, *, method: Any = None, n_map: int | None = None,
                     n_queries: int = 0, budget: int | None = None, reference: bool = False,
                     minimum_bytes: int | None = None) -> "EvaluationResult":
        """A row for a method that did not run (``status`` says why, ``reason`` in full)."""
        result = cls(name=name, params=_params_of(method) if method is not None else {}, n_map=n_map,
                     n_queries=int(n_queries), recall={}, recall_curve=np.zeros(0), recall_at_k=None, nbytes=None,
                     storage_breakdown=None, fit_time_s=None, query_time_s_per_query=None, status=status,
                     reason=reason, budget=budget, reference=reference,
                     uses_query_sequence=bool(getattr(method, "uses_query_sequence", False)),
                     minimum_bytes=minimum_bytes)
        return result

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "EvaluationResult":
        """A row back from :meth:`to_dict` (``metrics.json``): every number, no predictions or ranking.

        Raises
        ------
        InvalidParameterError
            ``data`` lacks a field :meth:`to_dict` writes.
        """
        try:
            result = cls(
                name=str(data["name"]), params=dict(data.get("params") or {}), n_map=data.get("n_map"),
                n_queries=int(data["n_queries"]), recall={int(t): float(v) for t, v in (data.get("recall") or {}).items()},
                recall_curve=np.asarray(data.get("recall_curve") or [], dtype=np.float64),
                recall_at_k=(None if data.get("recall_at_k") is None
                             else {int(k): float(v) for k, v in data["recall_at_k"].items()}),
                nbytes=data.get("nbytes"), storage_breakdown=data.get("storage_breakdown"),
                fit_time_s=data.get("fit_time_s"), query_time_s_per_query=data.get("query_time_s_per_query"),
                rank_time_s_per_query=data.get("rank_time_s_per_query"), query_latency_s=data.get("query_latency_s"),
                n_threads=data.get("n_threads"), timing_repeats=data.get("timing_repeats"), auc_pr=data.get("auc_pr"),
                recall_at_100_precision=data.get("recall_at_100_precision"), pr_curve=data.get("pr_curve"),
                tolerance_for_k=int(data.get("tolerance_for_k") or 0), status=str(data["status"]),
                reason=data.get("reason"), budget=data.get("budget"), reference=bool(data.get("reference")),
                uses_query_sequence=bool(data.get("uses_query_sequence")), minimum_bytes=data.get("minimum_bytes"),
                series=data.get("series"), settings=data.get("settings"))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InvalidParameterError(f"not a row of metrics.json ({type(exc).__name__}: {exc}).") from exc
        return result

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no predictions). Tolerances and K stay ints here; JSON makes them strings."""
        return {
            "name": self.name,
            "status": self.status,
            "reason": self.reason,
            "series": self.series or self.name,
            "settings": _jsonable(self.settings) if self.settings else None,
            "reference": self.reference,
            "uses_query_sequence": self.uses_query_sequence,
            "budget": self.budget,
            "minimum_bytes": self.minimum_bytes,
            "params": self.params,
            "n_map": self.n_map,
            "n_queries": self.n_queries,
            "recall": {int(t): float(r) for t, r in self.recall.items()},
            "recall_curve": [float(r) for r in np.asarray(self.recall_curve)],
            "recall_at_k": (
                None if self.recall_at_k is None else {int(k): float(r) for k, r in self.recall_at_k.items()}
            ),
            "tolerance_for_k": self.tolerance_for_k,
            "nbytes": self.nbytes,
            "storage_breakdown": self.storage_breakdown,
            "fit_time_s": self.fit_time_s,
            "query_time_s_per_query": self.query_time_s_per_query,
            "rank_time_s_per_query": self.rank_time_s_per_query,
            "query_latency_s": self.query_latency_s,
            "n_threads": self.n_threads,
            "timing_repeats": self.timing_repeats,
            "auc_pr": self.auc_pr,
            "recall_at_100_precision": self.recall_at_100_precision,
            "pr_curve": self.pr_curve,
            "ground_truth": None if self.ground_truth is None else self.ground_truth.kind,
        }

    def headline(self) -> dict[int, float]:
        """What the storage plot shows: recall@t when the ground truth has a tolerance, else R@K keyed by K."""
        return dict(self.recall) if self.recall else dict(self.recall_at_k or {})

    def to_row(self) -> dict[str, Any]:
        """A row for :func:`btel.plots.plot_recall_vs_storage` / :func:`~btel.plots.plot_recall_vs_n`."""
        return {"method": self.name, "bytes": self.nbytes, "n_places": self.n_map, "recall": dict(self.recall)}


# -- timing ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class QueryTiming:
    """How long a fitted method takes to answer queries, measured so that runs agree.

    Attributes
    ----------
    batch_s_per_query : float
        Median over ``repeats`` timed ``predict(Q)`` calls on every query (after a warm-up call),
        divided by the number of queries: throughput when the queries come as one batch.
    latency_s : float or None
        Median wall time of one query answered alone (``stream().search`` — what a robot runs —
        or ``predict`` on one row), over ``n_single`` queries after a few warm-up queries. None when
        the method answers batches only.
    n_threads : int
        Threads the numerical libraries (BLAS, OpenMP) may use during the measurement.
    repeats : int
        Timed batch calls behind the median.
    n_single : int
        Queries behind the latency median.
    """

    batch_s_per_query: float
    latency_s: float | None
    n_threads: int
    repeats: int
    n_single: int


def _n_threads() -> int:
    """The largest thread count any loaded numerical library (BLAS, OpenMP) may use."""
    try:
        from threadpoolctl import threadpool_info

        counts = [int(info.get("num_threads") or 0) for info in threadpool_info()]
    except Exception:  # noqa: BLE001 - a description of the machine, never a reason to fail a run
        counts = []
    import os

    return max(counts, default=0) or (os.cpu_count() or 1)


def time_queries(method: Any, Q: np.ndarray, *, repeats: int = 5, n_single: int = 50, warmup: int = 1,
                 max_seconds: float = 10.0, threads: int | None = 1) -> tuple[np.ndarray, QueryTiming]:
    """Localize ``Q`` with a fitted ``method`` and time it: warm-up first, then repeats, medians.

    One un-warmed batch call is not a timing: the first call pays for page faults, lazy
    allocations and thread start-up (a 100× spread between identical runs). Here the first
    ``warmup`` calls are not timed, the batch is then timed ``repeats`` times (fewer once the timed
    calls pass ``max_seconds``; at least one) and the median is reported; single-query latency is
    timed separately, one query at a time.

    Parameters
    ----------
    method : fitted estimator with ``predict``
    Q : ndarray of shape (n_queries, n_features)
    repeats : int, default 5
        Timed batch calls.
    n_single : int, default 50
        Queries timed one at a time (the first ones of ``Q``); 0 skips the latency.
    warmup : int, default 1
        Untimed batch calls before the timed ones (the predictions come from the first).
    max_seconds : float, default 10
        Stop repeating once the timed batch calls have taken this long.
    threads : int or None, default 1
        BLAS/OpenMP threads while localizing and timing (threadpoolctl). One thread by default:
        on a shared machine multi-threaded BLAS and faiss calls spin against other processes, and
        identical runs then differ by 2–100× (benchmarks/bench_timing_stability.py); one thread
        gives figures that repeat. None leaves the libraries' own setting.

    Returns
    -------
    predictions : ndarray of shape (n_queries,)
        ``method.predict(Q)`` as returned (from the first call).
    timing : QueryTiming
    """
    if threads is not None:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=int(threads)):
            return _time_queries(method, Q, repeats, n_single, warmup, max_seconds)
    return _time_queries(method, Q, repeats, n_single, warmup, max_seconds)


def _time_queries(method: Any, Q: np.ndarray, repeats: int, n_single: int, warmup: int,
                  max_seconds: float) -> tuple[np.ndarray, QueryTiming]:
    n_queries = Q.shape[0]
    predictions = method.predict(Q)
    for _ in range(max(0, warmup - 1)):
        method.predict(Q)
    times: list[float] = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        method.predict(Q)
        times.append(time.perf_counter() - start)
        if sum(times) > max_seconds:
            break
    latency, n_timed = _single_query_latency(method, Q, min(n_single, n_queries), max_seconds)
    timing = QueryTiming(batch_s_per_query=float(np.median(times)) / n_queries, latency_s=latency,
                         n_threads=_n_threads(), repeats=len(times), n_single=n_timed)
    return predictions, timing


def _single_query_latency(method: Any, Q: np.ndarray, n: int, max_seconds: float) -> tuple[float | None, int]:
    """Median seconds of one query answered alone, over up to ``n`` queries (after 3 untimed ones)."""
    if n <= 0:
        return None, 0
    if callable(getattr(method, "stream", None)):
        stream = method.stream()

        def one(i: int) -> None:
            stream.search(Q[i])
    elif getattr(method, "uses_query_sequence", False):
        return None, 0  # one row alone is not the same question for a sequence method without a stream
    else:
        def one(i: int) -> None:
            method.predict(Q[i:i + 1])
    for i in range(min(3, n)):
        one(i)
    if callable(getattr(method, "stream", None)):
        stream = method.stream()  # the timed traverse starts afresh
    times: list[float] = []
    for i in range(n):
        start = time.perf_counter()
        one(i)
        times.append(time.perf_counter() - start)
        if sum(times) > max_seconds:
            break
    return float(np.median(times)), len(times)


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
        A :class:`~btel.base.PlaceLocalizer` or any object with ``fit(X)`` and ``predict(Q)``
        returning place indices. Ranking (``rank(Q, k)``) is used when the method has ``rank``
        (and, where it says so, ``supports_ranking`` is true); storage is read from ``nbytes`` /
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
        ks = _check_points(ks, "ks", 1)
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
        raise InvalidAnswerError(  # never score an answer outside the map (issue 20)
            f"{type(method).__name__}.predict(Q) answered place {int(predictions[(predictions < 0) | (predictions >= n_map)][0])}, "
            f"outside the map's 0..{int(n_map) - 1}.")

    ranked = None
    rank_time = None
    r_at_k = None
    best_scores = None
    has_search = callable(getattr(method, "search", None))
    if ks and getattr(method, "supports_ranking", callable(getattr(method, "rank", None))):
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
        pr = precision_recall(best_scores, gt.is_correct(predictions, k_tolerance))

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
        auc_pr=None if pr is None else pr["auc_pr"],
        recall_at_100_precision=None if pr is None else pr["recall_at_100_precision"],
        pr_curve=None if pr is None else dict(zip(("precision", "recall"), _thin_curve(pr["precision"],
                                                                                        pr["recall"]))),
        predictions=predictions,
        ranked=ranked,
        ground_truth=gt,
        tolerance_for_k=int(k_tolerance),
        budget=budget if budget is not None else parse_budget(getattr(method, "budget", None)),
        reference=bool(reference),
        uses_query_sequence=bool(getattr(method, "uses_query_sequence", False)),
    )


def _tolerances_for(tolerances: Iterable[int] | None, gt: GroundTruth, n_map: int | None) -> tuple[int, ...]:
    """Checked tolerances, or the default for this ground truth and map."""
    if tolerances is None:
        return default_tolerances(n_map, gt)
    tolerances = _check_points(tolerances, "tolerances", 0)
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


#: Status of a row that was refused before fitting because the queries are not a route.
STATUS_REFUSED = "refused"
STATUS_DOES_NOT_FIT = "does not fit"
STATUS_FAILED = "failed"
STATUS_NOT_RUN = "not run"


def _budget_check(method: Any, n_rows: int, n_features: int, budget: int | None) -> None:
    """Raise what the method's own fit would raise for this map shape and budget, without fitting:
    the method answers (:meth:`btel.base.PlaceLocalizer.check_budget`, its own planner). An object
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


# -- the table -------------------------------------------------------------------------------------
SEQUENCE_MARK = "†"
REFERENCE_MARK = "*"


def format_table(results: Sequence[EvaluationResult]) -> str:
    """The results as a plain-text table, with the metrics the ground truth supports.

    Columns: method, status, bytes, fit seconds, batch µs per query (median throughput), single-query
    latency in µs, the thread count, recall@t for every tolerance any
    row has (frame-aligned ground truth only) and R@K for every K. Rows that did not run show
    their status and reason. ``†`` marks methods that use the query sequence (not comparable
    with single-frame methods), ``*`` the unbudgeted reference; a legend line says so.
    """
    tolerances = sorted({t for r in results for t in r.recall})
    ks = sorted({k for r in results for k in (r.recall_at_k or {})})
    has_pr = any(r.auc_pr is not None for r in results)
    metric_names = [f"recall@{t}" for t in tolerances] + [f"R@{k}" for k in ks] + (["AUC-PR", "R@100%P"] if has_pr else [])
    width = max([len("method")] + [len(_row_label(r)) for r in results]) + 1
    header = (f"{'method':<{width}} {'status':<12} {'bytes':>10} {'fit s':>7} {'batch µs/q':>10} {'1-query µs':>10} "
              f"{'threads':>7} " + " ".join(f"{m:>9}" for m in metric_names))
    lines = [header.rstrip(), "-" * len(header.rstrip())]
    for r in results:
        label = _row_label(r)
        if not r.ok:
            # The table says what the user needs to decide; the full message is in metrics.csv/json.
            why = (f"needs ≥ {format_bytes(r.minimum_bytes)}"
                   + (f" (budget {format_bytes(r.budget)})" if r.budget is not None else "")
                   if r.status == STATUS_DOES_NOT_FIT and r.minimum_bytes is not None else (r.reason or ""))
            lines.append(f"{label:<{width}} {r.status:<12} {why}")
            continue
        size = format_bytes(r.nbytes) if r.nbytes is not None else "?"
        fit = f"{r.fit_time_s:.1f}" if r.fit_time_s is not None else "-"
        values = [r.recall.get(t) for t in tolerances] + [(r.recall_at_k or {}).get(k) for k in ks]
        if has_pr:
            values += [r.auc_pr, r.recall_at_100_precision]
        cells = " ".join(f"{v:>9.3f}" if v is not None else f"{'-':>9}" for v in values)
        query = f"{r.query_time_s_per_query * 1e6:.1f}" if r.query_time_s_per_query is not None else "-"
        latency = f"{r.query_latency_s * 1e6:.1f}" if r.query_latency_s is not None else "-"
        threads = str(r.n_threads) if r.n_threads is not None else "-"
        lines.append(f"{label:<{width}} {r.status:<12} {size:>10} {fit:>7} {query:>10} {latency:>10} {threads:>7} "
                     f"{cells}".rstrip())
    notes = []
    repeats = {r.timing_repeats for r in results if r.ok and r.timing_repeats}
    if repeats:
        notes.append(f"batch µs/q: median of {'/'.join(map(str, sorted(repeats)))} timed predict calls on all queries "
                     "after a warm-up, per query; 1-query µs: median latency of one query answered alone")
    if tolerances:
        notes.append("recall@t: point prediction within t frames of the true place")
    if ks:
        k_tol = max((r.tolerance_for_k for r in results if r.ok), default=0)
        within = f" (within {k_tol} frames)" if k_tol else ""
        notes.append(f"R@K: a correct place{within} among the top K ranked candidates")
    if has_pr:
        notes.append("AUC-PR, R@100%P: precision-recall of accepting each query's top-1 match by its score "
                     "(recall over all queries)")
    if any(r.reference for r in results):
        notes.append(f"{REFERENCE_MARK} reference (unbudgeted)")
    if any(r.uses_query_sequence for r in results):
        notes.append(f"{SEQUENCE_MARK} uses the query sequence: not comparable with single-frame methods")
    lines += [f"  {n}" for n in notes]
    return "\n".join(lines)


def _row_label(r: EvaluationResult) -> str:
    return r.name + (REFERENCE_MARK if r.reference else "") + (SEQUENCE_MARK if r.uses_query_sequence else "")
