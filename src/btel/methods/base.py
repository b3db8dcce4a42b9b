"""The one interface every localization method implements (BTEL and each baseline).

A method is a scikit-learn estimator with **one required primitive** (faiss-style)::

    search(Q, k) -> (scores, places)     # (n_queries, k) each, best first; higher score = more likely

implemented in the method's own file — either ``_search`` directly, or ``_place_scores`` (a score
for every place) from which the base class derives ``_search``; each one derives the other.
Everything else is built here on that primitive alone, so it behaves the same for every method:

- ``predict(Q)`` — the best place per query (``search(Q, 1)``), int64 in [0, N);
- ``rank(Q, k)`` — the k best places, best first (R@K); ``rank(Q, 1)[:, 0] == predict(Q)``;
- ``place_scores(Q)`` — (n_queries, N) scores, higher = more likely;
- ``predict_sequence(Q, 'hmm' | 'median')`` — decoding over an ordered traverse
  (:mod:`btel.sequence.hmm`, :mod:`btel.sequence`), in blocks of queries (O(block × N) memory);
- :meth:`storage_breakdown` / :attr:`nbytes` / :meth:`save` — the storage rule (:mod:`btel.core.storage`) and
  the model file (:mod:`btel.core.modelfile`; ``btel.load`` reads it back).

``fit(X, places=None)`` is a template: it checks the parameters (``_parameter_constraints``) and the data,
fits the front end (:mod:`btel.core.frontend`) and calls ``_fit(X, places, n_places, budget, reserved)``
on the transformed map (``reserved``: the front end's bytes). A subclass implements ``_fit``, ``_search`` or
``_place_scores``, ``_stored_arrays`` (what inference reads), ``_fitted_state``, ``_array_specs``, ``_restore``.
"""

from __future__ import annotations

import inspect
import time
from contextlib import nullcontext
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from ..core.params import ParamsMixin
from ..core.validation import Budget, check_descriptors, check_is_fitted, check_params, check_positive_int, map_places
from ..exceptions import BudgetTooSmallError, InvalidAnswerError, InvalidDescriptorsError, InvalidParameterError, NotEnoughPlacesError
from ..core.frontend import FRONT_END_CONSTRAINTS, FRONT_END_MEANINGS, FrontEnd, traverse_starts, with_front_end_parameters
from ..core.storage import BUDGET_MEANING, budget_of, exact_bytes, parse_budget, storage_breakdown, summary_line
from ..core.fingerprint import map_fingerprint
from ..core.modelfile import ArraySpec, jsonable, save_arrays
from ..sequence.querystream import QueryStream
from ..core.topk import as_answered, put_first, top_k
from ..core.threads import one_blas_thread, predict_pool, predict_threads

__all__ = ["PlaceLocalizer", "ArraySpec", "QueryStream", "top_k", "put_first"]

#: Queries scored at a time when a (block × N) score matrix is built (about 32 MB of float64).
_SCORE_BLOCK_VALUES = 1 << 22
#: Batches of at least this many queries are predicted with one BLAS thread (below, no threads start).
_ONE_BLAS_THREAD_FROM = 512
#: Batches of at least this many queries are predicted in row chunks (of the second) on every core (linear methods).
_PARALLEL_PREDICT_FROM, _PREDICT_CHUNK_ROWS = 8192, 4096


class PlaceLocalizer(ParamsMixin, ABC):
    """Base class of every localization method (module docstring); scikit-learn's contract, not its import."""

    #: An answer depends on the queries before it (SeqSLAM; any method with delta: uses_query_sequence).
    uses_sequence: ClassVar[bool] = False
    #: True where classifiers predict a place's index code (BTEL, output codes): the results page asks.
    encodes_place_index: ClassVar[bool] = False
    label: ClassVar[str] = "this method"  #: as messages name it: what a user types (``--methods``), not the class
    #: Parameters' constraints (core.validation) and meanings (core.paramdocs); budget and front end here.
    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {}
    _parameter_meanings: ClassVar[dict[str, str]] = {"budget": BUDGET_MEANING, **FRONT_END_MEANINGS}
    #: The byte budget, a parameter of every method: parsed by :func:`btel.core.storage.budget_of`.
    budget: int | str | None = None
    #: Parameters that say how a model runs, not what it learned: never restored from a model file.
    _runtime_params: ClassVar[tuple[str, ...]] = ()
    #: The fitted attribute whose presence means "fitted" (set last by fit and load).
    _fitted_marker: ClassVar[str] = "n_places_"
    #: Fewest map rows the method can index.
    _min_rows: ClassVar[int] = 2
    #: True when queries are read only by ``Q @ W`` and row selections: they come as frontend.ScaledRows (no copy).
    _linear_in_queries: ClassVar[bool] = False
    #: True when ``_fit`` reads the map only by row selections and ``np.asarray`` of row blocks: it takes ScaledRows.
    _fit_reads_row_blocks: ClassVar[bool] = False
    #: False when ``_predict`` fills runtime caches that threads must not share: no row chunks then.
    _predict_in_threads: ClassVar[bool] = True

    #: The front end's three parameters and their defaults (:mod:`btel.core.frontend`), declared once for every
    #: method: each subclass's ``__init__`` gets them as keyword-only parameters (seen by ``get_params``, ``clone``
    #: and model files) and their constraints. A method whose defaults differ overrides it (SeqSLAM: no L2).
    front_end_defaults: ClassVar[dict[str, Any]] = {"normalize": "l2", "whiten": None, "delta": None}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not inspect.isabstract(cls) and cls._search is PlaceLocalizer._search \
                and cls._place_scores is PlaceLocalizer._place_scores:
            raise TypeError(f"{cls.__name__} must implement _search or _place_scores (the method's primitive).")
        if "__init__" in cls.__dict__:
            cls.__init__ = with_front_end_parameters(cls.__dict__["__init__"], dict(cls.front_end_defaults))
        cls._parameter_constraints = {"budget": [Budget()], **cls._parameter_constraints, **FRONT_END_CONSTRAINTS}

    # -- to implement ---------------------------------------------------------------------------
    @abstractmethod
    def _fit(self, X: np.ndarray, places: np.ndarray | None, n_places: int, budget: int | None,
             reserved: int) -> None:
        """Learn from the front-end-transformed map.

        Parameters
        ----------
        X : ndarray of shape (n_rows, n_features_out), float32
            Validated, transformed map (may be memory-mapped: do not copy it whole needlessly).
        places : ndarray of shape (n_rows,), int64, or None
            Place of each row; None means row i is place i.
        n_places : int
            N ≥ 2.
        budget, reserved : int or None, int
            The whole byte budget (None: none) and the bytes of it already taken (front end): the method
            must fit in ``budget − reserved``.
        """

    def _search(self, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(scores, places) of the k best places for transformed queries; default: from _place_scores."""
        scores = np.empty((Q.shape[0], k))
        places = np.empty((Q.shape[0], k), dtype=np.int64)
        for start, stop, block in self._score_blocks(Q):
            scores[start:stop], places[start:stop] = top_k(block, k)
        return scores, places

    def _sequence_context(self) -> int:
        """Earlier query rows a query's scores depend on (0: single frames; SeqSLAM: ds − 1)."""
        return 0

    def _score_blocks(self, Q: np.ndarray):
        """Yield (start, stop, place scores of rows start:stop) over blocks of about 32 MB.

        A sequence method gets the :meth:`_sequence_context` rows before each block (its whole-sequence scores).
        """
        rows = max(1, _SCORE_BLOCK_VALUES // max(int(self.n_places_), 1))
        context = self._sequence_context()
        for start in range(0, Q.shape[0], rows):
            stop = min(start + rows, Q.shape[0])
            first = max(0, start - context)
            yield start, stop, self._place_scores(Q[first:stop])[start - first :]

    def _place_scores(self, Q: np.ndarray) -> np.ndarray:
        """(n_queries, N) float64 scores of transformed queries; default: every place from _search."""
        n = int(self.n_places_)
        scores, places = self._search(Q, n)
        out = np.empty((Q.shape[0], n))
        np.put_along_axis(out, places, scores, axis=1)
        return out

    @abstractmethod
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        """Every array inference reads (besides the front end's), at its stored dtype."""

    def _fitted_state(self) -> dict[str, Any]:
        """JSON-serialisable scalars learned by fit (besides N, d and the front end)."""
        return {}

    @abstractmethod
    def _array_specs(self, state: dict[str, Any]) -> dict[str, ArraySpec]:
        """Shape and dtype of every stored array implied by a (validated) fitted state."""

    @abstractmethod
    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        """Set the fitted attributes from checked arrays and state (see :mod:`btel.methods`)."""

    # -- fit ------------------------------------------------------------------------------------
    def fit(self, X: Any, places: Any = None, **unknown: Any) -> "PlaceLocalizer":
        """Learn the map.

        Parameters
        ----------
        X : array-like of shape (n_rows, n_features)
            Map descriptors in route order. Row i is place i unless ``places`` is given.
        places : array-like of shape (n_rows,), int, optional
            Place index of each row (several rows may share a place: several traverses, augmented
            views). Must cover 0..N−1.

        Returns
        -------
        self
        """
        if unknown:  # e.g. calibration=(Q, truth) given to a method that cannot use it: say which one can
            raise InvalidParameterError(f"{self.label}'s fit takes X and places only, not {', '.join(unknown)}; "
                                        "labelled queries (calibration=…) are for make_method('auto', …).fit.")
        start = time.perf_counter()
        X, labels, n_places = self._check_fit_input(X, places)
        budget, front = budget_of(self), FrontEnd.of(self)
        reserved = self._front_end_bytes(X.shape[0], X.shape[1], budget)
        if labels is None:  # one place per row, as the planner counts: refuse the budget before transforming
            self._check_plan(X.shape[0], front.n_features_out(X.shape[1]), budget, reserved)
        Z = front.fit_transform(X, traverse_starts(labels), lazy=self._fit_reads_row_blocks)
        self._fit(Z, labels, n_places, budget, reserved)
        self.front_end_ = front
        self.n_features_in_ = int(X.shape[1])
        self.fit_time_ = time.perf_counter() - start
        setattr(self, self._fitted_marker, int(n_places))  # the fitted marker: set last
        return self

    def _check_fit_input(self, X: Any, places: Any) -> tuple[np.ndarray, np.ndarray | None, int]:
        """Parameters, descriptors and places checked as every ``fit`` does: ``(X, labels, n_places)``."""
        check_params(self)
        X = check_descriptors(X, name="X", distinct_rows=True)
        labels, n_places = map_places(places, X.shape[0])
        self.map_fingerprint_ = map_fingerprint(X)  # which rows the places index (the model file records it)
        if X.shape[0] < self._min_rows:
            raise NotEnoughPlacesError(
                f"{self.label} needs at least {self._min_rows} map descriptors; got {X.shape[0]}."
            )
        return X, labels, n_places

    def check_budget(self, n_rows: int, n_features: int, budget: int | None, reserved: int | None = None) -> None:
        """Raise now what :meth:`fit` would raise for a map of this shape under ``budget``, without fitting.

        The same planner ``fit`` uses, applied to the shapes alone: the evaluation's pre-check and the
        experiments call this and nothing else. Where the storage depends on what fitting finds (BTEL
        with a fixed r ≥ 2: the region sizes come from KTS), nothing is raised and the fit decides.

        Parameters
        ----------
        n_rows : int
            Map rows (one place each).
        n_features : int
            Raw descriptor dimension d, before the front end.
        budget : int, str or None
            Bytes, or a size such as ``"64KB"`` (None: unbudgeted).
        reserved : int, optional
            Bytes the front end takes; None: computed here, raising its own too-small error.

        Raises
        ------
        BudgetTooSmallError
            Nothing fits; ``minimum`` says how many bytes would.
        NotEnoughPlacesError
            Too few places for the method's parameters (regions, periods).
        """
        budget = parse_budget(budget)  # a size as the budget parameter takes it ("64KB"), or bytes
        reserved = self._front_end_bytes(n_rows, n_features, budget) if reserved is None else reserved
        self._check_plan(n_rows, FrontEnd.of(self).n_features_out(n_features), budget, reserved)

    def _check_plan(self, n_rows: int, n_features_out: int, budget: int | None, reserved: int) -> None:
        """The planner on shapes alone (:meth:`check_budget`; ``fit`` runs it first). Default: nothing."""

    def _front_end_bytes(self, n_rows: int, n_features: int, budget: int | None) -> int:
        """Bytes of the front end's stored arrays, or the error ``fit`` raises when they alone fill the budget."""
        front = FrontEnd.of(self)
        reserved = front.planned_bytes(n_rows, n_features)
        if budget is not None and reserved >= budget:
            raise BudgetTooSmallError(
                f"budget {exact_bytes(budget)} is too small for {self.label} with "
                f"whiten = {front.whiten}: the whitening matrix alone needs {reserved} B. Raise the budget or "
                "whiten to fewer dimensions.", budget=budget, minimum=reserved + 1,
            )
        return reserved

    def budget_saturated(self) -> bool:
        """True when this fitted model is as large as its parameters allow, so any larger budget gives the
        same model (the experiments then reuse it). Default: False (every budget may change the model)."""
        return False

    def summary(self) -> str:
        """What fitting chose, in a line or a few (by default N, d, the bytes against the budget, the front end)."""
        return summary_line(self)

    # -- inference --------------------------------------------------------------------------------
    @property
    def uses_query_sequence(self) -> bool:
        """True when answers depend on the query sequence (SeqSLAM, or a delta front end)."""
        return bool(self.uses_sequence or self.delta)

    def _check_queries(self, Q: Any) -> np.ndarray:
        """Validated queries (float32, 2-D, finite, the fitted dimension) through the front end."""
        check_is_fitted(self, self._fitted_marker)
        front = self.front_end_  # a normalising front end checks NaN/inf in its own pass over Q (the row norms)
        Q = check_descriptors(Q, name="Q", n_features=self.n_features_in_, check_finite=not front.checks_finite)
        return front.transform(Q, check_finite=True, lazy=self._linear_in_queries)

    def _check_k(self, k: Any) -> int:
        return min(k if type(k) is int and k >= 1 else check_positive_int(k, "k"), int(self.n_places_))

    def search(self, Q: Any, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` most likely places per query, best first, with their scores (the primitive).

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)
        k : int
            Candidates per query (capped at N).

        Returns
        -------
        scores : ndarray of shape (n_queries, min(k, N)), float64
            The method's score of each candidate (higher = more likely; e.g. −distance).
        places : ndarray of shape (n_queries, min(k, N)), int64
            Distinct places in [0, N), best first; ``places[:, 0]`` is :meth:`predict`, and where that is a decode
            (BTEL's, RYTH's) it comes first with its own score, which can be below the next place's.
        """
        Q = self._check_queries(Q)
        scores, places = as_answered(*self._search(Q, self._check_k(k)))  # places[:, 0] is predict's
        self._check_answers(places, scores)
        return scores, places

    def predict(self, Q: Any) -> np.ndarray:
        """Place index of each query.

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)

        Returns
        -------
        ndarray of shape (n_queries,), int64, every value in [0, N)
        """
        if (self._linear_in_queries and self._predict_in_threads and getattr(Q, "ndim", 0) == 2
                and Q.shape[0] >= _PARALLEL_PREDICT_FROM and predict_threads() > 1 and not self.front_end_.uses_sequence):
            return self._predict_in_chunks(Q, predict_threads())
        Q = self._check_queries(Q)
        with one_blas_thread() if Q.shape[0] >= _ONE_BLAS_THREAD_FROM else nullcontext():
            return self._check_answers(self._predict(Q))

    def _predict_in_chunks(self, Q: Any, n_threads: int) -> np.ndarray:
        """:meth:`predict` of a large batch as row chunks on ``n_threads`` threads (one BLAS thread each) where a row's
        answer depends on that row alone: single-threaded numpy passes (norms, decoding) use every core."""
        check_is_fitted(self, self._fitted_marker)
        front = self.front_end_
        Q = check_descriptors(Q, name="Q", n_features=self.n_features_in_, check_finite=not front.checks_finite)
        step = _PREDICT_CHUNK_ROWS
        slices = [slice(a, min(a + step, Q.shape[0])) for a in range(0, Q.shape[0], step)]

        def one(rows: slice) -> np.ndarray:
            return self._predict(front.transform(Q[rows], check_finite=True, lazy=True))

        try:
            with one_blas_thread():
                return self._check_answers(np.concatenate(list(predict_pool(n_threads).map(one, slices))))
        except InvalidDescriptorsError:
            self._check_queries(Q)  # the same error, with row numbers counted over the whole batch
            raise

    def _predict(self, Q: np.ndarray) -> np.ndarray:
        """Best place of transformed queries: ``_search(Q, 1)``'s, unless a method has a faster exact path."""
        return self._search(Q, 1)[1][:, 0]

    def rank(self, Q: Any, k: int = 10) -> np.ndarray:
        """The ``k`` most likely places per query, best first (shape (n_queries, min(k, N)), int64)."""
        return self.search(Q, k)[1]

    def place_scores(self, Q: Any) -> np.ndarray:
        """Score of every place for every query, higher = more likely.

        Returns
        -------
        ndarray of shape (n_queries, N), float64
        """
        scores = self._place_scores(self._check_queries(Q))
        self._check_answers(None, scores)
        return scores

    def _check_answers(self, places: np.ndarray | None, scores: np.ndarray | None = None) -> np.ndarray | None:
        """Every answer a place in [0, N) and every score finite, for every method.

        Raises
        ------
        InvalidAnswerError
            Naming the cause: overflowing scores (a damaged or hostile model file) or a place outside the map.
        """
        n = int(self.n_places_)
        if scores is not None and scores.size and not np.isfinite(scores).all():
            bad = int(np.argwhere(~np.isfinite(scores))[0][0])
            raise InvalidAnswerError(
                f"{self.label} produced non-finite scores (first at query row {bad}): its stored weights "
                "overflow float arithmetic, which a damaged or hostile model file causes. Refit the model or "
                "check where the file came from.")
        if places is not None and places.size and not (places.size == 1 and 0 <= places.item(0) < n) \
                and (places.min() < 0 or places.max() >= n):  # one valid answer: no reductions
            wrong = places[(places < 0) | (places >= n)][0]
            raise InvalidAnswerError(
                f"{self.label} answered place {int(wrong)}, outside the map's 0..{n - 1}: its stored "
                "weights overflow (a damaged or hostile model file?). Refit the model or check the file.")
        return places

    def stream(self) -> "QueryStream":
        """A query stream: one descriptor at a time, with the state a sequence needs (:class:`QueryStream`)."""
        check_is_fitted(self, self._fitted_marker)
        return QueryStream(self)

    def predict_sequence(self, Q: Any, decoder: str = "hmm", **options: Any) -> np.ndarray:
        """Place of each query of one ordered sequence (a traverse), decoded over time.

        No extra stored bytes: the decoders read only this model's per-query output.

        Parameters
        ----------
        Q : array-like of shape (n_queries, n_features)
            Consecutive frames of one traverse, in order.
        decoder : {'hmm', 'median'}
            'hmm': forward filtering over places, per-place scores (z-scored per frame) as emissions,
            forward motion as transitions (:class:`btel.sequence.hmm.HMMDecoder`; options
            ``temperature``, ``vmin``, ``vmax``, ``backward``, ``teleport``, ``mode``), in blocks of
            queries (O(block × N) memory). It assumes the queries advance 0 … ``vmax`` = 2 places a
            frame and hurts when they do not: set ``vmax`` to about twice their pace. 'median': the
            paper's filter on single-frame predictions (:func:`btel.sequence.filter_sequence`;
            option ``window``, default 5).

        Returns
        -------
        ndarray of shape (n_queries,), int64 in [0, N)
        """
        from ..sequence.hmm import predict_sequence

        return predict_sequence(self, Q, decoder, **options)

    # -- storage and files --------------------------------------------------------------------------
    def storage_breakdown(self) -> dict[str, int]:
        """Bytes of each stored array that inference reads (the storage rule), front end included.

        Returns
        -------
        dict of str to int
            Part name → bytes. ``sum(values) == nbytes``.
        """
        check_is_fitted(self, self._fitted_marker)
        return storage_breakdown({**self.front_end_.arrays(), **self._stored_arrays()})

    @property
    def nbytes(self) -> int:
        """Total storage in bytes: the sum of :meth:`storage_breakdown`."""
        return int(sum(self.storage_breakdown().values()))

    def save(self, path: Any, *, overwrite: bool | None = None) -> Any:
        """Save the fitted model: its stored arrays plus a JSON header (no pickles).

        The file exceeds :attr:`nbytes` by the container (a few KiB); runtime settings (``n_jobs``, progress)
        are not saved. An existing btel file is replaced, any other kept (``OutputExistsError``);
        ``overwrite=True`` replaces anything, ``False`` nothing, not even a racing save's file.

        Returns
        -------
        pathlib.Path
        """
        check_is_fitted(self, self._fitted_marker)
        params = {k: jsonable(v) for k, v in self.get_params(deep=False).items() if k not in self._runtime_params}
        state = {"n_places": int(self.n_places_), "n_features_in": int(self.n_features_in_),
                 # JSON has no NaN: a loaded model's unknown fit time is saved as null.
                 "fit_time": float(self.fit_time_) if np.isfinite(self.fit_time_) else None,
                 "front_end": self.front_end_.to_header(), **self._fitted_state()}
        header = {"model": type(self).__name__, "params": params, "state": state,
                  "map": getattr(self, "map_fingerprint_", None)}
        return save_arrays(path, {**self.front_end_.arrays(), **self._stored_arrays()}, header, overwrite)

    def __sklearn_tags__(self) -> Any:
        tags = super().__sklearn_tags__()
        tags.requires_fit = True
        return tags
