"""The codebook at inference: codewords derived once from (family, N, K, seed) and kept while queries come.

Nothing here is stored in a model file: :class:`Codewords` regenerates what the decoders of
:class:`~btel.methods.codes.estimator.CodeLocalizer` multiply by, in the cheapest form for the map —

- ``dense()``: the (N, 8⌈K/8⌉) float32 ±1 codewords, when small
  (:data:`~btel.methods.codes.decoding.DENSE_CACHE_BYTES`): one BLAS product scores every place;
- ``packed_rows()``: the (N, ⌈K/8⌉) packed codebook up to :data:`PACKED_CACHE_BYTES`, each place
  filled when first read (:meth:`Codewords.fill`), so the first query after ``load`` generates only
  the codewords it scores;
- ``adc_index()``: faiss' packed PQ scan, for the 'random' family past the dense cache;
- ``decoder()``: the bounded search's block bounds (:class:`~btel.methods.codes.decoding.BlockDecoder`);
- ``block_means()`` and :meth:`Codewords.coarse_search`: the coarse-to-fine decode of long maps.

**Coarse to fine.** The exact decode costs N·K per query. For route families on long maps the
route is cut into blocks of B consecutive places, each block is scored by its *mean* codeword
(⌈N/B⌉ × K values), which equals the mean score of the block's places, and only the places of
the best blocks are scored exactly (by faiss' packed scan of their codewords: :class:`CandidateScan`). Long-period columns are nearly constant on a block, so they
carry the coarse score; short-period ones average out. It is approximate: the true best place may
sit in a block whose mean is not among the best (``benchmarks/bench_codes.py`` measures the loss).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import numpy as np

from ..base import top_k
from ...core.threads import blas_threads, blas_threads_for_vector
from .codebook import Codebook
from .decoding import BYTE_SIGNS, DENSE_CACHE_BYTES, BlockDecoder, byte_table, packed_scores

__all__ = ["Codewords", "PackedScan", "RuntimeCache", "blas_for", "blas_for_decode", "BLOCK_VALUES", "PACKED_CACHE_BYTES",
           "SCAN_TABLE_VALUES"]

#: The codebook is cached at inference as packed bits (N × ⌈K/8⌉ bytes) up to this size (256 MB).
PACKED_CACHE_BYTES = 1 << 28
#: Values (rows × columns) of one block of scores or codes at inference (about 16 MB of float32).
BLOCK_VALUES = 1 << 22
#: Look-up table values (queries × ⌈K/8⌉ × 256) of one call to faiss' packed scan (4 MB of float32).
SCAN_TABLE_VALUES = 1 << 20
#: Missing places at most this far apart are generated as one run (the places between included).
FILL_GAP = 64
#: Past this many runs of missing places, the places are generated in one call, not run by run.
FILL_RUNS = 64
#: Below this many multiply-adds a decode runs its BLAS products on one thread (see blas_for).
_SMALL_PRODUCT = 1 << 27


def blas_for(n_queries: int, work_per_query: int) -> Any:
    """One BLAS thread for the decode's products, unless a large batch (where a second thread can pay).

    The decode's products are small (a batch's margins, one query's coarse scores): BLAS' own
    threads spin against other processes on a shared machine and cost more than they save, while
    setting the limit per call costs less than the timing noise.
    """
    if n_queries > 64 and n_queries * work_per_query >= _SMALL_PRODUCT:
        return blas_threads(None)
    return blas_threads(1)


def blas_for_decode(n_queries: int, largest_product: int) -> Any:
    """One BLAS thread for a decode's small products; for one query, none set while its largest
    matrix-vector product (``largest_product`` multiply-adds) is one BLAS runs on one thread anyway
    (:func:`~btel.core.threads.blas_threads_for_vector`: setting and restoring a limit costs ≈ 4–5 µs)."""
    return blas_threads_for_vector(largest_product) if n_queries == 1 else blas_threads(1)


class PackedScan:
    """faiss' packed PQ scan (``index``, an IndexPQ) searched a few queries at a time.

    faiss builds the look-up tables of every query of a call at once (⌈K/8⌉ × 256 float32 per
    query: 60 MB for 1,000 queries at K = 470, as much as the codes themselves), so a batch is cut
    into chunks whose tables hold about :data:`SCAN_TABLE_VALUES` values. Queries are independent:
    the answers are those of one call.
    """

    def __init__(self, index: Any) -> None:
        self.index = index

    def search(self, M: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """faiss' ``search`` (scores (n, k) float32, places (n, k) int64), chunk by chunk."""
        step = max(1, SCAN_TABLE_VALUES // (int(self.index.pq.M) * int(self.index.pq.ksub)))
        if M.shape[0] <= step:
            return self.index.search(M, k)
        parts = [self.index.search(M[a : a + step], k) for a in range(0, M.shape[0], step)]
        return np.concatenate([s for s, _ in parts]), np.concatenate([p for _, p in parts])


def _pattern_index(groups: int) -> Any:
    """An empty faiss.IndexPQ whose 256 centroids per group of 8 columns are the ±1 patterns of a byte, trained.

    Its inner-product scan of packed codewords computes m · c_i (:meth:`Codewords.adc_index`).
    """
    import faiss

    index = faiss.IndexPQ(8 * groups, groups, 8, faiss.METRIC_INNER_PRODUCT)
    faiss.copy_array_to_vector(np.tile(BYTE_SIGNS, (groups, 1)).ravel(), index.pq.centroids)
    index.is_trained = True
    return index


class CandidateScan:
    """m · c_i of a query's candidate places by faiss' packed scan: the pattern index's codes replaced by theirs.

    The coarse decode refines a few thousand places per query; faiss builds the query's ⌈K/8⌉ × 256 table and
    sums one entry per byte in C++, several times faster than the same look-ups in numpy. The index holds
    only the candidates of the current call, gathered straight into its code array (a runtime buffer sized
    once for the most candidates a call may have: ``capacity`` places).
    """

    def __init__(self, groups: int, capacity: int) -> None:
        self.groups = groups
        self.index = _pattern_index(groups)
        self.view = _codes_view(self.index, capacity, groups)

    def search(self, m: np.ndarray, packed: np.ndarray, runs: list[tuple[int, int]],
               k: int) -> tuple[np.ndarray, np.ndarray]:
        """(scores (k,) float32, rows (k,) int64), best first, for margins (1, 8·groups) float32 over the packed
        codewords of the places of ``runs`` ((start, stop) ranges, in order; at most ``capacity`` places in all)
        of ``packed`` ((N, groups) uint8), rows counted along the runs' places."""
        view, size = self.view, 0
        for start, stop in runs:  # one copy per run of consecutive places, not one per place
            view[size : size + stop - start] = packed[start:stop]
            size += stop - start
        self.index.ntotal = size
        scores, rows = self.index.search(m, k)
        return scores[0], rows[0]


def _codes_view(index: Any, n: int, code_size: int) -> np.ndarray:
    """A writable (n, code_size) uint8 view of a faiss flat-codes index's code array, resized to n codes.

    The array is allocated once at its final size (adding codes in batches grows faiss' vector,
    and each growth briefly holds the old and the new buffer). The caller fills the view, then sets
    ``index.ntotal``; the view is valid until the index's codes are resized again.
    """
    import faiss

    index.codes.resize(n * code_size)
    return faiss.rev_swig_ptr(index.codes.data(), n * code_size).reshape(n, code_size)


class Codewords:
    """The codewords of one fitted codebook in the forms inference reads (a runtime cache, one per model).

    Parameters
    ----------
    codebook : Codebook

    Attributes
    ----------
    width : int
        8⌈K/8⌉: K rounded up to whole bytes, the width of the codewords and margins the decoders
        multiply (padding columns are +1 codewords against zero margins, so they add nothing).
    packed : ndarray of shape (N, ⌈K/8⌉), uint8, or None
        Packed codewords (+1 → bit 1, column j in bit j % 8 of byte j // 8), filled on demand.
    filled : ndarray of shape (N,), bool, or None
        Which places of ``packed`` are filled.
    """

    def __init__(self, codebook: Codebook) -> None:
        self.codebook = codebook
        self.n_places = int(codebook.n_places)
        self.n_codes = int(codebook.n_codes)
        self.width = 8 * -(-self.n_codes // 8)
        self.codes: np.ndarray | None = None
        self.packed: np.ndarray | None = None
        self.filled: np.ndarray | None = None
        self.index: PackedScan | None = None
        self._decoder: BlockDecoder | None = None
        self.means: tuple[int, np.ndarray] | None = None
        self.candidates: CandidateScan | None = None
        # The codebook's work arrays (and the periodic r·F table), kept between fills: one set per thread,
        # since numpy releases the GIL inside the ufuncs that write them.
        self._local = threading.local()
        self._allocating = threading.Lock()

    def dense(self) -> np.ndarray | None:
        """(N, 8⌈K/8⌉) float32 ±1 codewords when they fit :data:`~btel.methods.codes.decoding.DENSE_CACHE_BYTES`, else None.

        Built once (the only copy of the codebook then: no packed bits are kept).
        """
        n, width = self.n_places, self.width
        if n * width * 4 > DENSE_CACHE_BYTES:
            return None
        if self.codes is None:
            codes = np.ones((n, width), dtype=np.float32)
            for a, b, block in self.codebook.iter_blocks():
                codes[a:b, : self.n_codes] = block
            self.codes = codes
        return self.codes

    def packed_rows(self, places: np.ndarray) -> np.ndarray | None:
        """Packed codewords (len(places), ⌈K/8⌉) uint8 of the given places, or None past :data:`PACKED_CACHE_BYTES`.

        The (N, ⌈K/8⌉) array is allocated once and filled place by place when first read
        (:meth:`fill`; untouched pages cost no memory).
        """
        return self.packed[places] if self.fill(places) else None

    def fill(self, places: np.ndarray) -> bool:
        """Make the packed codewords of ``places`` present in :attr:`packed` (False past the cache's size:
        :data:`PACKED_CACHE_BYTES`).

        Only places not yet filled are generated: each run of them (gaps of up to :data:`FILL_GAP`
        places bridged, so a block of places is one call) from its first place to its last; past
        :data:`FILL_RUNS` runs (places scattered over the map), the places themselves in one call.
        """
        n, groups = self.n_places, -(-self.n_codes // 8)
        if n * groups > PACKED_CACHE_BYTES:
            return False
        if self.filled is None:
            with self._allocating:  # two threads filling a fresh cache must share one pair of arrays
                if self.filled is None:
                    self.packed = np.empty((n, groups), dtype=np.uint8)
                    self.filled = np.zeros(n, dtype=bool)  # last: a thread that sees it sees packed too
        have = self.filled[places]
        if have.all():
            return True
        missing = places[~have]
        if missing.size > 1 and not (missing[1:] > missing[:-1]).all():  # the coarse decode's come sorted
            missing = np.sort(missing)  # sort and mask: np.unique (numpy 2.4) took 0.5 ms on 3,000 places
            missing = missing[np.concatenate(([True], missing[1:] != missing[:-1]))]
        breaks = np.flatnonzero(np.diff(missing) > FILL_GAP) + 1
        work = self._thread_work()
        if breaks.size >= FILL_RUNS:
            self.packed[missing] = self.codebook.packed(missing, work=work)
            self.filled[missing] = True
            return True
        for run in np.split(missing, breaks):
            a, b = int(run[0]), int(run[-1]) + 1
            self.codebook.packed(np.arange(a, b), out=self.packed[a:b], work=work)
            self.filled[a:b] = True  # after the bytes: another thread reads a place only once it is marked
        return True

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_local"] = state["_allocating"] = None  # per process and thread: not pickled
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._local = threading.local()
        self._allocating = threading.Lock()

    def _thread_work(self) -> dict:
        work = getattr(self._local, "work", None)
        if work is None:
            work = self._local.work = {}
        return work

    def packed_of(self, places: np.ndarray) -> np.ndarray:
        """Packed codewords of the given places: from the cache, or generated past its size limit."""
        packed = self.packed_rows(places)
        if packed is None:
            packed = self.codebook.packed(places)
        return packed

    def of(self, places: np.ndarray) -> np.ndarray:
        """±1 codewords of the given places, float32 (n, 8⌈K/8⌉): padding columns are +1 (× zero margins)."""
        places = np.asarray(places, dtype=np.intp)
        dense = self.dense()
        if dense is not None:
            return dense[places]
        packed = self.packed_rows(places)
        if packed is None:
            codes = np.ones((len(places), self.width), dtype=np.float32)
            codes[:, : self.n_codes] = self.codebook.codewords(places)
            return codes
        # One table look-up per byte: the 8 ±1 values of its bits.
        return BYTE_SIGNS[packed].reshape(len(places), -1)

    def blocks(self, rows: int | None = None) -> Iterator[tuple[int, int, np.ndarray]]:
        """Yield (start, stop, codewords float32 (stop − start, 8⌈K/8⌉)) over consecutive blocks of places."""
        n = self.n_places
        rows = rows or max(1, BLOCK_VALUES // self.n_codes)
        for a in range(0, n, rows):
            b = min(n, a + rows)
            yield a, b, self.of(np.arange(a, b))

    def adc_index(self) -> PackedScan | None:
        """faiss.IndexPQ over the packed codewords whose scan computes m · c_i exactly (or None), in a :class:`PackedScan`.

        The soft decode is an asymmetric-distance scan: cut the K columns into groups of 8, a group
        of a codeword is one byte, and the 256 "centroids" of every group are the 256 ±1 patterns
        of 8 columns. faiss' inner-product PQ scan then sums, per place, one table entry per group
        (⌈K/8⌉ look-ups instead of K multiply-adds). Only for the 'random' family past the dense
        cache (no blocks to bound). The index's code array is sized once and its codes are written
        in place block by block (:func:`_codes_view`; :meth:`Codebook.packed`, straight from the
        hashes' bytes under the random family's current rule): it holds the only copy, and no
        growth of faiss' vector ever holds two.
        """
        if self.index is None:
            n, groups = self.n_places, -(-self.n_codes // 8)
            if n * groups > PACKED_CACHE_BYTES:
                return None
            index = _pattern_index(groups)
            codes_out = _codes_view(index, n, groups)
            rows, work = max(1, BLOCK_VALUES // (8 * groups)), {}  # about 0.5 M packed bytes a step
            for a in range(0, n, rows):
                self.codebook.packed(np.arange(a, min(n, a + rows)), out=codes_out[a : a + rows], work=work)
            index.ntotal = n
            self.index = PackedScan(index)
        return self.index

    def decoder(self) -> BlockDecoder:
        """The bounded exact search over blocks of places (:mod:`btel.methods.codes.decoding`), built once."""
        if self._decoder is None:
            self._decoder = BlockDecoder(self.codebook, self.width, self.packed_of, dense=self.dense())
        return self._decoder

    def block_means(self, block: int) -> np.ndarray:
        """(⌈N/B⌉, 8⌈K/8⌉) float32 mean codeword of every block of B consecutive places (the last may be shorter).

        From the exact integer sums of :meth:`Codebook.block_sums` (closed form for the periodic
        family), each divided by its block's length in float32; padding columns are +1.
        """
        if self.means is None or self.means[0] != block:
            n_blocks = -(-self.n_places // block)
            lengths = np.minimum(block, self.n_places - block * np.arange(n_blocks)).astype(np.float32)
            means = np.ones((n_blocks, self.width), dtype=np.float32)
            np.divide(self.codebook.block_sums(block), lengths[:, None], out=means[:, : self.n_codes], dtype=np.float32)
            self.means = (block, means)
        return self.means[1]

    def coarse_search(self, M: np.ndarray, k: int, block: int, candidates: int) -> tuple[np.ndarray, np.ndarray]:
        """Score blocks by their mean codeword, then every place of the ``candidates`` best blocks exactly.

        Parameters
        ----------
        M : ndarray of shape (n, 8⌈K/8⌉), float32
            Padded margins.

        Returns
        -------
        scores : ndarray of shape (n, k), float64
        places : ndarray of shape (n, k), int64
        """
        n_places = self.n_places
        means = self.block_means(block)
        out_s = np.empty((M.shape[0], k))
        out_p = np.empty((M.shape[0], k), dtype=np.int64)
        n_blocks = means.shape[0]
        offsets = np.arange(block)
        step = max(1, BLOCK_VALUES // n_blocks)  # queries whose coarse scores are held at once
        for a in range(0, M.shape[0], step):
            coarse = M[a : a + step] @ means.T
            for q in range(coarse.shape[0]):
                m = M[a + q]
                blocks = np.sort(np.argpartition(coarse[q], n_blocks - candidates)[n_blocks - candidates :]) \
                    if candidates < n_blocks else np.arange(n_blocks)
                # Candidates in place order, so that ties go to the lower place as in the exact decode.
                places = (blocks[:, None] * block + offsets).ravel()
                if blocks[-1] == n_blocks - 1:  # the last block may be shorter
                    places = places[places < n_places]
                if not self.fill(places):  # past the packed cache: numpy look-ups of generated codewords
                    scores = packed_scores(byte_table(m), self.packed_of, places)
                    values, cols = top_k(scores.astype(np.float64)[None], k)
                    out_s[a + q], out_p[a + q] = values[0], places[cols[0]]
                    continue
                if self.candidates is None or self.candidates.view.shape[0] < candidates * block:
                    self.candidates = CandidateScan(self.packed.shape[1], candidates * block)
                runs = block_runs(blocks, block, n_places)
                values, rows = self.candidates.search(M[a + q : a + q + 1], self.packed, runs, k)
                # The scan's order; among equal scores the lower place first, as the exact decode.
                order = np.lexsort((places[rows], -values.astype(np.float64)))
                out_s[a + q], out_p[a + q] = values[order], places[rows[order]]
        return out_s, out_p


def block_runs(blocks: np.ndarray, block: int, n_places: int) -> list[tuple[int, int]]:
    """The (start, stop) place ranges of sorted block indices, adjacent blocks merged into one range."""
    runs: list[tuple[int, int]] = []
    for j in blocks.tolist():
        start, stop = j * block, min((j + 1) * block, n_places)
        if runs and runs[-1][1] == start:
            runs[-1] = (runs[-1][0], stop)
        else:
            runs.append((start, stop))
    return runs


class RuntimeCache:
    """What inference derives from a fitted model once (not stored, not compared: one object per model).

    ``weights``: the padded float32 dequantised weights and biases, built at the first query; ``columns``:
    the kept descriptor columns as intp; ``codewords``: the codebook at inference (:class:`Codewords`);
    ``composed``: :meth:`composed_map`; ``composed_rows``: the same map row by row for the bounded search. Queries fill these in place, so
    predicting leaves the estimator's ``__dict__`` unchanged (the scikit-learn contract).
    """

    def __init__(self, codebook: Codebook) -> None:
        self.weights: tuple[np.ndarray, np.ndarray] | None = None
        self.columns: np.ndarray | None = None
        self.codewords = Codewords(codebook)
        #: The composed map (V, v0) once decided: False where it is not the cheaper product, None before.
        self.composed: tuple[np.ndarray, np.ndarray] | bool | None = None
        #: The bounded search's composed rows (:class:`~btel.methods.codes.decoding.ComposedRows`) once
        #: decided: False where they do not serve, None before.
        self.composed_rows: Any = None
        #: (decode setting, the bounded search of single queries or None) once decided, else None.
        self.one_query: tuple[str, Any] | None = None

    def composed_map(self, weights: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(V, v0): V = W·Cᵀ (d', N) and v0 = b·Cᵀ (N,), float32, the scores of every place as one linear map
        of the query (:func:`~btel.methods.codes.decoding.composes`), from the (d', 8⌈K/8⌉) weights and biases
        (zero in the padding columns)."""
        codes = self.codewords.dense()  # cached wherever composes() holds
        with blas_threads(1):
            V = np.ascontiguousarray(weights @ codes.T)
        return V, (codes @ bias).astype(np.float32)
