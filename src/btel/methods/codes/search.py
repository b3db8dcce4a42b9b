"""Inference of a fitted :class:`~btel.methods.codes.estimator.CodeLocalizer` (mixed into it): margins, the decode paths.

A query's K margins m score place i as m · c_i. ``_search`` runs the cheapest exact path for the
shape (:func:`~btel.methods.codes.decoding.choose_path`: one composed linear map on small maps with
few places per code column, the dense product, the bounded block search, faiss' packed scan) or,
on long maps of route families, the coarse-to-fine decode (approximate; ``decode``). Every
runtime array lives in the model's :class:`~btel.methods.codes.codewords.RuntimeCache`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..base import top_k
from ...core.rows import ScaledRows
from ...core.threads import blas_threads_for_vector, faiss_threads, search_threads
from .codebook import ROUTE_FAMILIES
from .codewords import BLOCK_VALUES, Codewords, blas_for, blas_for_decode
from .decoding import BATCH_DENSE_FROM, BlockDecoder, DENSE_CACHE_BYTES, PROBE_QUERIES, ComposedRows, best_of, choose_path, composes

__all__ = ["CodeSearch", "COARSE_MIN_PLACES"]

#: From this many places ``decode='auto'`` decodes route families coarse to fine (approximate):
#: below it the exact bounded search is no slower, and exact is the better answer
#: (``benchmarks/bench_codes.py`` times both against N).
COARSE_MIN_PLACES = 1 << 19
#: A refined place's cost in the coarse decode (faiss' scan of its ⌈K/8⌉ packed bytes) against a block's coarse
#: row (8⌈K/8⌉ multiply-adds with its mean codeword): ≈ 0.4 at K = 470 (``benchmarks/bench_single_query.py``).
#: The default block B = √(N / (t · cost)) makes the two passes cost about the same.
REFINED_PLACE_COST = 0.4


class CodeSearch:
    """The inference half of :class:`~btel.methods.codes.estimator.CodeLocalizer` (which fits and stores)."""

    #: Queries are only multiplied by matrices (weights, the composed map): lazily normalised rows suffice.
    _linear_in_queries = True
    #: The codebook's packed rows and block means fill on demand: one thread predicts (BLAS may use more).
    _predict_in_threads = False

    @property
    def _codewords(self) -> Codewords:
        """The codebook at inference (:mod:`btel.methods.codes.codewords`), built on demand."""
        return self._cache.codewords

    def _weights_dense(self) -> tuple[np.ndarray, np.ndarray]:
        """(d', 8⌈K/8⌉) float32 dequantised weights and (8⌈K/8⌉,) biases, zero in the padding columns
        (a runtime cache, not stored): the margins come out padded to whole bytes, as the decoders read them."""
        if self._cache.weights is None:
            width, K = self._codewords.width, self.n_codes_
            weights = np.zeros((self.n_selected_, width), dtype=np.float32)
            weights[:, :K] = self.weights_.dequantise().T
            bias = np.zeros(width, dtype=np.float32)
            bias[:K] = self.bias_
            self._cache.weights = (weights, bias)
        return self._cache.weights

    def _linear(self, Q: np.ndarray | ScaledRows, matrix: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """(n, m) float32 ``q' @ matrix + offset`` of transformed queries q' (their d' kept columns).

        Q may be lazily L2-normalised rows (:class:`~btel.core.rows.ScaledRows`): the scale is applied
        to the product, which commutes with it.
        """
        raw, scale = (Q.raw, Q.scale) if isinstance(Q, ScaledRows) else (Q, None)
        columns = self._cache.columns
        if columns is None and self.columns_ is not None:
            columns = self._cache.columns = self.columns_.astype(np.intp)
        if raw.shape[0] == 1:  # one query: a vector product, scaled by a number (µs count here)
            out = (raw[0] if columns is None else raw[0, columns]) @ matrix
            if scale is not None:
                out *= scale[0]
            out += offset
            return out[None]
        out = (raw if columns is None else raw[:, columns]) @ matrix
        if scale is not None:
            out *= scale[:, None]
        out += offset
        return out

    def _margins(self, Q: np.ndarray | ScaledRows) -> np.ndarray:
        """(n, K) float32 margins of transformed queries."""
        return self._padded_margins(Q)[:, : self.n_codes_]

    def _padded_margins(self, Q: np.ndarray | ScaledRows) -> np.ndarray:
        """(n, 8⌈K/8⌉) float32 margins, zeros in the padding columns (which then add nothing)."""
        return self._linear(Q, *self._weights_dense())

    def _composed_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(V, v0) of :meth:`RuntimeCache.composed_map <btel.methods.codes.codewords.RuntimeCache.composed_map>`
        where the composed map is the cheaper product (:func:`~btel.methods.codes.decoding.composes`), else None;
        decided and built once per model."""
        cache = self._cache
        if cache.composed is None:
            cache.composed = (composes(int(self.n_places_), self.n_selected_, self.n_codes_, self._codewords.width)
                              and cache.composed_map(*self._weights_dense()))
        return cache.composed or None

    def _composed_rows(self) -> ComposedRows | None:
        """The bounded search's composed rows where they cost fewer multiply-adds per scored place than the
        codewords (d' < 8⌈K/8⌉, route families), built once. Only where they and the float32 codewords they are
        derived from fit in the cache bound together (N·(8⌈K/8⌉ + d')·4 B), so inference memory stays within it."""
        cache = self._cache
        if cache.composed_rows is None:
            codewords, n = self._codewords, int(self.n_places_)
            serves = (self.code_ in ROUTE_FAMILIES and self.n_selected_ < codewords.width
                      and 4 * n * (codewords.width + self.n_selected_) <= DENSE_CACHE_BYTES
                      and codewords.dense() is not None)
            if serves:
                with blas_for(1, 0):  # one thread, as the composed map: BLAS' own threads spin on a shared machine
                    cache.composed_rows = ComposedRows.build(codewords.dense(), *self._weights_dense())
            else:
                cache.composed_rows = False
        return cache.composed_rows or None

    def _kept(self, Q: np.ndarray | ScaledRows) -> np.ndarray:
        """(n, d') float32 transformed queries, their kept columns (what the weights multiply)."""
        raw, scale = (Q.raw, Q.scale) if isinstance(Q, ScaledRows) else (Q, None)
        out = raw if self.columns_ is None else raw[:, self.columns_]
        return np.asarray(out * scale[:, None] if scale is not None else out, dtype=np.float32)

    def _composed_scores(self, Q: np.ndarray | ScaledRows) -> np.ndarray | None:
        """(n, N) float32 scores of every place by the composed map, or None where it does not serve."""
        composed = self._composed_map()
        return None if composed is None else self._linear(Q, *composed)

    def decision_function(self, Q: Any) -> np.ndarray:
        """Margins of every code column (positive = +1), shape (n_queries, K), float32."""
        return self._margins(self._check_queries(Q))

    def _padded(self, M: np.ndarray) -> np.ndarray:
        """Margins (n, K) → (n, 8⌈K/8⌉) float32, zeros in the padding columns (which then add nothing)."""
        out = np.zeros((M.shape[0], self._codewords.width), dtype=np.float32)
        out[:, : self.n_codes_] = M
        return out

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        """m · c_i for every place (the exact soft decode), (n, N) float64."""
        with blas_for(Q.shape[0], self.n_codes_ * (self.n_selected_ + int(self.n_places_))):
            composed = self._composed_scores(Q)
            if composed is not None:
                return composed.astype(np.float64)
            M = self._padded_margins(Q)
            out = np.empty((Q.shape[0], int(self.n_places_)))
            for a, b, codes in self._codewords.blocks():
                out[:, a:b] = M @ codes.T
        return out

    def _coarse_default(self) -> bool:
        """Whether ``search`` decodes coarse to fine (``decode`` and the family; 'auto': long maps only)."""
        if self.code_ not in ROUTE_FAMILIES or self.decode == "exact":
            return False
        return self.decode == "coarse" or int(self.n_places_) >= COARSE_MIN_PLACES

    def _coarse_plan(self, k: int) -> tuple[int, int] | None:
        """(B, blocks refined) when ``search`` for the top ``k`` decodes coarse to fine, else None (exact)."""
        if not self._coarse_default():
            return None
        block, candidates = self._coarse_shape()
        n = int(self.n_places_)
        n_blocks = -(-n // block)
        # Fewest places the refined blocks hold: the short last block may be among them.
        fewest = n if candidates >= n_blocks else (candidates - 1) * block + n - (n_blocks - 1) * block
        return (block, candidates) if k <= fewest else None

    def _one_query_decoder(self) -> BlockDecoder | None:
        """The bounded search when it decodes a single query (k = 1) from float32 rows — composed rows or cached
        codewords — else None (the composed map, the coarse decode, 'dense', 'scan' or packed codewords serve);
        decided once per ``decode`` setting (an inference parameter)."""
        cache = self._cache
        if cache.one_query is None or cache.one_query[0] != self.decode:
            decoder = None
            if self._coarse_plan(1) is None and self.exact_path(1) == "bounded":
                decoder = self._codewords.decoder()
                if decoder.dense is None and self._composed_rows() is None:
                    decoder = None
            cache.one_query = (self.decode, decoder)
        return cache.one_query[1]

    def _search_one(self, Q: np.ndarray | ScaledRows, decoder: BlockDecoder) -> tuple[np.ndarray, np.ndarray]:
        """(1, 1) float64 score and int64 place of one query by :meth:`BlockDecoder.search_one
        <btel.methods.codes.decoding.BlockDecoder.search_one>`: exact, as ``_exact_search``'s bounded path."""
        rows = self._composed_rows()
        n_blocks, width = decoder.constant.shape[0], self._codewords.width
        largest = max(2 * n_blocks * width, self.n_selected_ * width,
                      int(self.n_places_) * (self.n_selected_ if rows is not None else width))
        with blas_threads_for_vector(largest):
            M = self._padded_margins(Q)
            # Non-finite margins (huge but finite weights in a model file) are an error naming the cause.
            self._check_answers(None, M)
            query = None if rows is None else self._kept(Q)[0]
            best, place = decoder.search_one(M[0], rows, query)
        if not math.isfinite(best):  # finite margins can still overflow float32 in the sums
            self._check_answers(None, np.array([best]))
        return np.array([[best]]), np.array([[place]], dtype=np.int64)

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        if k == 1 and Q.shape[0] == 1:
            decoder = self._one_query_decoder()
            if decoder is not None:
                return self._search_one(Q, decoder)
        # The search's products are small per query (margins, bounds, refined blocks): one BLAS thread
        # (none set when BLAS uses one anyway), unless a large batch's dense product can use a second one.
        with blas_for_decode(Q.shape[0], self._codewords.width * max(self.n_selected_, int(self.n_places_))):
            coarse = self._coarse_plan(k)
            composed = self._composed_scores(Q) if coarse is None else None
            if composed is not None:
                values, places = best_of(composed, k)
                self._check_answers(None, values)  # finite weights can still overflow float32 in the sums
                return values, places
            M = self._padded_margins(Q)
            if coarse is not None:
                return self._codewords.coarse_search(M, k, *coarse)
            if M.shape[0] < BATCH_DENSE_FROM:  # single queries: the whole decode on one BLAS thread
                return self._exact_search(M, k, queries=Q)
        return self._exact_search(M, k, queries=Q)

    def _predict(self, Q: np.ndarray | ScaledRows) -> np.ndarray:
        """Best place of transformed queries: one argmax over the composed scores where they serve, else ``_search``."""
        if Q.shape[0] == 1:
            decoder = self._one_query_decoder()
            if decoder is not None:
                return self._search_one(Q, decoder)[1][:, 0]
        composed = self._composed_map() if self._coarse_plan(1) is None else None
        if composed is None:
            return self._search(Q, 1)[1][:, 0]
        with blas_for_decode(Q.shape[0], composed[0].size):
            scores = self._linear(Q, *composed)
        # The first maximum (ties to the lower place, as top_k); NaN/inf best scores (finite weights can
        # still overflow float32 in the sums) are an error. One query in Python scalars (µs count here).
        if scores.shape[0] == 1:
            place = int(scores[0].argmax())
            if not math.isfinite(scores[0, place]):
                self._check_answers(None, scores[0, place : place + 1])
            return np.array([place])
        values, places = best_of(scores, 1)
        self._check_answers(None, values)
        return places[:, 0]

    def exact_path(self, n_queries: int = 1) -> str:
        """The exact decode :meth:`search` runs for ``n_queries`` queries: 'composed', 'bounded', 'dense', 'scan' or 'probe'.

        'probe': a batch whose first queries are decoded by the bounded search, the rest by whichever
        of 'bounded' and 'dense' the places they scored predict to be cheaper
        (:func:`~btel.methods.codes.decoding.choose_path`).
        """
        if self._composed_map() is not None:
            return "composed"
        return choose_path(int(self.n_places_), self._codewords.width, n_queries, self.code_ in ROUTE_FAMILIES,
                           self._codewords.dense() is not None)

    def _exact_search(self, M: np.ndarray, k: int, path: str | None = None,
                      queries: np.ndarray | ScaledRows | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Top k of m · c_i over every place, by ``path`` (default :func:`~btel.methods.codes.decoding.choose_path`).

        ``queries``: the transformed queries whose margins are M; with them the bounded search reads scored
        places from the composed rows where those serve (:meth:`_composed_rows`).
        """
        # Non-finite margins (a model file with huge but finite weights) are an error naming the cause,
        # not an answer: argmax over NaN scores would return a place.
        self._check_answers(None, M)
        path = path or self.exact_path(M.shape[0])
        rows = self._composed_rows() if queries is not None and path in ("bounded", "probe") else None
        if path == "probe":  # a batch: the first queries by the bounded search tell which path is cheaper
            head = min(PROBE_QUERIES, M.shape[0])
            with blas_for(1, 0):
                s_head, p_head, visited = self._codewords.decoder().search(
                    M[:head], k, rows, None if rows is None else self._kept(queries[:head]))
            fraction = float(visited.mean()) * self._codewords.decoder().block / int(self.n_places_)
            rest = choose_path(int(self.n_places_), self._codewords.width, M.shape[0], True, True, visited=fraction)
            s_rest, p_rest = (self._exact_search(M[head:], k, rest, None if queries is None else queries[head:])
                              if head < M.shape[0] else (s_head[:0], p_head[:0]))
            return np.concatenate([s_head, s_rest]), np.concatenate([p_head, p_rest])
        if path == "bounded":
            with blas_for_decode(M.shape[0], self._codewords.width * int(self.n_places_)):
                scores, places, _ = self._codewords.decoder().search(M, k, rows,
                                                                     None if rows is None else self._kept(queries))
            self._check_answers(None, scores)  # finite margins can still overflow float32 in the sums
            return scores, places
        if path == "scan":
            index = self._codewords.adc_index()
            if index is not None:
                with faiss_threads(search_threads(self.n_jobs, M.shape[0])):
                    scores, places = index.search(M, k)
                return scores.astype(np.float64), places.astype(np.int64)
        n = M.shape[0]
        dense = self._codewords.dense()
        if dense is not None and n * dense.shape[0] <= BLOCK_VALUES:
            # One product over the cached codewords (small maps, small batches): no blocks, no merging.
            with blas_for_decode(n, self._codewords.width * int(self.n_places_)):
                scores = M @ dense.T
            values, places = best_of(scores, k)
            self._check_answers(None, values)  # finite margins can still overflow float32 in the product
            return values, places
        best_s = np.empty((n, 0), dtype=np.float32)
        best_p = np.empty((n, 0), dtype=np.int64)
        with blas_for(n, self.n_codes_ * int(self.n_places_)):
            for a, b, codes in self._codewords.blocks():
                scores = np.concatenate([best_s, M @ codes.T], axis=1)
                places = np.concatenate([best_p, np.broadcast_to(np.arange(a, b), (n, b - a))], axis=1)
                kept_s, cols = top_k(scores, min(k, scores.shape[1]))
                best_s = kept_s.astype(np.float32)
                best_p = np.take_along_axis(places, cols, axis=1)
        return best_s.astype(np.float64), best_p

    # -- coarse to fine ----------------------------------------------------------------------------
    def _coarse_shape(self) -> tuple[int, int]:
        """(B places per block, blocks refined)."""
        n, t = int(self.n_places_), int(self.coarse_candidates)
        block = int(self.coarse_block) if self.coarse_block is not None else \
            max(1, int(round(np.sqrt(n / (t * REFINED_PLACE_COST)))))
        return min(block, n), min(t, -(-n // min(block, n)))
