"""Metrics as plain functions of arrays: recall at a tolerance, R@K, precision–recall (docs/guide/concepts.md).

Queries are rows: query j is row j of the predictions and of a ranking. Ground truth defaults to
frame-aligned traverses (the true place of query j is j); pass a
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
- **AUC-PR** — area under the precision–recall curve of accepting each query's top-1 match by
  its score, in two versions named by the code they reproduce: ``auc_pr_vpr_bench`` (VPR-Bench:
  recall over the correct top-1 matches) and ``auc_pr_vpr_tutorial`` (VPR_Tutorial: recall over
  the queries with a true place); :func:`precision_recall` gives both and the curve, one point
  per distinct score.

Nothing here fits, times or writes anything: :mod:`btel.evaluation` is the harness that does.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ..core.validation import check_positive_int
from ..datasets.groundtruth import GroundTruth
from ..exceptions import InvalidParameterError

__all__ = [
    "DEFAULT_TOLERANCES",
    "DEFAULT_KS",
    "TABLE_KS",
    "PR_CURVE_POINTS",
    "TruthLike",
    "check_ground_truth",
    "default_tolerances",
    "default_ks",
    "default_curve_max",
    "check_points",
    "recall_at_tolerance",
    "recall_curve",
    "recall_at_k",
    "precision_recall",
    "thin_curve",
    "VPR_TUTORIAL_THRESHOLDS",
]

#: Tolerances (frames) at which recall is reported (the evaluation protocol of docs/guide/concepts.md).
DEFAULT_TOLERANCES: tuple[int, ...] = (0, 1, 2, 5, 10, 20)
#: K values for R@K (the evaluation protocol of docs/guide/concepts.md).
DEFAULT_KS: tuple[int, ...] = (1, 5, 10, 20)
#: K values printed by default (R@20 stays in the files when asked for with ``ks``).
TABLE_KS: tuple[int, ...] = (1, 5, 10)

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
    true_places : GroundTruth, array-like of int of shape (n_queries,), list of lists, or None
        None means frame-aligned (query j ↔ place j); a list holding one list (or array) of map
        places per query gives explicit positives (:meth:`GroundTruth.from_positives`).
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
    elif isinstance(true_places, (list, tuple)) and true_places and all(
            isinstance(p, (list, tuple, range, np.ndarray)) for p in true_places):
        gt = GroundTruth.from_positives(true_places, n_map=n_map)  # one list of map places per query
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


def check_points(values: Iterable[Any], name: str, minimum: int) -> tuple[int, ...]:
    """Tolerances or K values checked (ints ≥ ``minimum``, at least one), sorted, without repeats."""
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
    gt = check_ground_truth(true_places, pred.shape[0])
    return {t: float(gt.is_correct(pred, t).mean()) for t in check_points(tolerances, "tolerances", 0)}


def recall_curve(predictions: Any, true_places: TruthLike = None, max_tolerance: int = 80) -> np.ndarray:
    """Recall at every tolerance t = 0, 1, …, ``max_tolerance``.

    Returns
    -------
    curve : ndarray of shape (max_tolerance + 1,), dtype float64
        ``curve[t]`` = recall at tolerance t (non-decreasing).
    """
    t_max = check_positive_int(max_tolerance, "max_tolerance", minimum=0)
    pred = _predictions_1d(predictions)
    gt = check_ground_truth(true_places, pred.shape[0])
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
    points = check_points(ks, "ks", 1)
    if points[-1] > arr.shape[1]:
        raise InvalidParameterError(
            f"R@{points[-1]} needs at least {points[-1]} ranked candidates per query; ranked has {arr.shape[1]}. "
            f"Call rank(Q, k={points[-1]}) or lower ks."
        )
    gt = check_ground_truth(true_places, arr.shape[0])
    found = np.logical_or.accumulate(gt.rank_correct(arr, tolerance), axis=1)
    return {k: float(found[:, k - 1].mean()) for k in points}


# -- precision–recall from the best-match score (VPR-Bench, VPR_Tutorial) ----------------------------
#: Points kept of a PR curve in results (the curve is drawn from them; the AUCs use every point).
PR_CURVE_POINTS = 256
#: Thresholds of VPR_Tutorial's ``createPR`` (its ``n_thresh`` default).
VPR_TUTORIAL_THRESHOLDS = 100


def _comparable_scores(best_scores: Any, correct: Any) -> tuple[np.ndarray, np.ndarray]:
    """Scores as finite float64 (NaN and −inf least confident, +inf most) and correctness as bool."""
    scores = np.asarray(best_scores, dtype=np.float64).reshape(-1)
    hits = np.asarray(correct, dtype=bool).reshape(-1)
    if scores.shape != hits.shape or scores.size == 0:
        raise InvalidParameterError(f"best_scores and correct must be 1-D of one length ≥ 1; got "
                                    f"{scores.shape} and {hits.shape}.")
    finite = np.isfinite(scores)
    low, high = (scores[finite].min() - 1.0, scores[finite].max() + 1.0) if finite.any() else (0.0, 0.0)
    return np.clip(np.nan_to_num(scores, nan=low, neginf=low, posinf=high), low, high), hits


def _vpr_tutorial_auc(scores: np.ndarray, hits: np.ndarray, n_relevant: int,
                      n_thresh: int = VPR_TUTORIAL_THRESHOLDS) -> float:
    """VPR_Tutorial's AUC: ``n_thresh`` evenly spaced thresholds from the highest score to the
    lowest, the point (recall 0, precision 1) first, trapezoids between the points."""
    descending = np.sort(scores)[::-1]
    true_so_far = np.cumsum(hits[np.argsort(-scores, kind="stable")])
    thresholds = np.linspace(descending[0], descending[-1], n_thresh)
    accepted = scores.size - np.searchsorted(descending[::-1], thresholds, side="left")  # score ≥ threshold
    true_accepted = true_so_far[accepted - 1]
    precision = np.concatenate([[1.0], true_accepted / accepted])
    recall = np.concatenate([[0.0], true_accepted / n_relevant])
    return float(np.trapezoid(precision, recall))


def precision_recall(best_scores: Any, correct: Any, *, n_relevant: int | None = None) -> dict[str, Any]:
    """Precision–recall of accepting a query's top-1 match when its score passes a threshold.

    Each query has one best match and its score (higher = more confident). A threshold accepts
    the matches scored at or above it; precision = correct accepted / accepted. The curve has one
    point per *distinct* score (tied scores enter together: constant scores give one point), so it
    cannot show a precision no threshold reaches. Only the order of one method's scores matters.

    Two areas under the curve, each as its source's code computes it (they differ by a large
    factor on the same matches, so compare a figure only with its own source's tables):

    - ``auc_pr_vpr_bench`` — VPR-Bench (Zaffar et al. 2021, ``performance_comparison.py`` in
      github.com/MubarizZaffar/VPR-Bench): sklearn's ``precision_recall_curve`` over the top-1
      correctness and the scores, so recall = correct accepted / *correct top-1 matches* (it
      reaches 1 whatever R@1 is), then trapezoidal ``auc``. 0 when no top-1 match is correct
      (VPR-Bench's code gives NaN there).
    - ``auc_pr_vpr_tutorial`` — VPR_Tutorial (Schubert et al. 2023, ``evaluation/metrics.py``
      ``createPR`` with single-best-match and ``demo.py`` in github.com/stschubert/VPR_Tutorial):
      recall = correct accepted / *queries with a true place in the map* (at most R@1),
      :data:`VPR_TUTORIAL_THRESHOLDS` evenly spaced thresholds, (0, 1) prepended, trapezoids.

    The returned curve and ``recall_at_100_precision`` use VPR_Tutorial's recall, over every
    distinct threshold.

    Parameters
    ----------
    best_scores : array-like of float, shape (n_queries,)
        Score of each query's best match (``search(Q, 1)[0][:, 0]``). NaN counts as least confident.
    correct : array-like of bool, shape (n_queries,)
        Whether that best match is a true place.
    n_relevant : int, optional
        Queries that have a true place in the map (default: all of them).

    Returns
    -------
    dict
        ``precision``, ``recall``, ``thresholds`` (float64 ndarrays, one point per distinct score,
        highest threshold first, so recall is non-decreasing), ``auc_pr_vpr_bench``,
        ``auc_pr_vpr_tutorial`` and ``recall_at_100_precision`` (the largest recall of a point
        with no false match accepted; 0 when the most confident match is wrong).
    """
    scores, hits = _comparable_scores(best_scores, correct)
    if n_relevant is None:
        n_relevant = scores.size
    n_relevant = check_positive_int(n_relevant, "n_relevant", minimum=1)
    n_correct = int(hits.sum())
    if n_correct > n_relevant:
        raise InvalidParameterError(f"{n_correct} top-1 matches are correct but n_relevant={n_relevant}: "
                                    "only queries with a true place can be matched correctly.")
    order = np.argsort(-scores, kind="stable")
    ranked = scores[order]
    last = np.flatnonzero(np.r_[ranked[1:] != ranked[:-1], True])  # the last index of each distinct score
    true_accepted = np.cumsum(hits[order])[last]
    precision = true_accepted / (last + 1.0)
    recall = true_accepted / n_relevant
    perfect = recall[precision >= 1.0]
    if n_correct:
        # sklearn's curve: these points with recall over the correct matches, then (recall 0, precision 1).
        bench = float(np.trapezoid(np.r_[1.0, precision], np.r_[0.0, true_accepted / n_correct]))
    else:
        bench = 0.0
    return {"precision": precision, "recall": recall, "thresholds": ranked[last], "auc_pr_vpr_bench": bench,
            "auc_pr_vpr_tutorial": _vpr_tutorial_auc(scores, hits, n_relevant),
            "recall_at_100_precision": float(perfect.max()) if perfect.size else 0.0}


def thin_curve(precision: np.ndarray, recall: np.ndarray,
               n: int = PR_CURVE_POINTS) -> tuple[list[float], list[float]]:
    """At most ``n`` points of a PR curve, evenly spaced along it.

    The first and last points are kept, and so is the last point at precision 1 (the recall at
    100 % precision), so the thinned curve shows the same R@100%P as the full one.
    """
    precision, recall = np.asarray(precision, dtype=np.float64), np.asarray(recall, dtype=np.float64)
    keep = np.linspace(0, precision.size - 1, max(2, min(n, precision.size))).round().astype(int)
    perfect = np.flatnonzero(precision >= 1.0)
    keep = np.unique(np.r_[keep, perfect[-1:]]) if precision.size > 1 else np.zeros(1, dtype=int)
    return [float(v) for v in precision[keep]], [float(v) for v in recall[keep]]
