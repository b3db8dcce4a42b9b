"""Ground-truth files as hostile input (issue 20, findings 3 and 9): tiny files that asked for
gigabytes, generic exceptions, FIFOs. Each crafted file is a few hundred bytes."""

from __future__ import annotations

import io
import os
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from btel.datasets import GroundTruth
from btel.exceptions import DataNotFoundError, InvalidParameterError, ResourceLimitError


def test_csv_with_a_huge_query_index_is_refused_before_allocating(tmp_path: Path) -> None:
    (tmp_path / "big.csv").write_text("query,positive\n1000000000000,1\n")  # 31 bytes (MemoryError before)
    with pytest.raises(ResourceLimitError, match="BTEL_MEMORY_LIMIT"):
        GroundTruth.from_file(tmp_path / "big.csv")
    # With the query count known (evaluate's queries), the index past the last query is the problem named.
    with pytest.raises(InvalidParameterError, match=r"lists query 1000000000000, but there are only 200 query rows"):
        GroundTruth.from_file(tmp_path / "big.csv", n_queries=200)
    (tmp_path / "huge.csv").write_text("query,positive\n" + "9" * 5000 + ",1\n")
    with pytest.raises(DataNotFoundError, match="line 2"):
        GroundTruth.from_file(tmp_path / "huge.csv")


@pytest.mark.parametrize("cell", ["1_0", "\u0661", "-1", "+1", "1.0", "0x1", " 1e3"])
def test_csv_indices_are_ascii_digits_only(tmp_path: Path, cell: str) -> None:
    (tmp_path / "odd.csv").write_text(f"query,positive\n0,{cell}\n", encoding="utf-8")
    with pytest.raises(DataNotFoundError, match="line 2"):
        GroundTruth.from_file(tmp_path / "odd.csv")


def test_csv_field_too_large_and_binary_are_data_errors(tmp_path: Path) -> None:
    (tmp_path / "field.csv").write_text('query,positives\n0,"' + "1 " * 70000 + '\n')
    with pytest.raises(DataNotFoundError, match="line 2: field larger than field limit .*one pair per line"):
        GroundTruth.from_file(tmp_path / "field.csv")
    (tmp_path / "bin.csv").write_bytes(b"query,positive\n\xff\xfe\x00\x01\n")
    with pytest.raises(DataNotFoundError, match="UnicodeDecodeError"):
        GroundTruth.from_file(tmp_path / "bin.csv")


@pytest.mark.parametrize("text, where", [
    ("query,positive\n0,7,0\n1,8\n", "line 2"),          # a place after a comma: a third column
    ("query,positive,distance\n0,7,1.5\n", "header"),    # an extra column of the header
    ("query,positives\n0,7;9,3\n", "line 2"),
])
def test_csv_with_more_than_two_columns_is_refused_not_truncated(tmp_path: Path, text: str, where: str) -> None:
    """The third column was dropped without a word (its places lost: recall 0 for a true match)."""
    (tmp_path / "extra.csv").write_text(text)
    with pytest.raises(DataNotFoundError, match=f"{where}.*two"):
        GroundTruth.from_file(tmp_path / "extra.csv")
    (tmp_path / "trailing.csv").write_text("query,positive,\n0,7,\n")  # an empty third field: no place lost
    assert GroundTruth.from_file(tmp_path / "trailing.csv").positives(0).tolist() == [7]


def test_csv_pairs_still_read_in_any_order(tmp_path: Path) -> None:
    (tmp_path / "pairs.csv").write_text("query,positive\n2,7\n0,6\n0,5\n3,\n")
    gt = GroundTruth.from_file(tmp_path / "pairs.csv")
    assert [gt.positives(j).tolist() for j in range(4)] == [[5, 6], [], [7], []]


def test_identical_positions_are_counted_before_pairs_are_built(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """20,000 identical points with posDistThr=0 asked for 4·10⁸ pairs from a 1,259-byte .npz."""
    utm = np.zeros((20000, 2))
    np.savez_compressed(tmp_path / "same.npz", utmDb=utm, utmQ=utm, posDistThr=np.float64(0.0))
    assert (tmp_path / "same.npz").stat().st_size < 2000
    start = time.perf_counter()
    with pytest.raises(ResourceLimitError, match="query-place pairs"):
        GroundTruth.from_file(tmp_path / "same.npz")
    assert time.perf_counter() - start < 20  # a hang guard, not a timing figure
    # Under a raised limit a small version is computed in chunks and matches the brute force.
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "64K")
    rng = np.random.default_rng(0)
    db, q = rng.uniform(0, 50, (300, 2)), rng.uniform(0, 50, (40, 2))
    gt = GroundTruth.from_utm(db, q, 4.0)
    dist = np.linalg.norm(q[:, None] - db[None], axis=2)
    assert all(gt.positives(j).tolist() == np.flatnonzero(dist[j] <= 4.0).tolist() for j in range(40))


def test_array_valued_posdistthr_and_n_map_are_named(tmp_path: Path) -> None:
    np.savez(tmp_path / "thr.npz", utmDb=np.zeros((3, 2)), utmQ=np.zeros((2, 2)), posDistThr=np.array([1.0, 2.0]))
    with pytest.raises(DataNotFoundError, match="posDistThr must be one number"):
        GroundTruth.from_file(tmp_path / "thr.npz")
    with pytest.raises(InvalidParameterError, match="posDistThr must be one distance"):
        GroundTruth.from_utm(np.zeros((3, 2)), np.zeros((2, 2)), np.array([1.0, 2.0]))
    np.savez(tmp_path / "nmap.npz", query_places=np.array([0, 1]), n_map=np.array([1e300]))
    with pytest.raises(DataNotFoundError, match="n_map"):
        GroundTruth.from_file(tmp_path / "nmap.npz")


def _npz_declaring(path: Path, shape: tuple[int, ...]) -> None:
    """An .npz whose member header declares ``shape`` float64 but holds a few bytes."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("utmDb.npy", header.getvalue() + b"\0" * 64)


def test_npz_declared_sizes_are_checked_before_reading(tmp_path: Path) -> None:
    _npz_declaring(tmp_path / "decl.npz", (250_000_000, 2))
    with pytest.raises(ResourceLimitError, match="ground-truth file"):
        GroundTruth.from_file(tmp_path / "decl.npz")
    # A zip bomb: 400 MB of zeros compressed into a small file.
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("query_places.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array_header_1_0(member, {"descr": "<i8", "fortran_order": False,
                                                          "shape": (50_000_000,)})
            chunk = b"\0" * (1 << 22)
            for _ in range(100):
                member.write(chunk)
    assert (tmp_path / "bomb.npz").stat().st_size < 1_000_000
    with pytest.raises(ResourceLimitError, match="decompressed"):
        GroundTruth.from_file(tmp_path / "bomb.npz")


def test_damaged_npz_and_npy_are_data_errors(tmp_path: Path) -> None:
    from btel.descriptors.npy import load_descriptor_matrix
    from btel.exceptions import InvalidDescriptorsError

    np.savez(tmp_path / "ok.npz", query_places=np.arange(5))
    data = bytearray((tmp_path / "ok.npz").read_bytes())
    (tmp_path / "cut.npz").write_bytes(bytes(data[: len(data) // 2]))
    (tmp_path / "badzip.npz").write_bytes(b"PK\x03\x04" + b"\0" * 40)
    (tmp_path / "junk.npy").write_bytes(b"\x93NUMPY\x01\x00\x10\x00{'descr': <<<}   \n")
    central = data.rindex(b"PK\x01\x02")  # 'version needed to extract' 25.5: zipfile's NotImplementedError
    data[central + 6:central + 8] = (255).to_bytes(2, "little")
    (tmp_path / "version.npz").write_bytes(bytes(data))
    for name in ("cut.npz", "badzip.npz", "junk.npy", "version.npz"):
        with pytest.raises(DataNotFoundError):
            GroundTruth.from_file(tmp_path / name)
        with pytest.raises((InvalidDescriptorsError, DataNotFoundError)):
            load_descriptor_matrix(tmp_path / name)


def test_mat_declared_sizes_are_checked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    scipy.io.savemat(tmp_path / "big.mat", {"utmDb": np.zeros((200_000, 2)), "utmQ": np.zeros((2, 2)),
                                            "posDistThr": 1.0}, do_compression=True)
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "1M")
    with pytest.raises(ResourceLimitError, match="MATLAB"):
        GroundTruth.from_file(tmp_path / "big.mat")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    for name in ("gt.npy", "gt.csv", "gt.mat"):
        os.mkfifo(tmp_path / name)
        with pytest.raises(DataNotFoundError, match="not a regular file"):
            GroundTruth.from_file(tmp_path / name)


# -- issue 34: ring geometries, counts before geometry, .mat inflation in pieces --------------------------
def _ring(n_map: int, radius: float = 100.0) -> np.ndarray:
    angle = np.linspace(0, 2 * np.pi, n_map, endpoint=False)
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def test_a_ring_for_other_counts_is_refused_before_any_geometry(tmp_path: Path) -> None:
    """Issue 34: 50,000 map points on a ring, 4,000,000 queries at its centre, the threshold just under
    the radius (a 721 KB .npz) kept the KD-tree busy for hours, while the evaluation had 50 queries."""
    np.savez_compressed(tmp_path / "ring.npz", utmDb=_ring(50_000), utmQ=np.zeros((4_000_000, 2)),
                        posDistThr=np.float64(100.0 * (1 - 1e-9)))
    assert (tmp_path / "ring.npz").stat().st_size < 1_000_000
    with pytest.raises(InvalidParameterError, match="utmQ is for 4000000 queries but there are 50"):
        GroundTruth.from_file(tmp_path / "ring.npz", n_queries=50, n_map=50_000)
    with pytest.raises(InvalidParameterError, match="utmDb is for 50000 map places but there are 49999"):
        GroundTruth.from_file(tmp_path / "ring.npz", n_queries=4_000_000, n_map=49_999)


@pytest.mark.parametrize("layout", ["places", "csr", "csv"])
def test_every_layout_is_checked_against_the_descriptor_counts(tmp_path: Path, layout: str) -> None:
    path = tmp_path / ("gt.csv" if layout == "csv" else "gt.npz")
    if layout == "places":
        np.savez(path, query_places=np.arange(5), n_map=np.int64(9))
    elif layout == "csr":
        np.savez(path, indptr=np.array([0, 1, 2, 2, 3, 3]), indices=np.array([0, 1, 2]), n_map=np.int64(9))
    else:
        path.write_text("query,positive\n0,1\n4,2\n")
    assert GroundTruth.from_file(path, n_queries=5).n_queries == 5
    counted = "has no line for queries 1, 2, 3, 5 " if layout == "csv" else "is for 5 queries but there are 6"
    with pytest.raises(InvalidParameterError, match=counted):
        GroundTruth.from_file(path, n_queries=6)
    if layout != "csv":
        with pytest.raises(InvalidParameterError, match="n_map is for 9 map places but there are 10"):
            GroundTruth.from_file(path, n_queries=5, n_map=10)


def test_a_ring_search_stops_at_its_distance_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without descriptor counts (the Python API) the ring is searched until the tree has computed
    DISTANCES_PER_PAIR distances per pair the limit holds; with counts that match it is answered."""
    from btel.datasets.positions import DISTANCES_PER_PAIR

    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "16M")
    bound = DISTANCES_PER_PAIR * (16 * 2**20 // 16)
    with pytest.raises(ResourceLimitError,
                       match=rf"computed \d+ distances after \d+ of 400000 queries, over the {bound} that"):
        GroundTruth.from_utm(_ring(50_000), np.zeros((400_000, 2)), 100.0 * (1 - 1e-9))
    gt = GroundTruth.from_utm(_ring(50_000), np.zeros((50, 2)), 100.0 * (1 - 1e-9))
    assert gt.n_queries == 50 and gt.indices.size == 0
    gt = GroundTruth.from_utm(_ring(1000), np.zeros((3, 2)), 100.0 * (1 + 1e-9))  # just over: all positives
    assert [gt.positives(j).tolist() for j in range(3)] == [list(range(1000))] * 3


def test_positions_whose_kd_tree_exceeds_the_limit_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "1M")
    with pytest.raises(ResourceLimitError, match="50000 map and 2 query positions with their KD-tree"):
        GroundTruth.from_utm(np.zeros((50_000, 2)), np.zeros((2, 2)), 1.0)


def test_a_mat_inflation_is_walked_in_pieces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 34: a .mat inflating to 256 MB peaked at 844 MB. The walk before scipy inflates in
    1 MiB pieces: its Python allocations stay a few pieces (≈ 7 MiB) however far the file inflates
    (61 MiB here), and past the limit it stops."""
    import tracemalloc

    from btel.datasets.groundtruth_mat import _check_mat5

    scipy.io.savemat(tmp_path / "big.mat", {"utmDb": np.zeros((4_000_000, 2)), "utmQ": np.zeros((2, 2)),
                                            "posDistThr": 1.0}, do_compression=True)
    data = (tmp_path / "big.mat").read_bytes()
    assert len(data) < 100_000  # inflates to 61 MiB
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "65M")
    tracemalloc.start()
    try:
        _check_mat5(data, "'big.mat'")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 12 * 2**20, peak
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", "60M")
    with pytest.raises(ResourceLimitError, match=r"MATLAB file 'big.mat' \(inflated\)"):
        _check_mat5(data, "'big.mat'")


@pytest.mark.parametrize("value, dtype", [(2**64 - 1, np.uint64), (1e30, np.float64)])
def test_a_place_index_beyond_int64_is_named_not_wrapped(value, dtype) -> None:
    """uint64 2⁶⁴ − 1 was cast to −1 and reported as 'found -1'."""
    with pytest.raises(InvalidParameterError, match="not a place index of any map"):
        GroundTruth.from_places(np.array([value, 1, 2], dtype=dtype), n_map=10)


# -- a CSV that omits queries: the message names them, where the count comes from, and the fix -------------
def test_a_csv_omitting_queries_names_them_and_how_to_list_a_query_without_positive(tmp_path: Path) -> None:
    """A CSV of 3 lines (queries 0, 1, 5) for 200 query rows said "it is for 6 queries"; one without
    query 199 said "it is for 199 queries". Both are refused, naming the missing query rows, that the
    count is the highest query index + 1, and the line that lists a query without a positive."""
    (tmp_path / "three.csv").write_text("query,positive\n0,0\n1,1\n5,5\n")
    with pytest.raises(InvalidParameterError) as caught:
        GroundTruth.from_file(tmp_path / "three.csv", n_queries=200)
    message = str(caught.value)
    assert "no line for queries 2, 3, 4, 6, 7 … (197 of the 200 query rows)" in message
    assert "ground truth of 6 queries (its highest query index + 1)" in message and "'199,'" in message
    lines = "".join(f"{q},{q}\n" for q in range(199))
    for header in ("query,positive", "query,positives"):
        (tmp_path / "gt.csv").write_text(f"{header}\n{lines}")
        with pytest.raises(InvalidParameterError, match=r"no line for query 199 \(1 of the 200 query rows\)"):
            GroundTruth.from_file(tmp_path / "gt.csv", n_queries=200)
        (tmp_path / "gt.csv").write_text(f"{header}\n{lines}199,\n")  # the fix the message gives
        gt = GroundTruth.from_file(tmp_path / "gt.csv", n_queries=200)
        assert gt.n_queries == 200 and gt.positives(199).size == 0 and gt.positives(198).tolist() == [198]
    (tmp_path / "past.csv").write_text("query,positive\n0,0\n250,5\n")
    with pytest.raises(InvalidParameterError, match="lists query 250, but there are only 200 query rows"):
        GroundTruth.from_file(tmp_path / "past.csv", n_queries=200)


def test_bad_positions_are_named_as_positions_of_their_file(tmp_path) -> None:
    """A 1-D utmDb was told to reshape "a single descriptor"; a NaN position to "repair those rows before
    fitting"; neither message named the file."""
    import numpy as np
    import pytest

    from btel.datasets import GroundTruth
    from btel.exceptions import InvalidParameterError

    np.savez(tmp_path / "flat.npz", utmDb=np.arange(5.0), utmQ=np.zeros((2, 2)), posDistThr=25)
    np.savez(tmp_path / "nan.npz", utmDb=np.array([[0.0, 0.0], [np.nan, 1.0]]), utmQ=np.zeros((2, 2)), posDistThr=25)
    with pytest.raises(InvalidParameterError, match=r"flat.npz': utmDb must hold one position per row.*shape \(5,\)"):
        GroundTruth.from_file(tmp_path / "flat.npz")
    with pytest.raises(InvalidParameterError, match=r"nan.npz': utmDb holds no finite position at row\(s\) \[1\]"):
        GroundTruth.from_file(tmp_path / "nan.npz")


def test_positives_that_make_most_of_the_map_correct_are_warned_about(tmp_path: Path) -> None:
    """A radius of 10⁹ m made every place correct and random queries scored R@1 = 1.000 without a word."""
    import warnings

    xy = np.stack([np.arange(50) * 10.0, np.zeros(50)], axis=1)
    path = tmp_path / "gt.npz"
    np.savez(path, utmDb=xy, utmQ=xy[:20], posDistThr=1e9)
    with pytest.warns(UserWarning, match=r"makes on average 100% of the 50 map places correct"):
        GroundTruth.from_file(path, n_queries=20, n_map=50)
    np.savez(path, utmDb=xy, utmQ=xy[:20], posDistThr=25.0)  # two or three neighbours each: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gt = GroundTruth.from_file(path, n_queries=20, n_map=50)
    assert 1 <= np.diff(gt.indptr).min() and np.diff(gt.indptr).max() <= 5
