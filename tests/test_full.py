"""Full training, BTE-F: one classifier per internal tree node (SPEC §3)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import encode, n_bits_for
from btel.exceptions import InvalidParameterError
from btel.methods.btel.full import full_n_classifiers, full_nodes, full_tasks, predict_full
from btel.learning.hyperplanes import Hyperplanes
from btel.methods.btel.localizer import planned_bytes


def brute_force_stored_nodes(n: int) -> list[tuple[int, int]]:
    """Every internal node (level, prefix) whose places do not all share one label, heap order."""
    b = n_bits_for(n)
    bits = encode(np.arange(n), b)
    stored = []
    for level in range(b):
        for prefix in range(1 << level):
            under = [i for i in range(n) if i >> (b - level) == prefix]
            if len({int(bits[i, level]) for i in under}) == 2:
                stored.append((level, prefix))
    return stored


# ----------------------------------------------------------------------------- tree structure
@settings(max_examples=200, deadline=None)
@given(n=st.integers(2, 1 << 16))
def test_full_nodes_gives_n_minus_one_classifiers_in_heap_order(n: int) -> None:
    levels, prefixes = full_nodes(n)
    assert levels.size == prefixes.size == n - 1 == full_n_classifiers(n)
    heap = (1 << levels) - 1 + prefixes
    assert np.all(np.diff(heap) > 0)
    assert np.all((levels >= 0) & (levels < n_bits_for(n)))


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 7, 8, 9, 13, 31, 33, 64, 100, 129])
def test_stored_nodes_are_exactly_those_with_two_labels(n: int) -> None:
    levels, prefixes = full_nodes(n)
    assert list(zip(levels.tolist(), prefixes.tolist())) == brute_force_stored_nodes(n)


@pytest.mark.parametrize("n", [2, 5, 12, 37])
@pytest.mark.parametrize("n_traverses", [1, 3])
def test_full_tasks_see_the_places_below_their_node(n: int, n_traverses: int) -> None:
    places = np.tile(np.arange(n), n_traverses)
    rows = np.arange(places.size) + 1000  # rows of a larger X (e.g. one region of it)
    b = n_bits_for(n)
    tasks = full_tasks(places, n, rows)
    levels, prefixes = full_nodes(n)
    assert len(tasks) == n - 1
    for task, level, prefix in zip(tasks, levels, prefixes):
        seen = places[task.rows - 1000]
        expected_places = [i for i in range(n) if i >> (b - level) == prefix]
        assert sorted(set(seen.tolist())) == expected_places
        assert np.bincount(seen).max() == n_traverses  # every traverse of those places
        np.testing.assert_array_equal(task.labels, encode(seen, b)[:, level])
        assert set(np.unique(task.labels)) == {0, 1}


# ----------------------------------------------------------------------------- descent
def oracle_hyperplanes(n: int, n_junk: int = 0) -> Hyperplanes:
    """Node classifiers that read column `level` of the query (a ±1 code) with weight 1."""
    levels, _ = full_nodes(n)
    K = levels.size + n_junk
    columns = np.concatenate([np.zeros(n_junk, dtype=np.uint16), levels.astype(np.uint16)]).reshape(K, 1)
    weights = np.concatenate([np.full(n_junk, -5.0), np.ones(levels.size)]).astype(np.float32).reshape(K, 1)
    return Hyperplanes(weights=weights, bias=np.zeros(K, np.float32), columns=columns, n_features_in=n_bits_for(n))


@pytest.mark.parametrize("n", [2, 3, 5, 6, 11, 64, 100, 1000])
@pytest.mark.parametrize("n_junk", [0, 3])
def test_descent_reaches_the_encoded_place(n: int, n_junk: int) -> None:
    idx = np.arange(n)
    Q = (2.0 * encode(idx, n_bits_for(n)) - 1.0).astype(np.float32)
    pred, margins = predict_full(Q, oracle_hyperplanes(n, n_junk), n_junk, n)
    np.testing.assert_array_equal(pred, idx)
    # Margins: ±1 at the stored nodes visited, −inf where the node on the path is constant (bit 0).
    finite = np.isfinite(margins)
    np.testing.assert_array_equal(margins[finite], Q[finite])
    assert np.all(Q[~finite] == -1.0)


@settings(max_examples=100, deadline=None)
@given(n=st.integers(2, 300), d=st.integers(1, 8), seed=st.integers(0, 2**31))
def test_descent_with_random_classifiers_stays_below_n(n: int, d: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    K = full_n_classifiers(n)
    d_sel = int(rng.integers(1, d + 1))
    hp = Hyperplanes(
        weights=rng.standard_normal((K, d_sel)).astype(np.float32),
        bias=rng.standard_normal(K).astype(np.float32),
        columns=rng.integers(0, d, size=(K, d_sel)).astype(np.uint16),
        n_features_in=d,
    )
    Q = (100.0 * rng.standard_normal((50, d))).astype(np.float32)
    pred, margins = predict_full(Q, hp, 0, n)
    assert pred.dtype == np.int64 and np.all((pred >= 0) & (pred < n))
    assert margins.shape == (50, n_bits_for(n))
    # The predicted bits are the signs of the margins along the path (−inf → 0).
    np.testing.assert_array_equal(encode(pred, n_bits_for(n)), (margins > 0).astype(np.uint8))


# ----------------------------------------------------------------------------- fitted BTE-F
@pytest.mark.parametrize("n", [2, 3, 17, 64, 100])
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_fitted_full_model_stores_the_planned_classifiers(n: int, dtype: str) -> None:
    X = synthetic_route(n, 32, n_traverses=1, seed=n).map
    model = BTELocalizer(scheme="full", dtype=dtype, progress=False, random_state=0).fit(X)
    assert len(model.hyperplanes_) == full_n_classifiers(n) == n - 1
    assert model.nbytes == planned_bytes(n, 32, n_selected=model.n_selected_, scheme="full", dtype=dtype)
    # Far-off queries still decode to valid places.
    Q = 1e3 * np.random.default_rng(0).standard_normal((200, 32))
    pred = model.predict(Q)
    assert np.all((pred >= 0) & (pred < n))


def test_full_model_with_regions_stores_one_tree_per_region() -> None:
    route = synthetic_route(120, 32, n_traverses=1, n_regions=3, seed=1)
    model = BTELocalizer(scheme="full", n_regions=3, progress=False, random_state=0).fit(route.map)
    assert len(model.hyperplanes_) == sum(int(n_k) - 1 for n_k in model.region_sizes_) == 120 - 3
    assert model.nbytes == planned_bytes(int(sum(model.region_sizes_)), 32, n_selected=model.n_selected_,
                                         region_sizes=list(model.region_sizes_), scheme="full")
    pred = model.predict(route.map)
    assert np.all((pred >= 0) & (pred < 120))


@pytest.mark.parametrize(("n", "d"), [(64, 128), (200, 256)])
@pytest.mark.parametrize("feature_ratio", [None, 1.0])
def test_full_scheme_is_near_exact_on_an_easy_problem(n: int, d: int, feature_ratio) -> None:
    # N ≤ d and queries = map + 5 % noise: every node's two halves are linearly separable.
    route = synthetic_route(n, d, n_traverses=1, seed=3)
    rng = np.random.default_rng(4)
    Q = route.map + 0.05 * route.map.std(axis=0) * rng.standard_normal(route.map.shape).astype(np.float32)
    model = BTELocalizer(scheme="full", feature_ratio=feature_ratio, progress=False, random_state=0).fit(route.map)
    assert np.mean(model.predict(Q) == np.arange(n)) >= 0.95


def test_full_decision_function_is_minus_inf_at_constant_nodes() -> None:
    n = 5  # codes 000..100: below the root's 0-branch every node splits; below 1 nothing does
    X = synthetic_route(n, 16, n_traverses=1, seed=0).map
    model = BTELocalizer(scheme="full", feature_ratio=1.0, progress=False).fit(X)
    margins = model.decision_function(X)
    pred = model.predict(X)
    assert margins.shape == (n, 3)
    high = pred >= 4  # on the 1-branch of the root the lower levels are constant 0
    assert np.all(np.isneginf(margins[high, 1:]))
    assert np.all(np.isfinite(margins[~high]))


def test_soft_decode_needs_the_compressed_scheme() -> None:
    X = np.random.default_rng(0).standard_normal((10, 4))
    with pytest.raises(InvalidParameterError, match="decode='soft' needs every bit margin"):
        BTELocalizer(scheme="full", decode="soft", progress=False).fit(X)
