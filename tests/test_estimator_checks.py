"""scikit-learn's estimator checks on every registered method, each expected failure with its reason."""

from __future__ import annotations

import warnings

import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from btel.methods import METHODS, make_method

#: Every method fails these by design or by wording only.
BY_DESIGN = {
    # The second argument of fit is a place index, named ``places`` (not an arbitrary y).
    "check_fit_score_takes_y": "fit(X, places): the target is a place index, deliberately not called y",
    # places must cover 0..N−1 (a route), so sklearn's arbitrary labels are rejected.
    "check_estimators_dtypes": "places must cover 0..N−1; the check's labels leave gaps",
    "check_fit2d_1feature": "places must cover 0..N−1; the check's labels leave gaps",
    # Descriptors must be numeric arrays; object arrays are refused rather than cast.
    "check_dtype_object": "object-dtype descriptors are refused with InvalidDescriptorsError",
    # Error *wording* only: btel raises the right ValueError subclass with its own message.
    "check_n_features_in_after_fitting": "DimensionMismatchError says 'Q has k features but the model was fitted on d'",
    "check_complex_data": "InvalidDescriptorsError says 'X is complex', not sklearn's wording",
    "check_estimators_empty_data_messages": "InvalidDescriptorsError names the shape, not sklearn's wording",
    "check_fit2d_1sample": "one row raises NotEnoughPlacesError ('N = 1 place'), not sklearn's wording",
    "check_fit2d_predict1d": "1-D queries get 'Q must be 2-D ... reshape(1, -1)', not 'Reshape your data'",
}

#: The checks fit on 2–30 rows of 2–4 columns, below what some methods need by construction.
TOO_SMALL = ["check_estimators_overwrite_params", "check_dont_overwrite_parameters",
             "check_estimators_fit_returns_self", "check_readonly_memmap_input", "check_positive_only_tag_during_fit",
             "check_pipeline_consistency", "check_estimators_nan_inf", "check_estimators_pickle",
             "check_f_contiguous_array_estimator", "check_methods_sample_order_invariance",
             "check_methods_subset_invariance", "check_dict_unchanged", "check_fit_idempotent",
             "check_fit_check_is_fitted", "check_n_features_in", "check_n_features_in_after_fitting"]

EXTRA: dict[str, dict[str, str]] = {
    "btel-r": {c: "20 regions need at least 40 places; the check's maps have 2–30 rows" for c in TOO_SMALL},
    "ryth": {c: "K = 3 co-prime periods (2, 3, 5) need N ≥ 5 places in every residue class; the check's maps "
                "have 2–3" for c in TOO_SMALL},
    "itq": {c: "8-bit codes need d ≥ 8 and 8 rows; the check's descriptors have 2–4 columns" for c in TOO_SMALL},
    "seqslam": {
        "check_methods_sample_order_invariance": "SeqSLAM answers a query from the queries before it (a sequence "
                                                 "method): reordering the queries changes the answers",
        "check_methods_subset_invariance": "SeqSLAM answers a query from the queries before it (a sequence method)",
    },
}


def _estimators():
    out = []
    for name in METHODS:
        est = make_method(name)
        params = est.get_params()
        if "progress" in params:
            est.set_params(progress=False)
        if "random_state" in params:
            est.set_params(random_state=0)
        est._registry_name = name  # noqa: SLF001 - identifies the method for its expected failures
        out.append(est)
    return out


def _expected(estimator) -> dict[str, str]:
    name = getattr(estimator, "_registry_name", None)
    if name is None:  # a clone made by a check: find the registry entry by its parameters
        name = next(n for n in METHODS if make_method(n).get_params(deep=False).keys() == estimator.get_params(
            deep=False).keys() and all(estimator.get_params(deep=False)[k] == v for k, v in
                                       make_method(n).get_params(deep=False).items()
                                       if k in ("scheme", "n_regions")))
    return {**BY_DESIGN, **EXTRA.get(name, {})}


# The methods take scikit-learn's contract from btel.core.params.ParamsMixin, not from BaseEstimator (whose
# import a loaded model would pay: docs/decisions/startup.md); every check below holds. scikit-learn warns
# that they do not inherit from BaseEstimator, once per estimator while the checks are collected.
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", category=UserWarning,
                            message="Estimator .* does not inherit from `sklearn.base.BaseEstimator`")
    _CHECKS = parametrize_with_checks(_estimators(), expected_failed_checks=_expected)


@pytest.mark.slow
@_CHECKS
def test_sklearn_estimator_checks(estimator, check) -> None:
    check(estimator)


def test_every_registered_method_is_checked() -> None:
    assert {e._registry_name for e in _estimators()} == set(METHODS)
