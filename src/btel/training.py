"""Running many independent classifier fits: one joblib call for every method.

A :class:`Task` is one classifier to learn: which rows of X it sees and their labels. BTE-C makes
b tasks per tree, BTE-F one per internal node, the region classifier one multiclass task. All of
a model's tasks go through a single ``joblib.Parallel`` so that both cores (or every worker of a
Dask cluster: ``backend="dask"``, see :mod:`btel.distributed`) stay busy across regions. Threads
are the default backend: liblinear releases the GIL and threads share X without copying it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from joblib import Parallel, delayed
from sklearn.exceptions import ConvergenceWarning
from threadpoolctl import threadpool_limits

from .distributed import fit_backend
from .feature_selection import select_features
from .linear import ColumnStats, fit_linear

__all__ = ["Task", "fit_tasks", "one_vs_rest_tasks"]


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

    The d' columns are chosen once with the n_classes-cluster BCSS (SPEC §4); two classes give one
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


def _fit_task(X, task: Task, n_selected, stats, sparsity, fit_kwargs):
    Xt = X if task.rows is None else X[task.rows]
    columns = task.columns
    if columns is None:
        columns = select_features(Xt, task.labels, n_selected, sparsity=sparsity, scale=stats.scale)
    weights, bias, converged = fit_linear(Xt, task.labels, columns, stats, sample_weight=task.sample_weight,
                                          **fit_kwargs)
    return weights, bias, columns, converged


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
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], int]:
    """Select features for and fit every task, in parallel, keeping the task order.

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
        Where the fits run (:func:`btel.distributed.fit_backend`); None keeps the caller's joblib
        configuration (threads by default).
    scheduler : str, optional
        Dask scheduler address for ``backend='dask'`` (None: the current Client).
    progress : callable, optional
        Called with 1 after each fitted task (e.g. ``tqdm.update``).
    **fit_kwargs
        classifier, C, max_iter, random_state, dtype — see :func:`btel.linear.fit_linear`.

    Returns
    -------
    parts : list of (weights (k, d'), bias (k,), columns (d',)), one per task
    n_unconverged : int
        Fits that stopped at max_iter.
    """
    calls = (delayed(_fit_task)(X, task, n_selected, stats, sparsity, fit_kwargs) for task in tasks)
    parts = []
    n_unconverged = 0
    # Parallel fits each get one BLAS thread: BLAS's own threads on top of ours oversubscribe the
    # cores and made two workers slower than one in measurements on a 2-core machine.
    blas_threads = None if n_jobs in (None, 1) else 1
    # ConvergenceWarning is silenced here, in the calling thread, for all workers: fit_linear's own
    # catch_warnings is not thread-safe (the filter list is process-global), so with threads it
    # let warnings through. Unconverged fits are counted from n_iter_ instead.
    # With Dask, X is broadcast to the workers once (scatter) and every task refers to that copy.
    with fit_backend(backend, scheduler, scatter=[X]), threadpool_limits(limits=blas_threads, user_api="blas"), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for weights, bias, columns, converged in Parallel(
            n_jobs=n_jobs, prefer="threads", return_as="generator"
        )(calls):
            parts.append((weights, bias, columns))
            n_unconverged += not converged
            if progress is not None:
                progress(1)
    return parts, n_unconverged
