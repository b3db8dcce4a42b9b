"""``AutoLocalizer``: the method :mod:`btel.methods.auto.rule` chooses, fitted and answered behind the one interface."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ...core.validation import N_JOBS, RANDOM_STATE, check_is_fitted, check_params
from ..base import ArraySpec, PlaceLocalizer
from ...exceptions import BudgetTooSmallError, ModelFileError
from ...core.storage import budget_of, format_bytes
from .rule import choose_method

__all__ = ["AutoLocalizer"]


class AutoLocalizer(PlaceLocalizer):
    """The method chosen from the map and budget alone (module docstring), behind the one interface.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"64KB"``); the chosen method fills it.
    normalize, delta
        Given to the chosen method's front end.
    whiten : None, int or 'shrink'
        None: the rule chooses (``'shrink'`` or none); anything else is given to the chosen method.
    random_state : int or None
        Seed of the chosen method.
    n_jobs : int, optional
        Threads of the chosen method, where it takes them (not saved).

    Attributes
    ----------
    model_ : PlaceLocalizer
        The fitted chosen method.
    choice_ : dict
        ``method``, ``params``, ``reason`` and the map statistics (``route_share``, ``bytes_per_place``…).
    front_end_ : FrontEnd
        The chosen method's front end.
    n_places_, n_features_in_ : int
    fit_time_ : float
    """

    _parameter_constraints = {"random_state": RANDOM_STATE, "n_jobs": N_JOBS}
    _runtime_params = ("n_jobs",)
    #: The method registry (:mod:`btel.methods` sets it when it registers this class; this module
    #: does not import the registry, which imports it).
    _registry: Any = None

    def __init__(self, *, budget: int | str | None = None, random_state: int | None = 0, n_jobs: int | None = None) -> None:
        self.budget = budget
        self.random_state = random_state
        self.n_jobs = n_jobs

    def _inner(self, method: str, params: dict[str, Any]) -> PlaceLocalizer:
        model = self._registry.make_method(method)
        valid = model.get_params(deep=False)
        extra = {"budget": self.budget, "normalize": self.normalize, "delta": self.delta,
                 "random_state": self.random_state, "n_jobs": self.n_jobs, "progress": False}
        model.set_params(**{k: v for k, v in {**extra, **params}.items() if k in valid})
        return model

    def fit(self, X: Any, places: Any = None) -> "AutoLocalizer":
        """Choose by the rule, then fit the chosen method (the first candidate that fits the budget).

        Returns
        -------
        self
        """
        start = time.perf_counter()
        X, labels, n_places = self._check_fit_input(X, places)
        budget = budget_of(self)
        candidates = choose_method(X, labels, n_places, budget, self.whiten)
        refused: list[str] = []
        error: BudgetTooSmallError | None = None
        for choice in candidates:
            model = self._inner(choice["method"], choice["params"])
            try:
                model.fit(X, places)
            except BudgetTooSmallError as exc:
                refused.append(f"{choice['method']} {choice['params']} needs ≥ {exc.minimum} B")
                error = exc if error is None or (exc.minimum or 0) < (error.minimum or 0) else error
                continue
            self.model_ = model
            self.choice_ = {**choice, "params": {k: v for k, v in choice["params"].items() if v is not None},
                            "refused": refused}
            break
        else:  # every candidate raised BudgetTooSmallError
            raise BudgetTooSmallError(
                f"budget {format_bytes(budget or 0)} ({budget} B) is too small for auto: no candidate fits "
                f"({'; '.join(refused)}). Raise the budget to at least {getattr(error, 'minimum', '?')} B.",
                budget=budget, minimum=getattr(error, "minimum", None))
        self.front_end_ = self.model_.front_end_
        self.n_features_in_ = int(X.shape[1])
        self.fit_time_ = time.perf_counter() - start
        self.n_places_ = int(n_places)
        return self

    def check_budget(self, n_rows: int, n_features: int, budget: int | None,
                     reserved: int | None = None) -> None:
        """Raise what ``fit`` would raise for this map shape and budget, without fitting.

        Every candidate list of the rule ends with plain ``lsh`` and ``btel-codes`` (the others need
        more bytes), so auto fits exactly when one of those two does; the minimum is the smaller one.
        """
        errors: list[BudgetTooSmallError] = []
        for method, params in (("lsh", {"whiten": self.whiten}), ("btel-codes", {"code": "periodic",
                                                                               "whiten": self.whiten})):
            try:
                self._inner(method, params).check_budget(n_rows, n_features, budget)
                return
            except BudgetTooSmallError as exc:
                errors.append(exc)
        smallest = min(errors, key=lambda e: e.minimum or 0)
        raise BudgetTooSmallError(f"budget {format_bytes(budget or 0)} ({budget} B) is too small for auto: neither "
                                  f"lsh nor btel-codes fits ({'; '.join(str(e) for e in errors)}).",
                                  budget=budget, minimum=smallest.minimum)

    def choice(self) -> dict[str, Any]:
        """What the rule chose: ``{"method", "params", "reason", "refused"}`` (a copy of ``choice_``)."""
        check_is_fitted(self, "choice_")
        return {k: (dict(v) if isinstance(v, dict) else list(v) if isinstance(v, list) else v)
                for k, v in self.choice_.items()}

    def summary(self) -> str:
        """One line: what the rule chose and why."""
        c = self.choice_
        params = ", ".join(f"{k}={v}" for k, v in c["params"].items())
        inner = self.model_.summary()
        return (f"auto chose {c['method']}{f' ({params})' if params else ''}: {c['reason']}"
                + (f" — {inner}" if inner else "") + (f" [refused: {'; '.join(c['refused'])}]" if c["refused"] else ""))

    # -- the one primitive, from the chosen method ------------------------------------------------
    @property
    def uses_query_sequence(self) -> bool:
        model = getattr(self, "model_", None)
        return bool(self.delta) if model is None else model.uses_query_sequence

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        return self.model_._search(Q, k)

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        return self.model_._place_scores(Q)

    def _predict(self, Q: np.ndarray) -> np.ndarray:
        return self.model_._predict(Q)

    def _sequence_context(self) -> int:
        return self.model_._sequence_context()

    def _fit(self, X, places, n_places, budget, reserved) -> None:  # pragma: no cover - fit is overridden
        raise NotImplementedError

    # -- storage and files ------------------------------------------------------------------------
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        return self.model_._stored_arrays()

    def _fitted_state(self) -> dict[str, Any]:
        from ...core.modelfile import jsonable

        params = {k: jsonable(v) for k, v in self.model_.get_params(deep=False).items()
                  if k not in self.model_._runtime_params}
        return {"choice": self.choice_, "inner_params": params, "inner_state": self.model_._fitted_state()}

    def _inner_from_state(self, state: dict[str, Any]) -> PlaceLocalizer:
        registry = self._registry
        choice = state.get("choice")
        if not isinstance(choice, dict) or choice.get("method") not in registry.method_names() \
                or choice.get("method") == "auto":
            raise ModelFileError("the auto model file does not name a registered method it chose.")
        params, inner_state = state.get("inner_params"), state.get("inner_state")
        if not isinstance(params, dict) or not isinstance(inner_state, dict):
            raise ModelFileError("the auto model file's inner parameters or state are not objects.")
        factory = registry._factory(choice["method"])  # imports the chosen method's module alone
        cls = factory.func if hasattr(factory, "func") else factory
        model = cls(**registry._params_from_file(cls, params))
        check_params(model)
        model.front_end_ = self.front_end_
        return model

    def _merged_state(self, state: dict[str, Any]) -> dict[str, Any]:
        return {**state["inner_state"], "n_places": state["n_places"], "n_features_in": state["n_features_in"]}

    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        self._loading = self._inner_from_state(state)
        return self._loading._array_specs(self._merged_state(state))

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        model = getattr(self, "_loading", None) or self._inner_from_state(state)
        self.__dict__.pop("_loading", None)
        model._restore(arrays, self._merged_state(state))
        model.n_features_in_ = int(state["n_features_in"])
        model.fit_time_ = float("nan")
        setattr(model, model._fitted_marker, int(state["n_places"]))
        self.model_ = model
        self.choice_ = state["choice"]
        self.choice_.setdefault("refused", [])
        self.choice_.setdefault("params", {})
        self.choice_.setdefault("reason", "")
