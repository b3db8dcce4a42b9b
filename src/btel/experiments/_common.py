"""What every experiment shares: the Nordland descriptors, fitted rows, and the result files.

An experiment is a function ``(data: NordlandData, out: Path, quick: bool) -> ExperimentRun`` whose
rows are :class:`~btel.evaluation.records.EvaluationResult` records (the experiment's own cells in their
``labels``) and whose ``plot`` draws its figure(s); :func:`write_results` turns the run into
``results.json``, ``results.csv`` (the records' flat rows) and those figures.

Fitting is shared too (:func:`fit_rows`, :func:`fit_model`):

- **cache** — a fitted model is kept by (method, parameters, a SHA-1 of the map's bytes and
  shape, a SHA-1 of btel's own source): in memory for the rest of the process and on disk in
  ``<cache_dir>/models/`` (``model.save`` / ``btel.load``: plain arrays, no pickles), so a
  configuration met again — the same BTE-C in several experiments, a rerun after a crash —
  is loaded instead of refitted. Any change to btel's code changes the key, so a cached model
  is always one the current code would fit. A row from the cache reports the fit time measured
  when the model was fitted, and ``"cached": true``. ``BTEL_EXPERIMENT_CACHE=0`` turns it off.
- **parallel** — the independent fits of an experiment run in ``BTEL_EXPERIMENT_JOBS`` threads
  (default: every core), each with one BLAS thread and one faiss thread (threadpoolctl), so fit
  times are single-core times; the rows come back in their order whatever finished first. The
  solvers are deterministic, so a rerun gives the same rows.
- **progress** — one bar per experiment with the rows done and an ETA.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ..evaluation.measure import measure, timed_fit
from ..evaluation.metrics import DEFAULT_TOLERANCES
from ..evaluation.records import EvaluationResult, does_not_fit_status
from ..exceptions import BudgetTooSmallError
from ..datasets.nordland import QUICK_FRAMES, SEASONS, NordlandData, default_nordland_root
from ..methods.registry import make_method
from ..core.storage import check_within_budget, parse_budget
from ..evaluation.tables import describe_row, rows_csv_text

__all__ = ["SEASONS", "QUICK_FRAMES", "NordlandData", "ExperimentRun", "default_nordland_root", "fit_row",
           "fit_rows", "fit_model", "ModelCache", "full_or_quick", "write_results", "describe_row",
           "data_fingerprint", "does_not_fit_cells", "experiment_jobs", "fit_and_predict",
           "FittedRow"]

@dataclass
class ExperimentRun:
    """Rows of one experiment, where they were written, and how the experiment draws them."""

    name: str
    rows: list[EvaluationResult]
    out_dir: Path
    curves: dict[str, list[float]] = field(default_factory=dict)
    #: Anything else an experiment reports (the "beyond" ladder, diagnostics, protocol).
    extra: dict[str, Any] = field(default_factory=dict)
    #: The experiment's figure(s): ``plot(run, out_dir) -> [PNG paths]``; None draws nothing.
    plot: Callable[["ExperimentRun", Path], list[Path]] | None = field(default=None, repr=False)

    @classmethod
    def from_rows(cls, name: str, rows: list[dict[str, Any]], out_dir: Path, **kwargs: Any) -> "ExperimentRun":
        """A run from the flat rows an experiment assembled (:meth:`EvaluationResult.from_row` each)."""
        return cls(name, [EvaluationResult.from_row(r) for r in rows], out_dir, **kwargs)


def experiment_jobs() -> int:
    """Threads for an experiment's independent fits: ``BTEL_EXPERIMENT_JOBS``, default every core."""
    value = os.environ.get("BTEL_EXPERIMENT_JOBS", "").strip()
    if not value:
        return max(1, os.cpu_count() or 1)
    if not (value.isascii() and value.isdigit()) or not 1 <= int(value) <= 4096:
        from ..exceptions import InvalidParameterError

        raise InvalidParameterError(f"BTEL_EXPERIMENT_JOBS={value[:40]!r} is not a number of threads; give a whole "
                                    f"number from 1 to 4096 (this machine has {os.cpu_count()} cores), or unset it.")
    return int(value)


def data_fingerprint(X: np.ndarray) -> str:
    """SHA-1 of an array's shape, dtype and bytes (C order)."""
    arr = np.ascontiguousarray(X)
    digest = hashlib.sha1(f"{arr.shape}|{arr.dtype.str}|".encode())
    digest.update(memoryview(arr).cast("B"))
    return digest.hexdigest()


_SOURCE_DIGEST: str | None = None


def _source_digest() -> str:
    """SHA-1 of every .py file of the installed btel package: the code a cached model was fitted by."""
    global _SOURCE_DIGEST
    if _SOURCE_DIGEST is None:
        root = Path(__file__).resolve().parents[1]
        digest = hashlib.sha1()
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
        _SOURCE_DIGEST = digest.hexdigest()
    return _SOURCE_DIGEST


class ModelCache:
    """Fitted models by (method, parameters, data fingerprint, btel source), in memory and on disk.

    Parameters
    ----------
    folder : path or None
        Where models are saved (``<key>.btel.npz`` + ``<key>.json``); None keeps them in memory only.
    enabled : bool
        False: never reuse (every fit runs).
    min_fit_seconds : float
        Models that fitted faster than this are not written to disk (refitting is cheaper than
        reading, e.g. brute force, whose file is the whole map).
    """

    def __init__(self, folder: Path | None, *, enabled: bool = True, min_fit_seconds: float = 2.0) -> None:
        self.folder = None if folder is None else Path(folder)
        self.enabled = enabled
        self.min_fit_seconds = float(min_fit_seconds)
        self._memory: dict[str, tuple[Any, float]] = {}
        self._lock = threading.Lock()
        self._key_locks: dict[str, threading.Lock] = {}
        self._aliases: dict[str, tuple[str, int]] = {}

    @staticmethod
    def key(name: str, params: dict[str, Any], X: np.ndarray) -> str:
        text = json.dumps({"method": name, "params": params, "data": data_fingerprint(X), "code": _source_digest()},
                          sort_keys=True, default=str)
        return hashlib.sha1(text.encode()).hexdigest()

    @contextlib.contextmanager
    def _locked(self, key: str) -> Iterator[None]:
        """One fit per key at a time: a second thread asking for it waits and then reads the cache."""
        with self._lock:
            lock = self._key_locks.setdefault(key, threading.Lock())
        with lock:
            yield

    def get(self, key: str, name: str | None = None, X: np.ndarray | None = None) -> tuple[Any, float] | None:
        """The model cached under ``key``; one read from disk must be a ``name`` model fitted on ``X``'s rows
        (its file records them: :mod:`btel.core.fingerprint`), else it is refitted (a file edited or
        swapped in the cache folder would otherwise label another model's results)."""
        if not self.enabled:
            return None
        if key in self._memory:
            return self._memory[key]
        if self.folder is not None:
            model_path, meta_path = self.folder / f"{key}.btel.npz", self.folder / f"{key}.json"
            if model_path.is_file() and meta_path.is_file():
                from ..core.fingerprint import same_map
                from ..methods.registry import load, make_method

                try:
                    model, fit_s = load(model_path), float(json.loads(meta_path.read_text())["fit_s"])
                except Exception:  # a damaged cache file is refitted, never trusted
                    return None
                if name is not None and type(model) is not type(make_method(name)):
                    return None
                if X is not None and not same_map(getattr(model, "map_fingerprint_", None), X):
                    return None
                self._memory[key] = (model, fit_s)
                return model, fit_s
        return None

    def put(self, key: str, model: Any, fit_s: float, description: dict[str, Any]) -> None:
        if not self.enabled:
            return
        self._memory[key] = (model, fit_s)
        if self.folder is not None and fit_s >= self.min_fit_seconds:
            self.folder.mkdir(parents=True, exist_ok=True)
            # model.save writes a temporary of a unique name and renames it (concurrent puts of one
            # key cannot collide: the last rename wins); the metadata goes the same way.
            model.save(self.folder / f"{key}.btel.npz", overwrite=True)  # the cache's own file, even if damaged
            fd, tmp = tempfile.mkstemp(dir=self.folder, prefix=f".{key}.json.", suffix=".tmp")
            try:
                with os.fdopen(fd, "w", encoding="utf-8") as fh:
                    fh.write(json.dumps({**description, "fit_s": fit_s}, default=str) + "\n")
                os.replace(tmp, self.folder / f"{key}.json")
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise

    def fit(self, name: str, params: dict[str, Any], X: np.ndarray) -> tuple[Any, float, bool]:
        """(fitted model, fit seconds, from the cache?) of ``make_method(name, **params)`` on X.

        A budget that only caps the model: when a model with the same parameters but another
        budget reached its configuration's cap (``model.budget_saturated()``: d' as large as the
        parameters allow, so its budget did not shape it) and fits this budget too, it *is* the
        model this budget gives — BTE-C at d' = d under 5 MB … 256 KB, RYTH under 5 MB … 1 MB —
        and is reused. Raises whatever ``fit`` raises (e.g. BudgetTooSmallError); such outcomes
        are not cached.
        """
        key = self.key(name, params, X)
        budget = params.get("budget")
        alias = None if budget is None else self.key(name, {k: v for k, v in params.items() if k != "budget"}, X) \
            + "-saturated"
        # Budgets of one configuration wait for each other: the second may reuse the first.
        with self._locked(alias or key):
            hit = self.get(key, name, X)
            if hit is not None:
                return hit[0], hit[1], True
            if alias is not None and self.enabled:
                target = self._aliases.get(alias) or self._read_alias(alias)
                if target is not None and target[1] <= parse_budget(budget):
                    hit = self.get(target[0], name, X)
                    if hit is not None:
                        return hit[0], hit[1], True
            model = make_method(name, **params)
            if "progress" in model.get_params():  # one bar per experiment instead (fit_rows)
                model.set_params(progress=False)
            fit_s = timed_fit(model, X)
            self.put(key, model, fit_s, {"method": name, "params": params, "n_places": int(X.shape[0])})
            if alias is not None and self.enabled and model.budget_saturated():
                self._aliases[alias] = (key, int(model.nbytes))
                if self.folder is not None and fit_s >= self.min_fit_seconds:
                    (self.folder / f"{alias}.json").write_text(json.dumps({"key": key, "nbytes": int(model.nbytes)}))
            return model, fit_s, False

    def _read_alias(self, alias: str) -> tuple[str, int] | None:
        path = None if self.folder is None else self.folder / f"{alias}.json"
        if path is None or not path.is_file():
            return None
        try:
            entry = json.loads(path.read_text())
            return str(entry["key"]), int(entry["nbytes"])
        except (ValueError, KeyError, TypeError):
            return None


@dataclass
class FittedRow:
    """A method fitted under a budget and measured on every query (:func:`fit_and_predict`)."""

    model: Any
    pred: np.ndarray
    fit_s: float
    query_us: float
    record: EvaluationResult


def does_not_fit_cells(exc: BudgetTooSmallError) -> dict[str, Any]:
    """The cells of a row whose method did not fit its budget: status, no bytes, the minimum it needs."""
    return {"status": does_not_fit_status(exc.minimum), "nbytes": None, "minimum_bytes": int(exc.minimum or 0)}


def fit_and_predict(name: str, params: dict[str, Any], X: np.ndarray, Q: np.ndarray, budget: int | None,
                    label: str, *, progress: bool | None = None, timing_repeats: int = 1
                    ) -> FittedRow | dict[str, Any]:
    """Fit one registered method under ``budget`` and measure it on every query (:func:`measure`).

    ``timing_repeats`` is :func:`measure`'s (0: the predicting call alone is timed). No
    precision–recall pass: these experiments report recall and times only.

    Returns the fields of a "does not fit" row (with the minimum bytes) when the budget is too
    small; ``progress`` (when given) is set on methods that have that parameter.
    """
    model = make_method(name, **({"budget": budget} if budget is not None else {}), **params)
    if progress is not None and "progress" in model.get_params(deep=False):
        model.set_params(progress=progress)
    try:
        fit_s = timed_fit(model, X)
    except BudgetTooSmallError as exc:
        return does_not_fit_cells(exc)
    check_within_budget(label, model.nbytes, budget)
    record = measure(model, None, Q, name=label, fit=False, fit_time_s=fit_s, ks=(), budget=budget,
                     timing_repeats=timing_repeats, score_answers=False)
    return FittedRow(model, record.predictions, fit_s, record.query_time_s_per_query * 1e6, record)


_CACHES: dict[str, ModelCache] = {}


def model_cache(data: "NordlandData | None") -> ModelCache:
    """The process' cache for this data's cache folder (``<cache_dir>/models``; memory only without data)."""
    folder = None if data is None else Path(data.cache_dir) / "models"
    key = str(folder)
    if key not in _CACHES:
        _CACHES[key] = ModelCache(folder, enabled=os.environ.get("BTEL_EXPERIMENT_CACHE", "1") != "0")
    return _CACHES[key]


def fit_model(name: str, params: dict[str, Any], X: np.ndarray, data: "NordlandData | None" = None
              ) -> tuple[Any, float, bool]:
    """(fitted model, fit seconds, cached?) through the experiment cache (module docstring)."""
    return model_cache(data).fit(name, dict(params), np.asarray(X))


def _descriptor_of(method: str) -> str:
    """The image descriptor an experiment reads for ``method``: the one it declares it was built on
    (``native_descriptor``: SeqSLAM's thumbnails), else HOG."""
    return getattr(make_method(method), "native_descriptor", None) or "hog"


def fit_row(name: str, data: NordlandData, *, budget: Any, n_places: int | None, map_season: str = "summer",
            params: dict[str, Any] | None = None, label: str | None = None,
            extra: dict[str, Any] | None = None) -> EvaluationResult:
    """Fit one method under a budget and measure it; a budget it cannot meet becomes a row, not an error.

    The record's cells: method, registry_name, n_places, map, budget, front_end,
    uses_query_sequence, ``extra``, status, nbytes, fit_s, query_us, recall@t (the paper's fixed
    tolerances and 0..80 curve whatever N), cached, n_unconverged, R@K.
    """
    X, Q = data.pair(_descriptor_of(name), map_season, n_places)
    kwargs = dict(params or {})
    budget_bytes = parse_budget(budget)
    if budget_bytes is not None:
        kwargs["budget"] = budget_bytes
    kwargs = {**(data.front_end or {}), **kwargs}
    method = make_method(name, **kwargs)
    front = {k: method.get_params()[k] for k in ("normalize", "whiten", "delta")}
    labels = {"registry_name": name, "map": map_season, "front_end": front, **(extra or {})}
    head = ("method", "registry_name", "n_places", "map", "budget", "front_end", "uses_query_sequence",
            *(extra or {}), "status", "nbytes")
    try:
        model, fit_s, cached = fit_model(name, kwargs, X, data)
    except BudgetTooSmallError as exc:
        record = EvaluationResult.not_measured(label or name, does_not_fit_status(exc.minimum), str(exc),
                                               n_map=int(X.shape[0]), budget=budget_bytes,
                                               minimum_bytes=exc.minimum, method=method)
        record.labels, record.columns = labels, (*head, "minimum_bytes")
        return record
    if cached:
        labels["cached"] = True
    if getattr(model, "n_unconverged_", None) is not None:
        labels["n_unconverged"] = int(model.n_unconverged_)
    record = measure(model, None, Q, name=label or name, fit=False, fit_time_s=fit_s,
                     tolerances=DEFAULT_TOLERANCES, curve_max=80, budget=budget_bytes, labels=labels)
    check_within_budget(label or name, record.nbytes, budget_bytes)
    record.uses_query_sequence = bool(method.uses_query_sequence)
    record.columns = (*head, "fit_s", "query_us", *(f"recall@{t}" for t in record.recall),
                      *(k for k in ("cached", "n_unconverged") if k in labels),
                      *(f"R@{k}" for k in (record.recall_at_k or {})))
    return record


@contextlib.contextmanager
def _one_thread_each() -> Iterator[None]:
    """BLAS and faiss limited to one thread for the parallel section (both are process-wide settings)."""
    from ..core.threads import limit_threads

    with limit_threads(1):
        yield


def fit_rows(data: NordlandData, jobs: list[dict[str, Any]], *, desc: str = "fits") -> list[EvaluationResult]:
    """:func:`fit_row` for every job (its keyword arguments, ``name`` included), in parallel, in order.

    Independent fits run in :func:`experiment_jobs` threads with one BLAS/faiss thread each; a
    progress bar shows the rows done and the ETA (``data.progress``).
    """
    from joblib import Parallel, delayed
    from tqdm.auto import tqdm

    for job in jobs:  # read every descriptor matrix first, in this thread
        data.pair(_descriptor_of(job["name"]), job.get("map_season", "summer"), job.get("n_places"))
    workers = min(experiment_jobs(), max(1, len(jobs)))
    out: list[Any] = [None] * len(jobs)
    with tqdm(total=len(jobs), desc=desc, unit="fit", disable=None if data.progress else True, leave=False) as bar:
        def run(i: int, job: dict[str, Any]) -> tuple[int, Any]:
            job = dict(job)
            return i, fit_row(job.pop("name"), data, **job)

        if workers == 1:
            for i, job in enumerate(jobs):
                out[i] = run(i, job)[1]
                bar.update(1)
            return out
        with _one_thread_each():
            for i, result in Parallel(n_jobs=workers, prefer="threads", return_as="generator_unordered")(
                    delayed(run)(i, job) for i, job in enumerate(jobs)):
                out[i] = result
                bar.update(1)
    return out


def full_or_quick(quick: bool, full: list[Any], small: list[Any]) -> list[Any]:
    """``small`` in quick mode, else ``full``."""
    return small if quick else full


def write_results(run: ExperimentRun, out: Path, meta: dict[str, Any]) -> None:
    """Write ``out/results.csv`` (one column per cell any row has, in order of first appearance), the
    experiment's figure(s) and, last, ``out/results.json`` (``{"run": meta, "rows", "curves",
    **run.extra}``) in one rename: ``btel report`` reads a run only through its results.json, so an
    experiment interrupted while writing leaves the previous run's (or none), never a half-written one."""
    from ..core.claims import atomic_output

    out.mkdir(parents=True, exist_ok=True)
    rows = [r.to_row() for r in run.rows]
    text = json.dumps({"run": meta, "rows": rows, "curves": run.curves, **run.extra}, indent=1,
                      default=_json_default) + "\n"
    with atomic_output(out / "results.csv", text=True) as fh:
        fh.write(rows_csv_text(run.rows))
    if run.plot is not None:
        run.plot(run, out)
    with atomic_output(out / "results.json", text=True) as fh:
        fh.write(text)


def _json_default(value: Any) -> Any:
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def docstring_markdown(text: str) -> str:
    """A docstring's text as Markdown on one line: ``:func:`~a.b.c``` becomes `` `c` ``, ``:mod:`a.b``` `` `a.b` ``,
    ````x```` `` `x` `` (the results page quotes the experiments' protocols from their docstrings)."""
    import re

    text = re.sub(r":[a-z]+:`(~?)([^`]+)`", lambda m: f"`{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}`", text)
    return " ".join(text.replace("``", "`").split())
