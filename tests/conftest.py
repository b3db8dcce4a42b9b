"""Shared fixtures. Real-data tests read ../shared/data beside the project.

When ../shared is absent the real-data tests are skipped with a reason, except under CI
(``CI`` or ``BTEL_REQUIRE_SHARED`` set), where a missing data folder fails the run: CI always
has ../shared, so a skip there would hide untested capabilities.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

# OpenMP threads that spin while waiting made faiss k-means 6× slower when two test workers share
# two cores; passive waiting keeps results identical and the suite fast. Set before faiss loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("BTEL_SHARED_DATA", PROJECT_ROOT.parent / "shared" / "data"))


def _require_shared(sub: str) -> Path:
    path = SHARED_DATA / sub
    if not path.exists():
        message = f"real data not found at {path} (expected ../shared/data beside the project)"
        if os.environ.get("CI") or os.environ.get("BTEL_REQUIRE_SHARED"):
            pytest.fail(message + "; CI must run the real-data tests")
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path to ../shared/data (skips, or fails under CI, when absent)."""
    return _require_shared("")


@pytest.fixture(scope="session")
def nordland_dir() -> Path:
    """Path to ../shared/data/nordland64 (folders summer/ and winter/)."""
    return _require_shared("nordland64")


@pytest.fixture(scope="session")
def gardenspoint_sample_dir() -> Path:
    """Path to ../shared/data/gardenspoint_sample (folders ref/ and query/)."""
    return _require_shared("gardenspoint_sample")


@pytest.fixture(scope="session")
def gardenspoint_netvlad() -> tuple[np.ndarray, np.ndarray]:
    """(map, queries) 500-D descriptors for 200 Gardens Point places, float32."""
    from btel.datasets.sources import load_gardens_point_netvlad

    return load_gardens_point_netvlad(_require_shared("gardenspoint_netvlad").parent)


def _read_grey_pixels(folder: Path, step: int) -> np.ndarray:
    import cv2

    files = sorted(folder.glob("images-*.png"))[::step]
    rows = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE).astype(np.float32).ravel() / 255.0 for f in files]
    return np.stack(rows)


@pytest.fixture(scope="session")
def nordland_pixels(nordland_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(summer, winter) flattened 64×32 grey pixels of every Nordland frame, float32 in [0, 1]."""
    return _read_grey_pixels(nordland_dir / "summer", 1), _read_grey_pixels(nordland_dir / "winter", 1)


@pytest.fixture(autouse=True)
def _an_idle_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test sees an idle machine: a run prints a note when the load average exceeds the cores, and a
    test's output must not depend on what else this machine runs (tests/test_runs.py checks the note)."""
    import btel.evaluation.runs as runs

    monkeypatch.setattr(runs, "load_average", lambda: [0.0, 0.0, 0.0])


# --- CI guard: a real-data test that was skipped under CI fails the run -----------------------
_skipped_realdata: list[str] = []


@pytest.fixture
def map_types(monkeypatch: pytest.MonkeyPatch):
    """``map_types(cls, "_fit")``: a list that records the type name of the map each call of that method
    receives (which form the front end handed a method's fit: an ndarray or lazily scaled rows)."""
    def record(cls: type, name: str) -> list[str]:
        seen: list[str] = []
        original = getattr(cls, name)

        def spy(self, X, *args, **kwargs):
            seen.append(type(X).__name__)
            return original(self, X, *args, **kwargs)

        monkeypatch.setattr(cls, name, spy)
        return seen

    return record


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.skipped and "realdata" in report.keywords:
        _skipped_realdata.append(report.nodeid)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if _skipped_realdata and (os.environ.get("CI") or os.environ.get("BTEL_REQUIRE_SHARED")):
        print(f"\nCI: {len(_skipped_realdata)} real-data test(s) were skipped; CI must run them all:")
        for nodeid in _skipped_realdata:
            print(f"  {nodeid}")
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@contextlib.contextmanager
def _file_lock(path: Path):
    """An exclusive lock across pytest-xdist workers (so a shared cache is computed once)."""
    with open(path, "w") as fh:
        try:
            import fcntl

            fcntl.flock(fh, fcntl.LOCK_EX)
        except ImportError:  # pragma: no cover - non-POSIX: no lock, at worst computed twice
            pass
        yield


@pytest.fixture(scope="session")
def nordland_hog(nordland_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(summer, winter) HOG descriptors (3576 × 3780) of every Nordland frame, through btel's pipeline.

    Extracted once with btel.descriptors.extract.extract_cached into a cache shared by the test
    workers (``BTEL_TEST_CACHE``, default <tmp>/btel-test-cache); the cache is keyed on the image
    files and descriptor parameters, so a changed pipeline or data set is recomputed.
    """
    from btel.descriptors.extract import extract_cached

    cache = Path(os.environ.get("BTEL_TEST_CACHE", Path(tempfile.gettempdir()) / "btel-test-cache"))
    cache.mkdir(parents=True, exist_ok=True)
    with _file_lock(cache / "nordland-hog.lock"):
        out = [extract_cached(nordland_dir / s, cache / f"nordland64-{s}-hog.npy", "hog", progress=False)[0]
               for s in ("summer", "winter")]
    return out[0], out[1]


@pytest.fixture()
def extracted(tmp_path: Path) -> tuple[Path, Path]:
    """(image folder of four 32×64 PNGs, side/db.npy written by extract_cached with its PATH.json record)."""
    import cv2

    from btel.descriptors.extract import extract_cached
    from btel.descriptors.hog import HOGDescriptor

    images = tmp_path / "imgs"
    images.mkdir()
    rng = np.random.default_rng(0)
    for i in range(4):
        cv2.imwrite(str(images / f"{i:02d}.png"), rng.integers(0, 255, (32, 64), dtype=np.uint8))
    out = tmp_path / "side" / "db.npy"
    extract_cached(images, out, HOGDescriptor(), progress=False)
    return images, out


@pytest.fixture()
def bruteforce_files(tmp_path: Path):  # noqa: ANN201
    """``make(n_places, dim, model_name)`` → (db.npy, q.npy, model): a random map, queries a little noise away,
    and a brute-force model of the map trained by ``btel train`` (for the CLI's input-handling tests)."""
    from click.testing import CliRunner

    from btel.cli import main

    def make(n_places: int, dim: int, model_name: str) -> tuple[Path, Path, Path]:
        rng = np.random.default_rng(0)
        X = rng.standard_normal((n_places, dim)).astype(np.float32)
        db, q, model = tmp_path / "db.npy", tmp_path / "q.npy", tmp_path / model_name
        np.save(db, X)
        np.save(q, X + 0.01 * rng.standard_normal(X.shape).astype(np.float32))
        trained = CliRunner().invoke(main, ["train", str(db), "-o", str(model), "--method", "bruteforce"])
        assert trained.exit_code == 0, trained.output
        return db, q, model

    return make

