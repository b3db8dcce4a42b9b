"""Ranked output of BTEL: the K most likely places from the bit margins, best first (R@K).

A query's bit margins ``m`` (shape (b,), positive = bit 1) score every code i by the soft score
``S(i) = Σ_k m_k·(2·bit_k(i) − 1)`` (SPEC §2). The hard code (every bit at the sign of its margin)
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

With regions (SPEC §5) a place i in region k has the cost

    cost(i) = flip cost of its local code in region k's tree + α·(s_max − s_k),

where s_k is the region classifier's score of region k, s_max the best region's score (its
predicted region) and α = ``region_weight``. For r = 2 the one hyperplane h gives the scores
(−h, +h), so the other region's deficit is 2|h|: exactly the flip cost of one more bit, as if the
region classifier were the tree's top bit. :func:`rank_places` merges the per-region k-best lists
of the ``n_regions_searched`` best regions (more when those hold fewer than K places);
:func:`place_costs` gives every place's cost, the brute-force reference of that rule and the
emission scores for :mod:`btel.sequence_decoding`.
"""

from __future__ import annotations

import heapq
import numbers
from typing import Any

import numpy as np

from ._validation import check_descriptors, check_is_fitted, check_positive_int
from .encoding import _check_margins as _check_decode_margins
from .encoding import bit_codes
from .exceptions import InvalidParameterError

__all__ = ["kbest_codes", "soft_scores", "tree_layout", "region_deficits", "place_costs", "rank_places"]


def _check_margins(margins: Any, n_places: int) -> tuple[np.ndarray, int, int]:
    m, n = _check_decode_margins(margins, n_places)  # the decoders' shape and N checks
    if not np.isfinite(m).all():
        raise InvalidParameterError("margins contain NaN or infinite values; rank the margins of one tree only.")
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
    return m @ bit_codes(n).astype(np.float64).T


# -- BTEL models ---------------------------------------------------------------------------------
def tree_layout(model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each region's tree lives in a fitted compressed ``BTELocalizer``.

    Returns
    -------
    starts : ndarray of shape (r,), int64
        First global place of each region (``region_starts_``).
    sizes : ndarray of shape (r,), int64
        N_k (``region_sizes_``).
    offsets : ndarray of shape (r + 1,), int64
        Region k's column classifiers are rows ``offsets[k]:offsets[k+1]`` of ``hyperplanes_``
        (b_k = ⌈log2 N_k⌉ bits MSB first, then any offset-code columns).

    Starts and sizes count the trees' codes: blocks of ``block_size_`` places when > 1.
    """
    check_is_fitted(model, "n_places_")
    if getattr(model, "scheme", "compressed") != "compressed":
        raise InvalidParameterError(
            "ranking needs one classifier per bit (scheme='compressed'); BTE-F visits one node per level."
        )
    starts = np.asarray(model.region_starts_, dtype=np.int64)
    sizes = np.asarray(model.region_sizes_, dtype=np.int64)
    return starts, sizes, np.asarray(model._tree_offsets, dtype=np.int64)


def _tree_costs(m: np.ndarray, n_k: int, copies: int) -> np.ndarray:
    """Flip cost ``Σ|m| − Σ m·sign`` of every code of one tree (all its columns), (n, n_k)."""
    if copies == 1:
        return np.abs(m).sum(axis=1, keepdims=True) - soft_scores(m, n_k)
    from .compressed import code_signs

    return np.abs(m).sum(axis=1, keepdims=True) - m @ code_signs(n_k, copies).astype(np.float64).T


def _check_weight(region_weight: Any) -> float:
    if isinstance(region_weight, bool) or not isinstance(region_weight, numbers.Real) \
            or not np.isfinite(region_weight) or region_weight < 0:
        raise InvalidParameterError(f"region_weight must be a finite number ≥ 0; got {region_weight!r}.")
    return float(region_weight)


def region_deficits(model: Any, Q: np.ndarray) -> np.ndarray:
    """``s_max − s_k`` of every region for validated queries (zeros when r = 1).

    r = 2 reads the one hyperplane h as the scores (−h, +h); r > 2 the one-vs-rest scores.

    Returns
    -------
    ndarray of shape (n_queries, r), float64, ≥ 0, 0 at the predicted region
    """
    r = int(model.n_regions_)
    if r == 1:
        return np.zeros((Q.shape[0], 1))
    s = model.region_hyperplanes_.margins(Q).astype(np.float64)
    if r == 2:
        s = np.concatenate([-s, s], axis=1)
    return s.max(axis=1, keepdims=True) - s


def _margins_and_deficits(model: Any, Q: Any) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
    layout = tree_layout(model)
    Q = check_descriptors(Q, name="Q", n_features=model.n_features_in_)
    margins = model.hyperplanes_.margins(Q).astype(np.float64)  # every tree's bits: one product
    return margins, region_deficits(model, Q), layout


def place_costs(model: Any, Q: Any, *, region_weight: float = 1.0) -> np.ndarray:
    """Cost of every place for every query (lower = more likely): the rule of :func:`rank_places`.

    O(N·b) per query. ``-place_costs`` is a per-place score matrix for
    :func:`btel.sequence_decoding.decode_sequence`.

    Parameters
    ----------
    model : BTELocalizer
        Fitted, ``scheme='compressed'``.
    Q : array-like of shape (n_queries, n_features)
    region_weight : float ≥ 0
        α, the weight of the region classifier's score deficit.

    Returns
    -------
    ndarray of shape (n_queries, N), float64, ≥ 0
    """
    alpha = _check_weight(region_weight)
    margins, deficits, (starts, sizes, offsets) = _margins_and_deficits(model, Q)
    out = np.empty((margins.shape[0], int(model.n_codes_)))
    for k, (s, n_k) in enumerate(zip(starts.tolist(), sizes.tolist())):
        m = margins[:, offsets[k] : offsets[k + 1]]
        if n_k == 1:  # a one-place region has no bits: its one place costs nothing in the tree
            tree = np.zeros((m.shape[0], 1))
        else:
            tree = _tree_costs(m, n_k, model.code_copies_)
        out[:, s : s + n_k] = tree + alpha * deficits[:, k : k + 1]
    if model.block_size_ > 1:  # every place costs what its block costs
        out = out[:, np.arange(int(model.n_places_)) // model.block_size_]
    return out


def rank_places(
    model: Any, Q: Any, k: int = 10, *, n_regions_searched: int = 1, region_weight: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` most likely places per query from a fitted compressed BTEL model, best first.

    Within a region the candidates come from :func:`kbest_codes` on that region's tree. Across
    regions, the ``n_regions_searched`` best regions by region score are searched (more, in
    order of score, while they hold fewer than ``k`` places), and candidates are merged by
    ``cost = flip cost + region_weight·(s_max − s_k)`` (module docstring). With r = 1 this is
    :func:`kbest_codes` of ``decision_function``.

    Parameters
    ----------
    model : BTELocalizer
        Fitted with ``scheme='compressed'``.
    Q : array-like of shape (n_queries, n_features)
    k : int
        Candidates per query (capped at N).
    n_regions_searched : int
        Regions searched per query (1: the predicted region only, unless it is smaller than k).
    region_weight : float ≥ 0
        α. 0 ranks purely by tree flip cost across the searched regions.

    Returns
    -------
    places : ndarray of shape (n_queries, min(k, N)), int64
        Distinct places, best first.
    costs : ndarray of shape (n_queries, min(k, N)), float64
        Their costs (non-decreasing along each row); equal to :func:`place_costs` at those places.
    """
    alpha = _check_weight(region_weight)
    searched = check_positive_int(n_regions_searched, "n_regions_searched")
    tree_layout(model)  # fitted, compressed: checked before reading the code options
    if model.code_copies_ > 1:
        # Offset codes: no best-first search over flips of independent bits; rank every code.
        return _rank_by_costs(model, Q, k, alpha)
    margins, deficits, (starts, sizes, offsets) = _margins_and_deficits(model, Q)
    n = int(model.n_codes_)
    k = min(check_positive_int(k, "k"), n)
    places = np.empty((margins.shape[0], k), dtype=np.int64)
    costs = np.empty((margins.shape[0], k))
    region_order = np.argsort(deficits, axis=1, kind="stable")
    for q in range(margins.shape[0]):
        cand_places: list[int] = []
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
            cand_places.extend(int(starts[reg]) + i for i in local)
            cand_costs.extend(c + offset for c in local_cost)
            held += min(n_k, k)
        order = np.argsort(np.asarray(cand_costs), kind="stable")[:k]
        places[q] = np.asarray(cand_places, dtype=np.int64)[order]
        costs[q] = np.asarray(cand_costs)[order]
    return model._places_of_codes(places), costs  # distinct blocks → distinct centre places


def _rank_by_costs(model: Any, Q: Any, k: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Top-k codes by :func:`place_costs` over every code (O(N·K) per query), as places."""
    block = model.block_size_
    costs = place_costs(model, Q, region_weight=alpha)
    if block > 1:
        costs = costs[:, ::block]  # one column per block (its first place), block order
    k = min(check_positive_int(k, "k"), costs.shape[1])
    top = np.argpartition(costs, k - 1, axis=1)[:, :k] if k < costs.shape[1] else \
        np.broadcast_to(np.arange(costs.shape[1]), costs.shape).copy()
    order = np.argsort(np.take_along_axis(costs, top, axis=1), axis=1, kind="stable")
    codes = np.take_along_axis(top, order, axis=1).astype(np.int64)
    return model._places_of_codes(codes), np.take_along_axis(costs, codes, axis=1)
