"""Ground truth: frame-aligned places, explicit positives (CSR files), positions within a radius."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from btel.datasets.groundtruth import GroundTruth, load_positives, save_positives
from btel.exceptions import DataNotFoundError, DimensionMismatchError, InvalidParameterError


def test_frame_aligned_tolerance() -> None:
    gt = GroundTruth.frame_aligned(5, n_map=8)
    assert gt.kind == "places" and gt.uses_tolerance and len(gt) == 5
    pred = np.array([0, 3, 2, 7, 4])  # errors 0, 2, 0, 4, 0
    np.testing.assert_array_equal(gt.is_correct(pred, 0), [True, False, True, False, True])
    np.testing.assert_array_equal(gt.is_correct(pred, 2), [True, True, True, False, True])
    np.testing.assert_array_equal(gt.is_correct(pred, 4), [True] * 5)
    np.testing.assert_array_equal(gt.distances(pred), [0, 2, 0, 4, 0])
    # Windows clipped to the map.
    np.testing.assert_array_equal(gt.positives(0, 2), [0, 1, 2])
    np.testing.assert_array_equal(gt.positives(4, 5), [0, 1, 2, 3, 4, 5, 6, 7])


def test_explicit_query_places_and_rank_correct() -> None:
    gt = GroundTruth.from_places([4, 0, 2])
    ranked = np.array([[1, 4, 9], [0, 5, 6], [9, 8, 3]])
    np.testing.assert_array_equal(
        gt.rank_correct(ranked, 0), [[False, True, False], [True, False, False], [False, False, False]]
    )
    np.testing.assert_array_equal(gt.rank_correct(ranked, 1)[2], [False, False, True])


def test_bad_places_and_predictions() -> None:
    with pytest.raises(InvalidParameterError, match="only 3 places"):
        GroundTruth.from_places([0, 5], n_map=3)
    with pytest.raises(InvalidParameterError, match="non-negative"):
        GroundTruth.from_places([0, -1])
    with pytest.raises(InvalidParameterError, match="either query_places"):
        GroundTruth(query_places=[0], indptr=[0, 1], indices=[0])
    gt = GroundTruth.frame_aligned(3)
    with pytest.raises(InvalidParameterError, match="one place index per query \\(3\\)"):
        gt.is_correct([0, 1])
    with pytest.raises(InvalidParameterError, match="whole numbers"):
        gt.is_correct([0.5, 1, 2])
    with pytest.raises(InvalidParameterError, match="tolerance"):
        gt.is_correct([0, 1, 2], tolerance=-1)


def test_positives_ignore_tolerance_and_count_empty_rows_as_wrong() -> None:
    gt = GroundTruth.from_positives([[3, 1, 3], [], [0]], n_map=5)
    assert gt.kind == "positives" and not gt.uses_tolerance
    assert gt.n_without_positives == 1
    np.testing.assert_array_equal(gt.indptr, [0, 2, 2, 3])
    np.testing.assert_array_equal(gt.indices, [1, 3, 0])  # sorted, duplicates merged
    pred = np.array([3, 0, 1])
    for t in (0, 1, 10):
        np.testing.assert_array_equal(gt.is_correct(pred, t), [True, False, False])
    ranked = np.array([[0, 1], [1, 2], [4, 0]])
    np.testing.assert_array_equal(gt.rank_correct(ranked), [[False, True], [False, False], [False, True]])
    # Out-of-map or negative predictions are simply wrong.
    np.testing.assert_array_equal(gt.is_correct([-1, 99, 0]), [False, False, True])
    with pytest.raises(InvalidParameterError, match="one true place per query"):
        gt.distances(pred)


def test_bad_csr_rejected() -> None:
    with pytest.raises(InvalidParameterError, match="indptr must start at 0"):
        GroundTruth.from_csr([0, 2, 1], [0, 1])
    with pytest.raises(InvalidParameterError, match="only 2 places"):
        GroundTruth.from_csr([0, 1], [4], n_map=2)


def test_csr_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    positives = [rng.choice(50, size=rng.integers(0, 6), replace=False) for _ in range(30)]
    path = save_positives(tmp_path / "gt.npz", positives, n_map=50)
    assert path == tmp_path / "gt.npz" and path.is_file()
    with np.load(path, allow_pickle=False) as npz:
        assert set(npz.files) == {"indptr", "indices", "n_map"}
    gt = load_positives(path)
    assert gt.n_queries == 30 and gt.n_map == 50
    for j, expected in enumerate(positives):
        np.testing.assert_array_equal(gt.positives(j), np.sort(expected))
    # Also through the GroundTruth form, and the generic reader.
    again = load_positives(save_positives(tmp_path / "gt2.npz", gt))
    np.testing.assert_array_equal(again.indices, gt.indices)
    assert GroundTruth.from_file(path).kind == "positives"


def test_utm_radius_positives_on_toy_layout() -> None:
    utm_db = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    utm_q = np.array([[12.0, 0.0], [100.0, 0.0], [20.0, 6.0]])
    gt = GroundTruth.from_utm(utm_db, utm_q, 8.0)
    assert gt.n_map == 4
    np.testing.assert_array_equal(gt.positives(0), [1, 2])  # distances 12, 2, 8 (on the boundary), 18
    np.testing.assert_array_equal(gt.positives(1), [])
    np.testing.assert_array_equal(gt.positives(2), [2])  # 6 m from place 2, 11.7 m from places 1 and 3
    assert gt.n_without_positives == 1
    np.testing.assert_array_equal(gt.is_correct([2, 3, 1]), [True, False, False])


def test_utm_positives_match_brute_force_distances() -> None:
    rng = np.random.default_rng(2)
    utm_db = rng.uniform(0, 200, size=(120, 2))
    utm_q = rng.uniform(0, 200, size=(40, 2))
    gt = GroundTruth.from_utm(utm_db, utm_q, 25.0)
    dist = np.linalg.norm(utm_q[:, None, :] - utm_db[None, :, :], axis=2)
    for j in range(40):
        np.testing.assert_array_equal(gt.positives(j), np.flatnonzero(dist[j] <= 25.0))


def test_utm_errors() -> None:
    with pytest.raises(DimensionMismatchError, match="coordinates"):
        GroundTruth.from_utm(np.zeros((3, 2)), np.zeros((2, 3)), 5.0)
    with pytest.raises(InvalidParameterError, match="posDistThr"):
        GroundTruth.from_utm(np.zeros((3, 2)), np.zeros((2, 2)), -1.0)


def test_from_file_dispatches_by_contents(tmp_path: Path) -> None:
    utm_db = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    utm_q = np.array([[9.0, 0.0], [21.0, 0.0]])
    np.savez(tmp_path / "utm.npz", utmDb=utm_db, utmQ=utm_q, posDistThr=np.float64(5.0))
    gt = GroundTruth.from_file(tmp_path / "utm.npz")
    assert [list(gt.positives(j)) for j in range(2)] == [[1], [2]]

    np.savez(tmp_path / "places.npz", query_places=np.array([2, 0, 1]), n_map=np.int64(3))
    gt = GroundTruth.from_file(tmp_path / "places.npz")
    assert gt.kind == "places" and gt.n_map == 3
    np.testing.assert_array_equal(gt.query_places, [2, 0, 1])

    np.save(tmp_path / "places.npy", np.array([1, 1, 0]))
    np.testing.assert_array_equal(GroundTruth.from_file(tmp_path / "places.npy").query_places, [1, 1, 0])

    # MATLAB: top-level variables (rows = places) and NetVLAD's dbStruct (2×n positions).
    scipy.io.savemat(tmp_path / "top.mat", {"utmDb": utm_db, "utmQ": utm_q, "posDistThr": 5.0})
    gt = GroundTruth.from_file(tmp_path / "top.mat")
    assert [list(gt.positives(j)) for j in range(2)] == [[1], [2]]
    db_struct = {
        "whichSet": "test", "utmDb": utm_db.T, "utmQ": utm_q.T, "numImages": 3, "numQueries": 2, "posDistThr": 5.0,
    }
    scipy.io.savemat(tmp_path / "netvlad.mat", {"dbStruct": db_struct})
    gt = GroundTruth.from_file(tmp_path / "netvlad.mat")
    assert gt.n_map == 3 and [list(gt.positives(j)) for j in range(2)] == [[1], [2]]
    scipy.io.savemat(tmp_path / "csr.mat", {"indptr": np.array([0, 1, 3]), "indices": np.array([2, 0, 1])})
    gt = GroundTruth.from_file(tmp_path / "csr.mat")  # MATLAB vectors are 1×n
    assert [list(gt.positives(j)) for j in range(2)] == [[2], [0, 1]]


def test_from_file_errors(tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError, match="does not exist"):
        GroundTruth.from_file(tmp_path / "nothing.npz")
    np.savez(tmp_path / "other.npz", foo=np.arange(3))
    with pytest.raises(DataNotFoundError, match=r"\['foo'\].*match no ground-truth layout"):
        GroundTruth.from_file(tmp_path / "other.npz")
    np.save(tmp_path / "float.npy", np.zeros((3, 2)))
    with pytest.raises(DataNotFoundError, match="1-D integer array"):
        GroundTruth.from_file(tmp_path / "float.npy")
    # An object array is read only when every item is integers (VPR-Bench's per-query positives).
    np.save(tmp_path / "obj.npy", np.array(["a", "b"], dtype=object), allow_pickle=True)
    with pytest.raises(DataNotFoundError, match="found a str where place indices"):
        GroundTruth.from_file(tmp_path / "obj.npy")
    (tmp_path / "junk.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(DataNotFoundError, match="not a MATLAB v5/v7 file"):
        GroundTruth.from_file(tmp_path / "junk.mat")


def test_save_and_reload_places(tmp_path: Path) -> None:
    gt = GroundTruth.from_places([3, 1, 2], n_map=4)
    back = GroundTruth.from_file(gt.save(tmp_path / "sub" / "gt.npz"))
    assert back.kind == "places" and back.n_map == 4
    np.testing.assert_array_equal(back.query_places, [3, 1, 2])


@pytest.mark.realdata
def test_three_forms_agree_on_real_predictions(gardenspoint_netvlad: tuple[np.ndarray, np.ndarray]) -> None:
    """Aligned ± 2 frames, explicit ±2 windows and positions 10 m apart within 25 m are the same truth."""
    from sklearn.neighbors import NearestNeighbors

    X, Q = gardenspoint_netvlad
    nn = NearestNeighbors(n_neighbors=5).fit(X)
    ranked = nn.kneighbors(Q, return_distance=False)
    pred = ranked[:, 0]
    n = X.shape[0]

    aligned = GroundTruth.frame_aligned(Q.shape[0], n_map=n)
    windows = GroundTruth.from_positives([aligned.positives(j, 2) for j in range(Q.shape[0])], n_map=n)
    along_track = np.column_stack([10.0 * np.arange(n), np.zeros(n)])
    utm = GroundTruth.from_utm(along_track, along_track[: Q.shape[0]], 25.0)

    expected = np.abs(pred - np.arange(Q.shape[0])) <= 2
    assert 0 < expected.sum() < expected.size  # real predictions: some right, some wrong
    for gt in (windows, utm):
        np.testing.assert_array_equal(gt.is_correct(pred), expected)
        np.testing.assert_array_equal(gt.rank_correct(ranked), aligned.rank_correct(ranked, 2))
    np.testing.assert_array_equal(aligned.is_correct(pred, 2), expected)
