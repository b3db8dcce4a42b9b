"""Large maps: memory-mapped descriptors, folders of shards, and fits that never copy X whole."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel import BTELocalizer, load
from btel.core.validation import check_descriptors
from btel.cli import main
from btel.datasets import list_shards, load_shards, synthetic_route
from btel.exceptions import DataNotFoundError, DimensionMismatchError, InvalidDescriptorsError
from btel.learning.feature_selection import between_cluster_ss
from btel.learning.linear import ColumnStats, standardised_columns


@pytest.fixture(scope="module")
def route():
    return synthetic_route(600, 48, n_regions=4, seed=2)


def write_shards(folder: Path, X: np.ndarray, cuts: list[int], names: list[str]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, part in zip(names, np.split(X, cuts)):
        np.save(folder / name, part)


# ----------------------------------------------------------------------------- memory maps
def test_check_descriptors_keeps_a_float32_memmap_mapped(tmp_path: Path, route) -> None:
    np.save(tmp_path / "map.npy", route.map)
    mapped = np.load(tmp_path / "map.npy", mmap_mode="r")
    checked = check_descriptors(mapped)
    assert checked is mapped  # no copy, still backed by the file
    assert isinstance(checked, np.memmap) and not checked.flags.writeable


def test_chunked_finite_check_finds_a_nan_far_down(tmp_path: Path) -> None:
    # 2**22 values per chunk: with d = 64 a chunk is 65,536 rows; put the NaN in the third one.
    X = np.zeros((140_000, 64), dtype=np.float32)
    X[131_075, 7] = np.nan
    np.save(tmp_path / "bad.npy", X)
    with pytest.raises(InvalidDescriptorsError, match="row 131075, column 7"):
        check_descriptors(np.load(tmp_path / "bad.npy", mmap_mode="r"))


def test_fit_on_memmap_equals_fit_in_memory(tmp_path: Path, route) -> None:
    np.save(tmp_path / "map.npy", route.map)
    mapped = np.load(tmp_path / "map.npy", mmap_mode="r")
    params = dict(n_regions=3, feature_ratio=0.25, random_state=0, progress=False)
    a = BTELocalizer(**params).fit(route.map)
    b = BTELocalizer(**params).fit(mapped)
    np.testing.assert_array_equal(a.predict(route.queries), b.predict(route.queries))
    np.testing.assert_array_equal(a.hyperplanes_.weights, b.hyperplanes_.weights)


def test_chunked_statistics_equal_the_whole_array_formulas(route) -> None:
    X = route.map
    labels = np.arange(X.shape[0]) % 3
    # Tiny chunks against one chunk: the same sums, up to float64 rounding.
    np.testing.assert_allclose(between_cluster_ss(X, labels, chunk_rows=7), between_cluster_ss(X, labels),
                               rtol=1e-10, atol=1e-9)
    stats = ColumnStats.of(X)
    cols = np.array([1, 5, 40], dtype=np.intp)
    expected = (X[:, cols].astype(np.float64) - stats.mean[cols]) / stats.scale[cols]
    np.testing.assert_array_equal(
        standardised_columns(X, cols, stats.mean[cols], stats.scale[cols], chunk_rows=50), expected
    )


def test_column_stats_of_a_wide_map_hold_a_bounded_block_not_the_map_in_float64() -> None:
    """At today's widths a fixed row count would be the whole map in float64 (and again its squares)."""
    import tracemalloc

    X = np.random.default_rng(0).normal(size=(2000, 8192)).astype(np.float32)  # 65.5 MB
    tracemalloc.start()
    try:
        stats = ColumnStats.of(X)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 0.6 * X.nbytes  # one float64 block of ≤ 4M values (33.6 MB), not 2 × 131 MB
    X64 = X.astype(np.float64)
    np.testing.assert_allclose(stats.mean, X64.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(stats.scale, X64.std(axis=0), rtol=1e-10)


# ----------------------------------------------------------------------------- shards
def test_load_shards_concatenates_in_natural_order(tmp_path: Path, route) -> None:
    X = route.map
    # shard_10 must come after shard_2 (natural order, not lexicographic).
    write_shards(tmp_path / "shards", X, [100, 350], ["shard_1.npy", "shard_2.npy", "shard_10.npy"])
    (tmp_path / "shards" / "notes.txt").write_text("not a shard")
    assert [p.name for p in list_shards(tmp_path / "shards")] == ["shard_1.npy", "shard_2.npy", "shard_10.npy"]
    Y = load_shards(tmp_path / "shards")
    assert isinstance(Y, np.memmap) and not Y.flags.writeable and Y.dtype == np.float32
    np.testing.assert_array_equal(Y, X)


def test_load_shards_converts_dtypes_and_keeps_out_file(tmp_path: Path, route) -> None:
    X = route.map
    write_shards(tmp_path / "s", X.astype(np.float64), [300], ["a0.npy", "a1.npy"])
    Y = load_shards(tmp_path / "s", out=tmp_path / "merged.npy")
    np.testing.assert_array_equal(Y, X)  # float64 of float32 values round-trips exactly
    np.testing.assert_array_equal(np.load(tmp_path / "merged.npy"), X)


def test_single_shard_is_mapped_without_copy(tmp_path: Path, route) -> None:
    write_shards(tmp_path / "one", route.map, [], ["only.npy"])
    Y = load_shards(tmp_path / "one")
    assert isinstance(Y, np.memmap) and Path(Y.filename) == (tmp_path / "one" / "only.npy").resolve()


def test_temporary_concatenation_is_unlinked(tmp_path: Path, route) -> None:
    write_shards(tmp_path / "s", route.map, [10], ["0.npy", "1.npy"])
    tmp_dir = tmp_path / "tmp"
    tmp_dir.mkdir()
    Y = load_shards(tmp_path / "s", tmp_dir=tmp_dir)
    assert list(tmp_dir.iterdir()) == []  # unlinked at once; the mapping keeps the data
    np.testing.assert_array_equal(Y, route.map)


def test_shard_errors(tmp_path: Path, route) -> None:
    with pytest.raises(DataNotFoundError, match="does not exist"):
        load_shards(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataNotFoundError, match="no .npy shards"):
        load_shards(tmp_path / "empty")
    (tmp_path / "empty" / "000.png").write_bytes(b"")  # an image folder given where descriptors go
    with pytest.raises(DataNotFoundError, match="holds 1 image and no .npy shards: describe them first"):
        load_shards(tmp_path / "empty")
    write_shards(tmp_path / "dims", route.map, [], ["0.npy"])
    np.save(tmp_path / "dims" / "1.npy", np.zeros((5, 7), dtype=np.float32))
    with pytest.raises(DimensionMismatchError, match="1.npy has 7 columns"):
        load_shards(tmp_path / "dims")
    write_shards(tmp_path / "nan", route.map, [], ["0.npy"])
    np.save(tmp_path / "nan" / "1.npy", np.full((3, 48), np.nan, dtype=np.float32))
    with pytest.raises(InvalidDescriptorsError, match="1.npy"):
        load_shards(tmp_path / "nan")


def test_cli_train_accepts_a_shard_folder(tmp_path: Path, route) -> None:
    np.save(tmp_path / "db.npy", route.map)
    write_shards(tmp_path / "shards", route.map, [200, 201, 450], [f"part-{i}.npy" for i in range(4)])
    runner = CliRunner()
    for db, out in ((tmp_path / "db.npy", "a.npz"), (tmp_path / "shards", "b.npz")):
        result = runner.invoke(main, ["train", str(db), "-o", str(tmp_path / out), "--method", "btel-c", "--n-features", "12",
                                      "--seed", "0", "--no-progress"], catch_exceptions=False)
        assert result.exit_code == 0, result.output
        assert "600 places × 48 dims" in result.output
    a, b = load(tmp_path / "a.npz"), load(tmp_path / "b.npz")
    np.testing.assert_array_equal(a.predict(route.queries), b.predict(route.queries))


@pytest.mark.parametrize("entry", ["broken link", "folder", "device", "npz beside", "h5 beside"])
def test_a_shard_that_cannot_be_read_is_refused_not_skipped(tmp_path: Path, route, entry: str) -> None:
    """Skipping shard_1 would give shard_2's rows the place indices of shard_1's: refused, named."""
    folder = tmp_path / "shards"
    write_shards(folder, route.map, [100, 200], ["shard_0.npy", "shard_1.npy", "shard_2.npy"])
    (folder / "shard_1.npy").unlink()
    name = "shard_1.npy"
    if entry == "broken link":
        (folder / name).symlink_to(tmp_path / "missing" / name)
    elif entry == "folder":
        (folder / name).mkdir()
    elif entry == "device":
        (folder / name).symlink_to("/dev/zero")
    else:
        name = "shard_1.npz" if entry == "npz beside" else "shard_1.h5"
        (folder / name).write_bytes(b"not read")
    with pytest.raises(DataNotFoundError, match=name.replace(".", r"\.")):
        list_shards(folder)
