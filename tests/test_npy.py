"""Memory-mapped descriptor files (issue 34, item 2): never a silent whole copy. A C-ordered float32
``.npy`` stays a view of the file; any other layout or dtype is converted in row blocks when its
float32 copy fits the memory limit, else refused with the command that rewrites it."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.descriptors import npy
from btel.descriptors.npy import load_descriptor_matrix, to_float32_npy
from btel.exceptions import InvalidDescriptorsError, InvalidParameterError, ResourceLimitError


def _sparse_npy(path: Path, dtype: str, fortran: bool, shape: tuple[int, int]) -> Path:
    """An .npy whose data is a hole: gigabytes declared, a few KB on disk."""
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": dtype, "fortran_order": fortran, "shape": shape})
        fh.truncate(fh.tell() + shape[0] * shape[1] * np.dtype(dtype).itemsize)
    return path


@pytest.mark.parametrize("dtype, fortran", [("<f4", True), ("<f8", False), (">f8", True)])
def test_a_large_mapped_file_that_would_be_copied_whole_is_refused_with_the_rewrite(
        tmp_path: Path, dtype: str, fortran: bool) -> None:
    """Issue 34: mmap_mode="r" on a Fortran-order or float64 .npy copied it whole (a sparse 1.2 GB
    file: a bare MemoryError)."""
    rows = 1_200_000_000 // np.dtype(dtype).itemsize // 100
    path = _sparse_npy(tmp_path / "x.npy", dtype, fortran, (rows, 100))
    with pytest.raises(ResourceLimitError, match=r"would copy it whole as C-ordered float32.*to_float32_npy\("
                                                 r"'.*x.npy', '.*x.float32.npy'\)"):
        load_descriptor_matrix(path, mmap_mode="r")


@pytest.mark.parametrize("dtype, fortran", [("<f4", True), ("<f8", False), ("<f8", True), (">i2", False),
                                            ("<u1", True)])
def test_a_small_mapped_file_is_converted_in_blocks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    dtype: str, fortran: bool) -> None:
    X = np.random.default_rng(0).integers(0, 100, size=(37, 5)).astype(dtype)
    np.save(tmp_path / "x.npy", np.asfortranarray(X) if fortran else X)
    monkeypatch.setattr(npy, "_BLOCK_VALUES", 12)  # several blocks of 2 rows
    loaded = load_descriptor_matrix(tmp_path / "x.npy", mmap_mode="r")
    assert loaded.dtype == np.float32 and loaded.flags.c_contiguous and not isinstance(loaded, np.memmap)
    np.testing.assert_array_equal(loaded, X.astype(np.float32))


def test_a_c_ordered_float32_file_stays_a_view(tmp_path: Path) -> None:
    X = np.arange(12, dtype=np.float32).reshape(4, 3)
    np.save(tmp_path / "x.npy", X)
    mapped = load_descriptor_matrix(tmp_path / "x.npy", mmap_mode="r")
    assert isinstance(mapped, np.memmap) or isinstance(mapped.base, np.memmap)


def test_to_float32_npy_rewrites_in_blocks_then_maps_without_a_copy(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    X = np.random.default_rng(1).normal(size=(20_000, 64))
    np.save(tmp_path / "x.npy", np.asfortranarray(X))  # 10 MB of float64
    monkeypatch.setattr(npy, "_BLOCK_VALUES", 1 << 16)
    tracemalloc.start()
    try:
        to_float32_npy(tmp_path / "x.npy", tmp_path / "x32.npy")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 * 2**20, peak  # a few blocks of 64 Ki values, not the 10 MB matrix
    mapped = load_descriptor_matrix(tmp_path / "x32.npy", mmap_mode="r")
    assert isinstance(mapped, np.memmap) or isinstance(mapped.base, np.memmap)
    np.testing.assert_array_equal(mapped, X.astype(np.float32))
    with pytest.raises(InvalidParameterError, match="target other than"):
        to_float32_npy(tmp_path / "x.npy", tmp_path / "x.npy")


def test_train_on_a_large_fortran_file_is_one_line(tmp_path: Path) -> None:
    path = _sparse_npy(tmp_path / "map.npy", "<f4", True, (3_000_000, 100))
    result = CliRunner().invoke(main, ["train", str(path), "-o", str(tmp_path / "m.btel")])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
    assert result.output.count("\n") == 1 and "to_float32_npy" in result.output


def test_float64_values_beyond_float32_are_named(tmp_path: Path) -> None:
    X = np.ones((4, 3))
    X[2, 1] = 1e300
    np.save(tmp_path / "x.npy", X)
    with pytest.raises(InvalidDescriptorsError,
                       match=r"holds 1e\+300 at row 2, column 1, beyond float32's range"):
        load_descriptor_matrix(tmp_path / "x.npy", mmap_mode="r")


def test_float64_values_that_all_underflow_are_named(tmp_path: Path) -> None:
    np.save(tmp_path / "x.npy", np.full((4, 3), 2e-300))
    with pytest.raises(InvalidDescriptorsError, match=r"only values below float32's smallest .*2e-300.*scale the descriptors up"):
        load_descriptor_matrix(tmp_path / "x.npy", mmap_mode="r")
    tiny = np.full((4, 3), 2e-300)
    tiny[3, 2] = 1e-3  # one value that float32 keeps: the file is read (whatever a fit then makes of it)
    np.save(tmp_path / "y.npy", tiny)
    assert load_descriptor_matrix(tmp_path / "y.npy", mmap_mode="r")[3, 2] == np.float32(1e-3)


def test_an_npz_without_arrays_is_named(tmp_path: Path) -> None:
    """Found by the readers' fuzz (desc_npy, seed 0, case 450): an empty archive raised IndexError."""
    import zipfile

    with zipfile.ZipFile(tmp_path / "empty.npz", "w"):
        pass
    with pytest.raises(InvalidDescriptorsError, match="without arrays"):
        load_descriptor_matrix(tmp_path / "empty.npz")


@pytest.mark.realdata
def test_real_descriptors_in_every_layout_map_to_the_same_matrix(gardenspoint_netvlad,
                                                                  tmp_path: Path) -> None:
    """Gardens Point NetVLAD (200 × 500): Fortran-ordered, float64 and C-ordered float32 files all give
    the same float32 matrix memory-mapped; the rewrite maps without a copy."""
    X = gardenspoint_netvlad[0]
    for name, array in (("f.npy", np.asfortranarray(X)), ("d.npy", X.astype(np.float64)), ("c.npy", X)):
        np.save(tmp_path / name, array)
        np.testing.assert_array_equal(load_descriptor_matrix(tmp_path / name, mmap_mode="r"), X)
    to_float32_npy(tmp_path / "f.npy", tmp_path / "f32.npy")
    mapped = load_descriptor_matrix(tmp_path / "f32.npy", mmap_mode="r")
    assert isinstance(mapped, np.memmap) or isinstance(mapped.base, np.memmap)
    np.testing.assert_array_equal(mapped, X)


def test_a_negative_shape_and_an_npz_of_many_arrays_get_short_plain_messages(tmp_path) -> None:
    """A header announcing shape (-1, 64) was "more than the -256 B its shape announces"; an .npz of 1,000 arrays
    listed all 1,000 names in one message."""
    import io

    from btel.descriptors.npy import load_descriptor_matrix
    from btel.exceptions import BTELError

    buf = io.BytesIO()
    np.save(buf, np.zeros((2, 64), dtype=np.float32))
    (tmp_path / "neg.npy").write_bytes(buf.getvalue().replace(b"'shape': (2, 64)", b"'shape': (-1, 64)"))
    with pytest.raises(BTELError, match=r"announcing a negative size, shape \(-1, 64\)"):
        load_descriptor_matrix(tmp_path / "neg.npy")
    np.savez(tmp_path / "many.npz", **{f"a{i}": np.zeros((2, 2), dtype=np.float32) for i in range(1000)})
    with pytest.raises(BTELError) as caught:
        load_descriptor_matrix(tmp_path / "many.npz")
    assert "holds 1000 arrays (a0, a1, a2, a3, a4, a5, a6, a7, …); choose one" in str(caught.value)
    assert len(str(caught.value)) < 300
