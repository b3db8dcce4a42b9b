"""Kernel Temporal Segmentation into regions, and the region classifier of BTEL (SPEC §5)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.exceptions import InvalidParameterError, NotEnoughPlacesError
from btel.methods.btel.segmentation import (
    MIN_REGION_LENGTH,
    kts_auto_regions,
    kts_penalised_costs,
    kts_regions,
    kts_segmentations,
    region_of,
)


def piecewise_constant(lengths, d: int = 16, noise: float = 0.05, seed: int = 0):
    """Signal with one random level per segment plus small noise; returns (X, true starts)."""
    rng = np.random.default_rng(seed)
    levels = 3.0 * rng.standard_normal((len(lengths), d))
    X = np.repeat(levels, lengths, axis=0) + noise * rng.standard_normal((int(np.sum(lengths)), d))
    return X.astype(np.float32), np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)


def _normalised(X: np.ndarray) -> np.ndarray:
    X = X.astype(np.float64)
    return X / np.linalg.norm(X, axis=1, keepdims=True)


def _scatter(Z: np.ndarray, starts: np.ndarray) -> float:
    bounds = np.append(starts, Z.shape[0])
    return float(sum(((Z[a:b] - Z[a:b].mean(axis=0)) ** 2).sum() for a, b in zip(bounds[:-1], bounds[1:])))


# ----------------------------------------------------------------------------- known change points
@pytest.mark.parametrize("pca_dims", [None, 8, 128])
@pytest.mark.parametrize("seed", range(4))
def test_kts_recovers_known_change_points(seed: int, pca_dims) -> None:
    rng = np.random.default_rng(100 + seed)
    lengths = rng.integers(2, 40, size=int(rng.integers(2, 9)))
    X, true_starts = piecewise_constant(lengths, seed=seed)
    starts = kts_regions(X, len(lengths), pca_dims=pca_dims, random_state=0)
    assert starts.dtype == np.int64
    np.testing.assert_array_equal(starts, true_starts)


@pytest.mark.parametrize("seed", range(4))
def test_kts_auto_picks_the_true_count_on_a_clear_signal(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    lengths = rng.integers(5, 40, size=int(rng.integers(1, 9)))
    X, true_starts = piecewise_constant(lengths, seed=seed)
    np.testing.assert_array_equal(kts_auto_regions(X), true_starts)


def test_kts_auto_penalty_trades_regions_for_cost() -> None:
    X, _ = piecewise_constant([10, 10, 10, 10], noise=0.5, seed=1)
    counts = [kts_auto_regions(X, penalty=v).size for v in (0.0, 0.01, 1.0, 100.0, 1e6)]
    # A larger penalty never gives more regions; none gives the most, a huge one gives one region.
    assert counts == sorted(counts, reverse=True)
    assert counts[0] == 20 and counts[-1] == 1


def test_r_equals_one_is_one_region() -> None:
    X, _ = piecewise_constant([5, 5])
    np.testing.assert_array_equal(kts_regions(X, 1), [0])


# ----------------------------------------------------------------------------- structure
@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 60), d=st.integers(1, 5), data=st.data(), seed=st.integers(0, 2**31))
def test_every_region_is_at_least_two_places(n: int, d: int, data, seed: int) -> None:
    r = data.draw(st.integers(1, n // MIN_REGION_LENGTH))
    X = np.random.default_rng(seed).standard_normal((n, d))
    starts = kts_regions(X, r, pca_dims=None)
    assert starts.shape == (r,) and starts[0] == 0
    lengths = np.diff(np.append(starts, n))
    assert np.all(lengths >= MIN_REGION_LENGTH)


def test_kts_segmentations_match_fixed_counts_and_costs() -> None:
    X, _ = piecewise_constant([6, 9, 4, 12, 7], noise=0.3, seed=3)
    starts_by_r, costs = kts_segmentations(X, 6, pca_dims=None)
    assert sorted(starts_by_r) == list(range(1, 7)) and costs.shape == (6,)
    Z = _normalised(X)
    for r, starts in starts_by_r.items():
        np.testing.assert_array_equal(starts, kts_regions(X, r, pca_dims=None))
        # V_m is the within-segment scatter of the L2-normalised descriptors (linear kernel).
        assert costs[r - 1] == pytest.approx(_scatter(Z, starts), rel=1e-6, abs=1e-9)
    assert np.all(np.diff(costs) <= 1e-9)


def test_kts_segmentations_cap_the_count_at_half_the_places() -> None:
    X = np.random.default_rng(0).standard_normal((7, 3))
    starts_by_r, costs = kts_segmentations(X, 50, pca_dims=None)
    assert max(starts_by_r) == 3 and costs.size == 3
    starts_by_r, costs = kts_segmentations(X[:3], 50)
    assert list(starts_by_r) == [1] and costs.size == 1


def test_kts_penalised_costs_formula() -> None:
    costs = np.array([10.0, 4.0, 3.0])
    n, v = 100, 2.0
    expected = [
        10.0 / n,
        4.0 / n + v * 1 / (2 * n) * (np.log(n / 1) + 1),
        3.0 / n + v * 2 / (2 * n) * (np.log(n / 2) + 1),
    ]
    np.testing.assert_allclose(kts_penalised_costs(costs, n, v), expected)


def test_region_of() -> None:
    starts = np.array([0, 3, 7])
    np.testing.assert_array_equal(region_of(np.array([0, 2, 3, 6, 7, 9]), starts), [0, 0, 1, 1, 2, 2])


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(("n", "r"), [(5, 3), (2, 2), (3, 2), (10, 6)])
def test_too_many_regions_for_the_places(n: int, r: int) -> None:
    X = np.random.default_rng(0).standard_normal((n, 4))
    with pytest.raises(NotEnoughPlacesError, match=rf"use n_regions ≤ {n // 2}"):
        kts_regions(X, r)


@pytest.mark.parametrize("r", [0, -1, 2.5])
def test_invalid_region_count(r) -> None:
    with pytest.raises(InvalidParameterError, match="n_regions must be an integer"):
        kts_regions(np.zeros((10, 2)), r)


def test_localizer_with_too_many_regions() -> None:
    X = np.random.default_rng(0).standard_normal((9, 4))
    with pytest.raises(NotEnoughPlacesError, match="cannot split 9 places into 5 regions"):
        BTELocalizer(n_regions=5, progress=False).fit(X)


# ----------------------------------------------------------------------------- regions model
@pytest.mark.parametrize("seed", [0, 1])
def test_regions_model_finds_the_true_regions_and_classifies_the_map(seed: int) -> None:
    route = synthetic_route(400, 64, n_traverses=1, n_regions=6, seed=seed)
    model = BTELocalizer(n_regions=6, progress=False, random_state=0).fit(route.map)
    assert model.n_regions_ == 6
    assert np.all(np.abs(model.region_starts_ - route.region_starts) <= 5)
    np.testing.assert_array_equal(model.region_sizes_, np.diff(np.append(model.region_starts_, 400)))
    # The region classifier is trained on the map: on the map itself it should be nearly always right.
    own = region_of(np.arange(400), model.region_starts_)
    assert np.mean(model.predict_region(route.map) == own) >= 0.9
    # Each prediction lands in the predicted region, at a valid place.
    pred = model.predict(route.map)
    np.testing.assert_array_equal(region_of(pred, model.region_starts_), model.predict_region(route.map))


def test_regions_model_auto_finds_at_least_the_true_change_points() -> None:
    # The synthetic route drifts inside regions, so the KTS penalty may split more finely; the
    # true boundaries must be among the ones found.
    route = synthetic_route(300, 64, n_traverses=1, n_regions=4, seed=5)
    model = BTELocalizer(n_regions="auto", progress=False, random_state=0).fit(route.map)
    found = model.region_starts_
    assert model.n_regions_ == found.size >= 4
    for start in route.region_starts:
        assert np.min(np.abs(found - start)) <= 3
