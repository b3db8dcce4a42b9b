"""Supervised feature selection by between-cluster sum of squares (the paper's feature selection).

For a classifier whose labels split the training points into clusters S_1..S_r, column j scores
``BCSS_j = TSS_j − WCSS_j = Σ_k n_k (μ_kj − μ_j)²`` (for two clusters ``n0·n1/N·(μ0_j − μ1_j)²``).
Witten & Tibshirani's sparse weights are ``w = S(a, Δ)/‖S(a, Δ)‖₂`` with ``a = BCSS``, ``S`` the
soft-threshold and Δ found by bisection so that ``‖w‖₁ ≤ s``. The classifier keeps the top d'
columns by weight, ties (including the zero weights below Δ) broken by BCSS — so the kept set
equals the top d' columns by BCSS for any s, and s only shapes the weights.

The paper uses s = 0.1, which lies outside W&T's valid range [1, √d] (a unit-L2 vector has
‖w‖₁ ≥ 1). For s < 1 the bisection ends at the sparsest solution (Δ just below max a). The
parameter is exposed and the result documented rather than silently changed.

Scores are computed on standardised columns (divided by the training standard deviation): the
classifiers see standardised data, so raw scale must not decide which columns they get.
"""

from __future__ import annotations

import numpy as np

from ..exceptions import InvalidParameterError

__all__ = ["between_cluster_ss", "between_cluster_ss_binary", "sparse_weights", "select_features",
           "select_features_many", "column_index_dtype"]


def column_index_dtype(n_columns: int) -> np.dtype:
    """Smallest unsigned dtype that holds column indices < ``n_columns`` (uint16 up to 65 536)."""
    return np.dtype(np.uint16) if n_columns <= 65536 else np.dtype(np.uint32)


def between_cluster_ss(
    X: np.ndarray,
    labels: np.ndarray,
    *,
    scale: np.ndarray | None = None,
    chunk_rows: int = 65536,
) -> np.ndarray:
    """Between-cluster sum of squares of every column.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features)
    labels : ndarray of shape (n_samples,), int
        Cluster of each row (any integers; 2 clusters for a bit, r for regions).
    scale : ndarray of shape (n_features,), optional
        Column standard deviations; the scores are those of ``X / scale``.
    chunk_rows : int
        Rows converted to float64 at a time (bounds the extra memory at ``chunk_rows × d``
        doubles; X may be memory-mapped).

    Returns
    -------
    bcss : ndarray of shape (n_features,), dtype float64
    """
    import scipy.sparse as sp  # fit-only: a loaded model never imports SciPy

    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    n = X.shape[0]
    # Cluster sums by a sparse one-hot product, over row chunks: the product upcasts X to float64,
    # and doing it at once held an N×d float64 copy (2 GB at N = 1M, d = 256) per concurrent fit.
    sums = np.zeros((counts.size, X.shape[1]))  # (n_clusters, n_features), float64
    for start in range(0, n, chunk_rows):
        stop = min(n, start + chunk_rows)
        onehot = sp.csr_matrix(
            (np.ones(stop - start), (inverse[start:stop], np.arange(stop - start))), shape=(counts.size, stop - start)
        )
        sums += onehot @ np.asarray(X[start:stop], dtype=np.float64)
    total = sums.sum(axis=0)
    # Σ_k n_k (μ_k − μ)² = Σ_k sums_k² / n_k − total² / n
    bcss = (sums**2 / counts[:, None]).sum(axis=0) - total**2 / n
    np.maximum(bcss, 0.0, out=bcss)  # rounding can give −1e-12
    if scale is not None:
        bcss /= np.asarray(scale, dtype=np.float64) ** 2
    return bcss


def between_cluster_ss_binary(
    X: np.ndarray,
    labels: np.ndarray,
    *,
    scale: np.ndarray | None = None,
    chunk_rows: int = 16384,
) -> np.ndarray:
    """BCSS of every column for K two-cluster labellings at once, in one pass over X.

    For cluster sums S₁ (label 1) and the total T: ``BCSS = S₁²/n₁ + (T − S₁)²/n₀ − T²/n``, the
    same as :func:`between_cluster_ss` for each column of ``labels``; all K sums S₁ come from one
    matrix product per row chunk, so X is read and converted to float64 once instead of K times.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features)
    labels : ndarray of shape (n_samples, K), values in {0, 1}
    scale : ndarray of shape (n_features,), optional
        Column standard deviations; the scores are those of ``X / scale``.

    Returns
    -------
    bcss : ndarray of shape (K, n_features), float64
    """
    Y = np.asarray(labels, dtype=np.float64).reshape(X.shape[0], -1)
    n, d = X.shape
    ones_sum = np.zeros((Y.shape[1], d))
    total = np.zeros(d)
    step = max(1, min(int(chunk_rows), (1 << 22) // max(d, 1)))
    for start in range(0, n, step):
        block = np.asarray(X[start : start + step], dtype=np.float64)
        ones_sum += Y[start : start + step].T @ block
        total += block.sum(axis=0)
    n1 = Y.sum(axis=0)[:, None]
    n0 = n - n1
    with np.errstate(divide="ignore", invalid="ignore"):
        bcss = np.where(n1 > 0, ones_sum**2 / np.maximum(n1, 1), 0.0) \
            + np.where(n0 > 0, (total - ones_sum) ** 2 / np.maximum(n0, 1), 0.0) - total**2 / n
    np.maximum(bcss, 0.0, out=bcss)  # rounding can give −1e-12
    if scale is not None:
        bcss /= np.asarray(scale, dtype=np.float64) ** 2
    return bcss


def _soft_threshold(a: np.ndarray, delta: float) -> np.ndarray:
    return np.maximum(a - delta, 0.0)


def sparse_weights(bcss: np.ndarray, sparsity: float, *, n_iter: int = 60) -> np.ndarray:
    """Witten–Tibshirani feature weights: unit L2 norm with ``‖w‖₁ ≤ s`` where reachable.

    Parameters
    ----------
    bcss : ndarray of shape (n_features,)
        Non-negative scores a.
    sparsity : float
        The L1 bound s (> 0). W&T's valid range is [1, √d]; below 1 the sparsest solution
        (the largest score alone, or the tied largest scores) is returned.
    n_iter : int
        Bisection steps on Δ.

    Returns
    -------
    w : ndarray of shape (n_features,), float64, non-negative, ‖w‖₂ = 1 (all zeros if a = 0)
    """
    if not sparsity > 0:
        raise InvalidParameterError(f"sparsity s must be > 0; got {sparsity!r}.")
    a = np.asarray(bcss, dtype=np.float64)
    top = a.max(initial=0.0)
    if top <= 0:
        return np.zeros_like(a)
    # w does not change when a is scaled; scaling to max 1 keeps a² from under/overflowing in the
    # norm (scores of 1e-200 or 1e200 gave NaN weights).
    a = a / top
    top = 1.0

    def normalised(delta: float) -> np.ndarray:
        w = _soft_threshold(a, delta)
        return w / np.linalg.norm(w)

    w = normalised(0.0)
    if w.sum() <= sparsity:
        return w
    lo, hi = 0.0, top
    for _ in range(n_iter):
        mid = 0.5 * (lo + hi)
        if mid >= top or normalised(mid).sum() <= sparsity:
            hi = mid
        else:
            lo = mid
    # hi satisfies the bound when it is reachable; when s < 1 it converges to just below max(a).
    return normalised(min(hi, np.nextafter(top, 0.0)))


def select_features(
    X: np.ndarray,
    labels: np.ndarray,
    n_features: int,
    *,
    sparsity: float = 0.1,
    scale: np.ndarray | None = None,
) -> np.ndarray:
    """Columns a classifier keeps: top ``n_features`` by W–T weight, ties broken by BCSS.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features_in)
    labels : ndarray of shape (n_samples,)
    n_features : int
        d', the number of columns kept (1 ≤ d' ≤ n_features_in).
    sparsity : float
        W–T L1 bound s.
    scale : ndarray of shape (n_features_in,), optional
        Column standard deviations (scores computed on standardised columns).

    Returns
    -------
    columns : ndarray of shape (n_features,), sorted ascending, dtype uint16 (uint32 when d > 65 536)
    """
    d = X.shape[1]
    if not 1 <= n_features <= d:
        raise InvalidParameterError(f"n_features must be in [1, {d}]; got {n_features}.")
    return _top_columns(between_cluster_ss(X, labels, scale=scale), n_features, sparsity)


def _top_columns(bcss: np.ndarray, n_features: int, sparsity: float) -> np.ndarray:
    """Top ``n_features`` columns by W–T weight, ties by BCSS, then by index; sorted ascending."""
    d = bcss.size
    weights = sparse_weights(bcss, sparsity)
    # lexsort: last key is primary. Descending weight, then descending BCSS, then lowest index.
    order = np.lexsort((np.arange(d), -bcss, -weights))
    return np.sort(order[:n_features]).astype(column_index_dtype(d))


def select_features_many(
    X: np.ndarray,
    labels: list[np.ndarray],
    n_features: int,
    *,
    sparsity: float = 0.1,
    scale: np.ndarray | None = None,
) -> list[np.ndarray]:
    """:func:`select_features` for several labellings of the same rows, in one pass over X.

    Two-cluster labellings (the bits of BTE-C) share one product per row chunk
    (:func:`between_cluster_ss_binary`); others are scored one by one.

    Returns
    -------
    list of ndarray of shape (n_features,), one per labelling (as :func:`select_features`)
    """
    d = X.shape[1]
    if not 1 <= n_features <= d:
        raise InvalidParameterError(f"n_features must be in [1, {d}]; got {n_features}.")
    out: list[np.ndarray | None] = [None] * len(labels)
    binary = []
    for i, y in enumerate(labels):
        values = np.unique(y)
        if values.size <= 2:
            binary.append((i, (np.asarray(y) == values[-1]).astype(np.int8)))
        else:
            out[i] = select_features(X, y, n_features, sparsity=sparsity, scale=scale)
    if binary:
        bcss = between_cluster_ss_binary(X, np.stack([y for _, y in binary], axis=1), scale=scale)
        for (i, _), scores in zip(binary, bcss):
            out[i] = _top_columns(scores, n_features, sparsity)
    return out  # type: ignore[return-value]
