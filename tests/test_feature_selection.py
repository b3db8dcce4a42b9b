"""Between-cluster sums of squares, Witten–Tibshirani weights and the kept columns (SPEC §4)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from btel.exceptions import InvalidParameterError
from btel.learning.feature_selection import between_cluster_ss, column_index_dtype, select_features, sparse_weights

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False, allow_subnormal=False)


def tss_minus_wcss(X: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Definition: total minus within-cluster sum of squares, per column, in float64."""
    X = X.astype(np.float64)
    tss = ((X - X.mean(axis=0)) ** 2).sum(axis=0)
    wcss = np.zeros(X.shape[1])
    for k in np.unique(labels):
        part = X[labels == k]
        wcss += ((part - part.mean(axis=0)) ** 2).sum(axis=0)
    return tss - wcss


@st.composite
def labelled_data(draw, n_clusters: int | None = 2):
    n = draw(st.integers(min_value=2, max_value=40))
    d = draw(st.integers(min_value=1, max_value=6))
    X = draw(arrays(np.float64, (n, d), elements=finite))
    if n_clusters == 2:
        labels = np.array(draw(st.lists(st.integers(0, 1), min_size=n, max_size=n)))
        assume(0 < labels.sum() < n)
    else:
        # Any integers, not necessarily contiguous, one to several clusters.
        labels = np.array(draw(st.lists(st.sampled_from([-3, 0, 2, 7, 11]), min_size=n, max_size=n)))
    return X, labels


def _tolerance(X: np.ndarray) -> np.ndarray:
    # BCSS is a difference of sums of squares: its rounding error scales with Σ x².
    return 1e-9 * (X.astype(np.float64) ** 2).sum(axis=0) + 1e-9


# ----------------------------------------------------------------------------- BCSS
@settings(max_examples=200, deadline=None)
@given(labelled_data())
def test_two_cluster_bcss_closed_form_equals_tss_minus_wcss(case) -> None:
    X, labels = case
    n = labels.size
    n1 = labels.sum()
    n0 = n - n1
    closed = n0 * n1 / n * (X[labels == 0].mean(axis=0) - X[labels == 1].mean(axis=0)) ** 2
    definition = tss_minus_wcss(X, labels)
    tol = _tolerance(X)
    assert np.all(np.abs(closed - definition) <= tol)
    assert np.all(np.abs(between_cluster_ss(X, labels) - definition) <= tol)


@settings(max_examples=150, deadline=None)
@given(labelled_data(n_clusters=None))
def test_multiclass_bcss_equals_definition(case) -> None:
    X, labels = case
    mu = X.mean(axis=0)
    weighted = sum((labels == k).sum() * (X[labels == k].mean(axis=0) - mu) ** 2 for k in np.unique(labels))
    bcss = between_cluster_ss(X, labels)
    tol = _tolerance(X)
    assert bcss.shape == (X.shape[1],) and bcss.dtype == np.float64
    assert np.all(bcss >= 0)
    assert np.all(np.abs(bcss - weighted) <= tol)
    assert np.all(np.abs(bcss - tss_minus_wcss(X, labels)) <= tol)


def test_bcss_hand_made() -> None:
    # Column 0 separates the clusters (means 0 and 2), column 1 does not.
    X = np.array([[0.0, 1.0], [0.0, -1.0], [2.0, 1.0], [2.0, -1.0]])
    labels = np.array([0, 0, 1, 1])
    np.testing.assert_allclose(between_cluster_ss(X, labels), [2 * 2 / 4 * 4.0, 0.0])
    # One cluster: nothing between clusters.
    np.testing.assert_allclose(between_cluster_ss(X, np.zeros(4, dtype=int)), [0.0, 0.0])


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_clusters=st.integers(2, 5))
def test_scale_argument_equals_scoring_standardised_columns(seed: int, n_clusters: int) -> None:
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((30, 8)) * rng.uniform(0.01, 100.0, size=8)
    labels = rng.integers(0, n_clusters, size=30)
    scale = X.std(axis=0)
    np.testing.assert_allclose(
        between_cluster_ss(X, labels, scale=scale), between_cluster_ss(X / scale, labels), rtol=1e-9, atol=1e-9
    )
    np.testing.assert_array_equal(
        select_features(X, labels, 3, scale=scale), select_features(X / scale, labels, 3)
    )


def test_scale_keeps_raw_magnitude_from_deciding_the_columns() -> None:
    rng = np.random.default_rng(0)
    labels = np.repeat([0, 1], 50)
    informative = labels + 0.1 * rng.standard_normal(100)  # separates the clusters, small scale
    loud = 1000.0 * rng.standard_normal(100)  # no information, huge scale
    X = np.column_stack([informative, loud])
    # Raw BCSS of the loud column dwarfs the informative one by chance alone ...
    assert select_features(X, labels, 1)[0] == 1
    # ... standardised, the informative column wins.
    assert select_features(X, labels, 1, scale=X.std(axis=0))[0] == 0


# ----------------------------------------------------------------------------- W–T weights
@st.composite
def scores_and_sparsity(draw):
    d = draw(st.integers(min_value=1, max_value=200))
    a = draw(arrays(np.float64, d, elements=st.floats(min_value=0, max_value=1e300, allow_subnormal=False)))
    assume(a.max() > 0)
    # A unique largest score: with k tied maxima no unit vector reaches ‖w‖₁ < √k.
    assume((a == a.max()).sum() == 1)
    s = draw(st.floats(min_value=1.0, max_value=float(np.sqrt(d))))
    return a, s


@settings(max_examples=200, deadline=None)
@given(scores_and_sparsity())
def test_sparse_weights_unit_norm_and_l1_bound(case) -> None:
    a, s = case
    w = sparse_weights(a, s)
    assert w.shape == a.shape and np.all(w >= 0)
    assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-9)
    assert w.sum() <= s + 1e-9
    # A soft threshold keeps the order of the scores (larger score, no smaller weight).
    order = np.argsort(a, kind="stable")
    assert np.all(np.diff(w[order]) >= -1e-12)


def test_sparse_weights_bound_is_active_when_it_binds() -> None:
    a = np.array([4.0, 3.0, 2.0, 1.0])
    w = sparse_weights(a, 1.5)
    assert w.sum() == pytest.approx(1.5, abs=1e-9)
    assert np.linalg.norm(w) == pytest.approx(1.0)
    # Solved by hand: with x = 3 − Δ on the support {4, 3, 2}, 3x / √(3x² + 2) = 1.5 gives x = √2,
    # so Δ = 3 − √2 and w = (1 + √2, √2, √2 − 1, 0) / (2√2).
    r2 = np.sqrt(2.0)
    np.testing.assert_allclose(w, np.array([1 + r2, r2, r2 - 1, 0.0]) / (2 * r2), atol=1e-9)


def test_sparse_weights_without_a_binding_bound_is_the_normalised_scores() -> None:
    a = np.array([1.0, 2.0, 2.0])
    np.testing.assert_allclose(sparse_weights(a, np.sqrt(3)), a / np.linalg.norm(a))


@pytest.mark.parametrize("s", [0.1, 0.5, 0.999])
def test_sparsity_below_one_gives_the_sparsest_solution(s: float) -> None:
    # W&T's valid range is [1, √d]; the paper's s = 0.1 yields the largest score alone.
    a = np.array([0.5, 3.0, 1.0, 2.9])
    np.testing.assert_allclose(sparse_weights(a, s), [0.0, 1.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("factor", [1e-250, 1e-30, 1e30, 1e250])
@pytest.mark.parametrize("s", [0.1, 1.3, 2.0])
def test_sparse_weights_do_not_depend_on_the_scale_of_the_scores(factor: float, s: float) -> None:
    a = np.array([4.0, 3.0, 2.0, 1.0, 0.0])
    np.testing.assert_allclose(sparse_weights(a * factor, s), sparse_weights(a, s), atol=1e-12)


def test_sparse_weights_of_zero_scores_are_zero() -> None:
    np.testing.assert_array_equal(sparse_weights(np.zeros(5), 2.0), np.zeros(5))


@pytest.mark.parametrize("s", [0.0, -1.0, float("nan")])
def test_sparse_weights_rejects_non_positive_sparsity(s: float) -> None:
    with pytest.raises(InvalidParameterError, match="sparsity s must be > 0"):
        sparse_weights(np.ones(3), s)


# ----------------------------------------------------------------------------- kept columns
@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    d=st.integers(1, 40),
    s=st.sampled_from([0.1, 1.0, 2.0, "sqrt", 1e6]),
    ties=st.booleans(),
    data=st.data(),
)
def test_selection_is_the_top_d_prime_by_bcss(seed: int, d: int, s, ties: bool, data) -> None:
    rng = np.random.default_rng(seed)
    n = 24
    # With small integers many columns tie (or score 0): ties go to the lowest column index.
    X = rng.integers(-1, 2, size=(n, d)).astype(np.float64) if ties else rng.standard_normal((n, d))
    labels = rng.integers(0, 2, size=n)
    k = data.draw(st.integers(1, d))
    sparsity = float(np.sqrt(d)) if s == "sqrt" else s
    kept = select_features(X, labels, k, sparsity=sparsity)
    bcss = between_cluster_ss(X, labels)
    expected = np.sort(np.lexsort((np.arange(d), -bcss))[:k])
    np.testing.assert_array_equal(kept, expected)
    assert kept.dtype == np.uint16
    assert np.all(np.diff(kept.astype(np.int64)) > 0)


def test_selection_finds_the_informative_columns() -> None:
    rng = np.random.default_rng(1)
    labels = rng.integers(0, 2, size=200)
    X = rng.standard_normal((200, 50))
    informative = [3, 17, 42]
    X[:, informative] += 3.0 * labels[:, None]
    np.testing.assert_array_equal(select_features(X, labels, 3, sparsity=0.1), informative)


@pytest.mark.parametrize("k", [0, 11, -1])
def test_select_features_rejects_a_count_outside_one_to_d(k: int) -> None:
    with pytest.raises(InvalidParameterError, match=r"n_features must be in \[1, 10\]"):
        select_features(np.zeros((4, 10)), np.array([0, 0, 1, 1]), k)


@pytest.mark.parametrize(("d", "dtype"), [(1, np.uint16), (2048, np.uint16), (65536, np.uint16), (65537, np.uint32)])
def test_column_index_dtype(d: int, dtype) -> None:
    assert column_index_dtype(d) == np.dtype(dtype)
