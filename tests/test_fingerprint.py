"""btel.core.fingerprint: a model file records the rows it was fitted on, and says when a map is another one."""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

import btel
from btel.cli import main
from btel.core import fingerprint as fp
from btel.core.modelfile import HEADER_KEY, load_arrays
from btel.exceptions import ModelFileError


def _rows(n: int = 120, d: int = 24, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, d)).astype(np.float32)


def test_the_digest_is_sha256_of_the_rows_as_float32_in_c_order() -> None:
    X = _rows()
    expected = hashlib.sha256(np.ascontiguousarray(X, dtype="<f4")).hexdigest()
    assert fp.map_fingerprint(X) == {"rows": 120, "dims": 24, "sha256": expected}
    # The same rows in another layout or dtype that holds them exactly: the same map.
    assert fp.map_fingerprint(np.asfortranarray(X))["sha256"] == expected
    assert fp.map_fingerprint(X.astype(np.float64))["sha256"] == expected
    assert fp.map_fingerprint(X[::-1])["sha256"] != expected  # the order of the rows is the places' order


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 40), d=st.integers(1, 9), block=st.integers(1, 200))
def test_the_digest_does_not_depend_on_the_block_it_is_read_in(n: int, d: int, block: int) -> None:
    X = _rows(n, d, seed=n * 10 + d)
    whole = fp.map_fingerprint(X)
    saved = fp._BLOCK_BYTES
    try:
        fp._BLOCK_BYTES = block
        assert fp.map_fingerprint(X) == whole
    finally:
        fp._BLOCK_BYTES = saved


def test_a_memory_mapped_map_gives_the_digest_of_its_rows(tmp_path: Path) -> None:
    X = _rows()
    np.save(tmp_path / "db.npy", X)
    assert fp.map_fingerprint(np.load(tmp_path / "db.npy", mmap_mode="r")) == fp.map_fingerprint(X)


def test_same_map() -> None:
    X = _rows()
    recorded = fp.map_fingerprint(X)
    assert fp.same_map(recorded, X) is True
    assert fp.same_map(recorded, X[:-1]) is False
    Y = X.copy()
    Y[7, 3] += 1e-3
    assert fp.same_map(recorded, Y) is False
    assert fp.same_map(None, X) is None


@pytest.mark.parametrize("value", [
    [], "abc", {"rows": 1, "dims": 2}, {"rows": 1, "dims": 2, "sha256": "0" * 63},
    {"rows": True, "dims": 2, "sha256": "0" * 64}, {"rows": 0, "dims": 2, "sha256": "0" * 64},
    {"rows": 3, "dims": 2, "sha256": "A" * 64}, {"rows": 3, "dims": 2, "sha256": "0" * 64, "x": 1},
    {"rows": 3.0, "dims": 2, "sha256": "0" * 64}, {"rows": 2**70, "dims": 2, "sha256": "0" * 64},
])
def test_a_malformed_fingerprint_is_refused(value: object) -> None:
    with pytest.raises(ModelFileError, match="map fingerprint is malformed"):
        fp.read_fingerprint(value)


def _rewrite_header(path: Path, edit) -> None:
    """The model file at ``path`` with its JSON header changed by ``edit`` (arrays kept byte for byte)."""
    arrays, header = load_arrays(path)
    edit(header)
    raw = np.frombuffer(json.dumps(header).encode("utf-8"), dtype=np.uint8)
    with zipfile.ZipFile(path, "w") as archive:
        for name, a in {HEADER_KEY: raw, **arrays}.items():
            with archive.open(f"{name}.npy", "w") as fh:
                np.lib.format.write_array(fh, np.asarray(a))


def test_a_model_file_with_an_edited_fingerprint_is_refused_and_an_old_one_loads(tmp_path: Path) -> None:
    X = _rows()
    path = btel.make_method("lsh", budget="2KB").fit(X).save(tmp_path / "m.npz")
    _rewrite_header(path, lambda h: h.__setitem__("map", {"rows": 1, "dims": 1, "sha256": "not hex"}))
    with pytest.raises(ModelFileError, match="map fingerprint is malformed"):
        btel.load(path)
    _rewrite_header(path, lambda h: h.pop("map"))  # a file saved before btel recorded its map
    assert btel.load(path).map_fingerprint_ is None
    result = CliRunner().invoke(main, ["info", str(path)])
    assert result.exit_code == 0 and "fitted on not recorded" in result.output


def test_btel_info_shows_the_map_and_evaluate_says_when_a_model_was_fitted_on_another(tmp_path: Path) -> None:
    X, other = _rows(seed=1), _rows(seed=2)
    np.save(tmp_path / "db.npy", X)
    np.save(tmp_path / "other.npy", other)
    np.save(tmp_path / "q.npy", X + 0.01)
    runner = CliRunner()
    for name in ("db", "other"):
        result = runner.invoke(main, ["train", str(tmp_path / f"{name}.npy"), "--method", "lsh", "--budget", "2KB",
                                      "-o", str(tmp_path / f"{name}.npz")])
        assert result.exit_code == 0, result.output
    digest = hashlib.sha256(np.ascontiguousarray(X, dtype="<f4")).hexdigest()
    result = runner.invoke(main, ["info", str(tmp_path / "db.npz")])
    assert f"fitted on 120 rows × 24 values, sha256 {digest[:16]}…" in result.output
    args = ["evaluate", "--db", str(tmp_path / "db.npy"), "--queries", str(tmp_path / "q.npy"), "--methods", "lsh",
            "--budget", "2KB"]
    result = runner.invoke(main, [*args, "--model", str(tmp_path / "other.npz"), "--out", str(tmp_path / "r1")])
    assert result.exit_code == 0, result.output
    assert "note: model other was fitted on other map rows" in result.output
    result = runner.invoke(main, [*args, "--model", str(tmp_path / "db.npz"), "--out", str(tmp_path / "r2")])
    assert result.exit_code == 0, result.output
    assert "other map rows" not in result.output


@pytest.mark.realdata
def test_a_model_of_the_gardens_point_map_records_its_rows(gardenspoint_netvlad, tmp_path: Path) -> None:
    X, Q = gardenspoint_netvlad
    model = btel.make_method("auto", budget="16KB").fit(X)
    again = btel.load(model.save(tmp_path / "gp.npz"))
    assert again.map_fingerprint_ == {"rows": 200, "dims": 500,
                                      "sha256": hashlib.sha256(np.ascontiguousarray(X, dtype="<f4")).hexdigest()}
    assert fp.same_map(again.map_fingerprint_, X) and not fp.same_map(again.map_fingerprint_, Q)
