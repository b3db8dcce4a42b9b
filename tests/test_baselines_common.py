"""The PlaceLocalizer contract for every baseline: recall sanity, budgets, files, ranking, places."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from sklearn.base import clone

from btel.methods import MODEL_CLASSES, load
from btel.methods.baselines import BASELINES, BruteForceNN, ITQLocalizer, OPQLocalizer, PQLocalizer, SeqSLAM
from btel.methods.baselines._common import rank_unique_places
from btel.exceptions import (
    BudgetTooSmallError,
    DimensionMismatchError,
    InvalidParameterError,
    NotEnoughPlacesError,
    NotFittedError,
)
from btel.core.storage import parse_budget

N_PLACES, DIM = 300, 32


def make(name: str, **params):
    """A baseline on one faiss thread (small indexes: threads only add overhead in tests)."""
    return BASELINES[name](n_jobs=1, **params)


@pytest.fixture(scope="module")
def route() -> tuple[np.ndarray, np.ndarray]:
    """A map of well-separated places and queries = map + small noise (query j is at place j)."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(N_PLACES, DIM)).astype(np.float32)
    Q = (X + 0.05 * rng.normal(size=X.shape)).astype(np.float32)
    return X, Q


@pytest.fixture(scope="module")
def fitted(route) -> dict[str, object]:
    X, _ = route
    return {name: make(name).fit(X) for name in BASELINES}


def test_registry_lists_every_baseline_and_registers_it_for_load():
    assert set(BASELINES) == {"bruteforce", "pq", "opq", "itq", "lsh", "seqslam"}
    for cls in BASELINES.values():
        assert MODEL_CLASSES[cls.__name__] is cls


@pytest.mark.parametrize("name", list(BASELINES))
def test_recall_on_noisy_copies_of_the_map(name, route, fitted):
    X, Q = route
    pred = fitted[name].predict(Q)
    assert pred.dtype == np.int64 and pred.shape == (N_PLACES,)
    assert pred.min() >= 0 and pred.max() < N_PLACES
    # Noise (σ = 0.05) is tiny next to the spacing of the places (σ = 1 per dimension).
    assert np.mean(pred == np.arange(N_PLACES)) >= 0.9


@pytest.mark.parametrize("name", list(BASELINES))
def test_fitted_attributes(name, route, fitted):
    model = fitted[name]
    assert model.n_places_ == N_PLACES
    assert model.n_features_in_ == DIM
    assert model.fit_time_ >= 0
    assert model.row_places_ is None
    assert model.nbytes == sum(model.storage_breakdown().values())
    assert model.nbytes == sum(a.nbytes for a in model._stored_arrays().values())


@pytest.mark.parametrize("name", list(BASELINES))
@pytest.mark.parametrize("budget", [3_000, 12_000, "20KB", "40KB", 10**6])
def test_bytes_never_exceed_the_budget_and_the_stated_minimum_fits(name, budget, route):
    X, Q = route
    limit = parse_budget(budget)
    try:
        model = make(name, budget=budget).fit(X)
    except BudgetTooSmallError as err:
        assert err.budget == limit and err.minimum > limit
        assert str(err.minimum) in str(err)
        # The minimum the error names is achievable: a budget of exactly that many bytes fits.
        model = make(name, budget=err.minimum).fit(X)
        assert model.nbytes <= err.minimum
    else:
        assert model.nbytes <= limit
    pred = model.predict(Q)
    assert pred.min() >= 0 and pred.max() < N_PLACES


@pytest.mark.parametrize(
    "name, expected",
    [("bruteforce", N_PLACES * DIM * 4), ("seqslam", N_PLACES * DIM + 8)],
)
def test_single_configuration_methods_state_their_exact_size(name, expected, route):
    X, _ = route
    with pytest.raises(BudgetTooSmallError, match=str(expected)) as info:
        make(name, budget=expected - 1).fit(X)
    assert info.value.minimum == expected
    assert make(name, budget=expected).fit(X).nbytes == expected


@pytest.mark.parametrize("name", list(BASELINES))
def test_tiny_budget_raises_with_the_minimum(name, route):
    X, _ = route
    with pytest.raises(BudgetTooSmallError) as info:
        make(name, budget=100).fit(X)
    assert info.value.budget == 100
    assert f"{info.value.minimum} B" in str(info.value)


@pytest.mark.parametrize("name", list(BASELINES))
def test_save_load_round_trip(name, route, fitted, tmp_path):
    _, Q = route
    model = fitted[name]
    path = model.save(tmp_path / f"{name}.btel.npz")
    loaded = load(path)
    assert type(loaded) is type(model)
    # Runtime settings (faiss threads) are not model content: they are not saved.
    assert loaded.get_params() == {**model.get_params(), "n_jobs": None}
    np.testing.assert_array_equal(loaded.predict(Q), model.predict(Q))
    np.testing.assert_array_equal(loaded.rank(Q, 5), model.rank(Q, 5))
    assert loaded.storage_breakdown() == model.storage_breakdown()
    # The file holds the stored arrays plus a small header and container overhead only.
    assert 0 <= path.stat().st_size - model.nbytes < 4096


@pytest.mark.parametrize("name", list(BASELINES))
def test_pickle_round_trip(name, route, fitted):
    _, Q = route
    model = fitted[name]
    model.predict(Q[:2])  # make sure any faiss index exists before pickling
    copy = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(copy.predict(Q), model.predict(Q))


@pytest.mark.parametrize("name", list(BASELINES))
def test_rank_shape_order_and_agreement_with_predict(name, route, fitted):
    _, Q = route
    model = fitted[name]
    ranked = model.rank(Q, 7)
    assert ranked.shape == (N_PLACES, 7) and ranked.dtype == np.int64
    assert ranked.min() >= 0 and ranked.max() < N_PLACES
    assert all(len(set(row)) == 7 for row in ranked)
    np.testing.assert_array_equal(ranked[:, 0], model.predict(Q))
    # k is capped at the number of places.
    assert model.rank(Q[:3], N_PLACES + 5).shape == (3, N_PLACES)


def test_bruteforce_rank_is_sorted_by_true_distance(route, fitted):
    model = fitted["bruteforce"]
    X, Q = (model.front_end_.transform(a) for a in route)  # distances on the front end's rows
    ranked = model.rank(route[1][:20], 10)
    dist = ((Q[:20, None, :] - X[None, :, :]) ** 2).sum(-1)
    got = np.take_along_axis(dist, ranked, axis=1)
    assert np.all(np.diff(got, axis=1) >= -1e-4)
    np.testing.assert_allclose(got[:, 0], dist.min(axis=1), rtol=1e-4)


@pytest.mark.parametrize("name", list(BASELINES))
def test_several_descriptors_per_place_map_back_to_place_labels(name):
    # Two descriptors per place, interleaved in route order; queries are noisy copies of the
    # second descriptor of each place, so the predicted *row* is odd but the answer is the place.
    rng = np.random.default_rng(1)
    n = 150
    X = rng.normal(size=(2 * n, DIM)).astype(np.float32)
    places = np.repeat(np.arange(n), 2)
    Q = (X[1::2] + 0.05 * rng.normal(size=(n, DIM))).astype(np.float32)
    # SeqSLAM would see two map rows per query (velocity 2); judge its row → place step alone.
    params = {"ds": 1} if name == "seqslam" else {}
    model = make(name, **params).fit(X, places=places)
    assert model.n_places_ == n
    assert "row_places" in model.storage_breakdown()
    assert model.row_places_.dtype == np.uint8
    pred = model.predict(Q)
    assert pred.max() < n and np.mean(pred == np.arange(n)) >= 0.9
    ranked = model.rank(Q, 5)
    assert ranked.shape == (n, 5) and all(len(set(row)) == 5 for row in ranked)
    np.testing.assert_array_equal(ranked[:, 0], pred)


def test_identity_places_store_no_table(route):
    X, _ = route
    model = make("bruteforce").fit(X, places=np.arange(N_PLACES))
    assert model.row_places_ is None and "row_places" not in model.storage_breakdown()


def test_rank_unique_places_keeps_first_occurrences_in_order():
    rows = np.array([[4, 5, 0, 1, 2, 3], [0, 2, 1, 5, 3, 4]])
    places = np.array([0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(rank_unique_places(rows, places, 3)[0], [[2, 0, 1], [0, 1, 2]])


@pytest.mark.parametrize("name", list(BASELINES))
def test_errors_before_fit_and_on_bad_queries(name, route, fitted):
    X, Q = route
    with pytest.raises(NotFittedError):
        make(name).predict(Q)
    with pytest.raises(DimensionMismatchError, match=f"fitted on {DIM}"):
        fitted[name].predict(Q[:, :-1])
    with pytest.raises(InvalidParameterError, match="k must be"):
        fitted[name].rank(Q, 0)
    with pytest.raises(NotEnoughPlacesError):
        make(name).fit(X[:1])


@pytest.mark.parametrize("name", list(BASELINES))
def test_bad_budget_and_n_jobs_are_rejected_in_fit(name, route):
    X, _ = route
    with pytest.raises(InvalidParameterError, match="budget"):
        make(name, budget="lots").fit(X)
    with pytest.raises(InvalidParameterError, match="n_jobs"):
        BASELINES[name](n_jobs=0).fit(X)


@pytest.mark.parametrize("cls", [BruteForceNN, PQLocalizer, OPQLocalizer, ITQLocalizer, SeqSLAM])
def test_sklearn_params_and_clone(cls):
    model = cls(budget="1MB")
    params = model.get_params()
    assert params["budget"] == "1MB" and "n_jobs" in params
    assert clone(model).get_params() == params
    with pytest.raises(TypeError):
        cls("1MB")  # keyword-only


@pytest.mark.parametrize("name", ["bruteforce", "pq", "itq", "rabitq"])
def test_a_single_query_too_long_for_float32_distances_is_refused_without_normalisation(name) -> None:
    from btel.exceptions import InvalidDescriptorsError

    rng = np.random.default_rng(0)
    X = rng.normal(size=(N_PLACES, DIM)).astype(np.float32)
    from btel.methods import make_method

    model = make_method(name, n_jobs=1, normalize="none").fit(X)
    q = np.full((1, DIM), 1e19, dtype=np.float32)  # finite, its squared norm overflows float32
    for call in (model.predict, lambda q: model.search(q, 1)):
        with pytest.raises(InvalidDescriptorsError, match="row 0 has length"):
            call(q)
        with pytest.raises(InvalidDescriptorsError, match="row 0 has length"):
            call(np.vstack([X[:2], q])[2:])
    # Normalised (the default front end), the same query is a unit row: answered.
    assert 0 <= make_method(name, n_jobs=1).fit(X).predict(q)[0] < N_PLACES


@pytest.mark.parametrize("name", ["bruteforce", "pq", "opq", "itq", "rabitq", "lsh"])
def test_predict_reads_rows_only_and_answers_as_search(name) -> None:
    from btel.methods import make_method

    rng = np.random.default_rng(1)
    X = rng.normal(size=(N_PLACES, DIM)).astype(np.float32)
    Q = X[::25] + 0.1 * rng.normal(size=(12, DIM)).astype(np.float32)
    for places in (None, np.repeat(np.arange(N_PLACES // 2), 2)):  # row i = place i, then a row table
        model = make_method(name, n_jobs=1).fit(X, places=places)
        best = model.search(Q, 1)[1][:, 0]
        np.testing.assert_array_equal(model.predict(Q), best)
        np.testing.assert_array_equal([model.predict(Q[i : i + 1])[0] for i in range(len(Q))], best)
    seen: list[bool] = []
    model = make_method(name, n_jobs=1).fit(X)
    search_rows = model._search_rows

    def spy(Q, k, scores=True):
        seen.append(scores)
        return search_rows(Q, k, scores)

    model._search_rows = spy
    model.predict(Q[:1])
    model.search(Q[:1], 1)
    assert seen == [False, True]  # predict asks for no scores; search does


@pytest.mark.parametrize("name", ["pq", "itq", "bruteforce"])
def test_one_query_fast_path_refuses_what_the_general_path_refuses(name) -> None:
    from btel.exceptions import DimensionMismatchError, InvalidDescriptorsError, NotFittedError
    from btel.methods import make_method

    X = np.random.default_rng(2).normal(size=(N_PLACES, DIM)).astype(np.float32)
    with pytest.raises(NotFittedError):
        make_method(name).predict(X[:1])
    model = make_method(name).fit(X)
    for bad in (np.nan, np.inf):
        q = X[:1].copy()
        q[0, 5] = bad
        for call in (model.predict, lambda q: model.search(q, 1)):
            with pytest.raises(InvalidDescriptorsError, match="row 0, column 5"):
                call(q)
    with pytest.raises(DimensionMismatchError):
        model.predict(X[:1, :-1])
    best = model.predict(X[3:4])
    # float64, a strided view and a list take the general path, with the same answer.
    for q in (X[3:4].astype(np.float64), np.asfortranarray(np.vstack([X[3], X[3]]))[:1], X[3:4].tolist()):
        np.testing.assert_array_equal(model.predict(q), best)
    assert model.predict(X[3:4]).shape == (1,) and model.search(X[3:4], 1)[0].dtype == np.float64
    zero = np.zeros((1, DIM), dtype=np.float32)  # the fast path's scale 1.0: the general path's answer
    np.testing.assert_array_equal(model.predict(zero), model.predict(zero.astype(np.float64)))
    np.testing.assert_array_equal(model.search(zero, 1)[1], model.search(zero.astype(np.float64), 1)[1])


def test_index_search_answers_as_faiss_search_and_sends_only_matching_rows_to_the_swig_method() -> None:
    import faiss

    from btel.methods.baselines._common import index_search, negated_distances

    rng = np.random.default_rng(3)
    X = rng.normal(size=(300, 32)).astype(np.float32)
    flat, pq, binary = faiss.IndexFlatL2(32), faiss.IndexPQ(32, 4, 4), faiss.IndexBinaryFlat(32)
    flat.add(X)
    pq.train(X)
    pq.add(X)
    codes = np.packbits(X > 0, axis=1)
    binary.add(codes)
    for index, rows in ((flat, X), (pq, X), (binary, codes)):
        for q in (rows[7:8], rows[:5]):  # one row (the SWIG method), a batch (faiss' search)
            for k in (1, 3):
                got, want = index_search(index, q, k), index.search(q, k)
                assert got[0].dtype == want[0].dtype and got[1].dtype == np.int64
                np.testing.assert_array_equal(got[0], want[0])
                np.testing.assert_array_equal(got[1], want[1])
    # A row of another width or dtype never reaches the raw pointer: faiss' own search refuses it.
    for index, q in ((flat, X[:1, :16]), (flat, X[:1].astype(np.float64)[:, :16]), (binary, X[:1, :4])):
        with pytest.raises((AssertionError, ValueError, TypeError)):
            index_search(index, np.ascontiguousarray(q), 1)
    one = np.array([[2.5]], dtype=np.float32)
    assert negated_distances(one).dtype == np.float64 and negated_distances(one)[0, 0] == -2.5
    many = np.array([[1.0, 2.0]], dtype=np.float32)
    np.testing.assert_array_equal(negated_distances(many), [[-1.0, -2.0]])
    assert negated_distances(np.array([[3]], dtype=np.int32)).dtype == np.float64
