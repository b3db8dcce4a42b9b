"""``AutoLocalizer``: the method :mod:`btel.methods.auto.rule` chooses (or
:mod:`~btel.methods.auto.calibrate`, given labelled queries), fitted and answered behind the one interface."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ...core.validation import BOOLEAN, N_JOBS, RANDOM_STATE, Interval, check_is_fitted, check_params
from ..base import ArraySpec, PlaceLocalizer
from ...exceptions import BudgetTooSmallError, ModelFileError, NotEnoughPlacesError
from ...core.storage import budget_of, exact_bytes, parse_budget
from .rule import choose_method, reason_terms

__all__ = ["AutoLocalizer", "calibration_table"]


#: What the calibration table's columns say (printed under it by ``summary()``, ``btel info``, ``btel train``).
CALIBRATION_COLUMNS = (
    "  score: share of the calibration queries each candidate gets right (mean over its seeds); diff: its score\n"
    "  minus the map-only pick's, paired on the same queries; W/L: queries it gets right more often than the pick /\n"
    "  less often (over the seeds); p (adj.): one-sided p-value of 'beats the pick', adjusted over every candidate\n"
    "  (max-T); conf.: 1 − p (a switch needs {need:g}); n for {ref:g} / n for diff: calibration queries that would\n"
    "  certify a lead of {ref:g} / of the observed diff (power 0.8; blank for a candidate behind the pick, or one that\n"
    "  disagrees with it on too few queries to hold such a lead); fit s: its fits' seconds; µs/q: its mean answer\n"
    "  time per calibration query on the compared map rows (speed to weigh beside accuracy; not used to choose).")


def _verdict(c: dict[str, Any], rows: list[dict[str, Any]]) -> str:
    """Why the chosen row was chosen, in one sentence."""
    alpha = c.get("alpha", 0.05)
    chosen = next((e for e in rows if e.get("candidate") == c.get("chosen")), {})
    if c.get("switched"):
        return (f"chosen: {c.get('chosen')}, ahead of the map-only pick {c.get('map_only')} by "
                f"{chosen.get('difference', 0):+.3f} beyond noise (adjusted p {chosen.get('p_adjusted', 0):.3f} "
                f"< α = {alpha:g}, confidence {chosen.get('confidence', 0):.2f}).")
    ahead = [e for e in rows if e.get("status") == "ok" and (e.get("difference") or 0) > 0]
    if not ahead:
        return f"chosen: the map-only pick {c.get('map_only')}; no candidate scored higher."
    best = max(ahead, key=lambda e: e.get("confidence", 0))
    n = best.get("queries_needed_observed")
    return (f"chosen: the map-only pick {c.get('map_only')}; the most likely better candidate, {best['candidate']} "
            f"({best['difference']:+.3f}), reaches confidence {best.get('confidence', 0):.2f}, short of "
            f"{1 - alpha:g}" + (f" (about {n} queries would certify a lead that size)." if n else "."))


def calibration_table(calibration: dict[str, Any] | None) -> str:
    """The calibration table as aligned text lines, the verdict and what each column means ('' without one)."""
    if not isinstance(calibration, dict) or not isinstance(calibration.get("table"), list):
        return ""
    c = calibration
    rows = [e for e in c["table"] if isinstance(e, dict)]
    correct = c.get("correct_when") or f"within {c.get('tolerance')} places of the true place"
    head = (f"calibration: {c.get('n_queries')} labelled queries, correct when {correct}; seeds {c.get('seeds')}; "
            f"{c.get('rows_compared')} map rows compared; map-only pick {c.get('map_only')}, chosen {c.get('chosen')}")
    ref = c.get("reference_difference", 0.05)
    reference = "n for " + format(ref, "g")
    lines = [head, f"  {'candidate':<28} {'score':>6} {'diff':>7} {'W/L':>7} {'p (adj.)':>8} {'conf.':>6} "
                   f"{reference:>10} {'n for diff':>10} {'fit s':>6} {'µs/q':>7}  note"]
    for e in rows:
        if e.get("status") != "ok":
            lines.append(f"  {str(e.get('candidate')):<28} {'—':>6} {'':>7} {'':>7} {'':>8} {'':>6} {'':>10} {'':>10} "
                         f"{'':>6} {'':>7}  {e.get('status')}" + (f", needs ≥ {e['needs']}" if e.get("needs") else ""))
            continue
        diff = "" if "difference" not in e else f"{e['difference']:+.3f}"
        wl = "" if "wins" not in e else f"{e['wins']}/{e.get('losses')}"
        p = "" if "p_adjusted" not in e else f"{e['p_adjusted']:.3f}"
        conf = "" if "confidence" not in e else f"{e['confidence']:.2f}"
        need = "" if e.get("queries_needed") is None or (e.get("difference") or 0) < 0 else str(e["queries_needed"])
        need_obs = ("" if e.get("queries_needed_observed") is None or (e.get("difference") or 0) <= 0
                    else str(e["queries_needed_observed"]))
        fit_s = "" if e.get("fit_s") is None else f"{e['fit_s']:.1f}"
        query_us = "" if e.get("query_us") is None else f"{e['query_us']:.1f}"  # absent in files before btel timed it
        role = e.get("role", "")
        role = "map-only pick, kept" if role == "chosen" and e.get("candidate") == c.get("map_only") else role
        lines.append(f"  {str(e.get('candidate')):<28} {e.get('score', float('nan')):>6.3f} {diff:>7} {wl:>7} {p:>8} "
                     f"{conf:>6} {need:>10} {need_obs:>10} {fit_s:>6} {query_us:>7}  {role}".rstrip())
    lines.append("  " + _verdict(c, rows))
    lines.append(CALIBRATION_COLUMNS.format(need=1 - c.get("alpha", 0.05), ref=ref))
    return "\n".join(lines)


def _finite(value: Any) -> bool:
    """A finite JSON number (booleans excluded)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(value))


def check_saved_choice(choice: dict[str, Any]) -> None:
    """Check the fields of a saved ``state.choice`` that ``summary()`` and the calibration table read.

    ``params`` must be an object, ``reason`` a string, ``refused`` a list of strings (each may be
    absent); ``calibration`` absent, null or an object whose ``alpha`` (in (0, 1)) and
    ``reference_difference`` are finite numbers where present, and whose ``table`` is a list of
    objects with finite ``score``, ``difference``, ``p_adjusted``, ``confidence`` (and ``fit_s``,
    ``query_us`` or null) where present.

    Raises
    ------
    ModelFileError
        A field has the wrong type; the message names it (a damaged or hand-edited model file).
    """
    def bad(name: str, what: str) -> ModelFileError:
        return ModelFileError(f"the auto model file's state.choice.{name} must be {what}; the file is damaged "
                              "(train the model again with `btel train`).")

    for name, kind, what in (("params", dict, "an object"), ("reason", str, "a string"), ("refused", list, "a list")):
        if name in choice and not isinstance(choice[name], kind):
            raise bad(name, what)
    if not all(isinstance(r, str) for r in choice.get("refused", [])):
        raise bad("refused", "a list of strings")
    c = choice.get("calibration")
    if c is None:
        return
    if not isinstance(c, dict):
        raise bad("calibration", "an object or null")
    if "alpha" in c and not (_finite(c["alpha"]) and 0 < c["alpha"] < 1):
        raise bad("calibration.alpha", "a number in (0, 1)")
    if "reference_difference" in c and not _finite(c["reference_difference"]):
        raise bad("calibration.reference_difference", "a finite number")
    table = c.get("table", [])
    if not isinstance(table, list) or not all(isinstance(e, dict) for e in table):
        raise bad("calibration.table", "a list of objects")
    for i, e in enumerate(table):
        for key in ("score", "difference", "p_adjusted", "confidence", "fit_s", "query_us"):
            if key in e and not (_finite(e[key]) or (key in ("fit_s", "query_us") and e[key] is None)):
                raise bad(f"calibration.table[{i}].{key}", "a finite number")


def _params_text(params: dict[str, Any]) -> str:
    """``(code=periodic, whiten=shrink)`` ('' without parameters)."""
    shown = ", ".join(f"{k}={v}" for k, v in params.items() if v is not None)
    return f"({shown})" if shown else ""


class AutoLocalizer(PlaceLocalizer):
    """The method chosen from the map and budget (or from labelled queries), behind the one interface.

    Parameters
    ----------
    budget : int or str, optional
        Bytes (or ``"64KB"``); the chosen method fills it.
    calibration_tolerance : int
        With ``fit(X, calibration=(Q, truth))`` and true places as ints: a calibration query is
        correct when the prediction lies within this many places of its truth.
    normalize, delta
        Given to the chosen method's front end.
    whiten : None, int or 'shrink'
        None: the rule chooses (``'shrink'`` or none); anything else is given to the chosen method.
    random_state : int or None
        Seed of the chosen method.
    n_jobs : int, optional
        Threads of the chosen method, where it takes them (not saved).
    progress : bool
        A progress bar over the candidates' fits during a calibrated fit (on a terminal only; not saved).

    Attributes
    ----------
    model_ : PlaceLocalizer
        The fitted chosen method.
    choice_ : dict
        ``method``, ``params``, ``reason`` and the map statistics (``route_share``, ``bytes_per_place``…);
        after a calibrated fit also ``calibration``: the table of every candidate (score, paired
        difference against the map-only pick, p-values, confidence, queries needed), no query.
    front_end_ : FrontEnd
        The chosen method's front end.
    n_places_, n_features_in_ : int
    fit_time_ : float
    """

    label = "auto"
    #: ``progress`` draws bars only for a calibrated fit (a command line shows the time elapsed otherwise).
    _bars_only_when_calibrating = True
    _parameter_constraints = {"calibration_tolerance": [Interval(int, 0, None)],
                              "random_state": RANDOM_STATE, "n_jobs": N_JOBS, "progress": BOOLEAN}
    _runtime_params = ("n_jobs", "progress")
    #: The method registry (:mod:`btel.methods` sets it when it registers this class; this module
    #: does not import the registry, which imports it).
    _registry: Any = None

    def __init__(self, *, budget: int | str | None = None, calibration_tolerance: int = 0,
                 random_state: int | None = 0, n_jobs: int | None = None, progress: bool = True) -> None:
        self.budget = budget
        self.calibration_tolerance = calibration_tolerance
        self.random_state = random_state
        self.n_jobs = n_jobs
        self.progress = progress

    def _inner(self, method: str, params: dict[str, Any], budget: Any = "same") -> PlaceLocalizer:
        model = self._registry.make_method(method)
        valid = model.get_params(deep=False)
        extra = {"budget": self.budget if budget == "same" else budget, "normalize": self.normalize,
                 "delta": self.delta, "random_state": self.random_state, "n_jobs": self.n_jobs,
                 "progress": False}
        model.set_params(**{k: v for k, v in {**extra, **params}.items() if k in valid})
        return model

    def fit(self, X: Any, places: Any = None, calibration: Any = None) -> "AutoLocalizer":
        """Choose by the rule (or by calibration), then fit the chosen method on the whole map.

        Parameters
        ----------
        X : array-like of shape (n_rows, n_features)
        places : array-like of shape (n_rows,), int, optional
        calibration : (Q, truth), optional
            Labelled queries: Q (n_queries, n_features), truth an int array (n_queries,) of true
            places or a :class:`~btel.datasets.GroundTruth`. Scored and dropped, never stored
            (:mod:`btel.methods.auto.calibrate`).

        Returns
        -------
        self
        """
        start = time.perf_counter()
        X, labels, n_places = self._check_fit_input(X, places)
        budget = budget_of(self)
        if calibration is not None:  # checked before any work
            from .calibrate import check_calibration

            calibration = check_calibration(calibration, X.shape[1], n_places, self.calibration_tolerance)
            self.check_budget(X.shape[0], X.shape[1], budget)  # no candidate scored when none can be kept
        candidates = choose_method(X, labels, n_places, budget, self.whiten)
        if calibration is not None:
            candidates = self._calibrated(X, labels, budget, *calibration, candidates)
        refused: list[str] = []
        error: BudgetTooSmallError | None = None
        for choice in candidates:
            model = self._inner(choice["method"], choice["params"])
            try:
                model.fit(X, places)
            except BudgetTooSmallError as exc:
                said = f"{choice['method']} {_params_text(choice['params'])} needs ≥ {exc.minimum} B"
                refused += [] if said in refused else [said]
                error = exc if error is None or (exc.minimum or 0) < (error.minimum or 0) else error
                continue
            except NotEnoughPlacesError as exc:  # e.g. PQ's codebooks on a map of a few rows
                refused.append(f"{choice['method']} {_params_text(choice['params'])}: {exc}")
                continue
            self.model_ = model
            self.choice_ = {**choice, "params": {k: v for k, v in choice["params"].items() if v is not None},
                            "refused": refused}
            break
        else:  # every candidate raised BudgetTooSmallError
            raise BudgetTooSmallError(
                f"budget {exact_bytes(budget or 0)} is too small for auto: no candidate fits "
                f"({'; '.join(refused)}). Raise the budget to at least {getattr(error, 'minimum', '?')} B.",
                budget=budget, minimum=getattr(error, "minimum", None))
        self.front_end_ = self.model_.front_end_
        self.n_features_in_ = int(X.shape[1])
        self.fit_time_ = time.perf_counter() - start
        self.n_places_ = int(n_places)
        return self

    def _calibrated(self, X: np.ndarray, labels: np.ndarray | None, budget: int | None, Q: np.ndarray,
                    truth: Any, candidates: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The calibrated choice first, then the rule's candidates (the fallbacks)."""
        from .calibrate import choose_calibrated

        first = candidates[0]
        for choice in candidates:  # the map-only pick: the first candidate that fits
            try:
                self._inner(choice["method"], choice["params"]).check_budget(X.shape[0], X.shape[1], budget)
                first = choice
                break
            except (BudgetTooSmallError, NotEnoughPlacesError):
                continue
        picked = choose_calibrated(X, labels, budget, Q, truth, int(self.calibration_tolerance), first,
                                   lambda m, p, b: self._inner(m, p, b), self.whiten, bool(self.progress))
        c = picked["calibration"]
        why = (f"calibrated on {c['n_queries']} labelled queries: {picked['label']} "
               + (f"beats the map-only pick {c['map_only']} beyond noise" if c["switched"]
                  else f"(the map-only pick: no candidate better beyond noise at α = {c['alpha']})"))
        stats = {k: v for k, v in first.items() if k not in ("method", "params", "reason")}
        return [{**stats, "method": picked["method"], "params": picked["params"], "reason": why,
                 "calibration": c}] + candidates

    def check_budget(self, n_rows: int, n_features: int, budget: int | None,
                     reserved: int | None = None) -> None:
        """Raise what ``fit`` would raise for this map shape and budget, without fitting.

        Every candidate list of the rule ends with plain ``lsh`` and ``btel-codes`` (the others need
        more bytes), so auto fits exactly when one of those two does; the minimum is the smaller one.
        """
        budget = parse_budget(budget)
        errors: list[BudgetTooSmallError] = []
        for method, params in (("lsh", {"whiten": self.whiten, "center": False}),
                               ("btel-codes", {"code": "periodic", "whiten": self.whiten})):
            try:
                self._inner(method, params).check_budget(n_rows, n_features, budget)
                return
            except BudgetTooSmallError as exc:
                errors.append(exc)
        smallest = min(errors, key=lambda e: e.minimum or 0)
        raise BudgetTooSmallError(f"budget {exact_bytes(budget or 0)} is too small for auto: neither "
                                  f"lsh nor btel-codes fits ({'; '.join(str(e).rstrip('.') for e in errors)}). "
                                  f"Raise the budget to at least {smallest.minimum} B.",
                                  budget=budget, minimum=smallest.minimum)

    def choice(self) -> dict[str, Any]:
        """What the rule chose: ``{"method", "params", "reason", "refused"}`` (a copy of ``choice_``)."""
        check_is_fitted(self, "choice_")
        return {k: (dict(v) if isinstance(v, dict) else list(v) if isinstance(v, list) else v)
                for k, v in self.choice_.items()}

    def summary(self) -> str:
        """What the rule chose and why (one line), a line defining the reason's figures, and the
        calibration table when there is one."""
        c = self.choice_
        params = ", ".join(f"{k}={v}" for k, v in c["params"].items())
        inner = self.model_.summary()
        line = (f"auto chose {c['method']}{f' ({params})' if params else ''}: {c['reason']}"
                + (f" — {inner}" if inner else "") + (f" [refused: {'; '.join(c['refused'])}]" if c["refused"] else ""))
        return "\n".join(part for part in (line, reason_terms(c["reason"]), calibration_table(c.get("calibration")))
                         if part)

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
        check_saved_choice(choice)  # summary(), `btel info` and the tables read these fields later
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
