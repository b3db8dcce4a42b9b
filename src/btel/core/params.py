"""The parameter half of scikit-learn's estimator contract, without importing scikit-learn.

``get_params``, ``set_params`` and ``repr`` behave as ``sklearn.base.BaseEstimator``'s: the
parameters are the arguments of ``__init__`` (read from its signature), stored under their own
names, nested estimators' as ``outer__inner``. That is all :func:`sklearn.base.clone`, grid search
and ``check_estimator`` need from a base class. scikit-learn itself (about a second to import) is
imported only for its tags (``__sklearn_tags__``), which only scikit-learn's own functions ask for:
loading a model and answering queries never imports it.
"""

from __future__ import annotations

import inspect
from typing import Any

from ..exceptions import InvalidParameterError

__all__ = ["ParamsMixin", "chosen_at_fit"]


class ParamsMixin:
    """``get_params`` / ``set_params`` / ``repr`` of a scikit-learn estimator (module docstring)."""

    @classmethod
    def _get_param_names(cls) -> list[str]:
        """The parameter names of ``__init__``, sorted (no ``*args``: every parameter has a name)."""
        init = cls.__init__
        if init is object.__init__:
            return []
        names = []
        for p in inspect.signature(init).parameters.values():
            if p.kind == p.VAR_POSITIONAL:
                raise TypeError(f"{cls.__name__}.__init__ takes *{p.name}: an estimator's parameters are "
                                "named (scikit-learn's convention).")
            if p.name != "self" and p.kind != p.VAR_KEYWORD:
                names.append(p.name)
        return sorted(names)

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Parameter name → value; with ``deep``, a nested estimator's too, as ``name__parameter``."""
        out: dict[str, Any] = {}
        for key in self._get_param_names():
            value = getattr(self, key)
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update((f"{key}__{k}", v) for k, v in value.get_params().items())
            out[key] = value
        return out

    def set_params(self, **params: Any) -> "ParamsMixin":
        """Set parameters (``name__parameter`` reaches a nested estimator's); returns self.

        Raises
        ------
        InvalidParameterError
            A name this estimator does not take (a ``ValueError``, as scikit-learn raises).
        """
        if not params:
            return self
        valid = self.get_params(deep=True)
        nested: dict[str, dict[str, Any]] = {}
        for key, value in params.items():
            key, delim, sub_key = key.partition("__")
            if key not in valid:
                raise InvalidParameterError(f"invalid parameter {key!r} for {type(self).__name__}; valid "
                                            f"parameters are: {', '.join(self._get_param_names())}.")
            if delim:
                nested.setdefault(key, {})[sub_key] = value
            else:
                setattr(self, key, value)
                valid[key] = value
        for key, sub_params in nested.items():
            if valid[key] is None and key in self._nested_defaults:  # None stands for the default estimator
                setattr(self, key, self._nested_defaults[key]())
                valid[key] = getattr(self, key)
            if not hasattr(valid[key], "set_params"):
                raise InvalidParameterError(f"{type(self).__name__}'s {key} is {valid[key]!r}, which has no "
                                            f"parameters to set; give {key}=<an estimator> instead.")
            valid[key].set_params(**sub_params)
        return self

    #: Parameter → the estimator class that its None stands for (``opq``'s ``pq``): ``pq__nbits`` reaches it.
    _nested_defaults: dict[str, Any] = {}

    def _nested_param_names(self) -> set[str]:
        """``name__parameter`` of every nested estimator, those a None parameter stands for included."""
        names = set(self.get_params(deep=True))
        for key, factory in self._nested_defaults.items():
            if getattr(self, key) is None:
                names |= {f"{key}__{sub}" for sub in factory().get_params(deep=True)}
        return names

    def __repr__(self) -> str:
        """``Class(param=value, …)``: the parameters that differ from their defaults (as scikit-learn)."""
        defaults = {name: p.default for name, p in inspect.signature(type(self).__init__).parameters.items()}
        changed = [f"{k}={v!r}" for k, v in self.get_params(deep=False).items()
                   if k not in defaults or repr(v) != repr(defaults[k])]
        return f"{type(self).__name__}({', '.join(changed)})"

    def __getstate__(self) -> dict[str, Any]:
        """The attributes, as a copy (subclasses drop what does not pickle, e.g. a faiss index)."""
        return dict(self.__dict__)

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        state.pop("_sklearn_version", None)  # written by scikit-learn's BaseEstimator (older pickles)
        self.__dict__.update(state)

    def __sklearn_tags__(self) -> Any:
        """scikit-learn's default estimator tags (only scikit-learn asks: it is imported already)."""
        from sklearn.base import BaseEstimator

        return BaseEstimator.__sklearn_tags__(self)


def chosen_at_fit(estimator: Any) -> dict[str, Any]:
    """The parameters left to the fit (given as None or ``"auto"``) → the value the fit chose.

    Read from the fitted model's saved state (``_fitted_state``; a state key named otherwise is mapped
    by the class's ``_STATE_OF_PARAM``, e.g. pq's ``pca_dim`` → ``dim``): pq's ``n_subquantizers``,
    lsh's ``n_bits``, btel-codes' ``code``. A parameter whose choice the state does not hold is left
    out; empty for an estimator that is not fitted or keeps no state. ``btel info`` and the run records
    (``metrics.json``'s ``chosen_at_fit``) both show this.
    """
    fitted_state = getattr(estimator, "_fitted_state", None)
    if not callable(fitted_state) or not callable(getattr(estimator, "get_params", None)):
        return {}
    try:  # a method that did not fit (a row that did not run) has chosen nothing
        state = fitted_state()
    except (AttributeError, NotImplementedError):
        return {}
    named = getattr(estimator, "_STATE_OF_PARAM", {})
    out = {}
    for key, given in estimator.get_params(deep=False).items():
        chosen = state.get(named.get(key, key))
        left_to_fit = given is None or (isinstance(given, str) and given == "auto")
        if left_to_fit and isinstance(chosen, (bool, int, float, str)) and chosen != given:
            out[key] = chosen
    return out
