"""Ground truth: which map places count as correct for each query.

Queries are **rows** everywhere: query j is row j of the query descriptor matrix, entry j of a
prediction vector and row j of a ranking. Map places are indices into the map's rows.

Two kinds of ground truth, one :class:`GroundTruth` class:

``"places"`` (the default, the paper's protocol)
    Each query has one true place ``query_places[j]`` — for frame-aligned traverses simply
    ``j``. A prediction is correct at tolerance t iff ``|pred − true| ≤ t`` (frames).
``"positives"``
    Each query has an explicit set of correct places, stored as CSR arrays (``indptr``,
    ``indices``: the positives of query j are ``indices[indptr[j]:indptr[j + 1]]``). A prediction
    is correct iff it is one of them; **the tolerance does not apply** (the positives already
    encode how far is close enough). GPS-tagged data sets (NetVLAD's ``utmDb``/``utmQ``/
    ``posDistThr``) become positives: the map places within ``posDistThr`` metres of the query.

Files (:meth:`GroundTruth.from_file`) are ``.npz`` / ``.npy`` read with ``allow_pickle=False``,
MATLAB ``.mat`` files read with :func:`scipy.io.loadmat`, CSV files of positives, and VPR-Bench's
``ground_truth_new.npy`` — an object array, i.e. a pickle — read by :func:`read_object_npy`, which
parses the pickle's opcodes and never unpickles (:mod:`btel.datasets.pickleparse`). Every reader
checks what a file declares against :mod:`btel.core.limits` before allocating it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..core.claims import atomic_output
from ..core.validation import check_descriptors, check_positive_int
from ..exceptions import BTELError, DataNotFoundError, DimensionMismatchError, InvalidParameterError
from .groundtruth_files import read_object_npy
from .placeindex import _as_int, check_predictions
from .positions import positives_within

__all__ = ["GroundTruth", "save_positives", "load_positives", "check_predictions", "read_object_npy"]

logger = logging.getLogger(__name__)


def _check_tolerance(tolerance: Any) -> int:
    return check_positive_int(tolerance, "tolerance", minimum=0)


def _positions(values: Any, name: str) -> np.ndarray:
    """A (n, coordinates) float64 array of positions, or the error in the words of positions (not descriptors)."""
    try:
        array = check_descriptors(values, name=name, dtype=np.float64)
    except BTELError as exc:
        arr = np.asarray(values) if isinstance(values, np.ndarray) else None
        if arr is not None and arr.ndim != 2:
            raise InvalidParameterError(f"{name} must hold one position per row (n × coordinates, e.g. UTM easting "
                                        f"and northing); got shape {arr.shape}.") from None
        if arr is not None and arr.dtype.kind in "fc" and arr.size and not np.isfinite(arr).all():
            rows = np.flatnonzero(~np.isfinite(arr).all(axis=1))
            raise InvalidParameterError(f"{name} holds no finite position at row(s) {rows[:5].tolist()}"
                                        f"{' …' if rows.size > 5 else ''}: every place and query needs one.") from None
        raise type(exc)(str(exc).replace("descriptor", "position")) from None
    return array


class GroundTruth:
    """Which map places are correct for each query (queries are rows).

    Build one with :meth:`frame_aligned`, :meth:`from_places`, :meth:`from_positives`,
    :meth:`from_csr`, :meth:`from_utm` or :meth:`from_file`.

    Parameters
    ----------
    query_places : array-like of int, shape (n_queries,), optional
        True place of each query (kind ``"places"``).
    indptr : array-like of int, shape (n_queries + 1,), optional
        CSR row pointers of the positives (kind ``"positives"``; give ``indices`` too).
    indices : array-like of int, shape (n_positives,), optional
        CSR column indices: map places that are correct for each query.
    n_map : int, optional
        Number of map places. When given, true places and positives must lie in ``[0, n_map)``.

    Attributes
    ----------
    kind : {"places", "positives"}
    n_queries : int
    n_map : int or None
    query_places : ndarray of shape (n_queries,), dtype int64, or None
    indptr : ndarray of shape (n_queries + 1,), dtype int64, or None
    indices : ndarray of shape (n_positives,), dtype int64, or None
        Sorted and without duplicates within each query.
    radius : float or None
        The distance the positives were found within (:meth:`from_utm`, the files' ``posDistThr``), else None.
    """

    def __init__(
        self,
        *,
        query_places: Any = None,
        indptr: Any = None,
        indices: Any = None,
        n_map: int | None = None,
    ) -> None:
        has_places = query_places is not None
        has_csr = indptr is not None or indices is not None
        if has_places == has_csr:
            raise InvalidParameterError(
                "give either query_places (one true place per query) or indptr and indices "
                "(explicit positives per query), not both and not neither."
            )
        self.n_map = None if n_map is None else check_positive_int(n_map, "n_map")
        self.query_places: np.ndarray | None = None
        self.indptr: np.ndarray | None = None
        self.indices: np.ndarray | None = None
        self._csr: sp.csr_array | None = None
        self.radius: float | None = None
        if has_places:
            self.kind = "places"
            places = np.asarray(query_places)
            if places.ndim != 1 or places.shape[0] == 0:
                raise InvalidParameterError(
                    f"query_places must be a non-empty 1-D array (one true place per query); got shape {places.shape}."
                )
            places = _as_int(places, "query_places")
            self._check_range(places, "query_places")
            self.query_places = places
            self.n_queries = int(places.shape[0])
        else:
            self.kind = "positives"
            self._set_csr(indptr, indices)

    # -- construction ---------------------------------------------------------------------------
    def _check_range(self, values: np.ndarray, name: str) -> None:
        if values.size and values.min() < 0:
            raise InvalidParameterError(f"{name} must be non-negative map place indices; found {values.min()}.")
        if values.size and self.n_map is not None and values.max() >= self.n_map:
            raise InvalidParameterError(
                f"{name} refer to map place {values.max()} but the map has only {self.n_map} places "
                f"(0..{self.n_map - 1})."
            )

    def _set_csr(self, indptr: Any, indices: Any) -> None:
        if indptr is None or indices is None:
            raise InvalidParameterError("explicit positives need both indptr and indices (CSR arrays).")
        ptr = np.asarray(indptr)
        idx = np.asarray(indices)
        if ptr.ndim != 1 or ptr.shape[0] < 2 or idx.ndim != 1:
            raise InvalidParameterError(
                "indptr must be 1-D of length n_queries + 1 ≥ 2 and indices 1-D; "
                f"got shapes {ptr.shape} and {idx.shape}."
            )
        ptr = _as_int(ptr, "indptr")
        idx = _as_int(idx, "indices")
        if ptr[0] != 0 or ptr[-1] != idx.shape[0] or np.any(np.diff(ptr) < 0):
            raise InvalidParameterError(
                "indptr must start at 0, never decrease, and end at len(indices) "
                f"(got first {ptr[0]}, last {ptr[-1]}, len(indices) {idx.shape[0]})."
            )
        self._check_range(idx, "positives (indices)")
        n_queries = ptr.shape[0] - 1
        n_cols = self.n_map if self.n_map is not None else (int(idx.max()) + 1 if idx.size else 1)
        csr = sp.csr_array((np.ones(idx.shape[0], dtype=bool), idx, ptr), shape=(n_queries, n_cols))
        # Canonical form (sorted, no duplicates) so that saved files and comparisons are stable.
        csr.sum_duplicates()
        csr.sort_indices()
        self._csr = csr
        self.indptr = csr.indptr.astype(np.int64)
        self.indices = csr.indices.astype(np.int64)
        self.n_queries = int(n_queries)
        if self.n_without_positives:
            logger.warning(
                "%d of %d queries have no positive map place; they count as wrong at every tolerance",
                self.n_without_positives,
                self.n_queries,
            )

    @classmethod
    def frame_aligned(cls, n_queries: int, *, n_map: int | None = None) -> "GroundTruth":
        """Frame-aligned traverses: the true place of query j is j (the paper's protocol)."""
        n = check_positive_int(n_queries, "n_queries")
        return cls(query_places=np.arange(n, dtype=np.int64), n_map=n_map)

    @classmethod
    def from_places(cls, query_places: Any, *, n_map: int | None = None) -> "GroundTruth":
        """One true place per query: ``query_places[j]`` for query row j."""
        return cls(query_places=query_places, n_map=n_map)

    @classmethod
    def from_csr(cls, indptr: Any, indices: Any, *, n_map: int | None = None) -> "GroundTruth":
        """Explicit positives as CSR arrays: query j ↦ ``indices[indptr[j]:indptr[j + 1]]``."""
        return cls(indptr=indptr, indices=indices, n_map=n_map)

    @classmethod
    def from_positives(cls, positives: Sequence[Any], *, n_map: int | None = None) -> "GroundTruth":
        """Explicit positives as one list of map place indices per query (may be empty)."""
        rows = [np.asarray(p).ravel() for p in positives]
        if not rows:
            raise InvalidParameterError("positives is empty; give one list of map places per query.")
        indptr = np.concatenate([[0], np.cumsum([r.shape[0] for r in rows])])
        indices = np.concatenate(rows) if indptr[-1] else np.zeros(0, dtype=np.int64)
        return cls(indptr=indptr, indices=indices, n_map=n_map)

    @classmethod
    def from_utm(cls, utm_db: Any, utm_q: Any, pos_dist_thr: float) -> "GroundTruth":
        """Positives from positions: the map places within ``pos_dist_thr`` of each query.

        As in NetVLAD's evaluation (a radius query with a KD-tree; places exactly at the
        threshold count), bounded in memory and in work by
        :func:`btel.datasets.positions.positives_within`.

        Parameters
        ----------
        utm_db : array-like of shape (n_map, n_coords)
            Position of each map place (e.g. UTM easting, northing in metres), one row per place.
        utm_q : array-like of shape (n_queries, n_coords)
            Position of each query, one row per query.
        pos_dist_thr : float
            Radius in the same unit (NetVLAD uses 25 m).

        Raises
        ------
        ResourceLimitError
            More pairs or distance computations than the memory limit allows.
        """
        db, q = _positions(utm_db, "utmDb"), _positions(utm_q, "utmQ")
        if q.shape[1] != db.shape[1]:
            raise DimensionMismatchError(
                f"utmQ has {q.shape[1]} coordinates per row but utmDb has {db.shape[1]}; "
                "both must hold one position per row in the same coordinate system."
            )
        thr_arr = np.asarray(pos_dist_thr)
        if thr_arr.size != 1 or thr_arr.dtype.kind not in "iuf":
            raise InvalidParameterError(
                f"posDistThr must be one distance; got shape {thr_arr.shape} and dtype {thr_arr.dtype}.")
        thr = float(thr_arr.reshape(-1)[0])
        if not np.isfinite(thr) or thr < 0:
            raise InvalidParameterError(f"posDistThr must be a finite distance ≥ 0; got {thr!r}.")
        indptr, indices = positives_within(db, q, thr)
        gt = cls(indptr=indptr, indices=indices, n_map=db.shape[0])
        gt.radius = thr  # the positive rule a run records: "positives within 25 m"
        return gt

    @classmethod
    def from_file(cls, path: str | os.PathLike, *, n_queries: int | None = None,
                  n_map: int | None = None) -> "GroundTruth":
        """Read ground truth from a file, choosing the layout by its contents.

        ``n_queries`` and ``n_map`` (the descriptor counts), when given, are checked against the
        file before any positive is computed (positions of 4,000,000 queries for 50 query rows).

        Layouts (array names are case-sensitive):

        - ``.npz`` with ``indptr`` and ``indices`` (optional scalar ``n_map``): explicit positives
          (as written by :func:`save_positives`);
        - ``.npz`` with ``utmDb`` (n_map, c), ``utmQ`` (n_queries, c) and scalar ``posDistThr``:
          positions, positives within the radius (one position per row);
        - ``.npz`` with ``query_places`` (optional ``n_map``), or a ``.npy`` holding a 1-D integer
          array: one true place per query;
        - ``.mat`` (MATLAB, read with scipy): top-level ``utmDb``/``utmQ``/``posDistThr`` (one
          position per row), or NetVLAD's ``dbStruct`` whose ``utmDb``/``utmQ`` are 2×n
          (transposed on reading);
        - ``.npy`` object array as VPR-Bench writes it (``ground_truth_new.npy``: rows ``[query
          index, positives]``, or one item of positives per query), read by
          :func:`read_object_npy` (numpy integer arrays only, nothing else is unpickled);
        - ``.csv``: explicit positives with a header ``query,positive`` and one (query, map place)
          pair per line (a query may take several lines; a query without any line has no
          positive), or a header ``query,positives`` with the places of each query separated by
          spaces or semicolons in one cell. Queries are numbered from 0; the number of queries is
          the largest query index + 1 (with ``n_queries`` given, another count is refused, naming
          the queries without a line). A line ``j,`` (either header) lists query j without positive.

        Raises
        ------
        DataNotFoundError
            Missing file, not a regular file, unreadable or damaged file, pickled content other
            than VPR-Bench's integer arrays, or an unknown layout.
        InvalidParameterError
            The file's positions, true places or positives are for another number of queries or
            map places than ``n_queries`` / ``n_map``.
        ResourceLimitError
            The file declares more than :mod:`btel.core.limits` allows (raise ``BTEL_MEMORY_LIMIT``).
        """
        from .groundtruth_files import read_ground_truth

        return read_ground_truth(cls, path, n_queries=n_queries, n_map=n_map)

    # -- queries ----------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.n_queries

    def __repr__(self) -> str:
        return f"GroundTruth(kind={self.kind!r}, n_queries={self.n_queries}, n_map={self.n_map})"

    @property
    def uses_tolerance(self) -> bool:
        """True for one-true-place ground truth; explicit positives ignore the tolerance."""
        return self.kind == "places"

    @property
    def n_without_positives(self) -> int:
        """Queries that no prediction can get right (explicit positives only; else 0)."""
        if self.kind == "places":
            return 0
        return int(np.count_nonzero(np.diff(self.indptr) == 0))

    def positives(self, j: int, tolerance: int = 0) -> np.ndarray:
        """Map places correct for query row ``j``, sorted (int64).

        For kind ``"places"`` the window ``true ± tolerance`` (clipped to the map when ``n_map``
        is known); for ``"positives"`` the stored list (``tolerance`` ignored).
        """
        j = check_positive_int(j, "j", minimum=0)
        if j >= self.n_queries:
            raise InvalidParameterError(f"query {j} out of range: there are {self.n_queries} queries.")
        t = _check_tolerance(tolerance)
        if self.kind == "positives":
            return self.indices[self.indptr[j] : self.indptr[j + 1]].copy()
        p = int(self.query_places[j])
        hi = p + t + 1 if self.n_map is None else min(self.n_map, p + t + 1)
        return np.arange(max(0, p - t), hi, dtype=np.int64)

    def distances(self, predictions: Any) -> np.ndarray:
        """``|prediction − true place|`` per query in frames (kind ``"places"`` only).

        Returns
        -------
        ndarray of shape (n_queries,), dtype int64
        """
        if self.kind != "places":
            raise InvalidParameterError(
                "distances need one true place per query; this ground truth holds explicit positives."
            )
        pred = check_predictions(predictions, self.n_queries)
        return np.abs(pred - self.query_places)

    def is_correct(self, predictions: Any, tolerance: int = 0) -> np.ndarray:
        """Whether each query's predicted place is correct.

        Parameters
        ----------
        predictions : array-like of int, shape (n_queries,)
            Predicted map place per query row.
        tolerance : int, default 0
            Frames of slack for kind ``"places"`` (``|pred − true| ≤ tolerance``); ignored for
            explicit positives.

        Returns
        -------
        correct : ndarray of shape (n_queries,), dtype bool
        """
        t = _check_tolerance(tolerance)
        pred = check_predictions(predictions, self.n_queries)
        if self.kind == "places":
            return np.abs(pred - self.query_places) <= t
        return self._lookup(np.arange(self.n_queries), pred)

    def rank_correct(self, ranked: Any, tolerance: int = 0) -> np.ndarray:
        """Whether each ranked candidate is correct.

        Parameters
        ----------
        ranked : array-like of int, shape (n_queries, k)
            Candidate places per query row, best first (as ``PlaceLocalizer.rank``).
        tolerance : int, default 0
            As in :meth:`is_correct`.

        Returns
        -------
        correct : ndarray of shape (n_queries, k), dtype bool
            ``correct[:, :K].any(axis=1)`` tells whether query j is found in the top K.
        """
        t = _check_tolerance(tolerance)
        arr = np.asarray(ranked)
        if arr.ndim != 2 or arr.shape[0] != self.n_queries or arr.shape[1] == 0:
            raise InvalidParameterError(
                f"ranked must have shape (n_queries={self.n_queries}, k ≥ 1), best candidate first; got {arr.shape}."
            )
        arr = _as_int(arr, "ranked")
        if self.kind == "places":
            return np.abs(arr - self.query_places[:, None]) <= t
        rows = np.repeat(np.arange(self.n_queries), arr.shape[1])
        return self._lookup(rows, arr.ravel()).reshape(arr.shape)

    def _lookup(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        # A place outside the positives matrix (or negative) is simply not a positive.
        inside = (cols >= 0) & (cols < self._csr.shape[1])
        out = np.zeros(rows.shape[0], dtype=bool)
        if inside.any():
            out[inside] = np.asarray(self._csr[rows[inside], cols[inside]]).ravel().astype(bool)
        return out

    # -- files --------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, overwrite: bool = True) -> Path:
        """Write this ground truth as ``.npz`` (no pickles) that :meth:`from_file` reads back.

        Kind ``"places"`` writes ``query_places``; kind ``"positives"`` writes ``indptr`` and
        ``indices``; both add ``n_map`` when known. Whole or not at all; ``overwrite=False`` keeps a file.
        """
        path = Path(path)
        arrays: dict[str, np.ndarray] = {}
        if self.kind == "places":
            arrays["query_places"] = self.query_places
        else:
            arrays["indptr"] = self.indptr
            arrays["indices"] = self.indices
        if self.n_map is not None:
            arrays["n_map"] = np.int64(self.n_map)
        path.parent.mkdir(parents=True, exist_ok=True)
        # np.savez appends ".npz" to names without it; write through a handle to keep the name.
        with atomic_output(path, overwrite=overwrite) as fh:
            np.savez(fh, **arrays)
        return path


def save_positives(
    path: str | os.PathLike, positives: Sequence[Any] | GroundTruth, *, n_map: int | None = None
) -> Path:
    """Save explicit per-query positives as CSR arrays (``indptr``, ``indices``) in an ``.npz``.

    Parameters
    ----------
    path : path
        Output file.
    positives : sequence of array-like of int, or GroundTruth of kind "positives"
        ``positives[j]`` = map places correct for query row j.
    n_map : int, optional
        Number of map places (stored, and checked on loading).
    """
    if isinstance(positives, GroundTruth):
        if positives.kind != "positives":
            raise InvalidParameterError(
                "this GroundTruth holds one true place per query, not explicit positives; use its save() method."
            )
        gt = positives if n_map is None else GroundTruth.from_csr(positives.indptr, positives.indices, n_map=n_map)
    else:
        gt = GroundTruth.from_positives(positives, n_map=n_map)
    return gt.save(path)


def load_positives(path: str | os.PathLike) -> GroundTruth:
    """Read positives written by :func:`save_positives` (a GroundTruth of kind "positives")."""
    gt = GroundTruth.from_file(path)
    if gt.kind != "positives":
        raise DataNotFoundError(
            f"{str(path)!r} holds one true place per query, not explicit positives (indptr/indices)."
        )
    return gt
