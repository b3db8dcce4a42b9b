"""Recall at a tolerance, R@K and evaluate() (run folders: tests/test_runs.py)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from sklearn.neighbors import NearestNeighbors

from btel.core.validation import Options
from btel.methods.base import ArraySpec, PlaceLocalizer
from btel.datasets.groundtruth import GroundTruth
from btel.evaluation import (
    DEFAULT_TOLERANCES,
    evaluate,
    recall_at_k,
    recall_at_tolerance,
    recall_curve,
)
from btel.exceptions import DimensionMismatchError, InvalidParameterError


class _NearestNeighbour(PlaceLocalizer):
    """A tiny localizer for these tests: adding a method is ``_fit``, one primitive and its arrays."""

    _parameter_constraints = {"metric": [Options("euclidean", "manhattan")]}

    def __init__(self, *, metric: str = "euclidean") -> None:
        self.metric = metric

    def _fit(self, X, places, n_places, budget, reserved) -> None:
        self.map_ = np.array(X)
        self.index_ = NearestNeighbors(metric=self.metric).fit(self.map_)

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        dist, rows = self.index_.kneighbors(Q, k)
        return -dist, rows.astype(np.int64)

    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return {"map": self.map_}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        return {"map": ArraySpec((state["n_places"], None), np.float32)}

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        self._fit(arrays["map"], None, state["n_places"], None, 0)


class _PlainPredictor:
    """An object with only fit/predict (no storage, no params): evaluate must still work."""

    def fit(self, X: Any) -> "_PlainPredictor":
        self.n_ = len(X)
        return self

    def predict(self, Q: Any) -> np.ndarray:
        return np.minimum(np.arange(len(Q)) + 1, self.n_ - 1)  # always one frame ahead


def _route(n: int = 60, d: int = 16, noise: float = 0.3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)).astype(np.float32)
    return X, (X + noise * rng.normal(size=X.shape)).astype(np.float32)


# -- recall --------------------------------------------------------------------------------------
def test_recall_at_tolerance_exact_values() -> None:
    pred = np.array([0, 2, 5, 3, 0, 9])  # errors vs j: 0, 1, 3, 0, 4, 4
    got = recall_at_tolerance(pred)
    assert list(got) == list(DEFAULT_TOLERANCES)
    assert got == {0: 2 / 6, 1: 3 / 6, 2: 3 / 6, 5: 1.0, 10: 1.0, 20: 1.0}
    assert recall_at_tolerance(pred, [0, 2, 2, 3, 4, 5], tolerances=(0, 3)) == {0: 3 / 6, 3: 4 / 6}


def test_recall_curve_matches_points() -> None:
    rng = np.random.default_rng(3)
    pred = rng.integers(0, 200, size=150)
    curve = recall_curve(pred, max_tolerance=80)
    assert curve.shape == (81,)
    assert np.all(np.diff(curve) >= 0)
    points = recall_at_tolerance(pred, tolerances=range(81))
    np.testing.assert_allclose(curve, [points[t] for t in range(81)])


def test_recall_with_ground_truth_object() -> None:
    gt = GroundTruth.from_positives([[0, 1], [5], [], [3]])
    pred = np.array([1, 4, 0, 3])
    # Explicit positives: no tolerance, the empty row is always wrong.
    assert recall_at_tolerance(pred, gt, (0, 1, 10)) == {0: 0.5, 1: 0.5, 10: 0.5}
    np.testing.assert_allclose(recall_curve(pred, gt, 5), np.full(6, 0.5))
    ranked = np.array([[9, 1], [5, 0], [0, 1], [2, 3]])
    assert recall_at_k(ranked, gt, ks=(1, 2)) == {1: 0.25, 2: 0.75}


def test_recall_at_k_exact_values_and_tolerance() -> None:
    ranked = np.array(
        [
            [0, 7, 8],  # query 0: hit at rank 1
            [4, 1, 9],  # query 1: hit at rank 2
            [9, 8, 3],  # query 2: ranks 1..3 miss at t=0; rank 3 within 1 frame
            [6, 5, 3],  # query 3: hit at rank 3
        ]
    )
    assert recall_at_k(ranked, ks=(1, 2, 3)) == {1: 0.25, 2: 0.5, 3: 0.75}
    assert recall_at_k(ranked, ks=(1, 3), tolerance=1) == {1: 0.25, 3: 1.0}
    with pytest.raises(InvalidParameterError, match="R@5 needs at least 5"):
        recall_at_k(ranked, ks=(1, 5))


def test_recall_input_errors() -> None:
    with pytest.raises(InvalidParameterError, match="1-D"):
        recall_at_tolerance(np.zeros((3, 2), dtype=int))
    with pytest.raises(InvalidParameterError, match="covers 2 queries but there are 3"):
        recall_at_tolerance([0, 1, 2], GroundTruth.frame_aligned(2))
    with pytest.raises(InvalidParameterError, match="tolerances"):
        recall_at_tolerance([0, 1], tolerances=(-1,))


# -- evaluate --------------------------------------------------------------------------------------
def test_evaluate_localizer_with_ranking_and_storage() -> None:
    X, Q = _route(noise=1.0)
    method = _NearestNeighbour()
    result = evaluate(method, X, Q, name="nn", curve_max=30)
    assert result.name == "nn" and result.n_map == 60 and result.n_queries == 60
    # Every method has the front end's three parameters (declared once in PlaceLocalizer).
    assert result.params == {"metric": "euclidean", "normalize": "l2", "whiten": None, "delta": None}
    np.testing.assert_array_equal(result.predictions, method.predict(Q))
    # 60 places: tolerances up to a tenth of the route are reported by default.
    assert list(result.recall) == [0, 1, 2, 5]
    assert result.recall == recall_at_tolerance(result.predictions, tolerances=(0, 1, 2, 5))
    assert result.recall_curve.shape == (31,)
    assert 0.5 < result.recall[0] < 1.0  # noisy queries: mostly but not always the right place
    # The best-ranked candidate is the prediction, so R@1 equals recall@0; R@K grows with K.
    assert result.recall_at_k is not None
    assert result.recall_at_k[1] == result.recall[0]
    values = [result.recall_at_k[k] for k in (1, 5, 10, 20)]
    assert values == sorted(values)
    assert result.ranked.shape == (60, 20)
    assert result.nbytes == X.nbytes == 60 * 16 * 4
    assert result.storage_breakdown == {"map": X.nbytes}
    assert result.fit_time_s is not None and result.fit_time_s >= 0
    assert result.query_time_s_per_query > 0 and result.rank_time_s_per_query > 0
    json.dumps(result.to_dict(), allow_nan=False)  # strictly JSON-safe


def test_evaluate_plain_object_and_explicit_truth() -> None:
    X, Q = _route(n=20)
    result = evaluate(_PlainPredictor(), X, Q[:10], ground_truth=np.arange(10) + 1, ks=(1, 5))
    # No rank(): the point prediction is the only candidate, so R@1 (and only R@1) is known.
    assert result.nbytes is None and result.storage_breakdown is None and result.recall_at_k == {1: result.recall[0]}
    assert result.params == {}
    assert result.name == "_PlainPredictor"
    assert result.recall[0] == 1.0  # the predictor is always one frame ahead, and so is this truth
    frame_aligned = evaluate(_PlainPredictor(), X, Q[:10])
    assert frame_aligned.recall[0] == 0.0 and frame_aligned.recall[1] == 1.0


def test_evaluate_caps_k_at_the_map_size() -> None:
    X, Q = _route(n=8)
    result = evaluate(_NearestNeighbour(), X, Q)
    assert set(result.recall_at_k) == {1, 5}
    assert result.ranked.shape == (8, 8)


def test_evaluate_prefitted_method() -> None:
    X, Q = _route()
    method = _NearestNeighbour().fit(X)
    result = evaluate(method, None, Q, fit=False)
    assert result.fit_time_s is None and result.n_map == 60
    assert result.recall == evaluate(_NearestNeighbour(), X, Q).recall


def test_evaluate_input_errors() -> None:
    X, Q = _route(n=10)
    with pytest.raises(DimensionMismatchError, match="Q has 8 features"):
        evaluate(_NearestNeighbour(), X, Q[:, :8])
    with pytest.raises(InvalidParameterError, match="12 queries but only 10 map places"):
        evaluate(_NearestNeighbour(), X, np.vstack([Q, Q[:2]]))
    with pytest.raises(InvalidParameterError, match="fit=True"):
        evaluate(_NearestNeighbour(), None, Q)


@pytest.mark.realdata
def test_evaluate_on_nordland_pixels(nordland_pixels: tuple[np.ndarray, np.ndarray]) -> None:
    summer, winter = nordland_pixels
    X, Q = summer[::4], winter[::4]  # every 4th frame: 894 places
    result = evaluate(_NearestNeighbour(), X, Q, name="pixel NN")
    chance_at_10 = 21 / X.shape[0]
    print(f"pixel NN, summer→winter, every 4th frame (N={X.shape[0]}): "
          + ", ".join(f"R@t={t}: {r:.3f}" for t, r in result.recall.items())
          + f"; R@K: {result.recall_at_k}; {result.query_time_s_per_query * 1e3:.2f} ms/query")
    assert result.n_map == 894 and result.nbytes == X.nbytes
    # Frame alignment is right if matching beats chance by far (a shifted truth would sit at chance).
    assert result.recall[10] > 3 * chance_at_10
    assert result.recall[0] <= result.recall[10] <= result.recall[20]
    shifted = recall_at_tolerance(result.predictions, np.roll(np.arange(X.shape[0]), 200), (10,))
    assert shifted[10] < result.recall[10] / 2


# -- the timing harness ------------------------------------------------------------------------------
class _Clock:
    """A fake perf_counter that only the fake method moves: timings become exact, not measured."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class _SlowFirstCall:
    """predict costs 100 s the first time (cold caches, thread start-up), 1 s per batch after; a query
    answered alone costs 0.01 s (0.5 s the first time)."""

    uses_query_sequence = False

    def __init__(self, clock: _Clock) -> None:
        self.clock = clock
        self.calls = 0

    def predict(self, Q: np.ndarray) -> np.ndarray:
        self.calls += 1
        if Q.shape[0] == 1:
            self.clock.now += 0.5 if self.calls == 1 else 0.01
        else:
            self.clock.now += 100.0 if self.calls == 1 else 1.0
        return np.arange(Q.shape[0])


def test_time_queries_warms_up_then_reports_medians(monkeypatch) -> None:
    import btel.evaluation.timing as ev

    clock = _Clock()
    monkeypatch.setattr(ev.time, "perf_counter", clock)
    method = _SlowFirstCall(clock)
    Q = np.zeros((10, 4), np.float32)
    predictions, timing = ev.time_queries(method, Q, repeats=3, n_single=7)
    np.testing.assert_array_equal(predictions, np.arange(10))
    assert timing.batch_s_per_query == pytest.approx(1.0 / 10)  # the 100 s first call is not in it
    assert timing.latency_s == pytest.approx(0.01) and timing.n_single == 7
    assert timing.repeats == 3 and timing.n_threads >= 1
    assert method.calls == 1 + 3 + 3 + 7  # first (warm-up, kept), 3 timed, 3 untimed singles, 7 timed


def test_evaluate_reports_batch_throughput_and_single_query_latency_apart(monkeypatch) -> None:
    import btel.evaluation as ev

    rng = np.random.default_rng(0)
    X = rng.standard_normal((40, 8)).astype(np.float32)
    result = ev.evaluate(_NearestNeighbour(), X, X, ks=(1,))
    assert result.query_time_s_per_query > 0 and result.query_latency_s > 0
    assert result.timing_repeats >= 1 and result.n_threads >= 1
    summary = result.to_dict()
    assert {"query_latency_s", "n_threads", "timing_repeats"} <= set(summary)
    table = ev.format_table([result])
    assert "batch µs/q" in table and "1-query µs" in table and "threads" in table


def test_time_queries_stops_repeating_after_max_seconds(monkeypatch) -> None:
    import btel.evaluation.timing as ev

    clock = _Clock()
    monkeypatch.setattr(ev.time, "perf_counter", clock)
    method = _SlowFirstCall(clock)
    _, timing = ev.time_queries(method, np.zeros((10, 4), np.float32), repeats=50, n_single=0, max_seconds=2.5)
    assert timing.repeats == 3 and timing.latency_s is None  # 1 + 1 + 1 s passes 2.5 s


def test_time_queries_with_no_repeats_times_the_predicting_call_alone(monkeypatch) -> None:
    import btel.evaluation.timing as ev

    clock = _Clock()
    monkeypatch.setattr(ev.time, "perf_counter", clock)
    method = _SlowFirstCall(clock)
    predictions, timing = ev.time_queries(method, np.zeros((10, 4), np.float32), repeats=0)
    np.testing.assert_array_equal(predictions, np.arange(10))
    assert method.calls == 1 and timing.repeats == 1 and timing.latency_s is None and timing.n_single == 0
    assert timing.batch_s_per_query == pytest.approx(100.0 / 10)  # un-warmed: the first call's cost


def test_measure_without_precision_recall_skips_the_scoring_pass() -> None:
    import btel
    from btel.evaluation import measure

    X = np.random.default_rng(0).standard_normal((60, 16)).astype(np.float32)
    calls = []
    model = btel.make_method("bruteforce").fit(X)
    real = model.search
    model.search = lambda Q, k=1: calls.append(k) or real(Q, k=k)
    light = measure(model, None, X, fit=False, ks=(), score_answers=False, timing_repeats=0)
    assert calls == [] and light.auc_pr_vpr_bench is None and light.recall[0] == 1.0
    full = measure(model, None, X, fit=False, ks=())
    assert calls == [1] and full.auc_pr_vpr_bench is not None


# -- precision-recall from the best-match score --------------------------------------------------------
def test_precision_recall_by_hand() -> None:
    from btel.evaluation import precision_recall

    # Most confident first: right, right, wrong, right; 5 queries (one wrong match scored lowest).
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.1])
    correct = np.array([True, True, False, True, False])
    pr = precision_recall(scores, correct)
    np.testing.assert_allclose(pr["recall"], [0.2, 0.4, 0.4, 0.6, 0.6])  # one point per distinct score
    np.testing.assert_allclose(pr["precision"], [1, 1, 2 / 3, 3 / 4, 3 / 5])
    assert pr["recall_at_100_precision"] == pytest.approx(0.4)
    # VPR-Bench: recall over the 3 correct matches, (0, 1) first, trapezoids.
    assert pr["auc_pr_vpr_bench"] == pytest.approx(1 / 3 + 1 / 3 + 1 / 3 * (2 / 3 + 3 / 4) / 2)
    # VPR_Tutorial: recall over the 5 queries; its 100 thresholds hit every gap between these scores.
    assert pr["auc_pr_vpr_tutorial"] == pytest.approx(0.2 + 0.2 + 0.2 * (2 / 3 + 3 / 4) / 2)
    # Only the order of the scores matters (each method's own scale).
    again = precision_recall(np.exp(scores) * 7 - 3, correct)
    assert again["auc_pr_vpr_bench"] == pytest.approx(pr["auc_pr_vpr_bench"])
    # The most confident match wrong: no recall at 100 % precision; no correct match: zeros.
    assert precision_recall([0.9, 0.1], [False, True])["recall_at_100_precision"] == 0.0
    none_right = precision_recall([0.9, 0.1], [False, False])
    assert none_right["auc_pr_vpr_bench"] == 0.0 and none_right["auc_pr_vpr_tutorial"] == 0.0
    with pytest.raises(InvalidParameterError):
        precision_recall([0.1, 0.2], [True])


def test_evaluate_reports_pr_from_search_scores() -> None:
    from btel.evaluation import format_table, precision_recall

    rng = np.random.default_rng(0)
    X = rng.standard_normal((60, 8)).astype(np.float32)
    Q = X + 0.8 * rng.standard_normal(X.shape).astype(np.float32)
    method = _NearestNeighbour().fit(X)
    result = evaluate(method, None, Q, fit=False, ks=(1, 5))
    scores, places = method.search(Q, 1)
    expected = precision_recall(scores[:, 0], places[:, 0] == np.arange(60))
    assert result.auc_pr_vpr_bench == pytest.approx(expected["auc_pr_vpr_bench"])
    assert result.auc_pr_vpr_tutorial == pytest.approx(expected["auc_pr_vpr_tutorial"])
    assert result.recall_at_100_precision == pytest.approx(expected["recall_at_100_precision"])
    # VPR_Tutorial's recall stops at R@1; VPR-Bench's (over the correct matches) reaches 1.
    assert 0 < result.auc_pr_vpr_tutorial <= result.recall_at_k[1] < result.auc_pr_vpr_bench <= 1
    summary = json.loads(json.dumps(result.to_dict()))
    assert summary["auc_pr_vpr_bench"] == pytest.approx(result.auc_pr_vpr_bench)
    assert summary["auc_pr_vpr_tutorial"] == pytest.approx(result.auc_pr_vpr_tutorial)
    assert len(summary["pr_curve"]["recall"]) == len(summary["pr_curve"]["precision"]) <= 256
    table = format_table([result])
    assert "AUC-PR:VB" in table and "AUC-PR:VT" in table and "R@100%P" in table and "VPR_Tutorial" in table


def test_time_queries_runs_with_the_thread_count_it_reports() -> None:
    from threadpoolctl import threadpool_info

    import btel.evaluation.timing as ev

    seen: list[int] = []

    class Probe:
        uses_query_sequence = False

        def predict(self, Q: np.ndarray) -> np.ndarray:
            seen.append(max((int(i["num_threads"]) for i in threadpool_info()), default=1))
            return np.zeros(Q.shape[0], dtype=np.int64)

    np.ones((2, 2)) @ np.ones((2, 2))  # BLAS loaded
    _, timing = ev.time_queries(Probe(), np.zeros((4, 2), np.float32), repeats=2, n_single=2)
    assert set(seen) == {1} and timing.n_threads == 1


def test_a_model_that_cannot_use_the_rest_of_its_budget_says_so_in_the_run(tmp_path) -> None:
    """Issue 37: a method that leaves part of its budget unspent because its parameters cap the model says so
    in the table (‡ and a legend line), in metrics.csv and in metrics.json; the others are not marked."""
    import btel.evaluation as ev
    from btel.datasets import synthetic_route
    from btel.evaluation.records import EvaluationResult
    from btel.methods import make_method

    r = synthetic_route(300, 32, seed=0)
    capped = ev.evaluate(make_method("lsh", budget="1MB"), r.map, r.queries, name="lsh 1MB")
    spent = ev.evaluate(make_method("lsh", budget="600B"), r.map, r.queries, name="lsh 600B")
    unbudgeted = ev.evaluate(make_method("bruteforce"), r.map, r.queries, name="bruteforce")
    assert capped.budget_saturated and capped.nbytes < 1_000_000
    assert not spent.budget_saturated and not unbudgeted.budget_saturated
    table = ev.format_table([capped, spent, unbudgeted])
    lines = {line.split()[0] + " " + line.split()[1]: line for line in table.splitlines() if line.startswith(("lsh", "brute"))}
    assert "KB‡" in lines["lsh 1MB"] and "‡" not in lines["lsh 600B"] and "‡" not in lines["bruteforce ok"]
    assert "‡ the largest model the method's parameters allow: the rest of its budget stays unused" in table
    assert "‡" not in ev.format_table([spent, unbudgeted])  # no legend where no row is marked
    from btel.evaluation.tables import metrics_csv_text

    csv_rows = metrics_csv_text([capped, spent]).splitlines()
    column = csv_rows[0].split(",").index("budget_saturated")
    assert [row.split(",")[column] for row in csv_rows[1:]] == ["1", "0"]
    again = EvaluationResult.from_dict(json.loads(json.dumps(capped.to_dict())))
    assert again.budget_saturated and not EvaluationResult.from_dict(spent.to_dict()).budget_saturated


def test_gardens_point_at_1mb_marks_the_methods_that_leave_bytes_unspent(gardenspoint_netvlad) -> None:
    import btel.evaluation as ev
    from btel.methods import make_method

    db, queries = gardenspoint_netvlad
    rows = [ev.evaluate(make_method(name, budget="1MB"), db, queries, name=name, tolerances=(0, 2))
            for name in ("lsh", "pq", "btel-c", "btel-codes")]
    marked = {r.name: r.budget_saturated for r in rows}
    assert marked == {"lsh": True, "pq": True, "btel-c": True, "btel-codes": False}, marked
    assert all(r.nbytes < 1_000_000 for r in rows if r.budget_saturated)
    table = ev.format_table(rows)
    assert sum("‡" in line for line in table.splitlines() if line.startswith(("lsh", "pq", "btel"))) == 3
