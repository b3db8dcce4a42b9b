"""A short seeded run of the readers' fuzz harness (``benchmarks/fuzz_readers.py``, issues 20 and 34).

Every case is a seed file (legitimate or one of the issues' crafted files) with seeded mutations, or
a case of one of issue 34's structure-aware families (HDF5 link graphs and chunk shapes, image
headers, UTM ring geometries, image names), read in a worker process: it must be read or refused
with a btel error — never another exception, a broken invariant, a hang, a crash or more than
1 GiB. The long run is the documented command ``python benchmarks/fuzz_readers.py --cases 20000
--seed 0`` (README, "Security").
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

HARNESS_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_readers.py"


@pytest.fixture(scope="module")
def harness():
    spec = importlib.util.spec_from_file_location("fuzz_readers", HARNESS_PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_seeded_fuzz_run_finds_no_failure(harness) -> None:
    summary = harness.run_cases(25, seed=11, timeout=20.0)
    assert set(summary["readers"]) == set(harness.READERS)
    failures = [f"{reader} case {f['id']} ({f['case']}): {f['outcome']} {f['error']}"
                for reader, r in summary["readers"].items() for f in r["failed_cases"]]
    assert summary["failures"] == 0, "\n".join(failures[:10])
    for reader, r in summary["readers"].items():
        assert r["cases"] == 25 and r["outcomes"].get("refused", 0) > 0, (reader, r["outcomes"])
        assert r["outcomes"].get("ok", 0) > 0, (reader, r["outcomes"])  # the legitimate seeds are read


def test_cases_are_reproducible_and_differ(harness) -> None:
    seeds = harness.seeds_gt_csv()
    cases = [harness.make_case("gt_csv", 5, i, seeds) for i in range(30)]
    assert cases == [harness.make_case("gt_csv", 5, i, seeds) for i in range(30)]
    assert len({data for data, _, _ in cases}) > 20


def test_issue_34_families_make_cases(harness, tmp_path) -> None:
    """Each structure-aware family builds cases (not only byte mutations of seeds), reproducibly."""
    kinds = {}
    for reader, marks in (("hdf5", ("link graph", "chunk (")), ("image", ("png ", "jpeg ", "tiff ")),
                          ("gt_utm", ("ring ",)), ("names", ("hloc names", "sidecar"))):
        seeds = harness.build_seeds(reader, tmp_path)
        cases = [harness.make_case(reader, 0, i, seeds) for i in range(len(seeds), len(seeds) + 60)]
        kinds[reader] = {mark: sum(mark in description for _, description, _ in cases) for mark in marks}
        again = [harness.make_case(reader, 0, i, seeds) for i in range(len(seeds), len(seeds) + 5)]
        assert cases[:5] == again
    assert all(n > 0 for marks in kinds.values() for n in marks.values()), kinds


def test_a_worker_started_by_a_large_process_is_measured_by_its_own_peak(harness, monkeypatch) -> None:
    """ru_maxrss survives exec: a worker spawned by a pytest process that had once held more than the
    limit counted every case as a memory failure (a CI run: gt_pickle 25 of 25)."""
    import numpy as np

    big = np.ones(50_000_000)  # 400 MB touched: this process' peak is now above the limit set below
    del big
    monkeypatch.setattr(harness, "MAX_RSS_BYTES", 300 << 20)
    summary = harness.run_cases(3, seed=11, readers=("gt_pickle",), timeout=20.0)
    outcomes = summary["readers"]["gt_pickle"]["outcomes"]
    assert "memory" not in outcomes, outcomes
    assert summary["readers"]["gt_pickle"]["peak_worker_rss_mib"] < 300
