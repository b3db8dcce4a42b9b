"""Exact top-k soft decoding of output codes: a bounded search over blocks of places, or one dense product.

A query's K margins m score place i as m · c_i (:mod:`btel.methods.codes.estimator`). Scoring every place costs N·K
multiply-adds, more than flat search's N·d when K > d (the 64 KB model at d = 256 has K = 470).
Route codes need not score every place to be exact:

**Bound and refine** (:class:`BlockDecoder`). Cut the route into blocks of B consecutive places.
On a block a column is either constant (sign s_jk) or varies; then for every place i of block j

    m · c_i ≤ U_j = Σ_{k constant} m_k s_jk + Σ_{k varying} |m_k|,

two small products over the ⌈N/B⌉ blocks (:meth:`btel.methods.codes.codebook.Codebook.block_signs`, computed
in closed form for the periodic family). Blocks are scored exactly in decreasing order of U_j
(a doubling number at a time) until the k-th best exact score exceeds the next block's bound
(plus twice the float32 rounding bound of a K-term sum, so rounding cannot change the answer):
no unscored place can then enter the top k. The answer is that of scoring every place (up to
ties within float32 rounding); only the work depends on how tight the bounds are (a query whose
margins are mostly wrong visits more blocks, at worst all of them, never fewer than needed).

Where the model keeps fewer descriptor columns than code columns (d' < 8⌈K/8⌉), a scored place is read
as q · v_i + v0_i from the *composed rows* v_i = W·c_i (:class:`ComposedRows`, N × d' float32 derived at
the first query): the same score in d' multiply-adds instead of 8⌈K/8⌉, the bounds unchanged and the
pruning slack widened by the rounding the two computations can differ by.

**One dense product**: ``M @ C.T`` over the ±1 codewords expanded once to float32 (N·8⌈K/8⌉·4
bytes, kept only up to :data:`DENSE_CACHE_BYTES`). BLAS-3, the cheapest for batches.

Which one runs (:func:`choose_path`) is a measured rule: ``benchmarks/bench_codes.py`` times
both (and faiss' packed scan) per N; see :func:`choose_path`'s docstring.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..base import top_k
from .codebook import Codebook

__all__ = ["BlockDecoder", "ComposedRows", "DENSE_CACHE_BYTES", "BATCH_DENSE_FROM", "block_size", "choose_path", "composes", "best_of", "byte_table", "packed_scores", "BYTE_SIGNS",
           "DENSE_SMALL_VALUES", "PROBE_QUERIES"]

#: Largest float32 codeword cache (N × 8⌈K/8⌉ × 4 bytes) kept for the dense product (32 MB).
DENSE_CACHE_BYTES = 32 << 20
#: From this many queries in one call a dense product over every place may beat the per-query bounded search
#: (on maps of at most :data:`DENSE_BATCH_MAX_VALUES` codeword values; :func:`choose_path`).
BATCH_DENSE_FROM = 16
#: Up to this many codeword values (N × 8⌈K/8⌉, 2 MB of float32) every query is decoded densely: one
#: query's dense product and bounded search cost the same at about 0.7–1 M values (one BLAS thread,
#: ``benchmarks/bench_codes.py``: at 472 000 values 30 against 40 µs, at 944 000 49 against 46 µs).
DENSE_SMALL_VALUES = 1 << 19
#: Queries of a batch decoded by the bounded search to measure how many places it scores.
PROBE_QUERIES = 8
#: Nanoseconds per codeword value (from ``benchmarks/bench_codes.py``): the dense product (per query of a
#: batch) and the bounded search (per value of a scored place), plus the bounded search's per-query overhead.
DENSE_NS, BOUNDED_NS, BOUNDED_OVERHEAD_NS = 0.05, 0.2, 40_000.0
#: Packed bytes looked up at a time when blocks are scored from packed codewords (≈ 1 M: a few MB of temporaries).
LOOKUP_VALUES = 1 << 20
#: Blocks scored in the first round of the bounded search (then 2×, 4×, … more per round).
FIRST_BLOCKS = 8
#: The ±1 values of the 8 bits of every byte (bit j → column j), float32 (256, 8).
BYTE_SIGNS = (((np.arange(256)[:, None] >> np.arange(8)) & 1) * 2.0 - 1.0).astype(np.float32)


def block_size(n_places: int) -> int:
    """B, places per block of the bounded search: ≈ √N, within [8, 1024].

    Bounds cost 2·(N/B)·K per query and the visited blocks v·B·K. The blocks a query needs fall
    slowly as B grows, and every round of blocks costs Python overhead, so B ≈ √N (a few rounds
    of ≈ 8–16 blocks) balances the two (``benchmarks/bench_codes.py``).
    """
    return int(min(1024, max(8, round(np.sqrt(n_places)))))


def byte_table(m: np.ndarray) -> np.ndarray:
    """m's 256 partial sums of every 8 columns, float32 (8⌈K/8⌉ / 8 × 256,): entry g·256 + b is the
    sum of m over the 8 columns of group g signed by the bits of byte value b (:data:`BYTE_SIGNS`)."""
    return (m.reshape(-1, 8) @ BYTE_SIGNS.T).ravel()


def packed_scores(table: np.ndarray, packed_of, places: np.ndarray) -> np.ndarray:
    """m · c_i (float32) of the given places from their packed codewords: one look-up of :func:`byte_table` per byte.

    ``packed_of(places)`` gives the (n, groups) uint8 packed codewords. The look-ups run
    :data:`LOOKUP_VALUES` bytes at a time, so the indices and gathered partial sums stay a few MB
    however many places a query scores.
    """
    groups = table.size // 256
    # Index g·256 + b: uint16 while it fits (groups ≤ 256, K ≤ 2048), else uint32.
    rows = (np.arange(groups) * 256).astype(np.uint16 if groups <= 256 else np.uint32)
    scores = np.empty(places.size, dtype=np.float32)
    step = max(1, LOOKUP_VALUES // groups)
    for a in range(0, places.size, step):
        scores[a : a + step] = np.take(table, packed_of(places[a : a + step]) + rows).sum(axis=1)
    return scores


def best_of(scores: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Top k of every row of (n, N) scores: (float64 scores, int64 places), ties to the lower place."""
    if k == 1:  # argmax: the first maximum, i.e. ties to the lower place as top_k
        places = np.argmax(scores, axis=1)[:, None]
        return np.take_along_axis(scores, places, axis=1).astype(np.float64), places.astype(np.int64)
    values, places = top_k(scores, k)
    return values.astype(np.float64, copy=False), places.astype(np.int64, copy=False)


def composes(n_places: int, n_selected: int, n_codes: int, width: int) -> bool:
    """Whether to score places by one composed linear map of the query, V = W·Cᵀ (d' × N), not margins then codewords.

    A place's score m · c_i = (q·W + b) · c_i = q · (W c_i) + b · c_i is linear in the query, so
    V = W·Cᵀ and v0 = b·Cᵀ (derived at the first query from the stored weights and the regenerated
    codewords: a runtime cache, no stored byte) score every place with d'·N multiply-adds, against
    d'·K + N·8⌈K/8⌉ for the margins and the dense decode. Used where that is fewer (maps with fewer
    places than code columns: the margins alone cost more than scoring every place) on maps the
    dense decode serves (N·8⌈K/8⌉ ≤ :data:`DENSE_SMALL_VALUES`) and while V fits
    :data:`DENSE_CACHE_BYTES`. The sums run in another order than the two products', so scores
    differ within float32 rounding (exact answers up to near-ties, as the other paths).
    """
    if n_places * width > DENSE_SMALL_VALUES or n_selected * n_places * 4 > DENSE_CACHE_BYTES:
        return False
    return n_selected * n_places < n_selected * n_codes + n_places * width


def choose_path(n_places: int, width: int, n_queries: int, route: bool, dense_cached: bool,
                visited: float | None = None) -> str:
    """The exact decode to run: 'bounded', 'dense', 'scan' (faiss' packed scan) or 'probe'.

    Rule, from ``benchmarks/bench_codes.py`` (results in ``benchmarks/results/bench_codes*.json``;
    one BLAS thread):

    - 'random' codes have no blocks to bound: 'dense' while the float32 codewords are cached
      (N·8⌈K/8⌉·4 ≤ :data:`DENSE_CACHE_BYTES`), else 'scan';
    - a small map (N·8⌈K/8⌉ ≤ :data:`DENSE_SMALL_VALUES`): 'dense' (the bounded search's bounds
      and rounds would cost more than scoring every place);
    - a batch (≥ :data:`BATCH_DENSE_FROM` queries) with the codewords cached: 'probe' — decode the
      first :data:`PROBE_QUERIES` by the bounded search, then call again with ``visited``, the
      fraction of places they scored: 'dense' when N·W·:data:`DENSE_NS` is below
      visited·N·W·:data:`BOUNDED_NS` + :data:`BOUNDED_OVERHEAD_NS` (per query: the dense product
      reads every codeword at BLAS speed, the bounded search a few blocks and their bounds;
      :data:`BOUNDED_NS` was measured with the blocks scored by table look-ups, which the
      float32 products now replace while the codewords are cached, so it overstates that cost),
      else 'bounded';
    - otherwise 'bounded' (single queries on larger maps: faster than faiss' packed scan and the
      dense product).
    """
    if not route:
        return "dense" if dense_cached else "scan"
    if dense_cached and n_places * width <= DENSE_SMALL_VALUES:
        return "dense"
    if dense_cached and n_queries >= BATCH_DENSE_FROM:
        if visited is None:
            return "probe"
        values = n_places * width
        return "dense" if values * DENSE_NS < visited * values * BOUNDED_NS + BOUNDED_OVERHEAD_NS else "bounded"
    return "bounded"


class ComposedRows(NamedTuple):
    """Place scores as one linear map of the query, read row by row: q · v_i + v0_i = m · c_i.

    For d' < 8⌈K/8⌉ a scored place then costs d' multiply-adds instead of 8⌈K/8⌉ (the 64 KB model at
    N = 10⁴, d = 256: 256 against 472, about half the memory read per place).
    """

    #: (N, d') float32, row i = W·c_i (the weights times place i's codeword).
    rows: np.ndarray
    #: (N,) float32, b · c_i.
    offset: np.ndarray
    #: (d',) float64: a query's extra rounding bound is 2⁻²² · (|q| @ error + error0), covering the
    #: float32 margins, the float32 rows and the float32 row products against exact arithmetic.
    error: np.ndarray
    error0: float

    @classmethod
    def build(cls, dense: np.ndarray, weights: np.ndarray, bias: np.ndarray) -> "ComposedRows":
        """From the (N, W) float32 ±1 codewords and the (d', W) float32 weights and (W,) biases."""
        rows = np.ascontiguousarray(dense @ weights.T)
        d, width = weights.shape
        weight_sums = np.abs(weights).sum(axis=1, dtype=np.float64)
        terms = d + width + 2  # the longest float32 sums a score passes through
        error = terms * weight_sums + d * np.abs(rows).max(axis=0).astype(np.float64)
        return cls(rows, (dense @ bias).astype(np.float32), error,
                   float(terms * np.abs(bias).sum(dtype=np.float64)))


class BlockDecoder:
    """Bounded exact top-k over blocks of places (module docstring), codewords read from a source.

    Parameters
    ----------
    codebook : Codebook
    width : int
        8⌈K/8⌉: margins and codewords are zero-padded / +1-padded to whole bytes.
    packed_of : callable
        ``packed_of(places)`` → uint8 (len(places), width / 8) packed codewords (bit j % 8 of
        byte j // 8 is column j), read when the float32 codewords are not cached (``dense``): a
        place is scored by one table look-up per byte (the query's 256 partial sums of every 8
        columns), 1/32 of the memory traffic of float32 codewords gathered row by row.
    block : int, optional
        B (default :func:`block_size`).
    dense : ndarray of shape (N, width), float32, optional
        The float32 codewords when cached: a block is then B consecutive rows, scored by one
        matrix-vector product per run of consecutive blocks without a copy (3–4× faster than the
        table look-ups at N = 10⁴, ``benchmarks/bench_codes.py``).
    """

    def __init__(self, codebook: Codebook, width: int, packed_of, block: int | None = None,
                 dense: np.ndarray | None = None) -> None:
        n, K = int(codebook.n_places), int(codebook.n_codes)
        self.n_places = n
        self.block = int(block) if block is not None else block_size(n)
        signs = codebook.block_signs(self.block)
        self.constant = np.zeros((signs.shape[0], width), dtype=np.float32)
        self.constant[:, :K] = signs
        self.varying = np.zeros_like(self.constant)
        self.varying[:, :K] = signs == 0
        self.packed_of, self.width, self.dense = packed_of, width, dense
        self._offsets = np.arange(self.block)
        self._stacked: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        return int(self.constant.nbytes + self.varying.nbytes + (0 if self._stacked is None else self._stacked.nbytes))

    def stacked(self) -> np.ndarray:
        """(⌈N/B⌉, 2·width) float32 [constant | varying], built once: a query's bounds are one product with [m, |m|]."""
        if self._stacked is None:
            self._stacked = np.ascontiguousarray(np.hstack([self.constant, self.varying]))
        return self._stacked

    def bounds(self, M: np.ndarray) -> np.ndarray:
        """U (n, ⌈N/B⌉) float32: an upper bound of m · c_i over every place of each block."""
        return M @ self.constant.T + np.abs(M) @ self.varying.T

    def search(self, M: np.ndarray, k: int, composed: ComposedRows | None = None,
               queries: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact top k of m · c_i per row of M (n, width) float32.

        With ``composed`` and ``queries`` (n, d') float32 (the transformed queries whose margins are M),
        scored places are read from the composed rows (q · v_i + v0_i) instead of the codewords; the
        bounds still come from M, and the pruning slack grows by the rounding the two computations
        can differ by (:class:`ComposedRows`).

        Returns
        -------
        scores : (n, k) float64; places : (n, k) int64; visited : (n,) int64, blocks scored per query
        """
        n_blocks = self.constant.shape[0]
        absolute = np.abs(M)
        U = M @ self.constant.T + absolute @ self.varying.T  # self.bounds(M), reusing |M|
        # Twice the worst rounding of a float32 sum of `width` terms of size ≤ |m_k| (bound and score).
        slacks = (2.0 * self.width * 2.0**-23) * absolute.sum(axis=1, dtype=np.float64)
        if composed is not None:
            slacks += 2.0**-22 * (np.abs(queries) @ composed.error + composed.error0)
        out_s = np.empty((M.shape[0], k))
        out_p = np.empty((M.shape[0], k), dtype=np.int64)
        visited = np.empty(M.shape[0], dtype=np.int64)
        step = min(max(FIRST_BLOCKS, -(-k // self.block)), n_blocks)
        for q in range(M.shape[0]):
            m, u = M[q], U[q]
            # The vector scored places are read against: the query (composed rows), else the margins.
            rows = (composed.rows, queries[q], composed.offset) if composed is not None else \
                None if self.dense is None else (self.dense, m, None)
            # m's 256 partial sums of every 8 columns (the packed codewords' look-up table)
            table = byte_table(m) if rows is None else None
            # Round 1: the blocks of highest bound. Round 2: every other block whose bound exceeds the
            # k-th best score found (the k-th best only rises, so nothing past round 2 can enter).
            take = np.sort(np.argpartition(u, n_blocks - step)[n_blocks - step :]) if step < n_blocks \
                else np.arange(n_blocks)
            places, scores = self._score_blocks(take, rows, table)
            done, merged = take.size, False
            if done < n_blocks:
                if k == 1:
                    kth = scores.max()
                else:
                    kth = np.partition(scores, scores.size - k)[scores.size - k] if scores.size >= k else -np.inf
                u[take] = -np.inf  # U is this call's own array: scored blocks leave the race
                more = np.flatnonzero(u >= kth - slacks[q])
                if more.size:
                    p2, s2 = self._score_blocks(more, rows, table)
                    places, scores = np.concatenate([places, p2]), np.concatenate([scores, s2])
                    done, merged = done + more.size, True
            if k == 1:  # the best score, ties to the lower place as in a full scan (NaN: the first, as argmax)
                i = int(np.argmax(scores))
                best = scores[i]
                # Places ascend within a round; after two rounds a tie may sit at a lower place.
                place = places[scores == best].min() if merged and best == best else places[i]
                out_s[q, 0], out_p[q, 0] = best, place
            else:  # places ascend within a round: sorted, ties go to the lower place as in a full scan
                by_place = np.argsort(places, kind="stable")
                kept_s, cols = top_k(scores[by_place].astype(np.float64)[None], k)
                out_s[q], out_p[q] = kept_s[0], places[by_place][cols[0]]
            visited[q] = done
        return out_s, out_p, visited

    def search_one(self, m: np.ndarray, composed: ComposedRows | None = None,
                   query: np.ndarray | None = None) -> tuple[float, int]:
        """Exact best place of one query (k = 1): :meth:`search`'s answer with the fewest calls per query.

        The same bounds, slack and two rounds as :meth:`search`, for a single row read against the
        float32 codewords (``dense``) or the composed rows: the bounds are one product with the
        stacked [constant | varying] signs, and the scored blocks are read run by run of consecutive
        blocks, each run reduced to its maximum at once (no concatenation of scores or places).

        Parameters
        ----------
        m : ndarray of shape (width,), float32
            Padded margins (finite).
        composed, query : ComposedRows and ndarray of shape (d',), float32, optional
            Read scored places as q · v_i + v0_i (as :meth:`search`); else the codewords (``dense``
            must be cached).

        Returns
        -------
        (score, place) : the best score as a Python float (it may be NaN or ±inf when the sums
        overflow: the caller checks) and its place, ties to the lower place.
        """
        n_blocks = self.constant.shape[0]
        absolute = np.abs(m)
        u = self.stacked() @ np.concatenate((m, absolute))
        slack = (2.0 * self.width * 2.0**-23) * float(absolute.sum(dtype=np.float64))
        if composed is not None:
            slack += 2.0**-22 * (float(np.abs(query) @ composed.error) + composed.error0)
            matrix, vector, offset = composed.rows, query, composed.offset
        else:
            matrix, vector, offset = self.dense, m, None
        step = min(FIRST_BLOCKS, n_blocks)
        take = np.arange(n_blocks) if step == n_blocks else np.argpartition(u, n_blocks - step)[n_blocks - step :]
        take.sort()
        best, place = self._best_of_blocks(take.tolist(), matrix, vector, offset, -math.inf, -1)
        if step < n_blocks and best == best:  # round 2 (a NaN best is returned as it is, for the caller's check)
            u[take] = -np.inf
            more = np.flatnonzero(u >= best - slack)
            if more.size:
                best, place = self._best_of_blocks(more.tolist(), matrix, vector, offset, best, place)
        return best, place

    def _best_of_blocks(self, blocks: list[int], matrix: np.ndarray, vector: np.ndarray, offset: np.ndarray | None,
                        best: float, place: int) -> tuple[float, int]:
        """The best (score, place) over the given ascending blocks and a running (best, place); ties to the
        lower place; a NaN score of a run becomes the answer (so the caller's finiteness check sees it)."""
        B, n = self.block, self.n_places
        i = 0
        while i < len(blocks):
            j = i
            while j + 1 < len(blocks) and blocks[j + 1] == blocks[j] + 1:
                j += 1
            a, b = blocks[i] * B, min(n, (blocks[j] + 1) * B)
            scores = matrix[a:b] @ vector
            if offset is not None:
                scores += offset[a:b]
            r = int(scores.argmax())  # the first maximum (the first NaN, if any)
            value = float(scores[r])
            if value != value:
                return value, a + r
            if value > best or (value == best and a + r < place):
                best, place = value, a + r
            i = j + 1
        return best, place

    def _score_blocks(self, take: np.ndarray, rows: tuple | None, table: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(places, float32 m · c_i) of every place of the given sorted blocks.

        From ``rows`` = (matrix, vector, offset or None) — the float32 codewords and the margins, or the
        composed rows and the query — one product per run of consecutive blocks; else one table
        look-up per byte of the packed codewords.
        """
        if rows is not None:
            B, n, (dense, m, offset) = self.block, self.n_places, rows
            runs: list[list[int]] = []  # [start, stop) of runs of consecutive blocks
            for j in take.tolist():
                if runs and runs[-1][1] == j * B:
                    runs[-1][1] = min(n, (j + 1) * B)
                else:
                    runs.append([j * B, min(n, (j + 1) * B)])
            if len(runs) == 1:
                a, b = runs[0]
                scores = dense[a:b] @ m
                if offset is not None:
                    scores += offset[a:b]
                return np.arange(a, b), scores
            scores = np.concatenate([dense[a:b] @ m for a, b in runs])
            if offset is not None:
                scores += np.concatenate([offset[a:b] for a, b in runs])
            return np.concatenate([np.arange(a, b) for a, b in runs]), scores
        places = (take[:, None] * self.block + self._offsets).ravel()
        places = places[places < self.n_places]
        return places, packed_scores(table, self.packed_of, places)
