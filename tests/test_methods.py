"""Every registered method honours the one interface and its byte budget (parametrised over the registry)."""

from __future__ import annotations

import numpy as np
import pytest

from btel import load
from btel.core.fingerprint import map_fingerprint
from btel.exceptions import BudgetTooSmallError, InvalidParameterError
from btel.methods import METHODS, make_method


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    from btel.datasets import synthetic_route

    r = synthetic_route(200, 48, n_regions=4, noise=0.05, condition_shift=0.05, seed=3)
    return r.map, r.queries


@pytest.mark.parametrize("name", list(METHODS))
@pytest.mark.parametrize("budget", [3_000, 40_000])
def test_budget_is_honoured_or_refused_with_the_minimum(name: str, budget: int, route) -> None:
    X, Q = route
    method = make_method(name, budget=budget)
    try:
        method.fit(X)
    except BudgetTooSmallError as exc:
        assert exc.minimum > budget
        assert str(exc.minimum) in str(exc)
        return
    assert method.nbytes <= budget
    assert sum(method.storage_breakdown().values()) == method.nbytes
    # Every method's summary says what it spends of the budget (it was '' for most): the figure, as printed.
    assert f"{method.nbytes:,d} B" in method.summary() and f"{budget:,d} B" in method.summary()
    pred = method.predict(Q)
    assert pred.dtype == np.int64 and pred.shape == (200,)
    assert pred.min() >= 0 and pred.max() < 200


@pytest.mark.parametrize("name", list(METHODS))
def test_a_budget_of_ten_bytes_is_refused(name: str, route) -> None:
    with pytest.raises(BudgetTooSmallError, match="B"):
        make_method(name, budget=10).fit(route[0])


@pytest.mark.parametrize("name", list(METHODS))
def test_save_load_and_ranking(name: str, route, tmp_path) -> None:
    X, Q = route
    method = make_method(name).fit(X)
    path = method.save(tmp_path / f"{name}.npz")
    again = load(path)
    np.testing.assert_array_equal(again.predict(Q), method.predict(Q))
    assert path.stat().st_size - method.nbytes <= 4096
    # The file records which rows the places index (btel info shows it), and the digest is of those rows.
    assert again.map_fingerprint_ == method.map_fingerprint_ == map_fingerprint(X)
    if True:  # every method ranks
        ranked = method.rank(Q, 5)
        assert ranked.shape == (200, 5)
        assert len(np.unique(ranked[0])) == 5


def test_unknown_method_names_the_choices() -> None:
    with pytest.raises(InvalidParameterError, match="btel-c"):
        make_method("nope")


@pytest.mark.parametrize("name", list(METHODS))
def test_the_first_ranked_place_is_the_prediction_for_every_method(name: str, route) -> None:
    """R@1 is the recall of predict, for every method (the ranking starts with the point decode)."""
    X, Q = route
    method = make_method(name, budget=40_000).fit(X) if name not in ("bruteforce", "seqslam") else \
        make_method(name).fit(X)
    scores, places = method.search(Q, 10)
    assert places.shape == scores.shape == (200, 10) and scores.dtype == np.float64
    np.testing.assert_array_equal(places[:, 0], method.predict(Q))
    np.testing.assert_array_equal(method.rank(Q, 10), places)
    assert all(len(set(row)) == 10 for row in places.tolist())
    assert places.min() >= 0 and places.max() < 200


@pytest.mark.parametrize("name", list(METHODS))
def test_tied_places_rank_lowest_first_so_predict_is_the_first_ranked(name: str, route) -> None:
    """A map with identical rows (Gardens Point has one pair): faiss' heaps return ties in no set order,
    and search put place 183 first where predict answered 179."""
    X, Q = route
    X = X.copy()
    X[150:160] = X[40:50]  # ten places identical to ten others: every query near them ties
    method = make_method(name, budget=40_000).fit(X) if name not in ("bruteforce", "seqslam") else \
        make_method(name).fit(X)
    scores, places = method.search(Q, 10)
    np.testing.assert_array_equal(places[:, 0], method.predict(Q))
    tied = scores[:, 1:] == scores[:, :-1]
    assert (places[:, 1:][tied] > places[:, :-1][tied]).all()


@pytest.mark.parametrize("name", ["btel-c", "btel-r", "btel-f", "ryth"])
@pytest.mark.parametrize("front", [{}, {"whiten": 8}])
def test_large_batches_predicted_in_chunks_equal_the_whole_batch_answer(name: str, front, route) -> None:
    """Batches ≥ 8192 queries run in row chunks on every core: same answers as one-chunk prediction."""
    from btel.methods import base

    X, Q = route
    model = make_method(name, **front).fit(X)
    rng = np.random.default_rng(0)
    big = np.repeat(Q, -(-9000 // len(Q)), axis=0)[:9000] + 0.01 * rng.standard_normal((9000, Q.shape[1]))
    big = big.astype(np.float32)
    chunked = model.predict(big)
    expected = model._predict(model._check_queries(big))  # the whole batch in one call, one thread
    np.testing.assert_array_equal(chunked, expected)
    np.testing.assert_array_equal(chunked, model.search(big, 1)[1][:, 0])
    assert base._PARALLEL_PREDICT_FROM <= len(big)


def test_a_nan_in_a_chunked_batch_is_named_by_its_row_in_the_whole_batch(route) -> None:
    from btel.exceptions import InvalidDescriptorsError

    X, Q = route
    model = make_method("btel-c").fit(X)
    big = np.repeat(Q, -(-9000 // len(Q)), axis=0)[:9000].astype(np.float32)
    big[8500, 3] = np.nan
    with pytest.raises(InvalidDescriptorsError, match="row 8500, column 3"):
        model.predict(big)


def test_check_budget_refuses_btel_codes_before_fitting() -> None:
    """btel-codes had no branch in the old pre-fit chain: it was never checked before fitting."""
    from btel.exceptions import BudgetTooSmallError

    model = make_method("btel-codes", budget=40)
    with pytest.raises(BudgetTooSmallError, match="output codes") as info:
        model.check_budget(1000, 512, 40)
    assert info.value.minimum > 40
    X = np.random.default_rng(0).normal(size=(1000, 512)).astype(np.float32)
    with pytest.raises(BudgetTooSmallError) as fitted:  # the same minimum as fit's
        make_method("btel-codes", budget=40).fit(X)
    assert fitted.value.minimum == info.value.minimum
    make_method("btel-codes", budget="64KB").check_budget(1000, 512, 64_000)  # fits: no error


def test_shared_layers_ask_the_method_not_its_class() -> None:
    """The evaluation pre-check and the experiments' cache never name a method class (issue 19)."""
    import inspect

    import btel.evaluation.batch
    import btel.evaluation.measure
    import btel.experiments._common

    for module in (btel.evaluation.measure, btel.evaluation.batch, btel.experiments._common):
        source = inspect.getsource(module)
        for name in ("BTELocalizer", "RYTHLocalizer", "PQLocalizer", "ITQLocalizer", "BruteForceNN", "CodeLocalizer"):
            assert f"isinstance(method, {name}" not in source and f"isinstance(model, {name}" not in source, \
                (module.__name__, name)


def test_registry_holds_one_factory_and_description_per_method() -> None:
    from btel.methods.base import PlaceLocalizer
    from btel.methods import DESCRIPTIONS, REGISTRY

    assert list(REGISTRY) == list(METHODS) == list(DESCRIPTIONS)
    for name, (factory, description) in REGISTRY.items():
        assert isinstance(factory(), PlaceLocalizer), name
        assert description and "\n" not in description, name


#: Methods whose largest model fits 400 KB on the module's route (N = 200, d = 48).
SATURATE_ON_THE_ROUTE = {"btel-c", "btel-f", "btel-r", "ryth", "bruteforce", "pq", "opq", "itq", "lsh", "seqslam", "rabitq"}


@pytest.mark.parametrize("name", list(METHODS))
def test_a_saturated_model_is_the_model_of_every_larger_budget(name: str, route) -> None:
    """``budget_saturated()`` is what the run table's ‡ and the experiments' reuse of fits rely on: where a
    model says it, a budget 8 times larger gives the same stored bytes and the same answers."""
    X, Q = route
    saturated_at = []
    for budget in (3_000, 40_000, 400_000):
        try:
            model = make_method(name, budget=budget).fit(X)
        except BudgetTooSmallError:
            continue
        if model.budget_saturated():
            larger = make_method(name, budget=8 * budget).fit(X)
            assert larger.budget_saturated()
            assert larger.storage_breakdown() == model.storage_breakdown()
            np.testing.assert_array_equal(larger.predict(Q), model.predict(Q))
            saturated_at.append(budget)
    assert bool(saturated_at) == (name in SATURATE_ON_THE_ROUTE), saturated_at


@pytest.mark.parametrize("name", ["pq", "auto", "btel-codes"])
def test_check_budget_takes_a_budget_as_the_budget_parameter_does(name: str) -> None:
    from btel.exceptions import BudgetTooSmallError

    with pytest.raises(BudgetTooSmallError, match="budget 10 B is too small"):
        make_method(name).check_budget(300, 64, "10B")
    make_method(name).check_budget(300, 64, "64KB")  # fits: nothing raised


@pytest.mark.parametrize("name", list(METHODS))
def test_messages_name_the_method_as_a_user_types_it(name: str) -> None:
    """A message says 'pq', not 'PQLocalizer': the name given to make_method and --methods (BTEL: its family)."""
    model = make_method(name)
    assert model.label == ("BTEL" if name.startswith("btel-") and name != "btel-codes" else name)
    too_few = np.random.default_rng(0).normal(size=(model._min_rows - 1 or 1, 8)).astype(np.float32)
    with pytest.raises(Exception) as err:
        model.fit(too_few)
    assert type(model).__name__ not in str(err.value)


def test_calibration_given_to_a_method_other_than_auto_says_which_method_takes_it(route) -> None:
    X, Q = route
    with pytest.raises(InvalidParameterError, match=r"lsh's fit takes X and places only, not calibration; .*'auto'"):
        make_method("lsh", budget="4KB").fit(X, calibration=(Q[:5], np.arange(5)))


@pytest.mark.parametrize("name", list(METHODS))
def test_search_scores_hold_no_negative_zero(name: str, route) -> None:
    """BTE-C scored most Nordland queries -0.0 (a negated zero distance), printed "-0." by numpy."""
    X, Q = route
    params = {"progress": False} if "progress" in make_method(name).get_params() else {}
    scores, _ = make_method(name, **params).fit(X).search(Q, 3)
    assert not np.any((scores == 0) & np.signbit(scores))
