"""How long a fitted method takes to answer queries, measured so that runs agree.

:func:`time_queries` warms up, repeats, takes medians and limits the numerical libraries' threads;
:func:`btel.evaluation.evaluate` reports what it measures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.threads import limit_threads, max_threads

__all__ = ["QueryTiming", "time_queries"]


@dataclass(frozen=True)
class QueryTiming:
    """How long a fitted method takes to answer queries, measured so that runs agree.

    Attributes
    ----------
    batch_s_per_query : float
        Median over ``repeats`` timed ``predict(Q)`` calls on every query (after a warm-up call),
        divided by the number of queries: throughput when the queries come as one batch.
    latency_s : float or None
        Median wall time of one query answered alone (``stream().search`` — what a robot runs —
        or ``predict`` on one row), over ``n_single`` queries after a few warm-up queries. None when
        the method answers batches only.
    n_threads : int
        Threads the numerical libraries (BLAS, OpenMP) may use during the measurement.
    repeats : int
        Timed batch calls behind the median.
    n_single : int
        Queries behind the latency median.
    """

    batch_s_per_query: float
    latency_s: float | None
    n_threads: int
    repeats: int
    n_single: int


def time_queries(method: Any, Q: np.ndarray, *, repeats: int = 5, n_single: int = 50, warmup: int = 1,
                 max_seconds: float = 10.0, threads: int | None = 1) -> tuple[np.ndarray, QueryTiming]:
    """Localize ``Q`` with a fitted ``method`` and time it: warm-up first, then repeats, medians.

    One un-warmed batch call is not a timing: the first call pays for page faults, lazy
    allocations and thread start-up (a 100× spread between identical runs). Here the first
    ``warmup`` calls are not timed, the batch is then timed ``repeats`` times (fewer once the timed
    calls pass ``max_seconds``; at least one) and the median is reported; single-query latency is
    timed separately, one query at a time.

    Parameters
    ----------
    method : fitted estimator with ``predict``
    Q : ndarray of shape (n_queries, n_features)
    repeats : int, default 5
        Timed batch calls. 0 times the one call that gives the predictions (no warm-up, no
        single-query latency): the cheapest honest figure, for sweeps that fit hundreds of rows.
    n_single : int, default 50
        Queries timed one at a time (the first ones of ``Q``); 0 skips the latency.
    warmup : int, default 1
        Untimed batch calls before the timed ones (the predictions come from the first).
    max_seconds : float, default 10
        Stop repeating once the timed batch calls have taken this long.
    threads : int or None, default 1
        BLAS and faiss threads while localizing and timing (:func:`btel.core.threads.limit_threads`). One thread by default:
        on a shared machine multi-threaded BLAS and faiss calls spin against other processes, and
        identical runs then differ by 2–100× (benchmarks/bench_timing_stability.py); one thread
        gives figures that repeat. None leaves the libraries' own setting.

    Returns
    -------
    predictions : ndarray of shape (n_queries,)
        ``method.predict(Q)`` as returned (from the first call).
    timing : QueryTiming
    """
    if threads is not None:
        with limit_threads(int(threads)):
            return _time_queries(method, Q, repeats, n_single, warmup, max_seconds)
    return _time_queries(method, Q, repeats, n_single, warmup, max_seconds)


def _time_queries(method: Any, Q: np.ndarray, repeats: int, n_single: int, warmup: int,
                  max_seconds: float) -> tuple[np.ndarray, QueryTiming]:
    n_queries = Q.shape[0]
    if repeats <= 0:
        start = time.perf_counter()
        predictions = method.predict(Q)
        elapsed = time.perf_counter() - start
        return predictions, QueryTiming(batch_s_per_query=elapsed / n_queries, latency_s=None,
                                        n_threads=max_threads(), repeats=1, n_single=0)
    predictions = method.predict(Q)
    for _ in range(max(0, warmup - 1)):
        method.predict(Q)
    times: list[float] = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        method.predict(Q)
        times.append(time.perf_counter() - start)
        if sum(times) > max_seconds:
            break
    latency, n_timed = _single_query_latency(method, Q, min(n_single, n_queries), max_seconds)
    timing = QueryTiming(batch_s_per_query=float(np.median(times)) / n_queries, latency_s=latency,
                         n_threads=max_threads(), repeats=len(times), n_single=n_timed)
    return predictions, timing


def _single_query_latency(method: Any, Q: np.ndarray, n: int, max_seconds: float) -> tuple[float | None, int]:
    """Median seconds of one query answered alone, over up to ``n`` queries (after 3 untimed ones)."""
    if n <= 0:
        return None, 0
    if callable(getattr(method, "stream", None)):
        stream = method.stream()

        def one(i: int) -> None:
            stream.search(Q[i])
    elif getattr(method, "uses_query_sequence", False):
        return None, 0  # one row alone is not the same question for a sequence method without a stream
    else:
        def one(i: int) -> None:
            method.predict(Q[i:i + 1])
    for i in range(min(3, n)):
        one(i)
    if callable(getattr(method, "stream", None)):
        stream = method.stream()  # the timed traverse starts afresh
    times: list[float] = []
    for i in range(n):
        start = time.perf_counter()
        one(i)
        times.append(time.perf_counter() - start)
        if sum(times) > max_seconds:
            break
    return float(np.median(times)), len(times)
