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

from ..exceptions import ModelFileError

__all__ = ["Hyperplanes"]


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
