"""HMM sequence decoding over places (btel.sequence.hmm)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import BTELocalizer
from btel.methods.baselines import BruteForceNN, ITQLocalizer, PQLocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import decode_soft
from btel.exceptions import InvalidParameterError, NotFittedError
from btel.methods.btel.ranking import soft_scores
from btel.sequence.filter import filter_sequence
from btel.sequence.hmm import HMMDecoder, decode_sequence, transition_kernel, zscore_rows


def transition_matrix(n, vmin, vmax, backward, teleport):
    """Explicit N×N matrix P[i, j] = p(i → j), mass leaving the route dropped (rows may sum < 1)."""
    offsets, weights = transition_kernel(vmin, vmax, backward)
    P = np.full((n, n), teleport / n)
    for o, w in zip(offsets, weights):
        for i in range(n):
            if 0 <= i + o < n:
                P[i, i + o] += (1 - teleport) * w
    return P, offsets, weights


params = dict(
    n=st.integers(2, 12),
    T=st.floats(0.2, 5.0),
    vmin=st.integers(0, 2),
    extra=st.integers(0, 3),
    backward=st.sampled_from([0.0, 0.1]),
    teleport=st.sampled_from([0.0, 1e-2, 0.2]),
    seed=st.integers(0, 2**31 - 1),
)


@settings(max_examples=60, deadline=None)
@given(**params)
def test_forward_filter_equals_explicit_forward_algorithm(n, T, vmin, extra, backward, teleport, seed):
    rng = np.random.default_rng(seed)
    scores = rng.standard_normal((6, n)) * 2
    vmax = vmin + extra
    dec = HMMDecoder(n, temperature=T, vmin=vmin, vmax=vmax, backward=backward, teleport=teleport)
    offsets, weights = transition_kernel(vmin, vmax, backward)
    alpha = np.full(n, 1.0 / n) * np.exp(scores[0] / T)
    alpha /= alpha.sum()
    dec.update(scores[0])
    np.testing.assert_allclose(dec.belief, alpha, rtol=1e-9, atol=1e-12)
    for s in scores[1:]:
        moved = np.zeros(n)
        for o, w in zip(offsets, weights):  # the shift, then renormalise what stayed on the route
            for i in range(n):
                if 0 <= i + o < n:
                    moved[i + o] += w * alpha[i]
        moved = moved / moved.sum() if moved.sum() > 0 else np.full(n, 1.0 / n)
        alpha = ((1 - teleport) * moved + teleport / n) * np.exp(s / T)
        alpha /= alpha.sum()
        place = dec.update(s)
        np.testing.assert_allclose(dec.belief, alpha, rtol=1e-9, atol=1e-12)
        assert place == int(np.argmax(alpha))


@settings(max_examples=60, deadline=None)
@given(**params)
def test_viterbi_equals_explicit_max_product(n, T, vmin, extra, backward, teleport, seed):
    rng = np.random.default_rng(seed)
    scores = rng.standard_normal((6, n)) * 2
    P, _, _ = transition_matrix(n, vmin, vmin + extra, backward, teleport)
    with np.errstate(divide="ignore"):
        logP = np.log(P)
    dec = HMMDecoder(n, temperature=T, vmin=vmin, vmax=vmin + extra, backward=backward, teleport=teleport,
                     mode="viterbi")
    delta = scores[0] / T
    dec.update(scores[0])
    for s in scores[1:]:
        candidate = (delta[:, None] + logP).max(axis=0) + s / T
        delta = candidate if np.isfinite(candidate.max()) else s / T
        place = dec.update(s)
        np.testing.assert_allclose(dec.belief, delta - delta.max(), rtol=1e-9, atol=1e-9)
        assert place == int(np.argmax(delta))


def trajectory_scores(n=400, steps=300, signal=1.5, seed=0, speed=1):
    """Noise everywhere plus a weak bump at the true place, which moves ``speed`` per step."""
    rng = np.random.default_rng(seed)
    truth = (np.arange(steps) * speed) % n
    scores = rng.standard_normal((steps, n))
    scores[np.arange(steps), truth] += signal
    return scores, truth


def test_hmm_recovers_a_path_that_single_frames_miss():
    scores, truth = trajectory_scores()
    single = np.mean(np.abs(np.argmax(scores, axis=1) - truth) <= 2)
    decoded = decode_sequence(scores, temperature=1.0, vmax=2)
    hmm = np.mean(np.abs(decoded - truth) <= 2)
    # The bump (1.5σ) rarely beats 400 noise values in one frame; 20 frames of it are decisive.
    assert single < 0.2
    assert hmm > 0.8
    viterbi = np.mean(np.abs(decode_sequence(scores, temperature=1.0, vmax=2, mode="viterbi") - truth) <= 2)
    assert viterbi > 0.8
    median = np.mean(np.abs(filter_sequence(np.argmax(scores, axis=1), 5, n_places=400) - truth) <= 2)
    assert hmm > median


def test_streaming_equals_batch_and_resets_split_runs():
    scores, _ = trajectory_scores(n=100, steps=60, seed=1)
    dec = HMMDecoder(100, temperature=0.7, vmax=3, teleport=0.01)
    streamed = [dec.update(s) for s in scores]
    np.testing.assert_array_equal(decode_sequence(scores, temperature=0.7, vmax=3, teleport=0.01), streamed)
    both = decode_sequence(scores, temperature=0.7, vmax=3, resets=[30])
    np.testing.assert_array_equal(both[30:], decode_sequence(scores[30:], temperature=0.7, vmax=3))
    dec.reset()
    assert dec.belief is None
    assert dec.update(scores[0]) == streamed[0]


def test_teleport_recovers_from_a_kidnapping():
    scores, truth = trajectory_scores(n=300, steps=200, signal=3.0, seed=2)
    # Kidnapped at step 100: the true place jumps back by 150.
    truth2 = truth.copy()
    truth2[100:] = truth[100:] - 150
    rng = np.random.default_rng(3)
    kidnapped = rng.standard_normal(scores.shape)
    kidnapped[np.arange(200), truth2] += 3.0
    with_teleport = decode_sequence(kidnapped, temperature=1.0, vmax=2, teleport=1e-3)
    without = decode_sequence(kidnapped, temperature=1.0, vmax=2, teleport=0.0)
    late = slice(150, 200)
    assert np.mean(np.abs(with_teleport[late] - truth2[late]) <= 2) > 0.9
    assert np.mean(np.abs(without[late] - truth2[late]) <= 2) < 0.5  # forward-only: cannot go back


def test_transition_kernel():
    offsets, weights = transition_kernel(1, 3, 0.1)
    assert offsets.tolist() == [1, 2, 3, -1, -2, -3]
    np.testing.assert_allclose(weights.sum(), 1.0)
    np.testing.assert_allclose(weights[:3], 0.3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"temperature": 0}, "temperature"),
        ({"vmin": 3, "vmax": 1}, "vmax must be ≥ vmin"),
        ({"teleport": 1.0}, "teleport"),
        ({"backward": -0.1}, "backward"),
        ({"mode": "smooth"}, "mode"),
    ],
)
def test_bad_parameters(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        HMMDecoder(10, **kwargs)


def test_bad_scores():
    dec = HMMDecoder(5)
    with pytest.raises(InvalidParameterError, match=r"shape \(5,\)"):
        dec.update(np.zeros(4))
    with pytest.raises(InvalidParameterError, match="NaN"):
        dec.update(np.array([0, 1, np.nan, 0, 0]))
    with pytest.raises(InvalidParameterError, match="2-D"):
        decode_sequence(np.zeros(5))


def test_zscore_rows():
    z = zscore_rows(np.array([[1.0, 2.0, 3.0], [4.0, 4.0, 4.0]]))
    np.testing.assert_allclose(z[0].mean(), 0, atol=1e-12)
    np.testing.assert_allclose(z[0].std(), 1)
    np.testing.assert_array_equal(z[1], 0)


# ------------------------------------------------------------------------- scores of every method
@pytest.fixture(scope="module")
def route():
    return synthetic_route(256, 32, seed=5)


def test_place_scores_argmax_is_each_methods_prediction(route):
    X, Q = route.map, route.queries
    for model in (BruteForceNN(), PQLocalizer(n_subquantizers=8, nbits=4), ITQLocalizer(code_bits=16)):
        model.fit(X)
        S = model.place_scores(Q)
        assert S.shape == (Q.shape[0], X.shape[0])
        best = S[np.arange(Q.shape[0]), model.predict(Q)]
        np.testing.assert_allclose(best, S.max(axis=1), rtol=1e-5)  # ties allowed (ITQ)
    bf = BruteForceNN(normalize="none").fit(X)  # raw rows: the scores are minus squared L2 distances
    sq = ((Q[:, None, :].astype(np.float64) - X[None, :, :]) ** 2).sum(-1)
    np.testing.assert_allclose(-bf.place_scores(Q), sq, rtol=1e-4, atol=1e-3)


def test_place_scores_of_ryth_are_its_soft_decode_scores(route):
    from btel.methods.ryth import RYTHLocalizer

    model = RYTHLocalizer(decode="soft", feature_ratio=0.5, random_state=0).fit(route.map)
    S = model.place_scores(route.queries)
    assert S.shape == (256, 256)
    np.testing.assert_array_equal(np.argmax(S, axis=1), model.predict(route.queries))


def test_place_scores_of_btel_are_minus_flip_costs(route):
    model = BTELocalizer(feature_ratio=0.5, progress=False, random_state=0).fit(route.map)
    S = model.place_scores(route.queries)
    margins = model.decision_function(route.queries).astype(np.float64)
    np.testing.assert_allclose(S, soft_scores(margins, 256) - np.abs(margins).sum(axis=1, keepdims=True), atol=1e-9)
    np.testing.assert_array_equal(np.argmax(S, axis=1), decode_soft(model.decision_function(route.queries), 256))
    with pytest.raises(NotFittedError):
        BTELocalizer().place_scores(route.queries)


# ------------------------------------------------------------------------- real data
@pytest.mark.realdata
def test_hmm_on_gardens_point_beats_single_frames(gardenspoint_netvlad):
    X, Q = gardenspoint_netvlad
    n = X.shape[0]
    S = zscore_rows(BruteForceNN().fit(X).place_scores(Q))
    single = np.mean(np.abs(np.argmax(S, axis=1) - np.arange(n)) <= 2)
    hmm = np.mean(np.abs(decode_sequence(S, temperature=1.0, vmax=2) - np.arange(n)) <= 2)
    assert hmm > single
