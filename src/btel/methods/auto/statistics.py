"""Map statistics of ``auto``'s rule (:mod:`btel.methods.auto.rule`): route share, route continuity, the birthday bound.

Each reads the map rows (and their place labels) only, never a query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.validation import check_descriptors, map_places
from ...core.frontend import normalize_rows
from ...exceptions import InvalidParameterError

__all__ = ["CONTINUITY_GAPS", "CONTINUITY_REFERENCE", "IndexOrder", "MIN_STAT_ROWS", "ORDER_CONTINUITY",
           "ROUTE_CONTINUITY", "ROUTE_SHARE", "ROUTE_WINDOW", "SHARE_SEARCH_ROWS", "SHARE_SPANS", "STAT_PRODUCTS",
           "STAT_ROWS", "collision_bits", "index_order", "map_cone_ratio", "probe_rows", "route_continuity",
           "route_share"]

#: Places within which the nearest other map row must lie for a row to count as "route-like".
ROUTE_WINDOW = 2
#: Route when at least this share of map rows is route-like.
ROUTE_SHARE = 0.5
#: Map rows the statistic samples (evenly spaced) at most ...
STAT_ROWS = 2000
#: ... and at least, where fewer would keep :func:`index_order` within :data:`STAT_PRODUCTS`.
MIN_STAT_ROWS = 500
#: Multiply-adds (probes × rows searched × d) :func:`index_order`'s route share is held to: a wide or
#: long map is probed by fewer rows (not fewer than :data:`MIN_STAT_ROWS`), so that auto's fit at
#: d = 16,384 is not spent on its statistics (``docs/decisions/auto-rule.md``, "What the statistics cost").
STAT_PRODUCTS = 1 << 34
#: The route share searches maps of up to this many rows whole, larger ones in spans (:func:`route_share`).
SHARE_SEARCH_ROWS = 65536
#: Spans of consecutive places the route share searches in a larger map.
SHARE_SPANS = 8
#: Places apart (from, to) of the rows whose similarity the route continuity ranks.
CONTINUITY_GAPS = (3, 8)
#: Route only when the continuity is at least this (0.5: no order; 1: a perfectly smooth route).
ROUTE_CONTINUITY = 0.75
#: A map is ordered (rule, step 2) when its continuity is at least this: the order holds beyond the
#: nearest frames (0.5 when it does not; pairs and triples of alike rows in random order stay at ≈ 0.5;
#: Nordland HOG 0.68).
ORDER_CONTINUITY = 0.6
#: Other map rows (evenly spaced) each probe's similarities are ranked among, at most.
CONTINUITY_REFERENCE = 1024


def _unit_rows(X: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The L2-normalised float32 copy of the given rows only (a memory-mapped map is read, never copied whole)."""
    return normalize_rows(np.ascontiguousarray(X[rows], dtype=np.float32), "l2")


def _checked(X: np.ndarray, places: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """The map and its place labels validated as a fit validates them (a float32 map is not copied)."""
    X = check_descriptors(X)
    return X, map_places(places, X.shape[0])[0]


def map_cone_ratio(X: np.ndarray) -> float:
    """:func:`~btel.methods.baselines.lsh.cone_ratio` of the L2-normalised map rows, read in blocks."""
    X = check_descriptors(X)
    n, d = X.shape
    total, squares = np.zeros(d), 0.0
    step = max(1, (1 << 22) // max(d, 1))
    for start in range(0, n, step):
        Z = _unit_rows(X, np.arange(start, min(n, start + step)))
        total += Z.sum(axis=0, dtype=np.float64)
        squares += float(np.einsum("ij,ij->", Z, Z, dtype=np.float64))
    return float(np.linalg.norm(total / n) / np.sqrt(squares / n)) if squares > 0 else 0.0


def probe_rows(n_rows: int, n_features: int) -> int:
    """The probes :func:`index_order` samples: :data:`STAT_ROWS`, fewer (down to :data:`MIN_STAT_ROWS`)
    where probes × rows searched (at most :data:`SHARE_SEARCH_ROWS`) × d would pass :data:`STAT_PRODUCTS`.

    The statistics are means over the probes: 500 probes put a share's standard error at ≤ 0.022.
    """
    searched = max(1, min(int(n_rows), SHARE_SEARCH_ROWS)) * max(1, int(n_features))
    return int(min(STAT_ROWS, max(MIN_STAT_ROWS, STAT_PRODUCTS // searched)))


def collision_bits(n_rows: int) -> float:
    """2·log2 N: the bits per row below which N random sign codes are unlikely to be all distinct.

    The birthday bound: N independent random P-bit codes are all distinct with probability about
    exp(−N² / 2^(P+1)), which is small unless P ≳ 2·log2 N. Below it many places of an LSH map share
    their code, while output codes give every place its own codeword by construction.
    """
    return 2.0 * float(np.log2(max(int(n_rows), 2)))


def route_share(X: np.ndarray, places: np.ndarray | None = None, *, window: int = ROUTE_WINDOW,
                max_rows: int = STAT_ROWS, search_rows: int = SHARE_SEARCH_ROWS) -> float:
    """Share of map rows whose nearest map row of another place (cosine) lies within ``window`` places.

    Raises :class:`~btel.exceptions.InvalidDescriptorsError` (not 2-D numbers, NaN/inf) or
    :class:`~btel.exceptions.InvalidParameterError` (bad place labels) as a fit does.

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    places : ndarray of shape (n_rows,), int, or None (row i = place i)
    window : int
    max_rows : int
        Rows sampled evenly as probes.
    search_rows : int
        Maps of up to this many rows are searched whole; a larger map in :data:`SHARE_SPANS` evenly
        spaced spans of consecutive places (search_rows rows in all), each probe within its own span,
        so the cost stays bounded at any N. A route's nearest frame lies in its span; a revisit of the
        place far along the route may not, which can only raise the share.

    Returns
    -------
    float in [0, 1]
    """
    return _route_share(*_checked(X, places), window=window, max_rows=max_rows, search_rows=search_rows)


def _route_share(X: np.ndarray, places: np.ndarray | None, *, window: int = ROUTE_WINDOW, max_rows: int = STAT_ROWS,
                 search_rows: int = SHARE_SEARCH_ROWS) -> float:
    n = X.shape[0]
    labels = np.arange(n) if places is None else places
    if n <= search_rows:
        spans = [np.arange(n)]
    else:
        by_place = np.argsort(labels, kind="stable")
        length = search_rows // SHARE_SPANS
        spans = [np.sort(by_place[s : s + length])
                 for s in np.linspace(0, n - length, SHARE_SPANS).round().astype(np.int64)]
    near: list[np.ndarray] = []
    for rows in spans:
        picks = np.unique(np.linspace(0, rows.size - 1, min(rows.size, max_rows // len(spans))).round()
                          .astype(np.int64))
        probes, other = rows[picks], _nearest_other(X, rows, picks, labels)
        valid = other >= 0
        near.append(np.abs(labels[other[valid]] - labels[probes[valid]]) <= window)
    hits = np.concatenate(near)
    return float(hits.mean()) if hits.size else 0.0


def _nearest_other(X: np.ndarray, rows: np.ndarray, picks: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """For each probe ``rows[picks]``, its nearest (cosine) row among ``rows`` of another place (``labels``);
    −1 if none.

    Rows of the probe's own place are left out: with several traverses the nearest row would be the same
    place seen again, which says nothing about how alike neighbouring places are. Read in blocks of rows
    (a memory-mapped map is never copied whole).
    """
    P = _unit_rows(X, rows[picks])
    best = np.full(picks.size, -np.inf, dtype=np.float32)
    other = np.full(picks.size, -1, dtype=np.int64)
    step = max(1, min(rows.size, (1 << 22) // max(picks.size, X.shape[1], 1)))
    for start in range(0, rows.size, step):
        block = _unit_rows(X, rows[start : start + step])
        scores = P @ block.T
        same = labels[rows[picks]][:, None] == labels[rows[start : start + step]][None, :]
        scores[same] = -np.inf  # the probe itself, and its place in other traverses, are not its neighbours
        top = np.argmax(scores, axis=1)
        value = scores[np.arange(picks.size), top]
        better = value > best
        best[better], other[better] = value[better], rows[start + top[better]]
    return other


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
    return _route_continuity(*_checked(X, places), gaps=gaps, max_rows=max_rows, n_reference=n_reference)


def _route_continuity(X: np.ndarray, places: np.ndarray | None, *, gaps: tuple[int, int] = CONTINUITY_GAPS,
                      max_rows: int = STAT_ROWS, n_reference: int = CONTINUITY_REFERENCE) -> float:
    n = X.shape[0]
    labels = np.arange(n) if places is None else places
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    probes = np.unique(np.linspace(0, n - 1, min(n, max_rows)).round().astype(np.int64))
    reference = np.unique(np.linspace(0, n - 1, min(n, n_reference)).round().astype(np.int64))
    reference_rows = _unit_rows(X, reference)
    lo, hi = gaps
    ranks: list[float] = []
    for start in range(0, probes.size, 256):
        chunk = probes[start : start + 256]
        chunk_rows = _unit_rows(X, chunk)
        ref_scores = np.sort(chunk_rows @ reference_rows.T, axis=1)
        wanted = []
        for i in chunk:
            near = [order[np.searchsorted(sorted_labels, a, "left") : np.searchsorted(sorted_labels, b, "right")]
                    for a, b in ((labels[i] - hi, labels[i] - lo), (labels[i] + lo, labels[i] + hi))]
            others = np.concatenate(near)
            wanted.append(others[np.unique(np.linspace(0, others.size - 1, min(others.size, 32)).round()
                                           .astype(np.int64))] if others.size else others)
        needed = np.unique(np.concatenate(wanted)) if wanted else np.zeros(0, dtype=np.int64)
        needed_rows = _unit_rows(X, needed)
        for row, (i, others) in enumerate(zip(chunk, wanted)):
            if others.size == 0:
                continue
            refs = ref_scores[row]
            # The probe's own row (cosine 1) is among the reference rows when sampled: leave it out.
            n_ref = refs.size - int(np.isin(i, reference))
            below = np.searchsorted(refs, needed_rows[np.searchsorted(needed, others)] @ chunk_rows[row], side="left")
            ranks.append(float(np.mean(np.minimum(below, n_ref) / max(n_ref, 1))))
    return float(np.mean(ranks)) if ranks else 0.5


@dataclass(frozen=True)
class IndexOrder:
    """What the map's index order says about its places (steps 1 and 2 of the rule).

    Attributes
    ----------
    kind : {'route', 'ordered', 'independent'}
        'route': route share ≥ :data:`ROUTE_SHARE` and continuity ≥ :data:`ROUTE_CONTINUITY`;
        'ordered': otherwise continuity ≥ :data:`ORDER_CONTINUITY` (rows a few places apart look more
        alike than most, though the nearest row need not be the next frame); 'independent' otherwise.
    share : float
        :func:`route_share`.
    continuity : float
        :func:`route_continuity`.
    why : str
        The figures and thresholds that decided (without the kind itself).
    """

    kind: str
    share: float
    continuity: float
    why: str


def index_order(X: np.ndarray, places: np.ndarray | None = None, *, probes: int | None = None) -> IndexOrder:
    """Route, ordered map or independent places, from the map rows (and place labels) alone.

    Parameters
    ----------
    X : ndarray of shape (n_rows, n_features)
    places : ndarray of shape (n_rows,), int, or None (row i = place i)
    probes : int or None
        Rows both statistics sample; None: :func:`probe_rows` (2,000 but on wide or long maps).

    Returns
    -------
    IndexOrder
    """
    X, places = _checked(X, places)
    if probes is None:
        probes = probe_rows(*X.shape)
    elif isinstance(probes, bool) or not isinstance(probes, (int, np.integer)) or probes < 1:
        raise InvalidParameterError(f"probes must be a whole number ≥ 1 (or None: probe_rows), got {probes!r}.")
    share, continuity = _route_share(X, places, max_rows=probes), _route_continuity(X, places, max_rows=probes)
    labels = np.arange(X.shape[0]) if places is None else places
    if int(labels.max() - labels.min()) < CONTINUITY_GAPS[0]:
        # No two places are far enough apart for the continuity (nor the share) to mean anything.
        return IndexOrder("independent", share, continuity,
                          f"{np.unique(labels).size} places: too few to read an order (the continuity compares "
                          f"rows {CONTINUITY_GAPS[0]}–{CONTINUITY_GAPS[1]} places apart)")
    if share >= ROUTE_SHARE and continuity >= ROUTE_CONTINUITY:
        return IndexOrder("route", share, continuity, f"route share {share:.2f} ≥ {ROUTE_SHARE}, continuity "
                                                      f"{continuity:.2f} ≥ {ROUTE_CONTINUITY}")
    figures = f"route share {share:.2f}, continuity {continuity:.2f}"
    if continuity >= ORDER_CONTINUITY:
        # "Route" is the rule's word for frames dense enough that a row's nearest row is its neighbour;
        # a user's route sampled more sparsely is an ordered map, and the reason says which test failed.
        short = (f"most rows' nearest row is not an adjacent frame: share < {ROUTE_SHARE}" if share < ROUTE_SHARE
                 else f"the order fades within a few places: continuity < {ROUTE_CONTINUITY}")
        return IndexOrder("ordered", share, continuity, f"{figures} ≥ {ORDER_CONTINUITY}; {short}")
    return IndexOrder("independent", share, continuity,
                      f"{figures} < {ORDER_CONTINUITY}: no order beyond the nearest frames")
