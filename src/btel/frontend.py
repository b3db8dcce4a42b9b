"""What happens to a descriptor before a method sees it: delta → normalise → whiten (every method).

Every registered method owns one :class:`FrontEnd`, set by its parameters ``normalize``,
``whiten`` and ``delta``, fitted on the map in ``fit`` and applied to every query. Its arrays are
stored in the model file and counted by the storage rule, so :func:`btel.load` reproduces it.

- ``delta = w`` — **sequence (delta) descriptors** (Garg & Milford, RA-L 2020): frame j becomes the
  mean of frames j−w+1 … j minus the mean of frames j−2w+1 … j−w along the traverse. Causal (frame
  j uses frames ≤ j only), so it works online (:class:`FrontEndStream`). Before 2w frames have been
  seen the missing frames are taken to be copies of the first one (edge replication), so frame 0's
  delta is 0 and the early answers carry little information. A map given with ``places`` that
  restart (several traverses) is differenced traverse by traverse: a new traverse starts wherever
  the place label goes down. Queries must be consecutive frames of one traverse, in order — a
  method with a delta front end uses the query *sequence*, like SeqSLAM, and tables mark it so.
- ``normalize`` — ``'l2'`` (each row to unit length: cosine similarity, what NetVLAD-family global
  descriptors are made for), ``'power'`` (signed square root, then L2; the power-law
  normalisation of VLAD/RootSIFT), or ``'none'``. Applied to the frames before the delta and again
  to its result (a delta is compared by its direction).
- ``whiten = p`` — PCA whitening learnt on the (normalised) map: centre, project on the top p
  principal directions, divide by their standard deviations (scikit-learn ``PCA(whiten=True)``),
  then L2 again when ``normalize`` is not ``'none'``. Stores a d×p float32 matrix and a d float32
  mean (counted in the method's bytes).
- ``whiten = "shrink"`` — shrinkage whitening x ↦ (Σ + λI)^(-1/2)(x − μ), then L2 (λ = 0.05 × the
  mean eigenvalue; low rank, int8/float16, at most a quarter of the budget: :mod:`btel.shrink`).
  Keeps the dimension d; its arrays are stored and counted like PCA whitening's.

Measured (``btel experiment front-ends``; docs/results.md has every row): brute force on Gardens
Point NetVLAD day→night, recall@0/2/10, 0.07/0.235/0.48 raw L2 → 0.155/0.48/0.755 with ``'l2'``;
Nordland HOG summer→winter recall@10 0.382 / 0.381 without / with ``'l2'``, 0.625 / 0.650 with
``delta`` 10 / 20; whitening lowered brute force on both sets and ``'power'`` was level with or
below ``'l2'``. Hence the default front end is ``normalize='l2'``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validation import Interval, Options, check_descriptors, check_positive_int
from .exceptions import InvalidParameterError, ModelFileError, NotEnoughPlacesError

__all__ = ["FrontEnd", "FrontEndStream", "ScaledRows", "delta_descriptors", "normalize_rows", "row_norms",
           "traverse_starts",
           "NORMALIZATIONS", "FRONT_END_CONSTRAINTS"]

NORMALIZATIONS = ("none", "l2", "power")
#: Longest delta window (frames per half window).
MAX_DELTA = 1000

#: The constraints of the three front-end parameters every method declares.
FRONT_END_CONSTRAINTS: dict[str, list[Any]] = {
    "normalize": [Options(*NORMALIZATIONS)],
    "whiten": [None, Interval(int, 1, None), Options("shrink")],
    # A window of w frames keeps 2w frames per streamed query (and reads 2w·d values each frame):
    # windows are tens of frames; 1000 bounds what a model file can ask for.
    "delta": [None, Interval(int, 1, MAX_DELTA)],
}

#: Rows transformed at a time (bounds the float64 temporaries on large, memory-mapped maps).
_CHUNK_ROWS = 65536


def row_norms(X: np.ndarray, *, check_finite: bool = False, name: str = "X") -> np.ndarray:
    """L2 norm of every row, float64 (n,), read in chunks of about a million values.

    float32 rows are summed in float32 (SIMD, no float64 copy of X: about 3× faster than a float64
    pass); a row whose float32 sum of squares is not finite — an overflow of huge finite values, or
    a NaN/inf — is summed again in float64. With ``check_finite`` a row that is still not finite is an
    :class:`InvalidDescriptorsError` naming its first bad value (the norms double as the input's
    finiteness check, so validated queries are read once for both).
    """
    if X.shape[0] == 1 and X.dtype == np.float32 and X.ndim == 2:  # one query (streaming): BLAS' sdot
        sq1 = float(np.dot(X[0], X[0]))
        if not math.isfinite(sq1):
            sq1 = float(np.dot(X[0].astype(np.float64), X[0].astype(np.float64)))
            if check_finite and not math.isfinite(sq1):
                from ._validation import raise_if_non_finite

                raise_if_non_finite(np.asarray(X), name)
        return np.array([math.sqrt(sq1)])  # NaN stays NaN, inf stays inf (math.sqrt does not raise on them)
    if X.size <= 1 << 16:  # a few queries: one pass, least fixed overhead
        if X.dtype == np.float32:
            sq = np.einsum("ij,ij->i", X, X)
            if not np.isfinite(sq).all():  # overflow of huge finite values, or NaN/inf: again in float64
                sq = np.einsum("ij,ij->i", X, X, dtype=np.float64)
            sq = sq.astype(np.float64)
        else:
            sq = np.einsum("ij,ij->i", X, X, dtype=np.float64)
        if check_finite and not np.isfinite(sq).all():
            from ._validation import raise_if_non_finite

            raise_if_non_finite(np.asarray(X), name)
        return np.sqrt(sq)
    norms = np.empty(X.shape[0])
    step = max(1, min(_CHUNK_ROWS, (1 << 23) // max(X.shape[1], 1)))  # ~32 MB of float32 per chunk
    for start in range(0, X.shape[0], step):
        block = X[start : start + step]
        with np.errstate(invalid="ignore", over="ignore"):
            if block.dtype == np.float32:
                sq = np.einsum("ij,ij->i", block, block).astype(np.float64)
            else:
                sq = np.einsum("ij,ij->i", block, block, dtype=np.float64)
            bad = ~np.isfinite(sq)
            if bad.any():
                rows = np.asarray(block[bad], dtype=np.float64)
                sq[bad] = np.einsum("ij,ij->i", rows, rows)
        if check_finite and not np.isfinite(sq).all():
            from ._validation import raise_if_non_finite

            raise_if_non_finite(np.asarray(X[start : start + step]), name, row_offset=start)
        norms[start : start + step] = np.sqrt(sq)
    return norms


def normalize_rows(X: np.ndarray, how: str = "l2", *, check_finite: bool = False, name: str = "X") -> np.ndarray:
    """Rows scaled to unit L2 length (``'l2'``), after a signed square root (``'power'``), or as is.

    A zero row stays zero. Returns a new float32 array (X itself for ``'none'``). With
    ``check_finite`` the row norms double as the finiteness check of the input (:func:`row_norms`).
    """
    if how == "none":
        return X
    if how not in NORMALIZATIONS:
        raise InvalidParameterError(f"normalize must be one of {NORMALIZATIONS}; got {how!r}.")
    if how == "power":
        if check_finite:
            row_norms(X, check_finite=True, name=name)
        X = np.asarray(X, dtype=np.float64)
        X = (np.sign(X) * np.sqrt(np.abs(X))).astype(np.float32)
    norms = row_norms(X, check_finite=check_finite, name=name)
    inverse = (1.0 / np.where(norms > 0, norms, 1.0)).astype(np.float32)
    out = np.empty(X.shape, dtype=np.float32)
    step = max(1, min(_CHUNK_ROWS, (1 << 20) // max(X.shape[1], 1)))
    for start in range(0, X.shape[0], step):
        np.multiply(X[start : start + step], inverse[start : start + step, None], out=out[start : start + step],
                    casting="unsafe")
    return out


class ScaledRows:
    """Rows ``raw[i] · scale[i]`` kept unmultiplied: what an L2-normalising front end hands a linear method.

    Normalising a batch of queries costs a pass over them and a copy as large as them, more than
    the product that follows. A linear map commutes with the row scaling, so a method whose only use
    of the queries is ``Q @ W`` (BTEL's and RYTH's hyperplanes) takes this object instead and the
    scale is applied to the (n, K) output: BTE-C's batch predict at d = 4096 about twice as fast.
    Row selection (``rows[i:j]``, ``rows[mask]``) keeps it lazy; anything else reads
    ``np.asarray(rows)``, the normalised rows multiplied out.
    """

    __slots__ = ("raw", "scale")

    def __init__(self, raw: np.ndarray, scale: np.ndarray) -> None:
        self.raw = raw
        self.scale = scale

    @property
    def shape(self) -> tuple[int, int]:
        return self.raw.shape

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.float32)

    ndim = 2

    def __len__(self) -> int:
        return int(self.raw.shape[0])

    def __getitem__(self, rows: Any) -> "ScaledRows":
        if isinstance(rows, tuple):
            raise TypeError("ScaledRows selects rows only; use np.asarray(rows) for anything else.")
        return ScaledRows(self.raw[rows], self.scale[rows])

    def __matmul__(self, matrix: np.ndarray) -> np.ndarray:
        out = self.raw @ matrix
        out *= self.scale[:, None]
        return out

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self.raw * self.scale[:, None]
        return out if dtype is None else out.astype(dtype)


def traverse_starts(places: np.ndarray | None) -> np.ndarray:
    """Rows where a new traverse starts: 0 and every row whose place label is below the previous one."""
    if places is None:
        return np.zeros(1, dtype=np.int64)
    p = np.asarray(places, dtype=np.int64)
    return np.concatenate([[0], np.flatnonzero(np.diff(p) < 0) + 1]).astype(np.int64)


def delta_descriptors(X: Any, window: int, *, starts: Any = None) -> np.ndarray:
    """Delta descriptors of a traverse: mean of the last ``window`` frames minus the mean of the window before.

    Row j of the result is ``mean(X[j−w+1 … j]) − mean(X[j−2w+1 … j−w])`` with frames before the
    start of the traverse replaced by its first frame (so row 0 is 0). Causal: row j reads rows ≤ j.

    Parameters
    ----------
    X : array-like of shape (n_frames, n_features)
        Descriptors of consecutive frames, in travel order.
    window : int
        w ≥ 1, frames per half window; the traverse must have at least 2w frames.
    starts : array-like of int, optional
        Rows where a new traverse starts (each is differenced on its own); default one traverse.

    Returns
    -------
    ndarray of shape (n_frames, n_features), float32
    """
    X = check_descriptors(X, name="X")
    w = check_positive_int(window, "delta window")
    bounds = [0] if starts is None else sorted({int(s) for s in np.asarray(starts).ravel()} | {0})
    bounds.append(X.shape[0])
    out = np.empty(X.shape, dtype=np.float32)
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < 2 * w:
            raise NotEnoughPlacesError(
                f"a delta window of w = {w} needs a traverse of at least 2w = {2 * w} frames; rows {a}…{b - 1} "
                f"hold {b - a}. Use a smaller window (delta ≤ {max((b - a) // 2, 1)})."
            )
        out[a:b] = _delta_one(X[a:b], w)
    return out


def _delta_one(X: np.ndarray, w: int) -> np.ndarray:
    """Delta of one traverse by cumulative sums over the edge-padded frames (O(n·d))."""
    n, d = X.shape
    out = np.empty((n, d), dtype=np.float32)
    # Work in column blocks so the float64 cumulative sum stays small on wide descriptors.
    step = max(1, (1 << 24) // max(n + 2 * w, 1))
    for c0 in range(0, d, step):
        cols = np.asarray(X[:, c0 : c0 + step], dtype=np.float64)
        padded = np.concatenate([np.repeat(cols[:1], 2 * w, axis=0), cols])
        csum = np.concatenate([np.zeros((1, cols.shape[1])), np.cumsum(padded, axis=0)])
        end = np.arange(n) + 2 * w + 1  # exclusive end of frame j's last window in the padded rows
        last = csum[end] - csum[end - w]
        before = csum[end - w] - csum[end - 2 * w]
        out[:, c0 : c0 + step] = (last - before) / w
    return out


@dataclass
class FrontEnd:
    """The fitted front end of one model (module docstring for the steps and their order).

    Attributes
    ----------
    normalize : {'none', 'l2', 'power'}
    whiten : int or None
        p, whitened dimension (None: no whitening).
    delta : int or None
        w, delta window (None: single frames).
    mean_ : ndarray of shape (d,), float32, or None
        Whitening mean (only with ``whiten``).
    whitening_ : ndarray of shape (d, p), float32, or None
        Whitening matrix (principal directions divided by their standard deviations).
    """

    normalize: str = "none"
    whiten: int | None = None
    delta: int | None = None
    mean_: np.ndarray | None = field(default=None, repr=False)
    whitening_: np.ndarray | None = field(default=None, repr=False)
    #: The model's byte budget (sets the rank of ``whiten="shrink"``; not stored).
    budget: int | None = field(default=None, repr=False)
    #: ``whiten="shrink"``: mean (float16), basis (int8 d×r), basis scales and gains (float32 r).
    shrink_: tuple | None = field(default=None, repr=False)

    @classmethod
    def of(cls, estimator: Any) -> "FrontEnd":
        """The (unfitted) front end an estimator's ``normalize``/``whiten``/``delta`` parameters ask for
        (declared once for every method in :class:`btel.base.PlaceLocalizer`)."""
        from .storage import parse_budget

        return cls(estimator.normalize, estimator.whiten, estimator.delta,
                   budget=parse_budget(getattr(estimator, "budget", None)))

    @property
    def is_identity(self) -> bool:
        return self.normalize == "none" and self.whiten is None and self.delta is None

    @property
    def uses_sequence(self) -> bool:
        """True with delta descriptors: a query's answer depends on the frames before it."""
        return self.delta is not None

    # -- fit / transform ----------------------------------------------------------------------
    @property
    def checks_finite(self) -> bool:
        """True when :meth:`transform` with ``check_finite=True`` rejects NaN/inf itself (a normalising front end)."""
        return self.normalize != "none"

    def _frames(self, X: np.ndarray, starts: np.ndarray | None, check_finite: bool = False) -> np.ndarray:
        """Normalise, delta, normalise: everything before the whitening."""
        Z = normalize_rows(X, self.normalize, check_finite=check_finite, name="Q")
        if self.delta is not None:
            Z = normalize_rows(delta_descriptors(Z, self.delta, starts=starts), self.normalize)
        return Z

    def fit_transform(self, X: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
        """Learn the whitening (if any) on the map and return the transformed map, float32 (n, d_out)."""
        Z = self._frames(X, starts)
        if self.whiten == "shrink":
            from .shrink import fit_shrink, shrink_rank

            self.shrink_ = fit_shrink(Z, shrink_rank(Z.shape[1], Z.shape[0], self.budget))
            self._shrink_basis = None
        elif self.whiten is not None:
            from sklearn.decomposition import PCA

            n, d = Z.shape
            if self.whiten > min(d, n - 1):
                raise InvalidParameterError(
                    f"whiten = {self.whiten} needs at least {self.whiten + 1} map rows and descriptors of at least "
                    f"{self.whiten} dimensions; got {n} rows of {d}. Use whiten ≤ {max(min(d, n - 1), 1)}."
                )
            pca = PCA(n_components=int(self.whiten), whiten=True, random_state=0).fit(Z)
            std = np.sqrt(np.maximum(pca.explained_variance_, 1e-12))
            self.mean_ = pca.mean_.astype(np.float32)
            self.whitening_ = np.ascontiguousarray((pca.components_.T / std).astype(np.float32))
        return self._whitened(Z)

    def _whitened(self, Z: np.ndarray) -> np.ndarray:
        if self.shrink_ is not None:
            from .shrink import apply_shrink

            mean, basis, scale, gains = self.shrink_
            if getattr(self, "_shrink_basis", None) is None:  # runtime cache of the dequantised basis
                self._shrink_basis = basis.astype(np.float32) * scale
            out = np.empty(Z.shape, dtype=np.float32)
            for start in range(0, Z.shape[0], _CHUNK_ROWS):
                out[start : start + _CHUNK_ROWS] = apply_shrink(Z[start : start + _CHUNK_ROWS], mean, basis, scale,
                                                                gains, self._shrink_basis)
            return normalize_rows(out, "none" if self.normalize == "none" else "l2")
        if self.whitening_ is None:
            return Z
        out = np.empty((Z.shape[0], self.whitening_.shape[1]), dtype=np.float32)
        for start in range(0, Z.shape[0], _CHUNK_ROWS):
            out[start : start + _CHUNK_ROWS] = (Z[start : start + _CHUNK_ROWS] - self.mean_) @ self.whitening_
        return normalize_rows(out, "none" if self.normalize == "none" else "l2")

    def transform(self, X: np.ndarray, starts: np.ndarray | None = None, *, check_finite: bool = False,
                  lazy: bool = False) -> np.ndarray | ScaledRows:
        """Apply the fitted front end to validated descriptors (queries: one traverse, in order).

        ``check_finite``: reject NaN/inf in X while normalising (see :attr:`checks_finite`).
        ``lazy``: the caller only multiplies the rows by matrices, so a plain L2 normalisation
        comes back as :class:`ScaledRows` (no normalised copy of X).
        """
        if self.is_identity:
            return X
        if lazy and self.normalize == "l2" and self.delta is None and self.whiten is None:
            norms = row_norms(X, check_finite=check_finite, name="Q")
            if norms.shape[0] == 1:  # one query: Python arithmetic beats three tiny numpy calls
                return ScaledRows(X, np.array([1.0 / norms[0] if norms[0] > 0 else 1.0], dtype=np.float32))
            norms[norms == 0] = 1.0  # a zero row stays zero
            return ScaledRows(X, (1.0 / norms).astype(np.float32))
        return self._whitened(self._frames(X, starts, check_finite))

    def stream(self) -> "FrontEndStream":
        """A streaming version for one descriptor at a time (``btel localize --stream``)."""
        return FrontEndStream(self)

    # -- storage --------------------------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """The stored arrays (empty without whitening)."""
        if self.shrink_ is not None:
            return dict(zip(_SHRINK_ARRAYS, self.shrink_))
        if self.whitening_ is None:
            return {}
        return {"frontend_mean": self.mean_, "frontend_whitening": self.whitening_}

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.arrays().values()))

    def planned_bytes(self, n_features: int, n_rows: int | None = None) -> int:
        """Bytes the fitted front end will store for d = ``n_features`` (known before fitting)."""
        if self.whiten == "shrink":
            from .shrink import shrink_bytes, shrink_rank

            return shrink_bytes(n_features, shrink_rank(n_features, n_rows, self.budget))
        return 0 if self.whiten is None else int(n_features) * (int(self.whiten) + 1) * 4

    def n_features_out(self, n_features: int) -> int:
        return int(n_features) if self.whiten in (None, "shrink") else int(self.whiten)

    def to_header(self) -> dict[str, Any]:
        return {"normalize": self.normalize, "whiten": self.whiten, "delta": self.delta}

    def describe(self) -> str:
        """One line: the front end's steps (and the shrinkage rank)."""
        white = self.whiten
        if self.shrink_ is not None:
            white = f"shrink (rank {self.shrink_[1].shape[1]}, {self.nbytes} B)"
        return f"normalize={self.normalize}, whiten={white}, delta={self.delta}"

    @classmethod
    def restore(cls, header: Any, arrays: dict[str, np.ndarray], n_features: int) -> "FrontEnd":
        """The front end recorded in a model file, checked against its arrays (ModelFileError if not)."""
        from ._validation import check_param

        if not isinstance(header, dict) or set(header) != {"normalize", "whiten", "delta"}:
            raise ModelFileError("the model file's front end is missing or malformed.")
        for name, constraints in FRONT_END_CONSTRAINTS.items():
            try:
                check_param("front end", name, header[name], constraints)
            except InvalidParameterError as exc:
                raise ModelFileError(f"the model file's front end is invalid: {exc}") from exc
        front = cls(header["normalize"], header["whiten"], header["delta"])
        if front.whiten == "shrink":
            front.shrink_ = _restore_shrink(arrays, n_features)
            return front
        mean, matrix = arrays.pop("frontend_mean", None), arrays.pop("frontend_whitening", None)
        if front.whiten is None:
            if mean is not None or matrix is not None:
                raise ModelFileError("the model file holds a whitening matrix but its header says no whitening.")
            return front
        p = int(front.whiten)
        if mean is None or matrix is None or mean.shape != (n_features,) or matrix.shape != (n_features, p) \
                or mean.dtype != np.float32 or matrix.dtype != np.float32:
            raise ModelFileError(
                f"the model file's whitening arrays do not match d = {n_features}, p = {p} (float32 expected)."
            )
        if not (np.isfinite(mean).all() and np.isfinite(matrix).all()):
            raise ModelFileError("the model file's whitening arrays contain NaN or infinite values.")
        front.mean_, front.whitening_ = mean, matrix
        return front


#: Names of the stored arrays of ``whiten="shrink"``.
_SHRINK_ARRAYS = ("frontend_shrink_mean", "frontend_shrink_basis", "frontend_shrink_scale", "frontend_shrink_gains")


def _restore_shrink(arrays: dict[str, np.ndarray], n_features: int) -> tuple:
    """The shrinkage arrays of a model file, checked (ModelFileError if not as fit writes them)."""
    parts = [arrays.pop(name, None) for name in _SHRINK_ARRAYS]
    if any(p is None for p in parts):
        raise ModelFileError("the model file says whiten='shrink' but lacks its arrays "
                             f"({', '.join(n for n, p in zip(_SHRINK_ARRAYS, parts) if p is None)}).")
    mean, basis, scale, gains = parts
    if basis.ndim != 2:
        raise ModelFileError("the model file's shrinkage basis is not a matrix.")
    r = basis.shape[1]
    if mean.shape != (n_features,) or mean.dtype != np.float16 or basis.shape != (n_features, r) \
            or basis.dtype != np.int8 or scale.shape != (r,) or gains.shape != (r,) \
            or scale.dtype != np.float32 or gains.dtype != np.float32:
        raise ModelFileError(f"the model file's shrinkage arrays do not match d = {n_features} (float16 mean, "
                             "int8 d×r basis, float32 scales and gains expected).")
    if not all(np.isfinite(a).all() and float(np.abs(a).max(initial=0)) <= 1e6 for a in (mean, scale, gains)):
        raise ModelFileError("the model file's shrinkage arrays contain NaN, infinite or out-of-range values.")
    return mean, basis, scale, gains


class FrontEndStream:
    """One descriptor at a time through a fitted :class:`FrontEnd` (causal; keeps the last 2w frames).

    ``update(x)`` takes a (1, d) float32 row and returns the transformed (1, d_out) row, from the
    first frame on; before 2w frames the missing ones are copies of the first (as in the batch
    transform, so streaming equals :meth:`FrontEnd.transform` row by row). :meth:`reset` starts a
    new traverse.
    """

    def __init__(self, front: FrontEnd) -> None:
        self.front = front
        self._history: list[np.ndarray] = []

    def reset(self) -> None:
        self._history = []

    def update(self, x: np.ndarray) -> np.ndarray:
        front = self.front
        z = normalize_rows(np.asarray(x, dtype=np.float32).reshape(1, -1), front.normalize)
        if front.delta is not None:
            w = int(front.delta)
            if not self._history:
                self._history = [z[0]] * (2 * w)
            self._history = self._history[1:] + [z[0]]
            frames = np.asarray(self._history, dtype=np.float64)
            d = (frames[w:].mean(axis=0) - frames[:w].mean(axis=0)).astype(np.float32)
            z = normalize_rows(d.reshape(1, -1), front.normalize)
        return front._whitened(z)
