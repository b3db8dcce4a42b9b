"""Positives from positions: the map places within a radius of each query, bounded in memory and work.

A KD-tree's radius search costs what the geometry makes it cost: map positions on a ring with the
queries at its centre and the threshold just under the radius make every query compare with every
place and find none. :func:`positives_within` bounds the pairs it builds by the memory limit
(16 bytes each) and the distances it computes by :data:`DISTANCES_PER_PAIR` per pair the limit
holds, counted by the tree itself; the evidence is on ``docs/decisions/reader-bounds.md``.
"""

from __future__ import annotations

import numpy as np

from ..exceptions import ResourceLimitError
from ..core.limits import ENV_MEMORY_LIMIT, check_bytes, check_count, format_size, memory_limit

__all__ = ["DISTANCES_PER_PAIR", "positives_within"]

#: Distances the radius search may compute per query-place pair the memory limit can hold (16 bytes
#: each): 16 × 2²⁴ ≈ 2.7·10⁸ under the 256 MiB default. Position sets shaped like VPR data need 2–8
#: per pair found and 0.2–5 % of the bound.
DISTANCES_PER_PAIR = 16


def positives_within(db: np.ndarray, q: np.ndarray, thr: float) -> tuple[np.ndarray, np.ndarray]:
    """CSR positives: the rows of ``db`` within ``thr`` of each row of ``q`` (at ``thr`` included).

    A first pass counts each query's positives, in calls that can each compute at most a quarter
    of the distance bound (so it is overshot by at most a quarter); the second builds the pairs in
    calls of at most an eighth of the memory limit each.

    Parameters
    ----------
    db : ndarray of shape (n_map, n_coords), dtype float64
    q : ndarray of shape (n_queries, n_coords), dtype float64
    thr : float
        Radius ≥ 0.

    Returns
    -------
    indptr : ndarray of shape (n_queries + 1,), dtype int64
    indices : ndarray of shape (n_pairs,), dtype int64

    Raises
    ------
    ResourceLimitError
        The positions and their KD-tree, the pairs, or the distances computed exceed the limit.
    """
    from sklearn.neighbors import KDTree

    check_bytes(2 * db.nbytes + 8 * db.shape[0] + q.nbytes,
                f"{db.shape[0]} map and {q.shape[0]} query positions with their KD-tree")
    limit = memory_limit()
    max_distances = DISTANCES_PER_PAIR * (limit // 16)
    tree = KDTree(db)
    tree.reset_n_calls()
    # Count first, in calls that can each compute at most a quarter of the distance bound (every
    # query against every place), so the bound is overshot by at most that much.
    per_call = max(1, max_distances // 4 // db.shape[0])
    counts = np.zeros(q.shape[0], dtype=np.int64)
    n_pairs = 0
    for start in range(0, q.shape[0], per_call):
        stop = min(q.shape[0], start + per_call)
        counts[start:stop] = tree.query_radius(q[start:stop], r=thr, count_only=True)
        done = f"after {stop} of {q.shape[0]} queries"
        n_pairs += int(counts[start:stop].sum())
        what = f"positives within posDistThr={thr:g}"
        check_count(n_pairs, 16, f"{what} ({n_pairs} query-place pairs {done})")
        if tree.get_n_calls() > max_distances:
            raise ResourceLimitError(
                f"{what}: the radius search computed {tree.get_n_calls()} distances {done}, over the "
                f"{max_distances} that btel's memory limit of {format_size(limit)} allows "
                f"({DISTANCES_PER_PAIR} per pair it can hold; the positions put many places near the "
                f"threshold of every query). If the input is genuine, raise the limit with "
                f"{ENV_MEMORY_LIMIT}.")
    # Then the pairs, the same searches again, in calls of at most limit/8 bytes of output each.
    indptr = np.zeros(q.shape[0] + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    indices = np.empty(int(indptr[-1]), dtype=np.int64)
    start = 0
    while start < q.shape[0]:
        stop = max(start + 1, int(np.searchsorted(indptr, indptr[start] + limit // 64, side="right")) - 1)
        stop = min(stop, start + 65536, q.shape[0])  # and a bounded number of result arrays
        if indptr[stop] > indptr[start]:
            found = tree.query_radius(q[start:stop], r=thr)
            indices[indptr[start]:indptr[stop]] = np.concatenate(list(found))
        start = stop
    return indptr, indices
