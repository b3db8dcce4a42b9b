"""Map statistics of ``auto``'s rule (:mod:`btel.methods.auto.rule`): route share, route continuity, the birthday bound.

Each reads the map rows (and their place labels) only, never a query.
"""

from __future__ import annotations

import numpy as np

from ...frontend import normalize_rows

__all__ = ["CONTINUITY_GAPS", "CONTINUITY_REFERENCE", "ROUTE_CONTINUITY", "ROUTE_SHARE", "ROUTE_WINDOW", "STAT_ROWS",
           "collision_bits", "route_continuity", "route_share", "route_test"]

#: Places within which the nearest other map row must lie for a row to count as "route-like".
ROUTE_WINDOW = 2
#: Route when at least this share of map rows is route-like.
ROUTE_SHARE = 0.5
#: Map rows the statistic samples (evenly spaced) at most.
STAT_ROWS = 2000
#: Places apart (from, to) of the rows whose similarity the route continuity ranks.
CONTINUITY_GAPS = (3, 8)
#: Route only when the continuity is at least this (0.5: no order; 1: a perfectly smooth route).
ROUTE_CONTINUITY = 0.75
#: Other map rows (evenly spaced) each probe's similarities are ranked among, at most.
CONTINUITY_REFERENCE = 1024


def collision_bits(n_rows: int) -> float:
    """2·log2 N: the bits per row below which N random sign codes are unlikely to be all distinct.

    The birthday bound: N independent random P-bit codes are all distinct with probability about
    exp(−N² / 2^(P+1)), which is small unless P ≳ 2·log2 N. Below it many places of an LSH map share
    their code, while output codes give every place its own codeword by construction.
    """
    return 2.0 * float(np.log2(max(int(n_rows), 2)))


def route_share(X: np.ndarray, places: np.ndarray | None = None, *, window: int = ROUTE_WINDOW,
                max_rows: int = STAT_ROWS) -> float:
    """Share of map rows whose nearest other map row (cosine) lies within ``window`` places.

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    places : ndarray of shape (n_rows,), int, or None (row i = place i)
    window : int
    max_rows : int
        Rows sampled evenly as probes (the whole map is searched).

    Returns
    -------
    float in [0, 1]
    """
    import faiss

    Z = normalize_rows(np.ascontiguousarray(X, dtype=np.float32), "l2")
    n = Z.shape[0]
    labels = np.arange(n) if places is None else np.asarray(places, dtype=np.int64)
    probes = np.unique(np.linspace(0, n - 1, min(n, max_rows)).round().astype(np.int64))
    index = faiss.IndexFlatIP(Z.shape[1])
    index.add(Z)
    _, rows = index.search(Z[probes], 2)
    # The nearest row other than the probe itself (a duplicate row may come first).
    other = np.where(rows[:, 0] == probes, rows[:, 1], rows[:, 0])
    valid = other >= 0
    near = np.abs(labels[other[valid]] - labels[probes[valid]]) <= window
    return float(near.mean()) if near.size else 0.0


def route_continuity(X: np.ndarray, places: np.ndarray | None = None, *, gaps: tuple[int, int] = CONTINUITY_GAPS,
                     max_rows: int = STAT_ROWS, n_reference: int = CONTINUITY_REFERENCE) -> float:
    """Mean percentile rank of the cosine between a map row and the rows ``gaps`` places away.

    For every probe row (up to ``max_rows``, evenly spaced), the cosines to the map rows whose place
    lies 3 … 8 places away (either side) are ranked among its cosines to up to ``n_reference`` other
    map rows (evenly spaced); the statistic is the mean rank in [0, 1]. About 0.5 when the order of
    the rows says nothing beyond the nearest frames (independent places, or short snippets of a route
    in random order), towards 1 along a smooth route.

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    places : ndarray of shape (n_rows,), int, or None (row i = place i)
    gaps : (int, int)
    max_rows, n_reference : int

    Returns
    -------
    float in [0, 1]; 0.5 when no probe has rows that far apart (a map of fewer than 4 places).
    """
    Z = normalize_rows(np.ascontiguousarray(X, dtype=np.float32), "l2")
    n = Z.shape[0]
    labels = np.arange(n) if places is None else np.asarray(places, dtype=np.int64)
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    probes = np.unique(np.linspace(0, n - 1, min(n, max_rows)).round().astype(np.int64))
    reference = np.unique(np.linspace(0, n - 1, min(n, n_reference)).round().astype(np.int64))
    reference_rows = Z[reference]
    lo, hi = gaps
    ranks: list[float] = []
    for start in range(0, probes.size, 256):
        chunk = probes[start : start + 256]
        ref_scores = np.sort(Z[chunk] @ reference_rows.T, axis=1)
        for row, i in enumerate(chunk):
            near = [order[np.searchsorted(sorted_labels, a, "left") : np.searchsorted(sorted_labels, b, "right")]
                    for a, b in ((labels[i] - hi, labels[i] - lo), (labels[i] + lo, labels[i] + hi))]
            others = np.concatenate(near)
            if others.size == 0:
                continue
            others = others[np.unique(np.linspace(0, others.size - 1, min(others.size, 32)).round().astype(np.int64))]
            refs = ref_scores[row]
            # The probe's own row (cosine 1) is among the reference rows when sampled: leave it out.
            n_ref = refs.size - int(np.isin(i, reference))
            below = np.searchsorted(refs, Z[others] @ Z[i], side="left")
            ranks.append(float(np.mean(np.minimum(below, n_ref) / max(n_ref, 1))))
    return float(np.mean(ranks)) if ranks else 0.5


def route_test(X: np.ndarray, places: np.ndarray | None = None) -> tuple[bool, float, float | None, str]:
    """Whether the map is a route by step 1 of the rule: ``(is_route, share, continuity, why)``.

    The continuity is computed only when the route share reaches :data:`ROUTE_SHARE` (None otherwise).
    """
    share = route_share(X, places)
    if share < ROUTE_SHARE:
        return False, share, None, f"route share {share:.2f} < {ROUTE_SHARE}"
    continuity = route_continuity(X, places)
    if continuity < ROUTE_CONTINUITY:
        return False, share, continuity, (f"route share {share:.2f} ≥ {ROUTE_SHARE} but continuity {continuity:.2f} < "
                                          f"{ROUTE_CONTINUITY}: snippets, not a route")
    return True, share, continuity, f"route share {share:.2f} ≥ {ROUTE_SHARE}, continuity {continuity:.2f} ≥ {ROUTE_CONTINUITY}"
