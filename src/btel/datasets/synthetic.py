"""Synthetic routes: the embedded default data, with known regions and controllable appearance change.

A route of N places is a sequence of r regions (contiguous, random lengths). Place i's descriptor is

    p_i = centroid[region(i)] + drift_i + detail_i

- ``centroid``: one random vector per region (what makes regions distinct);
- ``drift``: a smooth low-dimensional random walk projected to d dims (neighbouring places look
  alike, as consecutive frames do);
- ``detail``: an independent vector per place (what makes each place recognisable).

Traverse 0 is the map, seen under the reference condition. Each further traverse t is the same
route under another condition: ``x = (1 + shift·g_t) ⊙ p + shift·o_t + noise·ε`` with a per-traverse
gain g_t and offset o_t (appearance change, e.g. season or lighting) and per-frame noise ε. Every
component has unit variance per dimension before weighting, so ``noise`` and ``condition_shift``
are relative to the spread of the place descriptors. Generation is chunked and float32 throughout,
so a million places fit in memory (d = 256: 1 GB per traverse).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.validation import check_positive_int
from ..exceptions import InvalidParameterError, NotEnoughPlacesError

__all__ = ["SyntheticRoute", "synthetic_route"]

_CHUNK = 65536


@dataclass
class SyntheticRoute:
    """A generated route.

    Attributes
    ----------
    traverses : list of ndarray of shape (n_places, dim), float32
        Frame-aligned traverses; row i of every traverse is place i.
    region_starts : ndarray of shape (n_regions,), int64
        First place of each true region.
    """

    traverses: list[np.ndarray]
    region_starts: np.ndarray

    @property
    def map(self) -> np.ndarray:
        """The map traverse (traverse 0), shape (n_places, dim)."""
        return self.traverses[0]

    @property
    def queries(self) -> np.ndarray:
        """The first query traverse (traverse 1), shape (n_places, dim)."""
        if len(self.traverses) < 2:
            raise InvalidParameterError("this route has a single traverse; generate it with n_traverses ≥ 2.")
        return self.traverses[1]

    @property
    def n_places(self) -> int:
        return int(self.traverses[0].shape[0])

    @property
    def region_labels(self) -> np.ndarray:
        """True region of every place, shape (n_places,), int64."""
        labels = np.zeros(self.n_places, dtype=np.int64)
        labels[self.region_starts[1:]] = 1
        return np.cumsum(labels)


def _region_starts(n_places: int, n_regions: int, rng: np.random.Generator) -> np.ndarray:
    # Random lengths ≥ 2 that sum to N: Dirichlet shares of what is left after the minimum.
    spare = n_places - 2 * n_regions
    shares = rng.dirichlet(np.full(n_regions, 2.0))
    lengths = 2 + np.floor(shares * spare).astype(np.int64)
    lengths[-1] += n_places - lengths.sum()
    return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)


def synthetic_route(
    n_places: int = 2000,
    dim: int = 512,
    *,
    n_traverses: int = 2,
    n_regions: int = 10,
    condition_shift: float = 0.3,
    noise: float = 0.2,
    detail: float = 0.7,
    drift: float = 0.7,
    latent_dim: int = 16,
    seed: int | None = 0,
) -> SyntheticRoute:
    """Generate a route with region structure and query traverses under an appearance change.

    Parameters
    ----------
    n_places : int
        N ≥ 2.
    dim : int
        Descriptor dimension d.
    n_traverses : int
        Traverses generated; 0 is the map, 1… are queries.
    n_regions : int
        True regions (capped at N // 2).
    condition_shift : float
        Strength of the appearance change of traverses 1… (0 = same condition as the map).
    noise : float
        Per-frame noise of every traverse, relative to the descriptor spread.
    detail : float
        Weight of the per-place component (higher = places easier to tell apart).
    drift : float
        Weight of the smooth along-route component.
    latent_dim : int
        Dimension of the smooth random walk before projection.
    seed : int or None
        Random seed; the same seed gives the same route.

    Returns
    -------
    SyntheticRoute
    """
    n = check_positive_int(n_places, "n_places")
    if n < 2:
        raise NotEnoughPlacesError("a route needs at least 2 places.")
    d = check_positive_int(dim, "dim")
    t_count = check_positive_int(n_traverses, "n_traverses")
    r = min(check_positive_int(n_regions, "n_regions"), n // 2)
    for name, value in (("condition_shift", condition_shift), ("noise", noise), ("detail", detail), ("drift", drift)):
        if not np.isfinite(value) or value < 0:
            raise InvalidParameterError(f"{name} must be a finite number ≥ 0; got {value!r}.")
    rng = np.random.default_rng(seed)
    starts = _region_starts(n, r, rng)
    region = np.searchsorted(starts, np.arange(n), side="right") - 1
    centroids = rng.standard_normal((r, d), dtype=np.float32)
    # Smooth drift: a random walk in latent_dim dims, normalised to unit variance, then projected.
    walk = np.cumsum(rng.standard_normal((n, latent_dim)), axis=0)
    walk = (walk - walk.mean(axis=0)) / np.maximum(walk.std(axis=0), 1e-9)
    projection = (rng.standard_normal((latent_dim, d)) / np.sqrt(latent_dim)).astype(np.float32)
    conditions = [(np.zeros(d, np.float32), np.zeros(d, np.float32))] + [
        (rng.standard_normal(d).astype(np.float32) * 0.5, rng.standard_normal(d).astype(np.float32))
        for _ in range(t_count - 1)
    ]
    traverses = [np.empty((n, d), dtype=np.float32) for _ in range(t_count)]
    for c0 in range(0, n, _CHUNK):
        c1 = min(n, c0 + _CHUNK)
        chunk_rng = np.random.default_rng([0 if seed is None else seed, c0])
        place = centroids[region[c0:c1]]
        place += drift * (walk[c0:c1].astype(np.float32) @ projection)
        place += detail * chunk_rng.standard_normal((c1 - c0, d), dtype=np.float32)
        for t, (gain, offset) in enumerate(conditions):
            shift = condition_shift if t > 0 else 0.0
            frame = place * (1.0 + shift * gain) + shift * offset
            frame += noise * chunk_rng.standard_normal((c1 - c0, d), dtype=np.float32)
            traverses[t][c0:c1] = frame
    return SyntheticRoute(traverses=traverses, region_starts=starts)
