"""Traverse folders, paired descriptor files and near-black frames."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from btel.datasets.traverses import (
    DARK_THRESHOLD,
    aligned_pairs,
    dark_frames,
    list_traverses,
    load_pair,
    mean_brightness,
    natural_key,
    traverse_images,
)
from btel.exceptions import (
    DataNotFoundError,
    DimensionMismatchError,
    InvalidDescriptorsError,
    InvalidParameterError,
    ResourceLimitError,
)


def _write(path: Path, grey: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    # Colour PNG like nordland64 (grey stored as RGB), so the grey conversion is exercised.
    cv2.imwrite(str(path), np.full((8, 16, 3), grey, dtype=np.uint8))


@pytest.fixture()
def layout(tmp_path: Path) -> Path:
    for name, grey in [("images-1.png", 0), ("images-2.png", 50), ("images-10.png", 200)]:
        _write(tmp_path / "summer" / name, grey)
    for name, grey in [("images-1.png", 100), ("images-10.png", 3), ("images-11.png", 80)]:
        _write(tmp_path / "winter" / name, grey)
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("not a traverse")
    return tmp_path


def test_natural_key_orders_digit_runs_by_value() -> None:
    names = ["img10.png", "img2.png", "IMG1.png", "img2a.png"]
    assert sorted(names, key=natural_key) == ["IMG1.png", "img2.png", "img2a.png", "img10.png"]


def test_list_traverses_keeps_folders_with_images(layout: Path) -> None:
    assert list_traverses(layout) == ["summer", "winter"]


def test_traverse_images_natural_order(layout: Path) -> None:
    names = [p.name for p in traverse_images(layout, "summer")]
    assert names == ["images-1.png", "images-2.png", "images-10.png"]


def test_missing_root_and_traverse_raise(layout: Path, tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError, match="does not exist"):
        list_traverses(tmp_path / "nowhere")
    with pytest.raises(DataNotFoundError, match="autumn.*available"):
        traverse_images(layout, "autumn")
    with pytest.raises(DataNotFoundError, match="holds no images"):
        traverse_images(layout, "empty")
    (tmp_path / "bare").mkdir()
    with pytest.raises(DataNotFoundError, match="no sub-folder with images"):
        list_traverses(tmp_path / "bare")


def test_aligned_pairs_reports_what_it_drops(layout: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="btel.datasets.traverses"):
        aligned = aligned_pairs(layout, "summer", "winter")
    assert aligned.names == ["images-1.png", "images-10.png"]
    assert len(aligned) == 2
    assert [p.parent.name for p in aligned.map_paths] == ["summer", "summer"]
    assert [p.name for p in aligned.query_paths] == aligned.names
    assert aligned.dropped_map == ["images-2.png"]
    assert aligned.dropped_query == ["images-11.png"]
    assert (aligned.n_dropped_map, aligned.n_dropped_query) == (1, 1)
    assert "dropped 1 map-only and 1 query-only" in caplog.text


def test_aligned_pairs_errors(layout: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidParameterError, match="two different traverses"):
        aligned_pairs(layout, "summer", "summer")
    _write(tmp_path / "other" / "a" / "x.png", 10)
    _write(tmp_path / "other" / "b" / "y.png", 10)
    with pytest.raises(DataNotFoundError, match="share no file name"):
        aligned_pairs(tmp_path / "other", "a", "b")


def test_dark_frames_from_paths_and_arrays(layout: Path) -> None:
    aligned = aligned_pairs(layout, "summer", "winter")
    map_dark, query_dark = aligned.dark_masks()
    # summer images-1 is 0 (dark), images-10 is 200; winter images-1 is 100, images-10 is 3 (dark).
    np.testing.assert_array_equal(map_dark, [True, False])
    np.testing.assert_array_equal(query_dark, [False, True])

    grey = np.array([9, 10, 11, 255], dtype=np.uint8)
    stack = np.repeat(grey[:, None, None], 4, axis=1).repeat(4, axis=2)  # (4, 4, 4) uint8 images
    np.testing.assert_array_equal(dark_frames(stack), [True, False, False, False])
    # The same images as float rows in [0, 1] (one flattened image per row).
    rows = stack.reshape(4, -1).astype(np.float32) / 255.0
    np.testing.assert_allclose(mean_brightness(rows), grey / 255.0, rtol=1e-6)
    np.testing.assert_array_equal(dark_frames(rows, threshold=12 / 255), [True, True, True, False])
    # A list of individual images (one of them colour).
    images = [np.zeros((4, 4), np.uint8), np.full((4, 4, 3), 120, np.uint8)]
    np.testing.assert_array_equal(dark_frames(images), [True, False])


def test_dark_frames_bad_input() -> None:
    with pytest.raises(InvalidParameterError, match="fraction of full white"):
        dark_frames(np.zeros((2, 4)), threshold=10)
    with pytest.raises(InvalidParameterError, match="uint8"):
        dark_frames([np.zeros((4, 4), dtype=np.int32)])
    with pytest.raises(InvalidParameterError, match="wrap it in a list"):
        dark_frames("image.png")
    with pytest.raises(DataNotFoundError, match="not a readable image"):
        dark_frames([Path("/nonexistent/image.png")])


def test_load_pair_round_trip_and_errors(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    db, q = rng.normal(size=(6, 5)), rng.normal(size=(4, 5))
    np.save(tmp_path / "db.npy", db)
    np.save(tmp_path / "q.npy", q)
    got_db, got_q = load_pair(tmp_path / "db.npy", tmp_path / "q.npy")
    assert got_db.dtype == np.float32 and got_q.dtype == np.float32
    np.testing.assert_allclose(got_db, db, rtol=1e-6)
    np.testing.assert_allclose(got_q, q, rtol=1e-6)

    with pytest.raises(DataNotFoundError, match="missing.npy"):
        load_pair(tmp_path / "db.npy", tmp_path / "missing.npy")
    np.save(tmp_path / "q3.npy", q[:, :3])
    with pytest.raises(DimensionMismatchError, match="3 features but the map has 5"):
        load_pair(tmp_path / "db.npy", tmp_path / "q3.npy")
    bad = q.copy()
    bad[2, 1] = np.nan
    np.save(tmp_path / "qnan.npy", bad)
    with pytest.raises(InvalidDescriptorsError, match="NaN"):
        load_pair(tmp_path / "db.npy", tmp_path / "qnan.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataNotFoundError, match="never loads pickles"):
        load_pair(tmp_path / "obj.npy", tmp_path / "q.npy")
    with open(tmp_path / "decl.npy", "wb") as fh:  # 100 bytes declaring 373 GiB: a bare MemoryError before
        header = {"descr": "<f4", "fortran_order": False, "shape": (10**9, 100)}
        np.lib.format.write_array_header_1_0(fh, header)
        fh.write(b"\0" * 64)
    with pytest.raises(ResourceLimitError, match="query descriptors file .*decl.npy"):
        load_pair(tmp_path / "db.npy", tmp_path / "decl.npy")


@pytest.mark.realdata
def test_nordland_alignment_and_dark_frames(nordland_dir: Path) -> None:
    assert list_traverses(nordland_dir) == ["summer", "winter"]
    aligned = aligned_pairs(nordland_dir, "summer", "winter")
    assert len(aligned) == 3576
    assert aligned.n_dropped_map == 0 and aligned.n_dropped_query == 0
    assert aligned.names[0] == "images-00010.png" and aligned.names[-1] == "images-35760.png"

    summer_dark, winter_dark = aligned.dark_masks(DARK_THRESHOLD)
    n_summer, n_winter = int(summer_dark.sum()), int(winter_dark.sum())
    print(f"near-black frames (mean grey < 10/255): summer {n_summer}, winter {n_winter} of {len(aligned)}")
    # The data README says ~170 (summer) and ~90 (winter).
    assert 120 <= n_summer <= 230
    assert 60 <= n_winter <= 130
    # The summer video starts in the dark.
    assert summer_dark[:10].all()
