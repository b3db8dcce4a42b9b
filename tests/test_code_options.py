"""The "beyond the paper" code options of BTELocalizer: block_size (tolerance-aware codes),
code_copies (offset / error-correcting codes), exemplar_radius (multi-exemplar weights), ranking,
per-place scores and sequence decoding."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btel import BTELocalizer, load
from btel.methods.btel.compressed import code_signs, compressed_code, compressed_n_classifiers, exemplar_weights
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import encode, n_bits_for
from btel.exceptions import InvalidParameterError, ModelFileError
from btel.methods.btel.decoding import block_centres
from btel.methods.btel.localizer import block_size_for_tolerance, planned_bytes
from btel.core.modelfile import load_arrays, save_arrays


@pytest.fixture(scope="module")
def route():
    return synthetic_route(400, 64, seed=11)


def _fit(X, **kw):
    return BTELocalizer(progress=False, random_state=0, **kw).fit(X)


# -- codes ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(("t", "B"), [(0, 1), (1, 1), (2, 2), (3, 2), (10, 8), (16, 16), (31, 16)])
def test_block_size_rule(t, B):
    assert block_size_for_tolerance(t) == B
    assert (B // 2 if B > 1 else 0) <= t  # worst error inside a block ≤ t


def test_block_centres_are_within_half_a_block():
    n, B = 103, 8
    centres = block_centres(np.arange(n) // B, B, n)
    assert centres.max() < n and np.abs(centres - np.arange(n)).max() <= B // 2
    assert centres[-1] == (96 + 102) // 2  # the short last block has its own centre


def test_plain_code_is_the_binary_code():
    levels, shifts = compressed_code(300, 1)
    np.testing.assert_array_equal(levels, np.arange(9))
    np.testing.assert_array_equal(shifts, 0)
    np.testing.assert_array_equal(code_signs(300, 1), 2.0 * encode(np.arange(300), 9) - 1.0)


@given(n=st.integers(2, 3000), copies=st.integers(1, 6))
@settings(max_examples=60, deadline=None)
def test_offset_code_columns_are_distinct_shifted_contiguous_splits(n, copies):
    levels, shifts = compressed_code(n, copies)
    b = n_bits_for(n)
    assert levels.size == compressed_n_classifiers(n, copies) >= b
    np.testing.assert_array_equal(code_signs(n, copies)[:, :b], code_signs(n, 1))  # plain bits first
    assert len(set(zip(levels.tolist(), shifts.tolist()))) == levels.size  # no column twice
    block = 1 << (b - 1 - levels)
    assert np.all((shifts >= 0) & (shifts < block))
    # Each column changes value only at its own block boundaries: at most ⌈N / L⌉ + 1 runs.
    signs = code_signs(n, copies)
    runs = 1 + np.sum(signs[1:] != signs[:-1], axis=0)
    assert np.all(runs <= -(-n // block) + 1)


def test_exemplar_weights_count_same_block_neighbours():
    w = exemplar_weights(np.arange(16), 16, 1, radius=2)  # 4 bits; bit 3 (LSB) blocks of one place
    assert w.shape == (16, 4)
    np.testing.assert_array_equal(w[:, 3], 1)  # no neighbour shares a one-place block
    np.testing.assert_array_equal(w[:, 2], 2)  # blocks of two: exactly one neighbour within ±2
    assert w[0, 0] == 3 and w[7, 0] == 3 and w[3, 0] == 5  # boundary rows weigh less
    assert np.all((w >= 1) & (w <= 5))
    # A radius past the route's ends weighs every row as radius N − 1 does (a radius of 10¹¹ looped 10¹¹ times).
    np.testing.assert_array_equal(exemplar_weights(np.arange(16), 16, 1, radius=10**11),
                                  exemplar_weights(np.arange(16), 16, 1, radius=15))


# -- tolerance-aware codes -----------------------------------------------------------------------
def test_same_budget_buys_more_features_per_bit(route):
    budget = 2000  # plain (9 bits): d' = 36 of 64 columns; the 50-block tree (6 bits) affords all 64
    plain = _fit(route.map, budget=budget)
    tol = _fit(route.map, budget=budget, block_size=8)
    assert tol.n_blocks_ == 50 and tol.n_bits_ == 6 and plain.n_bits_ == 9
    assert tol.nbytes <= budget and plain.nbytes <= budget
    assert tol.n_selected_ > plain.n_selected_
    assert tol.nbytes == planned_bytes(50, 64, n_selected=tol.n_selected_)
    pred = tol.predict(route.queries)
    assert set(np.unique(pred)) <= set(block_centres(np.arange(50), 8, 400).tolist())


def test_learnable_map_decodes_to_the_right_block():
    # d ≫ number of blocks: the block labels are linearly separable, so noisy copies of the map
    # must land in their own block (error ≤ 2 from a 4-place block's centre).
    route = synthetic_route(128, 512, seed=12)
    tol = _fit(route.map, feature_ratio=1.0, block_size=block_size_for_tolerance(4))
    rng = np.random.default_rng(0)
    noisy = route.map + 0.05 * route.map.std(axis=0) * rng.standard_normal(route.map.shape).astype(np.float32)
    assert np.mean(np.abs(tol.predict(noisy) - np.arange(128)) <= 2) > 0.95


def test_blocks_with_regions_and_full_scheme(route):
    for kw in ({"n_regions": 3}, {"scheme": "full"}):
        model = _fit(route.map, block_size=4, feature_ratio=0.5, **kw)
        pred = model.predict(route.queries)
        assert pred.min() >= 0 and pred.max() < 400 and np.all(pred % 4 == 1)
        assert model.region_sizes_.sum() == model.n_blocks_ == 100



def test_a_model_file_saved_before_n_blocks_loads_and_answers_as_a_refit():
    # Saved by the release that still called n_blocks_ "n_codes_" (block_size = 4, r = 2, N = 120,
    # synthetic_route(120, 32, seed=0)). The count of blocks was never a key of the file: it is
    # derived from N and block_size on load, so the file reads unchanged.
    from pathlib import Path

    path = Path(__file__).parent / "data" / "btel-c-blocks-saved-before-n_blocks.btel"
    assert "n_codes" not in load_arrays(path)[1]["state"]
    old = load(path)
    route = synthetic_route(120, 32, seed=0)
    refit = _fit(route.map, block_size=4, n_regions=2)
    assert old.n_blocks_ == refit.n_blocks_ == 30 and not hasattr(old, "n_codes_")
    np.testing.assert_array_equal(old.predict(route.queries), refit.predict(route.queries))
    np.testing.assert_array_equal(old.search(route.queries, 5)[1], refit.search(route.queries, 5)[1])

# -- offset codes --------------------------------------------------------------------------------
def test_offset_codes_store_more_classifiers_and_decode_softly(route):
    plain = _fit(route.map, feature_ratio=0.5)
    ecoc = _fit(route.map, feature_ratio=0.5, code_copies=3)
    K = compressed_n_classifiers(400, 3)
    assert len(ecoc.hyperplanes_) == K > plain.n_bits_
    assert ecoc.nbytes == planned_bytes(400, 64, n_selected=ecoc.n_selected_, code_copies=3)
    margins = ecoc.decision_function(route.queries)
    assert margins.shape == (400, K)
    expected = np.argmax(margins @ code_signs(400, 3).T, axis=1)
    np.testing.assert_array_equal(ecoc.predict(route.queries), expected)


def test_offset_codes_fit_the_budget_with_fewer_columns(route):
    plain = _fit(route.map, budget=3000)
    ecoc = _fit(route.map, budget=3000, code_copies=2)
    assert ecoc.nbytes <= 3000 and ecoc.n_selected_ < plain.n_selected_


def test_offset_codes_recover_learnable_places():
    route = synthetic_route(128, 512, seed=3)
    model = _fit(route.map, feature_ratio=1.0, code_copies=2)
    rng = np.random.default_rng(1)
    noisy = route.map + 0.05 * route.map.std(axis=0) * rng.standard_normal(route.map.shape).astype(np.float32)
    assert np.mean(model.predict(noisy) == np.arange(128)) > 0.95


# -- multi-exemplar and several traverses ---------------------------------------------------------
def test_exemplar_radius_changes_the_fit_but_not_the_bytes(route):
    plain = _fit(route.map, budget=3000)
    ex = _fit(route.map, budget=3000, exemplar_radius=3)
    assert ex.nbytes == plain.nbytes
    assert not np.array_equal(ex.hyperplanes_.weights, plain.hyperplanes_.weights)
    pred = ex.predict(route.queries)
    assert pred.min() >= 0 and pred.max() < 400


def test_several_traverses_share_labels():
    # Variant 6 on a synthetic route: the map is two traverses under different conditions with
    # shared place labels; queries are a third traverse. Training on both must not do worse than
    # on one (the classifiers see the appearance change), and bytes do not grow with traverses.
    route = synthetic_route(256, 128, n_traverses=4, condition_shift=0.6, seed=5)
    X2 = np.concatenate([route.map, route.traverses[1]])
    places = np.concatenate([np.arange(256), np.arange(256)])
    queries = route.traverses[3]
    one = _fit(route.map, budget=4000)
    two = BTELocalizer(progress=False, random_state=0, budget=4000).fit(X2, places)
    assert two.nbytes <= 4000 and two.n_places_ == 256
    r_one = np.mean(np.abs(one.predict(queries) - np.arange(256)) <= 2)
    r_two = np.mean(np.abs(two.predict(queries) - np.arange(256)) <= 2)
    assert r_two >= r_one


# -- ranking, scores, sequences ------------------------------------------------------------------
@pytest.mark.parametrize("kw", [{}, {"block_size": 5}, {"code_copies": 2}, {"n_regions": 3},
                                {"block_size": 5, "code_copies": 2, "n_regions": 3, "exemplar_radius": 1}])
def test_rank_agrees_with_scores(route, kw):
    model = _fit(route.map, feature_ratio=0.5, **kw)
    ranked = model.rank(route.queries, 6)
    assert ranked.shape == (400, 6) and ranked.min() >= 0 and ranked.max() < 400
    assert all(len(set(row)) == 6 for row in ranked.tolist())
    scores = model.place_scores(route.queries)
    assert scores.shape == (400, 400)
    # The first candidate is the point prediction; the others follow by score, best first.
    np.testing.assert_array_equal(ranked[:, 0], model.predict(route.queries))
    rest = np.take_along_axis(scores, ranked[:, 1:], axis=1)
    assert np.all(np.diff(rest, axis=1) <= 1e-9)
    # Where the point is the best-scoring place (always, but for a constrained decode of an invalid
    # hard code), the ranking is the score order outright.
    first = np.take_along_axis(scores, ranked[:, :1], axis=1)[:, 0]
    top = np.isclose(first, scores.max(axis=1), rtol=1e-5, atol=1e-4)
    assert top.mean() > 0.8
    np.testing.assert_allclose(rest[top, 0], np.sort(scores[top], axis=1)[:, -2 if "block_size" not in kw else -6],
                               rtol=1e-5, atol=1e-4)
    if "block_size" in kw:
        np.testing.assert_array_equal(ranked % 5, 2)
        np.testing.assert_array_equal(scores[:, 0], scores[:, 4])  # one score per block


@pytest.mark.parametrize("decoder,opts", [("hmm", {}), ("hmm", {"temperature": 0.3, "vmax": 3}), ("median", {"window": 5})])
def test_predict_sequence(route, decoder, opts):
    model = _fit(route.map, feature_ratio=0.5)
    out = model.predict_sequence(route.queries, decoder, **opts)
    assert out.shape == (400,) and out.min() >= 0 and out.max() < 400


def test_hmm_helps_a_noisy_single_frame_localizer():
    # Queries far from the map: single frames are often wrong, but consecutive frames move forward
    # one place at a time, which the HMM uses.
    route = synthetic_route(300, 64, condition_shift=0.9, noise=0.6, seed=2)
    model = _fit(route.map, feature_ratio=1.0)
    truth = np.arange(300)
    single = np.mean(np.abs(model.predict(route.queries) - truth) <= 5)
    hmm = np.mean(np.abs(model.predict_sequence(route.queries) - truth) <= 5)
    assert hmm > single


def test_sequence_decoding_for_baselines_too(route):
    from btel.methods import make_method

    pq = make_method("pq", budget="20KB").fit(route.map)
    out = pq.predict_sequence(route.queries)
    assert out.shape == (400,)


# -- files and errors ----------------------------------------------------------------------------
@pytest.mark.parametrize("kw", [{"block_size": 4}, {"code_copies": 3, "exemplar_radius": 2}, {"block_size": 3, "n_regions": 2}])
def test_save_and_load(tmp_path, route, kw):
    model = _fit(route.map, budget=6000, **kw)
    again = load(model.save(tmp_path / "m.npz"))
    np.testing.assert_array_equal(again.predict(route.queries), model.predict(route.queries))
    np.testing.assert_array_equal(again.rank(route.queries, 4), model.rank(route.queries, 4))
    assert again.nbytes == model.nbytes


def test_foreign_block_size_in_file_is_rejected(tmp_path, route):
    path = _fit(route.map, budget=6000, block_size=4).save(tmp_path / "m.npz")
    arrays, header = load_arrays(path)
    header["params"]["block_size"] = 0
    save_arrays(tmp_path / "bad.npz", arrays, header)
    with pytest.raises(ModelFileError, match="block_size"):
        load(tmp_path / "bad.npz")


def test_errors(route):
    with pytest.raises(InvalidParameterError, match="2"):
        _fit(route.map, block_size=400)
    with pytest.raises(InvalidParameterError, match="compressed"):
        _fit(route.map, scheme="full", code_copies=2)
    with pytest.raises(InvalidParameterError, match="exemplar_radius"):
        _fit(route.map, exemplar_radius=-1)
    with pytest.raises(InvalidParameterError, match="decoder"):
        _fit(route.map, feature_ratio=0.2).predict_sequence(route.queries, "viterbi")
    # BTE-F ranks too (by the flip cost along each place's path), starting with its greedy descent.
    full = _fit(route.map, scheme="full", feature_ratio=0.2)
    np.testing.assert_array_equal(full.rank(route.queries, 3)[:, 0], full.predict(route.queries))


@pytest.mark.realdata
def test_options_on_gardens_point(gardenspoint_netvlad):
    X, Q = gardenspoint_netvlad
    budget = 12000
    plain = _fit(X, budget=budget)
    for kw in ({"block_size": 4}, {"code_copies": 2}, {"exemplar_radius": 2}):
        model = _fit(X, budget=budget, **kw)
        assert model.nbytes <= budget
        pred = model.predict(Q)
        assert pred.min() >= 0 and pred.max() < X.shape[0]
        ranked = model.rank(Q, 5)
        assert ranked.shape == (Q.shape[0], 5)
    assert _fit(X, budget=budget, block_size=4).n_selected_ > plain.n_selected_
    # R@5 of ranked output is at least single-frame recall (the first candidate is the prediction
    # for plain codes).
    truth = np.arange(X.shape[0])
    ranked = plain.rank(Q, 5)
    np.testing.assert_array_equal(ranked[:, 0], plain.predict(Q))
    assert np.mean(np.any(np.abs(ranked - truth[:, None]) <= 2, axis=1)) >= np.mean(np.abs(plain.predict(Q) - truth) <= 2)
