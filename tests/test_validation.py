"""Input checks: the shared validators and every kind of bad input to BTELocalizer."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from sklearn.exceptions import NotFittedError as SklearnNotFittedError

from btel import BTELocalizer
from btel.core.validation import check_descriptors, check_is_fitted, check_places, check_positive_int
from btel.methods.registry import make_method, method_names
from btel.exceptions import (
    BTELError,
    BudgetTooSmallError,
    DimensionMismatchError,
    InvalidDescriptorsError,
    InvalidParameterError,
    NotEnoughPlacesError,
    NotFittedError,
)


@pytest.fixture(scope="module")
def X() -> np.ndarray:
    return np.random.default_rng(0).standard_normal((40, 12)).astype(np.float32)


@pytest.fixture(scope="module")
def fitted(X) -> BTELocalizer:
    return BTELocalizer(progress=False, random_state=0).fit(X)


# ----------------------------------------------------------------------------- check_descriptors
@pytest.mark.parametrize(
    "value",
    [
        [[1, 2], [3, 4]],
        np.array([[1, 2], [3, 4]], dtype=np.int16),
        np.array([[True, False], [False, True]]),
        np.array([[1.0, 2.0], [3.0, 4.0]], dtype=np.float64),
        np.asfortranarray(np.ones((2, 2))),
    ],
)
def test_check_descriptors_accepts_numbers(value) -> None:
    out = check_descriptors(value)
    assert out.dtype == np.float32 and out.flags.c_contiguous and out.shape == (2, 2)
    np.testing.assert_array_equal(out, np.asarray(value, dtype=np.float32))


def test_check_descriptors_does_not_copy_float32() -> None:
    X = np.ones((3, 2), dtype=np.float32)
    assert np.shares_memory(check_descriptors(X), X)
    assert check_descriptors(X, dtype=np.float64).dtype == np.float64


@pytest.mark.parametrize(
    ("value", "error", "message"),
    [
        (np.array([[1.0, np.nan]]), InvalidDescriptorsError, r"NaN or infinite values \(first at row 0, column 1\)"),
        (np.array([[1.0, 2.0], [np.inf, 0.0]]), InvalidDescriptorsError, r"first at row 1, column 0"),
        (np.array([[1.0, 2.0], [0.0, -np.inf]]), InvalidDescriptorsError, "NaN or infinite"),
        (np.array([1.0, 2.0, 3.0]), InvalidDescriptorsError, r"must be 2-D .*Use X.reshape\(1, -1\)"),
        (np.zeros((2, 2, 2)), InvalidDescriptorsError, r"must be 2-D .*got shape \(2, 2, 2\)"),
        (np.float32(3.0), InvalidDescriptorsError, "must be 2-D"),
        (np.zeros((0, 4)), InvalidDescriptorsError, r"shape \(0, 4\); it needs at least 1 row"),
        (np.zeros((3, 0)), InvalidDescriptorsError, "one column"),
        ([], InvalidDescriptorsError, "must be 2-D"),
        ([["a", "b"], ["c", "d"]], InvalidDescriptorsError, "descriptors must be numbers"),
        (np.array([[1, "x"]], dtype=object), InvalidDescriptorsError, "has dtype object"),
        (np.ones((2, 2), dtype=complex), InvalidDescriptorsError, "is complex"),
        (np.ones((2, 2), dtype="m8[s]"), InvalidDescriptorsError, "must be numbers"),  # numpy: a number
        ([[1.0, 2.0], [3.0]], InvalidDescriptorsError, "could not be read as a numeric array"),
        (sp.csr_matrix(np.eye(3)), InvalidDescriptorsError, r"sparse matrix.*toarray\(\)"),
        (None, InvalidDescriptorsError, "descriptors must be numbers"),
    ],
)
def test_check_descriptors_rejects(value, error, message: str) -> None:
    with pytest.raises(error, match=message):
        check_descriptors(value)


def test_check_descriptors_dimension_and_rows() -> None:
    with pytest.raises(DimensionMismatchError, match="Q has 3 features but the model was fitted on 4"):
        check_descriptors(np.ones((2, 3)), name="Q", n_features=4)
    with pytest.raises(InvalidDescriptorsError, match="at least 5 row"):
        check_descriptors(np.ones((4, 3)), min_rows=5)


# ----------------------------------------------------------------------------- check_places
def test_check_places_valid() -> None:
    places, n = check_places([2, 0, 1, 1, 0, 2], 6)
    assert n == 3 and places.dtype == np.int64
    places, n = check_places(np.array([0.0, 1.0, 1.0]), 3)  # whole floats are fine
    assert n == 2 and places.tolist() == [0, 1, 1]


@pytest.mark.parametrize(
    ("places", "n_rows", "error", "message"),
    [
        ([0, 1, 3], 3, InvalidParameterError, r"cover every index 0..3; 1 are missing \(first: 2\)"),
        ([1, 2, 3], 3, InvalidParameterError, r"missing \(first: 0\)"),
        ([0, -1, 1], 3, InvalidParameterError, "non-negative"),
        ([0, 1.5, 2], 3, InvalidParameterError, "whole numbers"),
        ([0, np.nan, 1], 3, InvalidParameterError, "whole numbers"),
        (["a", "b"], 2, InvalidParameterError, "integer place indices"),
        ([0, 1], 3, InvalidParameterError, r"one label per descriptor row \(3\)"),
        ([[0, 1]], 2, InvalidParameterError, "must be 1-D"),
        ([0, 0, 0], 3, NotEnoughPlacesError, "N = 1 place"),
    ],
)
def test_check_places_rejects(places, n_rows: int, error, message: str) -> None:
    with pytest.raises(error, match=message):
        check_places(places, n_rows)


# ----------------------------------------------------------------------------- small helpers
@pytest.mark.parametrize("value", [1, 7, np.int64(3), np.uint8(2)])
def test_check_positive_int_accepts(value) -> None:
    assert check_positive_int(value, "k") == int(value)


@pytest.mark.parametrize("value", [0, -3, 2.0, 2.5, True, "3", None])
def test_check_positive_int_rejects(value) -> None:
    with pytest.raises(InvalidParameterError, match=r"k must be an integer ≥ 1"):
        check_positive_int(value, "k")


def test_check_positive_int_minimum() -> None:
    assert check_positive_int(0, "k", minimum=0) == 0
    with pytest.raises(InvalidParameterError, match="≥ 2"):
        check_positive_int(1, "k", minimum=2)


def test_check_is_fitted() -> None:
    class Thing:
        pass

    thing = Thing()
    with pytest.raises(NotFittedError, match="This Thing is not fitted yet"):
        check_is_fitted(thing, "n_places_")
    thing.n_places_ = 3
    check_is_fitted(thing, "n_places_")


def test_every_error_is_a_btel_error_and_a_builtin() -> None:
    assert issubclass(InvalidDescriptorsError, (BTELError, ValueError))
    assert issubclass(BudgetTooSmallError, ValueError)
    assert issubclass(NotFittedError, SklearnNotFittedError)


# ----------------------------------------------------------------------------- BTELocalizer: data
def _with(X: np.ndarray, row: int, col: int, value: float) -> np.ndarray:
    X = X.copy()
    X[row, col] = value
    return X


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_fit_rejects_non_finite_map(X, value) -> None:
    with pytest.raises(InvalidDescriptorsError, match=r"X contains NaN or infinite values \(first at row 5, column 3\)"):
        BTELocalizer(progress=False).fit(_with(X, 5, 3, value))


@pytest.mark.parametrize("method", ["predict", "decision_function", "predict_region"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_predict_rejects_non_finite_queries(fitted, X, method: str, value) -> None:
    with pytest.raises(InvalidDescriptorsError, match=r"Q contains NaN or infinite values \(first at row 2, column 0\)"):
        getattr(fitted, method)(_with(X, 2, 0, value))


@pytest.mark.parametrize("method", ["predict", "decision_function", "predict_region"])
def test_query_dimension_must_match_the_map(fitted, X, method: str) -> None:
    with pytest.raises(DimensionMismatchError, match="Q has 11 features but the model was fitted on 12"):
        getattr(fitted, method)(X[:, :11])
    with pytest.raises(DimensionMismatchError, match="Q has 13 features"):
        getattr(fitted, method)(np.hstack([X, X[:, :1]]))


@pytest.mark.parametrize(
    ("data", "error", "message"),
    [
        (np.ones((1, 5)), NotEnoughPlacesError, r"N = 1 place\): an index needs at least 2 places"),
        (np.zeros((0, 5)), InvalidDescriptorsError, r"shape \(0, 5\)"),
        (np.zeros((5, 0)), InvalidDescriptorsError, "one column"),
        (np.ones(5), InvalidDescriptorsError, r"X must be 2-D .*reshape"),
        (np.ones((4, 3, 2)), InvalidDescriptorsError, r"X must be 2-D .*\(4, 3, 2\)"),
        ([["a", "b"], ["c", "d"]], InvalidDescriptorsError, "X has dtype <U1; descriptors must be numbers"),
        (np.array([[1.0, "b"], [2.0, 3.0]], dtype=object), InvalidDescriptorsError, "X has dtype object"),
    ],
)
def test_fit_rejects_bad_maps(data, error, message: str) -> None:
    with pytest.raises(error, match=message):
        BTELocalizer(progress=False).fit(data)


@pytest.mark.parametrize(
    ("query", "message"),
    [
        (np.ones(12), r"Q must be 2-D .*reshape\(1, -1\)"),
        (np.ones((2, 12, 1)), "Q must be 2-D"),
        (np.zeros((0, 12)), r"shape \(0, 12\)"),
        ([["x"] * 12], "descriptors must be numbers"),
    ],
)
def test_predict_rejects_bad_queries(fitted, query, message: str) -> None:
    with pytest.raises(InvalidDescriptorsError, match=message):
        fitted.predict(query)


def test_single_query_row_works(fitted, X) -> None:
    assert fitted.predict(X[:1]).shape == (1,)
    assert fitted.predict(X[0].reshape(1, -1).tolist())[0] == fitted.predict(X[:1])[0]


@pytest.mark.parametrize(
    ("places", "error", "message"),
    [
        (np.r_[np.arange(20), np.arange(21, 41)], InvalidParameterError, r"missing \(first: 20\)"),
        (np.arange(39), InvalidParameterError, r"one label per descriptor row \(40\)"),
        (np.zeros(40, dtype=int), NotEnoughPlacesError, "at least 2 places"),
        (np.full(40, 0.5), InvalidParameterError, "whole numbers"),
    ],
)
def test_fit_rejects_bad_places(X, places, error, message: str) -> None:
    with pytest.raises(error, match=message):
        BTELocalizer(progress=False).fit(X, places)


# ----------------------------------------------------------------------------- BTELocalizer: state
@pytest.mark.parametrize("method", ["predict", "decision_function", "predict_region", "storage_breakdown", "save"])
def test_use_before_fit(X, method: str, tmp_path) -> None:
    model = BTELocalizer()
    call = getattr(model, method)
    args = (tmp_path / "m.npz",) if method == "save" else () if method == "storage_breakdown" else (X,)
    with pytest.raises(NotFittedError, match="BTELocalizer is not fitted yet. Call fit"):
        call(*args)
    with pytest.raises(SklearnNotFittedError):
        call(*args)


def test_nbytes_before_fit() -> None:
    with pytest.raises(NotFittedError, match="not fitted yet"):
        BTELocalizer().nbytes


# ----------------------------------------------------------------------------- BTELocalizer: parameters
@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"scheme": "partial"}, r"scheme must be 'compressed' or 'full'; got 'partial'"),
        ({"classifier": "forest"}, r"classifier must be 'svm' or 'logistic'"),
        ({"decode": "hard"}, r"decode must be 'constrained' or 'soft'"),
        ({"scheme": "full", "decode": "soft"}, "decode='soft' needs every bit margin: use it with scheme='compressed'"),
        ({"dtype": "float64"}, r"dtype must be 'float32' or 'float16'; got 'float64'"),
        ({"dtype": "int8"}, "dtype must be 'float32' or 'float16'"),
        ({"dtype": "not-a-dtype"}, "dtype must be 'float32' or 'float16'"),
        ({"dtype": 3.5}, "dtype must be 'float32' or 'float16'"),
        ({"feature_ratio": 0}, r"feature_ratio must be None or a number > 0 and ≤ 1; got 0"),
        ({"feature_ratio": 1.5}, r"feature_ratio must be None or a number > 0 and ≤ 1; got 1.5"),
        ({"feature_ratio": -0.1}, "feature_ratio must be None or a number > 0"),
        ({"feature_ratio": "0.5"}, "feature_ratio must be None or a number > 0"),
        ({"n_features": 0}, "n_features must be None or an integer ≥ 1"),
        ({"n_features": 2.5}, "n_features must be None or an integer ≥ 1"),
        ({"n_regions": 0}, r"n_regions must be 'auto' or an integer ≥ 1; got 0"),
        ({"n_regions": "many"}, r"n_regions must be 'auto' or an integer ≥ 1"),
        ({"n_regions": 2.5}, r"n_regions must be 'auto' or an integer ≥ 1"),
        ({"C": 0}, "C must be None or a number > 0"),
        ({"C": -1.0}, "C must be None or a number > 0"),
        ({"C": "big"}, "C must be None or a number > 0"),
        # C = 1e308 wrote an all-zero model (overflow) and 1e100 never ended under liblinear: C ≤ 1e10.
        ({"C": 1e308}, r"C must be None or a number > 0 and ≤ 1e\+10"),
        ({"sparsity": 0}, "sparsity must be a number > 0"),
        ({"sparsity": None}, "sparsity must be a number > 0"),
        ({"max_regions": 0}, "max_regions must be an integer"),
        ({"max_iter": 0}, "max_iter must be None or an integer"),
        ({"solver": "sgd"}, "solver must be one of"),
        ({"budget": "lots"}, "budget 'lots' is not understood"),
        ({"budget": -5}, "budget must be a positive number of bytes"),
    ],
)
def test_invalid_parameters_are_rejected_by_fit_not_init(X, params, message: str) -> None:
    model = BTELocalizer(progress=False, **params)  # __init__ never validates (sklearn contract)
    assert all(model.get_params()[k] is v for k, v in params.items())
    with pytest.raises(InvalidParameterError, match=message):
        model.fit(X)


@pytest.mark.parametrize("scheme", ["compressed", "full"])
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_budget_too_small_names_the_minimum(X, scheme: str, dtype: str) -> None:
    with pytest.raises(BudgetTooSmallError, match=r"the smallest model \(d' = 1\) needs \d+ B") as info:
        BTELocalizer(budget=10, scheme=scheme, dtype=dtype, progress=False).fit(X)
    err = info.value
    assert err.budget == 10 and err.minimum > 10
    assert f"needs {err.minimum} B" in str(err)
    # The minimum is honest: a budget of exactly that many bytes fits, one byte less does not.
    model = BTELocalizer(budget=err.minimum, scheme=scheme, dtype=dtype, progress=False).fit(X)
    assert model.n_selected_ == 1 and model.nbytes == err.minimum
    with pytest.raises(BudgetTooSmallError):
        BTELocalizer(budget=err.minimum - 1, scheme=scheme, dtype=dtype, progress=False).fit(X)


# The finiteness screen sums rows with BLAS and only falls back to the exact element check when a
# sum is not finite; these cases pin both branches.
def test_huge_finite_values_are_not_mistaken_for_inf() -> None:
    X = np.full((6, 8), 3e38, dtype=np.float32)  # every row sum overflows float32
    assert check_descriptors(X) is X


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("shape,where", [((5, 3), (4, 2)), ((3000, 2048), (2999, 0)), ((3000, 2048), (1500, 7))])
def test_first_non_finite_value_is_located(bad: float, shape: tuple[int, int], where: tuple[int, int]) -> None:
    X = np.zeros(shape, dtype=np.float32)
    X[where] = bad
    with pytest.raises(InvalidDescriptorsError, match=f"row {where[0]}, column {where[1]}"):
        check_descriptors(X)


def test_opposite_infinities_in_one_row_are_caught() -> None:
    X = np.ones((4, 4), dtype=np.float32)
    X[2, 0], X[2, 3] = np.inf, -np.inf
    with pytest.raises(InvalidDescriptorsError, match="row 2, column 0"):
        check_descriptors(X)


# ----------------------------------------------------------------------------- past float32, all rows alike
def test_a_float64_value_past_float32s_range_is_named_without_a_warning(X) -> None:
    data = X.astype(np.float64)
    data[7, 2] = -3e300
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "overflow encountered in cast" before the error
        with pytest.raises(InvalidDescriptorsError, match=r"X row 7, column 2 is -3e\+300, outside float32's range"):
            check_descriptors(data)
        with pytest.raises(InvalidDescriptorsError, match="scale the descriptors down"):
            BTELocalizer(progress=False).fit(data)


def test_queries_past_float32s_range_are_named(fitted, X) -> None:
    Q = X[:3].astype(np.float64)
    Q[1, 4] = 1e39
    with pytest.raises(InvalidDescriptorsError, match=r"Q row 1, column 4 is 1e\+39, outside float32's range"):
        fitted.predict(Q)
    Q[1, 4] = np.inf  # a value that was not finite before the cast keeps its own message
    with pytest.raises(InvalidDescriptorsError, match=r"Q contains NaN or infinite values \(first at row 1, column 4\)"):
        fitted.predict(Q)


@pytest.mark.parametrize("method", method_names())
def test_every_method_refuses_a_map_whose_rows_are_all_the_same(method: str) -> None:
    with pytest.raises(InvalidDescriptorsError, match="all 60 rows of X are the same descriptor"):
        make_method(method).fit(np.tile(np.arange(8, dtype=np.float32), (60, 1)))


def test_a_map_underflowing_to_zero_is_named_and_one_distinct_row_is_enough(X) -> None:
    with pytest.raises(InvalidDescriptorsError, match=r"every value of X is zero in float32: .*largest \|v\| 3e-300.*scale the descriptors up"):
        BTELocalizer(progress=False).fit(np.full((30, 6), 3e-300))
    same = np.zeros((50, 6), dtype=np.float32)
    same[-1, 0] = 1.0  # only the last row differs: the check reads the whole map before refusing
    assert make_method("bruteforce").fit(same).n_places_ == 50


def test_real_map_scaled_past_float32_is_named(gardenspoint_netvlad) -> None:
    db, _ = gardenspoint_netvlad
    with pytest.raises(InvalidDescriptorsError, match="outside float32's range"):
        make_method("auto", budget="16KB").fit(db.astype(np.float64) * 1e300)
    with pytest.raises(InvalidDescriptorsError, match="every value of X is zero in float32"):
        make_method("auto", budget="16KB").fit(db.astype(np.float64) * 1e-300)
    with pytest.raises(InvalidDescriptorsError, match="every value of Q is zero in float32"):
        make_method("bruteforce").fit(db).predict(db.astype(np.float64) * 1e-300)


def test_masked_values_are_refused_not_silently_unmasked() -> None:
    """predict(np.ma.masked_array(...)) answered from the hidden values under the mask."""
    from btel.core.validation import check_descriptors
    from btel.exceptions import InvalidDescriptorsError

    X = np.ma.masked_array(np.ones((3, 4), dtype=np.float32), mask=False)
    assert check_descriptors(X).shape == (3, 4)  # nothing masked: the values are the data
    X.mask[1, 2] = True
    with pytest.raises(InvalidDescriptorsError, match="X has masked values; fill them"):
        check_descriptors(X)
