"""RYTH (Yu, Jacobson & Milford 2018): place index by its residues modulo co-prime periods (the paper's baselines).

K pairwise co-prime periods p_k near N^(1/K) with Π p_k ≥ N. Classifier k is a multiclass linear
classifier (one-vs-rest linear SVM) whose label is ``i mod p_k``, on its own d' columns. Decoding:

- ``'soft'`` (default): argmax over valid i < N of ``Σ_k score_k[i mod p_k]`` (O(N·K) per query),
  which also ranks candidates (R@K);
- ``'crt'``: the Chinese remainder theorem on each classifier's argmax residue; an index ≥ N
  (possible when Π p_k > N) falls back to the soft decode.

Storage: Σ_k p_k hyperplanes of d' weights plus one bias, and K sets of d' column indices.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.validation import MAX_C, N_JOBS, RANDOM_STATE, DType, Interval, Options, check_positive_int, read_state_int
from .base import ArraySpec, PlaceLocalizer
from ..exceptions import BudgetTooSmallError, ModelFileError, NotEnoughPlacesError
from ..learning.feature_selection import column_index_dtype
from ..learning.hyperplanes import Hyperplanes
from ..learning.linear import ColumnStats, default_C
from ..learning.solvers import CLASSIFIERS, SOLVERS
from ..core.storage import budget_of, exact_bytes
from ..learning.training import convergence_warning, fit_tasks, one_vs_rest_tasks

__all__ = ["RYTHLocalizer", "coprime_periods", "crt"]


def coprime_periods(n_places: int, n_periods: int) -> list[int]:
    """K pairwise co-prime periods, each ≥ 2, near N^(1/K), whose product is ≥ N.

    Rule: start at ``ceil(N^(1/K))`` and take the smallest integers (upwards) co-prime with
    every period already chosen; if their product falls short of N, restart one higher.
    """
    n = check_positive_int(n_places, "n_places", minimum=2)
    k = check_positive_int(n_periods, "n_periods")
    base = max(2, math.ceil(n ** (1.0 / k) - 1e-9))
    while True:
        periods: list[int] = []
        candidate = base
        while len(periods) < k:
            if all(math.gcd(candidate, p) == 1 for p in periods):
                periods.append(candidate)
            candidate += 1
        if math.prod(periods) >= n:
            return periods
        base += 1


def crt(residues: np.ndarray, periods: list[int]) -> np.ndarray:
    """Chinese remainder theorem: the unique i in [0, Π p_k) with i ≡ residues[:, k] (mod p_k).

    Parameters
    ----------
    residues : ndarray of shape (n, K), int
    periods : list of K pairwise co-prime ints

    Returns
    -------
    ndarray of shape (n,), int64
    """
    total = math.prod(periods)
    out = np.zeros(residues.shape[0], dtype=object)  # exact big-int arithmetic for large products
    for k, p in enumerate(periods):
        rest = total // p
        out = out + residues[:, k].astype(object) * rest * pow(rest, -1, p)
    return np.asarray(out % total, dtype=np.int64)


class RYTHLocalizer(PlaceLocalizer):
    """Rhythmic representation localizer (RYTH), with the same storage accounting as BTEL.

    Parameters
    ----------
    n_periods : int
        K, the number of co-prime periods (classifiers), 1 … 16.
    classifier : {'svm', 'logistic'}
        Linear SVM (squared hinge) or logistic regression, as in :class:`btel.BTELocalizer`.
    solver : {'auto', 'newton', 'lbfgs', 'liblinear'}
        As in :class:`btel.BTELocalizer`. A period's p one-vs-rest classifiers share their columns,
        so they are solved together on one standardised copy.
    C : float, optional
        Regularisation, as in :class:`btel.BTELocalizer`.
    feature_ratio : float in (0, 1], optional
        c = d'/d (default 0.1 without a budget; as large as fits under one).
    n_features : int, optional
        d' directly.
    sparsity : float
        W–T L1 bound for the feature selection.
    budget : int or str, optional
        Bytes; fit picks the largest d' that fits, else raises BudgetTooSmallError.
    dtype : {'float32', 'float16'}
        Stored weight dtype.
    decode : {'soft', 'crt'}
        Residue scores → place: the soft decode over every place, or the Chinese remainder theorem
        on each period's best residue.
    max_iter, n_jobs, random_state
        As in :class:`btel.BTELocalizer` (max_iter None: the solver's default cap; classifiers that
        stop at it are counted in ``n_unconverged_`` and reported by one ``ConvergenceWarning``).
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).

    Attributes
    ----------
    periods_ : list of int
    n_places_, n_features_in_, n_selected_ : int
    hyperplanes_ : Hyperplanes
        Σ p_k rows (one for a period of 2), period by period, class order within a period.
    front_end_ : FrontEnd
    """

    label = "ryth"
    _linear_in_queries = True  # queries are only multiplied by hyperplanes (see btel.core.frontend.ScaledRows)
    _parameter_constraints = {
        "n_periods": [Interval(int, 1, 16)],
        "classifier": [Options(*CLASSIFIERS)],
        "solver": [Options(*SOLVERS)],
        "C": [None, Interval(float, 0, MAX_C, closed="right")],
        "feature_ratio": [None, Interval(float, 0, 1, closed="right")],
        "n_features": [None, Interval(int, 1, None)],
        "sparsity": [Interval(float, 0, None, closed="neither")],
        "dtype": [DType("float32", "float16")],
        "decode": [Options("soft", "crt")],
        "max_iter": [None, Interval(int, 1, 2**31 - 1)],  # None: the solver's own cap; liblinear takes a C int
        "n_jobs": N_JOBS,
        "random_state": RANDOM_STATE,
    }
    _runtime_params = ("n_jobs",)

    def __init__(
        self,
        *,
        n_periods: int = 3,
        classifier: str = "svm",
        solver: str = "auto",
        C: float | None = None,
        feature_ratio: float | None = None,
        n_features: int | None = None,
        sparsity: float = 0.1,
        budget: int | str | None = None,
        dtype: str = "float32",
        decode: str = "soft",
        max_iter: int | None = None,
        n_jobs: int | None = None,
        random_state: int | None = 0,
    ) -> None:
        self.n_periods = n_periods
        self.classifier = classifier
        self.solver = solver
        self.C = C
        self.feature_ratio = feature_ratio
        self.n_features = n_features
        self.sparsity = sparsity
        self.budget = budget
        self.dtype = dtype
        self.decode = decode
        self.max_iter = max_iter
        self.n_jobs = n_jobs
        self.random_state = random_state

    @staticmethod
    def planned_bytes(n_rows: int, n_features: int, *, periods: list[int], n_selected: int,
                      dtype: str = "float32") -> int:
        """Bytes for these periods and d' = ``n_selected`` of ``n_features`` columns: the sum of
        :func:`ryth_specs` (the ``n_rows`` places enter through the periods)."""
        return int(sum(s.nbytes for s in ryth_specs(periods, n_selected, n_features, dtype).values()))

    def _cap(self, d: int, budget: int | None) -> int:
        """The most descriptor columns the parameters allow (the budget may select fewer)."""
        if self.n_features is not None:
            return min(int(self.n_features), d)
        ratio = self.feature_ratio if self.feature_ratio is not None else (None if budget else 0.1)
        return d if ratio is None else int(min(d, max(1, round(ratio * d))))

    def _plan(self, n_places: int, d: int, budget: int | None, reserved: int) -> tuple[list[int], int]:
        """The periods and d' ``fit`` uses: the most columns (up to :meth:`_cap`) that fit the budget."""
        periods = coprime_periods(n_places, self.n_periods)
        if max(periods) > n_places:  # a residue class with no place cannot be learnt
            raise NotEnoughPlacesError(
                f"RYTH with K = {self.n_periods} co-prime periods {periods} needs N ≥ {max(periods)} places (every "
                f"residue class must hold one); got N = {n_places}. Use fewer periods (n_periods) or a longer route."
            )
        dtype = np.dtype(self.dtype).name
        cap = self._cap(d, budget)
        if budget is None:
            return periods, cap
        def planned(m: int) -> int:
            return self.planned_bytes(n_places, d, periods=periods, n_selected=m, dtype=dtype) + reserved

        n_selected = next((m for m in range(cap, 0, -1) if planned(m) <= budget), 0)
        if n_selected == 0:
            minimum = planned(1)
            raise BudgetTooSmallError(
                f"budget {exact_bytes(budget)} is too small for RYTH with periods {periods}: "
                f"the smallest model (d' = 1) needs {minimum} B. Raise the budget or use fewer periods.",
                budget=budget, minimum=minimum,
            )
        return periods, n_selected

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self._plan(n_rows, n_features_out, budget, reserved)

    def budget_saturated(self) -> bool:
        """d' reached the parameters' cap, so a larger budget gives the same model."""
        if not hasattr(self, "n_selected_"):
            return False
        d = self.front_end_.n_features_out(int(self.n_features_in_))
        return int(self.n_selected_) == self._cap(d, budget_of(self))

    def _fit(self, X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
             reserved: int) -> None:
        """Fit the K residue classifiers on the (front-end) map."""
        C = default_C(self.classifier) if self.C is None else float(self.C)
        places_arr = np.arange(n_places, dtype=np.int64) if places is None else places
        d = X.shape[1]
        periods, n_selected = self._plan(n_places, d, budget, reserved)
        dtype = np.dtype(self.dtype).name
        stats = ColumnStats.of(X)
        tasks = []
        for p in periods:
            tasks.extend(one_vs_rest_tasks(X, places_arr % p, p, n_selected, stats, sparsity=float(self.sparsity)))
        parts, summary = fit_tasks(
            X, tasks, n_selected, stats, sparsity=float(self.sparsity), n_jobs=self.n_jobs,
            classifier=self.classifier, C=C, solver=self.solver,
            max_iter=None if self.max_iter is None else int(self.max_iter), random_state=self.random_state,
            dtype=np.dtype(dtype),
        )
        convergence_warning(summary, "RYTHLocalizer.fit", self.max_iter)
        # Period 2 is a single hyperplane (positive = residue 1); store it as the two-class scores
        # (−m, m) at inference, so every period reads p rows' worth of scores.
        index_dtype = None if n_selected >= d else column_index_dtype(d)
        groups, first = [], 0
        for p in periods:
            count = 1 if p == 2 else p
            groups.append(Hyperplanes.stack(parts[first:first + count], d, n_selected, np.dtype(dtype), index_dtype,
                                            shared_columns=True))
            first += count
        self.hyperplanes_ = Hyperplanes(
            weights=np.concatenate([g.weights for g in groups]),
            bias=np.concatenate([g.bias for g in groups]),
            columns=None if index_dtype is None else np.concatenate([g.columns for g in groups]),
            n_features_in=d,
        )
        self.periods_ = periods
        self.n_selected_ = int(n_selected)
        self.n_unconverged_ = int(summary.n_unconverged)
        self.fit_summary_ = summary
        self._expanded_cache = None

    # The column sets are one row per period; expand them to one per hyperplane for the margins.
    def _expanded(self) -> Hyperplanes:
        if getattr(self, "_expanded_cache", None) is None:
            h = self.hyperplanes_
            columns = None
            if h.columns is not None:
                counts = [1 if p == 2 else p for p in self.periods_]
                columns = np.repeat(h.columns, counts, axis=0)
            self._expanded_cache = Hyperplanes(h.weights, h.bias, columns, h.n_features_in)
        return self._expanded_cache

    def decision_function(self, Q: Any) -> np.ndarray:
        """Scores of every residue class, period by period.

        Returns
        -------
        ndarray of shape (n_queries, Σ p_k), float32
        """
        return self._residue_scores(self._check_queries(Q))

    def _residue_scores(self, Q: np.ndarray) -> np.ndarray:
        margins = self._expanded().margins(Q)
        out, col = [], 0
        for p in self.periods_:
            if p == 2:
                out.extend([-margins[:, col : col + 1], margins[:, col : col + 1]])
                col += 1
            else:
                out.append(margins[:, col : col + p])
                col += p
        return np.hstack(out).astype(np.float32)

    def _summed(self, scores: np.ndarray) -> np.ndarray:
        """Soft-decode score ``Σ_k score_k[i mod p_k]`` of every place (n_queries, N), float64."""
        places = np.arange(self.n_places_)
        offsets = np.concatenate([[0], np.cumsum(self.periods_)[:-1]])
        return sum(scores[:, off + places % p].astype(np.float64) for off, p in zip(offsets, self.periods_))

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        return self._summed(self._residue_scores(Q))

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The decode first (soft, or CRT when it gives a valid place), then the rest by summed score."""
        from .base import put_first, top_k

        n = int(self.n_places_)
        rows = max(1, (1 << 22) // n)
        values = np.empty((Q.shape[0], k))
        places = np.empty((Q.shape[0], k), dtype=np.int64)
        for start in range(0, Q.shape[0], rows):
            stop = min(start + rows, Q.shape[0])
            scores = self._residue_scores(Q[start:stop])
            total = self._summed(scores)
            best = np.argmax(total, axis=1)
            if self.decode == "crt":  # the CRT answer when it is a valid place, else the soft one
                offsets = np.concatenate([[0], np.cumsum(self.periods_)[:-1]])
                residues = np.stack([np.argmax(scores[:, o : o + p], axis=1)
                                     for o, p in zip(offsets, self.periods_)], axis=1)
                exact = crt(residues, self.periods_)
                best = np.where(exact < n, exact, best)
            best_value = np.take_along_axis(total, best[:, None], axis=1)[:, 0]
            if k == 1:
                values[start:stop, 0], places[start:stop, 0] = best_value, best
            else:
                values[start:stop], places[start:stop] = put_first(*top_k(total, k), best_value, best)
        return values, places

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return self.hyperplanes_.arrays("")

    #: The state key holding what the fit chose for a parameter of another name (``chosen_at_fit``).
    _STATE_OF_PARAM = {"n_features": "n_selected"}

    def _fitted_state(self) -> dict[str, Any]:
        return {"n_selected": self.n_selected_, "periods": list(self.periods_)}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        n_places = int(state["n_places"])
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        n_selected = read_state_int(state, "n_selected", 1, d)
        periods = coprime_periods(n_places, self.n_periods)
        if state.get("periods") != periods:
            raise ModelFileError(f"the RYTH model file's periods {str(state.get('periods'))[:60]} are not the "
                                 f"co-prime periods {periods} of N = {n_places}, K = {self.n_periods}.")
        return ryth_specs(periods, n_selected, d, np.dtype(self.dtype).name)

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        d = self.front_end_.n_features_out(int(state["n_features_in"]))
        self.hyperplanes_ = Hyperplanes.from_arrays(arrays, "", d)
        self.periods_ = [int(p) for p in state["periods"]]
        self.n_selected_ = int(state["n_selected"])
        self.n_unconverged_ = 0
        self._expanded_cache = None


def ryth_specs(periods: list[int], n_selected: int, n_features: int, dtype: str = "float32") -> dict[str, ArraySpec]:
    """Arrays of a RYTH model: Σ p_k hyperplanes (one for p = 2), their biases, and K column sets."""
    rows = sum(1 if p == 2 else p for p in periods)
    specs = {"weights": ArraySpec((rows, n_selected), np.dtype(dtype)), "bias": ArraySpec((rows,), np.float32)}
    if n_selected < n_features:
        specs["columns"] = ArraySpec((len(periods), n_selected), column_index_dtype(n_features))
    return specs
