"""The BTEL localizer: regions, one binary tree per region, and the storage budget (SPEC §2–§7)."""

from __future__ import annotations

import numbers
import time
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from ._validation import check_descriptors, check_is_fitted, check_places, check_positive_int
from .base import PlaceLocalizer, register_model
from .compressed import (
    DECODERS,
    code_signs,
    compressed_n_classifiers,
    compressed_tasks,
    decode_code,
    decode_margins,
)
from .distributed import check_backend
from .encoding import n_bits_for
from .exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError, NotEnoughPlacesError
from .feature_selection import column_index_dtype
from .full import full_n_classifiers, full_tasks, predict_full
from .linear import CLASSIFIERS, ColumnStats, Hyperplanes, default_C
from .segmentation import kts_penalised_costs, kts_regions, kts_segmentations, region_of
from .storage import format_bytes, parse_budget
from .training import Task, fit_tasks, one_vs_rest_tasks

__all__ = ["BTELocalizer", "planned_bytes", "block_centres", "block_size_for_tolerance"]

SCHEMES = ("compressed", "full")
WEIGHT_DTYPES = ("float32", "float16")


def _n_classifiers(scheme: str, n_places: int, code_copies: int = 1) -> int:
    if scheme == "compressed":
        return compressed_n_classifiers(n_places, code_copies)
    return full_n_classifiers(n_places)


def block_centres(codes: np.ndarray, block_size: int, n_places: int) -> np.ndarray:
    """Centre place of each block of ``block_size`` consecutive places (the last may be shorter).

    Returns
    -------
    ndarray of the shape of ``codes``, int64, in [0, N)
    """
    first = np.asarray(codes, dtype=np.int64) * int(block_size)
    last = np.minimum(first + int(block_size), int(n_places)) - 1
    return (first + last) // 2


def block_size_for_tolerance(tolerance: int) -> int:
    """B = 2^L, the largest power of two ≤ t (1 for t = 0): "drop the L low bits with 2^L ≤ t"."""
    t = check_positive_int(tolerance, "tolerance", minimum=0)
    return 1 if t == 0 else 1 << (t.bit_length() - 1)


def _starts_dtype(n_places: int) -> np.dtype:
    return np.dtype(np.uint16) if n_places <= np.iinfo(np.uint16).max else np.dtype(np.uint32)


def planned_bytes(
    region_sizes: list[int] | np.ndarray,
    n_selected: int,
    n_features_in: int,
    *,
    scheme: str = "compressed",
    dtype: str = "float32",
    code_copies: int = 1,
) -> int:
    """Bytes a BTEL model will store, computed before fitting (equals the fitted ``nbytes``).

    Per tree classifier: d' weights + 1 float32 bias + d' column indices (none when d' = d).
    With r ≥ 2 regions add the region classifier (1 hyperplane for r = 2, else r, sharing one set
    of d' columns) and the r region starts.

    Parameters
    ----------
    region_sizes : sequence of int
        N_k of each region (one entry, N, when r = 1).
    n_selected : int
        d'.
    n_features_in : int
        d.
    """
    w = np.dtype(dtype).itemsize
    idx = 0 if n_selected >= n_features_in else column_index_dtype(n_features_in).itemsize
    per_classifier = n_selected * (w + idx) + 4
    total = sum(_n_classifiers(scheme, int(n), code_copies) for n in region_sizes) * per_classifier
    r = len(region_sizes)
    if r >= 2:
        n_region_planes = 1 if r == 2 else r
        total += n_region_planes * (n_selected * w + 4) + n_selected * idx
        total += r * _starts_dtype(int(np.sum(region_sizes))).itemsize
    return int(total)


def _largest_fitting(sizes, d: int, cap: int, budget: int, scheme: str, dtype: str, code_copies: int = 1) -> int:
    """Largest d' ≤ cap whose planned bytes fit the budget (0 when even d' = 1 does not)."""
    kw = dict(scheme=scheme, dtype=dtype, code_copies=code_copies)
    if planned_bytes(sizes, cap, d, **kw) <= budget:
        return cap
    # Below d the bytes are affine in d': solve, then step down past rounding.
    b1 = planned_bytes(sizes, 1, d, **kw)
    slope = planned_bytes(sizes, 2, d, **kw) - b1 if d > 2 else b1
    guess = min(cap, d - 1, 1 + (budget - b1) // max(slope, 1)) if budget >= b1 else 0
    while guess >= 1 and planned_bytes(sizes, guess, d, **kw) > budget:
        guess -= 1
    return int(max(guess, 0))


@register_model
class BTELocalizer(PlaceLocalizer):
    """Binary tree encoding for visual localization (BTEL; Le, Hoang & Milford).

    Learns b = ceil(log2 N) linear classifiers that predict the bits of a place's index, so the
    map costs O(log N) bytes instead of one code per image. Optionally the route is first split
    into r regions (Kernel Temporal Segmentation) with a region classifier and one tree each.

    Parameters
    ----------
    scheme : {'compressed', 'full'}
        'compressed' (BTE-C): one classifier per bit, O(log N) storage. 'full' (BTE-F): one per
        internal tree node, O(N) storage (the paper's foil).
    classifier : {'svm', 'logistic'}
        Linear SVM (``LinearSVC``, squared hinge) or L2 logistic regression (liblinear, tol 0.01).
    C : float, optional
        Regularisation; default 1.0 for 'svm', 4.0 for 'logistic'.
    feature_ratio : float in (0, 1], optional
        c: each classifier keeps d' = round(c·d) columns. Default 0.1 without a budget.
    n_features : int, optional
        d' directly (overrides ``feature_ratio``).
    sparsity : float
        Witten–Tibshirani L1 bound s (the paper's 0.1; W&T's valid range is [1, √d], and below 1
        the weights are the sparsest solution — the kept columns are the top d' by BCSS either way).
    n_regions : int or 'auto'
        r regions (1 = plain BTE-C/BTE-F). 'auto' picks r by the KTS penalty.
    budget : int or str, optional
        Byte budget ('500KB', '2MB', 64_000; KB = 1000 B). fit picks the largest d' that fits
        (``feature_ratio``/``n_features``, when given, cap it); with ``n_regions='auto'`` it then
        lowers r if even d' = 1 does not fit. Raises :class:`BudgetTooSmallError` naming the
        minimum when nothing fits.
    dtype : {'float32', 'float16'}
        Stored hyperplane dtype (biases stay float32).
    decode : {'constrained', 'soft'}
        Bit margins → index: MSB-first constrained decode, or the soft decode over valid indices
        (O(N·b) per query; compressed scheme only).
    max_regions : int
        Largest r tried when ``n_regions='auto'``.
    kts_penalty : float
        v of the KTS penalty for ``n_regions='auto'``.
    kts_pca_dims : int or None
        PCA dimension before KTS (None: none).
    kts_max_points : int
        Longest route KTS segments exactly (O(N²·r)); longer routes are averaged in blocks of
        ⌈N / kts_max_points⌉ places first (:func:`btel.segmentation.kts_regions`).
    max_iter : int
        liblinear iteration cap per classifier.
    n_jobs : int, optional
        Parallel classifier fits (joblib; −1 = all cores; with ``backend='dask'`` None means every
        worker of the cluster).
    backend : {None, 'threads', 'loky', 'dask'}
        Where the classifier fits run (:mod:`btel.distributed`). None: threads, or whatever
        ``joblib.parallel_config`` the caller set. 'dask': the workers of a Dask cluster (X is
        sent to each worker once); needs ``pip install btel[dask]``. The model does not depend
        on the backend — bitwise so when no worker process runs two fits at once: liblinear's
        dual solver draws from one random generator per process, so fits sharing a process in
        threads (``n_jobs`` ≥ 2 with threads) can differ in the last bits of their weights.
    scheduler : str, optional
        Dask scheduler address for ``backend='dask'`` (e.g. ``'tcp://10.0.0.5:8786'``); None uses
        the ``distributed.Client`` already running in this process.
    random_state : int, optional
        Seed for liblinear and the randomized PCA of KTS.
    progress : bool
        Show a progress bar while fitting (only on a terminal).
    block_size : int
        B ≥ 1, tolerance-aware codes: the trees index blocks of B consecutive places
        (``place // B``) and predict a block's centre place, which is within ⌊B/2⌋ of every place
        of the block. ⌈log2 ⌈N/B⌉⌉ bits instead of ⌈log2 N⌉, so under a budget each classifier
        keeps more columns. :func:`block_size_for_tolerance` gives the power of two for a
        tolerance t (B ≤ t, so the worst in-block error is ≤ t/2). 1: plain BTEL.
    code_copies : int
        m ≥ 1, error-correcting offset codes (``scheme='compressed'``): m − 1 shifted copies of
        each bit's contiguous-block split are learnt as extra classifiers and every tree is
        decoded softly over its whole code (:mod:`btel.compressed`). 1: the plain b bits.
    exemplar_radius : int
        e ≥ 0, multi-exemplar labels (``scheme='compressed'``): each row also stands for the
        places within ±e of it that share the column's high bits, i.e. rows next to a block
        boundary weigh less (:func:`btel.compressed.exemplar_weights`). 0: all rows weigh 1.
        Several exemplars per place from extra traverses or augmented images go through
        ``fit(X, places)``.

    Attributes
    ----------
    n_places_ : int
        N.
    n_codes_ : int
        Places the trees index: ⌈N / block_size⌉ (N when block_size = 1); region starts and
        sizes count these.
    n_features_in_ : int
        d.
    n_selected_ : int
        d', columns per classifier.
    n_regions_ : int
        r.
    region_starts_ : ndarray of shape (r,), int64
        First place of each region.
    region_sizes_ : ndarray of shape (r,), int64
    hyperplanes_ : Hyperplanes
        Every tree classifier, region by region (bits MSB first, or nodes in heap order).
    region_hyperplanes_ : Hyperplanes or None
        The region classifier (None when r = 1).
    n_unconverged_ : int
        Classifiers whose liblinear solver stopped at ``max_iter``.
    fit_time_ : float
        Seconds spent in fit.

    Examples
    --------
    >>> from btel import BTELocalizer
    >>> from btel.datasets import synthetic_route
    >>> route = synthetic_route(n_places=500, dim=256, seed=0)
    >>> model = BTELocalizer(budget="50KB").fit(route.map)
    >>> model.predict(route.queries).shape
    (500,)
    """

    def __init__(
        self,
        *,
        scheme: str = "compressed",
        classifier: str = "svm",
        C: float | None = None,
        feature_ratio: float | None = None,
        n_features: int | None = None,
        sparsity: float = 0.1,
        n_regions: int | str = 1,
        budget: int | str | None = None,
        dtype: str = "float32",
        decode: str = "constrained",
        max_regions: int = 50,
        kts_penalty: float = 1.0,
        kts_pca_dims: int | None = 128,
        kts_max_points: int = 4096,
        max_iter: int = 1000,
        n_jobs: int | None = None,
        backend: str | None = None,
        scheduler: str | None = None,
        random_state: int | None = None,
        progress: bool = True,
        block_size: int = 1,
        code_copies: int = 1,
        exemplar_radius: int = 0,
    ) -> None:
        self.scheme = scheme
        self.classifier = classifier
        self.C = C
        self.feature_ratio = feature_ratio
        self.n_features = n_features
        self.sparsity = sparsity
        self.n_regions = n_regions
        self.budget = budget
        self.dtype = dtype
        self.decode = decode
        self.max_regions = max_regions
        self.kts_penalty = kts_penalty
        self.kts_pca_dims = kts_pca_dims
        self.kts_max_points = kts_max_points
        self.max_iter = max_iter
        self.n_jobs = n_jobs
        self.backend = backend
        self.scheduler = scheduler
        self.random_state = random_state
        self.progress = progress
        self.block_size = block_size
        self.code_copies = code_copies
        self.exemplar_radius = exemplar_radius

    # ------------------------------------------------------------------ parameters
    def _checked_params(self) -> dict[str, Any]:
        if self.scheme not in SCHEMES:
            raise InvalidParameterError(f"scheme must be one of {SCHEMES}; got {self.scheme!r}.")
        if self.classifier not in CLASSIFIERS:
            raise InvalidParameterError(f"classifier must be one of {CLASSIFIERS}; got {self.classifier!r}.")
        if self.decode not in DECODERS:
            raise InvalidParameterError(f"decode must be one of {DECODERS}; got {self.decode!r}.")
        if self.decode == "soft" and self.scheme == "full":
            raise InvalidParameterError("decode='soft' needs every bit margin: use it with scheme='compressed'.")
        C = default_C(self.classifier) if self.C is None else self.C
        if not isinstance(C, numbers.Real) or not C > 0:
            raise InvalidParameterError(f"C must be a positive number; got {self.C!r}.")
        try:
            dtype = np.dtype(self.dtype).name
        except TypeError as exc:
            raise InvalidParameterError(f"dtype must be one of {WEIGHT_DTYPES}; got {self.dtype!r}.") from exc
        if dtype not in WEIGHT_DTYPES:
            raise InvalidParameterError(f"dtype must be one of {WEIGHT_DTYPES}; got {self.dtype!r}.")
        if self.feature_ratio is not None and not (
            isinstance(self.feature_ratio, numbers.Real) and 0 < self.feature_ratio <= 1
        ):
            raise InvalidParameterError(f"feature_ratio must be in (0, 1]; got {self.feature_ratio!r}.")
        if self.n_features is not None:
            check_positive_int(self.n_features, "n_features")
        if not isinstance(self.sparsity, numbers.Real) or not self.sparsity > 0:
            raise InvalidParameterError(f"sparsity must be a positive number; got {self.sparsity!r}.")
        if self.n_regions != "auto":
            check_positive_int(self.n_regions, "n_regions ('auto' or an integer)")
        check_positive_int(self.max_regions, "max_regions")
        check_positive_int(self.max_iter, "max_iter")
        check_positive_int(self.kts_max_points, "kts_max_points", minimum=4)
        check_backend(self.backend, self.scheduler)
        block_size = check_positive_int(self.block_size, "block_size")
        copies = check_positive_int(self.code_copies, "code_copies")
        radius = check_positive_int(self.exemplar_radius, "exemplar_radius", minimum=0)
        if self.scheme == "full" and (copies > 1 or radius > 0):
            raise InvalidParameterError(
                "code_copies > 1 and exemplar_radius > 0 extend the per-bit classifiers of scheme='compressed'; "
                "BTE-F ('full') has one classifier per node instead."
            )
        return {"C": float(C), "dtype": dtype, "budget": parse_budget(self.budget), "block_size": block_size,
                "code_copies": copies, "exemplar_radius": radius}

    def _cap(self, d: int, budget: int | None) -> int:
        """Upper bound on d' from n_features / feature_ratio (d itself under a budget)."""
        if self.n_features is not None:
            return min(int(self.n_features), d)
        ratio = self.feature_ratio if self.feature_ratio is not None else (None if budget else 0.1)
        return d if ratio is None else int(min(d, max(1, round(ratio * d))))

    # ------------------------------------------------------------------ fit
    def fit(self, X: Any, places: Any = None) -> "BTELocalizer":
        """Learn the map.

        Parameters
        ----------
        X : array-like of shape (n_samples, n_features)
            Map descriptors. Row i is place i unless ``places`` is given.
        places : array-like of shape (n_samples,), int, optional
            Place index of each row (several rows may share a place, e.g. several traverses).
            Must cover 0..N−1.

        Returns
        -------
        self : BTELocalizer
        """
        start_time = time.perf_counter()
        params = self._checked_params()
        X = check_descriptors(X, name="X")
        if places is None:
            if X.shape[0] < 2:  # one row is one place: the same error as places=[0] gives
                raise NotEnoughPlacesError(
                    f"X has {X.shape[0]} row (N = 1 place): an index needs at least 2 places. "
                    "Fit on a longer route."
                )
            places_arr = np.arange(X.shape[0], dtype=np.int64)
            n_places = X.shape[0]
        else:
            places_arr, n_places = check_places(places, X.shape[0])
        # Tolerance-aware codes: everything below works on block indices ("codes").
        block_size, copies = params["block_size"], params["code_copies"]
        n_codes = -(-n_places // block_size)
        if n_codes < 2:
            raise InvalidParameterError(
                f"block_size = {block_size} leaves {n_codes} block of N = {n_places} places; an index needs at "
                f"least 2. Use block_size ≤ {max(1, (n_places - 1))}."
            )
        codes_arr = places_arr // block_size if block_size > 1 else places_arr
        d = X.shape[1]
        budget = params["budget"]
        cap = self._cap(d, budget)
        starts = self._segment(X, codes_arr, n_codes, budget, cap, params["dtype"], copies)
        sizes = np.diff(np.append(starts, n_codes))
        n_selected = cap
        if budget is not None:
            n_selected = _largest_fitting(list(sizes), d, cap, budget, self.scheme, params["dtype"], copies)
            if n_selected < 1:
                minimum = planned_bytes(list(sizes), 1, d, scheme=self.scheme, dtype=params["dtype"],
                                        code_copies=copies)
                raise BudgetTooSmallError(
                    f"budget {format_bytes(budget)} ({budget} B) is too small for BTEL ({self.scheme}, "
                    f"N = {n_places}, r = {len(sizes)}): the smallest model (d' = 1) needs {minimum} B. "
                    "Raise the budget, use dtype='float16', or fewer regions.",
                    budget=budget,
                    minimum=minimum,
                )

        stats = ColumnStats.of(X)
        region_of_row = region_of(codes_arr, starts)
        tasks: list[Task] = []
        if len(starts) >= 2:
            # The region classifier R: one hyperplane for r = 2, else one-vs-rest, own feature selection.
            tasks.extend(one_vs_rest_tasks(X, region_of_row, len(starts), n_selected, stats,
                                           sparsity=float(self.sparsity)))
        first_tree_task = len(tasks)
        for k, (s, n_k) in enumerate(zip(starts, sizes)):
            rows = np.flatnonzero(region_of_row == k) if len(starts) >= 2 else None
            local = codes_arr[rows] - s if rows is not None else codes_arr
            if self.scheme == "compressed":
                tasks.extend(compressed_tasks(local, int(n_k), rows, code_copies=copies,
                                              exemplar_radius=params["exemplar_radius"]))
            else:
                tasks.extend(full_tasks(local, int(n_k), rows))

        with tqdm(total=len(tasks), desc="BTEL fit", unit="clf", disable=None if self.progress else True,
                  leave=False) as bar:
            parts, n_unconverged = fit_tasks(
                X, tasks, n_selected, stats, sparsity=float(self.sparsity), n_jobs=self.n_jobs,
                backend=self.backend, scheduler=self.scheduler, progress=bar.update, classifier=self.classifier,
                C=params["C"], max_iter=int(self.max_iter), random_state=self.random_state,
                dtype=np.dtype(params["dtype"]),
            )

        index_dtype = None if n_selected >= d else column_index_dtype(d)
        self.region_hyperplanes_ = (
            Hyperplanes.stack(parts[:first_tree_task], d, n_selected, np.dtype(params["dtype"]), index_dtype,
                              shared_columns=True)
            if first_tree_task else None
        )
        self.hyperplanes_ = Hyperplanes.stack(
            parts[first_tree_task:], d, n_selected, np.dtype(params["dtype"]), index_dtype
        )
        self._set_structure(n_places, d, n_selected, starts)
        self.n_unconverged_ = int(n_unconverged)
        self.fit_time_ = time.perf_counter() - start_time
        return self

    def _segment(self, X, places, n_places, budget, cap, dtype, code_copies=1) -> np.ndarray:
        """Region starts: fixed r, or r by the KTS penalty (lowered while nothing fits the budget)."""
        if self.n_regions == 1:
            return np.zeros(1, dtype=np.int64)
        # KTS runs on one descriptor per place, in route order (the mean when a place has several).
        if places.size == n_places and np.array_equal(places, np.arange(n_places)):
            per_place = X
        else:
            counts = np.bincount(places, minlength=n_places)
            per_place = np.zeros((n_places, X.shape[1]))
            np.add.at(per_place, places, X)
            per_place /= counts[:, None]
        if self.n_regions != "auto":
            return kts_regions(per_place, int(self.n_regions), pca_dims=self.kts_pca_dims,
                               random_state=self.random_state, max_points=int(self.kts_max_points))
        starts_by_r, costs = kts_segmentations(per_place, int(self.max_regions), pca_dims=self.kts_pca_dims,
                                               random_state=self.random_state, max_points=int(self.kts_max_points))
        r = int(np.argmin(kts_penalised_costs(costs, n_places, float(self.kts_penalty)))) + 1
        if budget is not None:
            d = X.shape[1]
            while r > 1:
                sizes = list(np.diff(np.append(starts_by_r[r], n_places)))
                if _largest_fitting(sizes, d, cap, budget, self.scheme, dtype, code_copies) >= 1:
                    break
                r -= 1
        return starts_by_r[r]

    def _set_structure(self, n_places: int, d: int, n_selected: int, starts: np.ndarray) -> None:
        """Derived attributes that follow from N, d, d', the code options and the region starts."""
        starts = np.asarray(starts, dtype=np.int64)
        self.block_size_ = int(self.block_size)
        self.code_copies_ = int(self.code_copies)
        n_codes = -(-int(n_places) // self.block_size_)
        sizes = np.diff(np.append(starts, n_codes))
        n_classifiers = [_n_classifiers(self.scheme, int(n), self.code_copies_) for n in sizes]
        self.n_places_ = int(n_places)
        self.n_codes_ = int(n_codes)
        self.n_features_in_ = int(d)
        self.n_selected_ = int(n_selected)
        self.n_regions_ = int(starts.size)
        self.region_starts_ = starts
        self.region_sizes_ = sizes.astype(np.int64)
        self.n_bits_ = n_bits_for(n_codes)
        self._tree_width = max(self.n_bits_, int(max(n_classifiers))) if self.scheme == "compressed" else self.n_bits_
        self._tree_offsets = np.concatenate([[0], np.cumsum(n_classifiers)]).astype(np.int64)

    # ------------------------------------------------------------------ inference
    def _check_queries(self, Q: Any) -> np.ndarray:
        check_is_fitted(self, "n_places_")
        return check_descriptors(Q, name="Q", n_features=self.n_features_in_)

    def _regions(self, Q: np.ndarray) -> np.ndarray:
        """Region of each (validated) query: the sign of R for r = 2, its argmax for r > 2."""
        if self.n_regions_ == 1:
            return np.zeros(Q.shape[0], dtype=np.int64)
        scores = self.region_hyperplanes_.margins(Q)
        if self.n_regions_ == 2:
            return (scores[:, 0] > 0).astype(np.int64)
        return np.argmax(scores, axis=1).astype(np.int64)

    def predict_region(self, Q: Any) -> np.ndarray:
        """Region of each query (int64, shape (n_queries,); all 0 when r = 1)."""
        return self._regions(self._check_queries(Q))

    def _tree_margins(self, Q: np.ndarray, region: int) -> tuple[np.ndarray, np.ndarray]:
        """(local indices, bit margins) of queries Q under region ``region``'s tree."""
        n_k = int(self.region_sizes_[region])
        first = int(self._tree_offsets[region])
        if self.scheme == "full":
            return predict_full(Q, self.hyperplanes_, first, n_k)
        rows = slice(first, int(self._tree_offsets[region + 1]))
        margins = self.hyperplanes_.margins(Q, rows if self.n_regions_ > 1 else None)
        if self.code_copies_ > 1:
            return decode_code(margins, n_k, self.code_copies_), margins
        return decode_margins(margins, n_k, self.decode), margins

    def _predict_with_margins(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.n_regions_ == 1:  # one tree over all codes: its local indices are global
            codes, margins = self._tree_margins(Q, 0)
            return self._places_of_codes(codes), margins
        regions = self._regions(Q)
        indices = np.empty(Q.shape[0], dtype=np.int64)
        margins = np.full((Q.shape[0], self._tree_width), np.nan, dtype=np.float32)
        present = np.unique(regions) if Q.shape[0] > 1 else regions
        for k in present:
            rows = slice(None) if present.size == 1 else np.flatnonzero(regions == k)
            local, m = self._tree_margins(Q[rows], int(k))
            indices[rows] = self.region_starts_[k] + local
            margins[rows, : m.shape[1]] = m
        return self._places_of_codes(indices), margins

    def _places_of_codes(self, codes: np.ndarray) -> np.ndarray:
        """Place answered for each code: the code itself, or its block's centre (block_size > 1)."""
        if self.block_size_ == 1:
            return codes
        return block_centres(codes, self.block_size_, self.n_places_)

    def predict(self, Q: Any) -> np.ndarray:
        """Place index of each query.

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)

        Returns
        -------
        ndarray of shape (n_queries,), int64, every value in [0, N)
        """
        return self._predict_with_margins(self._check_queries(Q))[0]

    def decision_function(self, Q: Any) -> np.ndarray:
        """Bit margins of each query's tree (positive = bit 1), MSB first.

        Returns
        -------
        ndarray of shape (n_queries, K), float32
            K = b, or with ``code_copies > 1`` the b bits then the offset columns. With regions,
            the margins of the predicted region's tree, left-aligned and padded with NaN where
            that tree has fewer columns. With ``scheme='full'``, the margin of
            the node visited at each level (−inf where the node is constant).
        """
        return self._predict_with_margins(self._check_queries(Q))[1]

    @property
    def supports_ranking(self) -> bool:  # type: ignore[override]
        """Ranking needs a margin per bit: ``scheme='compressed'``."""
        return self.scheme == "compressed"

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """The ``k`` most likely places per query, best first (ranked output, R@K).

        Best-first search over bit flips of the predicted region's tree (more regions when it
        holds fewer than k codes), merged across regions by the region classifier's score
        (:func:`btel.ranking.rank_places`); with ``code_copies > 1`` every code is scored
        (O(N·K)); with ``block_size > 1`` blocks are ranked and their centres returned.

        Returns
        -------
        ndarray of shape (n_queries, min(k, number of codes)), int64
        """
        from .ranking import rank_places

        if self.scheme != "compressed":
            raise InvalidParameterError("rank needs scheme='compressed' (BTE-F reads one node per level).")
        return rank_places(self, self._check_queries(Q), k)[0]

    def place_scores(self, Q: Any, *, region_weight: float = 1.0) -> np.ndarray:
        """Score of every place for every query, higher = more likely (``−`` flip cost).

        The emission scores of :meth:`predict_sequence` and of
        :func:`btel.sequence_decoding.decode_sequence`. O(N·K) per query.

        Returns
        -------
        ndarray of shape (n_queries, N), float64
        """
        from .ranking import place_costs

        if self.scheme != "compressed":
            raise InvalidParameterError("place_scores needs scheme='compressed'.")
        return -place_costs(self, self._check_queries(Q), region_weight=region_weight)

    # ------------------------------------------------------------------ storage and files
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = self.hyperplanes_.arrays("")
        if self.region_hyperplanes_ is not None:
            arrays.update(self.region_hyperplanes_.arrays("region_"))
            arrays["region_starts"] = self.region_starts_.astype(_starts_dtype(self.n_codes_))
        return arrays

    def _fitted_state(self) -> dict[str, Any]:
        return {
            "n_places": self.n_places_,
            "n_features_in": self.n_features_in_,
            "n_selected": self.n_selected_,
            "n_unconverged": self.n_unconverged_,
            "fit_time": self.fit_time_,
        }

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        n_places = int(state["n_places"])
        d = int(state["n_features_in"])
        n_selected = int(state["n_selected"])
        starts = arrays.get("region_starts", np.zeros(1, dtype=np.int64)).astype(np.int64)
        try:
            block_size = check_positive_int(self.block_size, "block_size")
            check_positive_int(self.code_copies, "code_copies")
        except InvalidParameterError as exc:
            raise ModelFileError(f"model header holds invalid parameters: {exc}") from exc
        n_codes = -(-n_places // block_size) if n_places >= 1 else 0
        if n_places < 2 or n_codes < 2 or not 1 <= n_selected <= d or starts[0] != 0 \
                or np.any(np.diff(starts) < 1) or starts[-1] >= n_codes:
            raise ModelFileError("model header and arrays disagree (places, features or regions).")
        self._set_structure(n_places, d, n_selected, starts)
        self.hyperplanes_ = Hyperplanes(arrays["weights"], arrays["bias"], arrays.get("columns"), d)
        self.region_hyperplanes_ = None
        if self.n_regions_ >= 2:
            self.region_hyperplanes_ = Hyperplanes(
                arrays["region_weights"], arrays["region_bias"], arrays.get("region_columns"), d
            )
            expected = 1 if self.n_regions_ == 2 else self.n_regions_
            if len(self.region_hyperplanes_) != expected:
                raise ModelFileError("region classifier size does not match the number of regions.")
        if len(self.hyperplanes_) != self._tree_offsets[-1] or self.hyperplanes_.weights.shape[1] != n_selected:
            raise ModelFileError(
                f"model file holds {len(self.hyperplanes_)} classifiers of width "
                f"{self.hyperplanes_.weights.shape[1]}; the header implies {self._tree_offsets[-1]} of width {n_selected}."
            )
        cols = self.hyperplanes_.columns
        if (cols is None) != (n_selected == d) or (cols is not None and cols.size and int(cols.max()) >= d):
            raise ModelFileError("column indices in the model file are missing or out of range.")
        self.n_unconverged_ = int(state.get("n_unconverged", 0))
        self.fit_time_ = float(state.get("fit_time", float("nan")))
