"""BTEL beyond the binary index: K ≥ b implicit output codes, fitted to a byte budget.

:class:`CodeLocalizer` generalises BTE-C (:mod:`btel.methods.btel.compressed`) from the b bits of
a place's index to K ≥ b code columns (error-correcting output codes, Dietterich & Bakiri 1995):

1. place i has a codeword c_i ∈ {−1, +1}^K from a family (:mod:`btel.methods.codes.codebook`:
   ``periodic``, ``blocks``, ``random``, and BTE-C's own ``binary`` and ``offset`` codes),
   regenerated from (family, N, K, seed) — never stored;
2. one linear model per column predicts it from the descriptor, all K fitted as one multi-output
   ridge problem in closed form (or one liblinear SVM per column;
   :mod:`btel.methods.codes.solvers`), on d' shared columns of largest variance;
3. the weights are stored at 32, 16, 8 or 4 bits with one scale per column
   (:mod:`btel.methods.codes.quantise`);
4. a query's K margins m are decoded softly over every place: score_i = m · c_i (the Gaussian
   log-likelihood of the margins up to a constant). The exact top k comes from the cheapest exact
   path for the shape (:func:`btel.methods.codes.decoding.choose_path`, a measured rule): one dense
   product with the float32 codewords on small maps, a bounded search over blocks of consecutive
   places on larger ones (:mod:`btel.methods.codes.decoding`), faiss' packed PQ scan for the
   'random' family. ``place_scores`` is the same sum in blocks of places; ``rank``, the HMM decoder
   and streaming come from the base class. Long maps of route families are decoded coarse to fine
   (``decode``; approximate; :mod:`btel.methods.codes.codewords`).

Storage is K·d' weights (plus K scales and biases, and d' column indices), independent of N, so it
stays sub-linear, and K is the dial that turns bytes into accuracy: the budget planner
(:mod:`btel.methods.codes.planning`) picks K, d' and the weight width that fill the budget; the
model file is :mod:`btel.methods.codes.model_file`.

**Relation to BTELocalizer.** ``btel-c`` (:class:`btel.methods.btel.localizer.BTELocalizer`) stays
the paper's BTE-C, unchanged; ``code='binary'`` and ``code='offset'`` regenerate its columns exactly.
Regions and per-classifier feature selection do not compose with the codes, on purpose; the
sequence filter and the HMM decoder do (``docs/decisions/codes-families.md``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.validation import MAX_C, N_JOBS, RANDOM_STATE, Interval, Options, String
from ..base import PlaceLocalizer
from ...exceptions import BudgetTooSmallError, InvalidDescriptorsError, InvalidParameterError
from ...learning.distributed import BACKENDS
from ...learning.feature_selection import column_index_dtype
from ...learning.hyperplanes import check_fitted_weights
from ...learning.linear import ColumnStats
from ...core.storage import UNLIMITED_BUDGET, exact_bytes
from .codebook import FAMILIES, MAX_COLUMNS, ROUTE_FAMILIES, Codebook
from .codewords import RuntimeCache
from .model_file import CodeModelFile
from .search import COARSE_MIN_PLACES, CodeSearch
from .planning import CodePlan, plan_codes
from .quantise import WEIGHT_BITS, quantise
from .solvers import fit_liblinear_codes, fit_ridge_codes

__all__ = ["CodeLocalizer", "SOLVERS", "DECODES", "COARSE_MIN_PLACES"]

SOLVERS = ("ridge", "liblinear")
DECODES = ("auto", "exact", "coarse")


class CodeLocalizer(CodeModelFile, CodeSearch, PlaceLocalizer):
    """Output-code localization: K implicit ±1 code columns per place, predicted linearly, decoded softly.

    Parameters
    ----------
    code : {'auto', 'periodic', 'blocks', 'random', 'binary', 'offset'}
        Code family (:mod:`btel.methods.codes.codebook`). 'periodic' (multi-scale square waves) for maps that
        are routes; 'random' for maps of independent places; 'binary' / 'offset' are BTE-C's codes.
        'auto' (the default) chooses from the map alone by the test ``auto`` uses
        (:func:`btel.methods.auto.index_order`: route share and continuity): periodic on a route or an
        ordered map, random on independent places; the family chosen is ``code_``, recorded in the model
        file and restored on load. The test reads the map once more (≈ 1 s for Nordland's 3576 × 3780
        rows); pass a family to skip it.
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
        Ridge regularisation α on the front-end-transformed map. None: α = 0.1 × the mean non-zero
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
        B, places per block of the coarse decode. None: √(N / (coarse_candidates · c)), c = the cost of
        a refined place against a block's coarse row
        (:data:`~btel.methods.codes.search.REFINED_PLACE_COST`), so the two passes cost about the same.
    coarse_candidates : int
        Blocks scored exactly by the coarse decode.
    random_state : int or None
        Seed of the codewords (and of liblinear). None draws one; the seed used is recorded in the
        model file either way, so a loaded model regenerates the same codewords.
    n_jobs, backend, scheduler
        Parallel fitting of the code columns (as :class:`~btel.methods.btel.localizer.BTELocalizer`); runtime
        settings, not saved.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).

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

    label = "btel-codes"
    encodes_place_index = True
    _fit_reads_row_blocks = True  # the ridge reads row blocks: an L2 front end hands it the map unscaled

    _parameter_constraints = {
        "code": [Options("auto", *FAMILIES)],
        "n_codes": [None, Interval(int, 1, MAX_COLUMNS)],
        "n_features": [None, Interval(int, 1, None)],
        "weight_bits": [None, Options(*WEIGHT_BITS)],
        "solver": [Options(*SOLVERS)],
        "alpha": [None, Interval(float, 0, None, closed="neither")],
        "C": [Interval(float, 0, MAX_C, closed="right")],
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
        code: str = "auto",
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
                "decode='coarse' needs codes that change slowly along the route "
                f"({', '.join(ROUTE_FAMILIES)}); the {self.code} family has none. Use decode='exact'.")

    def _choose_family(self, X: np.ndarray, places: np.ndarray | None) -> tuple[str, str]:
        """The code family and why: ``code`` itself, or for 'auto' periodic on a route or an ordered
        map, random on independent places."""
        if self.code != "auto":
            return self.code, "given"
        from ..auto import index_order

        order = index_order(getattr(X, "raw", X), places)  # cosines: the rows' L2 scaling changes none
        family = "random" if order.kind == "independent" else "periodic"
        kinds = {"route": "a route", "ordered": "an ordered map", "independent": "independent places"}
        kind = kinds[order.kind]
        return family, f"code='auto': {kind} ({order.why}) → {family}"

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
                f"budget {exact_bytes(budget)} is too small for output codes ({family}, "
                f"N = {n_places}): the smallest model needs {exact_bytes(minimum)}, front end "
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
        if self.normalize == "none":  # raw rows: the fitted weights (≈ 1/‖x‖) must stay normal float32 numbers
            _check_raw_values(X)
        if self.solver != "ridge":  # liblinear reads the map whole
            X = np.asarray(X)
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
            fitted = fit_liblinear_codes(X, cols, codebook, places, C=float(self.C),
                                         max_iter=int(self.max_iter), random_state=self.random_state,
                                         **common)
        weights = quantise(fitted.weights, plan.bits)
        # The bias from the stored weights, so quantisation does not shift every margin by (w − w_q)·μ.
        stored = weights.dequantise().astype(np.float64)
        self.bias_ = (fitted.offsets - stored @ fitted.center).astype(np.float32)
        check_fitted_weights(stored, self.bias_, "The fitted code columns")  # what load refuses, refused here
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
        self._cache = RuntimeCache(self.codebook_)

    def budget_saturated(self) -> bool:
        """True when no budget gives more codes, columns or weight bits: the planner's choice without a byte limit."""
        if self.budget is None:
            return False
        d = self.front_end_.n_features_out(int(self.n_features_in_))
        cap = self._plan(int(self.n_places_), d, UNLIMITED_BUDGET, 0, self.code_)
        return (cap.n_codes, cap.n_selected, cap.bits) == (self.n_codes_, self.n_selected_, self.weight_bits_)

    def summary(self) -> str:
        """One line on what was fitted: family, K, d', width, the planner's rule, α."""
        alpha = f", ridge α = {self.alpha_:.4g}" if self.alpha_ is not None else ", liblinear"
        why = f" [{self.code_reason_}]" if self.code == "auto" else ""
        return f"{self.code_} codes{why} (seed {self.code_seed_}): {self.plan_.describe()}{alpha}"

    def __getstate__(self) -> dict[str, Any]:
        state = dict(super().__getstate__())
        if "_cache" in state:  # runtime caches are rebuilt on demand, not shipped to workers
            state["_cache"] = RuntimeCache(self.codebook_)
        return state


#: Largest raw value (``normalize='none'``) whose map the ridge fit answers: the weights scale as the
#: inverse of the rows' length, and past about 1e37 they fall below float32's smallest normal number
#: (1.2e-38), quantise to nothing and every query gets the same answer.
MAX_RAW_VALUE = 1e35


def _check_raw_values(X: Any, chunk_values: int = 1 << 22) -> None:
    """InvalidDescriptorsError when a value of the (raw) map exceeds :data:`MAX_RAW_VALUE` in magnitude."""
    step = max(1, chunk_values // max(X.shape[1], 1))
    for start in range(0, X.shape[0], step):
        largest = float(np.abs(np.asarray(X[start : start + step])).max(initial=0.0))
        if largest > MAX_RAW_VALUE:
            raise InvalidDescriptorsError(
                f"X holds values up to {largest:.3g} (rows {start}–{min(X.shape[0], start + step) - 1}); with "
                f"normalize='none' btel-codes fits maps whose values stay within ±{MAX_RAW_VALUE:.0e} (its "
                "weights shrink as the values grow, below float32's range past that). Scale the descriptors "
                "down (or use normalize='l2').")
