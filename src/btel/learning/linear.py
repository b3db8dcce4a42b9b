"""Linear classifiers on selected, standardised columns, with the scaling folded in (the paper's training schemes).

Descriptors are standardised with training statistics (μ, σ) before a classifier is trained,
and the scaling is folded into the hyperplane so it costs no storage:
``w' = w/σ`` and ``c' = c − Σ w'·μ``. The bias is computed from the *stored* (possibly float16)
weights, so rounding the weights does not shift the decision boundary by ``Σ (w' − w16)·μ``.

Classifiers that read the same rows and columns are solved together on one standardised copy
(:func:`fit_linear_group`), by the solvers of :mod:`btel.learning.solvers`; the fitted stack is
stored and evaluated as :class:`btel.learning.hyperplanes.Hyperplanes`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..exceptions import InvalidParameterError
from .solvers import choose_solver, solve_linear

__all__ = ["ColumnStats", "fit_linear", "fit_linear_group", "standardised_columns", "default_C"]


def default_C(classifier: str) -> float:
    """C when the user gives none: 1.0 for the SVM, 4.0 for logistic (as in the BTEL authors' code)."""
    return 4.0 if classifier == "logistic" else 1.0


@dataclass(frozen=True)
class ColumnStats:
    """Training mean and standard deviation of every column (float64, shape (d,))."""

    mean: np.ndarray
    scale: np.ndarray

    @classmethod
    def of(cls, X: np.ndarray, chunk_rows: int = 65536) -> "ColumnStats":
        """Column statistics of X, accumulated in float64 over row chunks (memory-mapped X is fine)."""
        n, d = X.shape
        total = np.zeros(d)
        total_sq = np.zeros(d)
        # Row chunks of at most ~4M values (as standardised_columns): at d = 16,384 a chunk of 65,536 rows
        # would be the whole map in float64 and again its squares, 4 times a float32 map of 10⁴ rows.
        step = max(1, min(int(chunk_rows), (1 << 22) // max(d, 1)))
        for start in range(0, n, step):
            block = np.asarray(X[start : start + step], dtype=np.float64)
            total += block.sum(axis=0)
            block *= block
            total_sq += block.sum(axis=0)
            del block  # before the next chunk is read, not after: one chunk alive at a time
        mean = total / n
        var = np.maximum(total_sq / n - mean**2, 0.0)
        scale = np.sqrt(var)
        # A constant column carries no information; σ = 1 keeps it finite (its BCSS is 0, so it is
        # only ever selected when d' exceeds the number of informative columns). The floor is relative
        # to the map's own spread, so a map scaled by 1e-30 is standardised like the map itself.
        typical = float(np.median(scale)) or float(scale.max(initial=0.0))
        scale[scale < (1e-6 * typical if typical > 0 else np.inf)] = 1.0
        return cls(mean=mean, scale=scale)


def standardised_columns(
    X: np.ndarray, cols: np.ndarray, mean: np.ndarray, scale: np.ndarray, *, chunk_rows: int = 65536,
    dtype: np.dtype = np.dtype(np.float64),
) -> np.ndarray:
    """``(X[:, cols] − mean) / scale`` as a new array (float64 by default), built in row chunks.

    The one (n, d') float64 array liblinear needs is the only large allocation: gathering,
    converting and standardising the whole block at once would hold three such arrays
    (1.3 GB at N = 1M, d' = 64) per concurrent fit. X may be memory-mapped.
    """
    n = X.shape[0]
    out = np.empty((n, cols.size), dtype=dtype)
    full = cols.size == X.shape[1] and np.array_equal(cols, np.arange(X.shape[1]))
    # Row chunks of at most ~4M values: the float64 temporaries stay at 32 MB per chunk.
    step = max(1, min(int(chunk_rows), (1 << 22) // max(cols.size, 1)))
    for start in range(0, n, step):
        rows = X[start : start + step]
        block = np.array(rows if full else rows[:, cols], dtype=np.float64)
        block -= mean
        block /= scale
        out[start : start + step] = block
    return out



def _label_columns(labels: np.ndarray) -> np.ndarray:
    """{0,1} columns of one classifier's labels: one for two classes (positive = the larger), else one-vs-rest."""
    classes = np.unique(labels)
    if classes.size < 2:
        raise InvalidParameterError("a classifier needs rows of at least two classes.")
    if classes.size == 2:
        return (labels == classes[1]).astype(np.int8)[:, None]
    return (labels[:, None] == classes[None, :]).astype(np.int8)


def fit_linear_group(
    X: np.ndarray,
    labels: list[np.ndarray],
    columns: np.ndarray,
    stats: ColumnStats,
    *,
    classifier: str = "svm",
    C: float = 1.0,
    solver: str = "auto",
    max_iter: int | None = None,
    random_state: int | None = None,
    dtype: np.dtype = np.dtype(np.float32),
    sample_weight: list[np.ndarray | None] | None = None,
) -> list[tuple[np.ndarray, np.ndarray, int, int, float]]:
    """Several classifiers on the same rows and columns: one standardised copy, one solve.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features_in)
    labels : list of ndarray of shape (n_samples,), int
        One entry per classifier (two classes → one hyperplane, more → one-vs-rest hyperplanes).
    columns : ndarray of shape (d',), int
    sample_weight : list of (ndarray of shape (n_samples,) or None), optional

    Returns
    -------
    list of (weights (k, d') ``dtype`` with the scaling folded in, bias (k,) float32, hyperplanes
    that stopped at the cap, iterations, objective), one per entry of ``labels``.
    """
    cols = np.asarray(columns, dtype=np.intp)
    mu = stats.mean[cols]
    sigma = stats.scale[cols]
    n_classifiers = sum(1 if np.unique(y).size <= 2 else np.unique(y).size for y in labels)
    name = choose_solver(solver, X.shape[0], cols.size, n_classifiers)
    Xs = standardised_columns(X, cols, mu, sigma, dtype=np.dtype(np.float32 if name == "lbfgs" else np.float64))
    blocks = [_label_columns(np.asarray(y)) for y in labels]
    widths = [blk.shape[1] for blk in blocks]
    Y = np.concatenate(blocks, axis=1)
    weights = None
    if sample_weight is not None and any(w is not None for w in sample_weight):
        per_column = []
        for w, width in zip(sample_weight, widths):
            row_weights = np.ones(X.shape[0]) if w is None else np.asarray(w, dtype=np.float64)
            per_column.append(np.repeat(row_weights[:, None], width, axis=1))
        weights = np.concatenate(per_column, axis=1)
    solution = solve_linear(Xs, Y, C=C, classifier=classifier, solver=name, sample_weight=weights,
                            max_iter=max_iter, random_state=random_state)
    del Xs
    out = []
    first = 0
    for width in widths:
        part = slice(first, first + width)
        first += width
        # Bias from the stored weights: c' = c − Σ w_stored·μ. Weights past the stored type's range (a map
        # of tiny values without normalisation) become inf or NaN here; check_fitted_weights names that after.
        with np.errstate(over="ignore", invalid="ignore"):
            w = (solution.coef[part] / sigma).astype(dtype)
            bias = (solution.intercept[part] - w.astype(np.float64) @ mu).astype(np.float32)
        out.append((w, np.atleast_1d(bias), int((~solution.converged[part]).sum()),
                    int(solution.n_iter[part].max()), float(solution.objective[part].sum())))
    return out


def fit_linear(
    X: np.ndarray,
    labels: np.ndarray,
    columns: np.ndarray,
    stats: ColumnStats,
    *,
    classifier: str = "svm",
    C: float = 1.0,
    solver: str = "auto",
    max_iter: int | None = None,
    random_state: int | None = None,
    dtype: np.dtype = np.dtype(np.float32),
    sample_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Train one (binary or one-vs-rest) linear classifier on ``X[:, columns]``, standardised.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features_in)
    labels : ndarray of shape (n_samples,), int
        Two classes give one hyperplane (positive margin = the larger label); more give one per
        class (one-vs-rest), in sorted class order.
    columns : ndarray of shape (d',), int
    stats : ColumnStats
        Training statistics of all n_features_in columns.
    solver : {'auto', 'newton', 'lbfgs', 'liblinear'}
        See the module docstring.
    max_iter : int, optional
        Iteration cap (None: the solver's default, :func:`default_max_iter`).
    dtype : numpy dtype
        Stored weight dtype (float32 or float16).
    sample_weight : ndarray of shape (n_samples,), optional
        Per-row weight in the loss (multi-exemplar training).

    Returns
    -------
    weights : ndarray of shape (n_hyperplanes, d'), dtype ``dtype`` — scaling folded in
    bias : ndarray of shape (n_hyperplanes,), float32
    converged : bool
        False when the solver stopped at its iteration cap.
    """
    w, b, unconverged, _, _ = fit_linear_group(
        X, [labels], columns, stats, classifier=classifier, C=C, solver=solver, max_iter=max_iter,
        random_state=random_state, dtype=dtype, sample_weight=[sample_weight])[0]
    return w, b, unconverged == 0
