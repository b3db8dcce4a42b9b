"""The k best columns of a score matrix, and putting a known answer first: how every method ranks."""

from __future__ import annotations

import numpy as np

__all__ = ["top_k", "put_first", "ties_by_place", "as_answered"]


def top_k(scores: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k highest scores per row and their columns, best first (ties: lowest column first).

    Returns
    -------
    values : ndarray of shape (n, k), float64
    columns : ndarray of shape (n, k), int64
    """
    n_cols = scores.shape[1]
    if k == 1 and n_cols:  # one pass: argmax returns the first (lowest) column of the maximum
        best = np.argmax(scores, axis=1)[:, None]
        values = np.take_along_axis(scores, best, axis=1)
        if not np.isnan(values).any():  # argmax takes NaN for the maximum; the general path ranks it last
            return values.astype(np.float64), best.astype(np.int64)
    if k < n_cols:
        part = np.argpartition(-scores, k - 1, axis=1)[:, :k]
        # argpartition keeps an arbitrary k of the columns tied at the k-th score: where more tie than fit, the
        # row is ranked whole by (score, column), so the lowest tied columns are kept (as argmax and k = 1 do).
        kth = np.take_along_axis(scores, part, axis=1).min(axis=1)
        crowded = np.flatnonzero(np.count_nonzero(scores >= kth[:, None], axis=1) > k)
        for i in crowded:
            part[i] = np.lexsort((np.arange(n_cols), -scores[i]))[:k]
    else:
        part = np.broadcast_to(np.arange(n_cols), scores.shape).copy()
    values = np.take_along_axis(scores, part, axis=1)
    order = np.lexsort((part, -values), axis=1)
    columns = np.take_along_axis(part, order, axis=1).astype(np.int64)
    return np.take_along_axis(values, order, axis=1).astype(np.float64), columns


def put_first(scores: np.ndarray, places: np.ndarray, first_scores: np.ndarray,
              first_places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A ranking that starts with a method's point decode, then its other candidates in order.

    For decoders whose answer is not simply the best-scoring place (BTEL's constrained decode,
    RYTH's Chinese remainder theorem), so that ``rank(Q, k)[:, 0] == predict(Q)`` and R@1 is the
    recall of the point prediction. The point is dropped from later in the list (no duplicates).

    Parameters
    ----------
    scores, places : ndarray of shape (n, k)
    first_scores, first_places : ndarray of shape (n,)

    Returns
    -------
    scores, places : ndarray of shape (n, k)
    """
    k = places.shape[1]
    others = places != first_places[:, None]
    # The first k − 1 candidates that are not the point, in their order (stable sort of the mask).
    keep = np.argsort(~others, axis=1, kind="stable")[:, : k - 1]
    out_places = np.concatenate([first_places[:, None], np.take_along_axis(places, keep, axis=1)], axis=1)
    out_scores = np.concatenate([first_scores[:, None], np.take_along_axis(scores, keep, axis=1)], axis=1)
    return out_scores, out_places


def ties_by_place(scores: np.ndarray, places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Candidates with equal scores put in increasing place order within each row, as :func:`top_k` and
    ``argmax`` order them: faiss' heaps return tied candidates in no set order, so without this a map
    with two identical rows would answer one place from ``predict`` and put the other first in ``search``.

    Parameters
    ----------
    scores : ndarray of shape (n, k), best first
    places : ndarray of shape (n, k), int64

    Returns
    -------
    scores, places : the same arrays where no row holds a tie, else reordered copies
    """
    if scores.ndim != 2 or scores.shape[1] < 2 or not (scores[:, 1:] == scores[:, :-1]).any():
        return scores, places
    order = np.lexsort((places, -scores), axis=1)
    return np.take_along_axis(scores, order, axis=1), np.take_along_axis(places, order, axis=1)


def as_answered(scores: np.ndarray, places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A method's raw ``(scores, places)`` as ``search`` returns them, in a batch or a stream: ties in place
    order (:func:`ties_by_place`) and no −0 score (a negated zero distance is 0; numpy prints −0 as "-0.")."""
    scores, places = ties_by_place(scores, places)
    return scores + 0.0, places
