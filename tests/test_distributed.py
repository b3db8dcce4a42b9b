"""Training on a Dask cluster (and the other joblib backends) gives the model a local fit gives."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel import BTELocalizer, load
from btel.cli import main
from btel.datasets import synthetic_route
from btel.learning.distributed import dask_backend, fit_backend
from btel.exceptions import InvalidParameterError, MissingDependencyError

try:
    import distributed
except ImportError:  # the missing-dependency tests below still run
    distributed = None

needs_dask = pytest.mark.skipif(distributed is None, reason="dask.distributed is not installed (pip install btel[dask])")

# Three regions: the region classifier (one-vs-rest tasks) and per-region trees all run remotely.
PARAMS = dict(n_regions=3, feature_ratio=0.5, random_state=0, progress=False)


@pytest.fixture(scope="module")
def route():
    return synthetic_route(400, 64, n_regions=4, seed=0)


@pytest.fixture(scope="module")
def local_model(route) -> BTELocalizer:
    return BTELocalizer(**PARAMS).fit(route.map)


@pytest.fixture(scope="module")
def cluster():
    # Worker *processes*: X really travels to other processes. (liblinear's dual solver draws from
    # one process-wide random generator, so two fits running in threads of one process can give
    # different roundings; separate processes, like a real cluster's workers, cannot interfere.)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster:
        yield cluster


def assert_same_model(a: BTELocalizer, b: BTELocalizer, Q: np.ndarray) -> None:
    np.testing.assert_array_equal(a.predict(Q), b.predict(Q))
    np.testing.assert_array_equal(a.region_starts_, b.region_starts_)
    for name, array in a._stored_arrays().items():
        np.testing.assert_array_equal(array, b._stored_arrays()[name], err_msg=name)


@needs_dask
def test_dask_cluster_fit_equals_local_fit(route, local_model, cluster) -> None:
    remote = BTELocalizer(**PARAMS, backend="dask", scheduler=cluster.scheduler_address).fit(route.map)
    assert remote.n_regions_ == 3
    assert_same_model(local_model, remote, route.queries)


@needs_dask
def test_cli_train_on_dask_cluster(route, local_model, cluster, tmp_path: Path) -> None:
    np.save(tmp_path / "db.npy", route.map)
    result = CliRunner().invoke(main, [
        "train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"), "--method", "btel-r", "--regions", "3",
        "--feature-ratio", "0.5", "--seed", "0", "--backend", "dask", "--scheduler", cluster.scheduler_address,
    ], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert_same_model(local_model, load(tmp_path / "m.npz"), route.queries)


@needs_dask
def test_dask_backend_context_manager_uses_the_current_client(route, local_model) -> None:
    # One in-process worker thread: fits run one at a time, so the result must match exactly.
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as local, distributed.Client(local) as client:
        with dask_backend() as used:  # no address: the Client created above
            assert used is client
            model = BTELocalizer(**PARAMS).fit(route.map)
        assert_same_model(local_model, model, route.queries)
        # backend='dask' without scheduler also picks up the running Client.
        assert_same_model(local_model, BTELocalizer(**PARAMS, backend="dask").fit(route.map), route.queries)


def test_loky_worker_processes_equal_the_default(route, local_model) -> None:
    # Two worker processes (with n_jobs=1 joblib would not start any).
    model = BTELocalizer(**PARAMS, backend="loky", n_jobs=2).fit(route.map)
    assert_same_model(local_model, model, route.queries)


@needs_dask
def test_dask_without_client_names_the_fix(route) -> None:
    with pytest.raises(InvalidParameterError, match="scheduler="):
        BTELocalizer(**PARAMS, backend="dask").fit(route.map[:50])


def test_missing_dask_says_how_to_install(route, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # makes `import distributed` fail
    with pytest.raises(MissingDependencyError, match=r"pip install btel\[dask\]"):
        BTELocalizer(**PARAMS, backend="dask", scheduler="tcp://127.0.0.1:1").fit(route.map[:50])


def test_cli_missing_dask_is_a_one_line_error(route, monkeypatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)
    np.save(tmp_path / "db.npy", route.map[:60])
    result = CliRunner().invoke(main, ["train", str(tmp_path / "db.npy"), "-o", str(tmp_path / "m.npz"),
                                       "--method", "btel-c", "--backend", "dask", "--scheduler", "tcp://127.0.0.1:1"])
    assert result.exit_code == 1
    assert "pip install btel[dask]" in result.stderr and "Traceback" not in result.output


@pytest.mark.parametrize(
    "backend, scheduler, message",
    [
        ("spark", None, "backend must be"),
        ("threads", "tcp://127.0.0.1:8786", "only applies with backend='dask'"),
        ("dask", "", "scheduler must be"),
    ],
)
def test_bad_backend_parameters(route, backend, scheduler, message: str) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        BTELocalizer(**PARAMS, backend=backend, scheduler=scheduler).fit(route.map[:50])


def test_fit_backend_none_leaves_the_callers_joblib_config_alone() -> None:
    import joblib

    with joblib.parallel_config(backend="threading", n_jobs=3):
        with fit_backend(None):
            assert joblib.parallel.get_active_backend()[1] == 3
