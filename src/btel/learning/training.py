"""Running many classifier fits: shared work first, then one joblib call for every method.

A :class:`Task` is one classifier to learn: which rows of X it sees and their labels. BTE-C makes
b tasks per tree, BTE-F one per internal node, the region classifier one multiclass task.
:func:`fit_tasks` shares what tasks have in common before anything is solved:

- **one feature-selection pass** per set of rows: the BCSS of every bit of a tree comes from one
  product per row chunk (:func:`btel.learning.feature_selection.select_features_many`);
- **one standardised copy and one solve** per group of tasks that read the same rows and columns
  (every bit at d' = d, the one-vs-rest region classifier, a RYTH period): the solver works on all
  of them at once (:func:`btel.learning.linear.fit_linear_group`).

The groups then go through a single ``joblib.Parallel`` so that both cores (or every worker of a
Dask cluster: ``backend="dask"``, see :mod:`btel.learning.distributed`) stay busy across regions. Threads
are the default backend: the solvers spend their time in BLAS and LAPACK, which release the GIL,
and threads share X without copying it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .distributed import fit_backend
from .feature_selection import select_features, select_features_many
from .linear import ColumnStats, fit_linear_group
from ..core.threads import blas_threads as limit_blas

__all__ = ["Task", "FitSummary", "fit_tasks", "one_vs_rest_tasks", "convergence_warning"]


@dataclass(frozen=True)
class Task:
    """One classifier to fit.

    Attributes
    ----------
    labels : ndarray of shape (n_rows,), int
        Label of each row it is trained on.
    rows : ndarray of shape (n_rows,), int, or None
        Rows of X it sees; None means all rows.
    columns : ndarray of shape (d',), int, or None
        Columns chosen beforehand (the one-vs-rest region classifier shares one selection made
        with all r clusters); None means select them for this task's labels.
    """

    labels: np.ndarray
    rows: np.ndarray | None = None
    columns: np.ndarray | None = None
    sample_weight: np.ndarray | None = None


def one_vs_rest_tasks(
    X: np.ndarray,
    labels: np.ndarray,
    n_classes: int,
    n_selected: int,
    stats: ColumnStats,
    *,
    sparsity: float,
) -> list[Task]:
    """A multiclass linear classifier as binary tasks sharing one column selection.

    The d' columns are chosen once with the n_classes-cluster BCSS (the paper's feature selection); two classes give one
    hyperplane (positive = class 1), more give one-vs-rest hyperplanes in class order — the
    problems liblinear's one-vs-rest would solve, split so that they run in parallel.

    Parameters
    ----------
    labels : ndarray of shape (n_samples,), int in [0, n_classes)
    """
    columns = select_features(X, labels, n_selected, sparsity=sparsity, scale=stats.scale)
    if n_classes == 2:
        return [Task(labels=labels, columns=columns)]
    return [Task(labels=(labels == k).astype(np.int64), columns=columns) for k in range(n_classes)]


@dataclass
class FitSummary:
    """How the classifier fits of one model went.

    Attributes
    ----------
    n_classifiers : int
        Hyperplanes fitted.
    n_unconverged : int
        Hyperplanes whose solver stopped at its iteration cap.
    objective : float
        Sum of the solvers' primal objectives (:func:`btel.learning.solvers.linear_objective`).
    max_iter_used : int
        Most iterations any group took.
    solvers : tuple of str
        Solvers that ran (``'auto'`` resolved per group).
    """

    n_classifiers: int
    n_unconverged: int
    objective: float
    max_iter_used: int
    solvers: tuple[str, ...]


def convergence_warning(summary: FitSummary, owner: str, max_iter: int | None) -> None:
    """One :class:`~sklearn.exceptions.ConvergenceWarning` in the caller's thread when fits hit the cap."""
    if summary.n_unconverged:
        from sklearn.exceptions import ConvergenceWarning

        cap = "the solver's default cap" if max_iter is None else f"max_iter = {max_iter}"
        # Newton is the one to switch to when another solver stalled; when it was Newton, more rounds are the fix.
        fix = "Raise max_iter." if set(summary.solvers) <= {"newton"} else "Raise max_iter or use solver='newton'."
        warnings.warn(
            f"{owner}: {summary.n_unconverged} of {summary.n_classifiers} classifiers stopped at {cap} before "
            f"converging (solver {'/'.join(summary.solvers)}); the model is usable but not at the optimum. {fix}",
            ConvergenceWarning, stacklevel=3)


def _fit_group(X, rows, columns, labels, weights, stats, fit_kwargs):
    """Fit the tasks of one group (same rows, same columns): one standardised copy, one solve."""
    Xt = X if rows is None else X[rows]
    return fit_linear_group(Xt, labels, columns, stats, sample_weight=weights, **fit_kwargs)


def _rows_key(task: Task) -> int | None:
    return None if task.rows is None else id(task.rows)


def _select_columns(X, tasks: Sequence[Task], n_selected: int, stats: ColumnStats, sparsity: float
                    ) -> list[np.ndarray]:
    """Columns of every task: given, or selected with one BCSS pass per set of rows."""
    columns: list[np.ndarray | None] = [t.columns for t in tasks]
    pending: dict[int | None, list[int]] = {}
    for i, task in enumerate(tasks):
        if task.columns is None:
            pending.setdefault(_rows_key(task), []).append(i)
    for indices in pending.values():
        rows = tasks[indices[0]].rows
        Xt = X if rows is None else X[rows]
        if len(indices) == 1:
            columns[indices[0]] = select_features(Xt, tasks[indices[0]].labels, n_selected, sparsity=sparsity,
                                                  scale=stats.scale)
            continue
        chosen = select_features_many(Xt, [tasks[i].labels for i in indices], n_selected, sparsity=sparsity,
                                      scale=stats.scale)
        for i, cols in zip(indices, chosen):
            columns[i] = cols
    return columns  # type: ignore[return-value]


def fit_tasks(
    X: np.ndarray,
    tasks: Sequence[Task],
    n_selected: int,
    stats: ColumnStats,
    *,
    sparsity: float,
    n_jobs: int | None = None,
    backend: str | None = None,
    scheduler: str | None = None,
    progress: Callable[[int], Any] | None = None,
    **fit_kwargs: Any,
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], FitSummary]:
    """Select features for and fit every task, sharing work (module docstring), keeping the task order.

    Parameters
    ----------
    X : ndarray of shape (n_samples, n_features)
    tasks : sequence of Task
    n_selected : int
        d', columns kept per classifier.
    stats : ColumnStats
        Training statistics used to standardise (and folded into the hyperplanes).
    sparsity : float
        W–T L1 bound s.
    n_jobs : int, optional
        joblib workers (None: 1 unless inside ``joblib.parallel_config``; −1: all cores; with
        ``backend='dask'`` None means every worker of the cluster).
    backend : {None, 'threads', 'loky', 'dask'}
        Where the fits run (:func:`btel.learning.distributed.fit_backend`); None keeps the caller's joblib
        configuration (threads by default).
    scheduler : str, optional
        Dask scheduler address for ``backend='dask'`` (None: the current Client).
    progress : callable, optional
        Called with the number of tasks after each fitted group (e.g. ``tqdm.update``).
    **fit_kwargs
        classifier, C, solver, max_iter, random_state, dtype — see :func:`btel.learning.linear.fit_linear_group`.

    Returns
    -------
    parts : list of (weights (k, d'), bias (k,), columns (d',)), one per task
    summary : FitSummary
    """
    from joblib import Parallel, delayed  # fit-only imports: a loaded model never needs them
    from sklearn.exceptions import ConvergenceWarning

    columns = _select_columns(X, tasks, n_selected, stats, sparsity)
    groups: dict[tuple[int | None, bytes], list[int]] = {}
    for i, task in enumerate(tasks):
        groups.setdefault((_rows_key(task), np.asarray(columns[i]).tobytes()), []).append(i)
    members = list(groups.values())
    calls = (delayed(_fit_group)(X, tasks[idx[0]].rows, columns[idx[0]], [tasks[i].labels for i in idx],
                                 [tasks[i].sample_weight for i in idx], stats, fit_kwargs) for idx in members)
    parts: list[Any] = [None] * len(tasks)
    n_classifiers = n_unconverged = most_iter = 0
    objective = 0.0
    # Parallel groups each get one BLAS thread: BLAS's own threads on top of ours oversubscribe the
    # cores and made two workers slower than one in measurements on a 2-core machine. A single
    # group (every bit at d' = d) runs alone and keeps BLAS's threads for its matrix products.
    workers = 1 if len(members) == 1 and backend != "dask" else n_jobs
    blas_threads = None if workers in (None, 1) else 1
    # ConvergenceWarning is silenced here, in the calling thread, for all workers (liblinear's own
    # warnings; the filter list is process-global, so per-thread catch_warnings let them through).
    # Unconverged fits are counted from the solvers' iteration counts and reported by the caller
    # in one warning (convergence_warning).
    # With Dask, X is broadcast to the workers once (scatter) and every task refers to that copy.
    with fit_backend(backend, scheduler, scatter=[X]), limit_blas(blas_threads), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        results = Parallel(n_jobs=workers, prefer="threads", return_as="generator")(calls)
        for idx, fitted in zip(members, results):
            for i, (weights, bias, unconverged, n_iter, value) in zip(idx, fitted):
                parts[i] = (weights, bias, columns[i])
                n_classifiers += weights.shape[0]
                n_unconverged += unconverged
                most_iter = max(most_iter, n_iter)
                objective += value
            if progress is not None:
                progress(len(idx))
    from .solvers import choose_solver

    solver = fit_kwargs.get("solver", "auto")
    rows_of = [X.shape[0] if tasks[idx[0]].rows is None else len(tasks[idx[0]].rows) for idx in members]
    used = tuple(sorted({choose_solver(solver, r, len(columns[idx[0]]), len(idx)) for r, idx in zip(rows_of, members)}))
    return parts, FitSummary(n_classifiers, n_unconverged, objective, most_iter, used)
