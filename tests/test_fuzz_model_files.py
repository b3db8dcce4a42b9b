"""A short seeded run of the model-file fuzz harness (``benchmarks/fuzz_model_files.py``, issue #13).

Every case is a small fitted model's file with one mutation (bit flips, truncation, header JSON
and array edits, zip container edits), loaded and queried in a worker process: it must be refused
with a ModelFileError, or load and answer places in [0, N) — never another exception, a hang, a
crash of the worker or a place out of range. The long run is the documented command
``python benchmarks/fuzz_model_files.py --cases 50000 --seed 0`` (README, "Model files").
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

HARNESS_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "fuzz_model_files.py"


@pytest.fixture(scope="module")
def harness():
    spec = importlib.util.spec_from_file_location("fuzz_model_files", HARNESS_PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_seeded_fuzz_run_finds_no_failure(harness) -> None:
    summary = harness.run_cases(300, seed=13, workers=1)
    assert summary["cases"] == 300
    failures = "\n".join(f"case {f['id']} ({f['fixture']}, {f['kind']}: {f['description']}): {f['outcome']} "
                         f"{f['error']}" for f in summary["failed_cases"][:10])
    assert summary["failures"] == 0, failures
    # The run exercised every kind of mutation and both passing outcomes.
    assert set(summary["by_kind"]) == set(harness.KINDS)
    assert summary["outcomes"].get("rejected", 0) > 0 and summary["outcomes"].get("loaded", 0) > 0


def test_cases_are_reproducible_from_their_seed(harness, tmp_path) -> None:
    originals = {"a": _small_model_file(tmp_path)}
    cases = [harness.make_case(5, i, ["a"], originals) for i in range(20)]
    assert cases == [harness.make_case(5, i, ["a"], originals) for i in range(20)]
    assert len({data for _, _, data, _ in cases}) > 10  # and they differ from case to case


def _small_model_file(tmp_path: Path) -> bytes:
    from btel.methods.baselines import BruteForceNN

    X = np.random.default_rng(0).standard_normal((20, 8)).astype(np.float32)
    return BruteForceNN().fit(X).save(tmp_path / "m.npz").read_bytes()


@pytest.mark.parametrize(
    ("behaviour", "outcome"),
    [("minus-one", "out_of_range"), ("value-error", "exception"), ("refuse", "rejected"), ("fine", "loaded")],
)
def test_the_harness_tells_failures_from_passes(behaviour, outcome, harness, tmp_path, monkeypatch) -> None:
    """The harness can fail: an answer of −1 or a generic exception is counted as a failure."""
    import btel
    from btel.exceptions import ModelFileError

    path = tmp_path / "m.npz"
    path.write_bytes(_small_model_file(tmp_path))
    real = btel.load(path)
    Q = np.random.default_rng(1).standard_normal((3, 8)).astype(np.float32)

    def fake_load(p):
        if behaviour == "refuse":
            raise ModelFileError("bad file")
        if behaviour == "value-error":
            raise ValueError("generic")
        if behaviour == "minus-one":
            monkeypatch.setattr(real, "predict", lambda Q: np.full(len(Q), -1, dtype=np.int64))
        return real

    monkeypatch.setattr(btel, "load", fake_load)
    assert harness.run_case(str(path), Q)["outcome"] == outcome
