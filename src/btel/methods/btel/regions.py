"""BTEL's regions (the paper's regions): where the route is split (KTS) and which region a query is in.

The route is split into r contiguous regions by Kernel Temporal Segmentation
(:mod:`btel.methods.btel.segmentation`), r fixed or chosen by the KTS penalty (lowered while no model fits the
budget); each region gets its own tree and a linear region classifier picks the region of a query
(one hyperplane for r = 2, one-vs-rest for r > 2).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .segmentation import kts_penalised_costs, kts_regions, kts_segmentations

__all__ = ["per_code_descriptors", "segment_route", "predict_regions"]


def per_code_descriptors(X: np.ndarray, codes: np.ndarray, n_codes: int) -> np.ndarray:
    """One descriptor per code in route order: X itself, or the mean of a code's rows (several rows each).

    Returns
    -------
    ndarray of shape (n_codes, n_features)
    """
    if codes.size == n_codes and np.array_equal(codes, np.arange(n_codes)):
        return X
    counts = np.bincount(codes, minlength=n_codes)
    means = np.zeros((n_codes, X.shape[1]))
    np.add.at(means, codes, X)
    return means / counts[:, None]


def segment_route(
    X: np.ndarray,
    codes: np.ndarray,
    n_codes: int,
    n_regions: int | str,
    *,
    max_regions: int,
    penalty: float,
    pca_dims: int | None,
    random_state: int | None,
    max_points: int,
    fits: Callable[[list[int]], bool] | None = None,
) -> np.ndarray:
    """Region starts (int64, shape (r,)) over ``n_codes`` codes.

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    codes : ndarray of shape (n_rows,), int64
        Code (place or block) of each row.
    n_regions : int or 'auto'
        r; 'auto' picks it by the KTS penalty ``penalty`` among 1 … ``max_regions``.
    fits : callable, optional
        With 'auto': ``fits(region_sizes)`` says whether some model fits the budget; r is lowered
        until it does.
    """
    if n_regions == 1:
        return np.zeros(1, dtype=np.int64)
    # KTS runs on one descriptor per code, in route order.
    per_code = per_code_descriptors(X, codes, n_codes)
    if n_regions != "auto":
        return kts_regions(per_code, int(n_regions), pca_dims=pca_dims, random_state=random_state,
                           max_points=max_points)
    starts_by_r, costs = kts_segmentations(per_code, int(max_regions), pca_dims=pca_dims,
                                           random_state=random_state, max_points=max_points)
    r = int(np.argmin(kts_penalised_costs(costs, n_codes, float(penalty)))) + 1
    if fits is not None:
        while r > 1 and not fits(list(np.diff(np.append(starts_by_r[r], n_codes)))):
            r -= 1
    return starts_by_r[r]


def predict_regions(region_scores: np.ndarray | None, n_regions: int, n_queries: int) -> np.ndarray:
    """Region of each query: the sign of the one hyperplane for r = 2, the argmax for r > 2 (int64)."""
    if n_regions == 1 or region_scores is None:
        return np.zeros(n_queries, dtype=np.int64)
    if n_regions == 2:
        return (region_scores[:, 0] > 0).astype(np.int64)
    return np.argmax(region_scores, axis=1).astype(np.int64)
