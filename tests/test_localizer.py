"""BTELocalizer (BTE-C, regions, budgets), the folded linear classifiers and the sklearn contract."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st
from sklearn.base import clone
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from sklearn.svm import LinearSVC

from btel import BTELocalizer
from btel.methods.btel.compressed import compressed_n_classifiers, compressed_tasks
from btel.datasets import synthetic_route
from btel.methods.btel.encoding import decode_constrained, decode_soft, encode, n_bits_for
from btel.exceptions import BudgetTooSmallError
from btel.learning.hyperplanes import Hyperplanes
from btel.learning.linear import ColumnStats, fit_linear
from btel.methods.btel.localizer import planned_bytes


@pytest.fixture(scope="module")
def route():
    return synthetic_route(200, 64, n_traverses=2, n_regions=5, seed=21)


def noisy_copy(M: np.ndarray, level: float, seed: int) -> np.ndarray:
    """Map + Gaussian noise of std ``level`` × each column's std."""
    rng = np.random.default_rng(seed)
    return (M + level * M.std(axis=0) * rng.standard_normal(M.shape)).astype(np.float32)


def test_clone_and_params_round_trip() -> None:
    model = BTELocalizer(scheme="full", C=2.0, feature_ratio=0.3, n_regions="auto", budget="1MB", dtype="float16",
                         n_jobs=2, random_state=5, progress=False)
    copy = clone(model)
    assert copy is not model and copy.get_params() == model.get_params()
    copy.set_params(scheme="compressed", n_regions=3)
    assert copy.get_params()["scheme"] == "compressed" and copy.n_regions == 3
    assert model.scheme == "full"
    assert BTELocalizer(**model.get_params()).get_params() == model.get_params()


def test_init_stores_only_params() -> None:
    # Nonsense values are stored as given; fit (not __init__) validates them.
    model = BTELocalizer(scheme="nonsense", feature_ratio=7, n_regions=-1, budget="??")
    assert (model.scheme, model.feature_ratio, model.n_regions, model.budget) == ("nonsense", 7, -1, "??")
    assert set(vars(model)) == set(model.get_params())


def test_fit_returns_self_and_fitted_attributes_end_in_underscore(route) -> None:
    model = BTELocalizer(n_regions=3, progress=False)
    before = set(vars(model))
    assert model.fit(route.map) is model
    learned = set(vars(model)) - before
    public = {name for name in learned if not name.startswith("_")}
    assert {"n_places_", "n_features_in_", "n_selected_", "n_regions_", "region_starts_", "hyperplanes_",
            "region_hyperplanes_", "n_unconverged_", "fit_time_"} <= public
    assert all(name.endswith("_") for name in public)
    assert model.fit_time_ > 0


def test_refit_forgets_the_previous_fit(route) -> None:
    model = BTELocalizer(n_regions=3, progress=False, random_state=0).fit(route.map)
    model.set_params(n_regions=1).fit(route.map[:50, :10])
    assert (model.n_places_, model.n_features_in_, model.n_regions_) == (50, 10, 1)
    assert model.region_hyperplanes_ is None
    small = route.map[:50, :10]
    fresh = BTELocalizer(progress=False, random_state=0).fit(small)
    np.testing.assert_array_equal(model.predict(small), fresh.predict(small))


# ----------------------------------------------------------------------------- options
OPTIONS = [
    pytest.param({"scheme": s, "dtype": t, "n_regions": r, "decode": dec, "classifier": c}, id=f"{s}-{t}-r{r}-{dec}-{c}")
    for s in ("compressed", "full")
    for t in ("float32", "float16")
    for r in (1, 2, 4, "auto")
    for dec in ("constrained", "soft")
    for c in ("svm", "logistic")
    if not (s == "full" and dec == "soft")
    # keep the grid small: logistic only with float32 and r in {1, 4}
    if c == "svm" or (t == "float32" and r in (1, 4))
]


@pytest.mark.parametrize("params", OPTIONS)
def test_every_option_predicts_valid_places_and_reports_planned_bytes(route, params) -> None:
    model = BTELocalizer(progress=False, random_state=0, max_regions=10, **params).fit(route.map)
    N, d = route.map.shape
    pred = model.predict(route.queries)
    assert pred.dtype == np.int64 and pred.shape == (N,)
    assert np.all((pred >= 0) & (pred < N))
    margins = model.decision_function(route.queries)
    assert margins.shape == (N, n_bits_for(N)) and margins.dtype == np.float32
    breakdown = model.storage_breakdown()
    assert model.nbytes == sum(breakdown.values())
    assert model.nbytes == planned_bytes(int(sum(model.region_sizes_)), d, n_selected=model.n_selected_,
                                         region_sizes=list(model.region_sizes_),
                                         scheme=params["scheme"], dtype=params["dtype"])
    assert model.hyperplanes_.weights.dtype == np.dtype(params["dtype"])
    assert model.hyperplanes_.bias.dtype == np.float32
    if model.n_regions_ > 1:
        assert {"region_weights", "region_bias", "region_starts"} <= set(breakdown)
        assert len(model.region_hyperplanes_) == (1 if model.n_regions_ == 2 else model.n_regions_)
    else:
        assert not any(k.startswith("region") for k in breakdown)
    # On its own training data (the map) every option must beat chance at tolerance 5 (11/N).
    assert np.mean(np.abs(model.predict(route.map) - np.arange(N)) <= 5) > 11 / N


@pytest.mark.parametrize(
    ("params", "expected"),
    [({}, 6), ({"feature_ratio": 0.5}, 32), ({"feature_ratio": 1.0}, 64), ({"n_features": 5}, 5),
     ({"n_features": 500}, 64), ({"n_features": 5, "feature_ratio": 0.9}, 5), ({"feature_ratio": 0.001}, 1)],
)
def test_number_of_kept_columns(route, params, expected: int) -> None:
    model = BTELocalizer(progress=False, **params).fit(route.map)
    assert model.n_selected_ == expected
    assert model.hyperplanes_.weights.shape == (n_bits_for(200), expected)
    if expected == 64:
        assert model.hyperplanes_.columns is None and "columns" not in model.storage_breakdown()
    else:
        cols = model.hyperplanes_.columns
        assert cols.dtype == np.uint16 and cols.shape == (n_bits_for(200), expected)
        assert np.all(np.diff(cols.astype(int), axis=1) > 0)  # each classifier's columns sorted, distinct


def test_compressed_storage_is_b_classifiers(route) -> None:
    model = BTELocalizer(n_features=10, progress=False).fit(route.map)
    b = compressed_n_classifiers(200)
    assert b == 8 == len(model.hyperplanes_)
    # b × (10 float32 weights + 10 uint16 indices + 1 float32 bias)
    assert model.storage_breakdown() == {"weights": b * 10 * 4, "bias": b * 4, "columns": b * 10 * 2}


def test_compressed_tasks_label_the_bits_msb_first() -> None:
    places = np.array([0, 1, 2, 3, 4, 4])
    tasks = compressed_tasks(places, 5)
    assert len(tasks) == 3
    np.testing.assert_array_equal(np.stack([t.labels for t in tasks], axis=1), encode(places, 3))


@pytest.mark.parametrize("decode", ["constrained", "soft"])
def test_predictions_are_the_decoded_margins(route, decode: str) -> None:
    model = BTELocalizer(decode=decode, progress=False).fit(route.map)
    margins = model.decision_function(route.queries)
    decoder = decode_soft if decode == "soft" else decode_constrained
    np.testing.assert_array_equal(model.predict(route.queries), decoder(margins, 200))


def test_places_argument_with_several_traverses(route) -> None:
    X = np.vstack(route.traverses)
    places = np.tile(np.arange(200), 2)
    model = BTELocalizer(n_regions=3, progress=False, random_state=0).fit(X, places)
    assert model.n_places_ == 200
    pred = model.predict(route.queries)
    assert np.all((pred >= 0) & (pred < 200))
    # Places given explicitly in order equal the default (row i = place i).
    a = BTELocalizer(progress=False, random_state=0).fit(route.map, np.arange(200))
    b = BTELocalizer(progress=False, random_state=0).fit(route.map)
    np.testing.assert_array_equal(a.hyperplanes_.weights, b.hyperplanes_.weights)


def test_fit_is_deterministic_and_parallelism_does_not_change_the_model(route) -> None:
    # Holds for converged fits (as here). liblinear's dual solver draws from C's process-global
    # rand(), so fits stopped at max_iter can differ between runs with threads (n_jobs > 1).
    one = BTELocalizer(n_regions=3, n_jobs=1, random_state=0, progress=False).fit(route.map)
    two = BTELocalizer(n_regions=3, n_jobs=2, random_state=0, progress=False).fit(route.map)
    for name, array in one._stored_arrays().items():
        np.testing.assert_array_equal(array, two._stored_arrays()[name], err_msg=name)


def test_memory_mapped_map(route, tmp_path) -> None:
    path = tmp_path / "map.f32"
    mm = np.memmap(path, dtype=np.float32, mode="w+", shape=route.map.shape)
    mm[:] = route.map
    mm.flush()
    ro = np.memmap(path, dtype=np.float32, mode="r", shape=route.map.shape)
    a = BTELocalizer(progress=False, random_state=0).fit(ro)
    b = BTELocalizer(progress=False, random_state=0).fit(route.map)
    np.testing.assert_array_equal(a.predict(route.queries), b.predict(route.queries))


@pytest.mark.parametrize("solver", ["newton", "lbfgs", "liblinear"])
def test_unconverged_fits_are_counted_and_warned_once(route, solver: str) -> None:
    # max_iter = 1 stops (almost) every fit at its first iteration. The count must not depend on
    # the number of threads, and fit reports it in one ConvergenceWarning from the caller's thread.
    counts = []
    for n_jobs in (1, 2):
        with pytest.warns(ConvergenceWarning) as caught:
            model = BTELocalizer(max_iter=1, n_regions=3, n_jobs=n_jobs, solver=solver, progress=False,
                                 random_state=0).fit(route.map)
        assert len([w for w in caught if issubclass(w.category, ConvergenceWarning)]) == 1
        assert f"{model.n_unconverged_} of {len(model.hyperplanes_) + len(model.region_hyperplanes_)}" \
            in str(caught[0].message)
        counts.append(model.n_unconverged_)
    assert counts[0] == counts[1] >= len(model.hyperplanes_) // 2
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        assert BTELocalizer(n_jobs=2, solver="newton", progress=False, random_state=0).fit(route.map).n_unconverged_ == 0


# ----------------------------------------------------------------------------- learnable → exact
@pytest.mark.slow
def test_where_the_problem_is_learnable_the_method_is_exact() -> None:
    # N = 1024 ≤ d = 2048: every bit labelling is linearly separable; queries = map + 5 % noise.
    route = synthetic_route(1024, 2048, n_traverses=1, seed=0)
    Q = noisy_copy(route.map, 0.05, seed=1)
    model = BTELocalizer(n_regions=1, feature_ratio=1, progress=False, n_jobs=2, random_state=0).fit(route.map)
    exact = np.mean(model.predict(Q) == np.arange(1024))
    print(f"BTE-C exact on learnable synthetic route (N=1024, d=2048): {exact:.4f}")
    assert exact >= 0.95


def test_learnable_small_problem_is_exact_for_every_scheme() -> None:
    route = synthetic_route(100, 256, n_traverses=1, seed=2)
    Q = noisy_copy(route.map, 0.05, seed=3)
    for params in ({"scheme": "compressed"}, {"scheme": "full"}, {"decode": "soft"}, {"n_regions": 3}):
        model = BTELocalizer(feature_ratio=1, progress=False, random_state=0, **params).fit(route.map)
        assert np.mean(model.predict(Q) == np.arange(100)) >= 0.95, params


# ----------------------------------------------------------------------------- storage vs N
def test_compressed_bytes_grow_with_log_n_full_bytes_with_n() -> None:
    sizes = [1024, 4096, 16384, 65536]
    fitted = {}
    for n in sizes:
        X = synthetic_route(n, 64, n_traverses=1, seed=n).map
        model = BTELocalizer(n_features=16, progress=False, n_jobs=2, random_state=0).fit(X)
        assert model.nbytes == planned_bytes(n, 64, n_selected=16)
        fitted[n] = model.nbytes
    full = {n: planned_bytes(n, 64, n_selected=16, scheme="full") for n in sizes}
    print("BTE-C bytes:", fitted, " BTE-F planned bytes:", full)
    assert fitted[1024] < fitted[4096] < fitted[16384] < fitted[65536]
    assert fitted[65536] / fitted[1024] <= 1.7  # log: 16 bits / 10 bits = 1.6
    assert full[65536] / full[1024] >= 0.9 * 64  # linear: ×64 places


# ----------------------------------------------------------------------------- budgets
# Budgets log-uniform over 50 B … 50 KB, so both outcomes (fits / too small) come up for both schemes.
budgets = st.floats(np.log10(50), np.log10(50_000)).map(lambda e: int(round(10**e)))


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(4, 300),
    d=st.integers(4, 64),
    budget=budgets,
    scheme=st.sampled_from(["compressed", "full"]),
    dtype=st.sampled_from(["float32", "float16"]),
    n_regions=st.sampled_from([1, 2, "auto"]),
    seed=st.integers(0, 10_000),
)
def test_reported_bytes_never_exceed_the_budget(n, d, budget, scheme, dtype, n_regions, seed) -> None:
    X = np.random.default_rng(seed).standard_normal((n, d)).astype(np.float32)
    model = BTELocalizer(budget=budget, scheme=scheme, dtype=dtype, n_regions=n_regions, max_regions=10,
                         max_iter=200, progress=False, random_state=0)
    try:
        model.fit(X)
    except BudgetTooSmallError as err:
        event("budget too small")
        assert err.budget == budget and err.minimum > budget
        assert f"needs {err.minimum} B" in str(err)
        return
    event(f"fits ({scheme}, r = {'auto' if n_regions == 'auto' else model.n_regions_})")
    sizes = list(model.region_sizes_)
    assert model.nbytes <= budget
    assert planned_bytes(int(sum(sizes)), d, n_selected=model.n_selected_, region_sizes=sizes, scheme=scheme,
                         dtype=dtype) == model.nbytes
    # The largest d' that fits: one more column would not.
    if model.n_selected_ < d:
        assert planned_bytes(int(sum(sizes)), d, n_selected=model.n_selected_ + 1, region_sizes=sizes,
                             scheme=scheme, dtype=dtype) > budget


def test_budget_caps_by_feature_ratio(route) -> None:
    model = BTELocalizer(budget="1MB", feature_ratio=0.25, progress=False).fit(route.map)
    assert model.n_selected_ == 16  # the budget would allow all 64; the ratio caps d'
    assert BTELocalizer(budget="1MB", progress=False).fit(route.map).n_selected_ == 64


def test_budget_lowers_automatic_region_count(route) -> None:
    free = BTELocalizer(n_regions="auto", max_regions=10, progress=False, random_state=0).fit(route.map)
    assert free.n_regions_ >= 3
    tight = planned_bytes(200, 64, n_selected=1)  # only r = 1 fits at d' = 1
    model = BTELocalizer(n_regions="auto", max_regions=10, budget=tight, progress=False, random_state=0).fit(route.map)
    assert model.n_regions_ < free.n_regions_ and model.nbytes <= tight


def test_float16_halves_the_weights(route) -> None:
    a = BTELocalizer(n_features=20, progress=False).fit(route.map).storage_breakdown()
    b = BTELocalizer(n_features=20, dtype="float16", progress=False).fit(route.map).storage_breakdown()
    assert b["weights"] * 2 == a["weights"] and b["bias"] == a["bias"] and b["columns"] == a["columns"]


# ----------------------------------------------------------------------------- folded linear classifiers
@pytest.fixture(scope="module")
def offset_data():
    # Columns with large means and very different scales: folding errors would show.
    rng = np.random.default_rng(7)
    n, d = 300, 20
    X = (rng.standard_normal((n, d)) * rng.uniform(0.1, 50, d) + rng.uniform(-100, 100, d)).astype(np.float32)
    z = (X - X.mean(axis=0)) / X.std(axis=0)
    labels = (z[:, 0] + z[:, 3] + rng.standard_normal(n) > 0).astype(int)
    return X, labels


@pytest.mark.parametrize(
    ("classifier", "solver", "sk"),
    [
        ("svm", "liblinear", lambda: LinearSVC(C=1.0, loss="squared_hinge", dual="auto", max_iter=1000, random_state=0)),
        ("logistic", "liblinear",
         lambda: LogisticRegression(C=4.0, solver="liblinear", tol=0.01, max_iter=1000, random_state=0)),
        # Newton's method and L-BFGS stop at a relative gradient of 1e-5: compare with liblinear
        # run to a much tighter tolerance (the same optimum).
        ("svm", "newton", lambda: LinearSVC(C=1.0, dual=False, tol=1e-12, max_iter=100_000, random_state=0)),
        ("svm", "lbfgs", lambda: LinearSVC(C=1.0, dual=False, tol=1e-12, max_iter=100_000, random_state=0)),
        ("logistic", "newton",
         lambda: LogisticRegression(C=4.0, solver="liblinear", tol=1e-12, max_iter=100_000, random_state=0)),
    ],
)
@pytest.mark.parametrize("columns", [np.arange(20), np.array([0, 3, 5, 11, 19])])
def test_folded_hyperplane_equals_sklearn_on_standardised_columns(offset_data, classifier, solver, sk,
                                                                   columns) -> None:
    X, labels = offset_data
    stats = ColumnStats.of(X)
    C = 1.0 if classifier == "svm" else 4.0
    w, b, converged = fit_linear(X, labels, columns, stats, classifier=classifier, C=C, solver=solver,
                                 random_state=0)
    assert converged and w.shape == (1, columns.size) and w.dtype == np.float32 and b.dtype == np.float32
    Xs = (X[:, columns].astype(np.float64) - X[:, columns].mean(axis=0)) / X[:, columns].std(axis=0)
    expected = sk().fit(Xs, labels).decision_function(Xs)
    raw = X[:, columns].astype(np.float64) @ w[0].astype(np.float64) + b[0]
    # float32 weights and bias: agree to float32 precision relative to the margins' size (and,
    # for the gradient-tolerance solvers, to 1e-4 of the margins).
    scale = np.abs(X[:, columns] * w[0]).sum(axis=1).max()
    slack = 0.0 if solver == "liblinear" else 1e-4 * np.abs(expected).max()
    np.testing.assert_allclose(raw, expected, rtol=0, atol=2e-6 * scale + 1e-5 + slack)
    # The stacked form (one BLAS product over the scattered hyperplanes) gives the same margins.
    hp = Hyperplanes.stack([(w, b, columns)], 20, columns.size, np.dtype(np.float32),
                           None if columns.size == 20 else np.dtype(np.uint16))
    np.testing.assert_allclose(hp.margins(X)[:, 0], raw, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(hp.margins_per_row(X, np.zeros(len(X), int)), raw, rtol=1e-5, atol=1e-3)


def test_float16_hyperplane_is_close_and_keeps_the_boundary(offset_data) -> None:
    X, labels = offset_data
    stats = ColumnStats.of(X)
    cols = np.arange(20)
    w32, b32, _ = fit_linear(X, labels, cols, stats, random_state=0)
    w16, b16, _ = fit_linear(X, labels, cols, stats, random_state=0, dtype=np.dtype(np.float16))
    assert w16.dtype == np.float16 and b16.dtype == np.float32
    m32 = X.astype(np.float64) @ w32[0].astype(np.float64) + b32[0]
    m16 = X.astype(np.float64) @ w16[0].astype(np.float64) + b16[0]
    assert np.mean(np.sign(m16) == np.sign(m32)) >= 0.98
    np.testing.assert_allclose(m16, m32, atol=0.02 * np.abs(m32).max())
    # The bias is computed from the stored float16 weights, so at the training mean the margin
    # is the unscaled intercept in both (no shift of Σ (w32 − w16)·μ, large here: μ ~ 100).
    mu = stats.mean
    at_mean16 = float(mu @ w16[0].astype(np.float64) + b16[0])
    at_mean32 = float(mu @ w32[0].astype(np.float64) + b32[0])
    assert at_mean16 == pytest.approx(at_mean32, abs=1e-4)  # float32 bias rounding only


def test_column_stats_of_constant_columns() -> None:
    X = np.column_stack([np.arange(10.0), np.full(10, 3.0)]).astype(np.float32)
    stats = ColumnStats.of(X, chunk_rows=3)
    np.testing.assert_allclose(stats.mean, [4.5, 3.0])
    np.testing.assert_allclose(stats.scale, [np.std(np.arange(10.0)), 1.0])


def test_hyperplanes_margins_match_a_direct_computation() -> None:
    rng = np.random.default_rng(0)
    K, d, d_sel = 5, 30, 7
    cols = np.stack([np.sort(rng.choice(d, d_sel, replace=False)) for _ in range(K)]).astype(np.uint16)
    hp = Hyperplanes(rng.standard_normal((K, d_sel)).astype(np.float32), rng.standard_normal(K).astype(np.float32),
                     cols, d)
    Q = rng.standard_normal((40, d)).astype(np.float32)
    direct = np.stack([Q[:, cols[k]] @ hp.weights[k] + hp.bias[k] for k in range(K)], axis=1)
    np.testing.assert_allclose(hp.margins(Q), direct, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(hp.margins(Q, slice(1, 3)), direct[:, 1:3], rtol=1e-5, atol=1e-5)
    rows = rng.integers(0, K, size=40)
    np.testing.assert_allclose(hp.margins_per_row(Q, rows), direct[np.arange(40), rows], rtol=1e-5, atol=1e-5)
