"""What a run of several methods is measured on: its jobs (methods by name, saved models), one map, a title.

:func:`make_jobs` turns names, budgets and parameters into :class:`Job` rows (the unbudgeted
reference added); ``btel evaluate`` and ``btel demo`` parse their options, call these, then
:func:`btel.evaluation.run_methods`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..core.storage import budget_of, format_bytes, parse_budget
from ..exceptions import InvalidParameterError

__all__ = ["Job", "make_jobs", "method_named", "RUNTIME_PARAMS", "saved_jobs", "saved_names", "common_map_size", "run_title",
           "takes_calibration", "calibrate_jobs"]

#: Parameters set by runtime flags (progress bars, parallel fits): they change how a method runs,
#: not what it computes, so they are applied where a method has them and left out of its settings.
RUNTIME_PARAMS = frozenset({"progress", "n_jobs"})


@dataclass
class Job:
    """One row of an evaluation run: a method to fit (or an already fitted one) under a budget.

    Attributes
    ----------
    name : str
        Row name (distinct within a run).
    method : estimator
        Unfitted (``fit=True``) or fitted (``fit=False``, e.g. a saved model).
    fit : bool
    reference : bool
        The unbudgeted reference row (brute force).
    series : str, optional
        The method this row is one point of, when a run has several budgets (``pq`` for ``pq@100KB``).
    settings : dict, optional
        The parameters the user set for this row (``--param code=random``), shown in plot legends
        so that two rows of one method can be told apart.
    fit_params : dict, optional
        Keyword arguments of the row's ``fit`` beside the map (``calibration=(Q, truth)``,
        :func:`calibrate_jobs`).
    """

    name: str
    method: Any
    fit: bool = True
    reference: bool = False
    series: str | None = None
    settings: dict[str, Any] | None = None
    fit_params: dict[str, Any] | None = None

    @property
    def budget(self) -> int | None:
        return budget_of(self.method)




@contextmanager
def method_named(method: str) -> Iterator[None]:
    """A bad parameter value found while building ``method`` names the method, not its class."""
    try:
        yield
    except InvalidParameterError as exc:
        message = re.sub(r"^[A-Z][A-Za-z]+: ", "", str(exc))  # "BTELocalizer: C must be …"
        raise InvalidParameterError(f"{method}: {message}") from exc


def make_jobs(methods: Sequence[str], budgets: Sequence[Any] = (None,),
              params: Mapping[str, Mapping[str, Any]] | None = None, *, reference: bool = True) -> list[Job]:
    """One job per (method, budget); the reference method (brute force) once, unbudgeted.

    Brute force stores every map descriptor, so it is the upper reference, not a contender under the
    budget: it runs without a budget unless ``params`` gives it one
    (:data:`btel.methods.registry.REFERENCE_METHOD` says which method it is). With ``reference``
    and the reference not among ``methods``, it is added, and the same search on shrinkage-whitened
    rows (:data:`btel.methods.roles.WHITENED_REFERENCE`) is a second reference row beside it —
    unless ``params`` gives the reference a front end or budget of its own.

    Parameters
    ----------
    methods : sequence of str
        Registered method names.
    budgets : sequence of int, str or None
        One row per method and budget (``pq@100KB`` names the row when there are several).
    params : mapping of str to mapping, optional
        Method name → its parameters (:data:`RUNTIME_PARAMS` among them are not shown as settings).
    reference : bool, default True
        Add the reference rows when ``methods`` does not name the reference.

    Returns
    -------
    list of Job
    """
    from ..methods.registry import REFERENCE_METHOD, make_method
    from ..methods.roles import WHITENED_REFERENCE

    params = {name: dict(p) for name, p in (params or {}).items()}
    budgets = list(budgets) or [None]
    names = list(methods)
    added_reference = reference and REFERENCE_METHOD not in names
    if added_reference:
        names.append(REFERENCE_METHOD)
    jobs = []
    for name in names:
        given = params.get(name, {})
        is_reference = name == REFERENCE_METHOD and "budget" not in given
        settings = {k: v for k, v in given.items() if k != "budget" and k not in RUNTIME_PARAMS}
        for budget in ([None] if is_reference else budgets):
            label = name if len(budgets) == 1 or is_reference else f"{name}@{budget}"
            kwargs = {**given, **({"budget": budget} if budget is not None and "budget" not in given else {})}
            with method_named(name):
                jobs.append(Job(label, make_method(name, **kwargs), reference=is_reference, series=name,
                                settings=settings or None))
    white_label, white_params = WHITENED_REFERENCE
    own = params.get(REFERENCE_METHOD, {})
    if added_reference and not set(white_params) & set(own) and "budget" not in own:
        kwargs = {**own, **white_params}
        settings = {k: v for k, v in kwargs.items() if k not in RUNTIME_PARAMS}
        with method_named(REFERENCE_METHOD):
            jobs.append(Job(white_label, make_method(REFERENCE_METHOD, **kwargs), reference=True,
                            series=white_label, settings=settings))
    return jobs




def takes_calibration(method: Any) -> bool:
    """Whether ``method.fit`` takes labelled queries (a ``calibration`` argument): the method is asked, by
    its fit's signature, never by its class or name."""
    import inspect

    fit = getattr(method, "fit", None)
    try:
        return callable(fit) and "calibration" in inspect.signature(fit).parameters
    except (TypeError, ValueError):  # a fit whose signature cannot be read takes nothing more
        return False


def calibrate_jobs(jobs: Sequence[Job], calibration: tuple[Any, Any],
                   tolerance: int | None = None) -> list[str]:
    """Give every job to fit whose method takes calibration (:func:`takes_calibration`) the labelled
    queries; the names of the jobs that ignore them.

    Parameters
    ----------
    jobs : sequence of Job
        Changed in place: a calibrated job's ``fit_params["calibration"]`` is set, and its method's
        ``calibration_tolerance`` (where it has one) when ``tolerance`` is given.
    calibration : (Q, truth)
        The calibration queries, array of shape (n_calibration, n_features), and their ground truth
        (true places, int array of shape (n_calibration,), or a :class:`~btel.datasets.GroundTruth`).
    tolerance : int, optional
        Places of slack of a calibration query's true place.

    Returns
    -------
    list of str
        Jobs not calibrated: saved (already fitted) models and methods whose fit takes no calibration.

    Raises
    ------
    InvalidParameterError
        ``tolerance`` given for a job whose settings already set ``calibration_tolerance``.
    """
    ignored = []
    for job in jobs:
        if not (job.fit and takes_calibration(job.method)):
            ignored.append(job.name)
            continue
        job.fit_params = {**(job.fit_params or {}), "calibration": calibration}
        own = job.method.get_params() if callable(getattr(job.method, "get_params", None)) else {}
        if tolerance is not None and "calibration_tolerance" in own:
            if "calibration_tolerance" in (job.settings or {}):
                raise InvalidParameterError(
                    f"{job.name}: the calibration tolerance is set twice (--calibrate-tolerance and "
                    "--param calibration_tolerance); give one.")
            job.method.set_params(calibration_tolerance=tolerance)
            job.settings = {**(job.settings or {}), "calibration_tolerance": tolerance}
    return ignored


def saved_jobs(paths: Sequence[str | os.PathLike], n_features: int, taken: Sequence[str] = ()) -> list[Job]:
    """One ``fit=False`` job per saved model file, checked against the queries' width.

    A job is named by its file (``runs/a/lsh.npz`` → ``lsh``); where that name is taken — by another
    file of the same name, or by a row in ``taken`` (the fitted rows) — by as much of its folder path
    as tells it apart (``a/lsh`` beside ``b/lsh``).

    Raises
    ------
    InvalidParameterError
        A model fitted on descriptors of another dimension, or the same file given twice.
    """
    from ..methods.registry import load

    names = saved_names(paths, taken)
    jobs = []
    for path, name in zip(paths, names):
        model = load(path)
        if model.n_features_in_ != n_features:
            raise InvalidParameterError(f"model {path} expects {model.n_features_in_}-D descriptors but the "
                                        f"queries have {n_features}.")
        jobs.append(Job(name, model, fit=False))
    return jobs


def saved_names(paths: Sequence[str | os.PathLike], taken: Sequence[str] = ()) -> list[str]:
    """The row name of each saved model file (:func:`saved_jobs`): its name without ``.npz`` (and
    ``.btel``), with as many of its folders in front as keep it apart from the other files' names and
    from ``taken``, as written and as a file name (``predictions_<name>.csv``).

    Raises
    ------
    InvalidParameterError
        The same file twice, or two files no folder tells apart as file names (``a/lsh`` and ``a-lsh``).
    """
    from .runs import safe_file_name

    full = [Path(os.path.abspath(p)) for p in paths]
    twice = next((str(paths[i]) for i, p in enumerate(full) if p in full[:i]), None)
    if twice is not None:
        raise InvalidParameterError(f"the model file {twice} is given twice; give each --model once.")
    stems = [p.name.removesuffix(".npz").removesuffix(".btel") or p.name for p in full]
    depth = [0] * len(full)
    used = {safe_file_name(t) for t in taken}

    def name(i: int) -> str:
        return "/".join([*full[i].parent.parts[len(full[i].parent.parts) - depth[i]:], stems[i]])

    while True:
        names = [name(i) for i in range(len(full))]
        safe = [safe_file_name(n) for n in names]
        clash = [i for i, n in enumerate(safe) if n in used or safe.count(n) > 1]
        growable = [i for i in clash if depth[i] < len(full[i].parent.parts) - 1]
        if not clash:
            return names
        if not growable:
            both = [str(paths[i]) for i in clash]
            raise InvalidParameterError(f"the model files {', '.join(both)} would name the same row ({safe[clash[0]]}, "
                                        "its file names in the run folder); rename one of them.")
        for i in growable:
            depth[i] += 1


def common_map_size(X_map: Any, Q: Any, saved: Sequence[Job]) -> int:
    """The number of map places the map descriptors and every saved model share.

    Raises
    ------
    InvalidParameterError
        The map and queries differ in width, or the maps differ in size (one ground truth could
        not hold for all).
    """
    if X_map is not None and X_map.shape[1] != Q.shape[1]:
        raise InvalidParameterError(f"the map has {X_map.shape[1]} dims but the queries have {Q.shape[1]}; "
                                    "describe both with the same descriptor.")
    sizes = {int(job.method.n_places_) for job in saved}
    if X_map is not None:
        sizes.add(int(X_map.shape[0]))
    if len(sizes) != 1:
        raise InvalidParameterError(f"the maps differ in size ({sorted(sizes)} places): the map descriptors "
                                    "and every saved model must cover one map for one ground truth to hold.")
    return sizes.pop()


def fitted_on_other_rows(X_map: Any, saved: Sequence[Job]) -> list[str]:
    """A note for each saved model whose recorded map (:mod:`btel.core.fingerprint`) is not ``X_map``'s rows:
    its place indices refer to another map (other descriptors of the same images, another extraction)."""
    from ..core.fingerprint import map_fingerprint

    if X_map is None:
        return []
    recorded = [(job, getattr(job.method, "map_fingerprint_", None)) for job in saved]
    digest = map_fingerprint(X_map)["sha256"] if any(fp is not None for _, fp in recorded) else None
    return [f"model {job.name} was fitted on other map rows (sha256 {fp['sha256'][:12]}…) than these "
            f"(sha256 {digest[:12]}…): its places index that map" for job, fp in recorded
            if fp is not None and fp["sha256"] != digest]


def run_title(dataset: str, n_map: int, n_queries: int, budgets: Sequence[Any], truth: dict[str, str], *,
              saved: bool = False, fitted: bool = True) -> str:
    """The plots' title: data set, sizes, budgets, ground truth (source and rule)."""
    given = [b for b in budgets if b is not None]
    if given:
        budget = "budget " + ", ".join(format_bytes(parse_budget(b)) for b in given)
    else:
        budget = ("saved models" + (" and unbudgeted methods" if fitted else "")) if saved else "no budget"
    source = truth["source"]
    if source.startswith("frame-aligned"):
        said = "frame-aligned"
    else:
        said = (f"{truth['rule']} from {Path(source).name}" if os.path.isabs(source)
                else f"{truth['rule']} ({source})")
    return f"{dataset}: N = {n_map}, {n_queries} queries; {budget}; {said}"
