"""The synthetic route generator: shapes, regions, determinism and the appearance model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel.datasets import SyntheticRoute, synthetic_route
from btel.exceptions import InvalidParameterError, NotEnoughPlacesError


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 400),
    d=st.integers(1, 16),
    n_regions=st.integers(1, 300),
    n_traverses=st.integers(1, 3),
    seed=st.integers(0, 2**31),
)
def test_shapes_and_true_regions(n: int, d: int, n_regions: int, n_traverses: int, seed: int) -> None:
    route = synthetic_route(n, d, n_traverses=n_traverses, n_regions=n_regions, seed=seed)
    assert isinstance(route, SyntheticRoute)
    assert len(route.traverses) == n_traverses and route.n_places == n
    for t in route.traverses:
        assert t.shape == (n, d) and t.dtype == np.float32 and np.isfinite(t).all()
    starts = route.region_starts
    assert starts.dtype == np.int64
    assert starts.size == min(n_regions, n // 2)
    assert starts[0] == 0
    lengths = np.diff(np.append(starts, n))
    assert np.all(lengths >= 2)
    labels = route.region_labels
    assert labels.shape == (n,)
    np.testing.assert_array_equal(np.bincount(labels), lengths)
    np.testing.assert_array_equal(np.flatnonzero(np.diff(labels)) + 1, starts[1:])


def test_same_seed_same_route_other_seed_other_route() -> None:
    a = synthetic_route(300, 32, seed=7)
    b = synthetic_route(300, 32, seed=7)
    c = synthetic_route(300, 32, seed=8)
    for x, y in zip(a.traverses, b.traverses):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.region_starts, b.region_starts)
    assert not np.allclose(a.map, c.map)


def test_no_shift_no_noise_gives_identical_traverses() -> None:
    route = synthetic_route(100, 16, n_traverses=3, condition_shift=0.0, noise=0.0, seed=0)
    np.testing.assert_array_equal(route.queries, route.map)
    np.testing.assert_array_equal(route.traverses[2], route.map)


def test_noise_is_relative_to_the_descriptor_spread() -> None:
    # Every traverse carries its own noise: map − query has std noise·√2 when nothing else changes.
    noise = 0.3
    route = synthetic_route(2000, 64, condition_shift=0.0, noise=noise, seed=1)
    assert np.std(route.queries - route.map) == pytest.approx(noise * np.sqrt(2), rel=0.02)


def test_condition_shift_changes_appearance() -> None:
    base = synthetic_route(500, 64, condition_shift=0.0, seed=2)
    shifted = synthetic_route(500, 64, condition_shift=1.0, seed=2)
    change_base = np.mean((base.queries - base.map) ** 2)
    change_shifted = np.mean((shifted.queries - shifted.map) ** 2)
    assert change_shifted > 2 * change_base


def test_places_are_recognisable_and_regions_distinct_at_the_defaults() -> None:
    route = synthetic_route(400, 64, seed=3)
    # Nearest neighbour in the map recovers most query places (what BTEL is measured against).
    dist = ((route.queries[:, None, :] - route.map[None, :, :]) ** 2).sum(axis=-1)
    assert np.mean(dist.argmin(axis=1) == np.arange(400)) > 0.9
    # The region centroids dominate: nearest region mean classifies the map's places.
    labels = route.region_labels
    means = np.stack([route.map[labels == k].mean(axis=0) for k in range(labels.max() + 1)])
    nearest = ((route.map[:, None, :] - means[None]) ** 2).sum(axis=-1).argmin(axis=1)
    assert np.mean(nearest == labels) > 0.9


def test_chunked_generation_continues_past_the_first_chunk() -> None:
    # Rows are generated in chunks of 65 536; the next chunk must be fresh, not a copy.
    route = synthetic_route(65536 + 500, 4, n_traverses=1, n_regions=1, drift=0.0, seed=0)
    first, second = route.map[:500], route.map[65536:]
    assert not np.allclose(first, second)
    assert np.std(second) == pytest.approx(np.std(first), rel=0.15)


def test_unseeded_routes_differ() -> None:
    assert not np.array_equal(synthetic_route(50, 8, seed=None).map, synthetic_route(50, 8, seed=None).map)


def test_single_traverse_has_no_queries() -> None:
    route = synthetic_route(10, 4, n_traverses=1)
    with pytest.raises(InvalidParameterError, match="n_traverses ≥ 2"):
        route.queries


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"n_places": 1}, NotEnoughPlacesError, "at least 2 places"),
        ({"n_places": 0}, InvalidParameterError, "n_places must be an integer"),
        ({"dim": 0}, InvalidParameterError, "dim must be an integer"),
        ({"n_traverses": 0}, InvalidParameterError, "n_traverses must be an integer"),
        ({"n_regions": 0}, InvalidParameterError, "n_regions must be an integer"),
        ({"noise": -0.1}, InvalidParameterError, "noise must be a finite number"),
        ({"condition_shift": float("nan")}, InvalidParameterError, "condition_shift must be a finite number"),
        ({"detail": float("inf")}, InvalidParameterError, "detail must be a finite number"),
        ({"drift": -1.0}, InvalidParameterError, "drift must be a finite number"),
    ],
)
def test_invalid_parameters(kwargs, error, message: str) -> None:
    params = {"n_places": 20, "dim": 4, **kwargs}
    with pytest.raises(error, match=message):
        synthetic_route(**params)
