"""The linear solvers (btel.learning.solvers, btel.learning.primal): same optimum as liblinear run to convergence, shared work, honest stops."""

from __future__ import annotations

import warnings
import zlib

import numpy as np
import pytest
from sklearn.exceptions import ConvergenceWarning
from sklearn.linear_model import LogisticRegression
from sklearn.svm import LinearSVC

from btel import BTELocalizer
from btel.datasets import synthetic_route
from btel.exceptions import InvalidParameterError
from btel.learning.feature_selection import between_cluster_ss, between_cluster_ss_binary, select_features, select_features_many
from btel.learning.solvers import choose_solver, linear_objective, solve_linear
from btel.learning.primal import _solve_submatrices  # noqa: PLC2701 - the shared-inverse path, checked directly
from btel.methods.ryth import RYTHLocalizer


def _reference(X, y, w, classifier):
    """The lower objective of liblinear's dual and primal solvers, run to a far tighter tolerance."""
    values = []
    for dual in (True, False):
        if classifier == "svm":
            model = LinearSVC(C=1.0, dual=dual, tol=1e-12, max_iter=200_000, random_state=0)
        else:
            model = LogisticRegression(C=1.0, solver="liblinear", dual=dual, tol=1e-12, max_iter=200_000,
                                       random_state=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            model.fit(X, y, sample_weight=w)
        values.append(linear_objective(X, y, model.coef_, model.intercept_, C=1.0, classifier=classifier,
                                       sample_weight=w)[0])
    return min(values)


@pytest.mark.parametrize("classifier", ["svm", "logistic"])
@pytest.mark.parametrize("shape", [(240, 30), (50, 120)])  # primal form (rows > d' + 1) and kernel form
@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("solver", ["newton", "lbfgs"])
def test_solvers_reach_liblinears_converged_objective(classifier, shape, weighted, solver) -> None:
    # A fixed seed per case (str hashes change with PYTHONHASHSEED from one process to the next).
    rng = np.random.default_rng(zlib.crc32(repr((classifier, shape, weighted)).encode()))
    n, d = shape
    X = rng.standard_normal((n, d))
    labels = (rng.random((n, 3)) < 0.4).astype(int)
    labels[:, 0] = X[:, 0] + 0.5 * rng.standard_normal(n) > 0  # one learnable, two random labellings
    weights = rng.uniform(0.5, 3.0, (n, 3)) if weighted else None
    solution = solve_linear(X, labels, C=1.0, classifier=classifier, solver=solver, sample_weight=weights)
    assert solution.converged.all() and solution.solver == solver
    for k in range(3):
        best = _reference(X, labels[:, k], None if weights is None else weights[:, k], classifier)
        # Within the solvers' stopping rule (relative gradient 1e-5) of the converged reference, and not
        # far below it (same problem).
        assert best * (1 - 1e-4) <= solution.objective[k] <= best * (1 + 2e-5) + 1e-7


def test_shared_inverse_solve_equals_the_direct_solve() -> None:
    # (R_AA)⁻¹ r through R⁻¹ and the complement (|A| > n/2) against a direct factorisation.
    rng = np.random.default_rng(3)
    X = rng.standard_normal((60, 80))
    gram = X @ X.T + 1.0
    R = gram + 0.5 * np.eye(60)
    inverse = np.linalg.inv(R)
    masks = rng.random((60, 4)) < np.array([0.2, 0.5, 0.8, 1.0])
    rhs = rng.standard_normal((60, 4))
    got = _solve_submatrices(gram, inverse, masks, 0.5, rhs)
    for k in range(4):
        rows = np.flatnonzero(masks[:, k])
        expected = np.zeros(60)
        expected[rows] = np.linalg.solve(R[np.ix_(rows, rows)], rhs[rows, k])
        np.testing.assert_allclose(got[:, k], expected, rtol=1e-8, atol=1e-10)


def test_one_pass_feature_selection_equals_per_task_selection() -> None:
    rng = np.random.default_rng(5)
    X = rng.standard_normal((400, 50)).astype(np.float32)
    scale = rng.uniform(0.5, 2.0, 50)
    labels = [(rng.random(400) < p).astype(int) for p in (0.1, 0.5, 0.9)] + [rng.integers(0, 5, 400)]
    many = select_features_many(X, labels, 7, scale=scale)
    assert all(np.array_equal(a, select_features(X, y, 7, scale=scale)) for a, y in zip(many, labels))
    binary = between_cluster_ss_binary(X, np.stack(labels[:3], axis=1), scale=scale)
    expected = np.stack([between_cluster_ss(X, y, scale=scale) for y in labels[:3]])
    np.testing.assert_allclose(binary, expected, rtol=1e-10, atol=1e-9)


def test_auto_picks_newton_for_small_systems_and_lbfgs_beyond() -> None:
    assert choose_solver("auto", 3576, 3780) == "newton"  # kernel form, 3576 unknowns
    assert choose_solver("auto", 1_000_000, 64) == "newton"  # primal form, 65 unknowns
    assert choose_solver("auto", 8192, 4096) == "lbfgs"
    assert choose_solver("liblinear", 10, 10) == "liblinear"
    with pytest.raises(InvalidParameterError, match="solver must be one of"):
        choose_solver("sgd", 10, 10)


@pytest.fixture(scope="module")
def route():
    return synthetic_route(400, 96, n_traverses=2, seed=4)


def test_newton_fit_is_converged_identical_on_refit_and_no_worse_than_liblinear(route) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)  # a converged fit does not warn
        a = BTELocalizer(feature_ratio=1.0, solver="newton", progress=False).fit(route.map)
        b = BTELocalizer(feature_ratio=1.0, solver="newton", n_jobs=2, progress=False).fit(route.map)
    assert a.n_unconverged_ == 0 and a.fit_summary_.solvers == ("newton",)
    np.testing.assert_array_equal(a.hyperplanes_.weights, b.hyperplanes_.weights)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        lib = BTELocalizer(feature_ratio=1.0, solver="liblinear", progress=False).fit(route.map)
    assert a.fit_summary_.objective <= lib.fit_summary_.objective * (1 + 1e-6)


def test_ryth_solves_each_period_together_and_counts_stops(route) -> None:
    model = RYTHLocalizer(feature_ratio=0.5).fit(route.map)
    assert model.n_unconverged_ == 0 and model.fit_summary_.n_classifiers == len(model.hyperplanes_)
    with pytest.warns(ConvergenceWarning, match=r"RYTHLocalizer\.fit: \d+ of \d+ classifiers stopped"):
        stopped = RYTHLocalizer(feature_ratio=0.5, max_iter=1).fit(route.map)
    assert stopped.n_unconverged_ > 0


def test_experiment_cache_reuses_a_model_its_budget_did_not_shape(route, tmp_path) -> None:
    from btel.experiments._common import ModelCache

    cache = ModelCache(tmp_path, min_fit_seconds=0.0)
    X = route.map
    big, _, cached = cache.fit("btel-c", {"budget": 2_000_000, "feature_ratio": 0.5}, X)
    assert not cached and big.n_selected_ == 48  # capped by c = 0.5, not by 2 MB
    same, _, cached = cache.fit("btel-c", {"budget": 1_000_000, "feature_ratio": 0.5}, X)
    assert cached and same is big  # 1 MB gives the same model
    small, _, cached = cache.fit("btel-c", {"budget": 1_000, "feature_ratio": 0.5}, X)
    assert not cached and small.n_selected_ < 48  # a budget that does shape the model is fitted
    fresh = ModelCache(tmp_path, min_fit_seconds=0.0)  # another process: from disk
    again, _, cached = fresh.fit("btel-c", {"budget": 500_000, "feature_ratio": 0.5}, X)
    assert cached and np.array_equal(again.hyperplanes_.weights, big.hyperplanes_.weights)


def test_the_convergence_warning_suggests_newton_only_when_another_solver_stalled(route) -> None:
    """With solver newton it said 'Raise max_iter or use solver='newton''."""
    X = route.map
    with pytest.warns(ConvergenceWarning) as caught:
        BTELocalizer(budget="8KB", max_iter=1, solver="newton", progress=False).fit(X)
    message = str(caught[0].message)
    assert message.endswith("Raise max_iter.") and "use solver='newton'" not in message
