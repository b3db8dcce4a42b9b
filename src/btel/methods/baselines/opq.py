"""Optimised product quantisation (Ge et al. 2014) with faiss, under a storage budget (the paper's baselines).

OPQ learns an orthogonal rotation that balances the variance across the M sub-spaces before
product quantisation (faiss ``OPQMatrix``, alternating PQ training and a Procrustes update; its
inner product quantiser has the same M and nbits as the final codes). When the code dimension p is
below d, the descriptors are first reduced by PCA and the p×p rotation is learned on the PCA
output; the two are folded into one d×p matrix, which is all inference reads. (faiss' own d→p
OPQ starts from a random d×d rotation and keeps d×d work per iteration: minutes at d = 3780.)

OPQ *contains* a PQ (as nanopq does): its ``pq`` parameter is a :class:`~btel.methods.baselines.PQLocalizer`
whose ``n_subquantizers``, ``nbits``, ``pca_dim`` and ``random_state`` configure the quantiser, and
after fitting ``pq_`` is that quantiser fitted on the rotated descriptors. Storage: codes and
codebooks as for PQ (:mod:`btel.methods.baselines.pq`) plus the d×p float32 rotation, which OPQ always
stores (p = d included). No mean: L2 distances are translation invariant. The budget rule,
defaults and explicit parameters are PQ's, with the rotation's d·p·4 bytes counted for every p.

Training cost: ``n_iter`` rounds of (M k-means + a p×p SVD). faiss' default is 50 rounds; btel uses
20: on Nordland HOG (PCA 64, M = 16, 8 bits) round 20 has 93 % of the error reduction of round 50
at 40 % of the time. Many sub-quantisers (M = p, as the "most code bits" rule picks at large
budgets) cost minutes at N ≈ 3600; p = d is also slow for very wide descriptors (p³ per round).
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ...core.storage import UNLIMITED_BUDGET
from ...core.validation import N_JOBS, Instance, Interval
from ..base import ArraySpec
from ...exceptions import InvalidParameterError
from ...core.frontend import FrontEnd
from ._common import _RowLocalizer, quiet_faiss
from .pq import PQConfig, PQLocalizer, check_finite, pca_projection, pq_specs, read_config, warn_if_codes_collide

__all__ = ["OPQLocalizer"]


class OPQLocalizer(_RowLocalizer):
    """PCA (when p < d), a learned rotation, then product quantisation, fitted to a byte budget.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``); the most code bits that fit, as for :class:`PQLocalizer`, with the
        d×p rotation counted. :class:`~btel.exceptions.BudgetTooSmallError` when nothing fits.
    pq : PQLocalizer, optional
        The product quantiser's settings (``n_subquantizers``, ``nbits``, ``pca_dim``,
        ``random_state``); None: ``PQLocalizer()``. Its own budget and front end are not used.
        Nested parameters follow scikit-learn: ``OPQLocalizer().set_params(pq__nbits=4)`` (or ``make_method("opq",
        pq__nbits=4)``) sets them on the default ``PQLocalizer()``.
    n_iter : int
        Rounds of rotation learning (faiss ``OPQMatrix.niter``; faiss' default is 50).
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    pq_ : PQLocalizer
        The quantiser, fitted on the rotated descriptors ``X @ projection_`` (its ``config_``,
        ``codes_`` and ``codebooks_`` are OPQ's).
    projection_ : ndarray of shape (n_features, p), float32
        PCA directions times the OPQ rotation; a query's code-space vector is ``Q @ projection_``.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    front_end_ : FrontEnd
    fit_time_ : float
    """

    label = "opq"
    _float32_distances = True  # a map of tiny rows is refused at fit (_common.MIN_NORM)
    _parameter_constraints = {
        "pq": [None, Instance(PQLocalizer)],
        "n_iter": [Interval(int, 1, 10_000)],
        "n_jobs": N_JOBS,
    }

    _nested_defaults = {"pq": PQLocalizer}

    def __init__(
        self,
        *,
        budget: int | str | None = None,
        pq: PQLocalizer | None = None,
        n_iter: int = 20,
        n_jobs: int | None = None,
    ) -> None:
        self.budget = budget
        self.pq = pq
        self.n_iter = n_iter
        self.n_jobs = n_jobs

    def _quantiser(self) -> PQLocalizer:
        """A fresh copy of the ``pq`` settings (the parameter itself is never modified). Its parameters
        are scalars: this is scikit-learn's ``clone``, without importing scikit-learn on load."""
        return PQLocalizer() if self.pq is None else type(self.pq)(**self.pq.get_params(deep=False))

    @property
    def config_(self) -> PQConfig:
        """The chosen (p, M, nbits): the contained quantiser's."""
        return self.pq_.config_

    def _choose_config(self, pq: PQLocalizer, n_rows: int, n_features: int, budget: int | None,
                       reserved: int) -> PQConfig:
        """The contained quantiser's planner with the d × p rotation counted at every p, and p ≤ N: faiss'
        ``OPQMatrix.train`` corrupts its heap on fewer rows than dimensions (a crash, or minutes of work,
        from 201 rows of 200 dims up)."""
        if pq.pca_dim is not None and pq.pca_dim > n_rows:
            raise InvalidParameterError(
                f"OPQ learns its p × p rotation from the map's rows, so p must be ≤ N = {n_rows}; got "
                f"pca_dim={pq.pca_dim}. Give pca_dim ≤ {n_rows} (or leave it to the budget).")
        return pq.choose_config(n_rows, n_features, budget, reserved, method_name="OPQ", always_project=True,
                                max_dim=n_rows)

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self._choose_config(self._quantiser(), n_rows, n_features_out, budget, reserved)

    def budget_saturated(self) -> bool:
        """True when no budget gives a larger configuration: the planner's choice without a byte limit."""
        if self.budget is None:
            return False
        n_rows, d = self.pq_.codes_.shape[0], self.front_end_.n_features_out(int(self.n_features_in_))
        return self._choose_config(self._quantiser(), n_rows, d, UNLIMITED_BUDGET, 0) == self.config_

    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        pq = self._quantiser()
        config = self._choose_config(pq, X.shape[0], X.shape[1], budget, reserved)
        projection = self._learn_projection(X, config, pq.random_state)
        Y = np.ascontiguousarray(X @ projection, dtype=np.float32)
        pq.set_params(budget=None, n_subquantizers=config.n_subquantizers, nbits=config.nbits, pca_dim=config.dim,
                      normalize="none", whiten=None, delta=None, n_jobs=self.n_jobs)
        self.pq_ = pq.fit(Y)
        self.projection_ = projection
        if getattr(self, "_warn_colliding_codes", True):
            warn_if_codes_collide("opq", config, X.shape[0], X.shape[1], budget)

    def _learn_projection(self, X: np.ndarray, config: PQConfig, random_state: int | None) -> np.ndarray:
        pca = None if config.dim == X.shape[1] else pca_projection(X, config.dim, random_state)
        Z = X if pca is None else np.ascontiguousarray(X @ pca, dtype=np.float32)
        opq = faiss.OPQMatrix(config.dim, config.n_subquantizers)
        opq.niter = int(self.n_iter)
        # Optimise the rotation for the quantiser actually used (faiss' default inner PQ is 8-bit,
        # which would also need ≥ 256 rows).
        inner = faiss.ProductQuantizer(config.dim, config.n_subquantizers, config.nbits)
        if random_state is not None:
            inner.cp.seed = int(random_state)
        opq.pq = inner
        with quiet_faiss():
            opq.train(Z)
        # faiss applies y = A z with A of shape (p, p); as a right-multiplied matrix that is A.T.
        rotation = faiss.vector_to_array(opq.A).reshape(config.dim, config.dim).T
        projection = rotation if pca is None else pca @ rotation
        return np.ascontiguousarray(projection, dtype=np.float32)

    def project(self, Q: Any) -> np.ndarray:
        """Queries in the code space: front end, then ``Q @ projection_``.

        Returns
        -------
        ndarray of shape (n_queries, p), float32
        """
        return self._projected(self._check_queries(Q))

    def _projected(self, Q: np.ndarray) -> np.ndarray:
        return Q @ self.projection_  # float32 @ float32: C-contiguous float32, what faiss reads as is

    def _search_bytes_per_query(self) -> int:
        return self.pq_._search_bytes_per_query()

    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        return self.pq_._search_rows(self._projected(Q), k, scores)

    # -- storage and files ---------------------------------------------------------------------
    def _model_arrays(self) -> dict[str, np.ndarray]:
        return {"codes": self.pq_.codes_, "codebooks": self.pq_.codebooks_, "projection": self.projection_}

    def _model_state(self) -> dict[str, Any]:
        return self.pq_._model_state()

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        config = read_config(state, d)
        return {**pq_specs(config), "projection": ArraySpec((d, config.dim), np.float32)}

    def _n_rows(self) -> int:
        return int(self.pq_.codes_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        check_finite(arrays, ("codebooks", "projection"), "OPQ")
        config = read_config(state, d)
        pq = self._quantiser().set_params(budget=None, n_subquantizers=config.n_subquantizers, nbits=config.nbits,
                                          pca_dim=config.dim, normalize="none", whiten=None, delta=None)
        self.pq_ = pq._set_codes(config, arrays["codes"], arrays["codebooks"], None)
        # The contained quantiser is a fitted PQ over the rotated descriptors in every respect.
        self.pq_.front_end_, self.pq_.row_places_ = FrontEnd(), None
        self.pq_.n_features_in_, self.pq_.fit_time_ = config.dim, float("nan")
        self.pq_.n_places_ = int(arrays["codes"].shape[0])
        self.projection_ = arrays["projection"]
