"""evaluation.metrics: precision–recall over distinct thresholds and AUC-PR as each source computes it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.metrics import auc, precision_recall_curve

from btel.evaluation.metrics import VPR_TUTORIAL_THRESHOLDS, precision_recall, thin_curve
from btel.exceptions import InvalidParameterError

# Scores drawn from few values, so ties are common; correctness of each query's top-1 match.
_matches = st.integers(1, 60).flatmap(lambda n: st.tuples(
    st.lists(st.sampled_from([-2.0, -0.5, 0.0, 0.25, 1.0, 3.0]), min_size=n, max_size=n),
    st.lists(st.booleans(), min_size=n, max_size=n)))


def _vpr_tutorial_single_match(S: np.ndarray, GT: np.ndarray, n_thresh: int) -> float:
    """VPR_Tutorial's single-best-match PR and AUC, step by step as its ``createPR`` and ``demo.py``.

    ``S`` and ``GT`` are (n_map, n_queries) as there: similarities and true matches. Queries
    with a true match count for recall; each query's best match is thresholded on its similarity.
    """
    n_true = np.count_nonzero(GT.any(axis=0))
    best = np.argmax(S, axis=0)
    hit = GT[best, np.arange(S.shape[1])]
    s = S.max(axis=0)
    P, R = [1.0], [0.0]
    for threshold in np.linspace(s.max(), s.min(), n_thresh):
        accepted = s >= threshold
        tp = np.count_nonzero(hit & accepted)
        fp = np.count_nonzero(~hit & accepted)
        P.append(tp / (tp + fp))
        R.append(tp / n_true)
    return float(np.trapezoid(P, R))


@settings(max_examples=100, deadline=None)
@given(_matches)
def test_vpr_bench_auc_is_sklearn_precision_recall_curve_then_auc(case) -> None:
    scores, correct = np.array(case[0]), np.array(case[1])
    pr = precision_recall(scores, correct)
    if not correct.any():
        assert pr["auc_pr_vpr_bench"] == 0.0  # VPR-Bench's code gives NaN here; btel says 0
        return
    precision, recall, _ = precision_recall_curve(correct.astype(int), scores)  # performance_comparison.py
    assert pr["auc_pr_vpr_bench"] == pytest.approx(auc(recall, precision), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_vpr_tutorial_auc_is_its_create_pr_then_trapz(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_map, n_queries = 40, 30
    S = rng.standard_normal((n_map, n_queries))
    GT = np.zeros((n_map, n_queries), dtype=bool)
    truth = rng.integers(0, n_map, n_queries)
    GT[truth, np.arange(n_queries)] = True
    GT[:, :3] = False  # three queries without a true place: outside VPR_Tutorial's recall
    S[truth[5:20], np.arange(5, 20)] += 3.0  # half the queries matched right, at varied confidence
    if seed % 2:
        S = np.round(S, 0)  # ties among the best scores
    best = np.argmax(S, axis=0)
    hit = GT[best, np.arange(n_queries)]
    expected = _vpr_tutorial_single_match(S, GT, VPR_TUTORIAL_THRESHOLDS)
    pr = precision_recall(S.max(axis=0), hit, n_relevant=n_queries - 3)
    assert pr["auc_pr_vpr_tutorial"] == pytest.approx(expected, abs=1e-12)


def _brute_force_points(scores: np.ndarray, correct: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    thresholds = np.unique(scores)[::-1]
    accepted = scores[None, :] >= thresholds[:, None]
    tp = (accepted & correct[None, :]).sum(axis=1)
    return tp / accepted.sum(axis=1), tp / n


@settings(max_examples=100, deadline=None)
@given(_matches)
def test_one_point_per_distinct_score_and_no_curve_beyond_recall_at_full_precision(case) -> None:
    scores, correct = np.array(case[0]), np.array(case[1])
    pr = precision_recall(scores, correct)
    precision, recall = _brute_force_points(scores, correct, scores.size)
    np.testing.assert_allclose(pr["precision"], precision)
    np.testing.assert_allclose(pr["recall"], recall)
    np.testing.assert_array_equal(pr["thresholds"], np.unique(scores)[::-1])
    perfect = pr["recall"][pr["precision"] == 1.0]
    assert pr["recall_at_100_precision"] == (perfect.max() if perfect.size else 0.0)
    kept_p, kept_r = map(np.array, thin_curve(pr["precision"], pr["recall"], n=4))
    assert kept_p.size <= 5 and (kept_r[kept_p == 1.0].max() if (kept_p == 1.0).any() else 0.0) == \
        pr["recall_at_100_precision"]


def test_constant_scores_are_one_point_at_the_hit_rate() -> None:
    correct = np.array([True, False, False, True, False, False, False])
    pr = precision_recall(np.full(7, 0.3), correct)
    np.testing.assert_allclose(pr["precision"], [2 / 7])
    np.testing.assert_allclose(pr["recall"], [2 / 7])
    assert pr["recall_at_100_precision"] == 0.0


def test_nan_and_infinite_scores_rank_last_and_first() -> None:
    pr = precision_recall([np.nan, 0.5, np.inf, -np.inf], [False, True, True, False])
    np.testing.assert_allclose(pr["precision"], [1.0, 1.0, 0.5])  # inf, 0.5, then NaN and -inf tied
    assert pr["recall_at_100_precision"] == 0.5


def test_bad_inputs_are_named() -> None:
    with pytest.raises(InvalidParameterError, match="one length"):
        precision_recall([], [])
    with pytest.raises(InvalidParameterError, match="n_relevant"):
        precision_recall([0.1, 0.2, 0.3], [True, True, True], n_relevant=2)


@pytest.mark.realdata
def test_auc_pr_on_gardens_point_netvlad_as_each_source(gardenspoint_netvlad) -> None:
    from btel.methods.registry import make_method

    X, Q = gardenspoint_netvlad
    scores, places = make_method("bruteforce").fit(X).search(Q, 1)
    correct = places[:, 0] == np.arange(Q.shape[0])  # day ↔ night, frame-aligned
    pr = precision_recall(scores[:, 0], correct)
    precision, recall, _ = precision_recall_curve(correct.astype(int), scores[:, 0])
    assert pr["auc_pr_vpr_bench"] == pytest.approx(auc(recall, precision), abs=1e-12)
    S = np.full((X.shape[0], Q.shape[0]), -np.inf)  # only the best match's score matters for single matching
    S[places[:, 0], np.arange(Q.shape[0])] = scores[:, 0]
    truth = np.eye(X.shape[0], Q.shape[0], dtype=bool)
    expected = _vpr_tutorial_single_match(S, truth, VPR_TUTORIAL_THRESHOLDS)
    assert pr["auc_pr_vpr_tutorial"] == pytest.approx(expected, abs=1e-12)
    r_at_1 = correct.mean()
    assert 0 < r_at_1 < 1 and pr["auc_pr_vpr_tutorial"] <= r_at_1 < pr["auc_pr_vpr_bench"]


def test_a_list_of_lists_is_explicit_positives_as_from_positives_makes_them() -> None:
    from btel.datasets import GroundTruth
    from btel.evaluation.metrics import check_ground_truth

    positives = [[0, 1], [1], [], np.array([2, 3])]
    gt = check_ground_truth(positives, 4, 5)
    expected = GroundTruth.from_positives(positives, n_map=5)
    assert gt.kind == "positives" and np.array_equal(gt.indptr, expected.indptr)
    assert np.array_equal(gt.indices, expected.indices)
    assert check_ground_truth([0, 1, 2, 3], 4, 5).kind == "places"  # a flat list stays one place per query
