"""Row operations of the front end: norms, normalisation, delta descriptors, lazily scaled rows.

Plain functions of arrays, chunked so that memory-mapped maps of millions of rows never need a
float64 copy; :class:`btel.core.frontend.FrontEnd` composes them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .validation import check_descriptors, check_positive_int
from ..exceptions import InvalidParameterError, NotEnoughPlacesError

__all__ = ["BlankQueryWarning", "ScaledRows", "warn_blank_rows", "delta_descriptors", "mean_and_rms", "normalize_rows", "one_row_squares", "row_norms",
           "traverse_starts", "NORMALIZATIONS"]

NORMALIZATIONS = ("none", "l2", "power")

#: Rows transformed at a time (bounds the float64 temporaries on large, memory-mapped maps).
_CHUNK_ROWS = 65536
#: Squared row lengths below this are summed again in float64, and such rows are scaled in float64: in
#: float32 their squares underflow (the smallest normal float32 is 1.2e-38) and their inverse overflows,
#: so a map scaled by 1e-38 would not come out of the L2 front end at unit length.
TINY_SQUARED_NORM = 1e-30
#: Rows longer than this are not handed out as :class:`ScaledRows`: their raw product with a method's
#: weights (``raw @ W``, scaled after) overflows float32 near 1e38, while the normalised rows do not.
HUGE_NORM = 2.0**64


class BlankQueryWarning(UserWarning):
    """A query row of zeros (a blank or covered frame): it carries no appearance to localize by."""


def warn_blank_rows(Q: np.ndarray) -> None:
    """Warn when rows of the validated queries ``Q`` (n, d) are all zeros: a method still answers them
    (a tie's first place, or what its biases favour), but that answer is not a localization. One pass
    over Q; nothing is changed."""
    blank = np.flatnonzero(~Q.any(axis=1)) if Q.shape[0] > 1 else ([0] if not Q.any() else [])
    if len(blank):
        import warnings

        rows = ", ".join(map(str, blank[:5])) + (", …" if len(blank) > 5 else "")
        warnings.warn(f"{len(blank)} query row{'s' * (len(blank) != 1)} ({rows}) {'are' if len(blank) != 1 else 'is'} "
                      "all zeros (a blank frame?): a descriptor with no content gets an answer, but not a "
                      "localization.", BlankQueryWarning, stacklevel=4)


def one_row_squares(row: np.ndarray) -> float:
    """Sum of squares of one float32 row, (d,) or (1, d), as a float (NaN or inf when it holds NaN or inf).

    The rule of :func:`row_norms`: summed in float32 (one BLAS dot, which sets no floating-point error
    state), and again in float64 when that sum is not finite or below :data:`TINY_SQUARED_NORM` — an
    overflow, an underflow, a NaN or inf. float64 products of float32 values neither overflow nor
    underflow, so that sum sets no error state either (``np.errstate`` costs more than the sum of one
    query); a floating-point error the caller's numpy settings raise (a signalling NaN) comes back as NaN.
    """
    squares = float(np.vdot(row, row))  # one call: a single query's cost is counted in calls
    if squares >= TINY_SQUARED_NORM and squares != math.inf:  # False for NaN
        return squares
    wide = row.astype(np.float64)
    try:
        return float(np.vdot(wide, wide))
    except (FloatingPointError, RuntimeWarning):
        return math.nan


def mean_and_rms(X: Any) -> tuple[np.ndarray, float]:
    """Mean row, float64 (d,), and RMS row length of ``X`` (n, d), in one pass over row blocks of at most
    2²² values (an ndarray, a memory map or :class:`ScaledRows`, scaled block by block)."""
    n, d = X.shape
    total, squares = np.zeros(d), 0.0
    step = max(1, (1 << 22) // max(d, 1))
    for start in range(0, n, step):
        block = np.asarray(X[start : start + step], dtype=np.float32)
        total += block.sum(axis=0, dtype=np.float64)
        squares += float(np.einsum("ij,ij->", block, block, dtype=np.float64))
    return total / max(n, 1), math.sqrt(squares / max(n, 1))


def row_norms(X: np.ndarray, *, check_finite: bool = False, name: str = "X") -> np.ndarray:
    """L2 norm of every row, float64 (n,), read in chunks of about a million values.

    float32 rows are summed in float32 (SIMD, no float64 copy of X: about 3× faster than a float64
    pass); a row whose float32 sum of squares is not finite — an overflow of huge finite values, or
    a NaN/inf — or below :data:`TINY_SQUARED_NORM` (an underflow of tiny values) is summed again in
    float64. With ``check_finite`` a row that is still not finite is an
    :class:`InvalidDescriptorsError` naming its first bad value (the norms double as the input's
    finiteness check, so validated queries are read once for both).
    """
    if X.shape[0] == 1 and X.dtype == np.float32 and X.ndim == 2:  # one query (streaming): one float64 dot
        sq1 = one_row_squares(X)
        if check_finite and not math.isfinite(sq1):
            from .validation import raise_if_non_finite

            raise_if_non_finite(np.asarray(X), name)
        return np.array([math.sqrt(sq1)])  # NaN stays NaN, inf stays inf (math.sqrt does not raise on them)
    if X.size <= 1 << 16:  # a few queries: one pass, least fixed overhead
        if X.dtype == np.float32:
            sq = np.einsum("ij,ij->i", X, X)
            if not (np.isfinite(sq) & (sq >= TINY_SQUARED_NORM)).all():  # over/underflow, NaN/inf: in float64
                sq = np.einsum("ij,ij->i", X, X, dtype=np.float64)
            sq = sq.astype(np.float64)
        else:
            sq = np.einsum("ij,ij->i", X, X, dtype=np.float64)
        if check_finite and not np.isfinite(sq).all():
            from .validation import raise_if_non_finite

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
            bad = ~np.isfinite(sq) | (sq < TINY_SQUARED_NORM)
            if bad.any():
                rows = np.asarray(block[bad], dtype=np.float64)
                sq[bad] = np.einsum("ij,ij->i", rows, rows)
        if check_finite and not np.isfinite(sq).all():
            from .validation import raise_if_non_finite

            raise_if_non_finite(np.asarray(X[start : start + step]), name, row_offset=start)
        norms[start : start + step] = np.sqrt(sq)
    return norms


def normalize_rows(X: np.ndarray, how: str = "l2", *, check_finite: bool = False, name: str = "X") -> np.ndarray:
    """Rows scaled to unit L2 length (``'l2'``), after a signed square root (``'power'``), or as is.

    A zero row stays zero; a row shorter than ``sqrt(TINY_SQUARED_NORM)`` is scaled in float64 (its
    inverse length overflows float32), so every other row comes out at unit length whatever its
    scale. Returns a new float32 array (X itself for ``'none'``). With ``check_finite`` the row
    norms double as the finiteness check of the input (:func:`row_norms`).
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
    if X.shape[0] == 1 and not 0 < norms[0] * norms[0] < TINY_SQUARED_NORM:  # one query, not tiny: one scaled copy
        return np.multiply(X, np.float32(1.0 / norms[0] if norms[0] > 0 else 1.0), dtype=np.float32)
    tiny = np.flatnonzero((norms > 0) & (norms * norms < TINY_SQUARED_NORM))
    with np.errstate(over="ignore"):  # tiny rows' inverses overflow float32: they are set to 1 next
        inverse = (1.0 / np.where(norms > 0, norms, 1.0)).astype(np.float32)
    inverse[tiny] = 1.0
    out = np.empty(X.shape, dtype=np.float32)
    step = max(1, min(_CHUNK_ROWS, (1 << 20) // max(X.shape[1], 1)))
    for start in range(0, X.shape[0], step):
        np.multiply(X[start : start + step], inverse[start : start + step, None], out=out[start : start + step],
                    casting="unsafe")
    if tiny.size:
        out[tiny] = np.asarray(X[tiny], dtype=np.float64) / norms[tiny, None]
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


def refuse_one_direction(X: np.ndarray, normalize: str, name: str = "X") -> None:
    """Refuse a map whose rows all point one way (positive multiples of one row): after the L2 or power
    normalisation every method applies, all its places are then one descriptor and nothing tells them apart.

    Read in blocks, stopping at the first block holding a row of another direction (at once on real maps).

    Raises
    ------
    InvalidDescriptorsError
        Every row has a length and all point the same way (cosine to the first row ≥ 1 − 10⁻⁶).
    """
    from ..exceptions import InvalidDescriptorsError

    if normalize == "none" or X.shape[0] < 2:
        return
    first = np.asarray(X[0], dtype=np.float64)
    length = float(np.linalg.norm(first))
    if not length > 0:
        return  # a zero row stays zero: it differs from every row that has a length
    first /= length
    step = max(1, (1 << 20) // max(X.shape[1], 1))
    for start in range(0, X.shape[0], step):
        block = np.asarray(X[start:start + step], dtype=np.float64)
        norms = np.linalg.norm(block, axis=1)
        if not (norms > 0).all() or ((block @ first) < (1 - 1e-6) * norms).any():
            return
    raise InvalidDescriptorsError(
        f"every row of {name} points the same way (the {X.shape[0]} rows differ only in length): after the "
        f"normalisation (normalize={normalize!r}) all places are one descriptor, so nothing tells them apart. "
        "Check how the descriptors were made, or fit with normalize='none' if their lengths are what differs.")
