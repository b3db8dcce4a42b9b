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


# -- issue 34: link structures, chunk bombs, plugin filters ---------------------------------------------
def _hloc_group(fh, name: str = "db/a.jpg"):
    group = fh.create_group(name)
    group.create_dataset("global_descriptor", data=np.ones(8, dtype=np.float32))
    return group


@pytest.mark.parametrize("links", [("loop",), ("x", "y")])
def test_a_group_linked_into_itself_is_refused_by_name(tmp_path: Path, links: tuple[str, ...]) -> None:
    """Issue 34: ``g["loop"] = g`` never finished; ``g["x"] = g; g["y"] = g`` grew to 2.1 GB."""
    with h5py.File(tmp_path / "loop.h5", "w") as fh:
        group = _hloc_group(fh)
        for link in links:
            group[link] = group
    for load in (load_hloc_global, load_descriptor_matrix):
        message = rf"'db/a.jpg/{links[0]}' links to 'db/a.jpg', already reached \(a link cycle\)"
        with pytest.raises(InvalidDescriptorsError, match=message):
            load(tmp_path / "loop.h5")


def test_the_root_linked_below_itself_and_a_group_under_two_names_are_refused(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "root.h5", "w") as fh:
        _hloc_group(fh)
        fh["db/up"] = fh
    with pytest.raises(InvalidDescriptorsError, match=r"'db/up' links to '/'.*link cycle"):
        load_hloc_global(tmp_path / "root.h5")
    with h5py.File(tmp_path / "twice.h5", "w") as fh:
        fh["db/b.jpg"] = _hloc_group(fh)  # one descriptor under two image names: not a cycle, still refused
    with pytest.raises(InvalidDescriptorsError, match="already reached; hloc files are trees"):
        load_hloc_global(tmp_path / "twice.h5")


def test_deep_nesting_is_refused(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "deep.h5", "w") as fh:
        _hloc_group(fh, "/".join(["g"] * 70))
    with pytest.raises(InvalidDescriptorsError, match="more than 64 deep"):
        load_hloc_global(tmp_path / "deep.h5")
    with h5py.File(tmp_path / "ok.h5", "w") as fh:  # hloc's own nesting (one group per "/") is read
        _hloc_group(fh, "db/seq1/cam0/0001.jpg")
    assert load_hloc_global(tmp_path / "ok.h5")[1] == ["db/seq1/cam0/0001.jpg"]


def test_a_chunk_larger_than_the_limit_is_refused_before_it_is_inflated(tmp_path: Path, monkeypatch) -> None:
    """Issue 34: 8 values in one gzip chunk of 2²⁸ values (a 1 MB file) inflated to 1.19 GB. The same
    file in small: a 1 MiB limit and a chunk of 2¹⁸ float32 (1 MiB + 4 B would be allowed for the data)."""
    with h5py.File(tmp_path / "chunk.h5", "w") as fh:
        fh.create_group("db/a.jpg").create_dataset("global_descriptor", data=np.ones(8, dtype=np.float32),
                                                   maxshape=(None,), chunks=(2**19,), compression="gzip")
    assert (tmp_path / "chunk.h5").stat().st_size < 20_000
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "1M")
    with pytest.raises(ResourceLimitError, match=r"one chunk of shape \(524288,\), decompressed whole"):
        load_hloc_global(tmp_path / "chunk.h5")
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "16M")  # the same file under a limit that holds the chunk
    assert load_hloc_global(tmp_path / "chunk.h5")[0].shape == (1, 8)


def test_a_chunk_that_stores_more_than_it_declares_is_refused(tmp_path: Path, monkeypatch) -> None:
    """HDF5 inflates a stored gzip stream as far as it goes, whatever the chunk declares: a chunk
    of 8 floats storing 1 GiB of compressed zeros (a 4.7 MB file) read 1.2 GB and answered. Here in
    small: 16 MiB of zeros in a chunk of 8 values, under a 8 MiB limit."""
    import zlib

    with h5py.File(tmp_path / "lie.h5", "w") as fh:
        ds = fh.create_group("db/a.jpg").create_dataset("global_descriptor", shape=(8,), dtype="f4",
                                                        chunks=(8,), compression="gzip")
        ds.id.write_direct_chunk((0,), zlib.compress(b"\0" * (16 << 20)), 0)
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "8M")
    with pytest.raises(ResourceLimitError, match=r"a chunk of \d+ stored bytes, gzip-inflated"):
        load_hloc_global(tmp_path / "lie.h5")


def test_filters_other_than_gzip_shuffle_fletcher32_are_refused(tmp_path: Path) -> None:
    from h5py import h5d, h5p, h5s, h5t, h5z

    with h5py.File(tmp_path / "plugin.h5", "w") as fh:
        group = fh.create_group("a")
        dcpl = h5p.create(h5p.DATASET_CREATE)
        dcpl.set_chunk((8,))
        dcpl.set_filter(32015, h5z.FLAG_OPTIONAL, (3,))  # zstd, optional so that writing works without it
        space = h5s.create_simple((8,))
        dataset = h5py.Dataset(h5d.create(group.id, b"global_descriptor", h5t.IEEE_F32LE, space, dcpl=dcpl))
        dataset[...] = np.ones(8, dtype=np.float32)
    with pytest.raises(InvalidDescriptorsError,
                       match="filter 32015; btel reads gzip, shuffle and fletcher32 only"):
        load_hloc_global(tmp_path / "plugin.h5")
    with h5py.File(tmp_path / "lzf.h5", "w") as fh:  # built in, but sized by the file's own parameters
        fh.create_group("a").create_dataset("global_descriptor", data=np.ones(8, np.float32),
                                            compression="lzf")
    with pytest.raises(InvalidDescriptorsError, match="filter 32000"):
        load_hloc_global(tmp_path / "lzf.h5")


def test_gzip_shuffle_and_fletcher32_chunks_are_read(tmp_path: Path) -> None:
    X = np.random.default_rng(0).normal(size=(3, 256)).astype(np.float32)
    with h5py.File(tmp_path / "ok.h5", "w") as fh:
        for i, row in enumerate(X):
            fh.create_group(f"db/{i}.jpg").create_dataset("global_descriptor", data=row, compression="gzip",
                                                          shuffle=True, fletcher32=True)
    np.testing.assert_array_equal(load_hloc_global(tmp_path / "ok.h5")[0], X)


def test_a_long_or_control_character_name_is_shown_escaped_and_short(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "name.h5", "w") as fh:
        fh.create_group("a\nb" + "x" * 500).create_dataset("global_descriptor", shape=(3,), dtype="S8")
    with pytest.raises(InvalidDescriptorsError) as info:
        load_hloc_global(tmp_path / "name.h5")
    assert "\n" not in str(info.value) and "'a\\nbxxx" in str(info.value) and len(str(info.value)) < 400


def test_a_file_of_many_empty_groups_is_walked_holding_names_not_objects(tmp_path: Path) -> None:
    """10⁶ empty groups (162 MB) took 2.16 GB: every group waited on the stack as an open h5py object and
    every object was remembered. Groups now wait by name; only objects with several names are kept."""
    import tracemalloc

    import h5py

    path = tmp_path / "groups.h5"
    with h5py.File(path, "w", libver="latest") as fh:
        for i in range(20_000):
            fh.create_group(f"g{i}")
        for i in range(3):
            fh.create_dataset(f"img{i}.jpg/global_descriptor", data=np.full(16, i, np.float32))
    tracemalloc.start()
    X, names = load_hloc_global(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert names == ["img0.jpg", "img1.jpg", "img2.jpg"] and X.shape == (3, 16)
    assert peak < 8 * 2**20  # 14 MiB before (≈ 700 B a group), 3 MiB now
