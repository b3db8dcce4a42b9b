"""btel.core.params.ParamsMixin behaves as scikit-learn's BaseEstimator on every registered method."""

from __future__ import annotations

import pickle

import pytest
from sklearn.base import BaseEstimator, clone
from sklearn.model_selection import ParameterGrid
from sklearn.utils import get_tags

from btel.core.params import ParamsMixin
from btel.exceptions import InvalidParameterError
from btel.methods import make_method, method_names


@pytest.mark.parametrize("name", method_names())
def test_params_repr_and_clone_match_sklearn(name: str) -> None:
    model = make_method(name)
    assert not isinstance(model, BaseEstimator)  # the decision: scikit-learn's contract, not its import
    assert model.get_params(deep=True) == BaseEstimator.get_params(model, deep=True)
    changed = {"random_state": 3} if "random_state" in model.get_params() else {"normalize": "none"}
    model.set_params(**changed)
    assert repr(model) == BaseEstimator.__repr__(model)  # scikit-learn's changed-parameters-only style
    twin = clone(model)
    assert type(twin) is type(model) and twin is not model
    assert twin.get_params(deep=False) == model.get_params(deep=False)
    assert get_tags(model).requires_fit


def test_repr_of_defaults_is_bare() -> None:
    assert repr(make_method("lsh")) == "LSHLocalizer()"
    assert repr(make_method("lsh", budget="4KB")) == "LSHLocalizer(budget='4KB')"


def test_nested_parameters_and_bad_names() -> None:
    from btel.methods.baselines import OPQLocalizer, PQLocalizer

    opq = OPQLocalizer(pq=PQLocalizer(nbits=4))
    params = opq.get_params(deep=True)
    assert params["pq__nbits"] == 4 and params["pq"] is opq.pq
    opq.set_params(pq__nbits=8, n_iter=3)
    assert opq.pq.nbits == 8 and opq.n_iter == 3
    assert opq.set_params() is opq
    with pytest.raises(InvalidParameterError, match="invalid parameter 'nbit' for OPQLocalizer; valid"):
        opq.set_params(nbit=4)
    with pytest.raises(ValueError, match="invalid parameter 'nbit' for PQLocalizer"):
        opq.set_params(pq__nbit=4)


def test_grid_search_style_cloning_and_pickle() -> None:
    base = make_method("lsh", budget="1KB")
    grid = ParameterGrid({"random_state": [0, 1], "budget": ["1KB", "2KB"]})
    models = [clone(base).set_params(**p) for p in grid]
    assert {(m.random_state, m.budget) for m in models} == {(0, "1KB"), (0, "2KB"), (1, "1KB"), (1, "2KB")}
    assert base.budget == "1KB" and base.random_state == 0
    restored = pickle.loads(pickle.dumps(base))
    assert restored.get_params() == base.get_params()


def test_varargs_init_is_refused() -> None:
    class Bad(ParamsMixin):
        def __init__(self, *values: int) -> None:
            self.values = values

    with pytest.raises(TypeError, match=r"takes \*values"):
        Bad(1).get_params()


def test_a_plain_class_has_no_parameters() -> None:
    class Plain(ParamsMixin):
        pass

    assert Plain().get_params() == {} and repr(Plain()) == "Plain()"


def test_unpickling_drops_sklearn_version() -> None:
    model = make_method("bruteforce")
    model.__setstate__({**model.__getstate__(), "_sklearn_version": "1.5"})
    assert not hasattr(model, "_sklearn_version")
