"""The periodic family's square waves in 64-bit fixed point: signs, packed runs and block counts.

Column k of place i is +1 iff (i·F_k + Φ_k) mod 2⁶⁴ < 2⁶³ — a square wave of period 2⁶⁴ / F_k
places and phase Φ_k, evaluated with wrapping uint64 arithmetic, so the bits are the same on every
platform (:class:`~btel.methods.codes.codebook.Codebook` draws F and Φ and documents the family).
Three ways to read them, all giving the same bits:

- :func:`periodic_positive`: any places, one multiply and one add per (place, column);
- :func:`periodic_packed_run`: consecutive places, packed, one add per (place, column) to a kept
  table of r·F (the fill of the packed cache at inference);
- :func:`periodic_counts`: how many places of each block of B consecutive places are +1, in
  closed form (the block means of the coarse decode), without generating the places.
"""

from __future__ import annotations

import numpy as np

from .hashing import buffer

__all__ = ["periodic_positive", "periodic_packed_run", "periodic_counts"]

_U64 = np.uint64
_HALF = _U64(1 << 63)
#: Elements of the r·F table a run of consecutive places is generated from (2 MB of uint64: bigger
#: tables measured no faster, smaller ones pay numpy's per-call cost; benchmarks/studies/codes_cold_fill.py).
RUN_ELEMENTS = 1 << 18


def periodic_positive(i: np.ndarray, frequency: np.ndarray, phase: np.ndarray, work: dict | None) -> np.ndarray:
    """(n, K) bool: place i's column k is +1, for places ``i`` of shape (n, 1), int64.

    ``frequency`` and ``phase`` are the K columns' F and Φ (uint64); ``work`` keeps the work arrays
    between calls (:func:`~btel.methods.codes.hashing.buffer`).
    """
    shape = (i.shape[0], frequency.size)
    with np.errstate(over="ignore"):
        t = np.multiply(i.astype(_U64), frequency, out=buffer(work, "z", shape, _U64))
        t += phase
    return np.less(t, _HALF, out=buffer(work, "bool", shape, bool))


def periodic_packed_run(frequency: np.ndarray, phase: np.ndarray, start: int, n: int, out: np.ndarray,
                        work: dict) -> np.ndarray:
    """Packed codewords (n, ⌈K/8⌉) uint8 of the consecutive places start … start + n − 1, written to ``out``.

    Row r of a run is (start + r)·F + Φ = (start·F + Φ) + r·F (mod 2⁶⁴): one add per element to
    the table of r·F kept in ``work["steps"]``, where :func:`periodic_positive` multiplies and adds.
    Bits as ``np.packbits(positive, axis=1, bitorder="little")``.
    """
    k = frequency.size
    rows = max(1, RUN_ELEMENTS // max(k, 1))
    steps = work.get("steps")
    if steps is None or steps.shape[0] < min(rows, n):
        with np.errstate(over="ignore"):
            steps = work["steps"] = np.arange(min(rows, max(n, 2)), dtype=_U64)[:, None] * frequency
    rows = steps.shape[0]
    for a in range(0, n, rows):
        m = min(rows, n - a)
        with np.errstate(over="ignore"):
            base = _U64(start + a) * frequency + phase
            z = np.add(steps[:m], base, out=buffer(work, "z", (m, k), _U64))
        positive = np.less(z, _HALF, out=buffer(work, "bool", (m, k), bool))
        out[a : a + m] = np.packbits(positive, axis=1, bitorder="little")
    return out


def periodic_counts(frequency: np.ndarray, phase: np.ndarray, block: int, n_blocks: int) -> np.ndarray:
    """Positive places per (block, column), for the first ``n_blocks`` blocks of B = ``block`` places.

    Place a + i of column k is positive iff (T + i·F) mod 2⁶⁴ < 2⁶³, with T = a·F + Φ the block's
    start phase. As a function of T, place i is positive on the circular half-open interval
    [s_i, s_i + 2⁶³), s_i = −i·F mod 2⁶⁴: on at s_i, off at e_i = s_i + 2⁶³ mod 2⁶⁴. So count(T) =
    count(0) + #{i: 0 < s_i ≤ T} − #{i: 0 < e_i ≤ T}, a step function read by one binary search per
    block over the B sorted switch points: exact, O(B log B + (N/B)·log B) per column, not N·K.

    Returns
    -------
    ndarray of shape (n_blocks, K), int32
    """
    i = np.arange(block, dtype=np.int64).astype(_U64)
    a = np.arange(n_blocks, dtype=np.int64).astype(_U64) * _U64(block)
    out = np.empty((n_blocks, frequency.size), dtype=np.int32)
    with np.errstate(over="ignore"):
        for k in range(frequency.size):
            f, phi = frequency[k], phase[k]
            step = i * f  # i·F mod 2⁶⁴
            on = np.sort(_U64(0) - step)
            off = np.sort(on + _HALF)
            # count(0) − #{s_i = 0} + #{e_i = 0}: then #{s_i ≤ T} − #{e_i ≤ T} adds the rest.
            base = int(np.count_nonzero(step < _HALF) - np.count_nonzero(on == 0) + np.count_nonzero(off == 0))
            t = a * f + phi
            out[:, k] = base + np.searchsorted(on, t, side="right") - np.searchsorted(off, t, side="right")
    return out
