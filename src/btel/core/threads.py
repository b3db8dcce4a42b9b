"""Every limit btel puts on BLAS and faiss threads, in one module.

Both pools are process-wide: OpenBLAS' (through threadpoolctl) and faiss' OpenMP
(``faiss.omp_set_num_threads``). btel changes them only inside a ``with`` block and restores
them afterwards; it never sets OpenMP environment variables (``OMP_WAIT_POLICY`` and the like
change every library in the process, the benchmarks' peers included).

**Single queries run on one thread.** A faiss search of fewer than :data:`SINGLE_QUERY_MAX`
queries (the size below which faiss' flat search does not use BLAS either) runs on one OpenMP
thread unless the caller asks for more (``n_jobs``): waking and joining worker threads costs more
than a small search (``benchmarks/bench_codes.py`` times faiss' flat search both ways).
"""

from __future__ import annotations

import contextlib
import os
from typing import Any, Iterator

from ..exceptions import InvalidParameterError

__all__ = ["SINGLE_QUERY_MAX", "GEMV_ONE_THREAD_BELOW", "blas_threads", "blas_threads_for_vector", "one_blas_thread", "faiss_threads",
           "faiss_module", "search_threads", "limit_threads", "check_n_jobs", "load_average"]

#: Searches of fewer queries than this run faiss on one thread unless ``n_jobs`` says otherwise.
SINGLE_QUERY_MAX = 20
#: OpenBLAS computes a matrix-vector product of fewer multiply-adds than this on one thread
#: (115 200 × its default GEMM_MULTITHREAD_THRESHOLD of 4, interface/gemv.c). Measured with numpy's
#: OpenBLAS 0.3.30 here: (1, d) @ (d, K) took the same time with and without a one-thread limit
#: up to 459 684 multiply-adds and started threads from 461 041 (and under load a 972 000 one
#: took 20 ms on two threads against 49 µs on one).
GEMV_ONE_THREAD_BELOW = 460_800

_CONTROLLER: Any = None


def _controller() -> Any:
    global _CONTROLLER
    if _CONTROLLER is None:  # inspecting the loaded libraries costs milliseconds: once per process
        from threadpoolctl import ThreadpoolController

        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER


_BLAS_LIBS: list | None = None


def _blas_libs() -> list:
    """threadpoolctl's controllers of the loaded BLAS libraries (found once)."""
    global _BLAS_LIBS
    if _BLAS_LIBS is None:
        _BLAS_LIBS = list(_controller().select(user_api="blas").lib_controllers)
    return _BLAS_LIBS


_ACTIVE_LIMIT: int | None = None  # the innermost blas_threads limit in force (nested blocks are free)


class _BlasLimit:
    """Context limiting BLAS to ``limit`` threads (a class, not a generator: it runs per query)."""

    __slots__ = ("limit", "outer", "before")

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.before: list[int] | None = None

    def __enter__(self) -> None:
        global _ACTIVE_LIMIT
        if _ACTIVE_LIMIT is not None and _ACTIVE_LIMIT <= self.limit:
            return  # an enclosing block already limits BLAS at least as much
        limit, libs = self.limit, _blas_libs()
        self.before = before = [lib.num_threads for lib in libs]
        self.outer, _ACTIVE_LIMIT = _ACTIVE_LIMIT, limit
        for lib, n in zip(libs, before):
            if n > limit:
                lib.set_num_threads(limit)

    def __exit__(self, *exc: Any) -> None:
        global _ACTIVE_LIMIT
        if self.before is None:
            return
        _ACTIVE_LIMIT = self.outer
        limit = self.limit
        for lib, n in zip(_blas_libs(), self.before):
            if n > limit:
                lib.set_num_threads(n)
        self.before = None


def blas_threads(limit: int | None) -> Any:
    """A context running BLAS on at most ``limit`` threads (None: leave BLAS alone).

    Calls the libraries' own get/set functions through threadpoolctl's controllers found once:
    ``threadpool_limits`` inspects every loaded library on each call (≈ 70 µs, as much as a
    single btel-codes query).
    """
    if limit is None:
        return contextlib.nullcontext()
    return _BlasLimit(int(limit))


def blas_threads_for_vector(largest_product: int) -> Any:
    """One BLAS thread for one query's matrix-vector products, unless BLAS would use one anyway.

    ``largest_product``: multiply-adds of the largest product (rows × columns of its matrix).
    Below :data:`GEMV_ONE_THREAD_BELOW` OpenBLAS runs a matrix-vector product on one thread by
    itself, so no limit is set (setting and restoring it costs ≈ 4–5 µs, as much as the product).
    """
    if largest_product < GEMV_ONE_THREAD_BELOW:
        return contextlib.nullcontext()
    return _BlasLimit(1)


def one_blas_thread() -> Any:
    """A context that runs BLAS on one thread (see :func:`blas_threads`)."""
    return blas_threads(1)


def check_n_jobs(n_jobs: Any) -> None:
    """:class:`~btel.exceptions.InvalidParameterError` unless ``n_jobs`` is None, −1 or a positive int."""
    if n_jobs is not None and (isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs == 0
                               or n_jobs < -1):
        raise InvalidParameterError(f"n_jobs must be None, -1 (all cores) or a positive integer; got {n_jobs!r}.")


class faiss_threads:  # noqa: N801 (a context used like a function, as before)
    """Run faiss with ``n_jobs`` OpenMP threads inside the block (None: leave faiss' setting).

    ``-1`` means every core. The setting is process-wide while the block runs and is restored afterwards.
    A class, not a generator: it runs per query, and sets nothing where faiss already has that many threads.
    """

    __slots__ = ("wanted", "previous")

    def __init__(self, n_jobs: int | None) -> None:
        if not (type(n_jobs) is int and n_jobs >= 1):  # the common case (a single query's 1): nothing more
            check_n_jobs(n_jobs)
        self.wanted = None if n_jobs is None else (os.cpu_count() or 1) if n_jobs == -1 else n_jobs
        self.previous: int | None = None

    def __enter__(self) -> None:
        if self.wanted is None:
            return
        faiss = _FAISS or faiss_module()
        previous = faiss.omp_get_max_threads()
        if previous != self.wanted:
            faiss.omp_set_num_threads(self.wanted)
            self.previous = previous

    def __exit__(self, *exc: Any) -> None:
        if self.previous is not None:
            faiss_module().omp_set_num_threads(self.previous)
            self.previous = None


_FAISS: Any = None


def faiss_module() -> Any:
    """The faiss module, imported at first use (it is not needed to load the package)."""
    global _FAISS
    if _FAISS is None:
        import faiss

        _FAISS = faiss
    return _FAISS


def search_threads(n_jobs: int | None, n_queries: int) -> int | None:
    """faiss threads for a search of ``n_queries``: ``n_jobs`` if given, else 1 below :data:`SINGLE_QUERY_MAX`."""
    if n_jobs is not None:
        return n_jobs
    return 1 if n_queries < SINGLE_QUERY_MAX else None


@contextlib.contextmanager
def limit_threads(n: int | None) -> Iterator[None]:
    """Every loaded BLAS and OpenMP library, faiss' included, limited to ``n`` threads inside the block
    (None: their defaults).

    The libraries are inspected afresh on entry (threadpoolctl, ~ms: this block wraps whole runs, not
    single queries), so a library loaded after the first query (scikit-learn's OpenMP, scipy's
    BLAS) is limited too and the reported thread count is the one in force.
    """
    if n is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=int(n)), faiss_threads(n), blas_threads(n):
        yield


#: The pool of chunked batch prediction (made at first use, kept).
_PREDICT_POOL: Any = None


_PREDICT_THREADS: int | None = None


def predict_threads() -> int:
    """Cores this process may use (its CPU affinity at first call), at most 8."""
    global _PREDICT_THREADS
    if _PREDICT_THREADS is None:
        import os

        try:
            _PREDICT_THREADS = min(8, len(os.sched_getaffinity(0)))
        except AttributeError:  # not on Linux
            _PREDICT_THREADS = min(8, os.cpu_count() or 1)
    return _PREDICT_THREADS


def predict_pool(n_threads: int) -> Any:
    """One thread pool for chunked batch prediction, made at first use and kept."""
    global _PREDICT_POOL
    if _PREDICT_POOL is None or _PREDICT_POOL._max_workers != n_threads:
        from concurrent.futures import ThreadPoolExecutor

        _PREDICT_POOL = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="btel-predict")
    return _PREDICT_POOL


def max_threads() -> int:
    """The largest thread count any loaded numerical library (BLAS, OpenMP) may use."""
    try:
        from threadpoolctl import threadpool_info

        counts = [int(info.get("num_threads") or 0) for info in threadpool_info()]
    except Exception:  # noqa: BLE001 - a description of the machine, never a reason to fail a run
        counts = []
    return max(counts, default=0) or (os.cpu_count() or 1)


#: Environment variables that set the numerical libraries' thread pools (recorded by :func:`thread_settings`).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")


def thread_settings() -> dict[str, Any]:
    """The thread pools a run starts with: the variables of :data:`THREAD_VARIABLES` that are set, and
    every loaded BLAS/OpenMP library with its version and threads (threadpoolctl's ``threadpool_info``)."""
    from threadpoolctl import threadpool_info

    libraries = [{k: info.get(k) for k in ("user_api", "internal_api", "version", "num_threads")}
                 for info in threadpool_info()]
    return {"environment": {k: os.environ[k] for k in THREAD_VARIABLES if k in os.environ}, "libraries": libraries}


def load_average() -> list[float] | None:
    """The machine's load average over 1, 5 and 15 minutes (None where the system has none): beside the
    core count it says whether a run's times are those of an idle machine."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        return None
