"""btel.core.threads: the one place that limits BLAS and faiss threads; single queries on one faiss thread."""

from __future__ import annotations

import faiss
import numpy as np
import pytest
from threadpoolctl import threadpool_info

from btel.methods.baselines import BruteForceNN as BruteForce
from btel.exceptions import InvalidParameterError
from btel.core.threads import (GEMV_ONE_THREAD_BELOW, SINGLE_QUERY_MAX, blas_threads, blas_threads_for_vector, faiss_threads,
                          limit_threads, search_threads)


def _blas_counts() -> list[int]:
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


def test_blas_limit_is_applied_and_restored() -> None:
    before = _blas_counts()
    with blas_threads(1):
        assert all(n == 1 for n in _blas_counts())
    assert _blas_counts() == before
    with blas_threads(None):
        assert _blas_counts() == before


def test_nested_limits_and_one_query_products_below_the_gemv_threshold() -> None:
    before = _blas_counts()
    with blas_threads_for_vector(GEMV_ONE_THREAD_BELOW - 1):  # BLAS uses one thread anyway: nothing set
        assert _blas_counts() == before
    with blas_threads_for_vector(GEMV_ONE_THREAD_BELOW):
        assert all(n == 1 for n in _blas_counts())
        with blas_threads(1), blas_threads(2):  # inside a tighter limit: nothing changes
            assert all(n == 1 for n in _blas_counts())
        assert all(n == 1 for n in _blas_counts())
    assert _blas_counts() == before


def test_faiss_and_both_limits_are_restored() -> None:
    before = faiss.omp_get_max_threads()
    with faiss_threads(1):
        assert faiss.omp_get_max_threads() == 1
    with limit_threads(1):
        assert faiss.omp_get_max_threads() == 1 and all(n == 1 for n in _blas_counts())
    assert faiss.omp_get_max_threads() == before
    with pytest.raises(InvalidParameterError, match="n_jobs"):
        with faiss_threads(0):
            pass


def test_single_queries_run_on_one_faiss_thread_unless_asked() -> None:
    assert search_threads(None, 1) == 1 and search_threads(None, SINGLE_QUERY_MAX) is None
    assert search_threads(2, 1) == 2
    X = np.random.default_rng(0).normal(size=(300, 16)).astype(np.float32)
    seen: list[int] = []
    for n_jobs, rows, expected in ((None, 1, 1), (None, 50, faiss.omp_get_max_threads()), (2, 1, 2)):
        model = BruteForce(n_jobs=n_jobs).fit(X)
        search = model._search_rows

        def spy(Q, k, scores=True, search=search):
            seen.append(faiss.omp_get_max_threads())
            return search(Q, k, scores)

        model._search_rows = spy
        model.predict(X[:rows])
        assert seen[-1] == expected, (n_jobs, rows, seen)


def test_limit_threads_limits_every_loaded_library_even_one_loaded_late() -> None:
    """The "threads" a run reports is the one in force: libraries loaded after the first BLAS limit
    (scikit-learn's OpenMP, scipy's BLAS) are limited too."""
    from threadpoolctl import threadpool_info

    from btel.core.threads import blas_threads, limit_threads, max_threads

    with blas_threads(1):  # the BLAS controllers are found here, once per process
        pass
    import sklearn.cluster  # noqa: F401 - loads scikit-learn's OpenMP runtime (if not loaded yet)
    import scipy.linalg  # noqa: F401

    with limit_threads(1):
        counts = {info["filepath"]: info["num_threads"] for info in threadpool_info()}
        assert set(counts.values()) == {1}, counts
        assert max_threads() == 1
