"""Asymmetric scores of packed sign codes: q · s_i, s_i the ±1 code of row i, read from the packed bytes.

Row i's code is P bits packed 8 to a byte (``np.packbits``, most significant bit first; zero padding
bits to whole bytes); a query is P real values (its projection), zero-padded to the same 8·⌈P/8⌉, so
a padding bit adds nothing, and rounded to a grid on which every sum of its ±values is exact in
float32 (:func:`query_rows`). Two scans then give bit-identical scores — a query's answer does not
depend on the batch it came in — and neither holds an unpacked copy of the codes:

- **lookup tables** (a few queries): faiss ``ProductQuantizer.search_ip`` with ⌈P/8⌉ one-byte
  sub-quantisers whose 256 codewords are the ±1 patterns of a byte — per query a table of 256 partial
  sums per byte, then one lookup per byte of every row, reading the codes in place;
- **blocks** (batches): rows unpacked to ±1 :data:`BLOCK_VALUES` values at a time (``np.take`` of a
  256 × 8 table), one matrix product with a chunk of queries each, merged block by block; its two
  buffers (at most 2 × BLOCK_VALUES float32) are kept per thread between scans.

:data:`TABLE_QUERIES` is where the blocks' one matrix product per block starts to beat a table per
query. Evidence: ``docs/decisions/lsh-projection.md`` (``benchmarks/studies/lsh_projection_scan.py``).
"""

from __future__ import annotations

import threading
from typing import Iterator

import faiss
import numpy as np

from ...core.topk import top_k

__all__ = ["TABLE_QUERIES", "BLOCK_VALUES", "BYTE_SIGNS", "byte_tables", "query_rows", "search", "scores",
           "scan_tables", "scan_blocks"]

#: Batches of fewer queries are scanned by lookup tables, larger ones by blocks.
TABLE_QUERIES = 8
#: Values unpacked (or scored) at a time: 4 MB of float32.
BLOCK_VALUES = 1 << 20
#: The 256 byte values as 8 ±1 values each, most significant bit first (``np.packbits``' order).
BYTE_SIGNS = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).astype(np.float32) * 2 - 1
#: Per-thread work buffers of the block scan (:func:`_buffer`).
_BUFFERS = threading.local()


def byte_tables(n_bytes: int) -> faiss.ProductQuantizer:
    """The table scanner of codes of ``n_bytes`` bytes (8 KB of codewords per byte; a runtime object)."""
    tables = faiss.ProductQuantizer(8 * n_bytes, n_bytes, 8)
    faiss.copy_array_to_vector(np.tile(BYTE_SIGNS.ravel(), n_bytes), tables.centroids)
    return tables


def query_rows(P: np.ndarray, n_bytes: int) -> np.ndarray:
    """Queries (n, P) as the scans take them: contiguous float32 (n, 8·n_bytes), zero-padded, and each row
    rounded to the grid of step 2^(⌈log2(width · max|q|)⌉ − 24), on which every partial sum of ±q_j is
    an integer number of steps below 2²⁴ — exact in float32, so every scan and every summation order
    gives the same scores (and ties the same lower row). At least 2²⁴ / (2·width) steps span max|q|:
    1024 at P = 8192."""
    width = 8 * n_bytes
    out = np.zeros((P.shape[0], width), dtype=np.float32)
    out[:, : P.shape[1]] = P
    bound = np.abs(out).max(axis=1, keepdims=True).astype(np.float64) * width
    step = np.exp2(np.ceil(np.log2(np.where(bound > 0, bound, 1.0))) - 24)
    return (np.rint(out / step) * step).astype(np.float32)


def search(tables: faiss.ProductQuantizer, codes: np.ndarray, P: np.ndarray, k: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """The k best rows per query, best first (ties: lower row first).

    Parameters
    ----------
    tables : faiss.ProductQuantizer
        :func:`byte_tables` of ``codes.shape[1]`` bytes.
    codes : ndarray of shape (n_rows, n_bytes), uint8, C-contiguous
    P : ndarray of shape (n_queries, ≤ 8·n_bytes), float32
    k : int
        At most n_rows.

    Returns
    -------
    scores : ndarray of shape (n_queries, k), float64
    rows : ndarray of shape (n_queries, k), int64
    """
    P = query_rows(P, codes.shape[1])
    if P.shape[0] < TABLE_QUERIES:
        return scan_tables(tables, codes, P, k)
    return scan_blocks(codes, P, k)


def scores(codes: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Every row's score for every query, (n_queries, n_rows) float64, block by block."""
    P = query_rows(P, codes.shape[1])
    out = np.empty((P.shape[0], codes.shape[0]))
    for start, first, block in _row_blocks(codes, P):
        out[first : first + block.shape[0], start : start + block.shape[1]] = block
    return out


def scan_tables(tables: faiss.ProductQuantizer, codes: np.ndarray, P: np.ndarray, k: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`search` by lookup tables (``P`` from :func:`query_rows`)."""
    n = P.shape[0]
    values = np.empty((n, k), dtype=np.float32)
    rows = np.empty((n, k), dtype=np.int64)
    heap = faiss.float_minheap_array_t()
    heap.nh, heap.k, heap.val, heap.ids = n, k, faiss.swig_ptr(values), faiss.swig_ptr(rows)
    tables.search_ip(faiss.swig_ptr(P), n, faiss.swig_ptr(codes), codes.shape[0], heap, True)
    if k > 1:  # faiss' heap keeps the lower rows of a tie but lists them last: best first, then lower row
        order = np.lexsort((rows, -values), axis=1)
        values, rows = np.take_along_axis(values, order, axis=1), np.take_along_axis(rows, order, axis=1)
    return values.astype(np.float64), rows


def _buffer(name: str, size: int) -> np.ndarray:
    """A float32 work buffer of ``size`` values, kept per thread between scans: a fresh array each time
    costs its page faults, which outweighed the product they feed (a few MB, at most BLOCK_VALUES)."""
    buffer = getattr(_BUFFERS, name, None)
    if buffer is None or buffer.size < size:
        buffer = np.empty(size, dtype=np.float32)
        setattr(_BUFFERS, name, buffer)
    return buffer[:size]


def _row_blocks(codes: np.ndarray, P: np.ndarray) -> Iterator[tuple[int, int, np.ndarray]]:
    """Yield (start, first, scores of queries first:… against rows start:…): a block of rows at a time,
    unpacked once to ±1 and scored in chunks of queries, each of at most BLOCK_VALUES values. The scores
    are a reused buffer: read them before the next item."""
    n_rows, n_bytes = codes.shape
    rows = min(n_rows, max(1, BLOCK_VALUES // (8 * n_bytes)))
    chunk = max(1, BLOCK_VALUES // rows)
    for start in range(0, n_rows, rows):
        block = codes[start : start + rows]
        signs = _buffer("signs", block.size * 8).reshape(block.shape[0], n_bytes, 8)
        np.take(BYTE_SIGNS, block, axis=0, out=signs)
        signs = signs.reshape(block.shape[0], 8 * n_bytes)
        for first in range(0, P.shape[0], chunk):
            queries = P[first : first + chunk]
            scores = _buffer("scores", queries.shape[0] * block.shape[0]).reshape(queries.shape[0], -1)
            yield start, first, np.matmul(queries, signs.T, out=scores)


def scan_blocks(codes: np.ndarray, P: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`search` by blocks of unpacked rows (``P`` from :func:`query_rows`), merged block by block."""
    n = P.shape[0]
    best_values, best_rows = np.empty((n, 0)), np.empty((n, 0), dtype=np.int64)
    values: list[np.ndarray] = []
    rows: list[np.ndarray] = []
    for start, first, block in _row_blocks(codes, P):
        block_values, block_rows = top_k(block, min(k, block.shape[1]))
        values.append(block_values)
        rows.append(block_rows + start)
        if first + block.shape[0] < n:  # more chunks of queries of this block of rows to come
            continue
        best_values = np.concatenate([best_values, np.concatenate(values)], axis=1)
        best_rows = np.concatenate([best_rows, np.concatenate(rows)], axis=1)
        values, rows = [], []
        if best_values.shape[1] > k:
            best_values, keep = top_k(best_values, k)
            best_rows = np.take_along_axis(best_rows, keep, axis=1)
    order = top_k(best_values, best_values.shape[1])[1]
    return np.take_along_axis(best_values, order, axis=1), np.take_along_axis(best_rows, order, axis=1)
