"""Ranked output of BTEL: the K most likely places from the bit margins, best first (R@K).

A query's bit margins ``m`` (shape (b,), positive = bit 1) score every code i by the soft score
``S(i) = Σ_k m_k·(2·bit_k(i) − 1)`` (the paper's encoding). The hard code (every bit at the sign of its margin)
scores ``Σ_k |m_k|``, and flipping bit k costs ``2|m_k|``, so

    S(i) = Σ_k |m_k| − cost(i),   cost(i) = Σ_{k flipped in i} 2|m_k|.

Ranking by S is ranking by flip cost. :func:`kbest_codes` enumerates codes in increasing cost
without touching the N − K others: sort the ``2|m_k|`` ascending (``a_1 ≤ … ≤ a_b``) and walk the
subsets of flipped bits with a heap — from a subset whose largest sorted position is j, the two
successors are "also flip j+1" and "flip j+1 instead of j" (the classic k-best subsets
enumeration). Every subset is reached exactly once, each successor costs at least as much as its
parent, so the pops come out in non-decreasing cost. Codes ≥ N are skipped. Per query it costs
O((K + s)·log(K + s)) with s ≤ 2^b − N invalid codes skipped, against O(N·b) for sorting every
soft score (:func:`soft_scores`, the brute-force reference the tests compare with).

With regions (the paper's regions) a place i in region k has the cost

    cost(i) = flip cost of its local code in region k's tree + α·(s_max − s_k),

where s_k is the region classifier's score of region k, s_max the best region's score (its
predicted region) and α the region weight. For r = 2 the one hyperplane h gives the scores
(−h, +h), so the other region's deficit is 2|h|: exactly the flip cost of one more bit, as if the
region classifier were the tree's top bit. :func:`merge_region_kbest` merges the per-region k-best
lists of the ``n_regions_searched`` best regions (more when those hold fewer than K places);
:func:`code_costs` gives every code's cost, the brute-force reference of that rule.

These functions read arrays only (margins, region deficits, the trees' layout); the localizer
(:mod:`btel.methods.btel.localizer`) calls them with its own.
"""

from __future__ import annotations

import heapq
import numbers
from typing import Any

import numpy as np

from ...core.validation import check_positive_int
from .encoding import _check_margins as _check_decode_margins
from .compressed import code_scores
from .encoding import index_scores
from ...exceptions import InvalidParameterError

__all__ = ["kbest_codes", "soft_scores", "deficits_from_scores", "code_costs", "merge_region_kbest"]


def _check_margins(margins: Any, n_places: int) -> tuple[np.ndarray, int, int]:
    m, n = _check_decode_margins(margins, n_places)  # the decoders' shape and N checks
    if not np.isfinite(m).all():
        raise InvalidParameterError(
            "margins contain NaN or infinite values: the model's weights are out of range for these descriptors "
            "(a damaged or foreign model file, or queries on another scale than the map). Refit the model or "
            "check the file with `btel info`."
        )
    return m, n, m.shape[1]


def _kbest_one(margins: list[float], n_places: int, k: int) -> tuple[list[int], list[float]]:
    """The ``k`` lowest-cost valid codes of one query's margins (MSB first), with their costs."""
    b = len(margins)
    hard = 0
    for value in margins:
        hard = (hard << 1) | (value > 0)
    flip = [2.0 * abs(v) for v in margins]
    order = sorted(range(b), key=lambda p: (flip[p], p))
    a = [flip[p] for p in order]
    masks = [1 << (b - 1 - p) for p in order]  # position p (0 = MSB) is bit value 2^(b−1−p)
    codes: list[int] = []
    costs: list[float] = []
    if hard < n_places:
        codes.append(hard)
        costs.append(0.0)
    # Heap entries: (cost, last sorted position j, xor mask of the flipped bits).
    heap = [(a[0], 0, masks[0])]
    while heap and len(codes) < k:
        cost, j, xor = heapq.heappop(heap)
        code = hard ^ xor
        if code < n_places:
            codes.append(code)
            costs.append(cost)
        if j + 1 < b:
            heapq.heappush(heap, (cost + a[j + 1], j + 1, xor ^ masks[j + 1]))
            heapq.heappush(heap, (cost - a[j] + a[j + 1], j + 1, xor ^ masks[j] ^ masks[j + 1]))
    return codes, costs


def kbest_codes(margins: Any, n_places: int, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` valid indices (< N) with the highest soft score per query, best first.

    Parameters
    ----------
    margins : array-like of shape (n_queries, b)
        Bit margins, MSB first (``BTELocalizer.decision_function`` with r = 1); b = ⌈log2 N⌉.
    n_places : int
        N (≥ 2).
    k : int
        Candidates per query; capped at N.

    Returns
    -------
    indices : ndarray of shape (n_queries, min(k, N)), int64
        Distinct indices in [0, N), in non-decreasing flip cost (= non-increasing soft score).
    costs : ndarray of shape (n_queries, min(k, N)), float64
        Flip cost ``Σ_{flipped} 2|m_k|`` of each; the soft score is ``Σ|m| − cost``.
    """
    m, n, _ = _check_margins(margins, n_places)
    k = min(check_positive_int(k, "k"), n)
    indices = np.empty((m.shape[0], k), dtype=np.int64)
    costs = np.empty((m.shape[0], k), dtype=np.float64)
    for q, row in enumerate(m.tolist()):
        codes, cost = _kbest_one(row, n, k)
        indices[q], costs[q] = codes, cost
    return indices, costs


def soft_scores(margins: Any, n_places: int) -> np.ndarray:
    """Soft score ``Σ_k m_k (2·bit_k(i) − 1)`` of every valid index: O(N·b) per query.

    Returns
    -------
    ndarray of shape (n_queries, N), float64
    """
    m, n, _ = _check_margins(margins, n_places)
    return index_scores(m, n)


# -- several trees (regions) ----------------------------------------------------------------------
def deficits_from_scores(region_scores: np.ndarray | None, n_regions: int, n_queries: int) -> np.ndarray:
    """``s_max − s_k`` of every region from the region classifier's margins (zeros when r = 1).

    r = 2 reads the one hyperplane h as the scores (−h, +h); r > 2 the one-vs-rest scores.

    Parameters
    ----------
    region_scores : ndarray of shape (n_queries, 1 or r), or None when r = 1

    Returns
    -------
    ndarray of shape (n_queries, r), float64, ≥ 0, 0 at the predicted region
    """
    if n_regions == 1 or region_scores is None:
        return np.zeros((n_queries, 1))
    s = np.asarray(region_scores, dtype=np.float64)
    if n_regions == 2:
        s = np.concatenate([-s, s], axis=1)
    return s.max(axis=1, keepdims=True) - s


def _tree_costs(m: np.ndarray, n_k: int, copies: int) -> np.ndarray:
    """Flip cost ``Σ|m| − Σ m·sign`` of every code of one tree (all its columns), (n, n_k)."""
    if n_k == 1:  # a one-code region has no bits: its one code costs nothing in the tree
        return np.zeros((m.shape[0], 1))
    scores = soft_scores(m, n_k) if copies == 1 else code_scores(np.asarray(m, dtype=np.float64), n_k, copies)
    # In place: at N = 8·10⁶ places each (n, N) float64 temporary is 64 MB a query.
    return np.subtract(np.abs(m).sum(axis=1, keepdims=True), scores, out=scores)


def _check_weight(region_weight: Any) -> float:
    if isinstance(region_weight, bool) or not isinstance(region_weight, numbers.Real) \
            or not np.isfinite(region_weight) or region_weight < 0:
        raise InvalidParameterError(f"region_weight must be a finite number ≥ 0; got {region_weight!r}.")
    return float(region_weight)


def code_costs(margins: np.ndarray, deficits: np.ndarray, starts: np.ndarray, sizes: np.ndarray,
               offsets: np.ndarray, *, code_copies: int = 1, region_weight: float = 1.0) -> np.ndarray:
    """Cost of every code (lower = more likely) under several trees: the rule of :func:`merge_region_kbest`.

    O(N·b) per query.

    Parameters
    ----------
    margins : ndarray of shape (n_queries, K)
        Every tree's column margins side by side (region k's are ``offsets[k]:offsets[k+1]``).
    deficits : ndarray of shape (n_queries, r)
        :func:`deficits_from_scores`.
    starts, sizes : ndarray of shape (r,), int
        First code and number of codes of each region.
    offsets : ndarray of shape (r + 1,), int

    Returns
    -------
    ndarray of shape (n_queries, Σ sizes), float64, ≥ 0
    """
    alpha = _check_weight(region_weight)
    if len(sizes) == 1:  # one tree: its costs are the result (no second (n, N) array)
        tree = _tree_costs(margins[:, offsets[0] : offsets[1]], int(np.asarray(sizes)[0]), code_copies)
        tree += alpha * deficits[:, :1]
        return tree
    out = np.empty((margins.shape[0], int(np.sum(sizes))))
    for k, (s, n_k) in enumerate(zip(np.asarray(starts).tolist(), np.asarray(sizes).tolist())):
        tree = _tree_costs(margins[:, offsets[k] : offsets[k + 1]], n_k, code_copies)
        np.add(tree, alpha * deficits[:, k : k + 1], out=out[:, s : s + n_k])
    return out


def merge_region_kbest(margins: np.ndarray, deficits: np.ndarray, starts: np.ndarray, sizes: np.ndarray,
                       offsets: np.ndarray, k: int, *, n_regions_searched: int = 1,
                       region_weight: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` lowest-cost codes per query over several plain-bit trees, best first.

    Within a region the candidates come from :func:`kbest_codes` on that region's tree. Across
    regions, the ``n_regions_searched`` best regions by region score are searched (more, in
    order of score, while they hold fewer than ``k`` codes), and candidates are merged by
    ``cost = flip cost + region_weight·(s_max − s_k)`` (module docstring). With r = 1 this is
    :func:`kbest_codes`.

    Returns
    -------
    codes : ndarray of shape (n_queries, min(k, N)), int64
        Distinct codes, best first.
    costs : ndarray of shape (n_queries, min(k, N)), float64
        Non-decreasing along each row; equal to :func:`code_costs` at those codes.
    """
    alpha = _check_weight(region_weight)
    searched = check_positive_int(n_regions_searched, "n_regions_searched")
    n = int(np.sum(sizes))
    k = min(check_positive_int(k, "k"), n)
    codes = np.empty((margins.shape[0], k), dtype=np.int64)
    costs = np.empty((margins.shape[0], k))
    region_order = np.argsort(deficits, axis=1, kind="stable")
    for q in range(margins.shape[0]):
        cand_codes: list[int] = []
        cand_costs: list[float] = []
        held = 0
        for rank_r, reg in enumerate(region_order[q].tolist()):
            if rank_r >= searched and held >= k:
                break
            n_k = int(sizes[reg])
            offset = alpha * float(deficits[q, reg])
            if n_k == 1:
                local, local_cost = [0], [0.0]
            else:
                local, local_cost = _kbest_one(margins[q, offsets[reg] : offsets[reg + 1]].tolist(), n_k, k)
            cand_codes.extend(int(starts[reg]) + i for i in local)
            cand_costs.extend(c + offset for c in local_cost)
            held += min(n_k, k)
        order = np.argsort(np.asarray(cand_costs), kind="stable")[:k]
        codes[q] = np.asarray(cand_codes, dtype=np.int64)[order]
        costs[q] = np.asarray(cand_costs)[order]
    return codes, costs
