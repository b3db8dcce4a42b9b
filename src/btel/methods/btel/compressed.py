"""Compressed training, BTE-C (the paper's training schemes): b independent bit classifiers over all N places.

Classifier k is trained on every descriptor with label bit k of h(place) (MSB first), on its own
d' columns (:func:`btel.learning.feature_selection.select_features`). The b fits are independent and run in
parallel (:func:`btel.learning.training.fit_tasks`). Storage: b·(d' weights + d' column indices + 1 bias),
i.e. O(log N); inference: one margin per bit, then the constrained (or soft) decode.

Options (the "beyond the paper" variants, all ``BTELocalizer`` parameters):

- **offset codes** (``code_copies = m > 1``, error-correcting output codes): after the b plain
  bits, extra classifiers learn the same contiguous-block splits shifted along the route. Bit j
  (MSB first) splits the route into blocks of L_j = 2^(b−1−j) places; copy k of it is bit j of
  ``(i + s)`` with shift ``s = k·L_j // m`` (k = 1…m−1; shifts that repeat, e.g. every shift of
  the lowest bit, are dropped). Each added column is still a split into contiguous blocks, but
  with its boundaries between the plain bit's boundaries, so a query near a plain boundary is
  also read by a classifier for which it lies mid-block. Decoded softly: the valid i maximising
  ``Σ_c m_c (2·code_c(i) − 1)`` over all K columns (O(N·K) per query).
- **multi-exemplar weights** (``exemplar_radius = e > 0``): each place's label for a column is
  also carried by the frames within ±e of it that share that column's high bits (the same
  block at that level); since their own label is then the same, this is a per-row sample
  weight — the number of such neighbours — which down-weights frames next to a block boundary,
  where a small localisation error flips the label.

Limit: a linear classifier separates an arbitrary labelling of N points only when N ≲ d'+1.
The low bits alternate between neighbouring places, so with N ≫ d' they cannot be memorised and
accuracy rests on the high bits (long contiguous blocks of the route) being learnable.
"""

from __future__ import annotations

import functools

import numpy as np

from .encoding import decode_constrained, decode_soft, n_bits_for
from ...learning.training import Task

__all__ = ["compressed_tasks", "compressed_n_classifiers", "compressed_code", "code_signs", "code_scores", "decode_margins",
           "decode_code", "exemplar_weights", "DECODERS"]

DECODERS = ("constrained", "soft")


@functools.lru_cache(maxsize=64)
def _compressed_code(n_places: int, code_copies: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Levels and shifts of every column of a BTE-C code (plain bits first, then offset copies).

    Parameters
    ----------
    n_places : int
        N of the tree (≥ 1).
    code_copies : int
        m ≥ 1; 1 gives the plain b-bit code.

    Returns
    -------
    levels : ndarray of shape (K,), int64
        Bit level j of each column (0 = MSB).
    shifts : ndarray of shape (K,), int64
        Shift s of each column: column c of place i is bit ``levels[c]`` of ``i + shifts[c]``
        (mod 2^b). The first b columns have s = 0.
    """
    b = n_bits_for(n_places)
    levels = list(range(b))
    shifts = [0] * b
    seen = {(j, 0) for j in range(b)}
    for k in range(1, int(code_copies)):
        for j in range(b):
            block = 1 << (b - 1 - j)
            s = (k * block) // int(code_copies)
            if s and (j, s) not in seen:
                seen.add((j, s))
                levels.append(j)
                shifts.append(s)
    return np.asarray(levels, dtype=np.int64), np.asarray(shifts, dtype=np.int64)


def compressed_code(n_places: int, code_copies: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Levels and shifts of every column of a BTE-C code (cached; see :func:`_compressed_code`)."""
    levels, shifts = _compressed_code(int(n_places), int(code_copies))
    return levels.copy(), shifts.copy()


def compressed_n_classifiers(n_places: int, code_copies: int = 1) -> int:
    """Hyperplanes BTE-C stores for N places: b = max(1, ceil(log2 N)), plus the offset copies."""
    if code_copies == 1:
        return n_bits_for(n_places)
    return int(compressed_code(n_places, code_copies)[0].size)


def _code_bits(places: np.ndarray, n_places: int, code_copies: int) -> np.ndarray:
    """Code of each place, shape (len(places), K), uint8 (plain bits first)."""
    b = n_bits_for(n_places)
    levels, shifts = compressed_code(n_places, code_copies)
    shifted = (np.asarray(places, dtype=np.int64)[:, None] + shifts[None, :]) & ((1 << b) - 1)
    return ((shifted >> (b - 1 - levels)[None, :]) & 1).astype(np.uint8)


def code_signs(n_places: int, code_copies: int = 1) -> np.ndarray:
    """±1 code matrix of every valid place, shape (N, K), float32 (the soft decode's codebook)."""
    bits = _code_bits(np.arange(n_places), n_places, code_copies)
    return (2.0 * bits - 1.0).astype(np.float32)


def exemplar_weights(places: np.ndarray, n_places: int, code_copies: int, radius: int) -> np.ndarray:
    """Multi-exemplar sample weights, shape (len(places), K), float64 (module docstring).

    Weight of a row of place i for column c: the number of places i + δ, |δ| ≤ radius, inside
    the route and in the same block as i at that column's level (so weights lie in [1, 2e + 1]).
    """
    b = n_bits_for(n_places)
    levels, shifts = compressed_code(n_places, code_copies)
    p = np.asarray(places, dtype=np.int64)[:, None]
    low = (b - 1 - levels)[None, :]
    own = (p + shifts[None, :]) >> low
    weights = np.zeros((p.shape[0], levels.size))
    reach = min(int(radius), n_places - 1)  # offsets past the route's ends add nothing: never loop past them
    for delta in range(-reach, reach + 1):
        q = p + delta
        inside = (q >= 0) & (q < n_places)
        weights += inside & (((q + shifts[None, :]) >> low) == own)
    return weights


def compressed_tasks(places: np.ndarray, n_places: int, rows: np.ndarray | None = None, *,
                     code_copies: int = 1, exemplar_radius: int = 0) -> list[Task]:
    """The K column classifiers of one BTE-C tree: the b bits MSB first, then offset copies.

    Parameters
    ----------
    places : ndarray of shape (n_rows,), int64
        Local place index of each training row, in [0, n_places).
    n_places : int
        N of this tree (≥ 2).
    rows : ndarray of shape (n_rows,), optional
        Rows of X these places belong to (None: all of X).
    code_copies : int
        m, offset copies (1: the plain code).
    exemplar_radius : int
        e, multi-exemplar weights (0: every row weighs 1).
    """
    bits = _code_bits(places, n_places, code_copies)
    weights = exemplar_weights(places, n_places, code_copies, exemplar_radius) if exemplar_radius else None
    return [Task(labels=bits[:, k], rows=rows, sample_weight=None if weights is None else weights[:, k])
            for k in range(bits.shape[1])]


def decode_code(margins: np.ndarray, n_places: int, code_copies: int, *, chunk_size: int = 4096) -> np.ndarray:
    """Soft decode over a whole (offset) code: argmax over valid i of ``margins @ code_signs.T``.

    Returns
    -------
    ndarray of shape (n_queries,), int64 in [0, N)
    """
    m = np.asarray(margins, dtype=np.float32)
    out = np.empty(m.shape[0], dtype=np.int64)
    rows = max(1, min(chunk_size, (32 << 20) // (4 * n_places)))  # ≤ 32 MiB of scores at a time, whatever N
    for start in range(0, m.shape[0], rows):
        out[start : start + rows] = np.argmax(code_scores(m[start : start + rows], n_places, code_copies), axis=1)
    return out


def code_scores(margins: np.ndarray, n_places: int, code_copies: int) -> np.ndarray:
    """``margins @ code_signs(N, code_copies).T``, shape (n_queries, N), in the margins' float dtype.

    The signs are made for a block of places at a time (≤ 16 MiB), never the whole (N, K) matrix:
    a model file claiming N = 8·10⁶ places would otherwise cost gigabytes per query.
    """
    m = np.asarray(margins)
    out = np.empty((m.shape[0], int(n_places)), dtype=m.dtype)
    step = max(1, (16 << 20) // (m.dtype.itemsize * max(1, m.shape[1])))
    for start in range(0, int(n_places), step):
        stop = min(int(n_places), start + step)
        signs = (2.0 * _code_bits(np.arange(start, stop), n_places, code_copies) - 1.0).astype(m.dtype)
        out[:, start:stop] = m @ signs.T
    return out


def decode_margins(margins: np.ndarray, n_places: int, method: str = "constrained") -> np.ndarray:
    """Bit margins (n, b) → place indices (n,) int64 in [0, N), by the chosen decode."""
    if method == "soft":
        return decode_soft(margins, n_places)
    return decode_constrained(margins, n_places)
