"""Ranked output of BTEL (btel.methods.btel.ranking): k-best codes by flip cost, regions, R@K."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import decode_constrained, decode_soft, n_bits_for
from btel.evaluation import recall_at_k
from btel.exceptions import InvalidParameterError, NotEnoughPlacesError, NotFittedError
from btel.methods.btel.ranking import code_costs, kbest_codes, merge_region_kbest, soft_scores


def brute_force_top(margins: np.ndarray, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-k indices by sorting every soft score (ties: smallest index), and their scores."""
    scores = soft_scores(margins, n)
    order = np.lexsort((np.broadcast_to(np.arange(n), scores.shape), -scores), axis=1)[:, :k]
    return order, np.take_along_axis(scores, order, axis=1)


# ------------------------------------------------------------------------- k-best enumeration
@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 300),
    k=st.integers(1, 40),
    seed=st.integers(0, 2**31 - 1),
    ties=st.booleans(),
)
def test_kbest_equals_brute_force_sort_of_soft_scores(n, k, seed, ties):
    rng = np.random.default_rng(seed)
    b = n_bits_for(n)
    margins = rng.standard_normal((5, b))
    if ties:  # few distinct magnitudes: many codes share a score
        margins = np.round(margins * 2) / 2
    idx, cost = kbest_codes(margins, n, k)
    k_eff = min(k, n)
    assert idx.shape == (5, k_eff) and cost.shape == (5, k_eff)
    assert idx.min() >= 0 and idx.max() < n
    assert all(len(set(row)) == k_eff for row in idx.tolist())
    ref_idx, ref_scores = brute_force_top(margins, n, k_eff)
    total = np.abs(margins).sum(axis=1, keepdims=True)
    # Scores of the returned list equal the brute-force top scores, position by position ...
    np.testing.assert_allclose(total - cost, ref_scores, atol=1e-9)
    # ... and each returned index really has that score.
    got_scores = np.take_along_axis(soft_scores(margins, n), idx, axis=1)
    np.testing.assert_allclose(got_scores, ref_scores, atol=1e-9)
    if not ties:  # distinct scores: the very same indices
        gaps = np.diff(np.sort(soft_scores(margins, n), axis=1), axis=1)
        if np.all(np.abs(gaps) > 1e-9):
            np.testing.assert_array_equal(idx, ref_idx)


def test_first_candidate_is_the_soft_decode():
    rng = np.random.default_rng(1)
    n = 1000
    margins = rng.standard_normal((200, n_bits_for(n)))
    idx, cost = kbest_codes(margins, n, 3)
    np.testing.assert_array_equal(idx[:, 0], decode_soft(margins, n))
    assert np.all(np.diff(cost, axis=1) >= 0)


def test_hard_code_first_when_valid_and_costs_are_flip_costs():
    margins = np.array([[0.5, -2.0, -0.1]])  # N = 8: every code valid; hard code = 0b100 = 4
    idx, cost = kbest_codes(margins, 8, 8)
    assert idx[0, 0] == 4 and cost[0, 0] == 0
    # Next: flip the LSB (cost 0.2) → 5, then the MSB (1.0) → 0, then both → 1.
    assert idx[0, 1:4].tolist() == [5, 0, 1]
    np.testing.assert_allclose(cost[0, 1:4], [0.2, 1.0, 1.2])
    assert sorted(idx[0].tolist()) == list(range(8))


def test_invalid_codes_are_skipped():
    # N = 5 (b = 3): the hard code 0b111 = 7 is invalid; the best valid codes come after it.
    margins = np.array([[3.0, 2.0, 0.5]])
    idx, cost = kbest_codes(margins, 5, 5)
    assert sorted(idx[0].tolist()) == [0, 1, 2, 3, 4]
    # 0b100 flips bits 2 and 3 (cost 4 + 1); 0b011 flips the MSB (cost 6); 0b10x are invalid.
    assert idx[0, :2].tolist() == [4, 3] and cost[0, :2].tolist() == [5.0, 6.0]
    assert idx[0, 0] == decode_soft(margins, 5)[0] == decode_constrained(margins, 5)[0]


def test_k_larger_than_n_is_capped():
    idx, _ = kbest_codes(np.array([[0.3, -0.2]]), 3, 10)
    assert idx.shape == (1, 3) and sorted(idx[0].tolist()) == [0, 1, 2]


@pytest.mark.parametrize(
    ("margins", "n", "k", "error", "match"),
    [
        (np.zeros(3), 8, 2, InvalidParameterError, "2-D"),
        (np.zeros((2, 2)), 8, 2, InvalidParameterError, "needs 3 bit margins"),
        (np.zeros((2, 3)), 1, 2, NotEnoughPlacesError, "at least 2"),
        (np.zeros((2, 3)), 8, 0, InvalidParameterError, "k"),
        (np.array([[np.nan, 0, 0]]), 8, 2, InvalidParameterError, "NaN"),
    ],
)
def test_bad_input_raises(margins, n, k, error, match):
    with pytest.raises(error, match=match):
        kbest_codes(margins, n, k)


# ------------------------------------------------------------------------- fitted BTEL models
@pytest.fixture(scope="module")
def route():
    return synthetic_route(300, 64, n_regions=4, seed=3)


@pytest.fixture(scope="module")
def plain(route):
    return BTELocalizer(feature_ratio=0.5, progress=False, random_state=0).fit(route.map)


@pytest.fixture(scope="module")
def regional(route):
    return BTELocalizer(feature_ratio=0.5, n_regions=4, progress=False, random_state=0).fit(route.map)


def _layout(model, Q):
    """(column margins, region deficits) of a fitted BTEL model, what the pure functions take."""
    from btel.methods.btel.ranking import deficits_from_scores

    Qt = model.front_end_.transform(Q)
    scores = None if model.n_regions_ == 1 else model.region_hyperplanes_.margins(Qt)
    return model.column_margins(Q).astype(np.float64), deficits_from_scores(scores, model.n_regions_, Q.shape[0])


def test_search_r1_is_the_decode_then_kbest_of_decision_function(plain, route):
    scores, places = plain.search(route.queries, 7)
    idx, cost = kbest_codes(plain.decision_function(route.queries), 300, 7)
    # The constrained decode comes first (rank[:, 0] == predict), then the k-best by flip cost.
    point = plain.predict(route.queries)
    np.testing.assert_array_equal(places[:, 0], point)
    for row, best, first in zip(places, idx, point):
        np.testing.assert_array_equal(row[1:], [p for p in best if p != first][:6])
    # Where the hard code is a valid index (most queries) the decode is the cheapest code.
    same = idx[:, 0] == point
    assert same.mean() > 0.9
    np.testing.assert_array_equal(places[same], idx[same])
    np.testing.assert_allclose(-scores[same], cost[same], rtol=1e-6, atol=1e-6)


def test_soft_decode_search_is_exactly_kbest(route):
    soft = BTELocalizer(feature_ratio=0.5, decode="soft", progress=False, random_state=0).fit(route.map)
    scores, places = soft.search(route.queries, 7)
    idx, cost = kbest_codes(soft.decision_function(route.queries), 300, 7)
    np.testing.assert_array_equal(places, idx)
    np.testing.assert_allclose(-scores, cost, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("searched", [1, 2, 4])
@pytest.mark.parametrize("alpha", [0.0, 1.0, 5.0])
def test_merged_region_kbest_matches_sorted_code_costs(regional, route, searched, alpha):
    Q = route.queries[:40]
    margins, deficits = _layout(regional, Q)
    layout = (regional.region_starts_, regional.region_sizes_, regional.tree_offsets_)
    codes, costs = merge_region_kbest(margins, deficits, *layout, 10, n_regions_searched=searched,
                                      region_weight=alpha)
    full = code_costs(margins, deficits, *layout, region_weight=alpha)
    # The returned costs are the codes' costs under the documented rule.
    np.testing.assert_allclose(np.take_along_axis(full, codes, axis=1), costs, rtol=1e-6, atol=1e-6)
    assert np.all(np.diff(costs, axis=1) >= -1e-9)
    if searched == 4:  # every region searched: the k best places overall
        np.testing.assert_allclose(costs, np.sort(full, axis=1)[:, :10], rtol=1e-6, atol=1e-6)


def test_search_scores_are_minus_the_place_costs(regional, route):
    Q = route.queries[:40]
    scores, places = regional.search(Q, 10)
    np.testing.assert_allclose(np.take_along_axis(regional.place_scores(Q), places, axis=1), scores,
                               rtol=1e-6, atol=1e-6)


def test_predicted_region_comes_first_and_matches_predict(regional, route):
    Q = route.queries
    places = regional.rank(Q, 5)
    starts = regional.region_starts_
    region_of = np.searchsorted(starts, places, side="right") - 1
    np.testing.assert_array_equal(region_of[:, 0], regional.predict_region(Q))
    # With the soft decode, the top candidate is the localizer's own prediction.
    soft = BTELocalizer(feature_ratio=0.5, n_regions=4, decode="soft", progress=False, random_state=0)
    soft.fit(route.map)
    np.testing.assert_array_equal(soft.rank(Q, 5)[:, 0], soft.predict(Q))


def test_r_at_k_grows_with_k_and_r_at_1_is_the_point_prediction(plain, route):
    places = plain.rank(route.queries, 20)
    r = recall_at_k(places, None, ks=(1, 5, 10, 20))
    assert r[1] <= r[5] <= r[10] <= r[20]
    assert r[1] == pytest.approx(np.mean(plain.predict(route.queries) == np.arange(300)))


def test_ranking_errors(route):
    with pytest.raises(NotFittedError):
        BTELocalizer().rank(route.queries[:3], 2)


def test_bad_region_weight(plain, route):
    margins, deficits = _layout(plain, route.queries[:2])
    with pytest.raises(InvalidParameterError, match="region_weight"):
        code_costs(margins, deficits, plain.region_starts_, plain.region_sizes_, plain.tree_offsets_,
                   region_weight=-1)


# ------------------------------------------------------------------------- real data
@pytest.mark.realdata
def test_ranking_on_gardens_point(gardenspoint_netvlad):
    X, Q = gardenspoint_netvlad
    model = BTELocalizer(feature_ratio=0.3, progress=False, random_state=0).fit(X)
    scores, places = model.search(Q, 10)
    costs = -scores
    n = X.shape[0]
    ref_idx, ref_scores = brute_force_top(model.decision_function(Q).astype(np.float64), n, 10)
    # Where the constrained decode is the cheapest code (all but a few queries whose hard code is
    # ≥ N), the ranking is the brute-force top 10 by soft score.
    same = ref_idx[:, 0] == places[:, 0]
    assert same.mean() > 0.9
    np.testing.assert_allclose(np.abs(model.decision_function(Q).astype(np.float64)).sum(1, keepdims=True)[same]
                               - costs[same], ref_scores[same], rtol=1e-5, atol=1e-5)
    r = recall_at_k(places, None, ks=(1, 10), tolerance=2)
    single = np.mean(np.abs(model.predict(Q) - np.arange(n)) <= 2)
    assert r[1] == pytest.approx(single)  # R@1 is the point prediction's recall
    assert r[10] >= r[1]
