"""Tolerance-aware codes (btel.tolerant): blocks of B places, block centres, same budget."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.base import clone

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.encoding import n_bits_for
from btel.exceptions import InvalidParameterError, ModelFileError, NotEnoughPlacesError
from btel.storage import load_arrays
from btel.tolerant import TolerantLocalizer, block_centres, block_labels, block_size_for_tolerance


@pytest.mark.parametrize(("t", "B"), [(0, 1), (1, 1), (2, 2), (3, 2), (10, 8), (16, 16), (31, 16)])
def test_block_size_rule(t, B):
    assert block_size_for_tolerance(t) == B
    assert (B // 2 if B > 1 else 0) <= max(t, 0)  # worst error inside a block ≤ t


def test_block_centres_are_within_half_a_block():
    n, B = 103, 8
    places = np.arange(n)
    centres = block_centres(block_labels(places, B), B, n)
    assert centres.max() < n
    assert np.abs(centres - places).max() <= B // 2
    assert centres[-1] == (96 + 102) // 2  # the short last block has its own centre


@pytest.fixture(scope="module")
def route():
    return synthetic_route(400, 64, seed=11)


def test_same_budget_buys_more_features_per_bit(route):
    budget = 2000  # plain (9 bits): d' = 36 of 64 columns; the block tree (6 bits) affords all 64
    plain = BTELocalizer(budget=budget, progress=False, random_state=0).fit(route.map)
    tol = TolerantLocalizer(BTELocalizer(budget=budget, progress=False, random_state=0), block_size=8).fit(route.map)
    assert tol.n_blocks_ == 50 and tol.localizer_.n_bits_ == n_bits_for(50) == 6
    assert plain.n_bits_ == 9
    assert tol.nbytes <= budget and plain.nbytes <= budget
    assert tol.localizer_.n_selected_ > plain.n_selected_
    pred = tol.predict(route.queries)
    assert set(np.unique(pred)) <= set(block_centres(np.arange(50), 8, 400).tolist())


def test_learnable_map_decodes_to_the_right_block():
    # d ≫ number of blocks: the block labels are linearly separable, so noisy copies of the map
    # must land in their own block (error ≤ 2 from a 4-place block's centre).
    route = synthetic_route(128, 512, seed=12)
    tol = TolerantLocalizer(BTELocalizer(feature_ratio=1.0, progress=False, random_state=0), tolerance=4)
    tol.fit(route.map)
    assert tol.block_size_ == 4
    rng = np.random.default_rng(0)
    noisy = route.map + 0.05 * route.map.std(axis=0) * rng.standard_normal(route.map.shape).astype(np.float32)
    pred = tol.predict(noisy)
    assert np.mean(np.abs(pred - np.arange(128)) <= 2) > 0.95


def test_rank_and_scores(route):
    tol = TolerantLocalizer(BTELocalizer(feature_ratio=0.5, progress=False, random_state=0), block_size=5)
    tol.fit(route.map)
    ranked = tol.rank(route.queries, 6)
    assert ranked.shape == (400, 6)
    np.testing.assert_array_equal(ranked[:, 0] % 5, 2)  # centres of 5-place blocks
    scores = tol.place_scores(route.queries)
    assert scores.shape == (400, 400)
    np.testing.assert_array_equal(scores[:, 0], scores[:, 4])  # one score per block
    np.testing.assert_array_equal(np.argmax(scores, axis=1) // 5, ranked[:, 0] // 5)


def test_budget_overrides_the_localizers(route):
    tol = TolerantLocalizer(BTELocalizer(budget=50_000, progress=False, random_state=0), block_size=8, budget=1500)
    tol.fit(route.map)
    assert tol.nbytes <= 1500 and tol.localizer_.budget == 1500
    assert tol.localizer.budget == 50_000  # the template is left alone


def test_sklearn_params_and_clone(route):
    tol = TolerantLocalizer(BTELocalizer(C=0.1), tolerance=8)
    params = tol.get_params(deep=True)
    assert params["localizer__C"] == 0.1 and params["tolerance"] == 8
    assert clone(tol).get_params()["tolerance"] == 8


def test_save_and_restore(tmp_path, route):
    tol = TolerantLocalizer(BTELocalizer(budget=6000, C=0.5, progress=False, random_state=0), block_size=4)
    tol.fit(route.map)
    path = tol.save(tmp_path / "tol.npz")
    arrays, header = load_arrays(path)
    assert header["model"] == "TolerantLocalizer" and header["params"]["block_size"] == 4
    again = TolerantLocalizer(**header["params"])
    again._restore(arrays, header["state"])
    np.testing.assert_array_equal(again.predict(route.queries), tol.predict(route.queries))
    assert again.nbytes == tol.nbytes and again.localizer_.C == 0.5
    bad = dict(header["state"], block_size=3)
    with pytest.raises(ModelFileError, match="blocks"):
        TolerantLocalizer()._restore(arrays, bad)


def test_errors(route):
    with pytest.raises(InvalidParameterError, match="not both"):
        TolerantLocalizer(block_size=4, tolerance=4).fit(route.map)
    with pytest.raises(NotEnoughPlacesError, match="at least 2"):
        TolerantLocalizer(block_size=400).fit(route.map)
    with pytest.raises(InvalidParameterError, match="BTELocalizer"):
        TolerantLocalizer(localizer="svm", block_size=2).fit(route.map)


@pytest.mark.realdata
def test_tolerant_on_gardens_point(gardenspoint_netvlad):
    X, Q = gardenspoint_netvlad
    budget = 12000
    plain = BTELocalizer(budget=budget, progress=False, random_state=0).fit(X)
    tol = TolerantLocalizer(BTELocalizer(budget=budget, progress=False, random_state=0), tolerance=4).fit(X)
    assert tol.nbytes <= budget
    assert tol.localizer_.n_selected_ > plain.n_selected_
    pred = tol.predict(Q)
    assert pred.min() >= 0 and pred.max() < X.shape[0]
    assert np.all(pred % 4 == 1)  # centre of [4m, 4m + 3]
