"""Optimised product quantisation (Ge et al. 2014) with faiss, under a storage budget (SPEC §8).

OPQ learns an orthogonal rotation that balances the variance across the M sub-spaces before
product quantisation (faiss ``OPQMatrix``, alternating PQ training and a Procrustes update; its
inner product quantiser has the same M and nbits as the final codes). When the code dimension p is
below d, the descriptors are first reduced by PCA and the p×p rotation is learned on the PCA
output; the two are folded into one d×p matrix, which is all inference reads. (faiss' own d→p
OPQ starts from a random d×d rotation and keeps d×d work per iteration: minutes at d = 3780.)

Storage: codes and codebooks as for PQ (:mod:`btel.baselines.pq`) plus the d×p float32 rotation,
which OPQ always stores (p = d included). No mean: L2 distances are translation invariant.
The budget rule, defaults and explicit parameters are those of :class:`~btel.baselines.PQLocalizer`
with the rotation's d·p·4 bytes counted for every p.

Training cost: ``n_iter`` rounds of (M k-means + a p×p SVD). faiss' default is 50 rounds; btel uses
20: on Nordland HOG (PCA 64, M = 16, 8 bits) round 20 has 93 % of the error reduction of round 50
at 40 % of the time. Many sub-quantisers (M = p, as the "most code bits" rule picks at large
budgets) cost minutes at N ≈ 3600; p = d is also slow for very wide descriptors (p³ per round).
"""

from __future__ import annotations

from typing import ClassVar

import faiss
import numpy as np

from .._validation import check_positive_int
from ..base import register_model
from ._common import quiet_faiss
from .pq import PQConfig, _PQBase, pca_projection

__all__ = ["OPQLocalizer"]


@register_model
class OPQLocalizer(_PQBase):
    """PCA (when p < d), a learned rotation, then product quantisation, fitted to a byte budget.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``); the most code bits that fit, as for :class:`PQLocalizer`, with the
        d×p rotation counted. :class:`~btel.exceptions.BudgetTooSmallError` when nothing fits.
    n_subquantizers : int, optional
        M; must divide p.
    nbits : int, optional
        Bits per sub-quantiser, 1 … 8.
    pca_dim : int, optional
        Code dimension p (``n_features``: rotation without reduction).
    random_state : int or None
        Seed of k-means and of the randomized PCA (faiss seeds the initial rotation itself).
    n_iter : int
        Rounds of rotation learning (faiss ``OPQMatrix.niter``; faiss' default is 50).
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    config_ : PQConfig
    codes_ : ndarray of shape (n_rows, code_size), uint8
    codebooks_ : ndarray of shape (M, 2**nbits, p // M), float32
    projection_ : ndarray of shape (n_features, p), float32
        PCA directions times the OPQ rotation; a query's code-space vector is ``Q @ projection_``.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    fit_time_ : float
    """

    _method_name: ClassVar[str] = "OPQ"
    _projection_required: ClassVar[bool] = True

    def __init__(
        self,
        *,
        budget: int | str | None = None,
        n_subquantizers: int | None = None,
        nbits: int | None = None,
        pca_dim: int | None = None,
        random_state: int | None = 0,
        n_iter: int = 20,
        n_jobs: int | None = None,
    ) -> None:
        super().__init__(
            budget=budget, n_subquantizers=n_subquantizers, nbits=nbits, pca_dim=pca_dim,
            random_state=random_state, n_jobs=n_jobs,
        )
        self.n_iter = n_iter

    def _check_params(self) -> None:
        check_positive_int(self.n_iter, "n_iter")

    def _projection_bytes(self, n_features: int, dim: int) -> int:
        return n_features * dim * 4

    def _learn_projection(self, X: np.ndarray, config: PQConfig) -> np.ndarray:
        pca = None if config.dim == X.shape[1] else pca_projection(X, config.dim, self.random_state)
        Z = X if pca is None else np.ascontiguousarray(X @ pca, dtype=np.float32)
        opq = faiss.OPQMatrix(config.dim, config.n_subquantizers)
        opq.niter = int(self.n_iter)
        # Optimise the rotation for the quantiser actually used (faiss' default inner PQ is 8-bit,
        # which would also need ≥ 256 rows).
        inner = faiss.ProductQuantizer(config.dim, config.n_subquantizers, config.nbits)
        if self.random_state is not None:
            inner.cp.seed = int(self.random_state)
        opq.pq = inner
        with quiet_faiss():
            opq.train(Z)
        # faiss applies y = A z with A of shape (p, p); as a right-multiplied matrix that is A.T.
        rotation = faiss.vector_to_array(opq.A).reshape(config.dim, config.dim).T
        projection = rotation if pca is None else pca @ rotation
        return np.ascontiguousarray(projection, dtype=np.float32)
