"""One memory limit for what an input may make btel allocate (issue 20, findings 3 and 5)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import btel
from btel.exceptions import InvalidParameterError, ModelFileError, ResourceLimitError
from btel.core.limits import DEFAULT_MEMORY_LIMIT, check_bytes, check_places, memory_limit
from btel.core.modelfile import load_arrays, save_arrays


@pytest.mark.parametrize(("text", "expected"), [("", DEFAULT_MEMORY_LIMIT), ("1024", 1024), ("4G", 4 * 2**30),
                                                ("512M", 512 * 2**20), ("2GiB", 2 * 2**30), ("8k", 8192)])
def test_limit_from_the_environment(monkeypatch: pytest.MonkeyPatch, text: str, expected: int) -> None:
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", text)
    assert memory_limit() == expected


@pytest.mark.parametrize("text", ["-1", "0", "lots", "1e9", "4X", "9" * 30])
def test_a_bad_limit_is_named(monkeypatch: pytest.MonkeyPatch, text: str) -> None:
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", text)
    with pytest.raises(InvalidParameterError, match="BTEL_MEMORY_LIMIT"):
        memory_limit()


def test_checks_name_the_input_and_the_way_out() -> None:
    check_bytes(DEFAULT_MEMORY_LIMIT, "x")
    for n in (DEFAULT_MEMORY_LIMIT + 1, float("inf"), float("nan"), 10.0**300):
        with pytest.raises(ResourceLimitError, match="the thing would need .* BTEL_MEMORY_LIMIT=4G"):
            check_bytes(n, "the thing")
    check_places(1_000_000, "a model")
    with pytest.raises(ResourceLimitError, match="N = 4294967296"):
        check_places(2**32, "a model")


@pytest.fixture(scope="module")
def huge_n_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A small BTE-C file whose header claims N = 2³² places (issue: 32 GiB MemoryError under --hmm)."""
    folder = tmp_path_factory.mktemp("hugeN")
    X = np.random.default_rng(0).normal(size=(64, 16)).astype(np.float32)
    path = btel.make_method("btel-c").fit(X).save(folder / "m.btel")
    arrays, header = load_arrays(path)
    header["state"]["n_places"] = 2**32
    save_arrays(folder / "huge.btel", arrays, header)
    np.save(folder / "q.npy", X[:4])
    return folder / "huge.btel", folder / "q.npy"


def test_a_model_claiming_two_to_the_32_places_fails_at_load(huge_n_file: tuple[Path, Path]) -> None:
    path, _ = huge_n_file
    assert path.stat().st_size < 20_000
    start = time.perf_counter()
    with pytest.raises(ModelFileError, match="N = 4294967296 places .*BTEL_MEMORY_LIMIT"):
        btel.load(path)
    assert time.perf_counter() - start < 10  # a hang guard, not a timing figure


@pytest.mark.parametrize("extra", [[], ["--hmm"]])
def test_localize_reports_it_in_one_line(huge_n_file: tuple[Path, Path], extra: list[str]) -> None:
    path, queries = huge_n_file
    out = str(queries.with_suffix(".csv"))
    proc = subprocess.run([sys.executable, "-m", "btel.cli", "localize", str(path), str(queries), "-o", out, *extra],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "BTEL_MEMORY_LIMIT" in proc.stderr


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_load_on_a_fifo_does_not_block(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "model.btel")
    result: list[BaseException] = []

    def run() -> None:
        try:
            btel.load(tmp_path / "model.btel")
        except BaseException as exc:  # noqa: BLE001 - recorded for the assertion
            result.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(10)
    if thread.is_alive():  # unblock the reader so the test process can end
        with open(tmp_path / "model.btel", "wb"):
            pass
        pytest.fail("btel.load blocked on a FIFO")
    assert isinstance(result[0], ModelFileError) and "not a regular file" in str(result[0])


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs resource limits (POSIX)")
def test_more_shards_than_open_files_allowed(tmp_path: Path) -> None:
    """> ~1017 shards failed under `ulimit -n 1024` with 'not a readable .npy' (one open map each)."""
    folder = tmp_path / "shards"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(300):
        np.save(folder / f"shard_{i}.npy", rng.normal(size=(2, 4)).astype(np.float32))
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (128, 128));"
            "from btel.datasets.shards import load_shards; X = load_shards(sys.argv[1]); print(X.shape)")
    proc = subprocess.run([sys.executable, "-c", code, str(folder)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-500:]
    assert proc.stdout.strip() == "(600, 4)"
