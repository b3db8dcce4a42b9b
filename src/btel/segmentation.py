"""Splitting a traverse into contiguous regions: Kernel Temporal Segmentation (SPEC §5).

KTS (Potapov et al. 2014) with a linear kernel on L2-normalised descriptors minimises the
within-segment scatter over r−1 change points by dynamic programming; ``ruptures.KernelCPD
(kernel="linear")`` solves exactly that problem, and one call yields the optimal segmentations
for every count up to the maximum. Descriptors are reduced to at most 128 dimensions by PCA first
(allowed by SPEC §5): the DP costs O(n²·r) kernel evaluations and the reduction keeps them cheap.

Automatic r uses the KTS penalty over the DP costs V_m (m change points, n frames):
``cost_m = V_m/n + v·m/(2n)·(log(n/m) + 1)`` — not ruptures' ``pen=`` (which is a plain
linear penalty for PELT).
"""

from __future__ import annotations

import numpy as np
import ruptures as rpt
from sklearn.decomposition import PCA

from ._validation import check_positive_int
from .exceptions import NotEnoughPlacesError

__all__ = ["kts_regions", "kts_segmentations", "kts_auto_regions", "kts_penalised_costs", "region_of", "MIN_REGION_LENGTH"]

#: Shortest region KTS may produce (SPEC §5); a region needs ≥ 2 places for a 1-bit code.
MIN_REGION_LENGTH = 2


def _prepare(X: np.ndarray, pca_dims: int | None, random_state: int | None) -> np.ndarray:
    Z = np.asarray(X, dtype=np.float64)
    Z = Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1e-12)
    if pca_dims is not None and Z.shape[1] > pca_dims and Z.shape[0] > pca_dims:
        Z = PCA(n_components=pca_dims, svd_solver="randomized", random_state=random_state).fit_transform(Z)
    return np.ascontiguousarray(Z)


def _check_count(n: int, n_regions: int) -> None:
    if n_regions * MIN_REGION_LENGTH > n:
        raise NotEnoughPlacesError(
            f"cannot split {n} places into {n_regions} regions of at least {MIN_REGION_LENGTH} places; "
            f"use n_regions ≤ {n // MIN_REGION_LENGTH}."
        )


def _starts_from_breakpoints(bkps: list[int]) -> np.ndarray:
    return np.asarray([0] + list(bkps[:-1]), dtype=np.int64)


def kts_regions(
    X: np.ndarray,
    n_regions: int,
    *,
    pca_dims: int | None = 128,
    random_state: int | None = None,
) -> np.ndarray:
    """Split a traverse into ``n_regions`` contiguous regions with KTS (linear kernel).

    Parameters
    ----------
    X : ndarray of shape (n_places, n_features)
        One descriptor per place, in route order.
    n_regions : int
        r ≥ 1.
    pca_dims : int or None
        Reduce to this many dimensions first (None: no reduction).

    Returns
    -------
    starts : ndarray of shape (n_regions,), int64
        First place of each region; ``starts[0] == 0``, strictly increasing, every region ≥ 2 long.
    """
    r = check_positive_int(n_regions, "n_regions")
    n = X.shape[0]
    _check_count(n, r)
    if r == 1:
        return np.zeros(1, dtype=np.int64)
    Z = _prepare(X, pca_dims, random_state)
    algo = rpt.KernelCPD(kernel="linear", min_size=MIN_REGION_LENGTH).fit(Z)
    return _starts_from_breakpoints(algo.predict(n_bkps=r - 1))


def kts_penalised_costs(costs: np.ndarray, n: int, v: float) -> np.ndarray:
    """KTS objective for m = 0..len(costs)−1 change points: ``V_m/n + v·m/(2n)·(log(n/m) + 1)``."""
    m = np.arange(len(costs), dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        penalty = np.where(m > 0, v * m / (2.0 * n) * (np.log(n / np.maximum(m, 1)) + 1.0), 0.0)
    return np.asarray(costs, dtype=np.float64) / n + penalty


def kts_segmentations(
    X: np.ndarray,
    max_regions: int,
    *,
    pca_dims: int | None = 128,
    random_state: int | None = None,
) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """Optimal KTS segmentations for every r = 1 … max_regions, from one dynamic programme.

    Returns
    -------
    starts_by_r : dict of int to ndarray
        r → region starts (int64, shape (r,)).
    costs : ndarray of shape (max_regions,), float64
        ``costs[m]`` = V_m, the within-segment scatter with m = r − 1 change points.
    """
    n = X.shape[0]
    max_r = min(check_positive_int(max_regions, "max_regions"), n // MIN_REGION_LENGTH)
    if max_r < 2:
        return {1: np.zeros(1, dtype=np.int64)}, np.zeros(1)
    Z = _prepare(X, pca_dims, random_state)
    algo = rpt.KernelCPD(kernel="linear", min_size=MIN_REGION_LENGTH).fit(Z)
    algo.predict(n_bkps=max_r - 1)  # fills the segmentations for every m ≤ max_r − 1
    bkps = {0: [n], **algo.segmentations_dict}
    costs = np.array([algo.cost.sum_of_costs(bkps[m]) for m in range(max_r)])
    return {m + 1: _starts_from_breakpoints(bkps[m]) for m in range(max_r)}, costs


def kts_auto_regions(
    X: np.ndarray,
    *,
    max_regions: int = 50,
    penalty: float = 1.0,
    pca_dims: int | None = 128,
    random_state: int | None = None,
) -> np.ndarray:
    """Choose r automatically with the KTS penalty and split the traverse.

    Parameters
    ----------
    X : ndarray of shape (n_places, n_features)
    max_regions : int
        Largest r considered (capped at n_places // 2).
    penalty : float
        v in the KTS penalty; larger → fewer regions.

    Returns
    -------
    starts : ndarray of shape (r,), int64
    """
    starts_by_r, costs = kts_segmentations(X, max_regions, pca_dims=pca_dims, random_state=random_state)
    best_m = int(np.argmin(kts_penalised_costs(costs, X.shape[0], penalty)))
    return starts_by_r[best_m + 1]


def region_of(places: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Region index of each place given the region starts (int64, same shape as ``places``)."""
    return (np.searchsorted(np.asarray(starts), places, side="right") - 1).astype(np.int64)
