"""Iterative quantisation (Gong & Lazebnik 2011): binary codes searched by Hamming distance (the paper's baselines).

Fit: centre the map descriptors, project them on their top b principal directions, then learn an
orthogonal b×b rotation that minimises the quantisation error to the binary hypercube (faiss
``ITQMatrix``, 50 iterations). The PCA directions and the rotation are folded into one d×b
matrix. Code of a descriptor x: the b signs of ``(x − mean) @ projection``, packed 8 to a byte.
Query: its code, then an exact linear scan over the map codes by Hamming distance
(faiss ``IndexBinaryFlat``).

Unlike faiss' ``ITQTransform``, descriptors are not L2-normalised before the PCA (the original
ITQ does not; the signs at inference are the same either way), and the PCA is scikit-learn's
rather than faiss' full d×d eigendecomposition (minutes at d = 3780).

Storage: codes ``n_rows × b/8`` bytes, projection d×b float32, mean d float32.
Budget rule: b is the largest multiple of 8 with b ≤ min(d, number of map rows) whose bytes fit
(the most code bits). Without a budget: b = min(256, that bound). ``code_bits`` pins b.
"""

from __future__ import annotations

from typing import Any

import faiss
import numpy as np

from ...core.storage import UNLIMITED_BUDGET, spent_text
from ...core.validation import N_JOBS, RANDOM_STATE, Interval, check_positive_int, read_state_int
from ..base import ArraySpec
from ...exceptions import InvalidParameterError, ModelFileError, NotEnoughPlacesError
from ._common import _RowLocalizer, index_search, negated_distances, quiet_faiss, raise_budget_too_small
from .pq import check_finite, pca_projection

__all__ = ["ITQLocalizer"]

#: Without a budget, codes have at most this many bits.
DEFAULT_CODE_BITS = 256


class ITQLocalizer(_RowLocalizer):
    """PCA + ITQ rotation to binary codes, nearest code by Hamming distance, under a byte budget.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"500KB"``); ``fit`` uses the longest code (multiple of 8 bits) that fits and
        raises :class:`~btel.exceptions.BudgetTooSmallError` with the minimum (8-bit codes) otherwise.
    code_bits : int, optional
        Code length b, a multiple of 8, at most min(d, number of map rows).
    random_state : int or None
        Seed of the randomized PCA and of ITQ's initial rotation.
    normalize, whiten, delta
        The front end (:mod:`btel.core.frontend`).
    n_jobs : int, optional
        faiss threads for fitting and searching (None: faiss' default, all cores; -1: all cores).

    Attributes
    ----------
    code_bits_ : int
    codes_ : ndarray of shape (n_rows, code_bits_ // 8), uint8
    projection_ : ndarray of shape (n_features, code_bits_), float32
    mean_ : ndarray of shape (n_features,), float32
    n_places_, n_features_in_ : int
    row_places_ : ndarray of shape (n_rows,) or None
    fit_time_ : float
    """

    label = "itq"
    _min_rows = 8
    _parameter_constraints = {
        "code_bits": [None, Interval(int, 8, None)],
        "random_state": RANDOM_STATE,
        "n_jobs": N_JOBS,
    }

    def __init__(
        self,
        *,
        budget: int | str | None = None,
        code_bits: int | None = None,
        random_state: int | None = 0,
        n_jobs: int | None = None,
    ) -> None:
        self.budget = budget
        self.code_bits = code_bits
        self.random_state = random_state
        self.n_jobs = n_jobs

    @staticmethod
    def planned_bytes(n_rows: int, n_features: int, *, code_bits: int) -> int:
        """Codes (n_rows·b/8) + projection (d·b float32) + mean (d float32)."""
        return n_rows * (code_bits // 8) + (n_features * code_bits + n_features) * 4

    def choose_code_bits(self, n_rows: int, n_features: int, budget: int | None, extra_bytes: int = 0) -> int:
        """The code length ``fit`` uses (see the module docstring for the rule)."""
        largest = (min(n_features, n_rows) // 8) * 8
        if largest < 8:
            raise NotEnoughPlacesError(
                f"ITQ needs descriptors of at least 8 dimensions and at least 8 map rows for 8-bit codes; "
                f"got d = {n_features}, {n_rows} rows. Use the bruteforce method for such small inputs."
            )
        if self.code_bits is not None:
            bits = check_positive_int(self.code_bits, "code_bits", minimum=8)
            if bits % 8 or bits > largest:
                raise InvalidParameterError(
                    f"code_bits={bits} must be a multiple of 8 no larger than min(d, map rows) = "
                    f"{min(n_features, n_rows)}; use code_bits ≤ {largest}."
                )
            options = [bits]
        elif budget is None:
            return min(DEFAULT_CODE_BITS, largest)
        else:
            options = list(range(8, largest + 1, 8))
        if budget is None:
            return options[0]
        fitting = [b for b in options
                   if self.planned_bytes(n_rows, n_features, code_bits=b) + extra_bytes <= budget]
        if not fitting:
            minimum = self.planned_bytes(n_rows, n_features, code_bits=options[0]) + extra_bytes
            detail = f"{options[0]}-bit codes, {n_features}×{options[0]} projection"
            raise_budget_too_small("ITQ", budget, minimum, detail)
        return max(fitting)

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        self.choose_code_bits(n_rows, n_features_out, budget, reserved)

    def budget_saturated(self) -> bool:
        """True when no budget gives longer codes: the planner's choice without a byte limit."""
        if self.budget is None:
            return False
        n_rows, d = self.codes_.shape[0], self.front_end_.n_features_out(int(self.n_features_in_))
        return self.choose_code_bits(n_rows, d, UNLIMITED_BUDGET) == self.code_bits_

    def _fit_rows(self, X: np.ndarray, budget: int | None, reserved: int) -> None:
        n_rows, n_features = X.shape
        bits = self.choose_code_bits(n_rows, n_features, budget, reserved)
        mean = X.mean(axis=0, dtype=np.float64).astype(np.float32)
        pca = pca_projection(X, bits, self.random_state)
        # (X − μ)·P without a centred copy of the map: the copy was as large as the map.
        V = np.ascontiguousarray(X @ pca - mean @ pca, dtype=np.float32)
        itq = faiss.ITQMatrix(bits)
        if self.random_state is not None:
            itq.seed = int(self.random_state)
        with quiet_faiss():
            itq.train(V)
        # faiss applies y = A v with A of shape (b, b); right-multiplied that is A.T.
        rotation = faiss.vector_to_array(itq.A).reshape(bits, bits).T
        self.projection_ = np.ascontiguousarray(pca @ rotation, dtype=np.float32)
        self.mean_ = mean
        self.code_bits_ = bits
        step = max(1, (1 << 22) // max(n_features, 1))  # codes from centred row blocks, as queries are coded
        self.codes_ = np.concatenate([self.encode_centred(X[a : a + step] - mean) for a in range(0, n_rows, step)])
        self._index = self._build_index()

    def encode_centred(self, centred: np.ndarray) -> np.ndarray:
        """Binary codes of mean-subtracted descriptors: (n, b/8) uint8, bit = (projection > 0)."""
        return np.packbits(centred @ self.projection_ > 0, axis=1)

    def _build_index(self) -> faiss.IndexBinaryFlat:
        index = faiss.IndexBinaryFlat(self.code_bits_)
        index.add(np.ascontiguousarray(self.codes_))
        return index

    def _search_rows(self, Q: np.ndarray, k: int,
                     scores: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        dist, rows = index_search(self._index, self.encode_centred(Q - self.mean_), k)
        return negated_distances(dist) if scores else None, rows.astype(np.int64, copy=False)

    def _model_arrays(self) -> dict[str, np.ndarray]:
        return {"codes": self.codes_, "projection": self.projection_, "mean": self.mean_}

    def _model_state(self) -> dict[str, Any]:
        return {"code_bits": self.code_bits_}

    def _model_specs(self, state: dict[str, Any], d: int) -> dict[str, ArraySpec]:
        bits = read_state_int(state, "code_bits", 8, 8 * ((d + 7) // 8))
        if bits % 8:
            raise ModelFileError(f"the ITQ model file's code_bits = {bits} is not a multiple of 8.")
        return {"codes": ArraySpec((None, bits // 8), np.uint8), "projection": ArraySpec((d, bits), np.float32),
                "mean": ArraySpec((d,), np.float32)}

    def _n_rows(self) -> int:
        return int(self.codes_.shape[0])

    def summary(self) -> str:
        """One line: the code bits a row, the projection, the bytes against the budget and the front end."""
        return (f"itq: {self.code_bits_} bits a row (a learnt {self.projection_.shape[0]} × {self.code_bits_} projection, "
                f"Hamming distance); {spent_text(self)}; front end {self.front_end_.describe()}")

    def _restore_model(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        check_finite(arrays, ("projection", "mean"), "ITQ")
        self.code_bits_ = int(state["code_bits"])
        self.codes_, self.projection_, self.mean_ = arrays["codes"], arrays["projection"], arrays["mean"]
        self._index = self._build_index()
