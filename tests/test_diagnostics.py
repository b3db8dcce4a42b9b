"""Per-bit diagnostics (btel.methods.btel.diagnostics)."""

from __future__ import annotations

import numpy as np
import pytest

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.methods.btel.diagnostics import bit_accuracy, localizer_bit_accuracy, plot_bit_accuracy
from btel.methods.btel.encoding import encode
from btel.exceptions import InvalidParameterError


def test_bit_accuracy_counts():
    truth = np.array([[0, 1], [1, 1], [1, 0], [0, 0]])
    margins = np.array([[-1.0, 2.0], [1.0, -1.0], [-3.0, np.nan], [-0.5, -0.1]])
    d = bit_accuracy(margins, truth)
    np.testing.assert_allclose(d.accuracy, [3 / 4, 2 / 3])
    np.testing.assert_array_equal(d.counts, [4, 3])
    np.testing.assert_allclose(d.balanced, [(1 / 2 + 1) / 2, (1 / 2 + 1) / 2])
    np.testing.assert_allclose(d.majority, [0.5, 2 / 3])
    assert d.levels.tolist() == [1, 2]
    one_valued = bit_accuracy(np.array([[1.0], [2.0]]), np.array([[1], [1]]))
    assert np.isnan(one_valued.balanced[0]) and one_valued.majority[0] == 1.0
    assert one_valued.mutual_information[0] == 0.0  # a constant bit carries no information


def test_mutual_information_of_perfect_and_independent_bits():
    rng = np.random.default_rng(0)
    truth = rng.integers(0, 2, size=(4000, 2))
    margins = np.where(truth == 1, 1.0, -1.0)
    margins[:, 1] = rng.standard_normal(4000)  # level 2: a coin flip, independent of the truth
    d = bit_accuracy(margins, truth)
    ref = -(truth[:, 0].mean() * np.log2(truth[:, 0].mean()) + (1 - truth[:, 0].mean()) * np.log2(1 - truth[:, 0].mean()))
    np.testing.assert_allclose(d.mutual_information[0], ref)  # I(T; T) = H(T) ≈ 1 bit
    assert d.mutual_information[1] < 0.01
    assert d.to_dict()["information_per_query"] == pytest.approx(d.mutual_information.sum())


def test_bit_accuracy_shape_error():
    with pytest.raises(InvalidParameterError, match="one shape"):
        bit_accuracy(np.zeros((3, 2)), np.zeros((3, 3)))


@pytest.fixture(scope="module")
def route():
    return synthetic_route(300, 64, n_regions=3, seed=7)


def test_plain_model_matches_decision_function(route):
    model = BTELocalizer(feature_ratio=0.5, progress=False, random_state=0).fit(route.map)
    truth = np.arange(300)
    d = localizer_bit_accuracy(model, route.queries, truth)
    expected = ((model.decision_function(route.queries) > 0) == encode(truth, 9)).mean(axis=0)
    np.testing.assert_allclose(d.accuracy, expected)
    assert d.region_accuracy is None
    # The map itself is (nearly) learned: training accuracy ≥ query accuracy on average.
    train = localizer_bit_accuracy(model, route.map, truth)
    assert np.nanmean(train.accuracy) >= np.nanmean(d.accuracy)


def test_regions_use_the_true_regions_tree(route):
    model = BTELocalizer(feature_ratio=0.5, n_regions=3, progress=False, random_state=0).fit(route.map)
    d = localizer_bit_accuracy(model, route.queries, np.arange(300))
    assert d.region_accuracy is not None and 0 <= d.region_accuracy <= 1
    assert d.counts[0] == 300  # every query measured at the top level of its region's tree
    # Deeper levels exist only in the larger trees.
    assert d.accuracy.size == max(int(np.ceil(np.log2(s))) for s in model.region_sizes_)


def test_tolerant_model_uses_block_bits(route):
    tol = BTELocalizer(feature_ratio=0.5, progress=False, random_state=0, block_size=4).fit(route.map)
    d = localizer_bit_accuracy(tol, route.queries, np.arange(300))
    expected = ((tol.decision_function(route.queries) > 0) == encode(np.arange(300) // 4, 7)).mean(axis=0)
    np.testing.assert_allclose(d.accuracy, expected)


def test_offset_code_model_scores_its_plain_bits(route):
    model = BTELocalizer(feature_ratio=0.5, progress=False, random_state=0, code_copies=2).fit(route.map)
    d = localizer_bit_accuracy(model, route.queries, np.arange(300))
    expected = ((model.decision_function(route.queries)[:, :9] > 0) == encode(np.arange(300), 9)).mean(axis=0)
    np.testing.assert_allclose(d.accuracy, expected)


def test_true_places_checked(route):
    model = BTELocalizer(feature_ratio=0.5, progress=False).fit(route.map)
    with pytest.raises(InvalidParameterError, match="true_places"):
        localizer_bit_accuracy(model, route.queries, np.arange(299))


def test_plot_writes_png(tmp_path, route):
    model = BTELocalizer(feature_ratio=0.5, progress=False, random_state=0).fit(route.map)
    d = localizer_bit_accuracy(model, route.queries, np.arange(300))
    for balanced in (False, True):
        path = tmp_path / f"bits_{balanced}.png"
        fig = plot_bit_accuracy({"BTE-C": d, "BTE-C map": localizer_bit_accuracy(model, route.map, np.arange(300))},
                                path, title="t", balanced=balanced)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert len(fig.axes[0].lines) == 3
    assert d.to_dict()["levels"] == list(range(1, 10))
    with pytest.raises(InvalidParameterError):
        plot_bit_accuracy({}, tmp_path / "x.png")


@pytest.mark.realdata
def test_bit_diagnostics_on_gardens_point(gardenspoint_netvlad):
    X, Q = gardenspoint_netvlad
    model = BTELocalizer(feature_ratio=0.3, progress=False, random_state=0).fit(X)
    truth = np.arange(X.shape[0])
    queries = localizer_bit_accuracy(model, Q, truth)
    train = localizer_bit_accuracy(model, X, truth)
    assert queries.counts.tolist() == [X.shape[0]] * 8
    assert np.all((queries.accuracy >= 0) & (queries.accuracy <= 1))
    # A linear classifier fits its own map better than another traverse of it.
    assert train.accuracy.mean() > queries.accuracy.mean()
