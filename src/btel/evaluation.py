"""Evaluation protocol (SPEC §9): recall at a tolerance, R@K, timing, storage, run folders.

Queries are rows: query j is row j of ``Q``, entry j of the predictions and row j of a ranking.
Ground truth defaults to frame-aligned traverses (the true place of query j is j); pass a
:class:`~btel.datasets.groundtruth.GroundTruth` (or an array of true places) otherwise.

- **Recall@t** — share of queries whose prediction lies within t frames of the true place
  (``|pred − true| ≤ t``), reported at t ∈ {0, 1, 2, 5, 10, 20} and as a curve t = 0..80.
- **R@K** — for methods that rank candidates: share of queries with at least one of the top K
  candidates within the tolerance (default 0).
- Every result carries storage bytes (and their breakdown), fit time and query time per query.

Writing results to disk (run folders, run metadata) is :mod:`btel.runs`; this module reads and
writes no files.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validation import check_descriptors, check_positive_int
from .datasets.groundtruth import GroundTruth, check_predictions
from .exceptions import InvalidParameterError

__all__ = [
    "DEFAULT_TOLERANCES",
    "DEFAULT_KS",
    "recall_at_tolerance",
    "recall_curve",
    "recall_at_k",
    "EvaluationResult",
    "evaluate",
]

logger = logging.getLogger(__name__)

#: Tolerances (frames) at which recall is reported (SPEC §9).
DEFAULT_TOLERANCES: tuple[int, ...] = (0, 1, 2, 5, 10, 20)
#: K values for R@K of ranking methods (SPEC §9).
DEFAULT_KS: tuple[int, ...] = (1, 5, 10, 20)

TruthLike = GroundTruth | np.ndarray | Sequence[int] | None


# -- recall -------------------------------------------------------------------------------------
def _ground_truth(true_places: TruthLike, n_queries: int, n_map: int | None = None) -> GroundTruth:
    """A GroundTruth for ``n_queries`` rows: given, built from true places, or frame-aligned."""
    if isinstance(true_places, GroundTruth):
        gt = true_places
    elif true_places is None:
        if n_map is not None and n_queries > n_map:
            raise InvalidParameterError(
                f"there are {n_queries} queries but only {n_map} map places, so the default frame-aligned "
                "ground truth (query j ↔ place j) cannot hold. Pass ground_truth= (true places or a GroundTruth)."
            )
        gt = GroundTruth.frame_aligned(n_queries, n_map=n_map)
    else:
        gt = GroundTruth.from_places(true_places, n_map=n_map)
    if gt.n_queries != n_queries:
        raise InvalidParameterError(
            f"the ground truth covers {gt.n_queries} queries but there are {n_queries} query rows."
        )
    if n_map is not None and gt.n_map is not None and gt.n_map != n_map:
        raise InvalidParameterError(
            f"the ground truth refers to a map of {gt.n_map} places but the map has {n_map}."
        )
    return gt


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
    """Everything measured for one method on one map/query pair.

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
        Tolerance (frames) → recall.
    recall_curve : ndarray of shape (curve_max + 1,), dtype float64
        Recall at t = 0, 1, …, curve_max.
    recall_at_k : dict of int to float or None
        K → R@K for ranking methods, else None.
    nbytes : int or None
        Storage (SPEC §7); None when the method does not report it (plain scikit-learn objects).
    storage_breakdown : dict of str to int or None
        Part → bytes.
    fit_time_s : float or None
        Wall-clock seconds of ``fit`` (None when the method was evaluated already fitted).
    query_time_s_per_query : float
        Wall-clock seconds of ``predict`` on all queries divided by the number of queries.
    rank_time_s_per_query : float or None
        Same for ``rank`` (ranking methods only).
    predictions : ndarray of shape (n_queries,), dtype int64
        Predicted place per query row (not written to JSON; see ``predictions_<name>.csv``).
    ranked : ndarray of shape (n_queries, k), dtype int64, or None
        Ranked candidates (not written to JSON).
    ground_truth : GroundTruth or None
        The ground truth used (not written to JSON).
    tolerance_for_k : int
        Tolerance used for R@K.
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
    query_time_s_per_query: float
    rank_time_s_per_query: float | None = None
    predictions: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    ranked: np.ndarray | None = field(default=None, repr=False)
    ground_truth: GroundTruth | None = field(default=None, repr=False)
    tolerance_for_k: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no predictions). Tolerances and K stay ints here; JSON makes them strings."""
        return {
            "name": self.name,
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
            "ground_truth": None if self.ground_truth is None else self.ground_truth.kind,
        }

    def to_row(self) -> dict[str, Any]:
        """A row for :func:`btel.plots.plot_recall_vs_storage` / :func:`~btel.plots.plot_recall_vs_n`."""
        return {"method": self.name, "bytes": self.nbytes, "n_places": self.n_map, "recall": dict(self.recall)}


def evaluate(
    method: Any,
    X_map: Any,
    Q: Any,
    *,
    ground_truth: TruthLike = None,
    tolerances: Iterable[int] = DEFAULT_TOLERANCES,
    ks: Iterable[int] = DEFAULT_KS,
    k_tolerance: int = 0,
    name: str | None = None,
    curve_max: int = 80,
    fit: bool = True,
) -> EvaluationResult:
    """Fit ``method`` on the map, localize the queries, and measure everything SPEC §9 asks for.

    Parameters
    ----------
    method : estimator
        A :class:`~btel.base.PlaceLocalizer` or any object with ``fit(X)`` and ``predict(Q)``
        returning place indices. Ranking (``rank(Q, k)``) is used when the method has ``rank``
        (and, where it says so, ``supports_ranking`` is true); storage is read from ``nbytes`` / ``storage_breakdown()`` when present.
    X_map : array-like of shape (n_map, n_features)
        Map descriptors, row i = place i. May be None when ``fit=False`` and the method knows its
        number of places (``n_places_``).
    Q : array-like of shape (n_queries, n_features)
        Query descriptors, one query per row.
    ground_truth : GroundTruth, array-like of int of shape (n_queries,), or None
        None means frame-aligned: the true place of query j is j.
    tolerances : iterable of int
        Tolerances (frames) for the recall points.
    ks : iterable of int
        K values for R@K (ranking methods). K larger than the map is left out.
    k_tolerance : int, default 0
        Tolerance applied to R@K.
    name : str, optional
        Name in reports; default the method's class name.
    curve_max : int, default 80
        The recall curve covers t = 0..curve_max.
    fit : bool, default True
        False evaluates an already fitted method (``fit_time_s`` is then None).

    Returns
    -------
    EvaluationResult
    """
    tolerances = _check_points(tolerances, "tolerances", 0)
    ks = tuple(ks)
    if ks:
        ks = _check_points(ks, "ks", 1)
    curve_max = check_positive_int(curve_max, "curve_max", minimum=0)
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
    gt = _ground_truth(ground_truth, n_queries, n_map)

    fit_time = None
    if fit:
        start = time.perf_counter()
        method.fit(X_map)
        fit_time = time.perf_counter() - start

    start = time.perf_counter()
    raw = method.predict(Q)
    query_time = (time.perf_counter() - start) / n_queries
    predictions = check_predictions(raw, n_queries, name=f"{type(method).__name__}.predict(Q)")

    ranked = None
    rank_time = None
    r_at_k = None
    if ks and getattr(method, "supports_ranking", callable(getattr(method, "rank", None))):
        k = ks[-1] if n_map is None else min(ks[-1], n_map)
        start = time.perf_counter()
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

    nbytes, breakdown = _storage_of(method)
    return EvaluationResult(
        name=name if name is not None else type(method).__name__,
        params=_params_of(method),
        n_map=int(n_map) if n_map is not None else None,
        n_queries=int(n_queries),
        recall=recall_at_tolerance(predictions, gt, tolerances),
        recall_curve=recall_curve(predictions, gt, curve_max),
        recall_at_k=r_at_k,
        nbytes=nbytes,
        storage_breakdown=breakdown,
        fit_time_s=fit_time,
        query_time_s_per_query=query_time,
        rank_time_s_per_query=rank_time,
        predictions=predictions,
        ranked=ranked,
        ground_truth=gt,
        tolerance_for_k=int(k_tolerance),
    )
