"""A stack of K linear classifiers as stored and as used at inference: :class:`Hyperplanes`.

Classifier k reads its own d' columns (or every column, d' = d). The stored arrays are the
weights (scaling folded in: :mod:`btel.learning.linear`), the biases and the column indices;
:meth:`Hyperplanes.from_arrays` reads them back from a model file and checks them. At inference
the K classifiers are scattered once into a dense (d, K) matrix (a runtime cache, not stored), so
all K margins of a batch of queries are one matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..exceptions import InvalidDescriptorsError, ModelFileError

__all__ = ["Hyperplanes", "MAX_WEIGHT_NORM", "weights_out_of_range", "check_fitted_weights"]

#: Longest stored weight vector (L2 length, in the units of the front end's output) and largest |bias|
#: a fit may produce and a model file may hold: the margin of a descriptor no longer than 1e18 (the
#: bound on the rows the row indexes search) then stays within 1e36, finite in float32 (3.4e38) in any
#: order of summation. Longer weights only come from maps of tiny values without normalisation.
MAX_WEIGHT_NORM = 1e18
#: Weight rows read at a time by :func:`weights_out_of_range` (bounds its float32 temporaries).
_CHECK_ROWS = 4096


def weights_out_of_range(weights: np.ndarray, bias: np.ndarray) -> str | None:
    """What puts a stack of linear classifiers beyond :data:`MAX_WEIGHT_NORM`, or None when nothing does.

    Parameters
    ----------
    weights : ndarray of shape (K, d'), float
    bias : ndarray of shape (K,), float

    Returns
    -------
    str or None
        E.g. ``"a weight vector of length 3.1e+38 (classifier 4)"``.
    """
    bias = np.asarray(bias)
    if bias.size:
        if not np.isfinite(bias).all():
            return f"a bias that is NaN or infinite (classifier {int(np.flatnonzero(~np.isfinite(bias))[0])})"
        k = int(np.argmax(np.abs(bias)))
        if abs(float(bias[k])) > MAX_WEIGHT_NORM:
            return f"a bias of {float(bias[k]):.3g} (classifier {k})"
    for start in range(0, weights.shape[0], _CHECK_ROWS):
        block = np.asarray(weights[start : start + _CHECK_ROWS], dtype=np.float32)
        with np.errstate(over="ignore", invalid="ignore"):
            squares = np.einsum("ij,ij->i", block, block)  # an overflow (inf) is far past the bound anyway
        bad = np.flatnonzero(~(squares <= MAX_WEIGHT_NORM**2))
        if bad.size:
            k = int(bad[0])
            row = block[k].astype(np.float64)
            if not np.isfinite(row).all():
                return f"a weight that is NaN or infinite (classifier {start + k})"
            return f"a weight vector of length {float(np.sqrt(row @ row)):.3g} (classifier {start + k})"
    return None


def check_fitted_weights(weights: np.ndarray, bias: np.ndarray, who: str, *,
                         dtype: np.dtype | None = None) -> None:
    """Raise :class:`InvalidDescriptorsError` at fit when the fitted weights exceed :data:`MAX_WEIGHT_NORM`.

    Such weights come from a map whose values are tiny (their scale is folded into the weights) or
    from a ``float16`` weight beyond its range; a model holding them could not answer every query.
    """
    problem = weights_out_of_range(weights, bias)
    if problem is None:
        return
    hint = " Or store the weights as float32 (dtype='float32')." if dtype is not None and \
        np.dtype(dtype) == np.float16 else ""
    raise InvalidDescriptorsError(
        f"{who} of this map: {problem}, beyond the {MAX_WEIGHT_NORM:.0e} that float32 "
        "arithmetic scores safely: the map's values are too small for its front end. Scale the descriptors "
        f"(e.g. to unit length) or use normalize='l2'.{hint}")


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
        stored once, as one row. Weights a model file may not hold are refused here, at fit
        (:func:`check_fitted_weights`).
        """
        if not parts:
            return cls.empty(n_selected, n_features_in, dtype, index_dtype)
        with np.errstate(over="ignore", invalid="ignore"):  # float16 overflow: refused just below
            weights = np.concatenate([w for w, _, _ in parts]).astype(dtype)
        bias = np.concatenate([b for _, b, _ in parts]).astype(np.float32)
        check_fitted_weights(weights, bias, "The fitted classifiers", dtype=dtype)
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

        Raises :class:`~btel.exceptions.ModelFileError` for weights or biases beyond
        :data:`MAX_WEIGHT_NORM` (NaN/inf included: no fit stores them) and for column indices outside [0, d).
        """
        weights, bias = arrays[f"{prefix}weights"], arrays[f"{prefix}bias"]
        columns = arrays.get(f"{prefix}columns")
        problem = weights_out_of_range(weights, bias)
        if problem is not None:
            raise ModelFileError(f"the model file's {prefix}weights or {prefix}bias hold {problem}; no fit "
                                 f"stores weights beyond {MAX_WEIGHT_NORM:.0e}: the file is damaged or was "
                                 "edited. Refit and save the model again.")
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
        # query (BLAS against K gathers, the matrix in cache).
        return Q @ dense + bias

    def margins_per_row(self, Q: np.ndarray, row_of_query: np.ndarray) -> np.ndarray:
        """Margin of query i under its own classifier ``row_of_query[i]`` (shape (n,), float32).

        Gathers only that classifier's d' columns: O(n·d'), for when K is large (BTE-F).
        """
        rows = np.asarray(row_of_query, dtype=np.intp)
        w = self.weights[rows].astype(np.float32)
        Q = np.asarray(Q)  # ScaledRows: multiplied out (columns are gathered, not a product)
        if self.columns is None:
            q = Q
        else:
            cols = self.columns[rows if self.columns.shape[0] > 1 else np.zeros_like(rows)]
            q = np.take_along_axis(Q, cols.astype(np.intp), axis=1)
        return np.einsum("ij,ij->i", q, w) + self.bias[rows]
