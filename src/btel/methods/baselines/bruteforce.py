"""Brute-force nearest neighbour: every map descriptor at float32, exact search (the paper's baselines).

The upper reference of every comparison: storage grows linearly in N (N×d×4 bytes) and a query
costs N distance computations. The search is exact, by faiss, built at fit time and when a model
is loaded: with a normalising front end (the default ``normalize='l2'``) it is **cosine similarity**
(``IndexFlatIP`` on the unit rows; scores are the cosines), the strongest honest form of brute force
for global descriptors; with ``normalize='none'`` it is L2 (``IndexFlatL2``; scores are minus the
squared distances). The two rank unit vectors alike, except that a zero row (a delta descriptor of
a traverse's first frame, which carries no change) scores 0 under cosine but sits at distance 1
from every query under L2, where it swallowed most cross-season queries
(``docs/decisions/front-ends.md``).
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ...core.validation import N_JOBS
from ..base import ArraySpec
from ...exceptions import ModelFileError
from ._common import _RowLocalizer, check_magnitude, index_search, negated_distances, raise_budget_too_small

__all__ = ["BruteForceNN"]


class BruteForceNN(_RowLocalizer):
    """Exact nearest neighbour over the stored map descriptors: cosine on normalised rows, else L2.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``). Brute force has a single configuration, N×d float32 values
        (plus the row → place table when ``places`` maps several rows to one place): if that
        exceeds the budget, ``fit`` raises :class:`~btel.exceptions.BudgetTooSmallError` naming it.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    descriptors_ : ndarray of shape (n_rows, n_features), float32
        The (front-end transformed) map, exactly what inference reads.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,), unsigned int, or None
        Place of each row when ``places`` was given (None: row i = place i).
    front_end_ : FrontEnd
    fit_time_ : float
        Seconds.

    Examples
    --------
    >>> import numpy as np
    >>> X = np.random.default_rng(0).normal(size=(100, 16)).astype(np.float32)
    >>> BruteForceNN().fit(X).predict(X[:3]).tolist()
    [0, 1, 2]
    """

    label = "bruteforce"
    _float32_distances = True  # a map of tiny rows is refused at fit (_common.MIN_NORM)
    _parameter_constraints = {"n_jobs": N_JOBS}

    def __init__(self, *, budget: int | str | None = None, n_jobs: int | None = None) -> None:
        self.budget = budget
        self.n_jobs = n_jobs

    @staticmethod
    def planned_bytes(n_rows: int, n_features: int) -> int:
        """Storage of a map of ``n_rows`` descriptors of dimension ``n_features``: N·d·4 bytes."""
        return int(n_rows) * int(n_features) * 4

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        needed = self.planned_bytes(n_rows, n_features_out) + reserved
        if budget is not None and needed > budget:
            raise_budget_too_small(
                "brute-force NN", budget, needed, f"all {n_rows} descriptors × {n_features_out} float32 values"
            )

    def budget_saturated(self) -> bool:
        """True under any budget: the map is stored whole, whatever the budget (it only has to fit)."""
        return self.budget is not None

    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        self._check_plan(*X.shape, budget, reserved)
        # A private copy: the index must not change if the caller later edits X.
        self.descriptors_ = np.array(X, dtype=np.float32, order="C", copy=True)
        self._index = self._build_index()

    @property
    def metric(self) -> str:
        """'cosine' with a normalising front end, else 'l2'."""
        return "l2" if self.normalize == "none" else "cosine"

    def _build_index(self) -> faiss.IndexFlat:
        dim = self.descriptors_.shape[1]
        index = faiss.IndexFlatL2(dim) if self.metric == "l2" else faiss.IndexFlatIP(dim)
        index.add(self.descriptors_)
        return index

    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        values, rows = index_search(self._index, Q, k)
        rows = rows.astype(np.int64, copy=False)
        if not scores:
            return None, rows
        scores_ = negated_distances(values) if self.metric == "l2" else values.astype(np.float64)
        return scores_, rows

    def _model_arrays(self) -> dict[str, np.ndarray]:
        return {"descriptors": self.descriptors_}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        return {"descriptors": ArraySpec((None, d), np.float32)}

    def _n_rows(self) -> int:
        return int(self.descriptors_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        descriptors = arrays["descriptors"]
        check_magnitude(descriptors, "the brute-force model file's descriptors", error=ModelFileError)
        self.descriptors_ = np.ascontiguousarray(descriptors)
        self._index = self._build_index()
