"""BTEL's storage layout and budget planner: one function lists the arrays, the planner sums it.

:func:`array_specs` gives the shape and dtype of every array a BTEL model stores for a given
structure (region sizes, d', d, scheme, weight dtype, code copies). The planner
(:func:`planned_bytes`, :func:`largest_fitting`) adds those up before fitting; a fitted model's
arrays match them exactly (the tests check it) and ``btel.load`` checks a file's arrays against
them. So the storage formula exists once.

Per tree classifier: d' weights + 1 float32 bias + d' column indices (none when d' = d). With
r ≥ 2 regions add the region classifier (1 hyperplane for r = 2, else r, sharing one set of d'
columns) and the r region starts.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..base import ArraySpec
from .compressed import compressed_n_classifiers
from ...exceptions import BudgetTooSmallError
from ...learning.feature_selection import column_index_dtype
from .full import full_n_classifiers
from ...core.storage import exact_bytes

__all__ = ["array_specs", "planned_bytes", "largest_fitting", "tree_sizes", "starts_dtype", "n_tree_classifiers",
           "raise_budget_too_small", "SCHEMES", "WEIGHT_DTYPES"]

SCHEMES = ("compressed", "full")
WEIGHT_DTYPES = ("float32", "float16")


def n_tree_classifiers(scheme: str, n_codes: int, code_copies: int = 1) -> int:
    """Hyperplanes of one tree over ``n_codes`` codes: b (+ offset copies) for BTE-C, one per node for BTE-F."""
    if scheme == "compressed":
        return compressed_n_classifiers(n_codes, code_copies)
    return full_n_classifiers(n_codes)


def starts_dtype(n_codes: int) -> np.dtype:
    """Dtype of the stored region starts: uint16 up to 65 535 codes, else uint32."""
    return np.dtype(np.uint16) if n_codes <= np.iinfo(np.uint16).max else np.dtype(np.uint32)


def tree_sizes(starts: np.ndarray, n_codes: int) -> np.ndarray:
    """Codes per region from the region starts (int64, shape (r,))."""
    return np.diff(np.append(np.asarray(starts, dtype=np.int64), n_codes)).astype(np.int64)


def array_specs(
    region_sizes: Sequence[int] | np.ndarray,
    n_selected: int,
    n_features: int,
    *,
    scheme: str = "compressed",
    dtype: str = "float32",
    code_copies: int = 1,
) -> dict[str, ArraySpec]:
    """Shape and dtype of every array a BTEL model of this structure stores.

    Parameters
    ----------
    region_sizes : sequence of int
        Codes N_k of each region (one entry, the number of codes, when r = 1).
    n_selected : int
        d', columns per classifier.
    n_features : int
        d, the (front-end) descriptor dimension.

    Returns
    -------
    dict of str to ArraySpec
    """
    w = np.dtype(dtype)
    k = sum(n_tree_classifiers(scheme, int(n), code_copies) for n in region_sizes)
    specs = {"weights": ArraySpec((k, n_selected), w), "bias": ArraySpec((k,), np.float32)}
    index = column_index_dtype(n_features) if n_selected < n_features else None
    if index is not None:
        # One row when the tree has a single classifier (Hyperplanes.stack stores a lone part's columns once).
        specs["columns"] = ArraySpec((k, n_selected), index)
    r = len(region_sizes)
    if r >= 2:
        planes = 1 if r == 2 else r
        specs["region_weights"] = ArraySpec((planes, n_selected), w)
        specs["region_bias"] = ArraySpec((planes,), np.float32)
        if index is not None:
            specs["region_columns"] = ArraySpec((1, n_selected), index)
        specs["region_starts"] = ArraySpec((r,), starts_dtype(int(np.sum(region_sizes))))
    return specs


def planned_bytes(
    n_rows: int,
    n_features: int,
    *,
    n_selected: int,
    region_sizes: Sequence[int] | np.ndarray | None = None,
    scheme: str = "compressed",
    dtype: str = "float32",
    code_copies: int = 1,
) -> int:
    """Bytes a BTEL model will store, computed before fitting: the sum of :func:`array_specs`.

    ``n_rows`` places (or blocks) indexed over ``n_features`` descriptor dimensions, ``n_selected``
    of them kept; ``region_sizes`` (summing to ``n_rows``) splits them into regions (default: one).
    """
    sizes = [int(n_rows)] if region_sizes is None else [int(s) for s in region_sizes]
    if sum(sizes) != n_rows:
        raise ValueError(f"region sizes {sizes} do not add up to n_rows = {n_rows}.")
    return int(sum(spec.nbytes for spec in array_specs(sizes, n_selected, n_features, scheme=scheme,
                                                       dtype=dtype, code_copies=code_copies).values()))


def largest_fitting(sizes: Sequence[int], d: int, cap: int, budget: int, scheme: str, dtype: str,
                    code_copies: int = 1) -> int:
    """Largest d' ≤ cap whose planned bytes fit the budget (0 when even d' = 1 does not)."""
    kw = dict(region_sizes=sizes, scheme=scheme, dtype=dtype, code_copies=code_copies)
    n = int(sum(sizes))
    if planned_bytes(n, d, n_selected=cap, **kw) <= budget:
        return cap
    # Below d the bytes are affine in d': solve, then step down past rounding.
    b1 = planned_bytes(n, d, n_selected=1, **kw)
    slope = planned_bytes(n, d, n_selected=2, **kw) - b1 if d > 2 else b1
    guess = min(cap, d - 1, 1 + (budget - b1) // max(slope, 1)) if budget >= b1 else 0
    while guess >= 1 and planned_bytes(n, d, n_selected=guess, **kw) > budget:
        guess -= 1
    return int(max(guess, 0))


def raise_budget_too_small(what: str, budget: int, minimum: int, advice: str) -> None:
    """Raise :class:`BudgetTooSmallError` naming the smallest model's bytes."""
    raise BudgetTooSmallError(
        f"budget {exact_bytes(budget)} is too small for {what}: the smallest model (d' = 1) "
        f"needs {minimum} B. {advice}",
        budget=budget,
        minimum=minimum,
    )
