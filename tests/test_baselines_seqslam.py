"""SeqSLAM: contrast enhancement and line search against direct loops, and sequences that resolve
what single frames cannot."""

from __future__ import annotations

import numpy as np
import pytest

from btel.methods.baselines import SeqSLAM, enhance_contrast, seqslam_match, sequence_costs
from btel.methods.baselines.seqslam import velocities
from btel.exceptions import InvalidDescriptorsError, InvalidParameterError


def loop_enhance(D: np.ndarray, window: int) -> np.ndarray:
    """OpenSeqSLAM's doContrastEnhancement, transposed to queries-as-rows, cell by cell."""
    out = np.zeros_like(D, dtype=np.float64)
    half = window // 2
    for j in range(D.shape[0]):
        for i in range(D.shape[1]):
            v = D[j, max(0, i - half) : min(D.shape[1], i + half + 1)]
            out[j, i] = (D[j, i] - v.mean()) / v.std(ddof=1)
    return out - out.min()


def loop_costs(D: np.ndarray, ds: int, vs: np.ndarray) -> np.ndarray:
    n_q, n_map = D.shape
    out = np.full(D.shape, np.inf)
    for j in range(n_q):
        for e in range(n_map):
            for v in vs:
                total = 0.0
                for t in range(min(ds, j + 1)):
                    i = e - int(np.floor(v * t + 0.5))
                    total += D[j - t, i] if i >= 0 else D[j - t].mean()
                out[j, e] = min(out[j, e], total)
    return out


def test_contrast_enhancement_matches_the_openseqslam_loop():
    D = np.random.default_rng(0).random((6, 25))
    np.testing.assert_allclose(enhance_contrast(D, 10), loop_enhance(D, 10), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(enhance_contrast(D, 4), loop_enhance(D, 4), rtol=1e-5, atol=1e-5)


def test_sequence_costs_match_direct_loops():
    D = np.random.default_rng(1).random((14, 30)).astype(np.float32)
    vs = velocities(0.8, 1.2, 0.1)
    np.testing.assert_allclose(sequence_costs(D, 5), loop_costs(D, 5, vs), rtol=1e-5)
    np.testing.assert_allclose(sequence_costs(D, 3, 0.5, 2.0, 0.5), loop_costs(D, 3, velocities(0.5, 2.0, 0.5)), rtol=1e-5)


def test_velocities_include_both_ends():
    np.testing.assert_allclose(velocities(), [0.8, 0.9, 1.0, 1.1, 1.2])
    np.testing.assert_allclose(velocities(1.0, 1.0, 0.1), [1.0])
    with pytest.raises(InvalidParameterError):
        velocities(1.2, 0.8, 0.1)
    with pytest.raises(InvalidParameterError):
        velocities(0.8, 1.2, 0.0)


def noisy_route(offset: int, n_map: int = 200, n_query: int = 60, d: int = 8, noise: float = 1.0, seed: int = 0):
    """Queries j = map row offset + j plus noise strong enough to confuse single frames."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n_map, d)).astype(np.float32)
    Q = (X[offset : offset + n_query] + noise * rng.normal(size=(n_query, d))).astype(np.float32)
    return X, Q, offset + np.arange(n_query)


def test_seqslam_match_recovers_a_constant_offset_that_single_frames_miss():
    X, Q, truth = noisy_route(offset=70)
    D = np.abs(Q[:, None, :] - X[None]).mean(-1)  # (queries, map)
    single = np.argmin(D, axis=1)
    assert np.mean(single == truth) < 0.5  # the premise: frame-by-frame matching is ambiguous
    best, score = seqslam_match(D)
    settled = slice(10 - 1, None)  # from the ds-th query on, a full sequence is available
    assert np.mean(best[settled] == truth[settled]) >= 0.95
    assert best.dtype == np.int64 and score.shape == best.shape
    # Confident where right: the best line clearly beats any line outside the window.
    assert np.nanmedian(score[settled]) < 0.9 and np.all((score >= 0) | np.isnan(score))


def test_seqslam_follows_a_faster_traverse():
    # Queries every 1.2 map rows: only a matching velocity puts a line through the true cells.
    rng = np.random.default_rng(4)
    X = rng.normal(size=(200, 8)).astype(np.float32)
    truth = 30 + np.floor(1.2 * np.arange(60) + 0.5).astype(int)
    Q = (X[truth] + 1.0 * rng.normal(size=(60, 8))).astype(np.float32)
    pred = SeqSLAM(n_jobs=1).fit(X).predict(Q)
    assert np.mean(np.abs(pred[9:] - truth[9:]) <= 1) >= 0.9


def test_seqslam_estimator_matches_the_function_on_its_difference_matrix():
    X, Q, truth = noisy_route(offset=40, seed=2)
    model = SeqSLAM(n_jobs=1).fit(X)
    D = model.difference_matrix(Q)
    assert D.shape == (len(Q), len(X)) and D.dtype == np.float32
    best, score = seqslam_match(D)
    np.testing.assert_array_equal(model.predict(Q), best)
    places, model_score = model.match(Q)
    np.testing.assert_array_equal(places, best)
    # The model scores the codes' own differences (scale-free); D is them times the value step: float32
    # rounding apart, the same scores.
    np.testing.assert_allclose(model_score, score, rtol=1e-6, equal_nan=True)
    assert np.mean(best[9:] == truth[9:]) >= 0.95


def test_first_places_of_the_map_stay_reachable():
    # A query sequence that starts exactly at the map's first row.
    X, Q, truth = noisy_route(offset=0, noise=0.3, seed=3)
    pred = SeqSLAM(n_jobs=1).fit(X).predict(Q)
    assert np.mean(pred[:15] == truth[:15]) >= 0.9


def test_uint8_storage_and_quantisation_error_bound():
    X, Q, _ = noisy_route(offset=10, seed=5)
    model = SeqSLAM(n_jobs=1).fit(X)
    assert model.map_codes_.dtype == np.uint8 and model.map_codes_.shape == X.shape
    assert model.storage_breakdown() == {"map_codes": X.size, "value_range": 8}
    assert model.nbytes == SeqSLAM.planned_bytes(*X.shape)
    assert model.map_codes_.min() == 0 and model.map_codes_.max() == 255
    exact = np.abs(np.clip(Q, X.min(), X.max())[:, None, :] - X[None]).mean(-1)
    # Each value is off by at most half a step, so a mean absolute difference by at most one step.
    scale = float(model.value_range_[1])
    assert np.abs(model.difference_matrix(Q) - exact).max() <= scale * 1.001


def test_nearly_constant_map_does_not_divide_by_zero():
    X = np.ones((20, 4), dtype=np.float32)
    X[7] = 2.0  # one row differs (a map of one repeated row is refused: no place can be told apart)
    pred = SeqSLAM(n_jobs=1).fit(X).predict(X)
    assert pred.shape == (20,) and pred.min() >= 0 and pred.max() < 20
    with pytest.raises(InvalidDescriptorsError, match="all 20 rows of X are the same descriptor"):
        SeqSLAM(n_jobs=1).fit(np.ones((20, 4), dtype=np.float32))


def test_invalid_parameters_and_matrices():
    X = np.random.default_rng(0).random((30, 4)).astype(np.float32)
    for params in ({"ds": 0}, {"vmin": 1.3}, {"vskip": -0.1}, {"window": 1}):
        with pytest.raises(InvalidParameterError):
            SeqSLAM(**params).fit(X)
    with pytest.raises(InvalidDescriptorsError):
        seqslam_match(np.zeros((5,)))
    with pytest.raises(InvalidDescriptorsError):
        seqslam_match(np.full((3, 4), np.nan))
    # The score is undefined when no map row lies outside the exclusion window.
    _, score = seqslam_match(np.random.default_rng(0).random((4, 6)), ds=2, window=10)
    assert np.isnan(score).all()


def test_the_stream_gives_seqslams_batch_places_row_by_row_and_scores_up_to_an_offset() -> None:
    """As the query stream's docstring states: OpenSeqSLAM's contrast enhancement shifts the difference matrix by
    its minimum over the frames scored together, so streamed scores differ from a batch's by an offset."""
    from btel.datasets import synthetic_route

    r = synthetic_route(n_places=120, dim=32, seed=2)
    model = SeqSLAM().fit(r.map)
    scores, places = model.search(r.queries, 3)
    stream = model.stream()
    streamed = [stream.search(q, 3) for q in r.queries]
    np.testing.assert_array_equal(np.array([p for _, p in streamed]), places)
    gaps = np.array([s for s, _ in streamed]) - scores
    np.testing.assert_allclose(gaps - gaps[:, :1], 0, atol=1e-4)  # one offset per row: the ranking is the same
