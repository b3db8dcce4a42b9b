"""``btel extract``'s cache vouches only for what it read: images, fit-on images, fitted arrays.

The cache (``OUTPUT.json`` beside the matrix, :func:`btel.descriptors.extract.extraction_key`) is
reused when nothing changed; these tests change each input it depends on and check that the
output is not taken for up to date, and that the command says what changed.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from click.testing import CliRunner

from btel.cli import main
from btel.descriptors import DenseVLADDescriptor
from btel.descriptors.extract import extraction_difference, extraction_key
from btel.descriptors.images import list_images

_FAST = {"n_clusters": 4, "n_components": None, "sizes": (4,), "step": 6, "max_descriptors": 2000, "kmeans_iter": 5}


def _folder(path: Path, seed: int, n: int = 6) -> Path:
    path.mkdir()
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(path / f"img{i}.png"), rng.integers(0, 255, size=(32, 48), dtype=np.uint8))
    return path


def _invoke(*args: object) -> "click.testing.Result":  # noqa: F821
    return CliRunner().invoke(main, [str(a) for a in args])


def test_a_changed_fit_on_folder_changes_the_key(tmp_path: Path) -> None:
    images, fit_on = _folder(tmp_path / "q", 0), _folder(tmp_path / "map", 1)
    model = DenseVLADDescriptor(**_FAST)
    before = extraction_key(list_images(images), model, fit_on)
    first = sorted(fit_on.iterdir())[0]
    cv2.imwrite(str(first), np.zeros((32, 48), dtype=np.uint8))
    os.utime(first, ns=(1, 1))  # a new mtime whatever the clock's resolution
    assert extraction_key(list_images(images), model, fit_on) != before


def test_a_descriptor_file_fitted_again_changes_the_key(tmp_path: Path) -> None:
    images = _folder(tmp_path / "q", 0)
    one = DenseVLADDescriptor(**_FAST).fit(list_images(_folder(tmp_path / "a", 1)), progress=False)
    two = DenseVLADDescriptor(**_FAST).fit(list_images(_folder(tmp_path / "b", 2)), progress=False)
    assert one.get_params() == two.get_params()  # the same parameters: only the fitted arrays differ
    key_one, key_two = (extraction_key(list_images(images), m) for m in (one, two))
    assert key_one["fitted_sha1"] != key_two["fitted_sha1"] and key_one != key_two
    assert extraction_key(list_images(images), one) == key_one  # and the key is stable


def test_extract_names_what_changed_since_its_earlier_extraction(tmp_path: Path) -> None:
    images = _folder(tmp_path / "imgs", 0)
    out = tmp_path / "d.npy"
    assert _invoke("extract", images, "-o", out, "--no-progress").exit_code == 0
    assert "up to date" in _invoke("extract", images, "-o", out, "--no-progress").output
    before = out.read_bytes()
    cv2.imwrite(str(images / "img9.png"), np.zeros((32, 48), dtype=np.uint8))
    result = _invoke("extract", images, "-o", out, "--no-progress", "--size", "40x20")
    assert result.exit_code == 2 and "Usage:" not in result.output
    assert "holds an earlier extraction of these images that no longer matches" in result.output
    assert "1 image added (e.g. img9.png)" in result.output and "size: [64, 32] → [40, 20]" in result.output
    assert out.read_bytes() == before
    again = _invoke("extract", images, "-o", out, "--no-progress", "--size", "40x20", "--overwrite")
    assert again.exit_code == 0 and np.load(out).shape[0] == 7
    assert extraction_difference(out, images, DenseVLADDescriptor(**_FAST)) is not None  # another descriptor


def test_extract_says_what_in_the_folder_it_does_not_read(tmp_path: Path) -> None:
    images = _folder(tmp_path / "imgs", 0, n=3)
    (images / "notes.txt").write_text("route notes")
    (images / "nested").mkdir()
    (images / ".DS_Store").write_bytes(b"")  # hidden: not worth a word
    (images / "loop.jpg").symlink_to(images / "loop.jpg")  # an image's name on no regular file: says so
    result = CliRunner().invoke(main, ["extract", str(images), "-o", str(tmp_path / "d.npy"), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "3 entries of" in result.output
    assert "are not images btel reads (loop.jpg (not a regular file), nested/, notes.txt)" in result.output
    assert np.load(tmp_path / "d.npy").shape[0] == 3


def test_a_descriptor_file_that_is_not_there_is_named_as_a_missing_file(tmp_path: Path) -> None:
    images = _folder(tmp_path / "imgs", 0, n=2)
    result = _invoke("extract", images, "-o", tmp_path / "d.npy", "--descriptor", tmp_path / "dv.npz")
    assert result.exit_code == 2 and "no such file" in result.output and "unknown descriptor" not in result.output


def test_a_matrix_replaced_or_damaged_since_its_extraction_is_no_cache(tmp_path: Path) -> None:
    """`btel extract` said "up to date" over other data of the same shape written to OUTPUT, and a truncated
    cached matrix in an experiment's cache ended the run (exit 2) instead of being extracted again."""
    import json

    from btel.descriptors.extract import extract_cached

    images, out = _folder(tmp_path / "imgs", seed=1), tmp_path / "ex.npy"
    assert _invoke("extract", images, "-o", out, "--no-progress").exit_code == 0
    record = json.loads(Path(str(out) + ".json").read_text())
    assert record["output"]["bytes"] == out.stat().st_size  # the record vouches for these bytes
    assert "up to date" in _invoke("extract", images, "-o", out, "--no-progress").output
    original = np.load(out)
    np.save(out, np.random.default_rng(0).standard_normal(original.shape).astype(np.float32))
    result = _invoke("extract", images, "-o", out, "--no-progress")
    assert result.exit_code == 2 and "ex.npy itself (other bytes than the extraction wrote)" in result.output
    assert not np.array_equal(np.load(out), original)  # the user's data stays until --overwrite
    # A cache btel owns (an experiment's): a damaged matrix is extracted again, with or without its bytes recorded.
    for legacy in (False, True):
        with open(out, "r+b") as fh:
            fh.truncate(200)
        if legacy:  # a record from before btel kept the matrix's bytes
            Path(str(out) + ".json").write_text(json.dumps({k: v for k, v in record.items() if k != "output"}))
        X, reused = extract_cached(images, out, "hog", progress=False)
        assert not reused and np.array_equal(X, original) and np.array_equal(np.load(out), original)


def test_files_of_the_users_beside_the_output_are_never_replaced_without_overwrite(tmp_path: Path) -> None:
    """`btel extract … -o new.npy` replaced the user's new.npy.json (its record's path) without a word, and
    --delta replaced X.plain.npy and X.plain.npy.json (its cache of the plain descriptors). Each is refused
    before anything is written; --overwrite replaces a file, never a folder; btel's own cache is reused."""
    images = _folder(tmp_path / "imgs", 0)
    notes = tmp_path / "new.npy.json"
    notes.write_text('{"my": "notes"}')
    refused = _invoke("extract", images, "-o", tmp_path / "new.npy", "--descriptor", "patchnorm")
    assert refused.exit_code != 0 and "new.npy.json" in refused.output and "--overwrite" in refused.output
    assert notes.read_text() == '{"my": "notes"}' and not (tmp_path / "new.npy").exists()
    plain = tmp_path / "d.plain.npy"
    plain.write_text("precious")
    refused = _invoke("extract", images, "-o", tmp_path / "d.npy", "--delta", 2, "--descriptor", "patchnorm")
    assert refused.exit_code != 0 and "d.plain.npy" in refused.output
    assert plain.read_text() == "precious" and not (tmp_path / "d.npy").exists()
    record = tmp_path / "e.plain.npy.json"
    record.write_text("precious")
    refused = _invoke("extract", images, "-o", tmp_path / "e.npy", "--delta", 2, "--descriptor", "patchnorm")
    assert refused.exit_code != 0 and record.read_text() == "precious" and not (tmp_path / "e.plain.npy").exists()
    (tmp_path / "f.npy.json").mkdir()
    refused = _invoke("extract", images, "-o", tmp_path / "f.npy", "--descriptor", "patchnorm", "--overwrite")
    assert refused.exit_code != 0 and "folder" in refused.output and not (tmp_path / "f.npy").exists()
    for _ in range(2):  # btel's own cache of the plain descriptors: written, then reused without --overwrite
        done = _invoke("extract", images, "-o", tmp_path / "g.npy", "--delta", 2, "--descriptor", "patchnorm")
        assert done.exit_code == 0, done.output
        (tmp_path / "g.npy").unlink()
    replaced = _invoke("extract", images, "-o", tmp_path / "new.npy", "--descriptor", "patchnorm", "--overwrite")
    assert replaced.exit_code == 0 and '"descriptor"' in notes.read_text()
