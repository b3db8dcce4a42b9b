"""Linear classifiers on selected, standardised columns, with the scaling folded in (SPEC §3).

Descriptors are standardised with training statistics (μ, σ) before a classifier is trained,
and the scaling is folded into the hyperplane so it costs no storage:
``w' = w/σ`` and ``c' = c − Σ w'·μ``. The bias is computed from the *stored* (possibly float16)
weights, so rounding the weights does not shift the decision boundary by ``Σ (w' − w16)·μ``.

:class:`Hyperplanes` is a stack of K such classifiers, each on its own d' columns; it computes
all K margins of a batch of queries with one matrix product.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from sklearn.svm import LinearSVC

from .exceptions import InvalidParameterError, ModelFileError

__all__ = ["ColumnStats", "fit_linear", "standardised_columns", "Hyperplanes", "CLASSIFIERS", "default_C"]

CLASSIFIERS = ("svm", "logistic")


def default_C(classifier: str) -> float:
    """C when the user gives none: 1.0 for the SVM, 4.0 for logistic (the authors' earlier code)."""
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
        for start in range(0, n, chunk_rows):
            block = np.asarray(X[start : start + chunk_rows], dtype=np.float64)
            total += block.sum(axis=0)
            total_sq += (block**2).sum(axis=0)
        mean = total / n
        var = np.maximum(total_sq / n - mean**2, 0.0)
        scale = np.sqrt(var)
        # A constant column carries no information; σ = 1 keeps it finite (its BCSS is 0, so it is
        # only ever selected when d' exceeds the number of informative columns).
        floor = 1e-6 * max(float(np.median(scale)), 1e-12)
        scale[scale < floor] = 1.0
        return cls(mean=mean, scale=scale)


def standardised_columns(
    X: np.ndarray, cols: np.ndarray, mean: np.ndarray, scale: np.ndarray, *, chunk_rows: int = 65536
) -> np.ndarray:
    """``(X[:, cols] − mean) / scale`` as a new float64 array, built in row chunks.

    The one (n, d') float64 array liblinear needs is the only large allocation: gathering,
    converting and standardising the whole block at once held three such arrays
    (1.3 GB at N = 1M, d' = 64) per concurrent fit. X may be memory-mapped.
    """
    n = X.shape[0]
    out = np.empty((n, cols.size), dtype=np.float64)
    for start in range(0, n, chunk_rows):
        block = out[start : start + chunk_rows]
        block[...] = X[start : start + chunk_rows][:, cols]
        block -= mean
        block /= scale
    return out


def _use_dual(n_samples: int, n_features: int) -> bool:
    """liblinear's dual solver unless there are at least 3 samples per feature.

    scikit-learn's ``dual="auto"`` switches at n_samples = n_features; on standardised HOG
    (n = 3576) the primal Newton solver took 40–50 s per fit at d' ≈ 1800–2300 against 4–6 s for
    the dual, while at d' ≤ n/3 the primal was 2–8× faster (measured per bit and one-vs-rest task).
    """
    return n_samples < 3 * n_features


def _make_classifier(classifier: str, C: float, max_iter: int, random_state: int | None, dual: bool):
    if classifier == "svm":
        return LinearSVC(C=C, loss="squared_hinge", dual=dual, max_iter=max_iter, random_state=random_state)
    if classifier == "logistic":
        return LogisticRegression(C=C, solver="liblinear", tol=0.01, dual=dual, max_iter=max_iter,
                                  random_state=random_state)
    raise InvalidParameterError(f"classifier must be one of {CLASSIFIERS}; got {classifier!r}.")


def fit_linear(
    X: np.ndarray,
    labels: np.ndarray,
    columns: np.ndarray,
    stats: ColumnStats,
    *,
    classifier: str = "svm",
    C: float = 1.0,
    max_iter: int = 1000,
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
    dtype : numpy dtype
        Stored weight dtype (float32 or float16).
    sample_weight : ndarray of shape (n_samples,), optional
        Per-row weight in liblinear's loss (multi-exemplar training).

    Returns
    -------
    weights : ndarray of shape (n_hyperplanes, d'), dtype ``dtype`` — scaling folded in
    bias : ndarray of shape (n_hyperplanes,), float32
    converged : bool
        False when liblinear stopped at ``max_iter``.
    """
    cols = np.asarray(columns, dtype=np.intp)
    mu = stats.mean[cols]
    sigma = stats.scale[cols]
    Xs = standardised_columns(X, cols, mu, sigma)
    model = _make_classifier(classifier, C, max_iter, random_state, _use_dual(*Xs.shape))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(Xs, labels, sample_weight=sample_weight)
    # liblinear's own test (it warns when n_iter_ ≥ max_iter). Not recorded warnings: the warning
    # registry is process-global, so threads fitting at once lost each other's warnings and
    # n_unconverged_ changed with n_jobs.
    converged = int(np.max(model.n_iter_)) < max_iter
    coef = np.atleast_2d(model.coef_)
    weights = (coef / sigma).astype(dtype)
    # Bias from the stored weights: c' = c − Σ w_stored·μ.
    bias = (np.asarray(model.intercept_, dtype=np.float64) - weights.astype(np.float64) @ mu).astype(np.float32)
    return weights, np.atleast_1d(bias), converged


@dataclass
class Hyperplanes:
    """A stack of K linear classifiers, classifier k reading columns ``columns[k]``.

    Attributes
    ----------
    weights : ndarray of shape (K, d'), float32 or float16
    bias : ndarray of shape (K,), float32
    columns : ndarray of shape (K, d') or (1, d'), uint16/uint32, or None
        Columns read by each classifier; one shared row when all K read the same columns (the
        one-vs-rest region classifier); None when every classifier reads all d columns
        (d' = d: no indices stored).
    n_features_in : int
        d, the descriptor dimension.
    """

    weights: np.ndarray
    bias: np.ndarray
    columns: np.ndarray | None
    n_features_in: int
    _dense: np.ndarray | None = field(default=None, repr=False, compare=False)
    _dense_blocks: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def empty(cls, n_selected: int, n_features_in: int, dtype: np.dtype, index_dtype: np.dtype | None):
        return cls(
            weights=np.zeros((0, n_selected), dtype=dtype),
            bias=np.zeros(0, dtype=np.float32),
            columns=None if index_dtype is None else np.zeros((0, n_selected), dtype=index_dtype),
            n_features_in=n_features_in,
        )

    @classmethod
    def stack(cls, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], n_features_in: int,
              n_selected: int, dtype: np.dtype, index_dtype: np.dtype | None,
              *, shared_columns: bool = False) -> "Hyperplanes":
        """Stack (weights (k, d'), bias (k,), columns (d',)) triples, one per fitted classifier.

        ``index_dtype`` None means d' = d and no columns are stored. With ``shared_columns``
        (every part reads the same columns: the one-vs-rest region classifier) the columns are
        stored once, as one row.
        """
        if not parts:
            return cls.empty(n_selected, n_features_in, dtype, index_dtype)
        weights = np.concatenate([w for w, _, _ in parts]).astype(dtype)
        bias = np.concatenate([b for _, b, _ in parts]).astype(np.float32)
        columns = None
        if index_dtype is not None:
            if shared_columns or len(parts) == 1:
                columns = parts[0][2].reshape(1, -1).astype(index_dtype)
            else:
                columns = np.concatenate(
                    [np.broadcast_to(c, (w.shape[0], c.shape[0])) for w, _, c in parts]
                ).astype(index_dtype)
        return cls(weights=weights, bias=bias, columns=columns, n_features_in=n_features_in)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str, n_features_in: int) -> "Hyperplanes":
        """Hyperplanes read from a model file's (shape-checked) arrays ``{prefix}weights`` etc.

        Raises :class:`~btel.exceptions.ModelFileError` for NaN/inf weights or biases and for
        column indices outside [0, d).
        """
        weights, bias = arrays[f"{prefix}weights"], arrays[f"{prefix}bias"]
        columns = arrays.get(f"{prefix}columns")
        if not (np.isfinite(weights).all() and np.isfinite(bias).all()):
            raise ModelFileError(f"the model file's {prefix}weights or {prefix}bias contain NaN or infinite values.")
        if columns is not None and columns.size and int(columns.max()) >= n_features_in:
            raise ModelFileError(f"the model file's {prefix}columns index past d = {n_features_in}.")
        return cls(weights, bias, columns, n_features_in)

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The stored arrays, named ``{prefix}weights`` etc."""
        out = {f"{prefix}weights": self.weights, f"{prefix}bias": self.bias}
        if self.columns is not None:
            out[f"{prefix}columns"] = self.columns
        return out

    def dense(self) -> np.ndarray:
        """All K hyperplanes scattered into one (d, K) float32 matrix (a runtime cache, not stored).

        One BLAS product ``Q @ dense`` then gives every margin: faster than K gathers.
        """
        if self._dense is None:
            K, d_sel = self.weights.shape
            dense = np.zeros((self.n_features_in, K), dtype=np.float32)
            if self.columns is None:
                dense[:, :] = self.weights.T
            else:
                rows = np.broadcast_to(self.columns, (K, d_sel)).astype(np.intp)
                dense[rows, np.repeat(np.arange(K), d_sel).reshape(K, d_sel)] = self.weights
            self._dense = dense
        return self._dense

    def margins(self, Q: np.ndarray, rows: slice | np.ndarray | None = None) -> np.ndarray:
        """Margins of the queries under classifiers ``rows`` (all by default).

        Returns
        -------
        ndarray of shape (n_queries, n_rows), float32
        """
        dense = self.dense()
        bias = self.bias
        if isinstance(rows, slice):
            # One region's tree: a contiguous copy of its columns (cached). Slicing the (d, K)
            # matrix instead strides over all K columns: 3× slower for one query at K = 320.
            key = rows.indices(dense.shape[1])
            if key not in self._dense_blocks:
                self._dense_blocks[key] = np.ascontiguousarray(dense[:, rows])
            dense = self._dense_blocks[key]
            bias = bias[rows]
        elif rows is not None:
            dense = dense[:, rows]
            bias = bias[rows]
        # A dense (d, K) product beats gathering each classifier's d' columns even for a single
        # query (measured: 6 µs against 11 µs at d = 4096, K = 20, d' = 410, the matrix in cache).
        return Q @ dense + bias

    def margins_per_row(self, Q: np.ndarray, row_of_query: np.ndarray) -> np.ndarray:
        """Margin of query i under its own classifier ``row_of_query[i]`` (shape (n,), float32).

        Gathers only that classifier's d' columns: O(n·d'), for when K is large (BTE-F).
        """
        rows = np.asarray(row_of_query, dtype=np.intp)
        w = self.weights[rows].astype(np.float32)
        if self.columns is None:
            q = Q
        else:
            cols = self.columns[rows if self.columns.shape[0] > 1 else np.zeros_like(rows)]
            q = np.take_along_axis(Q, cols.astype(np.intp), axis=1)
        return np.einsum("ij,ij->i", q, w) + self.bias[rows]
