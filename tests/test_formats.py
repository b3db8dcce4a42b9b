"""Formats and settings users have (issue #14 items 9 and 10): VPR-Bench ground truth without
unpickling, hloc HDF5 global descriptors, CSV positives, and descriptors that say what they did."""

from __future__ import annotations

import os
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.datasets import GroundTruth
from btel.datasets.groundtruth import read_object_npy
from btel.descriptors import get_descriptor
from btel.descriptors.base import DescriptorWarning
from btel.descriptors.npy import load_descriptor_matrix
from btel.exceptions import DataNotFoundError, InvalidDescriptorsError


def _vpr_bench_array(positives: list[list[int]]) -> np.ndarray:
    """VPR-Bench's ground_truth_new.npy layout: rows [query index, positives as an int array]."""
    array = np.empty((len(positives), 2), dtype=object)
    for q, places in enumerate(positives):
        array[q, 0] = q
        array[q, 1] = np.asarray(places, dtype=np.int64)
    return array


def _write_object_npy(path: Path, payload: object, shape: tuple[int, ...], protocol: int = 3) -> None:
    """An .npy file with an object header and any pickle as payload (as a hostile file could be)."""
    with open(path, "wb") as fh:
        np.lib.format.write_array_header_1_0(fh, {"descr": "|O", "fortran_order": False, "shape": shape})
        pickle.dump(payload, fh, protocol=protocol)


# -- 9: VPR-Bench ground truth, read without unpickling arbitrary objects ---------------------------------
def test_vpr_bench_object_array_is_read_as_positives(tmp_path: Path) -> None:
    positives = [[0, 1], [1, 2, 3], [], [4]]
    np.save(tmp_path / "ground_truth_new.npy", _vpr_bench_array(positives), allow_pickle=True)
    gt = GroundTruth.from_file(tmp_path / "ground_truth_new.npy")
    assert gt.kind == "positives" and gt.n_queries == 4
    assert [gt.positives(j).tolist() for j in range(4)] == positives
    # Rows out of query order, lists instead of arrays, a protocol-2 (Python 2 era) pickle: same truth.
    shuffled = _vpr_bench_array(positives)[[2, 0, 3, 1]]
    shuffled[:, 1] = [list(map(int, p)) for p in shuffled[:, 1]]
    _write_object_npy(tmp_path / "p2.npy", shuffled, shuffled.shape, protocol=2)
    again = GroundTruth.from_file(tmp_path / "p2.npy")
    assert [again.positives(j).tolist() for j in range(4)] == positives
    # One item of positives per query (1-D object array).
    one_d = np.empty(2, dtype=object)
    one_d[0], one_d[1] = np.array([3], dtype=np.int32), np.array([0, 1], dtype=np.uint16)
    np.save(tmp_path / "flat.npy", one_d, allow_pickle=True)
    assert GroundTruth.from_file(tmp_path / "flat.npy").positives(1).tolist() == [0, 1]


class _RunsCode:
    """Unpickling this calls os.system (a file that would run code under np.load(allow_pickle=True))."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_a_pickle_that_would_run_code_is_refused_without_running(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    hostile = np.empty((1, 2), dtype=object)
    hostile[0, 0], hostile[0, 1] = 0, _RunsCode(marker)
    _write_object_npy(tmp_path / "evil.npy", hostile, (1, 2))
    with pytest.raises(DataNotFoundError, match=r"refused global (posix|nt)\.system"):
        GroundTruth.from_file(tmp_path / "evil.npy")
    assert not marker.exists()
    # Allowed globals, wrong contents: floats and strings are not place indices.
    floats = np.empty(1, dtype=object)
    floats[0] = np.array([0.5])
    np.save(tmp_path / "floats.npy", floats, allow_pickle=True)
    with pytest.raises(DataNotFoundError, match="dtype float64"):
        read_object_npy(tmp_path / "floats.npy")
    # builtins.eval is a global like any other: refused.
    _write_object_npy(tmp_path / "eval.npy", (eval, ("1",)), (1,))
    with pytest.raises(DataNotFoundError, match="refused global builtins"):
        read_object_npy(tmp_path / "eval.npy")


def test_csv_positives_in_both_layouts(tmp_path: Path) -> None:
    (tmp_path / "pairs.csv").write_text("query,positive\n0,5\n0,6\n2,7\n")
    gt = GroundTruth.from_file(tmp_path / "pairs.csv")
    assert gt.n_queries == 3 and gt.positives(0).tolist() == [5, 6] and gt.positives(1).tolist() == []
    (tmp_path / "lists.csv").write_text("query,positives\n0,5 6\n1,\n2,7;8\n")
    gt = GroundTruth.from_file(tmp_path / "lists.csv")
    assert [gt.positives(j).tolist() for j in range(3)] == [[5, 6], [], [7, 8]]
    (tmp_path / "bad.csv").write_text("q,place\n0,1\n")
    with pytest.raises(DataNotFoundError, match="query,positive"):
        GroundTruth.from_file(tmp_path / "bad.csv")


def _write_hloc(path: Path, names: list[str], X: np.ndarray) -> None:
    import h5py

    with h5py.File(path, "w") as fh:
        for name, x in zip(names, X):
            fh.create_group(name).create_dataset("global_descriptor", data=x)


def test_cli_reads_an_h5_of_top_level_images_as_one_set_and_keeps_its_refusal_short(tmp_path: Path) -> None:
    """Every top-level image was its own prefix: a flat file was refused with a message as long as it."""
    X = np.random.default_rng(0).normal(size=(40, 8)).astype(np.float32)
    _write_hloc(tmp_path / "flat.h5", [f"img{i:04d}.png" for i in range(40)], X)
    result = CliRunner().invoke(main, ["train", str(tmp_path / "flat.h5"), "-o", str(tmp_path / "m.npz"),
                                       "--method", "pq", "--budget", "2KB"])
    assert result.exit_code == 0, result.output
    _write_hloc(tmp_path / "many.h5", [f"p{i}/x.png" for i in range(40)], X)
    result = CliRunner().invoke(main, ["train", str(tmp_path / "many.h5"), "-o", str(tmp_path / "m2.npz"),
                                       "--method", "pq", "--budget", "2KB"])
    assert result.exit_code == 2 and "under 40 prefixes (p0/ 1 images" in result.output
    assert len(result.output) < 800


def test_cli_refuses_an_h5_holding_map_and_queries_without_a_prefix(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(40, 8)).astype(np.float32)
    _write_hloc(tmp_path / "feats.h5", [f"db/{i}.jpg" for i in range(30)] + [f"query/{i}.jpg" for i in range(10)], X)
    h5 = str(tmp_path / "feats.h5")
    for args in (["train", h5, "-o", str(tmp_path / "m.npz"), "--method", "pq", "--budget", "2KB"],
                 ["evaluate", "--db", f"{h5}:db/", "--queries", h5, "--methods", "pq", "--budget", "2KB",
                  "--out", str(tmp_path / "run")]):
        result = CliRunner().invoke(main, args)
        assert result.exit_code == 2, result.output
        assert "2 prefixes (db/ 30 images, query/ 10 images)" in result.output
        assert f"{h5}:db/ or {h5}:query/" in result.output
    assert not (tmp_path / "m.npz").exists()
    # One prefix only: read as it is.
    _write_hloc(tmp_path / "map.h5", [f"db/{i}.jpg" for i in range(30)], X[:30])
    result = CliRunner().invoke(main, ["train", str(tmp_path / "map.h5"), "-o", str(tmp_path / "m.npz"),
                                       "--method", "pq", "--budget", "2KB"])
    assert result.exit_code == 0, result.output


def test_cli_names_npz_arrays_in_cli_syntax(tmp_path: Path) -> None:
    np.savez(tmp_path / "both.npz", a=np.ones((5, 4), np.float32), b=np.ones((5, 4), np.float32))
    result = CliRunner().invoke(main, ["train", str(tmp_path / "both.npz"), "-o", str(tmp_path / "m.npz")])
    assert result.exit_code == 2 and f"choose one: {tmp_path / 'both.npz'}:a." in result.output
    assert "key=" not in result.output


def test_hloc_global_descriptors_in_natural_name_order(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    names = ["db/img10.jpg", "db/img2.jpg", "db/img1.jpg", "query/img1.jpg"]
    X = rng.normal(size=(4, 8)).astype(np.float32)
    _write_hloc(tmp_path / "feats.h5", names, X)
    db = load_descriptor_matrix(f"{tmp_path / 'feats.h5'}:db/")
    np.testing.assert_array_equal(db, X[[2, 1, 0]])  # img1, img2, img10
    np.testing.assert_array_equal(load_descriptor_matrix(tmp_path / "feats.h5"), X[[2, 1, 0, 3]])
    with pytest.raises(DataNotFoundError, match="under 'nope/'"):
        load_descriptor_matrix(f"{tmp_path / 'feats.h5'}:nope/")
    np.savez(tmp_path / "both.npz", hlrTrain=X[:2], hlrTest=X[2:])  # EchoVPR's layout: FILE.npz:KEY picks one
    np.testing.assert_array_equal(load_descriptor_matrix(f"{tmp_path / 'both.npz'}:hlrTest"), X[2:])
    (tmp_path / "not.h5").write_bytes(b"plain text")
    with pytest.raises(InvalidDescriptorsError, match="not a readable HDF5"):
        load_descriptor_matrix(tmp_path / "not.h5")


@pytest.mark.realdata
def test_evaluate_reads_hloc_and_vpr_bench_files(gardenspoint_netvlad, tmp_path: Path) -> None:
    """Gardens Point NetVLAD descriptors as hloc .h5 and a VPR-Bench ground truth (±2 frames), end to end."""
    X, Q = gardenspoint_netvlad
    _write_hloc(tmp_path / "gp.h5", [f"db/{i}.jpg" for i in range(200)] + [f"query/{i}.jpg" for i in range(200)],
                np.concatenate([X, Q]))
    positives = [list(range(max(0, j - 2), min(200, j + 3))) for j in range(200)]
    np.save(tmp_path / "ground_truth_new.npy", _vpr_bench_array(positives), allow_pickle=True)
    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["evaluate", "--db", f"{tmp_path / 'gp.h5'}:db/", "--queries",
                                       f"{tmp_path / 'gp.h5'}:query/", "--methods", "pq", "--budget", "20KB",
                                       "--ground-truth", str(tmp_path / "ground_truth_new.npy"), "--out", str(out),
                                       "--no-progress"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    import json

    rows = {r["name"]: r for r in json.loads((out / "metrics.json").read_text())["results"]}
    # The positives are the ±2 window, so R@1 of brute force equals its frame-aligned recall@2.
    nn = np.argmax((X / np.linalg.norm(X, axis=1, keepdims=True)) @ (Q / np.linalg.norm(Q, axis=1, keepdims=True)).T,
                   axis=0)
    assert rows["bruteforce"]["recall_at_k"]["1"] == pytest.approx(np.mean(np.abs(nn - np.arange(200)) <= 2))
    assert rows["pq"]["recall"] == {} and set(rows["pq"]["recall_at_k"]) == {"1", "5", "10", "20"}


# -- 10: descriptors say what they did to the images ------------------------------------------------------
def test_stretching_resize_and_mixed_sizes_warn() -> None:
    wide = [np.zeros((360, 640), np.uint8) + i for i in range(3)]
    with pytest.warns(DescriptorWarning, match=r"resizes every image to 64×32.*640×360.*size=\(56, 32\)"):
        get_descriptor("hog").transform(wide, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the right aspect: silent
        get_descriptor("hog", size=(56, 32)).transform(wide, progress=False)
        get_descriptor("patchnorm").transform([np.zeros((32, 64), np.uint8)], progress=False)
    mixed = [np.zeros((32, 64), np.uint8), np.zeros((64, 128), np.uint8)]
    with pytest.warns(DescriptorWarning, match="come in 2 sizes"):
        get_descriptor("patchnorm").transform(mixed, progress=False)


@pytest.mark.realdata
def test_densevlad_cap_is_warned_and_extract_help_says_it(gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    images = sorted((gardenspoint_sample_dir / "ref").glob("*.jpg"))[:4]
    with pytest.warns(DescriptorWarning, match=r"n_components=64 requested, 3-D descriptors produced.*n_train − 1 = 3"):
        get_descriptor("densevlad", n_clusters=4, n_components=64, step=16).fit(images, progress=False)
    help_text = " ".join(CliRunner().invoke(main, ["extract", "--help"]).output.split())
    assert "--size WxH" in help_text and "capped at (map images − 1)" in help_text and "stretched" in help_text
