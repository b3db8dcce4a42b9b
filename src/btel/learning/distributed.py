"""Where a model's classifier fits run: local threads, local processes, or a Dask cluster.

Every fit of a BTEL model — the bit classifiers, the per-region trees and the region classifier —
is an independent task that goes through one ``joblib.Parallel`` (:func:`btel.learning.training.fit_tasks`).
This module picks the joblib backend for that call:

- ``None`` (default): whatever the caller configured with ``joblib.parallel_config``, else threads
  (liblinear releases the GIL, and threads share X without copying it);
- ``"threads"``: joblib's threading backend;
- ``"loky"``: worker processes on this machine (joblib memory-maps X into them);
- ``"dask"``: the workers of a running Dask cluster. X is scattered to every worker once
  (broadcast) and each task then refers to it, so it is not shipped with every task.

Dask is an optional extra (``pip install btel[dask]``); it is imported only when asked for.

Examples
--------
>>> model = BTELocalizer(backend="dask", scheduler="tcp://10.0.0.5:8786")  # doctest: +SKIP
>>> with dask_backend("tcp://10.0.0.5:8786"):                               # doctest: +SKIP
...     model = BTELocalizer().fit(X)        # the same, for any code that uses joblib
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator, Sequence

from ..exceptions import InvalidParameterError, MissingDependencyError

__all__ = ["BACKENDS", "check_backend", "dask_backend", "fit_backend", "require_distributed"]

#: Backends accepted by ``BTELocalizer(backend=...)`` and ``btel train --backend`` (None = default).
BACKENDS = ("threads", "loky", "dask")

_INSTALL_HINT = "Dask is an optional extra: install it with `pip install btel[dask]`."


def require_distributed() -> Any:
    """Import and return the ``distributed`` package, or raise :class:`MissingDependencyError`."""
    try:
        import distributed
    except ImportError as exc:
        raise MissingDependencyError(f"backend 'dask' needs dask.distributed, which is not installed. {_INSTALL_HINT}") from exc
    return distributed


def check_backend(backend: str | None, scheduler: str | None) -> None:
    """Validate a (backend, scheduler) pair; raise :class:`InvalidParameterError` if they do not fit."""
    if backend is not None and backend not in BACKENDS:
        raise InvalidParameterError(f"backend must be None or one of {BACKENDS}; got {backend!r}.")
    if scheduler is not None:
        if backend != "dask":
            raise InvalidParameterError(
                f"scheduler={scheduler!r} only applies to backend='dask' (got backend={backend!r})."
            )
        if not isinstance(scheduler, str) or not scheduler:
            raise InvalidParameterError(
                f"scheduler must be a Dask scheduler address such as 'tcp://10.0.0.5:8786'; got {scheduler!r}."
            )


@contextmanager
def _client(scheduler: str | None) -> Iterator[Any]:
    """A Client connected to ``scheduler`` (closed on exit), or the process' current default Client."""
    distributed = require_distributed()
    if scheduler is None:
        try:
            client = distributed.get_client()
        except ValueError as exc:
            raise InvalidParameterError(
                "backend='dask' without a scheduler address needs a running dask.distributed Client in this "
                "process; create one (`Client('tcp://host:8786')`) or pass scheduler='tcp://host:8786'."
            ) from exc
        yield client
        return
    try:
        client = distributed.Client(scheduler, set_as_default=False)
    except OSError as exc:
        raise OSError(f"cannot connect to the Dask scheduler at {scheduler!r}: {exc}") from exc
    try:
        yield client
    finally:
        client.close()


@contextmanager
def dask_backend(scheduler: str | None = None, *, scatter: Sequence[Any] | None = None) -> Iterator[Any]:
    """Run every joblib call inside the block (btel's fits included) on a Dask cluster.

    Parameters
    ----------
    scheduler : str, optional
        Scheduler address, e.g. ``'tcp://10.0.0.5:8786'`` (``LocalCluster().scheduler_address`` for
        a local one). None uses the Client already created in this process.
    scatter : sequence of arrays, optional
        Large arguments to send to every worker once, up front; tasks that receive the same
        objects then refer to the workers' copies.

    Yields
    ------
    client : distributed.Client
    """
    from joblib import parallel_config  # fit-only: a loaded model never imports joblib

    with _client(scheduler) as client, parallel_config(
        backend="dask", n_jobs=-1, client=client, scatter=list(scatter) if scatter else None
    ):
        yield client


@contextmanager
def fit_backend(backend: str | None, scheduler: str | None = None, *, scatter: Sequence[Any] = ()) -> Iterator[None]:
    """The joblib configuration for one model fit (see the module docstring for the choices).

    Parameters
    ----------
    backend : {None, 'threads', 'loky', 'dask'}
    scheduler : str, optional
        Dask scheduler address (``backend='dask'`` only).
    scatter : sequence of arrays
        With Dask, arrays every task reads (the descriptor matrix): broadcast to the workers once.
    """
    check_backend(backend, scheduler)
    if backend is None:
        yield
    elif backend == "dask":
        with dask_backend(scheduler, scatter=scatter):
            yield
    else:
        from joblib import parallel_config

        with parallel_config(backend="threading" if backend == "threads" else "loky"):
            yield
