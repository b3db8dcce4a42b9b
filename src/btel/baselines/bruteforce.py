"""Brute-force nearest neighbour: every map descriptor at float32, exact L2 search (SPEC §8).

The upper reference of every comparison: storage grows linearly in N (N×d×4 bytes) and a query
costs N distance computations. The search is faiss' exact ``IndexFlatL2``, built at fit time or,
after loading, from the stored descriptors on first use.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ..base import register_model
from ..exceptions import ModelFileError
from ._common import _RowLocalizer, raise_budget_too_small

__all__ = ["BruteForceNN"]


@register_model
class BruteForceNN(_RowLocalizer):
    """Exact L2 nearest neighbour over the stored map descriptors.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``). Brute force has a single configuration, N×d float32 values
        (plus the row → place table when ``places`` maps several rows to one place): if that
        exceeds the budget, ``fit`` raises :class:`~btel.exceptions.BudgetTooSmallError` naming it.

    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).
    Attributes
    ----------
    descriptors_ : ndarray of shape (n_rows, n_features), float32
        The map, exactly what inference reads.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,), unsigned int, or None
        Place of each row when ``places`` was given (None: row i = place i).
    fit_time_ : float
        Seconds.

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(100, 16)).astype(np.float32)
    >>> BruteForceNN().fit(X).predict(X[:3]).tolist()
    [0, 1, 2]
    """

    def __init__(self, *, budget: int | str | None = None, n_jobs: int | None = None) -> None:
        self.budget = budget
        self.n_jobs = n_jobs

    @staticmethod
    def planned_bytes(n_rows: int, n_features: int) -> int:
        """Storage of a map of ``n_rows`` descriptors of dimension ``n_features``: N·d·4 bytes."""
        return int(n_rows) * int(n_features) * 4

    def _fit_rows(self, X: np.ndarray, budget: int | None, extra_bytes: int) -> None:
        needed = self.planned_bytes(*X.shape) + extra_bytes
        if budget is not None and needed > budget:
            raise_budget_too_small(
                "brute-force NN", budget, needed, f"all {X.shape[0]} descriptors × {X.shape[1]} float32 values"
            )
        # A private copy: the index must not change if the caller later edits X.
        self.descriptors_ = np.array(X, dtype=np.float32, order="C", copy=True)
        self._index = None

    def _get_index(self) -> faiss.IndexFlatL2:
        if getattr(self, "_index", None) is None:
            index = faiss.IndexFlatL2(self.descriptors_.shape[1])
            index.add(self.descriptors_)
            self._index = index
        return self._index

    def _search_rows(self, Q: np.ndarray, k: int) -> np.ndarray:
        _, rows = self._get_index().search(Q, k)
        return rows.astype(np.int64)

    def _model_arrays(self) -> dict[str, np.ndarray]:
        return {"descriptors": self.descriptors_}

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        descriptors = arrays["descriptors"]
        if descriptors.dtype != np.float32 or descriptors.ndim != 2 or descriptors.shape[1] != self.n_features_in_:
            raise ModelFileError(
                f"brute-force model file holds descriptors of shape {descriptors.shape} and dtype "
                f"{descriptors.dtype}; expected float32 with {self.n_features_in_} columns."
            )
        self.descriptors_ = np.ascontiguousarray(descriptors)
        self._index = None
