"""Product quantisation (Jégou et al. 2011) with faiss, under a storage budget (the paper's baselines).

Each map descriptor, optionally projected to p dimensions, is cut into M sub-vectors of p/M
dimensions; each sub-vector is replaced by the index of its nearest centroid in a 2^nbits-entry
codebook learned by k-means. A query is compared with every code by asymmetric distance
computation (faiss ``IndexPQ``: an exact linear scan over the codes; the query stays in float).

Storage (the storage rule of docs/guide/concepts.md), at stored dtype:

- codes: ``n_rows × ceil(M·nbits/8)`` bytes (faiss ``sa_code_size()`` per row);
- codebooks: ``M × 2^nbits × (p/M)`` float32 = ``2^nbits · p · 4`` bytes;
- the projection, when p < d: a d×p float32 PCA matrix. No mean is stored: L2 distances are
  translation invariant, so the codebooks are learned on the un-centred projection ``X @ P`` and
  a query is projected the same way (faiss' own PCA file would hold the full d×d eigenvectors).

Budget rule (deterministic): enumerate every configuration (p, M, nbits) with

- p ∈ {d (no projection)} ∪ {1, 2, 4, 8, … < d} ∪ {every p whose d×p projection alone fits the
  budget}, each ≤ the number of map rows (PCA needs as many rows as components);
- M dividing p;
- nbits ∈ {8, 4} with 2^nbits ≤ number of map rows (k-means needs a point per centroid); on a map
  of fewer than 16 rows, the largest nbits with 2^nbits ≤ its rows (3 bits for 8–15 rows);

keep those whose bytes fit, and take the one with the most code bits per row (M·nbits); ties go
to fewer bytes, then larger p, then larger nbits. Explicit ``pca_dim``, ``n_subquantizers`` or
``nbits`` pin that part of the configuration and the rule chooses the rest. On raw 3780-D HOG of
3576 Nordland frames, 500 KB selects no PCA, M = 140, nbits = 4: 492 240 B (the Nordland figures of docs/results.md).

Without a budget: p = d when d ≤ 256, else PCA to the largest power of two ≤ min(256, rows);
nbits = 8 (4 when there are fewer than 256 map rows; below 16 rows as above); M = the largest
divisor of p that is ≤ 32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator

import faiss
import numpy as np

from ...core.storage import UNLIMITED_BUDGET, spent_text
from ...core.validation import N_JOBS, RANDOM_STATE, Interval, check_positive_int, read_state_int
from ..base import ArraySpec
from ...exceptions import CollidingCodesWarning, InvalidParameterError, ModelFileError
from ._common import _RowLocalizer, check_model_values, index_search, negated_distances, quiet_faiss, raise_budget_too_small

__all__ = ["PQConfig", "PQLocalizer", "pca_projection"]

#: Sub-quantiser sizes the budget rule considers (bits per sub-quantiser).
AUTO_NBITS: tuple[int, ...] = (8, 4)


def auto_nbits(n_rows: int) -> list[int]:
    """The bits per sub-quantiser the planner considers for a map of ``n_rows`` rows, most first: those of
    :data:`AUTO_NBITS` with a map row per centroid, else (fewer than 16 rows) the most bits with one."""
    return [b for b in AUTO_NBITS if (1 << b) <= n_rows] or [max(1, n_rows.bit_length() - 1)]


#: Without a budget, descriptors wider than this are reduced by PCA.
DEFAULT_MAX_DIM = 256
#: Without a budget, the number of sub-quantisers is the largest divisor of p up to this.
DEFAULT_MAX_SUBQUANTIZERS = 32


@dataclass(frozen=True)
class PQConfig:
    """One product-quantiser configuration: code dimension p, M sub-quantisers of nbits bits."""

    dim: int
    n_subquantizers: int
    nbits: int

    @property
    def code_size(self) -> int:
        """Bytes per code (faiss ``sa_code_size()``)."""
        return (self.n_subquantizers * self.nbits + 7) // 8

    @property
    def code_bits(self) -> int:
        return self.n_subquantizers * self.nbits

    @property
    def codebook_bytes(self) -> int:
        """M codebooks of 2^nbits centroids of p/M float32 values."""
        return (1 << self.nbits) * self.dim * 4


def pca_projection(X: np.ndarray, dim: int, random_state: int | None) -> np.ndarray:
    """The d×p matrix of the top ``dim`` principal directions of ``X`` (columns orthonormal).

    scikit-learn's PCA (its 'auto' solver: randomized SVD for few components of a large matrix),
    not faiss' ``PCAMatrix``, which eigen-decomposes the full d×d covariance (minutes at d = 3780).

    Returns
    -------
    ndarray of shape (n_features, dim), float32
    """
    from sklearn.decomposition import PCA  # fit-only: a loaded model never imports scikit-learn

    # A map of (almost) no variance in float32 (tiny values, no normalisation): scikit-learn divides by its
    # zero total variance for explained_variance_ratio_, which is not read here.
    with np.errstate(divide="ignore", invalid="ignore"):
        pca = PCA(n_components=dim, random_state=random_state).fit(X)
    return np.ascontiguousarray(pca.components_.T, dtype=np.float32)


def _powers_of_two_below(limit: int, cap: int) -> list[int]:
    dims, p = [], 2
    while p < limit and p <= cap:
        dims.append(p)
        p *= 2
    return dims


def _divisors(n: int) -> list[int]:
    small = [m for m in range(1, int(n**0.5) + 1) if n % m == 0]
    return sorted(set(small + [n // m for m in small]))


class PQLocalizer(_RowLocalizer):
    """Product quantisation with an optional PCA projection, fitted to a byte budget.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``); ``fit`` picks the configuration by the rule in
        :mod:`btel.methods.baselines.pq` (most code bits that fit) and raises
        :class:`~btel.exceptions.BudgetTooSmallError` with the minimum when nothing fits.
    n_subquantizers : int, optional
        M; must divide the code dimension. None: chosen by the rule / default.
    nbits : int, optional
        Bits per sub-quantiser, 1 … 8 (2^nbits centroids, at most the number of map rows).
    pca_dim : int, optional
        Code dimension p; ``pca_dim == n_features`` means no projection.
    random_state : int or None
        Seed of k-means and of the randomized PCA.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    config_ : PQConfig
        The chosen (p, M, nbits).
    codes_ : ndarray of shape (n_rows, code_size), uint8
    codebooks_ : ndarray of shape (M, 2**nbits, p // M), float32
    projection_ : ndarray of shape (n_features, p), float32, or None
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    front_end_ : FrontEnd
    fit_time_ : float

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(300, 32)).astype(np.float32)
    >>> model = PQLocalizer(budget="20KB").fit(X)
    >>> model.nbytes <= 20_000
    True
    """

    label = "pq"
    _float32_distances = True  # a map of tiny rows is refused at fit (_common.MIN_NORM)
    #: The fitted state's name of a parameter the planner fills in (run records report its chosen value).
    _STATE_OF_PARAM = {"pca_dim": "dim"}
    _parameter_constraints = {
        "n_subquantizers": [None, Interval(int, 1, 1 << 16)],
        "nbits": [None, Interval(int, 1, 8)],
        "pca_dim": [None, Interval(int, 1, None)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
    }

    def __init__(
        self,
        *,
        budget: int | str | None = None,
        n_subquantizers: int | None = None,
        nbits: int | None = None,
        pca_dim: int | None = None,
        random_state: int | None = 0,
        n_jobs: int | None = None,
    ) -> None:
        self.budget = budget
        self.n_subquantizers = n_subquantizers
        self.nbits = nbits
        self.pca_dim = pca_dim
        self.random_state = random_state
        self.n_jobs = n_jobs

    # -- configuration -------------------------------------------------------------------------
    @staticmethod
    def projection_bytes(n_features: int, dim: int, always: bool = False) -> int:
        """Bytes of the stored d×p projection (0 when p = d, unless a rotation is ``always`` stored)."""
        return 0 if dim == n_features and not always else n_features * dim * 4

    def planned_bytes(self, n_rows: int, n_features: int, *, config: PQConfig,
                      always_project: bool = False) -> int:
        """Storage of ``config`` for ``n_rows`` map rows of dimension ``n_features`` (no row table)."""
        return n_rows * config.code_size + config.codebook_bytes + \
            self.projection_bytes(n_features, config.dim, always_project)

    def _check_explicit(self, n_rows: int, n_features: int) -> tuple[int | None, int | None, int | None]:
        dim = m = nbits = None
        if self.pca_dim is not None:
            dim = check_positive_int(self.pca_dim, "pca_dim")
            if dim > n_features:
                raise InvalidParameterError(
                    f"pca_dim={dim} exceeds the descriptor dimension {n_features}; use pca_dim ≤ {n_features} "
                    f"(pca_dim={n_features} keeps the descriptors unprojected for PQ)."
                )
            if dim < n_features and dim > n_rows:
                raise InvalidParameterError(
                    f"pca_dim={dim} needs at least {dim} map descriptors to learn {dim} principal directions; "
                    f"got {n_rows}. Use pca_dim ≤ {n_rows}."
                )
        if self.n_subquantizers is not None:
            m = check_positive_int(self.n_subquantizers, "n_subquantizers")
        if self.nbits is not None:
            nbits = check_positive_int(self.nbits, "nbits")
            if nbits > 8:
                raise InvalidParameterError(f"nbits must be between 1 and 8; got {nbits}.")
            if (1 << nbits) > n_rows:
                raise InvalidParameterError(
                    f"nbits={nbits} needs at least {1 << nbits} map descriptors to train {1 << nbits} centroids "
                    f"per sub-quantiser; got {n_rows}. Use nbits ≤ {n_rows.bit_length() - 1}."
                )
        return dim, m, nbits

    def candidates(self, n_rows: int, n_features: int, budget: int | None = None,
                   max_dim: int | None = None) -> Iterator[PQConfig]:
        """Every configuration the budget rule considers, given the explicit parameters (``max_dim``: the
        largest code dimension p allowed, OPQ's number of map rows)."""
        dim, m, nbits = self._check_explicit(n_rows, n_features)
        # Every p whose d×p projection alone fits the budget, beside the powers of two: on wide descriptors the
        # projection takes most of the bytes, and the powers of two left up to half of the budget unspent.
        # p = 1 always: the cheapest configuration, which a budget too small is told it needs.
        fitting = range(1, min(n_features - 1, n_rows, max(1, (budget or 0) // (4 * n_features))) + 1)
        dims = [dim] if dim is not None else sorted({n_features, *_powers_of_two_below(n_features, n_rows),
                                                     *fitting}, reverse=True)
        bits = [nbits] if nbits is not None else auto_nbits(n_rows)
        for p in dims:
            if max_dim is not None and p > max_dim:
                continue
            for b in bits:
                for mm in ([m] if m is not None else _divisors(p)):
                    if mm <= p and p % mm == 0:
                        yield PQConfig(p, mm, b)

    def _default_config(self, n_rows: int, n_features: int, max_dim: int | None = None) -> PQConfig:
        dim, m, nbits = self._check_explicit(n_rows, n_features)
        if dim is None:
            if n_features <= min(DEFAULT_MAX_DIM, max_dim or n_features):
                dim = n_features
            else:
                dim = max(_powers_of_two_below(n_features, min(DEFAULT_MAX_DIM, n_rows, max_dim or n_rows)),
                          default=n_features)
        if nbits is None:
            nbits = auto_nbits(n_rows)[0]
        if m is None:
            m = max(q for q in _divisors(dim) if q <= DEFAULT_MAX_SUBQUANTIZERS)
        if dim % m:
            raise InvalidParameterError(
                f"n_subquantizers={m} must divide the code dimension {dim}; choose a divisor of {dim} "
                "or set pca_dim to a multiple of n_subquantizers."
            )
        return PQConfig(dim, m, nbits)

    def choose_config(self, n_rows: int, n_features: int, budget: int | None, extra_bytes: int = 0, *,
                      method_name: str = "PQ", always_project: bool = False,
                      max_dim: int | None = None) -> PQConfig:
        """The configuration ``fit`` uses (see the module docstring for the rule).

        ``always_project`` counts a d×p matrix for every p (OPQ's rotation); ``max_dim`` caps p (OPQ's
        rotation is learnt from the map's rows, at most one dimension per row).
        """
        if budget is None:
            return self._default_config(n_rows, n_features, max_dim)
        options = [
            (c, self.planned_bytes(n_rows, n_features, config=c, always_project=always_project) + extra_bytes)
            for c in self.candidates(n_rows, n_features, budget, max_dim)
        ]
        if not options:
            raise InvalidParameterError(
                f"no {method_name} configuration matches n_subquantizers={self.n_subquantizers}, "
                f"pca_dim={self.pca_dim}: n_subquantizers must divide the code dimension."
            )
        fitting = [(c, b) for c, b in options if b <= budget]
        if not fitting:
            smallest, minimum = min(options, key=lambda cb: (cb[1], -cb[0].code_bits))
            raise_budget_too_small(
                method_name, budget, minimum,
                f"p = {smallest.dim}, {smallest.n_subquantizers} sub-quantiser(s) × {smallest.nbits} bits",
            )
        return max(fitting, key=lambda cb: (cb[0].code_bits, -cb[1], cb[0].dim, cb[0].nbits))[0]

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self.choose_config(n_rows, n_features_out, budget, reserved)

    def budget_saturated(self) -> bool:
        """True when no budget gives a larger configuration: the planner's choice without a byte limit."""
        if self.budget is None:
            return False
        n_rows, d = self.codes_.shape[0], self.front_end_.n_features_out(int(self.n_features_in_))
        return self.choose_config(n_rows, d, UNLIMITED_BUDGET) == self.config_

    def summary(self) -> str:
        """One line: the planner's configuration, its projection, the bytes against the budget."""
        c, d = self.config_, int(self.front_end_.n_features_out(int(self.n_features_in_)))
        on = f"a PCA projection {d} → {c.dim} dims" if self.projection_ is not None else f"all {c.dim} dims"
        # The planner's steps are coarse (sub-quantisers, bits, projection width): say what is left.
        return (f"pq: {c.n_subquantizers} sub-quantisers × {c.nbits} bits ({c.code_size} B a row) on {on}; "
                f"{spent_text(self)}; front end {self.front_end_.describe()}")

    # -- fitting -------------------------------------------------------------------------------
    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        n_rows, n_features = X.shape
        config = self.choose_config(n_rows, n_features, budget, reserved)
        projection = None if config.dim == n_features else pca_projection(X, config.dim, self.random_state)
        Y = X if projection is None else np.ascontiguousarray(X @ projection, dtype=np.float32)
        index = faiss.IndexPQ(config.dim, config.n_subquantizers, config.nbits)
        if self.random_state is not None:
            index.pq.cp.seed = int(self.random_state)
        with quiet_faiss():
            index.train(Y)
        index.add(Y)
        self.projection_ = projection
        self.codebooks_ = faiss.vector_to_array(index.pq.centroids).reshape(
            config.n_subquantizers, 1 << config.nbits, config.dim // config.n_subquantizers
        ).astype(np.float32)
        self.codes_ = faiss.vector_to_array(index.codes).reshape(n_rows, index.sa_code_size())
        self.config_ = config
        self._index = index
        if getattr(self, "_warn_colliding_codes", True):
            warn_if_codes_collide("pq", config, n_rows, n_features, budget)

    def _build_index(self) -> faiss.IndexPQ:
        c = self.config_
        index = faiss.IndexPQ(c.dim, c.n_subquantizers, c.nbits)
        faiss.copy_array_to_vector(np.ascontiguousarray(self.codebooks_).ravel(), index.pq.centroids)
        index.is_trained = True
        index.add_sa_codes(np.ascontiguousarray(self.codes_))
        return index

    # -- inference -----------------------------------------------------------------------------
    def project(self, Q: Any) -> np.ndarray:
        """Queries in the code space: front end, then the projection (identity when none is stored).

        Returns
        -------
        ndarray of shape (n_queries, p), float32
        """
        return self._projected(self._check_queries(Q))

    def _projected(self, Q: np.ndarray) -> np.ndarray:
        # float32 @ float32 is a C-contiguous float32 array: what faiss reads as is.
        return Q if self.projection_ is None else Q @ self.projection_

    def _search_bytes_per_query(self) -> int:
        # faiss' IndexPQ search builds every query's M × 2^nbits float32 distance table at once.
        return self.config_.n_subquantizers * (1 << self.config_.nbits) * 4

    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        dist, rows = index_search(self._index, self._projected(Q), k)  # faiss' labels are int64
        return negated_distances(dist) if scores else None, rows

    # -- storage and files ---------------------------------------------------------------------
    def _model_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"codes": self.codes_, "codebooks": self.codebooks_}
        if self.projection_ is not None:
            arrays["projection"] = self.projection_
        return arrays

    def _model_state(self) -> dict[str, Any]:
        c = self.config_
        return {"dim": c.dim, "n_subquantizers": c.n_subquantizers, "nbits": c.nbits}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        config = read_config(state, d)
        specs = pq_specs(config)
        if config.dim != d:
            specs["projection"] = ArraySpec((d, config.dim), np.float32)
        return specs

    def _n_rows(self) -> int:
        return int(self.codes_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        projection = arrays.get("projection")
        check_finite(arrays, ("codebooks", "projection"), "PQ")
        self._set_codes(read_config(state, d), arrays["codes"], arrays["codebooks"], projection)

    def _set_codes(self, config: PQConfig, codes: np.ndarray, codebooks: np.ndarray,
                   projection: np.ndarray | None) -> "PQLocalizer":
        """Adopt trained codes and codebooks (a loaded file, or OPQ's quantiser) and build the index."""
        self.config_, self.codes_, self.codebooks_, self.projection_ = config, codes, codebooks, projection
        self._index = self._build_index()
        return self


def warn_if_codes_collide(method: str, config: PQConfig, n_rows: int, n_features: int, budget: int | None) -> None:
    """Warn when the budget leaves codes of fewer than log2 N bits: at most 2^bits distinct codes, so rows share
    them whatever the quantiser learns (typically a projection to a few dimensions taking the budget). A
    model whose ``_warn_colliding_codes`` is False (a calibration candidate) is not warned about by its fit:
    an attribute, not a warnings filter, which is process-wide and unsafe in threaded fits."""
    if budget is None or (1 << min(config.code_bits, 62)) >= n_rows:
        return
    import warnings

    projection = f"; the projection {n_features} → {config.dim} dims" if config.dim != n_features else ""
    warnings.warn(
        f"{method} at {budget:,} B: codes of {config.code_bits} bits (at most {1 << config.code_bits:,} distinct "
        f"codes for {n_rows:,} map rows{projection}), so many places share a code. Use `lsh` or `auto`, or a larger "
        "budget.", CollidingCodesWarning, stacklevel=2)


def read_config(state: dict[str, Any], d: int) -> PQConfig:
    """The (p, M, nbits) recorded in a model file, checked (ModelFileError) against the dimension d."""
    dim = read_state_int(state, "dim", 1, d)
    m = read_state_int(state, "n_subquantizers", 1, dim)
    nbits = read_state_int(state, "nbits", 1, 8)
    if dim % m:
        raise ModelFileError(f"the model file's n_subquantizers = {m} does not divide its code dimension {dim}.")
    return PQConfig(dim, m, nbits)


def pq_specs(config: PQConfig) -> dict[str, ArraySpec]:
    """Codes and codebooks of a product quantiser (the number of codes is free)."""
    return {"codes": ArraySpec((None, config.code_size), np.uint8),
            "codebooks": ArraySpec((config.n_subquantizers, 1 << config.nbits,
                                    config.dim // config.n_subquantizers), np.float32)}


def check_finite(arrays: dict[str, np.ndarray], names: tuple[str, ...], method: str) -> None:
    """ModelFileError when a float array of a model file holds NaN, infinity or values beyond MAX_NORM."""
    check_model_values(arrays, names, method)
