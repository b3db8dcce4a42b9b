"""SeqSLAM (Milford & Wyeth 2012) with OpenSeqSLAM's parameters (the paper's baselines).

Orientation: **queries are rows** here as everywhere in btel, so a difference matrix ``D`` has
shape (n_queries, n_map) and ``D[j, i]`` compares query j with map row i.

1. Difference matrix: mean absolute difference between every query and every map descriptor
   (SeqSLAM's front end is a 64×32 patch-normalised thumbnail, 2048 values; any descriptor works).
2. Local contrast enhancement (OpenSeqSLAM ``R = 10``): for each query and map row i, subtract the
   mean and divide by the standard deviation (n−1 normalisation, as MATLAB's ``std``) of the
   differences to map rows i−5 … i+5 (truncated at the ends of the map); then shift the whole
   matrix so that its minimum is 0, as OpenSeqSLAM does.
3. Sequence search: the score of map row e for query j is the smallest, over velocities
   v ∈ {vmin, vmin+vskip, …, vmax}, of ``Σ_t D[j−t, e − round(v·t)]`` for t = 0 … ds−1 — a
   straight line through the trailing ds queries that ends at (j, e). It is causal (it only uses
   queries up to j; OpenSeqSLAM centres its window instead); the first ds−1 queries use the history
   they have. A line cell before the start of the map adds that query's mean difference — the
   value of "no evidence" — so that the first places stay reachable.
4. Best match: the row with the lowest score; its confidence is OpenSeqSLAM's ratio of that score
   to the lowest score outside ±window/2 rows of it (smaller = more distinctive).

Storage: the map as uint8, N×d bytes (N×2048 for SeqSLAM's thumbnails), plus 8 bytes for the
affine map ``code = round((x − lo)/scale)``, ``lo`` = the map's minimum value and
``scale = (max − min)/255``, that turns descriptors into bytes. Queries are quantised the same way
(clipped to 0…255), and differences are reported back in descriptor units.
"""

from __future__ import annotations

import numbers
from typing import Any

import faiss
import numpy as np

from ...core.validation import N_JOBS, Interval, check_positive_int
from ..base import ArraySpec
from ...exceptions import InvalidDescriptorsError, InvalidParameterError, ModelFileError
from ._common import MAX_NORM, _RowLocalizer, raise_budget_too_small

__all__ = ["SeqSLAM", "seqslam_match", "enhance_contrast", "sequence_costs", "velocities"]

#: Queries per block in the contrast enhancement (bounds its float64 temporaries).
_BLOCK_ROWS = 512
#: Most velocities searched (each is a line per cell and query).
MAX_VELOCITIES = 1000


def _check_matrix(D: Any, name: str) -> np.ndarray:
    arr = np.asarray(D)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] < 2 or arr.dtype.kind not in "biuf":
        raise InvalidDescriptorsError(
            f"{name} must be a numeric 2-D array (n_queries, n_map) with at least 2 map columns; "
            f"got shape {arr.shape}, dtype {arr.dtype}."
        )
    if not np.isfinite(arr).all():
        raise InvalidDescriptorsError(f"{name} contains NaN or infinite values.")
    return arr


def _check_window(window: Any) -> int:
    return check_positive_int(window, "window", minimum=2)


def velocities(vmin: float = 0.8, vmax: float = 1.2, vskip: float = 0.1) -> np.ndarray:
    """The velocities searched: vmin, vmin + vskip, …, up to vmax (inclusive), in map rows per query.

    Returns
    -------
    ndarray of shape (n_velocities,), float64
    """
    for name, value in (("vmin", vmin), ("vmax", vmax), ("vskip", vskip)):
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value):
            raise InvalidParameterError(f"{name} must be a finite number; got {value!r}.")
    if vmin < 0 or vmax < vmin or vskip <= 0:
        raise InvalidParameterError(
            f"velocities need 0 ≤ vmin ≤ vmax and vskip > 0; got vmin={vmin}, vmax={vmax}, vskip={vskip}."
        )
    # The small tolerance keeps vmax itself when (vmax − vmin)/vskip is a whole number in decimal.
    steps = np.floor((vmax - vmin) / vskip + 1e-9)
    if not np.isfinite(steps) or steps >= MAX_VELOCITIES:
        raise InvalidParameterError(
            f"vmin={vmin}, vmax={vmax}, vskip={vskip} give more than {MAX_VELOCITIES} velocities; "
            "raise vskip or narrow [vmin, vmax]."
        )
    return vmin + vskip * np.arange(int(steps) + 1)


def enhance_contrast(D: Any, window: int = 10) -> np.ndarray:
    """OpenSeqSLAM's local contrast enhancement along the map axis.

    Parameters
    ----------
    D : array-like of shape (n_queries, n_map)
        Difference matrix (queries are rows).
    window : int
        R: each cell is normalised by the map rows within ±window//2 of it.

    Returns
    -------
    ndarray of shape (n_queries, n_map), float32
        Locally z-scored differences, shifted so that the minimum is 0 (a cell whose neighbourhood
        is constant gets 0 before the shift).
    """
    D = _check_matrix(D, "D")
    half = _check_window(window) // 2
    n_map = D.shape[1]
    lo = np.maximum(np.arange(n_map) - half, 0)
    hi = np.minimum(np.arange(n_map) + half, n_map - 1) + 1
    count = (hi - lo).astype(np.float64)
    out = np.empty(D.shape, dtype=np.float32)
    # Blocks of queries bound the float64 temporaries (rows are independent until the final shift).
    for start in range(0, D.shape[0], _BLOCK_ROWS):
        block = D[start : start + _BLOCK_ROWS].astype(np.float64)
        # Window sums from cumulative sums: vectorised over every cell of the block.
        zeros = np.zeros((block.shape[0], 1))
        csum = np.concatenate([zeros, np.cumsum(block, axis=1)], axis=1)
        csq = np.concatenate([zeros, np.cumsum(block * block, axis=1)], axis=1)
        total = csum[:, hi] - csum[:, lo]
        mean = total / count
        var = np.maximum((csq[:, hi] - csq[:, lo]) - total * mean, 0.0) / np.maximum(count - 1, 1)
        std = np.sqrt(var)
        out[start : start + _BLOCK_ROWS] = np.divide(
            block - mean, std, out=np.zeros_like(block), where=std > 1e-12 * (1 + np.abs(mean))
        )
    out -= out.min()
    return out


def sequence_costs(D: Any, ds: int = 10, vmin: float = 0.8, vmax: float = 1.2, vskip: float = 0.1) -> np.ndarray:
    """Cost of the best straight line through the trailing ``ds`` queries ending at each cell.

    Parameters
    ----------
    D : array-like of shape (n_queries, n_map)
        (Contrast-enhanced) difference matrix; queries are consecutive frames, in order.
    ds : int
        Sequence length in queries.
    vmin, vmax, vskip : float
        Velocities searched, in map rows per query (see :func:`velocities`).

    Returns
    -------
    ndarray of shape (n_queries, n_map), float32
        ``C[j, e] = min_v Σ_{t<min(ds, j+1)} D[j−t, e − round(v·t)]``; cells before the map's
        first row count as the query's mean difference.
    """
    D = _check_matrix(D, "D").astype(np.float32)
    ds = check_positive_int(ds, "ds")
    n_queries, n_map = D.shape
    steps = np.arange(ds)
    # Round half up; velocities giving the same row offsets give the same line: search it once.
    # A line offset past the map's first row reads the padding whatever its size, so offsets are
    # capped at n_map: the same costs, and the padding never exceeds the map (huge vmax·ds).
    lines = np.minimum(np.floor(velocities(vmin, vmax, vskip)[:, None] * steps + 0.5), n_map)
    offsets = np.unique(lines.astype(np.int64), axis=0)
    pad = int(offsets.max())
    padded = np.empty((n_queries, pad + n_map), dtype=np.float32)
    padded[:, :pad] = D.mean(axis=1, keepdims=True)
    padded[:, pad:] = D
    best = np.full((n_queries, n_map), np.inf, dtype=np.float32)
    total = np.empty_like(best)
    for line in offsets:
        total[:] = 0.0
        # Query j − t at map row e − line[t]: add the whole shifted matrix at once per step t.
        for t in range(min(ds, n_queries)):
            start = pad - int(line[t])
            total[t:] += padded[: n_queries - t, start : start + n_map]
        np.minimum(best, total, out=best)
    return best


def _match_from_costs(costs: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    half = window // 2
    best = np.argmin(costs, axis=1)
    best_cost = costs[np.arange(costs.shape[0]), best].astype(np.float64)
    near = np.abs(np.arange(costs.shape[1])[None, :] - best[:, None]) <= half
    second = np.where(near, np.inf, costs).min(axis=1).astype(np.float64)
    # Undefined (NaN) when no row lies outside the window or the runner-up costs 0.
    score = np.full(best_cost.shape, np.nan)
    np.divide(best_cost, second, out=score, where=np.isfinite(second) & (second > 0))
    return best.astype(np.int64), score


def seqslam_match(
    difference_matrix: Any,
    ds: int = 10,
    vmin: float = 0.8,
    vmax: float = 1.2,
    vskip: float = 0.1,
    window: int = 10,
    *,
    enhance: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """SeqSLAM's sequence matching on any difference matrix (queries are rows).

    Parameters
    ----------
    difference_matrix : array-like of shape (n_queries, n_map)
        Smaller = more similar; queries are consecutive frames in travel order, map rows in route
        order. Any distance works (mean absolute difference, L2 between HOG or CNN descriptors…).
    ds : int
        Sequence length (OpenSeqSLAM: 10).
    vmin, vmax, vskip : float
        Velocities in map rows per query (OpenSeqSLAM: 0.8 … 1.2 in steps of 0.1).
    window : int
        OpenSeqSLAM's R = Rwindow = 10: the local contrast enhancement uses ±window//2 map rows,
        and the confidence ratio excludes ±window//2 rows around the best match.
    enhance : bool
        Apply the local contrast enhancement first (False for an already enhanced matrix).

    Returns
    -------
    best_index : ndarray of shape (n_queries,), int64
        Map row of the best-scoring line ending at each query.
    score : ndarray of shape (n_queries,), float64
        Best line cost / best cost outside ±window//2 rows (in [0, 1]; smaller = more confident;
        NaN when undefined).
    """
    window = _check_window(window)
    if enhance:
        D = enhance_contrast(difference_matrix, window)
    else:
        D = _check_matrix(difference_matrix, "difference_matrix")
    return _match_from_costs(sequence_costs(D, ds, vmin, vmax, vskip), window)


class SeqSLAM(_RowLocalizer):
    """Sequence matching over a uint8 map (OpenSeqSLAM parameters).

    ``predict(Q)`` treats the rows of ``Q`` as consecutive query frames in travel order: the
    answer for row j uses rows j−ds+1 … j. Shuffled or unrelated queries lose the sequence, so
    SeqSLAM is marked as a sequence method (``uses_sequence``) in every table.

    Parameters
    ----------
    budget : int or str, optional
        Bytes. SeqSLAM has one configuration, N×d bytes + 8 (see :mod:`btel.methods.baselines.seqslam`);
        a smaller budget raises :class:`~btel.exceptions.BudgetTooSmallError` naming it.
    ds : int
        Sequence length in frames.
    vmin, vmax, vskip : float
        Velocities searched (map rows per query); at most 1000 of them.
    window : int
        Contrast-enhancement window R (and the confidence ratio's exclusion window).
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`); none by default — SeqSLAM's own front end is the
        patch-normalised thumbnail and its contrast enhancement.
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    map_codes_ : ndarray of shape (n_rows, n_features), uint8
    value_range_ : ndarray of shape (2,), float32
        ``(lo, scale)`` of the affine map descriptor → byte.
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    front_end_ : FrontEnd
    fit_time_ : float
    """

    label = "seqslam"
    uses_sequence = True
    #: The image descriptor SeqSLAM was built on (patch-normalised thumbnails): experiments read it.
    native_descriptor = "patchnorm"
    #: SeqSLAM's own front end is the thumbnail and its contrast enhancement: no normalisation.
    front_end_defaults = {"normalize": "none", "whiten": None, "delta": None}
    _parameter_constraints = {
        "ds": [Interval(int, 1, 10_000)],
        "vmin": [Interval(float, 0, 1e6)],
        "vmax": [Interval(float, 0, 1e6)],
        "vskip": [Interval(float, 0, 1e6, closed="right")],
        "window": [Interval(int, 2, 1_000_000)],
        "n_jobs": N_JOBS,
    }

    def __init__(
        self,
        *,
        budget: int | str | None = None,
        ds: int = 10,
        vmin: float = 0.8,
        vmax: float = 1.2,
        vskip: float = 0.1,
        window: int = 10,
        n_jobs: int | None = None,
    ) -> None:
        self.budget = budget
        self.ds = ds
        self.vmin = vmin
        self.vmax = vmax
        self.vskip = vskip
        self.window = window
        self.n_jobs = n_jobs

    @staticmethod
    def planned_bytes(n_rows: int, n_features: int) -> int:
        """N×d bytes of map plus the 8-byte affine map."""
        return int(n_rows) * int(n_features) + 8

    def _check_params(self) -> None:
        check_positive_int(self.ds, "ds")
        velocities(self.vmin, self.vmax, self.vskip)  # at most MAX_VELOCITIES of them
        _check_window(self.window)

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        needed = self.planned_bytes(n_rows, n_features_out) + reserved
        if budget is not None and needed > budget:
            raise_budget_too_small("SeqSLAM", budget, needed, f"{n_rows} × {n_features_out} bytes of map + 8")

    def budget_saturated(self) -> bool:
        """True under any budget: the map is stored whole at one byte a value, whatever the budget."""
        return self.budget is not None

    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        self._check_params()
        self._check_plan(*X.shape, budget, reserved)
        lo, hi = float(X.min()), float(X.max())
        scale = (hi - lo) / 255.0 if hi > lo else 1.0
        # At least the smallest positive float32: a map of tiny values (1e-44) still gets a usable step.
        scale = max(float(np.float32(scale)), float(np.finfo(np.float32).smallest_subnormal))
        self.value_range_ = np.array([lo, scale], dtype=np.float32)
        self.map_codes_ = self._quantise(X)

    def _quantise(self, X: np.ndarray) -> np.ndarray:
        lo, scale = (float(v) for v in self.value_range_)
        return np.clip(np.rint((X.astype(np.float64) - lo) / scale), 0, 255).astype(np.uint8)

    def difference_matrix(self, Q: Any) -> np.ndarray:
        """Mean absolute difference between every query and every map row, in descriptor units.

        Returns
        -------
        ndarray of shape (n_queries, n_rows), float32
        """
        return self._differences(self._check_queries(Q))

    def _code_differences(self, Q: np.ndarray) -> np.ndarray:
        """Mean absolute difference of the byte codes (0 … 255): the difference matrix / the value step."""
        codes = self._quantise(Q).astype(np.float32)
        l1 = faiss.pairwise_distances(codes, self.map_codes_.astype(np.float32), metric=faiss.METRIC_L1)
        return l1 / np.float32(self.map_codes_.shape[1])

    def _differences(self, Q: np.ndarray) -> np.ndarray:
        return (self._code_differences(Q) * float(self.value_range_[1])).astype(np.float32)

    def _costs(self, Q: np.ndarray) -> np.ndarray:
        # Contrast enhancement z-scores every cell: in the codes' own units the costs are the same whatever
        # the scale of the descriptors (in descriptor units a map of tiny or huge values under/overflows).
        D = enhance_contrast(self._code_differences(Q), self.window)
        return sequence_costs(D, self.ds, self.vmin, self.vmax, self.vskip)

    def _sequence_context(self) -> int:
        return int(self.ds) - 1

    def _search_rows(self, Q: np.ndarray, k: int, scores: bool = True) -> tuple[np.ndarray, np.ndarray]:
        costs = self._costs(Q)
        if k == 1:
            rows = np.argmin(costs, axis=1)[:, None].astype(np.int64)
        else:
            top = np.argpartition(costs, k - 1, axis=1)[:, :k] if k < costs.shape[1] else \
                np.broadcast_to(np.arange(costs.shape[1]), costs.shape).copy()
            # Order the k best by cost, ties by map row, so that rankings are reproducible.
            values = np.take_along_axis(costs, top, axis=1)
            order = np.lexsort((top, values), axis=1)
            rows = np.take_along_axis(top, order, axis=1).astype(np.int64)
        return -np.take_along_axis(costs, rows, axis=1).astype(np.float64), rows

    def match(self, Q: Any) -> tuple[np.ndarray, np.ndarray]:
        """Best place and OpenSeqSLAM confidence ratio for each query of a sequence.

        Returns
        -------
        places : ndarray of shape (n_queries,), int64
        score : ndarray of shape (n_queries,), float64
            As in :func:`seqslam_match` (smaller = more distinctive), computed over map rows.
        """
        Q = self._check_queries(Q)
        rows, score = _match_from_costs(self._costs(Q), int(self.window))
        places = rows if self.row_places_ is None else self.row_places_[rows].astype(np.int64)
        return places, score

    def _model_arrays(self) -> dict[str, np.ndarray]:
        return {"map_codes": self.map_codes_, "value_range": self.value_range_}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        return {"map_codes": ArraySpec((None, d), np.uint8), "value_range": ArraySpec((2,), np.float32)}

    def _n_rows(self) -> int:
        return int(self.map_codes_.shape[0])

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        codes, value_range = arrays["map_codes"], arrays["value_range"]
        # Fit stores a finite lowest value of rows no longer than MAX_NORM and a positive step at most
        # 1/255 of their span: anything else is a damaged or edited file.
        if not (np.isfinite(value_range).all() and abs(float(value_range[0])) <= 2 * MAX_NORM
                and 0 < float(value_range[1]) <= MAX_NORM):
            raise ModelFileError(f"SeqSLAM model file holds an invalid value range {value_range.tolist()} "
                                 f"(fit stores a lowest value within ±{2 * MAX_NORM:.0e} and a positive step); "
                                 "the file is damaged or was edited. Refit and save it again.")
        try:
            self._check_params()
        except InvalidParameterError as exc:
            raise ModelFileError(f"the SeqSLAM model file's parameters are invalid: {exc}") from exc
        self.map_codes_, self.value_range_ = codes, value_range
