"""hloc HDF5 files as hostile input (issue 20, findings 2 and 3): external storage, virtual
datasets, links, odd dtypes, declared sizes and damaged files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from btel.descriptors.hdf5 import load_hloc_global
from btel.descriptors.npy import load_descriptor_matrix
from btel.exceptions import DataNotFoundError, InvalidDescriptorsError, ResourceLimitError

h5py = pytest.importorskip("h5py")


def _secret(tmp_path: Path) -> Path:
    path = tmp_path / "secret.bin"
    path.write_bytes(np.arange(64, dtype=np.float32).tobytes())
    return path


def test_external_storage_is_refused_not_read(tmp_path: Path) -> None:
    """A dataset whose bytes live in another local file (the password file in the issue)."""
    secret = _secret(tmp_path)
    with h5py.File(tmp_path / "ext.h5", "w") as fh:
        fh.create_group("db/0.jpg").create_dataset("global_descriptor", shape=(16,), dtype="f4",
                                                    external=[(str(secret), 0, 64)])
    assert (tmp_path / "ext.h5").stat().st_size < 4000
    with pytest.raises(InvalidDescriptorsError, match="external files"):
        load_descriptor_matrix(tmp_path / "ext.h5")


def test_virtual_datasets_and_links_are_refused(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "other.h5", "w") as fh:
        fh.create_dataset("data", data=np.ones((1, 8), dtype=np.float32))
    layout = h5py.VirtualLayout(shape=(8,), dtype="f4")
    layout[:] = h5py.VirtualSource(str(tmp_path / "other.h5"), "data", shape=(1, 8))[0]
    with h5py.File(tmp_path / "vds.h5", "w") as fh:
        fh.create_group("a").create_virtual_dataset("global_descriptor", layout)
    with pytest.raises(InvalidDescriptorsError, match="virtual dataset"):
        load_hloc_global(tmp_path / "vds.h5")
    with h5py.File(tmp_path / "ext_link.h5", "w") as fh:
        fh["a"] = h5py.ExternalLink(str(tmp_path / "other.h5"), "/")
    with pytest.raises(InvalidDescriptorsError, match="external link"):
        load_hloc_global(tmp_path / "ext_link.h5")
    with h5py.File(tmp_path / "soft.h5", "w") as fh:
        fh.create_group("a").create_dataset("global_descriptor", data=np.ones(4, dtype=np.float32))
        fh["b"] = h5py.SoftLink("/a")
    with pytest.raises(InvalidDescriptorsError, match="soft link"):
        load_hloc_global(tmp_path / "soft.h5")


@pytest.mark.parametrize("dtype", ["S8", h5py.string_dtype(), [("a", "f4"), ("b", "f4")], "c8"])
def test_non_numeric_dtypes_are_refused(tmp_path: Path, dtype: object) -> None:
    with h5py.File(tmp_path / "odd.h5", "w") as fh:
        fh.create_group("a").create_dataset("global_descriptor", shape=(3,), dtype=dtype)
    with pytest.raises(InvalidDescriptorsError, match="dtype"):
        load_hloc_global(tmp_path / "odd.h5")


def test_declared_shape_is_checked_before_reading(tmp_path: Path) -> None:
    """A 2.4 KB file declaring 250 M floats (3 GB before): chunked, never written, so tiny on disk."""
    with h5py.File(tmp_path / "big.h5", "w") as fh:
        fh.create_group("a").create_dataset("global_descriptor", shape=(250_000_000,), dtype="f4",
                                            chunks=(1_000_000,), fillvalue=1.0)
    assert (tmp_path / "big.h5").stat().st_size < 10_000
    with pytest.raises(ResourceLimitError, match="BTEL_MEMORY_LIMIT"):
        load_hloc_global(tmp_path / "big.h5")
    with h5py.File(tmp_path / "shape.h5", "w") as fh:
        fh.create_group("a").create_dataset("global_descriptor", shape=(3, 4), dtype="f4")
    with pytest.raises(InvalidDescriptorsError, match=r"shape \(3, 4\)"):
        load_hloc_global(tmp_path / "shape.h5")


def test_damaged_files_name_the_file_and_item(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    with h5py.File(tmp_path / "ok.h5", "w") as fh:
        for i in range(3):
            fh.create_group(f"db/{i}.jpg").create_dataset("global_descriptor", data=rng.normal(size=8).astype("f4"),
                                                          compression="gzip")
    data = bytearray((tmp_path / "ok.h5").read_bytes())
    assert load_hloc_global(tmp_path / "ok.h5")[1] == ["db/0.jpg", "db/1.jpg", "db/2.jpg"]
    errors = 0
    for offset in range(0, len(data), max(1, len(data) // 300)):  # flip bytes all over the file
        bad = bytearray(data)
        bad[offset] ^= 0xFF
        (tmp_path / "bad.h5").write_bytes(bytes(bad))
        try:
            load_hloc_global(tmp_path / "bad.h5")
        except (InvalidDescriptorsError, DataNotFoundError, ResourceLimitError):
            errors += 1
    assert errors > 0  # some flips damage structure; none may escape as a generic exception
    (tmp_path / "text.h5").write_bytes(b"plain text")
    with pytest.raises(InvalidDescriptorsError, match="not a readable HDF5 file"):
        load_hloc_global(tmp_path / "text.h5")
