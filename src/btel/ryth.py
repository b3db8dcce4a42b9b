"""RYTH (Yu, Jacobson & Milford 2018): place index by its residues modulo co-prime periods (SPEC §8).

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
import numbers
import time
from typing import Any

import numpy as np

from ._validation import check_descriptors, check_places, check_positive_int
from .base import PlaceLocalizer, register_model
from .exceptions import BudgetTooSmallError, InvalidParameterError, ModelFileError
from .feature_selection import column_index_dtype
from .linear import CLASSIFIERS, ColumnStats, Hyperplanes, default_C
from .storage import format_bytes, parse_budget
from .training import fit_tasks, one_vs_rest_tasks

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


@register_model
class RYTHLocalizer(PlaceLocalizer):
    """Rhythmic representation localizer (RYTH), with the same storage accounting as BTEL.

    Parameters
    ----------
    n_periods : int
        K, the number of co-prime periods (classifiers).
    classifier : {'svm', 'logistic'}
    C : float, optional
    feature_ratio : float in (0, 1], optional
        c = d'/d (default 0.1 without a budget; as large as fits under one).
    n_features : int, optional
        d' directly.
    sparsity : float
        W–T L1 bound for the feature selection.
    budget : int or str, optional
        Bytes; fit picks the largest d' that fits, else raises BudgetTooSmallError.
    dtype : {'float32', 'float16'}
    decode : {'soft', 'crt'}
    max_iter, n_jobs, random_state
        As in :class:`btel.BTELocalizer`.

    Attributes
    ----------
    periods_ : list of int
    n_places_, n_features_in_, n_selected_ : int
    hyperplanes_ : Hyperplanes
        Σ p_k rows, period by period, class order within a period.
    """

    supports_ranking = True

    def __init__(
        self,
        *,
        n_periods: int = 3,
        classifier: str = "svm",
        C: float | None = None,
        feature_ratio: float | None = None,
        n_features: int | None = None,
        sparsity: float = 0.1,
        budget: int | str | None = None,
        dtype: str = "float32",
        decode: str = "soft",
        max_iter: int = 1000,
        n_jobs: int | None = None,
        random_state: int | None = None,
    ) -> None:
        self.n_periods = n_periods
        self.classifier = classifier
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
    def planned_bytes(periods: list[int], n_selected: int, n_features_in: int, dtype: str = "float32") -> int:
        """Bytes for these periods and d': Σ p_k·(d'·w + 4) + K·d' column indices (none when d' = d)."""
        w = np.dtype(dtype).itemsize
        idx = 0 if n_selected >= n_features_in else column_index_dtype(n_features_in).itemsize
        return int(sum(periods) * (n_selected * w + 4) + len(periods) * n_selected * idx)

    def fit(self, X: Any, places: Any = None) -> "RYTHLocalizer":
        """Fit the K residue classifiers on map descriptors (row i = place i unless ``places``)."""
        start_time = time.perf_counter()
        if self.classifier not in CLASSIFIERS:
            raise InvalidParameterError(f"classifier must be one of {CLASSIFIERS}; got {self.classifier!r}.")
        if self.decode not in ("soft", "crt"):
            raise InvalidParameterError(f"decode must be 'soft' or 'crt'; got {self.decode!r}.")
        if np.dtype(self.dtype).name not in ("float32", "float16"):
            raise InvalidParameterError(f"dtype must be 'float32' or 'float16'; got {self.dtype!r}.")
        if self.feature_ratio is not None and not (isinstance(self.feature_ratio, numbers.Real) and 0 < self.feature_ratio <= 1):
            raise InvalidParameterError(f"feature_ratio must be in (0, 1]; got {self.feature_ratio!r}.")
        C = default_C(self.classifier) if self.C is None else float(self.C)
        if not C > 0:
            raise InvalidParameterError(f"C must be positive; got {self.C!r}.")
        X = check_descriptors(X, name="X", min_rows=2)
        if places is None:
            places_arr, n_places = np.arange(X.shape[0], dtype=np.int64), X.shape[0]
        else:
            places_arr, n_places = check_places(places, X.shape[0])
        d = X.shape[1]
        periods = coprime_periods(n_places, self.n_periods)
        budget = parse_budget(self.budget)
        dtype = np.dtype(self.dtype).name
        if self.n_features is not None:
            cap = min(check_positive_int(self.n_features, "n_features"), d)
        else:
            ratio = self.feature_ratio if self.feature_ratio is not None else (None if budget else 0.1)
            cap = d if ratio is None else int(min(d, max(1, round(ratio * d))))
        n_selected = cap
        if budget is not None:
            n_selected = next((m for m in range(cap, 0, -1)
                               if self.planned_bytes(periods, m, d, dtype) <= budget), 0)
            if n_selected == 0:
                minimum = self.planned_bytes(periods, 1, d, dtype)
                raise BudgetTooSmallError(
                    f"budget {format_bytes(budget)} ({budget} B) is too small for RYTH with periods {periods}: "
                    f"the smallest model (d' = 1) needs {minimum} B. Raise the budget or use fewer periods.",
                    budget=budget, minimum=minimum,
                )
        stats = ColumnStats.of(X)
        tasks = []
        for p in periods:
            tasks.extend(one_vs_rest_tasks(X, places_arr % p, p, n_selected, stats, sparsity=float(self.sparsity)))
        parts, n_unconverged = fit_tasks(
            X, tasks, n_selected, stats, sparsity=float(self.sparsity), n_jobs=self.n_jobs,
            classifier=self.classifier, C=C, max_iter=int(self.max_iter), random_state=self.random_state,
            dtype=np.dtype(dtype),
        )
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
        self.n_places_ = int(n_places)
        self.n_features_in_ = int(d)
        self.n_selected_ = int(n_selected)
        self.n_unconverged_ = int(n_unconverged)
        self.fit_time_ = time.perf_counter() - start_time
        return self

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
        margins = self._expanded().margins(self._check_queries(Q))
        out, col = [], 0
        for p in self.periods_:
            if p == 2:
                out.extend([-margins[:, col : col + 1], margins[:, col : col + 1]])
                col += 1
            else:
                out.append(margins[:, col : col + p])
                col += p
        return np.hstack(out).astype(np.float32)

    def _place_scores(self, scores: np.ndarray, chunk: int = 2048):
        places = np.arange(self.n_places_)
        offsets = np.concatenate([[0], np.cumsum(self.periods_)[:-1]])
        columns = [off + places % p for off, p in zip(offsets, self.periods_)]
        for start in range(0, scores.shape[0], chunk):
            block = scores[start : start + chunk]
            yield start, sum(block[:, c] for c in columns)

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """The k places with the highest summed residue scores, best first (int64, (n_queries, k))."""
        k = min(check_positive_int(k, "k"), self.n_places_ if hasattr(self, "n_places_") else k)
        scores = self.decision_function(Q)
        out = np.empty((scores.shape[0], k), dtype=np.int64)
        for start, total in self._place_scores(scores):
            top = np.argpartition(-total, k - 1, axis=1)[:, :k]
            order = np.argsort(-np.take_along_axis(total, top, axis=1), axis=1, kind="stable")
            out[start : start + total.shape[0]] = np.take_along_axis(top, order, axis=1)
        return out

    def predict(self, Q: Any) -> np.ndarray:
        """Place index of each query (int64, shape (n_queries,), values in [0, N))."""
        scores = self.decision_function(Q)
        soft = np.empty(scores.shape[0], dtype=np.int64)
        for start, total in self._place_scores(scores):
            soft[start : start + total.shape[0]] = np.argmax(total, axis=1)
        if self.decode == "soft":
            return soft
        offsets = np.concatenate([[0], np.cumsum(self.periods_)[:-1]])
        residues = np.stack([np.argmax(scores[:, o : o + p], axis=1) for o, p in zip(offsets, self.periods_)], axis=1)
        exact = crt(residues, self.periods_)
        return np.where(exact < self.n_places_, exact, soft)

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return self.hyperplanes_.arrays("")

    def _fitted_state(self) -> dict[str, Any]:
        return {"n_places": self.n_places_, "n_features_in": self.n_features_in_, "n_selected": self.n_selected_,
                "periods": list(self.periods_), "fit_time": self.fit_time_}

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        periods = [int(p) for p in state["periods"]]
        d, n_selected = int(state["n_features_in"]), int(state["n_selected"])
        rows = sum(1 if p == 2 else p for p in periods)
        if arrays["weights"].shape != (rows, n_selected):
            raise ModelFileError(f"RYTH model file holds weights of shape {arrays['weights'].shape}; "
                                 f"periods {periods} and d' = {n_selected} need ({rows}, {n_selected}).")
        self.hyperplanes_ = Hyperplanes(arrays["weights"], arrays["bias"], arrays.get("columns"), d)
        self.periods_ = periods
        self.n_places_ = int(state["n_places"])
        self.n_features_in_ = d
        self.n_selected_ = n_selected
        self.n_unconverged_ = 0
        self.fit_time_ = float(state.get("fit_time", float("nan")))
