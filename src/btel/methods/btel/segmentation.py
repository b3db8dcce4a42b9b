"""Splitting a traverse into contiguous regions: Kernel Temporal Segmentation (the paper's regions).

KTS (Potapov et al. 2014) with a linear kernel on L2-normalised descriptors minimises the
within-segment scatter over r−1 change points by dynamic programming; ``ruptures.KernelCPD
(kernel="linear")`` solves exactly that problem, and one call yields the optimal segmentations
for every count up to the maximum. Descriptors are reduced to at most 128 dimensions by PCA first
(a speed-up, not the paper's): the DP costs O(n²·r) kernel evaluations and the reduction keeps them cheap.

Automatic r uses the KTS penalty over the DP costs V_m (m change points, n frames):
``cost_m = V_m/n + v·m/(2n)·(log(n/m) + 1)`` — not ruptures' ``pen=`` (which is a plain
linear penalty for PELT).

Cost and the large-N path
-------------------------
The exact DP takes O(n²·(p + r)) time for n places, p (≤ 128) dimensions and r regions, and
O(n·(d + r)) memory: 25 s at n = 8192 on one core, days at n = 10⁶. Routes longer than
``max_points`` (4096 by default) take the **block path**:

1. average the L2-normalised descriptors over consecutive blocks of B = ⌈n / max_points⌉
   places — one chunked pass over X, O(n·d) time, O(M·d) memory for the M = ⌈n / B⌉ block
   means (X may be memory-mapped; it is never copied);
2. PCA of the M block means to p dimensions and the exact DP on them, O(M²·(p + r)): with equal
   blocks, the frame-level cost of a run of blocks is B times the linear-kernel cost of their
   means plus the within-block scatter, a constant — so this *is* KTS restricted to change
   points on block boundaries (the last, shorter block is weighted like the others);
3. refine each change point within ±B places by the exact frame-level cost (in the same PCA
   space) with its neighbours fixed, one pass left to right, O(r·B·d·p).

In total O(n·d + M²·(p + r) + r·B·d·p), linear in n (``benchmarks/bench_scale.py`` times it at
n = 10⁶ and checks the true boundaries of the synthetic route are found). A change point can differ from the
exact one only where the coarse DP put it in the wrong block; ``tests/test_segmentation_large.py``
checks that both paths find the true boundaries of a synthetic route.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.validation import check_positive_int
from ...exceptions import NotEnoughPlacesError

__all__ = [
    "kts_regions",
    "kts_segmentations",
    "kts_auto_regions",
    "kts_penalised_costs",
    "region_of",
    "MIN_REGION_LENGTH",
    "DEFAULT_MAX_POINTS",
]

#: Shortest region KTS may produce (the paper's regions); a region needs ≥ 2 places for a 1-bit code.
MIN_REGION_LENGTH = 2

#: Longest sequence segmented by the exact DP; longer routes take the block path.
DEFAULT_MAX_POINTS = 4096

_CHUNK_ROWS = 65536


def _pca(n_components: int, random_state: int | None) -> Any:
    """An unfitted randomized PCA (scikit-learn, imported here: a loaded model never needs it)."""
    from sklearn.decomposition import PCA

    return PCA(n_components=n_components, svd_solver="randomized", random_state=random_state)


def _kernel_cpd(Z: np.ndarray) -> Any:
    """ruptures' linear-kernel change-point search fitted on ``Z`` (imported here: fitting alone needs it)."""
    import ruptures as rpt

    return rpt.KernelCPD(kernel="linear", min_size=MIN_REGION_LENGTH).fit(Z)


def _prepare(X: np.ndarray, pca_dims: int | None, random_state: int | None) -> np.ndarray:
    Z = _normalised(X)
    if pca_dims is not None and Z.shape[1] > pca_dims and Z.shape[0] > pca_dims:
        Z = _pca(pca_dims, random_state).fit_transform(Z)
    return np.ascontiguousarray(Z)


def _normalised(block: np.ndarray) -> np.ndarray:
    """Rows at unit length (float64) whatever their scale; a zero row stays zero."""
    Z = np.asarray(block, dtype=np.float64)
    norms = np.linalg.norm(Z, axis=1, keepdims=True)
    return Z / np.where(norms > 0, norms, 1.0)


class _Blocks:
    """Block means of the L2-normalised descriptors and what the refinement needs (block path).

    Attributes
    ----------
    size : int
        B, places per block (the last block may be shorter).
    means : ndarray of shape (M, p), float64
        Block means, PCA-projected when a PCA is used.
    """

    def __init__(self, X: np.ndarray, n_segments: int, max_points: int, pca_dims: int | None,
                 random_state: int | None) -> None:
        n, d = X.shape
        # B so that the M blocks fit max_points, but never so coarse that r regions of ≥ 2 blocks
        # cannot be formed.
        self.size = max(1, min(-(-n // max_points), n // (MIN_REGION_LENGTH * n_segments)))
        self.X = X
        B = self.size
        n_blocks = -(-n // B)
        sums = np.zeros((n_blocks, d))
        chunk = max(B, (_CHUNK_ROWS // B) * B)  # whole blocks per chunk
        for start in range(0, n, chunk):
            Z = _normalised(X[start : start + chunk])
            sums[start // B : start // B + -(-Z.shape[0] // B)] = np.add.reduceat(Z, np.arange(0, Z.shape[0], B), axis=0)
        self.counts = np.full(n_blocks, B, dtype=np.float64)
        self.counts[-1] = n - B * (n_blocks - 1)
        means = sums / self.counts[:, None]
        self.pca = None
        if pca_dims is not None and d > pca_dims and n_blocks > pca_dims:
            self.pca = _pca(pca_dims, random_state).fit(means)
            means = self.pca.transform(means)
        self.means = np.ascontiguousarray(means)
        # Prefix sums of the projected frames at block boundaries (PCA is affine: the projected
        # mean of a block is the projection of its mean).
        self.prefix = np.concatenate([np.zeros((1, self.means.shape[1])), np.cumsum(self.means * self.counts[:, None], axis=0)])
        # Refining every r of an automatic choice revisits the same boundaries: keep up to
        # ~64 MB of projected blocks instead of projecting them again.
        self._cache: dict[int, np.ndarray] = {}
        self._cache_blocks = max(8, (64 << 20) // (8 * B * self.means.shape[1]))

    def block_frames(self, j: int) -> np.ndarray:
        """Projected, L2-normalised frames of block j (shape (≤ B, p)); recently used blocks are cached."""
        if j not in self._cache:
            if len(self._cache) >= self._cache_blocks:
                self._cache.pop(next(iter(self._cache)))  # oldest first
            Z = _normalised(self.X[j * self.size : (j + 1) * self.size])
            self._cache[j] = self.pca.transform(Z) if self.pca is not None else Z
        return self._cache[j]

    def frames(self, start: int, stop: int) -> np.ndarray:
        """Projected, L2-normalised frames ``start:stop`` (shape (stop − start, p))."""
        B = self.size
        blocks = [self.block_frames(j) for j in range(start // B, -(-stop // B))]
        return np.concatenate(blocks)[start - (start // B) * B : stop - (start // B) * B]

    def prefix_at(self, i: int) -> np.ndarray:
        """Σ of the projected frames 0..i−1."""
        j = i // self.size
        total = self.prefix[j]
        if i > j * self.size:
            total = total + self.block_frames(j)[: i - j * self.size].sum(axis=0)
        return total

    def refine(self, starts: np.ndarray, n: int) -> np.ndarray:
        """Move each change point within ±B places to its best frame-level position (left to right)."""
        bounds = [int(b) for b in starts] + [n]
        B = self.size
        for k in range(1, len(bounds) - 1):
            a, t0, b = bounds[k - 1], bounds[k], bounds[k + 1]
            lo = max(a + MIN_REGION_LENGTH, t0 - B)
            hi = min(b - MIN_REGION_LENGTH, t0 + B)
            if hi <= lo:
                continue
            # Within-segment scatter = Σ‖z‖² − ‖S‖²/len; Σ‖z‖² over [a, b) does not depend on t,
            # so the best t maximises ‖S(a,t)‖²/(t−a) + ‖S(t,b)‖²/(b−t).
            p_a, p_lo, p_b = self.prefix_at(a), self.prefix_at(lo), self.prefix_at(b)
            window = self.frames(lo, hi)
            p_t = p_lo + np.concatenate([np.zeros((1, window.shape[1])), np.cumsum(window, axis=0)])
            t = np.arange(lo, hi + 1)
            gain = ((p_t - p_a) ** 2).sum(axis=1) / (t - a) + ((p_b - p_t) ** 2).sum(axis=1) / (b - t)
            bounds[k] = int(t[np.argmax(gain)])
        return np.asarray(bounds[:-1], dtype=np.int64)

    def to_frames(self, starts: np.ndarray) -> np.ndarray:
        return np.asarray(starts, dtype=np.int64) * self.size


def check_segment_count(n: int, n_regions: int) -> None:
    if n_regions * MIN_REGION_LENGTH > n:
        raise NotEnoughPlacesError(
            f"cannot split {n} places into {n_regions} regions of at least {MIN_REGION_LENGTH} places; "
            f"use n_regions ≤ {n // MIN_REGION_LENGTH}."
        )


def _starts_from_breakpoints(bkps: list[int]) -> np.ndarray:
    return np.asarray([0] + list(bkps[:-1]), dtype=np.int64)


def kts_regions(
    X: np.ndarray,
    n_regions: int,
    *,
    pca_dims: int | None = 128,
    random_state: int | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    refine: bool = True,
) -> np.ndarray:
    """Split a traverse into ``n_regions`` contiguous regions with KTS (linear kernel).

    Exact DP up to ``max_points`` places, O(n²·(p + r)); beyond, the block path of the module
    docstring, O(n·d + M²·(p + r) + r·B·d·p) with M ≤ ``max_points`` blocks of B places.

    Parameters
    ----------
    X : ndarray of shape (n_places, n_features)
        One descriptor per place, in route order (may be memory-mapped).
    n_regions : int
        r ≥ 1.
    pca_dims : int or None
        Reduce to this many dimensions first (None: no reduction).
    random_state : int, optional
        Seed of the randomized PCA.
    max_points : int
        Longest route segmented exactly; longer ones are averaged in blocks first.
    refine : bool
        Block path only: move each change point to its best place within ±B (else the change
        points stay on block boundaries).

    Returns
    -------
    starts : ndarray of shape (n_regions,), int64
        First place of each region; ``starts[0] == 0``, strictly increasing, every region ≥ 2 long.
    """
    r = check_positive_int(n_regions, "n_regions")
    n = X.shape[0]
    check_segment_count(n, r)
    if r == 1:
        return np.zeros(1, dtype=np.int64)
    max_points = check_positive_int(max_points, "max_points", minimum=4)
    if n <= max_points:
        Z = _prepare(X, pca_dims, random_state)
        algo = _kernel_cpd(Z)
        return _starts_from_breakpoints(algo.predict(n_bkps=r - 1))
    blocks = _Blocks(X, r, max_points, pca_dims, random_state)
    algo = _kernel_cpd(blocks.means)
    starts = blocks.to_frames(_starts_from_breakpoints(algo.predict(n_bkps=r - 1)))
    return blocks.refine(starts, n) if refine else starts


def kts_penalised_costs(costs: np.ndarray, n: int, v: float) -> np.ndarray:
    """KTS objective for m = 0..len(costs)−1 change points: ``V_m/n + v·m/(2n)·(log(n/m) + 1)``."""
    m = np.arange(len(costs), dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        penalty = np.where(m > 0, v * m / (2.0 * n) * (np.log(n / np.maximum(m, 1)) + 1.0), 0.0)
    return np.asarray(costs, dtype=np.float64) / n + penalty


def kts_segmentations(
    X: np.ndarray,
    max_regions: int,
    *,
    pca_dims: int | None = 128,
    random_state: int | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    refine: bool = True,
) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """Optimal KTS segmentations for every r = 1 … max_regions, from one dynamic programme.

    Beyond ``max_points`` places the DP runs on block means (see :func:`kts_regions`); the costs
    are then the block-level costs scaled by B to frames, which leaves out the within-block
    scatter — a constant that shifts every V_m alike and so does not change the choice of r.

    Returns
    -------
    starts_by_r : dict of int to ndarray
        r → region starts (int64, shape (r,)).
    costs : ndarray of shape (max_regions,), float64
        ``costs[m]`` = V_m, the within-segment scatter with m = r − 1 change points.
    """
    n = X.shape[0]
    max_r = min(check_positive_int(max_regions, "max_regions"), n // MIN_REGION_LENGTH)
    if max_r < 2:
        return {1: np.zeros(1, dtype=np.int64)}, np.zeros(1)
    max_points = check_positive_int(max_points, "max_points", minimum=4)
    blocks = None
    if n <= max_points:
        Z = _prepare(X, pca_dims, random_state)
    else:
        blocks = _Blocks(X, max_r, max_points, pca_dims, random_state)
        Z = blocks.means
    algo = _kernel_cpd(Z)
    algo.predict(n_bkps=max_r - 1)  # fills the segmentations for every m ≤ max_r − 1
    bkps = {0: [Z.shape[0]], **algo.segmentations_dict}
    costs = np.array([algo.cost.sum_of_costs(bkps[m]) for m in range(max_r)])
    starts_by_r = {m + 1: _starts_from_breakpoints(bkps[m]) for m in range(max_r)}
    if blocks is not None:
        costs = costs * blocks.size
        starts_by_r = {r: blocks.to_frames(s) for r, s in starts_by_r.items()}
        if refine:
            starts_by_r = {r: blocks.refine(s, n) for r, s in starts_by_r.items()}
    return starts_by_r, costs


def kts_auto_regions(
    X: np.ndarray,
    *,
    max_regions: int = 50,
    penalty: float = 1.0,
    pca_dims: int | None = 128,
    random_state: int | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
) -> np.ndarray:
    """Choose r automatically with the KTS penalty and split the traverse.

    Parameters
    ----------
    X : ndarray of shape (n_places, n_features)
    max_regions : int
        Largest r considered (capped at n_places // 2).
    penalty : float
        v in the KTS penalty; larger → fewer regions.
    max_points : int
        Longest route segmented exactly (see :func:`kts_regions`).

    Returns
    -------
    starts : ndarray of shape (r,), int64
    """
    starts_by_r, costs = kts_segmentations(X, max_regions, pca_dims=pca_dims, random_state=random_state,
                                           max_points=max_points)
    best_m = int(np.argmin(kts_penalised_costs(costs, X.shape[0], penalty)))
    return starts_by_r[best_m + 1]


def region_of(places: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Region index of each place given the region starts (int64, same shape as ``places``)."""
    return (np.searchsorted(np.asarray(starts), places, side="right") - 1).astype(np.int64)
