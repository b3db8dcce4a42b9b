"""The BTEL estimator (Le, Hoang & Milford): regions, one binary tree per region, under a byte budget.

The ideas live in their own modules — the codes (:mod:`btel.methods.btel.compressed`,
:mod:`btel.methods.btel.full`, :mod:`btel.methods.btel.encoding`), inference and ranking over bit
flips (:mod:`btel.methods.btel.decoding`, :mod:`btel.methods.btel.ranking`), the storage layout and
budget planner (:mod:`btel.methods.btel.planning`), the model file (:mod:`btel.methods.btel.model_file`),
the regions (:mod:`btel.methods.btel.regions`) and the classifier fits (:mod:`btel.learning.training`);
this file wires them into one scikit-learn estimator: its parameters and ``fit``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.validation import BOOLEAN, MAX_C, N_JOBS, RANDOM_STATE, DType, Interval, Options, String, check_positive_int
from ..base import PlaceLocalizer
from ...exceptions import InvalidParameterError
from ...learning.distributed import BACKENDS
from ...learning.feature_selection import column_index_dtype
from ...learning.hyperplanes import Hyperplanes
from ...learning.linear import ColumnStats, default_C
from ...learning.solvers import CLASSIFIERS, SOLVERS
from ...learning.training import Task, convergence_warning, fit_tasks, one_vs_rest_tasks
from .compressed import DECODERS, compressed_tasks
from .decoding import TreeDecoding
from .encoding import n_bits_for
from .full import full_tasks
from .model_file import TreeModelFile
from .planning import (SCHEMES, WEIGHT_DTYPES, largest_fitting, n_tree_classifiers, planned_bytes,
                       raise_budget_too_small, tree_sizes)
from .regions import predict_regions, segment_route
from .segmentation import check_segment_count, region_of

__all__ = ["BTELocalizer", "planned_bytes", "block_size_for_tolerance"]

#: Most offset-code copies accepted (beyond ~log2 of the block sizes extra copies repeat shifts).
MAX_CODE_COPIES = 256


def block_size_for_tolerance(tolerance: int) -> int:
    """B = 2^L, the largest power of two ≤ t (1 for t = 0): "drop the L low bits with 2^L ≤ t"."""
    t = check_positive_int(tolerance, "tolerance", minimum=0)
    return 1 if t == 0 else 1 << (t.bit_length() - 1)


class BTELocalizer(TreeDecoding, TreeModelFile, PlaceLocalizer):
    """Binary tree encoding for visual localization (BTEL; Le, Hoang & Milford).

    Learns b = ceil(log2 N) linear classifiers that predict the bits of a place's index, so the
    map costs b·d' weights, O(d' log N) bytes, instead of one code per image. Optionally the route is first split
    into r regions (Kernel Temporal Segmentation) with a region classifier and one tree each.

    Parameters
    ----------
    scheme : {'compressed', 'full'}
        'compressed' (BTE-C): one classifier per bit, O(d log N) storage; 'full' (BTE-F): one per
        internal tree node, O(N d) storage (the paper's foil).
    classifier : {'svm', 'logistic'}
        L2-regularised linear SVM with the squared hinge loss, or L2 logistic regression (the
        objectives of liblinear; :mod:`btel.learning.solvers`).
    solver : {'auto', 'newton', 'lbfgs', 'liblinear'}
        How the classifiers are solved (:mod:`btel.learning.solvers`). 'newton': Newton's method with exact
        line search, to a relative gradient norm of 1e-5 (the exact optimum for the squared hinge);
        'lbfgs': L-BFGS over all classifiers that share rows and columns; 'liblinear':
        scikit-learn's liblinear (which can stop unconverged, far from the optimum, on maps with
        N ≈ d). 'auto' (default): 'newton' when min(rows, d' + 1) ≤ 4096, else 'lbfgs'.
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
        Bit margins → index: MSB-first constrained decode (``search``'s first candidate even where another place
        scores higher), or the soft decode over valid indices, ranked by score (O(N·b) a query; compressed only).
    max_regions : int
        Largest r tried when ``n_regions='auto'``.
    kts_penalty : float
        v of the KTS penalty for ``n_regions='auto'``.
    kts_pca_dims : int or None
        PCA dimension before KTS (None: none).
    kts_max_points : int
        Longest route KTS segments exactly (O(N²·r)); longer routes are averaged in blocks of
        ⌈N / kts_max_points⌉ places first (:func:`btel.methods.btel.segmentation.kts_regions`).
    max_iter : int, optional
        Iteration cap of the solver (None: its default — 100 Newton steps, 2000 L-BFGS steps,
        1000 liblinear iterations). Classifiers that stop at the cap are counted in
        ``n_unconverged_`` and reported by one ``ConvergenceWarning`` from ``fit``.
    n_jobs : int, optional
        Parallel classifier fits (joblib; −1 = all cores; with ``backend='dask'`` None means every
        worker of the cluster). A runtime setting: not saved in model files.
    backend : {None, 'threads', 'loky', 'dask'}
        Where the classifier fits run (:mod:`btel.learning.distributed`). None: threads, or whatever
        ``joblib.parallel_config`` the caller set. 'dask': the workers of a Dask cluster (X is
        sent to each worker once); needs ``pip install btel[dask]``. The model does not depend
        on the backend: the Newton and L-BFGS solvers are deterministic. (With
        ``solver='liblinear'`` only bitwise so when no worker process runs two fits at once:
        liblinear's dual solver draws from one random generator per process.)
    scheduler : str, optional
        Dask scheduler address for ``backend='dask'`` (e.g. ``'tcp://10.0.0.5:8786'``); None uses
        the ``distributed.Client`` already running in this process.
    random_state : int or None
        Seed for the randomized PCA of KTS and for liblinear (``solver='liblinear'``); default 0,
        so a refit gives the same model; None draws a fresh seed.
    progress : bool
        Show a progress bar while fitting (only on a terminal).
    block_size : int
        B ≥ 1, tolerance-aware codes: the trees index blocks of B consecutive places
        (``place // B``) and predict a block's centre place, which is within ⌊B/2⌋ of every place
        of the block. ⌈log2 ⌈N/B⌉⌉ bits instead of ⌈log2 N⌉, so under a budget each classifier
        keeps more columns. :func:`block_size_for_tolerance` gives the power of two for a
        tolerance t (B ≤ t, so the worst in-block error is ≤ t/2). 1: plain BTEL.
    code_copies : int
        m in [1, 256], error-correcting offset codes (``scheme='compressed'``): m − 1 shifted
        copies of each bit's contiguous-block split are learnt as extra classifiers and every tree
        is decoded softly over its whole code (:mod:`btel.methods.btel.compressed`). 1: the plain b bits.
    exemplar_radius : int
        e ≥ 0, multi-exemplar labels (``scheme='compressed'``): each row also stands for the
        places within ±e of it that share the column's high bits, i.e. rows next to a block
        boundary weigh less (:func:`btel.methods.btel.compressed.exemplar_weights`). 0: all rows weigh 1.
        Several exemplars per place from extra traverses or augmented images go through
        ``fit(X, places)``.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`): row normalisation ('l2' by default: global
        descriptors are compared by direction; 'none', 'power'), PCA whitening to that many
        dimensions (stored and counted), delta descriptors over a window of that many frames
        (queries are then one ordered traverse).

    Attributes
    ----------
    n_places_ : int
        N.
    n_blocks_ : int
        Blocks of ``block_size`` consecutive places, what the trees index: ⌈N / block_size⌉ (N
        when block_size = 1); region starts and sizes count these.
    n_features_in_ : int
        d, the dimension of the descriptors given to fit and predict.
    n_selected_ : int
        d', columns per classifier.
    n_regions_ : int
        r.
    region_starts_ : ndarray of shape (r,), int64
        First code of each region.
    region_sizes_ : ndarray of shape (r,), int64
    tree_offsets_ : ndarray of shape (r + 1,), int64
        Region k's classifiers are rows ``tree_offsets_[k]:tree_offsets_[k+1]`` of ``hyperplanes_``.
    hyperplanes_ : Hyperplanes
        Every tree classifier, region by region (bits MSB first, or nodes in heap order).
    region_hyperplanes_ : Hyperplanes or None
        The region classifier (None when r = 1).
    front_end_ : FrontEnd
    n_unconverged_ : int
        Classifiers whose solver stopped at its iteration cap (``fit`` then warns once).
    fit_summary_ : btel.learning.training.FitSummary
        Solvers used, summed objective, most iterations (not saved in model files).
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

    label, encodes_place_index = "BTEL", True
    _linear_in_queries = True  # queries are only multiplied by hyperplanes (see btel.core.frontend.ScaledRows)
    _parameter_constraints = {
        "scheme": [Options(*SCHEMES)],
        "classifier": [Options(*CLASSIFIERS)],
        "solver": [Options(*SOLVERS)],
        "C": [None, Interval(float, 0, MAX_C, closed="right")],
        "feature_ratio": [None, Interval(float, 0, 1, closed="right")],
        "n_features": [None, Interval(int, 1, None)],
        "sparsity": [Interval(float, 0, None, closed="neither")],
        "n_regions": [Options("auto"), Interval(int, 1, None)],
        "dtype": [DType(*WEIGHT_DTYPES)],
        "decode": [Options(*DECODERS)],
        "max_regions": [Interval(int, 1, None)],
        "kts_penalty": [Interval(float, 0, None)],
        "kts_pca_dims": [None, Interval(int, 1, None)],
        "kts_max_points": [Interval(int, 4, None)],
        "max_iter": [None, Interval(int, 1, 2**31 - 1)],  # None: the solver's own cap; liblinear takes a C int
        "n_jobs": N_JOBS,
        "backend": [None, Options(*BACKENDS)],
        "scheduler": [None, String()],
        "random_state": RANDOM_STATE,
        "progress": BOOLEAN,
        "block_size": [Interval(int, 1, None)],
        "code_copies": [Interval(int, 1, MAX_CODE_COPIES)],
        "exemplar_radius": [Interval(int, 0, None)],
    }
    _runtime_params = ("n_jobs", "backend", "scheduler", "progress")

    def __init__(
        self,
        *,
        scheme: str = "compressed",
        classifier: str = "svm",
        solver: str = "auto",
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
        max_iter: int | None = None,
        n_jobs: int | None = None,
        backend: str | None = None,
        scheduler: str | None = None,
        random_state: int | None = 0,
        progress: bool = True,
        block_size: int = 1,
        code_copies: int = 1,
        exemplar_radius: int = 0,
    ) -> None:
        self.scheme = scheme
        self.classifier = classifier
        self.solver = solver
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
    def _check_combinations(self) -> None:
        """Rules between parameters (each parameter alone is checked by its declared constraints)."""
        if self.decode == "soft" and self.scheme == "full":
            raise InvalidParameterError("decode='soft' needs every bit margin: use it with scheme='compressed'.")
        if self.scheme == "full" and (self.code_copies > 1 or self.exemplar_radius > 0):
            raise InvalidParameterError(
                "code_copies > 1 and exemplar_radius > 0 extend the per-bit classifiers of scheme='compressed'; "
                "BTE-F ('full') has one classifier per node instead."
            )
        if self.scheduler is not None and self.backend != "dask":
            raise InvalidParameterError("scheduler only applies with backend='dask'.")

    def _cap(self, d: int, budget: int | None) -> int:
        """Upper bound on d' from n_features / feature_ratio (d itself under a budget)."""
        if self.n_features is not None:
            return min(int(self.n_features), d)
        ratio = self.feature_ratio if self.feature_ratio is not None else (None if budget else 0.1)
        return d if ratio is None else int(min(d, max(1, round(ratio * d))))

    # ------------------------------------------------------------------ fit
    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        """The planner of ``fit`` on shapes alone. With a fixed r ≥ 2 the region sizes come from KTS, so
        only KTS' minimum is checked and the fit decides the bytes."""
        n_blocks = -(-n_rows // int(self.block_size))
        if self.n_regions != "auto" and int(self.n_regions) > 1:
            if n_blocks <= int(self.kts_max_points):  # longer routes are averaged in blocks first
                check_segment_count(n_blocks, int(self.n_regions))
            return
        if budget is None:
            return
        d = n_features_out
        dtype = str(np.dtype(self.dtype))
        kw = dict(scheme=self.scheme, dtype=dtype, code_copies=int(self.code_copies))
        if largest_fitting([n_blocks], d, self._cap(d, budget), budget - reserved, self.scheme, dtype,
                           int(self.code_copies)) < 1:
            raise_budget_too_small(f"BTEL ({self.scheme}, N = {n_rows}, r = 1)", budget,
                                   planned_bytes(n_blocks, d, n_selected=1, **kw) + reserved,
                                   "Raise the budget, use dtype='float16', or fewer regions.")

    def budget_saturated(self) -> bool:
        """d' reached the parameters' cap (r fixed), so a larger budget gives the same model."""
        if not hasattr(self, "n_selected_") or self.n_regions == "auto":
            return False
        d = self.front_end_.n_features_out(int(self.n_features_in_))
        return int(self.n_selected_) == int(self._cap(d, None if self.budget is None else 1))

    def _fit(self, X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
             reserved: int) -> None:
        self._check_combinations()
        C = float(default_C(self.classifier) if self.C is None else self.C)
        dtype = np.dtype(self.dtype).name
        places_arr = np.arange(n_places, dtype=np.int64) if places is None else places
        # Tolerance-aware codes: everything below works on block indices ("codes").
        block_size, copies = int(self.block_size), int(self.code_copies)
        n_blocks = -(-n_places // block_size)
        if n_blocks < 2:
            raise InvalidParameterError(
                f"block_size = {block_size} leaves {n_blocks} block of N = {n_places} places; an index needs at "
                f"least 2. Use block_size ≤ {max(1, (n_places - 1))}."
            )
        codes_arr = places_arr // block_size if block_size > 1 else places_arr
        d = X.shape[1]
        cap = self._cap(d, budget)
        available = None if budget is None else budget - reserved
        kw = dict(scheme=self.scheme, dtype=dtype, code_copies=copies)

        def fits(sizes: list[int]) -> bool:
            return largest_fitting(sizes, d, cap, available, self.scheme, dtype, copies) >= 1

        starts = segment_route(X, codes_arr, n_blocks, self.n_regions, max_regions=int(self.max_regions),
                               penalty=float(self.kts_penalty), pca_dims=self.kts_pca_dims,
                               random_state=self.random_state, max_points=int(self.kts_max_points),
                               fits=None if available is None else fits)
        sizes = tree_sizes(starts, n_blocks)
        n_selected = cap
        if available is not None:
            n_selected = largest_fitting(list(sizes), d, cap, available, self.scheme, dtype, copies)
            if n_selected < 1:
                raise_budget_too_small(
                    f"BTEL ({self.scheme}, N = {n_places}, r = {len(sizes)})", budget,
                    planned_bytes(int(sum(sizes)), d, n_selected=1, region_sizes=list(sizes), **kw) + reserved,
                    "Raise the budget, use dtype='float16', or fewer regions.")

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
                                              exemplar_radius=int(self.exemplar_radius)))
            else:
                tasks.extend(full_tasks(local, int(n_k), rows))

        from tqdm.auto import tqdm  # fit-only: a loaded model never imports it
        with tqdm(total=len(tasks), desc="BTEL fit", unit="clf", disable=None if self.progress else True,
                  leave=False) as bar:
            parts, summary = fit_tasks(
                X, tasks, n_selected, stats, sparsity=float(self.sparsity), n_jobs=self.n_jobs,
                backend=self.backend, scheduler=self.scheduler, progress=bar.update, classifier=self.classifier,
                C=C, solver=self.solver, max_iter=None if self.max_iter is None else int(self.max_iter),
                random_state=self.random_state, dtype=np.dtype(dtype),
            )
        convergence_warning(summary, "BTELocalizer.fit", self.max_iter)

        index_dtype = None if n_selected >= d else column_index_dtype(d)
        self.region_hyperplanes_ = (
            Hyperplanes.stack(parts[:first_tree_task], d, n_selected, np.dtype(dtype), index_dtype,
                              shared_columns=True)
            if first_tree_task else None
        )
        self.hyperplanes_ = Hyperplanes.stack(parts[first_tree_task:], d, n_selected, np.dtype(dtype), index_dtype)
        self.n_unconverged_ = int(summary.n_unconverged)
        self.fit_summary_ = summary
        self._set_structure(n_places, n_selected, starts)

    def _set_structure(self, n_places: int, n_selected: int, starts: np.ndarray) -> None:
        """Derived attributes that follow from N, d', the code options and the region starts."""
        starts = np.asarray(starts, dtype=np.int64)
        self.block_size_ = int(self.block_size)
        self.code_copies_ = int(self.code_copies)
        n_blocks = -(-int(n_places) // self.block_size_)
        sizes = tree_sizes(starts, n_blocks)
        n_classifiers = [n_tree_classifiers(self.scheme, int(n), self.code_copies_) for n in sizes]
        self.n_blocks_ = int(n_blocks)
        self.n_selected_ = int(n_selected)
        self.n_regions_ = int(starts.size)
        self.region_starts_ = starts
        self.region_sizes_ = sizes
        self.n_bits_ = n_bits_for(n_blocks)
        self.tree_offsets_ = np.concatenate([[0], np.cumsum(n_classifiers)]).astype(np.int64)
        self._tree_width = max(self.n_bits_, int(max(n_classifiers))) if self.scheme == "compressed" \
            else self.n_bits_

    # ------------------------------------------------------------------ inference
    def predict_region(self, Q: Any) -> np.ndarray:
        """Region of each query (int64, shape (n_queries,); all 0 when r = 1)."""
        Q = self._check_queries(Q)
        return predict_regions(self._region_scores(Q), self.n_regions_, Q.shape[0])

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
        return self._decode(self._check_queries(Q))[1]

    def column_margins(self, Q: Any) -> np.ndarray:
        """Margins of every tree classifier (all regions side by side, ``tree_offsets_`` apart).

        Returns
        -------
        ndarray of shape (n_queries, tree_offsets_[-1]), float32
        """
        return self.hyperplanes_.margins(self._check_queries(Q))

    # -- bit diagnostics (the beyond experiment asks the model for these) -------------------------
    def bit_accuracy(self, Q: Any, true_places: Any) -> Any:
        """Per-level accuracy of the bit classifiers on queries (:func:`.diagnostics.localizer_bit_accuracy`)."""
        from .diagnostics import localizer_bit_accuracy
        return localizer_bit_accuracy(self, Q, true_places)

    @staticmethod
    def answer_bit_accuracy(predictions: Any, true_places: Any, n_places: int) -> Any:
        """Per-level accuracy of the bits of any method's answers (:func:`.diagnostics.answer_bit_accuracy`)."""
        from .diagnostics import answer_bit_accuracy
        return answer_bit_accuracy(predictions, true_places, n_places)

    @staticmethod
    def plot_bit_accuracy(curves: Any, path: Any, **options: Any) -> Any:
        """Per-bit accuracy against bit level, one line per curve (:func:`.diagnostics.plot_bit_accuracy`)."""
        from .diagnostics import plot_bit_accuracy
        return plot_bit_accuracy(curves, path, **options)
