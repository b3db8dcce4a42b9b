"""BTEL beyond the binary index: K ≥ b implicit output codes, fitted to a byte budget.

:class:`CodeLocalizer` generalises BTE-C (:mod:`btel.methods.btel.compressed`) from the b bits of a place's
index to K ≥ b code columns (error-correcting output codes, Dietterich & Bakiri 1995):

1. place i has a codeword c_i ∈ {−1, +1}^K from a family (:mod:`btel.methods.codes.codebook`: ``periodic``,
   ``blocks``, ``random``, and BTE-C's own ``binary`` and ``offset`` codes), regenerated from
   (family, N, K, seed) — never stored;
2. one linear model per column predicts it from the descriptor, all K fitted as one multi-output
   ridge problem in closed form (or one liblinear SVM per column; :mod:`btel.methods.codes.solvers`), on
   d' shared columns of largest variance;
3. the weights are stored at 32, 16, 8 or 4 bits with one scale per column (:mod:`btel.methods.codes.quantise`);
4. a query's K margins m are decoded softly over every place: score_i = m · c_i (the Gaussian
   log-likelihood of the margins up to a constant). The exact top k is found by the cheapest
   exact path for the shape (:func:`btel.methods.codes.decoding.choose_path`, a measured rule): on small
   maps one dense product with the float32 codewords (cached when N·8⌈K/8⌉·4 ≤ 32 MB); on
   larger ones a bounded search over blocks of consecutive places (:mod:`btel.methods.codes.decoding`:
   per-block upper bounds from the columns constant on the block, blocks scored in order of
   their bound from packed codewords — N·⌈K/8⌉ bytes of memory, filled on demand, never stored —
   until no unscored block can beat the k-th best); batches take the dense product when a probe
   of their first queries says it is cheaper; the 'random' family (no blocks to bound) uses
   faiss' packed PQ scan past the dense cache. ``place_scores`` is the same sum as a matrix
   product in blocks of places. ``rank``, the HMM decoder and streaming come from the base class
   (:class:`btel.base.PlaceLocalizer`) on top of them.

Storage is K·d' weights (plus K scales and biases, and d' column indices), independent of N, so it
stays sub-linear, and K is the dial that turns bytes into accuracy: the budget planner
(:mod:`btel.methods.codes.planning`) picks K, d' and the weight width that fill the budget.

**Decoding long maps.** The exact decode costs N·K per query. For route families (every family but
``random``) on long maps (``decode='auto'`` from :data:`COARSE_MIN_PLACES` places, or
``decode='coarse'``) it runs coarse to fine: the route is cut into blocks of B consecutive places,
each block is scored by its *mean* codeword (precomputed once: ⌈N/B⌉ × K values, a runtime cache),
which equals the mean score of the block's places, and only the places of the
``coarse_candidates`` best blocks are scored exactly. Long-period columns are nearly constant on a
block, so they carry the coarse score; short-period ones average out. It is approximate: the true
best place may sit in a block whose mean is not among the best; ``benchmarks/bench_codes.py``
measures the loss against the exact decode.

**Relation to BTELocalizer.** ``btel-c`` (:class:`btel.methods.btel.localizer.BTELocalizer`) stays the paper's
BTE-C, unchanged. This is a separate estimator rather than another option of ``BTELocalizer``: its
solver (multi-output ridge), storage (quantised weights, shared columns), planner and decoder
differ in every part, and only the codes themselves are shared — ``code='binary'`` and
``code='offset'`` regenerate exactly the columns of BTE-C's plain and offset codes. What does not
compose: **regions** (BTEL's KTS regions with a region classifier and one tree each) — the
long-period code columns already play the region classifier's part (a coarse position along the
route), and per-region codes would multiply the weights by r; **per-classifier feature selection**
(BCSS / Witten–Tibshirani) — K × d' column indices would cost more than 4-bit weights; the kept
columns are shared instead. The **sequence filter** and the **HMM decoder** compose: they read
``predict`` and ``place_scores``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._validation import N_JOBS, RANDOM_STATE, Budget, Interval, Options, String, read_state_int
from ...base import ArraySpec, PlaceLocalizer, top_k
from .planning import CodePlan, code_array_specs, plan_codes
from .solvers import fit_liblinear_codes, fit_ridge_codes
from .decoding import (BATCH_DENSE_FROM, BYTE_SIGNS, DENSE_CACHE_BYTES, PROBE_QUERIES, BlockDecoder,
                            choose_path)
from .codebook import FAMILIES, MAX_COLUMNS, ROUTE_FAMILIES, Codebook
from ...learning.distributed import BACKENDS
from ...exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError
from ...learning.feature_selection import column_index_dtype
from ...learning.linear import ColumnStats
from .quantise import WEIGHT_BITS, QuantisedWeights, quantise
from ...storage import format_bytes
from ...threads import blas_threads, faiss_threads, search_threads

__all__ = ["CodeLocalizer", "SOLVERS", "DECODES", "COARSE_MIN_PLACES"]

SOLVERS = ("ridge", "liblinear")
DECODES = ("auto", "exact", "coarse")
#: From this many places ``decode='auto'`` decodes route families coarse to fine (approximate).
#: Measured (``benchmarks/bench_codes.py``, 64 KB, d = 256, single queries, load 7–15): N = 10⁴
#: coarse 0.10 ms against the exact bounded search's 0.18 ms; N = 10⁵ 1.02 against 0.76 ms (the
#: exact decode faster); N = 10⁶ 4.0 against 9.0 ms (coarse agreeing with the exact answer on
#: 99.5 % of the queries, but its first query builds the block means from every codeword: 3.6 s).
#: Exact where it is no slower, so coarse only past 2¹⁹ places.
COARSE_MIN_PLACES = 1 << 19
#: The codebook is cached at inference as packed bits (N × ⌈K/8⌉ bytes) up to this size (256 MB).
PACKED_CACHE_BYTES = 1 << 28
#: Values (rows × columns) of one block of scores or codes at inference (about 16 MB of float32).
_BLOCK_VALUES = 1 << 22
#: Places whose packed codewords are generated together when first read.
_FILL_PLACES = 256


class CodeLocalizer(PlaceLocalizer):
    """Output-code localization: K implicit ±1 code columns per place, predicted linearly, decoded softly.

    Parameters
    ----------
    code : {'auto', 'periodic', 'blocks', 'random', 'binary', 'offset'}
        Code family (:mod:`btel.methods.codes.codebook`). 'periodic' (multi-scale square waves) for maps that
        are routes; 'random' for maps of independent places; 'binary' / 'offset' are BTE-C's codes.
        'auto' chooses periodic or random from the map alone by the statistic ``auto`` uses
        (:func:`btel.methods.auto.route_share` ≥ :data:`btel.methods.auto.ROUTE_SHARE`: a route); the family
        chosen is ``code_``, recorded in the model file and restored on load.
    n_codes : int, optional
        K, code columns (binary: exactly ⌈log2 N⌉). None: chosen by the planner.
    n_features : int, optional
        d', kept descriptor columns (the d' of largest variance). None: chosen by the planner.
    weight_bits : {32, 16, 8, 4}, optional
        Stored weight width. None: chosen by the planner (4 unless bytes are left at K and d' maximal).
    budget : int or str, optional
        Byte budget ('64KB' = 64 000 B). The planner (:mod:`btel.methods.codes.planning`) fills it and never
        exceeds it; :class:`~btel.exceptions.BudgetTooSmallError` names the minimum when nothing fits.
    solver : {'ridge', 'liblinear'}
        Closed-form multi-output ridge (all columns at once) or a linear SVM per column.
    alpha : float, optional
        Ridge regularisation α on the front-end-transformed map. None: α = 0.03 × the mean non-zero
        eigenvalue of the centred Gram matrix (:mod:`btel.methods.codes.solvers`).
    C : float
        liblinear's C (``solver='liblinear'``).
    max_iter : int
        liblinear's iteration cap per column.
    decode : {'auto', 'exact', 'coarse'}
        Exact soft decode over every place, or coarse to fine (route families only; module
        docstring). 'auto': coarse from 524 288 places (:data:`COARSE_MIN_PLACES`) for route
        families, else exact.
    coarse_block : int, optional
        B, places per block of the coarse decode. None: ≈ √(N / coarse_candidates) (so the coarse
        and the fine pass score about as many rows each).
    coarse_candidates : int
        Blocks scored exactly by the coarse decode.
    random_state : int or None
        Seed of the codewords (and of liblinear). None draws one; the seed used is recorded in the
        model file either way, so a loaded model regenerates the same codewords.
    n_jobs, backend, scheduler
        Parallel fitting of the code columns (as :class:`~btel.methods.btel.localizer.BTELocalizer`); runtime
        settings, not saved.
    normalize, whiten, delta
        The front end (:mod:`btel.frontend`).

    Attributes
    ----------
    code_ : str
        The code family used (``code`` itself, or what 'auto' chose); ``code_reason_`` says why.
    codebook_ : Codebook
        The implicit codewords (family, N, K, seed).
    plan_ : CodePlan
        What the planner chose and by which rule.
    weights_ : QuantisedWeights
        K × d' stored weights.
    bias_ : ndarray of shape (K,), float32
    columns_ : ndarray of shape (d',), uint16/uint32, or None (every column kept)
    n_codes_, n_selected_, weight_bits_, code_seed_ : int
    alpha_ : float or None
        The ridge α used (None for liblinear).
    n_unconverged_ : int
    n_places_, n_features_in_ : int
    front_end_ : FrontEnd
    fit_time_ : float

    Examples
    --------
    >>> from btel.datasets import synthetic_route
    >>> route = synthetic_route(n_places=500, dim=64, seed=0)
    >>> model = CodeLocalizer(budget="8KB").fit(route.map)
    >>> model.nbytes <= 8000, model.predict(route.queries).shape
    (True, (500,))
    """

    _parameter_constraints = {
        "code": [Options("auto", *FAMILIES)],
        "n_codes": [None, Interval(int, 1, MAX_COLUMNS)],
        "n_features": [None, Interval(int, 1, None)],
        "weight_bits": [None, Options(*WEIGHT_BITS)],
        "budget": [Budget()],
        "solver": [Options(*SOLVERS)],
        "alpha": [None, Interval(float, 0, None, closed="neither")],
        "C": [Interval(float, 0, None, closed="neither")],
        "max_iter": [Interval(int, 1, None)],
        "decode": [Options(*DECODES)],
        "coarse_block": [None, Interval(int, 1, None)],
        "coarse_candidates": [Interval(int, 1, None)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
        "backend": [None, Options(*BACKENDS)],
        "scheduler": [None, String()],
    }
    _runtime_params = ("n_jobs", "backend", "scheduler")

    def __init__(
        self,
        *,
        code: str = "periodic",
        n_codes: int | None = None,
        n_features: int | None = None,
        weight_bits: int | None = None,
        budget: int | str | None = None,
        solver: str = "ridge",
        alpha: float | None = None,
        C: float = 1.0,
        max_iter: int = 1000,
        decode: str = "auto",
        coarse_block: int | None = None,
        coarse_candidates: int = 16,
        random_state: int | None = 0,
        n_jobs: int | None = None,
        backend: str | None = None,
        scheduler: str | None = None,
    ) -> None:
        self.code = code
        self.n_codes = n_codes
        self.n_features = n_features
        self.weight_bits = weight_bits
        self.budget = budget
        self.solver = solver
        self.alpha = alpha
        self.C = C
        self.max_iter = max_iter
        self.decode = decode
        self.coarse_block = coarse_block
        self.coarse_candidates = coarse_candidates
        self.random_state = random_state
        self.n_jobs = n_jobs
        self.backend = backend
        self.scheduler = scheduler

    # ------------------------------------------------------------------ fit
    def _check_combinations(self) -> None:
        if self.scheduler is not None and self.backend != "dask":
            raise InvalidParameterError("scheduler only applies with backend='dask'.")
        if self.decode == "coarse" and self.code != "auto" and self.code not in ROUTE_FAMILIES:
            raise InvalidParameterError(
                f"decode='coarse' needs codes that change slowly along the route ({', '.join(ROUTE_FAMILIES)}); "
                f"the {self.code} family has none. Use decode='exact'.")

    def _choose_family(self, X: np.ndarray, places: np.ndarray | None) -> tuple[str, str]:
        """The code family and why: ``code`` itself, or for 'auto' periodic on a route, random otherwise."""
        if self.code != "auto":
            return self.code, "given"
        from ..auto import ROUTE_SHARE, route_share

        share = route_share(X, places)
        family = "periodic" if share >= ROUTE_SHARE else "random"
        return family, (f"code='auto': route share {share:.2f} {'≥' if share >= ROUTE_SHARE else '<'} "
                        f"{ROUTE_SHARE} → {family}")

    def _plan(self, n_places: int, d: int, budget: int | None, reserved: int,
              family: str | None = None) -> CodePlan:
        """K, d' and the weight width ``fit`` uses (:func:`~btel.methods.codes.planning.plan_codes`)."""
        family = self.code if family is None else family
        available = None if budget is None else budget - reserved
        try:
            return plan_codes(available, d, n_places, family, n_codes=self.n_codes,
                              n_selected=self.n_features, bits=self.weight_bits)
        except BudgetTooSmallError as exc:
            minimum = int(exc.minimum or 0) + reserved
            raise BudgetTooSmallError(
                f"budget {format_bytes(budget)} ({budget} B) is too small for output codes ({family}, "
                f"N = {n_places}): the smallest model needs {minimum} B ({format_bytes(minimum)}), front end "
                f"included. Raise the budget or fix fewer codes (n_codes).", budget=budget, minimum=minimum,
            ) from None

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self._check_combinations()
        if self.code != "auto":
            self._plan(n_rows, n_features_out, budget, reserved)
            return
        # code='auto' picks its family from the map's rows, not its shape: raise only when neither fits.
        errors = []
        for family in ("periodic", "random"):
            try:
                self._plan(n_rows, n_features_out, budget, reserved, family)
                return
            except BudgetTooSmallError as exc:
                errors.append(exc)
        raise min(errors, key=lambda exc: exc.minimum or 0)

    def _fit(self, X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
             reserved: int) -> None:
        self._check_combinations()
        family, self.code_reason_ = self._choose_family(X, places)
        if self.decode == "coarse" and family not in ROUTE_FAMILIES:
            raise InvalidParameterError(f"decode='coarse' needs a route code family; {self.code_reason_}. "
                                        "Use decode='auto' or 'exact', or pass code='periodic'.")
        self.code_ = family
        d = X.shape[1]
        plan = self._plan(n_places, d, budget, reserved, family)
        seed = int(self.random_state) if self.random_state is not None else \
            int(np.random.default_rng().integers(0, 2**32 - 1))
        codebook = Codebook(family, n_places, plan.n_codes, seed)
        if plan.n_selected < d:
            variance = ColumnStats.of(X).scale ** 2
            order = np.lexsort((np.arange(d), -variance))  # largest variance first, ties to the lower index
            columns = np.sort(order[: plan.n_selected]).astype(column_index_dtype(d))
        else:
            columns = None
        cols = np.arange(d) if columns is None else columns.astype(np.intp)
        common = dict(n_jobs=self.n_jobs, backend=self.backend, scheduler=self.scheduler)
        if self.solver == "ridge":
            fitted = fit_ridge_codes(X, cols, codebook, places, alpha=self.alpha, **common)
        else:
            fitted = fit_liblinear_codes(X, cols, codebook, places, C=float(self.C), max_iter=int(self.max_iter),
                                         random_state=self.random_state, **common)
        weights = quantise(fitted.weights, plan.bits)
        # The bias from the stored weights, so quantisation does not shift every margin by (w − w_q)·μ.
        stored = weights.dequantise().astype(np.float64)
        self.bias_ = (fitted.offsets - stored @ fitted.center).astype(np.float32)
        self.weights_ = weights
        self.columns_ = columns
        self.plan_ = plan
        self.alpha_ = float(fitted.alpha) if self.solver == "ridge" else None
        self.n_unconverged_ = int(fitted.n_unconverged)
        self._set_structure(codebook)

    def _set_structure(self, codebook: Codebook) -> None:
        self.codebook_ = codebook
        self.n_codes_ = int(codebook.n_codes)
        self.code_seed_ = int(codebook.seed)
        self.n_selected_ = int(self.weights_.n_columns)
        self.weight_bits_ = int(self.weights_.bits)
        self._reset_caches()

    def _reset_caches(self) -> None:
        self._cache = _RuntimeCache()

    def summary(self) -> str:
        """One line on what was fitted: family, K, d', width, the planner's rule, α."""
        alpha = f", ridge α = {self.alpha_:.4g}" if self.alpha_ is not None else ", liblinear"
        why = f" [{self.code_reason_}]" if self.code == "auto" else ""
        return f"{self.code_} codes{why} (seed {self.code_seed_}): {self.plan_.describe()}{alpha}"

    # ------------------------------------------------------------------ inference
    def _weights_dense(self) -> np.ndarray:
        """(d', K) float32 dequantised weights (a runtime cache, not stored)."""
        if self._cache.dense is None:
            self._cache.dense = np.ascontiguousarray(self.weights_.dequantise().T)
        return self._cache.dense

    def _margins(self, Q: np.ndarray) -> np.ndarray:
        """(n, K) float32 margins of transformed queries."""
        q = Q if self.columns_ is None else Q[:, self.columns_.astype(np.intp)]
        return (q @ self._weights_dense() + self.bias_).astype(np.float32, copy=False)

    def decision_function(self, Q: Any) -> np.ndarray:
        """Margins of every code column (positive = +1), shape (n_queries, K), float32."""
        return self._margins(self._check_queries(Q))

    # -- the codebook at inference: float32 codewords, packed bits filled on demand, faiss' scan --
    def _dense_codes(self) -> np.ndarray | None:
        """(N, 8⌈K/8⌉) float32 ±1 codewords when they fit :data:`~btel.methods.codes.decoding.DENSE_CACHE_BYTES`, else None.

        Built once (a runtime cache; the only copy of the codebook then: no packed bits are kept).
        """
        n, width = int(self.n_places_), self._width()
        if n * width * 4 > DENSE_CACHE_BYTES:
            return None
        if self._cache.codes is None:
            codes = np.ones((n, width), dtype=np.float32)
            for a, b, block in self.codebook_.iter_blocks():
                codes[a:b, : self.n_codes_] = block
            self._cache.codes = codes
        return self._cache.codes

    def _packed_rows(self, places: np.ndarray) -> np.ndarray | None:
        """Packed codewords (len(places), ⌈K/8⌉) uint8 of the given places, or None past :data:`PACKED_CACHE_BYTES`.

        The (N, ⌈K/8⌉) array (+1 → bit 1, column j in bit j % 8 of byte j // 8) is allocated once
        and filled :data:`_FILL_PLACES` places at a time when first read, so the first query after
        ``load`` generates only the codewords it scores (untouched pages cost no memory).
        """
        n, groups = int(self.n_places_), -(-self.n_codes_ // 8)
        if n * groups > PACKED_CACHE_BYTES:
            return None
        cache = self._cache
        if cache.packed is None:
            cache.packed = np.empty((n, groups), dtype=np.uint8)
            cache.filled = np.zeros(-(-n // _FILL_PLACES), dtype=bool)
        chunk_of = places // _FILL_PLACES
        if cache.filled[chunk_of].all():
            return cache.packed[places]
        chunks = np.unique(chunk_of)
        for c in chunks[~cache.filled[chunks]]:
            a, b = int(c) * _FILL_PLACES, min(n, (int(c) + 1) * _FILL_PLACES)
            cache.packed[a:b] = np.packbits(self.codebook_.codewords(np.arange(a, b)) > 0, axis=1, bitorder="little")
            cache.filled[c] = True
        return cache.packed[places]

    def _packed_of(self, places: np.ndarray) -> np.ndarray:
        """Packed codewords of the given places: from the cache, or generated past its size limit."""
        packed = self._packed_rows(places)
        if packed is None:
            packed = np.packbits(self.codebook_.codewords(places) > 0, axis=1, bitorder="little")
        return packed

    def _width(self) -> int:
        """K rounded up to whole bytes: the width of the codewords and margins the decoders multiply."""
        return 8 * -(-self.n_codes_ // 8)

    def _padded(self, M: np.ndarray) -> np.ndarray:
        """Margins (n, K) → (n, 8⌈K/8⌉) float32, zeros in the padding columns (which then add nothing)."""
        out = np.zeros((M.shape[0], self._width()), dtype=np.float32)
        out[:, : self.n_codes_] = M
        return out

    def _codes_of(self, places: np.ndarray) -> np.ndarray:
        """±1 codewords of the given places, float32 (n, 8⌈K/8⌉): padding columns are +1 (× zero margins)."""
        places = np.asarray(places, dtype=np.intp)
        dense = self._dense_codes()
        if dense is not None:
            return dense[places]
        packed = self._packed_rows(places)
        if packed is None:
            codes = np.ones((len(places), self._width()), dtype=np.float32)
            codes[:, : self.n_codes_] = self.codebook_.codewords(places)
            return codes
        # One table look-up per byte: the 8 ±1 values of its bits.
        return BYTE_SIGNS[packed].reshape(len(places), -1)

    def _code_blocks(self, rows: int | None = None):
        """Yield (start, stop, codewords float32 (stop − start, 8⌈K/8⌉)) over consecutive blocks of places."""
        n = int(self.n_places_)
        rows = rows or max(1, _BLOCK_VALUES // self.n_codes_)
        for a in range(0, n, rows):
            b = min(n, a + rows)
            yield a, b, self._codes_of(np.arange(a, b))

    def _adc_index(self) -> Any:
        """faiss.IndexPQ over the packed codewords whose scan computes m · c_i exactly (or None).

        The soft decode is an asymmetric-distance scan: cut the K columns into groups of 8, a group
        of a codeword is one byte, and the 256 "centroids" of every group are the 256 ±1 patterns
        of 8 columns. faiss' inner-product PQ scan then sums, per place, one table entry per group
        (⌈K/8⌉ look-ups instead of K multiply-adds). Only for the 'random' family past the dense
        cache (no blocks to bound): its codes are added block by block, the index holds the only copy.
        """
        if self._cache.index is None:
            n, groups = int(self.n_places_), -(-self.n_codes_ // 8)
            if n * groups > PACKED_CACHE_BYTES:
                return None
            import faiss

            index = faiss.IndexPQ(8 * groups, groups, 8, faiss.METRIC_INNER_PRODUCT)
            faiss.copy_array_to_vector(np.tile(BYTE_SIGNS, (groups, 1)).ravel(), index.pq.centroids)
            index.is_trained = True
            for _, _, codes in self.codebook_.iter_blocks():
                index.add_sa_codes(np.packbits(codes > 0, axis=1, bitorder="little"))
            self._cache.index = index
        return self._cache.index

    def _decoder(self) -> BlockDecoder:
        """The bounded exact search over blocks of places (:mod:`btel.methods.codes.decoding`), built once."""
        if self._cache.decoder is None:
            self._cache.decoder = BlockDecoder(self.codebook_, self._width(), self._packed_of)
        return self._cache.decoder

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        """m · c_i for every place (the exact soft decode), (n, N) float64."""
        with _blas_for(Q.shape[0], self.n_codes_ * (self.n_selected_ + int(self.n_places_))):
            M = self._padded(self._margins(Q))
            out = np.empty((Q.shape[0], int(self.n_places_)))
            for a, b, codes in self._code_blocks():
                out[:, a:b] = M @ codes.T
        return out

    def _coarse_default(self) -> bool:
        """Whether ``search`` decodes coarse to fine (``decode`` and the family; 'auto': long maps only)."""
        if self.code_ not in ROUTE_FAMILIES or self.decode == "exact":
            return False
        return self.decode == "coarse" or int(self.n_places_) >= COARSE_MIN_PLACES

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        # The search's own products are small per query (margins, bounds, refined blocks): one
        # BLAS thread, unless a large batch's dense product can use a second one.
        with _blas_for(1, 0):
            M = self._padded(self._margins(Q))
            if self._coarse_default():
                block, candidates = self._coarse_shape()
                if k <= block * candidates:
                    return self._coarse_search(M, k, block, candidates)
            if M.shape[0] < BATCH_DENSE_FROM:  # single queries: the whole decode on one BLAS thread
                return self._exact_search(M, k)
        return self._exact_search(M, k)

    def exact_path(self, n_queries: int = 1) -> str:
        """The exact decode :meth:`search` runs for ``n_queries`` queries: 'bounded', 'dense', 'scan' or 'probe'.

        'probe': a batch whose first queries are decoded by the bounded search, the rest by whichever
        of 'bounded' and 'dense' the places they scored predict to be cheaper
        (:func:`~btel.methods.codes.decoding.choose_path`).
        """
        return choose_path(int(self.n_places_), self._width(), n_queries, self.code_ in ROUTE_FAMILIES,
                           self._dense_codes() is not None)

    def _exact_search(self, M: np.ndarray, k: int, path: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Top k of m · c_i over every place, by ``path`` (default :func:`~btel.methods.codes.decoding.choose_path`)."""
        # Non-finite margins (a model file with huge but finite weights) are an error naming the cause,
        # not an answer: argmax over NaN scores would return a place.
        self._check_answers(None, M)
        path = path or self.exact_path(M.shape[0])
        if path == "probe":  # a batch: the first queries by the bounded search tell which path is cheaper
            head = min(PROBE_QUERIES, M.shape[0])
            with _blas_for(1, 0):
                s_head, p_head, visited = self._decoder().search(M[:head], k)
            fraction = float(visited.mean()) * self._decoder().block / int(self.n_places_)
            rest = choose_path(int(self.n_places_), self._width(), M.shape[0], True, True, visited=fraction)
            s_rest, p_rest = self._exact_search(M[head:], k, rest) if head < M.shape[0] else (s_head[:0], p_head[:0])
            return np.concatenate([s_head, s_rest]), np.concatenate([p_head, p_rest])
        if path == "bounded":
            with _blas_for(1, 0):
                scores, places, _ = self._decoder().search(M, k)
            return scores, places
        if path == "scan":
            index = self._adc_index()
            if index is not None:
                with faiss_threads(search_threads(self.n_jobs, M.shape[0])):
                    scores, places = index.search(M, k)
                return scores.astype(np.float64), places.astype(np.int64)
        n = M.shape[0]
        dense = self._dense_codes()
        if dense is not None and n * dense.shape[0] <= _BLOCK_VALUES:
            # One product over the cached codewords (small maps, small batches): no blocks, no merging.
            with _blas_for(1, 0):
                scores = M @ dense.T
            if k == 1:  # argmax: the first maximum, i.e. ties to the lower place as top_k
                places = np.argmax(scores, axis=1)[:, None]
                values = np.take_along_axis(scores, places, axis=1).astype(np.float64)
            else:
                values, places = top_k(scores, k)
            self._check_answers(None, values)  # finite margins can still overflow float32 in the product
            return values, places.astype(np.int64)
        best_s = np.empty((n, 0), dtype=np.float32)
        best_p = np.empty((n, 0), dtype=np.int64)
        with _blas_for(n, self.n_codes_ * int(self.n_places_)):
            for a, b, codes in self._code_blocks():
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
        block = int(self.coarse_block) if self.coarse_block is not None else max(1, int(round(np.sqrt(n / t))))
        return min(block, n), min(t, -(-n // min(block, n)))

    def _block_means(self) -> np.ndarray:
        block, _ = self._coarse_shape()
        if self._cache.means is None or self._cache.means[0] != block:
            n_blocks = -(-int(self.n_places_) // block)
            means = np.empty((n_blocks, self._width()), dtype=np.float32)
            rows = max(block, (_BLOCK_VALUES // self.n_codes_) // block * block)
            for a, b, codes in self._code_blocks(rows):  # a is a multiple of block
                starts = np.arange(0, b - a, block)
                counts = np.diff(np.append(starts, b - a)).astype(np.float32)
                means[a // block : a // block + starts.size] = np.add.reduceat(codes, starts, axis=0) / counts[:, None]
            self._cache.means = (block, means)
        return self._cache.means[1]

    def _coarse_search(self, M: np.ndarray, k: int, block: int, candidates: int) -> tuple[np.ndarray, np.ndarray]:
        """Score blocks by their mean codeword, then every place of the best blocks exactly."""
        n_places = int(self.n_places_)
        means = self._block_means()
        width = candidates * block
        out_s = np.empty((M.shape[0], k))
        out_p = np.empty((M.shape[0], k), dtype=np.int64)
        step = max(1, _BLOCK_VALUES // (width * self.n_codes_))
        for a in range(0, M.shape[0], step):
            m = M[a : a + step]
            coarse = m @ means.T
            blocks = np.argpartition(-coarse, candidates - 1, axis=1)[:, :candidates] if candidates < coarse.shape[1] \
                else np.broadcast_to(np.arange(coarse.shape[1]), coarse.shape)
            # Candidates in place order, so that ties go to the lower place as in the exact decode.
            places = np.sort((blocks[:, :, None] * block + np.arange(block)).reshape(m.shape[0], width), axis=1)
            valid = places < n_places
            codes = self._codes_of(np.where(valid, places, 0).ravel()).reshape(m.shape[0], width, -1)
            scores = np.matmul(codes, m[:, :, None])[:, :, 0].astype(np.float64)
            scores[~valid] = -np.inf
            values, cols = top_k(scores, k)
            out_s[a : a + step] = values
            out_p[a : a + step] = np.take_along_axis(places, cols, axis=1)
        return out_s, out_p

    # ------------------------------------------------------------------ storage and files
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = {**self.weights_.arrays(), "bias": self.bias_}
        if self.columns_ is not None:
            arrays["columns"] = self.columns_
        return arrays

    def _fitted_state(self) -> dict[str, Any]:
        return {"n_codes": self.n_codes_, "n_selected": self.n_selected_, "weight_bits": self.weight_bits_,
                "code": self.code_, "code_reason": self.code_reason_, "code_seed": self.code_seed_, "alpha": self.alpha_, "n_unconverged": self.n_unconverged_,
                "plan_rule": self.plan_.rule, "plan_budget": self.plan_.budget}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        K = read_state_int(state, "n_codes", 1, MAX_COLUMNS)
        d_sel = read_state_int(state, "n_selected", 1, d)
        bits = read_state_int(state, "weight_bits", 4, 32)
        if bits not in WEIGHT_BITS:
            raise ModelFileError(f"the model file's weight width {bits} is not one of {WEIGHT_BITS}.")
        return code_array_specs(K, d_sel, d, bits)

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        try:
            self._check_combinations()
        except InvalidParameterError as exc:
            raise ModelFileError(f"the model file's parameters contradict each other: {exc}") from exc
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        K, d_sel = int(state["n_codes"]), int(state["n_selected"])
        seed = read_state_int(state, "code_seed", 0, 2**32 - 1)
        family = state.get("code", self.code)  # files written before code='auto' record only the parameter
        if family not in FAMILIES or (self.code != "auto" and family != self.code):
            raise ModelFileError(f"the model file's code family {family!r} is not one of {FAMILIES}"
                                 + ("" if self.code == "auto" else f" or contradicts its parameter code={self.code!r}")
                                 + "; the file is damaged or from another version. Refit and save it again.")
        if self.decode == "coarse" and family not in ROUTE_FAMILIES:
            raise ModelFileError(f"the model file asks for decode='coarse' with {family} codes, which have no "
                                 "route order; the file is damaged. Refit and save it again.")
        reason = state.get("code_reason")
        self.code_, self.code_reason_ = family, reason if isinstance(reason, str) else "given"
        codebook = Codebook(family, int(state["n_places"]), K, seed)  # InvalidParameterError → ModelFileError
        columns = arrays.get("columns")
        if columns is not None and (int(columns.max()) >= d or np.any(np.diff(columns.astype(np.int64)) <= 0)):
            raise ModelFileError("the model file's kept columns are not increasing indices below d.")
        bias = arrays["bias"]
        if not np.isfinite(bias).all():
            raise ModelFileError("the model file's biases contain NaN or infinite values.")
        self.weights_ = QuantisedWeights.from_arrays(arrays, int(state["weight_bits"]), d_sel)
        self.bias_ = bias
        self.columns_ = columns
        alpha = state.get("alpha")
        self.alpha_ = float(alpha) if isinstance(alpha, (int, float)) and not isinstance(alpha, bool) else None
        self.n_unconverged_ = read_state_int(state, "n_unconverged", 0, K)
        rule, room = state.get("plan_rule"), state.get("plan_budget")
        self.plan_ = CodePlan(K, d_sel, int(state["weight_bits"]),
                              int(sum(spec.nbytes for spec in self._array_specs(state).values())),
                              room if isinstance(room, int) and not isinstance(room, bool) else None,
                              rule if isinstance(rule, str) else "recorded without a rule")
        self._set_structure(codebook)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(super().__getstate__())
        if "_cache" in state:  # runtime caches are rebuilt on demand, not shipped to workers
            state["_cache"] = _RuntimeCache()
        return state


#: Below this many multiply-adds a decode runs its BLAS products on one thread (see _blas_for).
_SMALL_PRODUCT = 1 << 27


def _blas_for(n_queries: int, work_per_query: int) -> Any:
    """One BLAS thread for the decode's products, unless a large batch (where a second thread can pay).

    Measured on the shared 2-core machine (load ≈ 12): the (200 × 242) · (242 × 244) margin
    product of a Gardens Point batch took 71 ms with OpenBLAS' two threads (spinning against other
    processes) and 4 ms with one; the coarse decode's (4000 × 470) matrix-vector product of one
    query at N = 10⁶ took 14–21 ms with two threads and 2 ms with one (setting the limit per call
    cost less than the noise).
    """
    if n_queries > 64 and n_queries * work_per_query >= _SMALL_PRODUCT:
        return blas_threads(None)
    return blas_threads(1)


class _RuntimeCache:
    """What inference derives from the stored arrays once (not stored, not compared: one object per model).

    ``dense``: (d', K) float32 dequantised weights; ``codes``: the (N, 8⌈K/8⌉) float32 codewords
    when small (:data:`~btel.methods.codes.decoding.DENSE_CACHE_BYTES`); else ``packed``: the (N, ⌈K/8⌉)
    packed codebook up to :data:`PACKED_CACHE_BYTES`, filled on demand (``filled``: which chunks);
    ``index``: faiss' scan (the 'random' family only); ``decoder``: the bounded search's block
    bounds; ``means``: (B, the ⌈N/B⌉ × K block-mean codewords of the coarse decode).
    """

    def __init__(self) -> None:
        self.dense: np.ndarray | None = None
        self.codes: np.ndarray | None = None
        self.packed: np.ndarray | None = None
        self.filled: np.ndarray | None = None
        self.index: Any = None
        self.decoder: BlockDecoder | None = None
        self.means: tuple[int, np.ndarray] | None = None
