"""The one result record: what was measured for one method on one map/query pair, or why not.

:class:`EvaluationResult` is what :func:`btel.evaluation.evaluate`, ``btel demo``/``evaluate``
and every experiment produce, what the tables and plots read and what the result files hold. It
has two written forms:

- :meth:`~EvaluationResult.to_dict` / :meth:`~EvaluationResult.from_dict` — a run folder's ``metrics.json`` record;
- :meth:`~EvaluationResult.to_row` / :meth:`~EvaluationResult.from_row` — the flat row of an
  experiment's ``results.json`` / ``results.csv`` (``method``, ``n_places``, ``nbytes``, ``recall@t``,
  ``R@K``, …, and its own cells, e.g. ``direction``, in :attr:`~EvaluationResult.labels`), read back
  into the same cells in the same order, so a results file is reproduced exactly.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..core.modelfile import jsonable
from ..datasets.groundtruth import GroundTruth
from ..exceptions import InvalidParameterError

__all__ = ["EvaluationResult", "STATUS_OK", "STATUS_REFUSED", "STATUS_DOES_NOT_FIT", "STATUS_FAILED",
           "STATUS_NOT_RUN", "ROW_CELLS", "does_not_fit_status"]

#: The status of a row that ran; anything else says why it did not.
STATUS_OK = "ok"
#: Refused before fitting (e.g. a sequence method on queries that are not a route).
STATUS_REFUSED = "refused"
STATUS_DOES_NOT_FIT = "does not fit"
STATUS_FAILED = "failed"
STATUS_NOT_RUN = "not run"


def does_not_fit_status(minimum: int | None) -> str:
    """``"does not fit (needs ≥ 1234 B)"``: an experiment row's status when its budget is too small."""
    return f"{STATUS_DOES_NOT_FIT} (needs ≥ {minimum} B)"

#: Flat row cells (:meth:`EvaluationResult.to_row`) → fields (recall@t, R@K, query_us: see to_row; others: labels).
ROW_CELLS: dict[str, str] = {"method": "name", "n_places": "n_map", "budget": "budget", "status": "status",
                             "nbytes": "nbytes", "minimum_bytes": "minimum_bytes", "fit_s": "fit_time_s",
                             "uses_query_sequence": "uses_query_sequence", "reason": "reason"}
_RECALL_CELL, _RANKED_CELL = re.compile(r"recall@(\d+)$"), re.compile(r"R@(\d+)$")


def _params_of(method: Any) -> dict[str, Any]:
    """The parameters as given (``get_params(deep=False)``, JSON-safe); what the fit chose for those left
    to it is :func:`~btel.core.params.chosen_at_fit`."""
    if getattr(method, "get_params", None) is None:
        return {}
    return {str(k): jsonable(v) for k, v in method.get_params(deep=False).items()}


def _choice_of(method: Any) -> dict[str, Any] | None:
    """A fitted ``auto``'s public ``choice()`` made JSON-safe; None for a method that is what it was named."""
    choice = getattr(method, "choice", None)
    if not callable(choice):
        return None
    try:
        found = choice()
    except (AttributeError, NotImplementedError):  # not fitted, or a method outside btel's base
        return None
    return None if found is None else jsonable(dict(found))


def _storage_of(method: Any) -> tuple[int | None, dict[str, int] | None]:
    """(nbytes, breakdown) of a fitted method, None where the method does not report them."""
    breakdown = None
    if callable(getattr(method, "storage_breakdown", None)):
        try:
            breakdown = {str(k): int(v) for k, v in method.storage_breakdown().items()}
        except NotImplementedError:
            breakdown = None
    try:
        nbytes = getattr(method, "nbytes", None)
    except NotImplementedError:
        nbytes = None
    if nbytes is None and breakdown is not None:
        nbytes = sum(breakdown.values())
    return (None if nbytes is None else int(nbytes)), breakdown


#: Fields of a ``metrics.json`` row by kind, checked by :func:`_check_row` (a resumed run's file may be edited).
_INTS = ("n_map", "nbytes", "budget", "minimum_bytes", "n_threads", "timing_repeats", "tolerance_for_k")
_FLOATS = ("fit_time_s", "query_time_s_per_query", "rank_time_s_per_query", "query_latency_s",
           "auc_pr_vpr_bench", "auc_pr_vpr_tutorial", "recall_at_100_precision")
_TEXTS = ("reason", "chosen_method", "series", "ground_truth_source", "positive_rule")
_FLAGS = ("reference", "uses_query_sequence", "budget_saturated")
_OBJECTS = ("params", "chosen_at_fit", "storage_breakdown", "settings", "choice")


def _number(value: Any, integer: bool = False) -> bool:
    """A finite JSON number (an int64-sized int when ``integer``); booleans are not numbers here."""
    if isinstance(value, int) and not isinstance(value, bool):
        return abs(value) < 2 ** 63
    return not integer and isinstance(value, float) and bool(np.isfinite(value))


def _numbers(value: Any) -> bool:
    return isinstance(value, list) and all(_number(v) for v in value)


def _check_row(data: Mapping[str, Any]) -> None:
    """Raise ValueError naming the first field of a ``metrics.json`` row whose type or shape is wrong.

    Ints are non-negative ints, floats finite numbers, texts strings, flags booleans and objects dicts
    (each also null); ``recall``/``recall_at_k`` map integer keys to finite numbers, ``recall_curve``
    is a list of finite numbers and ``pr_curve`` null or ``{"precision": [...], "recall": [...]}``.
    """
    def bad(name: str, what: str) -> ValueError:
        return ValueError(f"field {name!r} must be {what}, not {data.get(name)!r:.60}")

    if not isinstance(data, Mapping):
        raise ValueError(f"a row must be an object, not {type(data).__name__}")
    if not isinstance(data.get("name"), str) or not isinstance(data.get("status"), str):
        raise bad("name" if not isinstance(data.get("name"), str) else "status", "a string")
    if not (_number(data.get("n_queries"), True) and data["n_queries"] >= 0):
        raise bad("n_queries", "a non-negative integer")
    for name in _INTS:
        if data.get(name) is not None and not (_number(data[name], True) and data[name] >= 0):
            raise bad(name, "a non-negative integer or null")
    for name, ok, what in [*((n, lambda v: _number(v), "a finite number or null") for n in _FLOATS),
                           *((n, lambda v: isinstance(v, str), "a string or null") for n in _TEXTS),
                           *((n, lambda v: isinstance(v, bool), "true, false or null") for n in _FLAGS),
                           *((n, lambda v: isinstance(v, dict), "an object or null") for n in _OBJECTS),
                           ("recall_curve", _numbers, "a list of finite numbers or null")]:
        if data.get(name) is not None and not ok(data[name]):
            raise bad(name, what)
    for name in ("recall", "recall_at_k"):
        value = data.get(name)
        if value is not None and not (isinstance(value, dict) and all(
                isinstance(k, (str, int)) and str(k).isdigit() and _number(v) for k, v in value.items())):
            raise bad(name, "an object of integer keys to finite numbers, or null")
    curve = data.get("pr_curve")
    if curve is not None and not (isinstance(curve, dict) and all(_numbers(curve.get(k)) for k in ("precision", "recall"))):
        raise bad("pr_curve", 'null or {"precision": [numbers], "recall": [numbers]}')
    if not all(_number(v, True) for v in (data.get("storage_breakdown") or {}).values()):
        raise bad("storage_breakdown", "an object of part names to integers")


@dataclass
class EvaluationResult:
    """Everything measured for one method on one map/query pair — or why it was not measured.

    Attributes
    ----------
    name : str
        Method name (used in tables, legends and file names).
    params : dict
        ``get_params(deep=False)`` made JSON-safe, as given (empty when the method has none).
    chosen_at_fit : dict or None
        The parameters given as None or ``"auto"`` → the value the fit chose
        (:func:`~btel.core.params.chosen_at_fit`); None for a row that did not fit.
    n_map : int or None
        Map places (None only when a pre-fitted method without ``n_places_`` was evaluated).
    n_queries : int
        Query rows.
    recall : dict of int to float
        recall@t: tolerance (frames) → share of point predictions within t of the true place.
        Empty with explicit positives (no tolerance applies) and for rows that did not run.
    recall_curve : ndarray of shape (curve_max + 1,), dtype float64
        recall@t at t = 0, 1, …, curve_max (empty where ``recall`` is).
    recall_at_k : dict of int to float or None
        R@K: K → share of queries with a correct place among the top K ranked candidates.
    nbytes : int or None
        Storage (the storage rule, docs/guide/concepts.md); None when the method does not report it.
    storage_breakdown : dict of str to int or None
        Part → bytes.
    fit_time_s : float or None
        Wall-clock seconds of ``fit`` (None when the method was evaluated already fitted).
    query_time_s_per_query : float or None
        Batch throughput: median wall-clock seconds of ``predict`` on all queries (after a warm-up
        call, over ``timing_repeats`` calls) divided by the number of queries.
    rank_time_s_per_query : float or None
        Wall-clock seconds of one ``rank`` call on all queries divided by the number of queries.
    query_latency_s : float or None
        Single-query latency: median seconds of one query answered alone (:func:`time_queries`).
    n_threads : int or None
        Threads the numerical libraries could use while timing.
    timing_repeats : int or None
        Timed batch calls behind ``query_time_s_per_query``.
    auc_pr_vpr_bench, auc_pr_vpr_tutorial : float or None
        Area under the precision–recall curve of accepting each query's top-1 match by its score,
        as VPR-Bench and as VPR_Tutorial compute it (:func:`precision_recall` says how they
        differ); None when the method gives no scores.
    recall_at_100_precision : float or None
        Recall at 100 % precision on that curve.
    pr_curve : dict or None
        ``{"precision": [...], "recall": [...]}``, at most :data:`PR_CURVE_POINTS` points.
    chosen_method : str or None
        For a method that picks another (``auto``): the registered name it chose (the plots draw
        ``auto → <choice>``).
    predictions : ndarray of shape (n_queries,), dtype int64
        Predicted place per query row (not written to JSON; see ``predictions_<name>.csv``).
    ranked : ndarray of shape (n_queries, k), dtype int64, or None
        Ranked candidates (not written to JSON).
    ground_truth : GroundTruth or None
        The ground truth used (not written to JSON).
    tolerance_for_k : int
        Tolerance used for R@K.
    status : str
        ``"ok"``, or why there are no numbers: ``"does not fit"`` (the budget), ``"failed"`` (an
        error while fitting or localizing), ``"refused"`` (e.g. a sequence method on queries that
        are not a route), ``"not run"`` (interrupted before its turn).
    reason : str or None
        The message behind a status other than ``"ok"``.
    budget : int or None
        The byte budget the method was given (None: unbudgeted).
    reference : bool
        The unbudgeted reference row (brute force).
    uses_query_sequence : bool
        Answers depend on the query sequence (SeqSLAM, a delta front end): not comparable with
        single-frame methods, marked in every table.
    minimum_bytes : int or None
        For ``"does not fit"``: the smallest budget the method needs.
    budget_saturated : bool
        The budgeted model is the largest its parameters allow (the method's ``budget_saturated()``):
        it cannot use the rest of its budget, and any larger budget gives the same model.
    series : str or None
        The method this row is one point of (``pq`` for the rows ``pq@100KB`` and ``pq@500KB``);
        plots draw one line per series. None: the row's own name.
    settings : dict or None
        The parameters set by the user for this row (``--param``), shown in plot legends.
    truth : dict or None
        Where the ground truth came from and which places count as correct: ``{"source": a file's
        path, "UTM in image names" or "frame-aligned …", "rule": e.g. "positives within 25 m"}``
        (:func:`btel.datasets.sources.resolve_ground_truth`); written as ``ground_truth_source`` and
        ``positive_rule``.
    choice : dict or None
        What a method that chooses at fit time (``auto``) chose: ``{"method", "params",
        "reason", …}`` from its :meth:`~btel.methods.auto.AutoLocalizer.choice`; None otherwise.
    labels : dict
        An experiment's own cells of the row (``direction``, ``decoder``, ``family``, ``options``,
        …): what the row is, beside what was measured. Written by :meth:`to_row` only.
    columns : tuple of str
        The cells of the flat row in order (:meth:`from_row` keeps the order it was given, so a
        results file is rewritten column for column); empty: every known cell, in a fixed order.
    """

    name: str
    params: dict[str, Any] = field(default_factory=dict)
    chosen_at_fit: dict[str, Any] | None = None
    n_map: int | None = None
    n_queries: int = 0
    recall: dict[int, float] = field(default_factory=dict)
    recall_curve: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    recall_at_k: dict[int, float] | None = None
    nbytes: int | None = None
    storage_breakdown: dict[str, int] | None = None
    fit_time_s: float | None = None
    query_time_s_per_query: float | None = None
    rank_time_s_per_query: float | None = None
    query_latency_s: float | None = None
    n_threads: int | None = None
    timing_repeats: int | None = None
    auc_pr_vpr_bench: float | None = None
    auc_pr_vpr_tutorial: float | None = None
    recall_at_100_precision: float | None = None
    pr_curve: dict[str, list[float]] | None = field(default=None, repr=False)
    chosen_method: str | None = None
    predictions: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)
    ranked: np.ndarray | None = field(default=None, repr=False)
    ground_truth: GroundTruth | None = field(default=None, repr=False)
    tolerance_for_k: int = 0
    status: str = STATUS_OK
    reason: str | None = None
    budget: int | None = None
    reference: bool = False
    uses_query_sequence: bool = False
    minimum_bytes: int | None = None
    budget_saturated: bool = False
    series: str | None = None
    settings: dict[str, Any] | None = None
    choice: dict[str, Any] | None = None
    truth: dict[str, str] | None = None
    labels: dict[str, Any] = field(default_factory=dict)
    columns: tuple[str, ...] = field(default=(), repr=False)

    @property
    def ok(self) -> bool:
        """True when the method ran and was measured."""
        return self.status == STATUS_OK

    @classmethod
    def not_measured(cls, name: str, status: str, reason: str, *, method: Any = None, n_map: int | None = None,
                     n_queries: int = 0, budget: int | None = None, reference: bool = False,
                     minimum_bytes: int | None = None) -> "EvaluationResult":
        """A row for a method that did not run (``status`` says why, ``reason`` in full)."""
        result = cls(name=name, params=_params_of(method) if method is not None else {}, n_map=n_map,
                     n_queries=int(n_queries), recall={}, recall_curve=np.zeros(0), recall_at_k=None, nbytes=None,
                     storage_breakdown=None, fit_time_s=None, query_time_s_per_query=None, status=status,
                     reason=reason, budget=budget, reference=reference,
                     uses_query_sequence=bool(getattr(method, "uses_query_sequence", False)),
                     minimum_bytes=minimum_bytes)
        return result

    @classmethod
    def does_not_fit(cls, name: str, exc: Any, **common: Any) -> "EvaluationResult":
        """The row of a method whose budget is too small (``exc``: its
        :class:`~btel.exceptions.BudgetTooSmallError`), status ``"does not fit"``, its minimum bytes."""
        reason = " ".join(str(exc).split()) or type(exc).__name__
        return cls.not_measured(name, STATUS_DOES_NOT_FIT, reason, minimum_bytes=exc.minimum, **common)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "EvaluationResult":
        """A row back from :meth:`to_dict` (``metrics.json``): every number, no predictions or ranking.

        Every field is checked before use (a resumed run's ``metrics.json`` may have been edited):
        see :func:`_check_row` for the type each field must have.

        Raises
        ------
        InvalidParameterError
            ``data`` lacks a field :meth:`to_dict` writes, or a field has the wrong type or shape
            (the message names it, and the row's ``name`` when it has one).
        """
        try:
            _check_row(data)
            result = cls(
                name=str(data["name"]), params=dict(data.get("params") or {}), n_map=data.get("n_map"),
                chosen_at_fit=data.get("chosen_at_fit"),
                n_queries=int(data["n_queries"]), recall={int(t): float(v) for t, v in (data.get("recall") or {}).items()},
                recall_curve=np.asarray(data.get("recall_curve") or [], dtype=np.float64),
                recall_at_k=(None if data.get("recall_at_k") is None
                             else {int(k): float(v) for k, v in data["recall_at_k"].items()}),
                nbytes=data.get("nbytes"), storage_breakdown=data.get("storage_breakdown"),
                fit_time_s=data.get("fit_time_s"), query_time_s_per_query=data.get("query_time_s_per_query"),
                rank_time_s_per_query=data.get("rank_time_s_per_query"), query_latency_s=data.get("query_latency_s"),
                n_threads=data.get("n_threads"), timing_repeats=data.get("timing_repeats"),
                auc_pr_vpr_bench=data.get("auc_pr_vpr_bench"), auc_pr_vpr_tutorial=data.get("auc_pr_vpr_tutorial"),
                recall_at_100_precision=data.get("recall_at_100_precision"), pr_curve=data.get("pr_curve"),
                chosen_method=data.get("chosen_method"),
                tolerance_for_k=int(data.get("tolerance_for_k") or 0), status=str(data["status"]),
                reason=data.get("reason"), budget=data.get("budget"), reference=bool(data.get("reference")),
                uses_query_sequence=bool(data.get("uses_query_sequence")), minimum_bytes=data.get("minimum_bytes"),
                budget_saturated=bool(data.get("budget_saturated")),
                series=data.get("series"), settings=data.get("settings"), choice=data.get("choice"),
                truth=(None if data.get("ground_truth_source") is None else
                       {"source": data["ground_truth_source"], "rule": data.get("positive_rule")}))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            row = f" {data.get('name')!r:.60}" if isinstance(data, Mapping) else ""
            raise InvalidParameterError(f"not a row{row} of metrics.json ({type(exc).__name__}: {exc}).") from exc
        return result

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no predictions). Tolerances and K stay ints here; JSON makes them strings."""
        return {
            "name": self.name,
            "status": self.status,
            "reason": self.reason,
            "series": self.series or self.name,
            "settings": jsonable(self.settings) if self.settings else None,
            "choice": self.choice,
            "reference": self.reference,
            "uses_query_sequence": self.uses_query_sequence,
            "budget": self.budget,
            "minimum_bytes": self.minimum_bytes,
            "budget_saturated": self.budget_saturated,
            "params": self.params,
            "chosen_at_fit": self.chosen_at_fit,
            "n_map": self.n_map,
            "n_queries": self.n_queries,
            "recall": {int(t): float(r) for t, r in self.recall.items()},
            "recall_curve": [float(r) for r in np.asarray(self.recall_curve)],
            "recall_at_k": (
                None if self.recall_at_k is None else {int(k): float(r) for k, r in self.recall_at_k.items()}
            ),
            "tolerance_for_k": self.tolerance_for_k,
            "nbytes": self.nbytes,
            "storage_breakdown": self.storage_breakdown,
            "fit_time_s": self.fit_time_s,
            "query_time_s_per_query": self.query_time_s_per_query,
            "rank_time_s_per_query": self.rank_time_s_per_query,
            "query_latency_s": self.query_latency_s,
            "n_threads": self.n_threads,
            "timing_repeats": self.timing_repeats,
            "auc_pr_vpr_bench": self.auc_pr_vpr_bench,
            "auc_pr_vpr_tutorial": self.auc_pr_vpr_tutorial,
            "recall_at_100_precision": self.recall_at_100_precision,
            "pr_curve": self.pr_curve,
            "chosen_method": self.chosen_method,
            "ground_truth": None if self.ground_truth is None else self.ground_truth.kind,
            "ground_truth_source": None if self.truth is None else self.truth.get("source"),
            "positive_rule": None if self.truth is None else self.truth.get("rule"),
        }

    def headline(self) -> dict[int, float]:
        """What the storage plot shows: recall@t when the ground truth has a tolerance, else R@K keyed by K."""
        return dict(self.recall) if self.recall else dict(self.recall_at_k or {})

    def to_row(self) -> dict[str, Any]:
        """The flat row of an experiment's ``results.json`` / ``results.csv`` (:data:`ROW_CELLS`).

        Cells in :attr:`columns` order when the record has one, else method, status, n_places,
        budget, nbytes, fit_s, query_us, recall@t…, R@K…, then the labels.
        """
        columns = self.columns or self._default_columns()
        row: dict[str, Any] = {}
        for cell in columns:
            if cell in ROW_CELLS:
                row[cell] = getattr(self, ROW_CELLS[cell])
            elif cell == "query_us":
                row[cell] = None if self.query_time_s_per_query is None else self.query_time_s_per_query * 1e6
            elif (match := _RECALL_CELL.match(cell)) and int(match.group(1)) in self.recall:
                row[cell] = self.recall[int(match.group(1))]
            elif (match := _RANKED_CELL.match(cell)) and int(match.group(1)) in (self.recall_at_k or {}):
                row[cell] = self.recall_at_k[int(match.group(1))]  # type: ignore[index]
            elif cell in self.labels:
                row[cell] = self.labels[cell]
        return row

    def _default_columns(self) -> tuple[str, ...]:
        cells = ["method", "status", "n_places", "budget", "nbytes"]
        cells += ["minimum_bytes"] if self.minimum_bytes is not None else []
        cells += [c for c, v in (("fit_s", self.fit_time_s), ("query_us", self.query_time_s_per_query)) if v is not None]
        cells += ["uses_query_sequence"] if self.uses_query_sequence else []
        cells += [f"recall@{t}" for t in self.recall] + [f"R@{k}" for k in (self.recall_at_k or {})]
        return tuple(cells + list(self.labels))

    @classmethod
    def from_row(cls, row: Mapping[str, Any], measured: "EvaluationResult | None" = None) -> "EvaluationResult":
        """A record from a flat row (an experiment's cells, or a row of ``results.json``).

        Known cells (:data:`ROW_CELLS`, ``query_us``, ``recall@t``, ``R@K``) become fields, every
        other cell a label; the order of the cells is kept. ``measured``: the record of the
        evaluation behind the row (its curve, predictions, ranking); the row's cells override it.
        """
        fields: dict[str, Any] = {}
        recall: dict[int, float] = {}
        ranked: dict[int, float] = {}
        labels: dict[str, Any] = {}
        for cell, value in row.items():
            if cell in ROW_CELLS:
                fields[ROW_CELLS[cell]] = value
            elif cell == "query_us":
                fields["query_time_s_per_query"] = None if value is None else value / 1e6
            elif match := _RECALL_CELL.match(cell):
                recall[int(match.group(1))] = value
            elif match := _RANKED_CELL.match(cell):
                ranked[int(match.group(1))] = value
            else:
                labels[cell] = value
        if "name" not in fields:
            raise InvalidParameterError(f"a result row needs a 'method' cell; got cells {list(row)}.")
        fields.update(recall=recall, recall_at_k=ranked or None, labels=labels, columns=tuple(row))
        return cls(**fields) if measured is None else replace(measured, **fields)
