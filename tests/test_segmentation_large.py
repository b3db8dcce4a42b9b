"""KTS on long routes: the block path (block means + exact DP + local refinement) against the exact DP."""

from __future__ import annotations

import numpy as np
import pytest

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.segmentation import (
    MIN_REGION_LENGTH,
    kts_auto_regions,
    kts_penalised_costs,
    kts_regions,
    kts_segmentations,
)


@pytest.fixture(scope="module")
def route():
    # Known regions of random lengths (seed 1: every region ≥ 130 places, so KTS can recover them);
    # 1500 places keeps the exact DP at a fraction of a second.
    route = synthetic_route(1500, 96, n_regions=6, seed=1)
    assert np.diff(np.append(route.region_starts, 1500)).min() >= 100
    return route


@pytest.mark.parametrize("max_points", [300, 120])
def test_block_path_agrees_with_exact_path(route, max_points: int) -> None:
    exact = kts_regions(route.map, 6)
    block = kts_regions(route.map, 6, max_points=max_points)
    block_size = -(-1500 // max_points)
    assert block.shape == exact.shape == (6,)
    # Both find the true region boundaries; the block path lands within a block of the exact one.
    assert np.max(np.abs(exact - route.region_starts)) <= 2
    assert np.max(np.abs(block - exact)) <= block_size
    assert np.max(np.abs(block - route.region_starts)) <= 2


def test_unrefined_block_path_stays_on_block_boundaries(route) -> None:
    coarse = kts_regions(route.map, 6, max_points=150, refine=False)
    assert np.all(coarse % 10 == 0)  # B = ⌈1500 / 150⌉ = 10
    refined = kts_regions(route.map, 6, max_points=150)
    # Refinement can only improve the frame-level KTS objective it optimises.
    def scatter(starts):
        Z = route.map / np.linalg.norm(route.map, axis=1, keepdims=True)
        return sum(((seg - seg.mean(0)) ** 2).sum() for seg in np.split(Z, starts[1:]))
    assert scatter(refined) <= scatter(coarse) + 1e-9


def test_block_path_respects_minimum_region_length() -> None:
    # Many regions on a short route: blocks of 2, refinement must keep every region ≥ 2 places.
    X = np.random.default_rng(0).standard_normal((400, 16)).astype(np.float32)
    starts = kts_regions(X, 60, max_points=200, pca_dims=None)
    lengths = np.diff(np.append(starts, 400))
    assert starts[0] == 0 and np.all(lengths >= MIN_REGION_LENGTH)


def test_automatic_r_is_the_same_on_both_paths(route) -> None:
    exact_starts, exact_costs = kts_segmentations(route.map, 12)
    block_starts, block_costs = kts_segmentations(route.map, 12, max_points=300)
    for v in (0.5, 1.0, 4.0):
        r_exact = int(np.argmin(kts_penalised_costs(exact_costs, 1500, v))) + 1
        r_block = int(np.argmin(kts_penalised_costs(block_costs, 1500, v))) + 1
        assert r_exact == r_block
    # The costs drop with every change point on both paths, by similar amounts.
    assert np.all(np.diff(block_costs) <= 1e-9)
    np.testing.assert_allclose(np.diff(block_costs)[:5], np.diff(exact_costs)[:5], rtol=0.05)
    assert np.max(np.abs(block_starts[6] - exact_starts[6])) <= 5
    auto = kts_auto_regions(route.map, max_regions=12, max_points=300)
    assert auto.size == int(np.argmin(kts_penalised_costs(block_costs, 1500, 1.0))) + 1


def test_block_path_reads_a_memory_mapped_route(route, tmp_path) -> None:
    np.save(tmp_path / "map.npy", route.map)
    mapped = np.load(tmp_path / "map.npy", mmap_mode="r")
    np.testing.assert_array_equal(kts_regions(mapped, 6, max_points=300), kts_regions(route.map, 6, max_points=300))


def test_localizer_uses_the_block_path_above_its_threshold(route) -> None:
    exact = BTELocalizer(n_regions=6, feature_ratio=0.2, progress=False, random_state=0).fit(route.map)
    block = BTELocalizer(n_regions=6, feature_ratio=0.2, kts_max_points=300, progress=False,
                         random_state=0).fit(route.map)
    assert np.max(np.abs(exact.region_starts_ - block.region_starts_)) <= 5
