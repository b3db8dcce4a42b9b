"""What every baseline shares: place labels of map rows, ranking, budgets and quiet faiss training.

A baseline indexes map *rows* (descriptors) and answers with *places*. With ``places`` given to
``fit`` several rows may belong to one place; the row → place table is then stored (smallest
unsigned dtype, counted in storage, since inference reads it) and the search returns unique
places, best first (a place scores its best row). Without ``places`` row i is place i and nothing
extra is stored.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
import tempfile
from abc import abstractmethod
from typing import Any, ClassVar, Iterator

import numpy as np

from ..base import ArraySpec, PlaceLocalizer
from ...exceptions import BudgetTooSmallError, InvalidDescriptorsError, ModelFileError
from ...core.rows import one_row_squares
from ...core.storage import exact_bytes
from ...core.threads import faiss_module, faiss_threads, search_threads

__all__ = ["quiet_faiss", "faiss_threads", "smallest_uint_dtype", "rank_unique_places", "raise_budget_too_small",
           "negated_distances", "index_search", "check_magnitude", "check_not_tiny", "check_model_values",
           "MAX_NORM", "MIN_NORM"]

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


def smallest_uint_dtype(max_value: int) -> np.dtype:
    """The smallest unsigned integer dtype that holds ``max_value``."""
    for dtype in (np.uint8, np.uint16, np.uint32):
        if max_value <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.uint64)


def rank_unique_places(row_ranking: np.ndarray, row_places: np.ndarray, k: int,
                       row_scores: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Turn ranked map rows into the first ``k`` distinct places per query, best first.

    Parameters
    ----------
    row_ranking : ndarray of shape (n_queries, k_rows), int
        Map rows per query, best first. Each row must name at least ``k`` distinct places.
    row_places : ndarray of shape (n_rows,), int
        Place label of every map row.
    k : int
    row_scores : ndarray of shape (n_queries, k_rows), optional
        Score of each ranked row (a place scores its best row).

    Returns
    -------
    places : ndarray of shape (n_queries, k), int64
    scores : ndarray of shape (n_queries, k), float64 (zeros without ``row_scores``)
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
    places = labels[keep].reshape(labels.shape[0], k)
    scores = np.zeros(places.shape) if row_scores is None else \
        np.asarray(row_scores, dtype=np.float64)[keep].reshape(labels.shape[0], k)
    return places, scores


#: Largest L2 norm of a descriptor (after the front end) a row index searches: squared distances
#: of such vectors stay far below float32's maximum (3.4e38), where faiss' distances overflow.
MAX_NORM = 1e18
#: Shortest the longest row of a map may be (after the front end) for an index of float32 distances
#: (the mirror of MAX_NORM): squared lengths below 1e-36 near float32's smallest normal number
#: (1.2e-38), below which squared distances keep fewer bits, then none — every place looks alike.
MIN_NORM = 1e-18
#: Scratch memory a batch search may take at once (64 MB): larger batches are searched in row chunks.
SEARCH_SCRATCH_BYTES = 1 << 26


def index_search(index: Any, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``index.search(x, k)`` of a faiss index; one query row through the index's own SWIG method.

    Parameters
    ----------
    index : faiss.Index or faiss.IndexBinary
    x : ndarray of shape (n, d), float32 (n, d / 8 uint8 for a binary index)
    k : int

    Returns
    -------
    distances : ndarray of shape (n, k), float32 (int32 for a binary index)
    labels : ndarray of shape (n, k), int64

    faiss' Python ``search`` converts and checks its input again on every call, a few µs: a share of
    one query that counts (the single-query decision page). A single C-contiguous row of the index's
    own dtype and width goes straight to ``search_c``, the SWIG method that ``search`` wraps; anything
    else goes through ``search``.
    """
    faiss = faiss_module()
    if x.shape[0] == 1 and x.flags.c_contiguous and k >= 1:
        binary = isinstance(index, faiss.IndexBinary)
        if (x.dtype == np.uint8 and x.shape[1] * 8 == index.d) if binary else \
                (x.dtype == np.float32 and x.shape[1] == index.d):
            distances = np.empty((1, k), dtype=np.int32 if binary else np.float32)
            labels = np.empty((1, k), dtype=np.int64)
            index.search_c(1, faiss.swig_ptr(x), k, faiss.swig_ptr(distances), faiss.swig_ptr(labels))
            return distances, labels
    return index.search(x, k)


def negated_distances(distances: np.ndarray) -> np.ndarray:
    """Scores from an index's distances: −distances in float64, (n_queries, k) as given.

    One query's one value is negated by Python arithmetic: a ufunc that casts costs microseconds more,
    a share of a single query that counts.
    """
    if distances.size == 1:
        return np.array(-float(distances.item(0)), ndmin=2)
    return np.negative(distances, dtype=np.float64)


def check_magnitude(X: np.ndarray, name: str, *, error: type[Exception] = InvalidDescriptorsError,
                    chunk_rows: int = 65536) -> float:
    """``error`` naming the first row of ``X`` that is not finite or whose L2 norm exceeds :data:`MAX_NORM`.

    Squared norms are summed in X's own float32: one that overflows is far beyond the bound anyway.
    Returns the largest squared norm (float32 arithmetic: 0 when every row underflows). ``X`` is read
    in blocks of rows of at most 2²² values (an ndarray, a memory map or lazily scaled rows).
    """
    if X.shape[0] == 1 and X.dtype == np.float32:  # one query (µs count here): one float64 dot, no FP state
        square = one_row_squares(X)
        if square <= MAX_NORM**2:  # False for NaN and inf: the full check names it
            return square
    largest = 0.0
    step = max(1, min(chunk_rows, (1 << 22) // max(X.shape[1], 1)))
    for start in range(0, X.shape[0], step):
        block = np.asarray(X[start : start + step])
        with np.errstate(over="ignore", invalid="ignore"):
            squares = np.einsum("ij,ij->i", block, block)
        bad = np.flatnonzero(~(squares <= MAX_NORM**2))
        if bad.size:
            row = start + int(bad[0])
            values = np.asarray(block[bad[0]], dtype=np.float64)
            length = float(np.sqrt(values @ values)) if np.isfinite(values).all() else float("nan")
            raise error(
                f"{name} row {row} has length {length:.3g} (after the front end); squared distances of "
                f"descriptors longer than {MAX_NORM:.0e} overflow float32. Scale the descriptors down (or "
                "use normalize='l2')."
            )
        if squares.size:
            largest = max(largest, float(squares.max()))
    return largest


def check_not_tiny(X: np.ndarray, largest_square: float, name: str) -> None:
    """InvalidDescriptorsError when every row of a map is shorter than :data:`MIN_NORM`, not all zero."""
    if largest_square >= MIN_NORM**2 or not np.any(X):
        return
    longest = 0.0
    for start in range(0, X.shape[0], 65536):
        block = np.asarray(X[start : start + 65536], dtype=np.float64)
        longest = max(longest, float(np.sqrt(np.einsum("ij,ij->i", block, block).max())))
    raise InvalidDescriptorsError(
        f"{name}'s rows are all shorter than {MIN_NORM:.0e} after the front end (the longest: "
        f"{longest:.3g}); their squared distances underflow float32, so every place would look alike. Scale "
        "the descriptors up (e.g. to unit length) or use normalize='l2'."
    )


def check_model_values(arrays: dict[str, np.ndarray], names: tuple[str, ...], method: str) -> None:
    """ModelFileError when a float array of a model file holds NaN, infinity or values beyond MAX_NORM."""
    for name in names:
        a = arrays.get(name)
        if a is not None and a.size and not (np.isfinite(a).all() and float(np.abs(a).max()) <= MAX_NORM):
            raise ModelFileError(f"the {method} model file's {name} contain NaN, infinite or out-of-range values.")


def recorded_kind(state: dict[str, Any], key: str, kinds: tuple[str, ...], method: str,
                  current: str | None = None) -> str:
    """The seeded transform a model file records under ``key`` (lsh's projection, RaBitQ's rotation).

    Files written before the key existed used ``kinds[-1]``. A name not in ``kinds``, or one that
    contradicts the parameters (``current``, when given), is a :class:`ModelFileError`.
    """
    kind = state.get(key, kinds[-1])
    if kind not in kinds:
        raise ModelFileError(f"the {method} model file's {key} {str(kind)[:40]!r} is not one of {kinds}.")
    if current is not None and key in state and kind != current:
        raise ModelFileError(f"the {method} model file's {key} {kind!r} contradicts its parameters "
                             f"({current!r}).")
    return kind


def raise_budget_too_small(method: str, budget: int, minimum: int, detail: str) -> None:
    """Raise :class:`BudgetTooSmallError` naming the minimum bytes and the smallest configuration."""
    raise BudgetTooSmallError(
        f"budget {exact_bytes(budget)} is too small for {method}: its smallest configuration "
        f"({detail}) needs {exact_bytes(minimum)}. Raise the budget to at least {minimum} B "
        "or choose a method whose storage grows more slowly with the map.",
        budget=budget,
        minimum=minimum,
    )


class _RowLocalizer(PlaceLocalizer):
    """Shared plumbing of the baselines that index map rows (see module docstring).

    A subclass implements ``_fit_rows(X, budget, reserved)`` (``reserved`` bytes of the budget are
    taken already: front end and row → place table), ``_search_rows(Q, k, scores) -> (scores, rows)``
    (the k best map rows per query, best first, higher score = better), ``_model_arrays``,
    ``_model_state``, ``_model_specs(state, n_rows)`` and ``_restore_model``.
    """

    _runtime_params = ("n_jobs",)
    #: True for an index of float32 squared distances: it refuses a map whose rows are all shorter than
    #: :data:`MIN_NORM` (sign codes and SeqSLAM's byte codes do not depend on the map's scale).
    _float32_distances: ClassVar[bool] = False

    def _search_bytes_per_query(self) -> int:
        """Scratch memory one query takes inside the index's batch search (0: negligible)."""
        return 0

    # -- to implement ------------------------------------------------------------------------
    @abstractmethod
    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        """Fit the row index on ``X`` within ``budget − reserved`` bytes (``budget`` may be None)."""

    @abstractmethod
    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        """(scores, rows): the ``k`` best map rows per query, best first, float64 and int64 (n_queries, k).

        ``scores=False``: the caller reads the rows only (:meth:`predict` of a map without a row table), so
        the scores may be None (no conversion of the index's distances).
        """

    @abstractmethod
    def _model_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of the row index."""

    def _model_state(self) -> dict[str, Any]:
        return {}

    @abstractmethod
    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        """Shape and dtype of every array of the row index (``None`` for the number of rows)."""

    @abstractmethod
    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        """Set the row index from checked arrays."""

    # -- shared ------------------------------------------------------------------------------
    def _fit(self, X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
             reserved: int) -> None:
        # Row i = place i needs no table; any other labelling is stored for inference.
        row_places = None if places is None else places.astype(smallest_uint_dtype(n_places - 1))
        extra = reserved + (0 if row_places is None else int(row_places.nbytes))
        largest = check_magnitude(X, "X")
        if self._float32_distances:
            check_not_tiny(X, largest, "X")
        with faiss_threads(self.n_jobs):
            self._fit_rows(X, budget, extra)
        self.row_places_ = row_places

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        # k places need at most k·(most rows of one place) rows.
        k_rows = k if self.row_places_ is None else \
            min(self._n_rows(), k * int(np.bincount(self.row_places_.astype(np.int64)).max()))
        scores, rows = self._checked_rows(Q, k_rows, True)
        if self.row_places_ is None:
            return scores, rows
        places, place_scores = rank_unique_places(rows, self.row_places_, k, scores)
        return place_scores, places

    def predict(self, Q: Any) -> np.ndarray:
        """Place index of each query (:meth:`PlaceLocalizer.predict`); one query by :meth:`_one_query`."""
        one = self._one_query(Q, False)
        return one[1][0] if one is not None else super().predict(Q)

    def search(self, Q: Any, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best places per query (:meth:`PlaceLocalizer.search`); one query's best by
        :meth:`_one_query`."""
        one = self._one_query(Q, True) if type(k) is int and k == 1 else None
        return one if one is not None else super().search(Q, k)

    def _one_query(self, Q: Any, scores: bool) -> tuple[np.ndarray | None, np.ndarray] | None:
        """(scores, rows) (1, 1) of the best row of one query of the common kind, or None: the general path.

        The common kind is a C-contiguous float32 row of the fitted width, the plain L2 front end, row i =
        place i and faiss' default threads; it takes the shortest path to the index with every check kept:
        the row's finite length (its float64 sum of squares), one faiss thread, the answer within the map, a
        finite score. Any other query, or one these checks refuse, takes the general path, which names the
        problem.
        """
        n_places = getattr(self, self._fitted_marker, None)  # None: not fitted (the general path says so)
        if not (type(Q) is np.ndarray and n_places is not None and Q.shape == (1, self.n_features_in_)
                and Q.flags.c_contiguous and self.row_places_ is None and self.n_jobs is None):
            return None
        scale = self.front_end_.one_row_scale(Q)  # None: not the plain L2 front end, or a row it refuses
        if scale is None:
            return None
        if faiss_module().omp_get_max_threads() == 1:  # already one thread: no context to enter
            values, rows = self._search_rows(Q * scale, 1, scores)
        else:
            with faiss_threads(1):
                values, rows = self._search_rows(Q * scale, 1, scores)
        if not 0 <= rows.item(0) < n_places or scores and not math.isfinite(values.item(0)):
            return None
        return values, rows

    def _predict(self, Q: np.ndarray) -> np.ndarray:
        if self.row_places_ is not None:  # a place scores its best row: the ranking of _search
            return super()._predict(Q)
        return self._checked_rows(Q, 1, False)[1][:, 0]  # row i is place i: no scores needed

    def _checked_rows(self, Q: np.ndarray, k: int, scores: bool) -> tuple[np.ndarray | None, np.ndarray]:
        """:meth:`_search_rows` on the right number of faiss threads, every row answered checked."""
        if self.front_end_.normalize == "none":  # a normalising front end hands over finite rows, length ≤ 1
            check_magnitude(Q, "Q")
        # Single queries on one faiss thread unless n_jobs says otherwise (btel.core.threads).
        with faiss_threads(search_threads(self.n_jobs, Q.shape[0])):
            step = max(1, SEARCH_SCRATCH_BYTES // max(1, self._search_bytes_per_query()))
            if Q.shape[0] <= step:
                values, rows = self._search_rows(Q, k, scores)
            else:  # the index's per-query scratch (PQ's look-up tables) grows with the batch: bound it
                parts = [self._search_rows(Q[start : start + step], k, scores) for start in range(0, Q.shape[0], step)]
                values = None if not scores else np.concatenate([p[0] for p in parts])
                rows = np.concatenate([p[1] for p in parts])
        n_rows = self._n_rows()
        # faiss answers −1 when no distance is finite (overflow, a corrupt index): never a place.
        if not (rows.size == 1 and 0 <= rows.item(0) < n_rows):  # one valid answer: no array passes
            bad = np.flatnonzero(((rows < 0) | (rows >= n_rows)).any(axis=1))
            if bad.size:
                raise InvalidDescriptorsError(
                    f"query row {int(bad[0])} has no finite distance to the map ({type(self).__name__}): its "
                    "values are too large for float32 arithmetic, or the model holds invalid values. Check "
                    "the descriptors."
                )
        return values, rows

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = dict(self._model_arrays())
        if self.row_places_ is not None:
            arrays["row_places"] = self.row_places_
        return arrays

    def _fitted_state(self) -> dict[str, Any]:
        return dict(self._model_state())

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        specs = dict(self._model_specs(state, d))
        specs["row_places"] = ArraySpec((None,), (np.uint8, np.uint16, np.uint32, np.uint64), required=False)
        return specs

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        row_places = arrays.get("row_places")
        n_places = int(state["n_places"])
        self._restore_model(arrays, state)
        n_rows = self._n_rows()
        if row_places is None:
            if n_rows != n_places:
                raise ModelFileError(f"the model file indexes {n_rows} map rows but says N = {n_places} places "
                                     "and has no row → place table.")
        else:
            if row_places.shape != (n_rows,) or int(row_places.max()) >= n_places \
                    or np.unique(row_places).size != n_places:
                raise ModelFileError(f"the model file's row_places table does not fit {n_rows} rows and N = "
                                     f"{n_places} places.")
        self.row_places_ = row_places

    @abstractmethod
    def _n_rows(self) -> int:
        """Map rows in the (restored) index."""

    def __getstate__(self) -> dict[str, Any]:
        # A faiss index does not pickle (joblib/dask workers); it is rebuilt on unpickling.
        state = dict(super().__getstate__())  # a copy: object.__getstate__ returns the live __dict__
        state.pop("_index", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        super().__setstate__(state)
        if hasattr(self, "n_places_"):
            self._index = self._build_index()

    def _build_index(self) -> Any:
        """The faiss index of the fitted row index (None for methods that search without one)."""
        return None
