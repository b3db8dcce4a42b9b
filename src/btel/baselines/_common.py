"""What every baseline shares: place labels of map rows, ranking, budgets and quiet faiss training.

A baseline indexes map *rows* (descriptors) and answers with *places*. With ``places`` given to
``fit`` several rows may belong to one place; the row → place table is then stored (smallest
unsigned dtype, counted in storage, since inference reads it) and :meth:`_RowLocalizer.rank`
returns unique places, best first. Without ``places`` row i is place i and nothing extra is stored.

A subclass implements the row index: ``_fit_rows``, ``_search_rows`` (k best rows per query, best
first), ``_model_arrays``, ``_model_state`` and ``_restore_model``.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import time
from typing import Any, Iterator

import numpy as np

from .._validation import check_descriptors, check_places, check_positive_int
from ..base import PlaceLocalizer
from ..exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError, NotEnoughPlacesError
from ..storage import format_bytes, parse_budget

__all__ = ["quiet_faiss", "faiss_threads", "smallest_uint_dtype", "rank_unique_places", "raise_budget_too_small"]

#: faiss' k-means prints this from C++ whenever it has fewer than 39 points per centroid, which is
#: the normal case for a map of a few thousand places; it is not actionable for a btel user.
_FAISS_NOISE = re.compile(r"^WARNING clustering \d+ points to \d+ centroids")


@contextlib.contextmanager
def quiet_faiss() -> Iterator[None]:
    """Hide faiss' "WARNING clustering N points to K centroids" lines written to file descriptor 2.

    faiss writes from C++ straight to fd 2, past ``sys.stderr``, so the descriptor itself is
    redirected to a temporary file for the duration of the block. Every other line written
    meanwhile (by faiss or anything else) is passed on to ``sys.stderr`` afterwards, not lost.
    """
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (embedded interpreters): nothing to silence
        yield
        return
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            text = capture.read().decode("utf-8", errors="replace")
            kept = [line for line in text.splitlines(keepends=True) if not _FAISS_NOISE.match(line)]
            if kept:
                sys.stderr.write("".join(kept))


@contextlib.contextmanager
def faiss_threads(n_jobs: int | None) -> Iterator[None]:
    """Run faiss with ``n_jobs`` OpenMP threads inside the block (None: leave faiss' setting).

    ``-1`` means every core. Small indexes train and search faster on one thread, and OpenMP's
    busy-waiting makes an oversubscribed machine (parallel tests, several fits at once) much slower.
    The setting is process-wide while the block runs and is restored afterwards.
    """
    if n_jobs is None:
        yield
        return
    import faiss

    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs == 0 or n_jobs < -1:
        raise InvalidParameterError(f"n_jobs must be None, -1 (all cores) or a positive integer; got {n_jobs!r}.")
    previous = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads((os.cpu_count() or 1) if n_jobs == -1 else n_jobs)
    try:
        yield
    finally:
        faiss.omp_set_num_threads(previous)


def smallest_uint_dtype(max_value: int) -> np.dtype:
    """The smallest unsigned integer dtype that holds ``max_value``."""
    for dtype in (np.uint8, np.uint16, np.uint32):
        if max_value <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.uint64)


def rank_unique_places(row_ranking: np.ndarray, row_places: np.ndarray, k: int) -> np.ndarray:
    """Turn ranked map rows into the first ``k`` distinct places per query, best first.

    Parameters
    ----------
    row_ranking : ndarray of shape (n_queries, k_rows), int
        Map rows per query, best first. Each row must name at least ``k`` distinct places.
    row_places : ndarray of shape (n_rows,), int
        Place label of every map row.
    k : int

    Returns
    -------
    ndarray of shape (n_queries, k), int64
    """
    labels = np.asarray(row_places, dtype=np.int64)[row_ranking]
    # First occurrence of each label within a query row: sort stably, mark label changes,
    # scatter the marks back to the original (ranked) positions.
    order = np.argsort(labels, axis=1, kind="stable")
    sorted_labels = np.take_along_axis(labels, order, axis=1)
    first_sorted = np.ones(sorted_labels.shape, dtype=bool)
    first_sorted[:, 1:] = sorted_labels[:, 1:] != sorted_labels[:, :-1]
    first = np.empty_like(first_sorted)
    np.put_along_axis(first, order, first_sorted, axis=1)
    keep = first & (np.cumsum(first, axis=1) <= k)
    return labels[keep].reshape(labels.shape[0], k)


def raise_budget_too_small(method: str, budget: int, minimum: int, detail: str) -> None:
    """Raise :class:`BudgetTooSmallError` naming the minimum bytes and the smallest configuration."""
    raise BudgetTooSmallError(
        f"budget {format_bytes(budget)} ({budget} B) is too small for {method}: its smallest configuration "
        f"({detail}) needs {minimum} B ({format_bytes(minimum)}). Raise the budget to at least {minimum} B "
        "or choose a method whose storage grows more slowly with the map.",
        budget=budget,
        minimum=minimum,
    )


class _RowLocalizer(PlaceLocalizer):
    """Shared ``fit``/``predict``/``rank``/storage plumbing of the baselines (see module docstring)."""

    supports_ranking = True

    #: Fewest map rows the method can index (k-means and PCA need a few).
    _min_rows: int = 2
    #: faiss threads for fit and search (every subclass takes ``n_jobs``; see :func:`faiss_threads`).
    n_jobs: int | None = None

    # -- to implement ------------------------------------------------------------------------
    def _fit_rows(self, X: np.ndarray, budget: int | None, extra_bytes: int) -> None:  # pragma: no cover
        """Fit the row index on ``X`` within ``budget − extra_bytes`` bytes (``budget`` may be None)."""
        raise NotImplementedError

    def _search_rows(self, Q: np.ndarray, k: int) -> np.ndarray:  # pragma: no cover
        """The ``k`` best map rows per query, best first: int64 (n_queries, k)."""
        raise NotImplementedError

    def _model_arrays(self) -> dict[str, np.ndarray]:  # pragma: no cover
        raise NotImplementedError

    def _model_state(self) -> dict[str, Any]:
        return {}

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:  # pragma: no cover
        raise NotImplementedError

    # -- shared ------------------------------------------------------------------------------
    def fit(self, X: Any, places: Any = None) -> "_RowLocalizer":
        """Index the map descriptors.

        Parameters
        ----------
        X : array-like of shape (n_rows, n_features)
            Map descriptors in route order.
        places : array-like of int of shape (n_rows,), optional
            Place label of each row (several rows may share a place); default: row i = place i.

        Returns
        -------
        self
        """
        start = time.perf_counter()
        budget = parse_budget(self.budget)
        X = check_descriptors(X, name="X")
        n_rows = X.shape[0]
        if places is None:
            row_places, n_places = None, n_rows
            if n_places < 2:
                raise NotEnoughPlacesError(
                    f"N = {n_places} place(s): an index needs at least 2 places. Fit on a longer route."
                )
        else:
            labels, n_places = check_places(places, n_rows)
            # Row i = place i needs no table; any other labelling is stored for inference.
            identity = n_places == n_rows and np.array_equal(labels, np.arange(n_rows))
            row_places = None if identity else labels.astype(smallest_uint_dtype(n_places - 1))
        if n_rows < self._min_rows:
            raise NotEnoughPlacesError(
                f"{type(self).__name__} needs at least {self._min_rows} map descriptors; got {n_rows}."
            )
        extra = 0 if row_places is None else int(row_places.nbytes)
        with faiss_threads(self.n_jobs):
            self._fit_rows(X, budget, extra)
        self.row_places_ = row_places
        self.n_features_in_ = int(X.shape[1])
        self.fit_time_ = time.perf_counter() - start
        self.n_places_ = int(n_places)  # the fitted marker: set last
        return self

    def predict(self, Q: Any) -> np.ndarray:
        """Place of each query.

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)

        Returns
        -------
        ndarray of shape (n_queries,), dtype int64
            Values in ``[0, n_places_)``.
        """
        Q = self._check_queries(Q)
        with faiss_threads(self.n_jobs):
            rows = self._search_rows(Q, 1)[:, 0]
        return rows.astype(np.int64) if self.row_places_ is None else self.row_places_[rows].astype(np.int64)

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """The ``k`` best places per query, best first (``k`` is capped at ``n_places_``).

        Returns
        -------
        ndarray of shape (n_queries, min(k, n_places_)), dtype int64
            Distinct places per row.
        """
        Q = self._check_queries(Q)
        k = min(check_positive_int(k, "k"), self.n_places_)
        if self.row_places_ is None:
            with faiss_threads(self.n_jobs):
                return self._search_rows(Q, k).astype(np.int64)
        # k places need at most k·(most rows of one place) rows.
        per_place = int(np.bincount(self.row_places_.astype(np.int64)).max())
        n_rows = self.row_places_.shape[0]
        with faiss_threads(self.n_jobs):
            rows = self._search_rows(Q, min(n_rows, k * per_place))
        return rank_unique_places(rows, self.row_places_, k)

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = dict(self._model_arrays())
        if self.row_places_ is not None:
            arrays["row_places"] = self.row_places_
        return arrays

    def _fitted_state(self) -> dict[str, Any]:
        return {
            "n_places": self.n_places_,
            "n_features_in": self.n_features_in_,
            "fit_time": self.fit_time_,
            **self._model_state(),
        }

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        row_places = arrays.get("row_places")
        n_places = int(state["n_places"])
        if row_places is not None:
            if row_places.ndim != 1 or row_places.dtype.kind != "u" or int(row_places.max()) >= n_places:
                raise ModelFileError(f"the model file's row_places table does not fit N = {n_places} places.")
        self.row_places_ = row_places
        self.n_features_in_ = int(state["n_features_in"])
        self.fit_time_ = float(state.get("fit_time", float("nan")))
        self._restore_model(arrays, state)
        self.n_places_ = n_places

    def __getstate__(self) -> dict[str, Any]:
        # A faiss index does not pickle (joblib/dask workers); subclasses rebuild it from the
        # stored arrays on first use.
        state = super().__getstate__()
        state.pop("_index", None)
        return state
