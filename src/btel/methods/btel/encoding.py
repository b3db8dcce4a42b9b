"""Binary tree codes of place indices (the paper's binary tree encoding).

Place i has the b-bit code h(i), most significant bit first: ``bits[:, 0]`` is the MSB and level
l of the tree splits on ``bits[:, l]``. N is usually not a power of two, so decoding must never
produce an index ≥ N:

- :func:`decode_constrained` (default) reads bits MSB first; once the prefix decoded so far equals
  the prefix of N−1, a 1 that would push the index past N−1 is forced to 0.
- :func:`decode_soft` returns the valid index maximising ``Σ_k m_k (2·bit_k(i) − 1)`` over the bit
  margins, O(N·b) per query.
"""

from __future__ import annotations

import numpy as np

from ...core.validation import check_positive_int
from ...exceptions import InvalidParameterError, NotEnoughPlacesError

__all__ = ["n_bits_for", "encode", "decode", "decode_constrained", "decode_soft", "bit_codes", "index_scores"]


def n_bits_for(n_places: int) -> int:
    """Tree depth b = max(1, ceil(log2 N)) for N places."""
    n = check_positive_int(n_places, "n_places")
    return max(1, int(n - 1).bit_length())


def encode(indices: np.ndarray, n_bits: int) -> np.ndarray:
    """MSB-first binary codes of place indices.

    Parameters
    ----------
    indices : array-like of int, shape (n,)
    n_bits : int
        Code length b; every index must be < 2**b.

    Returns
    -------
    bits : ndarray of shape (n, n_bits), dtype uint8
    """
    idx = np.asarray(indices, dtype=np.int64)
    if idx.ndim != 1:
        raise InvalidParameterError(f"indices must be 1-D; got shape {idx.shape}.")
    if idx.size and (idx.min() < 0 or idx.max() >= (1 << n_bits)):
        raise InvalidParameterError(f"indices must lie in [0, 2**{n_bits}).")
    shifts = np.arange(n_bits - 1, -1, -1, dtype=np.int64)
    return ((idx[:, None] >> shifts) & 1).astype(np.uint8)


def decode(bits: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode` (h⁻¹): MSB-first bits (n, b) → int64 indices (n,)."""
    b = np.asarray(bits)
    if b.ndim != 2:
        raise InvalidParameterError(f"bits must be 2-D (n, n_bits); got shape {b.shape}.")
    weights = (1 << np.arange(b.shape[1] - 1, -1, -1, dtype=np.int64))
    return (b.astype(np.int64) @ weights).astype(np.int64)


def _check_margins(margins: np.ndarray, n_places: int) -> tuple[np.ndarray, int]:
    m = np.asarray(margins, dtype=np.float64)
    if m.ndim != 2:
        raise InvalidParameterError(f"margins must be 2-D (n_queries, n_bits); got shape {m.shape}.")
    n = check_positive_int(n_places, "n_places")
    if n < 2:
        raise NotEnoughPlacesError("N must be at least 2 to decode a place index.")
    b = n_bits_for(n)
    if m.shape[1] != b:
        raise InvalidParameterError(f"N = {n} needs {b} bit margins per query; got {m.shape[1]}.")
    return m, n


def decode_constrained(margins: np.ndarray, n_places: int) -> np.ndarray:
    """Constrained MSB-first decode of bit margins; the result is always < N.

    Parameters
    ----------
    margins : ndarray of shape (n_queries, b)
        Positive margin means bit 1. (Bits in {0, 1} work too, with 0 read as "not positive".)
    n_places : int
        N; ``b`` must equal ``n_bits_for(N)``.

    Returns
    -------
    indices : ndarray of shape (n_queries,), dtype int64, every value in [0, N)
    """
    m, n = _check_margins(margins, n_places)
    return _decode_constrained(m, n)


def _decode_constrained(m: np.ndarray, n: int) -> np.ndarray:
    """:func:`decode_constrained` of checked margins (shape (n_queries, b), b = n_bits_for(n))."""
    if m.shape[0] == 1:
        # One query (streaming): the same rule on Python ints, without a dozen tiny numpy calls.
        return np.array([_constrained_one(m[0], n - 1)], dtype=np.int64)
    weights = 1 << np.arange(m.shape[1] - 1, -1, -1, dtype=np.int64)
    raw = (m > 0).astype(np.int64) @ weights
    # Reading MSB first, the walk stays "tight" (prefix equal to N−1's) while it copies N−1's bits:
    # a raw 1 where N−1 has 0 is forced to 0. It is released at the first bit where N−1 has a 1 and
    # the raw code a 0; from there on the raw bits are kept. So: N−1's bits above the release
    # position p, 0 at p, the raw bits below p — and N−1 itself when there is no release.
    limit = n - 1
    release = limit & ~raw
    out = np.full_like(raw, limit)
    has = release > 0
    if has.any():
        p = np.floor(np.log2(release[has])).astype(np.int64)  # exact: values < 2**53
        high = (limit >> (p + 1)) << (p + 1)
        out[has] = high | (raw[has] & ((np.int64(1) << p) - 1))
    return out


def _constrained_one(margins: np.ndarray, limit: int) -> int:
    """:func:`decode_constrained` of one query's margins (shape (b,)) with N − 1 = ``limit``."""
    raw = 0
    for value in margins.tolist():
        raw = (raw << 1) | (value > 0)
    release = limit & ~raw
    if not release:
        return limit
    p = release.bit_length() - 1
    return ((limit >> (p + 1)) << (p + 1)) | (raw & ((1 << p) - 1))


def bit_codes(n_places: int) -> np.ndarray:
    """Signed codes of every valid index: ``2·h(i) − 1``, shape (N, b), dtype int8."""
    n = check_positive_int(n_places, "n_places")
    return (2 * encode(np.arange(n), n_bits_for(n)).astype(np.int8) - 1).astype(np.int8)


def decode_soft(margins: np.ndarray, n_places: int, *, chunk_size: int = 4096) -> np.ndarray:
    """Soft decode: the valid index i < N maximising ``Σ_k m_k (2·bit_k(i) − 1)``.

    O(N·b) per query; no extra storage. Ties go to the smallest index.

    Parameters
    ----------
    margins : ndarray of shape (n_queries, b)
    n_places : int
    chunk_size : int
        Queries scored per block (bounds memory at ``chunk_size × N`` floats).

    Returns
    -------
    indices : ndarray of shape (n_queries,), dtype int64
    """
    m, n = _check_margins(margins, n_places)
    out = np.empty(m.shape[0], dtype=np.int64)
    rows = max(1, min(chunk_size, (32 << 20) // (8 * n)))  # ≤ 32 MiB of scores at a time, whatever N
    for start in range(0, m.shape[0], rows):
        out[start : start + rows] = np.argmax(index_scores(m[start : start + rows], n), axis=1)
    return out


def index_scores(margins: np.ndarray, n_places: int) -> np.ndarray:
    """``Σ_k m_k (2·bit_k(i) − 1)`` of every index i < N (MSB first), shape (n_queries, N), float64.

    Built by doubling from the last bit (the indices with bit k set score the others' + 2·m_k), in
    O(N) per query and no memory beyond the result: the (N, b) sign matrix a product would need is
    8·b bytes a place (1.5 GB for a file that claims N = 8·10⁶).
    """
    m = np.asarray(margins, dtype=np.float64)
    out = np.empty((m.shape[0], int(n_places)))
    out[:, :1] = 0.0
    size = 1
    for k in range(m.shape[1] - 1, -1, -1):
        grown = min(2 * size, out.shape[1])
        column = m[:, k : k + 1]
        out[:, size:grown] = out[:, : grown - size] + column  # bit k set
        out[:, :size] -= column  # bit k clear
        size = grown
    return out
